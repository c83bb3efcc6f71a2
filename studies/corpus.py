"""A corpus of disk packings made in different ways, each with its exact linear response: the data
the statistics-only closure (``microhom.closure``) is fitted to and tested on (issue 25).

    python -m studies.corpus [--cache DIR] [--quick] [--only PROTOCOL ...]

Each corpus row is *data*: a :class:`CorpusRow` (protocol name, its knobs, seed, N), so that it can
be mapped onto a protocol object later. A row is built once (its contact network is cached as one
npz under ``--cache``, default ``out/closure/cache/``, keyed by the row's parameters and written
atomically) and measured at every kt/kn of :data:`KT_RATIOS` (the same geometry and forces, only
the tangent stiffness changes; cached as a CSV beside the network). A rerun only computes what is
missing.

Protocols (:data:`PROTOCOLS`):

``pack_frictional``
    :func:`dem.engine.packing.pack`: random gas, servo compression to p/kn, equilibrium at the
    preparation friction ``mu_prep``, then the test friction 0.5 (kt = kn); sliding contacts as the
    packing left them.
``pack_frictionless``
    :func:`dem.engine.packing.pack` with mu = mu_prep = 0 (the specialised frictionless law, servo +
    FIRE quench): the densest packings at each pressure, no tangential forces.
``lammps_prep``
    LAMMPS (through :func:`dem.engine.lammps.run_lammps`), the ``studies/lammps_bench/in.prep`` protocol
    many users follow: soft push-off of a random insertion, fixed-rate isotropic compression
    (``fix deform``) to a target solid fraction, relaxation at fixed box with friction 0.5 and a
    global drag. The tangential forces are not read back: the network has normal forces from the
    overlaps, no sliding contacts.
``minimise``
    The jamming literature's protocol (O'Hern et al. 2003; jax-md's ``minimize``): random
    positions at a fixed solid fraction, harmonic repulsion ``U = kn/2 sum overlap^2``, energy
    minimised (scipy L-BFGS, up to 20 restarts while the largest force exceeds 1e-12 kn d; the
    reached residual is stored as ``grad_max``, 1e-7 to 1.5e-6 of the mean contact force on the
    corpus); frictionless. Radii: the
    50:50 bidisperse 1:1.4 mixture or uniform with dispersity 0.5.
``pack_slowdamped``
    :func:`dem.engine.packing.pack` with the older single-damping protocol (``damping_compaction=None,
    fire=False``: heavy local damping throughout the slow compaction), frictional.
``pack_study``
    The main study's packings (``python -m studies.kuhn``): :func:`dem.engine.packing.pack` with the
    protocol of ``studies.cases.PROTOCOL`` (the one before issue 12.3: ``damping_compaction=0.1,
    dt_over_dtcrit=0.8, fire=False``), identical disks, test friction tan 26 deg (0.4877), kt = kn;
    knobs mu_prep (0.05: the main study's) and p/kn (1e-4: the main study's). Identical disks at
    small mu_prep partly order (psi6 up to ~0.5).
``dem_fixedphi``
    The ``lammps_prep`` protocol run by this project's disk engine (``_dem_fixedphi``, which
    drives :class:`dem.engine.integrate.Simulation` directly: :func:`dem.engine.packing.pack`
    only servo-compresses to a pressure): a cold random gas at phi 0.30 (random sequential
    addition, no overlaps, where LAMMPS pushes a random insertion apart), fixed-rate compression
    with the box side linear in time to the target phi (LAMMPS ``fix deform ... final``, the same
    20000 steps of 0.2 sqrt(m/kn)), then relaxation at fixed box until the translational kinetic
    energy per particle is below 1e-12 kn d^2 (checked every 100 steps, at most 400000 steps);
    :class:`dem.engine.contact_laws.LinearFriction` with kt = kn, mu = 0.5 and normal and
    tangential dashpots of damping ratio 0.05, plus the global drag ``F = -0.1 sqrt(kn m) v`` of
    ``in.prep`` (LAMMPS ``fix viscous``, applied to the translational velocities after every
    step), no local damping. Read back as the LAMMPS rows are: normal forces from the overlaps,
    no tangential forces, no sliding contacts (the engine's own sliding fraction is kept in the
    row's meta).

Exact response: :func:`dem.analysis.stiffness.stiffness` of the network with ``kt = ratio * kn`` (kn = 1),
without pre-stress (``K``, ``G``; the target of the closure, as the theory) and with it (``K_ps``,
``G_ps``, the geometric stiffness of the normal forces), stated per row.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["CorpusRow", "packing_protocol", "PROTOCOLS", "KT_RATIOS", "corpus_rows", "build_network", "measure_network",
           "load_corpus", "network_features"]

#: tangent over normal stiffness at which every packing is analysed
KT_RATIOS = (0.0, 0.05, 0.2, 0.5, 1.0)
#: bump when the measurement changes (invalidates the cached measurement CSVs, not the packings)
MEASURE_VERSION = 5
#: measurement versions that differ from the current one only by statistics of
#: :func:`network_features` (5 added psi6, psi6_local): their exact moduli are kept and the
#: statistics recomputed from the cached network
FEATURES_ONLY_SINCE = (4,)
PROTOCOLS = ("pack_frictional", "pack_frictionless", "lammps_prep", "minimise", "pack_slowdamped", "pack_study",
             "dem_fixedphi")


@dataclass(frozen=True)
class CorpusRow:
    """One packing of the corpus, as data.

    protocol : one of :data:`PROTOCOLS`; knobs : sorted ``(name, value)`` pairs of the protocol's
    parameters (p_over_kn, mu_prep, dispersity, phi, radii law...); seed : random seed; n : disks.
    """

    protocol: str
    knobs: tuple
    seed: int
    n: int

    @property
    def params(self) -> dict:
        return dict(self.knobs)

    @property
    def key(self) -> str:
        """File-name key: protocol, N, seed and a short hash of the knobs."""
        h = hashlib.sha1(json.dumps([self.protocol, list(self.knobs), self.seed, self.n]).encode()).hexdigest()[:10]
        return f"{self.protocol}_n{self.n}_s{self.seed}_{h}"

    def describe(self) -> str:
        return f"{self.protocol}(" + ", ".join(f"{k}={v}" for k, v in self.knobs) + f"; seed {self.seed}, N {self.n})"


def _row(protocol, n, seed, **knobs):
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")
    return CorpusRow(protocol, tuple(sorted(knobs.items())), int(seed), int(n))


def corpus_rows(quick=False) -> list[CorpusRow]:
    """The rows of the corpus (``quick``: a tiny corpus of N = 300 for CI)."""
    if quick:
        n = 300
        return [_row("pack_frictional", n, 1, p_over_kn=1e-3, mu_prep=0.3, dispersity=0.2),
                _row("pack_frictionless", n, 1, p_over_kn=1e-3, dispersity=0.2),
                _row("minimise", n, 1, phi=0.87, radii="bidisperse")]
    rows = []
    for seed in (1, 2, 3):
        for mp in (0.1, 0.3, 1.0):
            for p in (1e-4, 1e-3, 1e-2, 3e-2):
                rows.append(_row("pack_frictional", 1000, seed, p_over_kn=p, mu_prep=mp, dispersity=0.2))
        for mp in (0.05, 0.3):    # identical disks with the default protocol, as pack_study
            for p in (1e-4, 1e-3):
                rows.append(_row("pack_frictional", 1000, seed, p_over_kn=p, mu_prep=mp, dispersity=0.0))
        for d in (0.2, 0.45):     # dem.engine.packing takes dispersity < 0.5
            for p in (1e-4, 1e-3, 1e-2):
                rows.append(_row("pack_frictionless", 1000, seed, p_over_kn=p, dispersity=d))
        for radii in ("bidisperse", "uniform0.5"):
            for phi in (0.85, 0.87, 0.91):
                rows.append(_row("minimise", 1000, seed, phi=phi, radii=radii))
        for d in (0.1, 0.3):
            for phi in (0.83, 0.86):
                rows.append(_row("lammps_prep", 1000, seed, phi=phi, dispersity=d))
                rows.append(_row("dem_fixedphi", 1000, seed, phi=phi, dispersity=d))
            rows.append(_row("lammps_prep", 1000, seed, phi=0.845, dispersity=d))
            rows.append(_row("dem_fixedphi", 1000, seed, phi=0.845, dispersity=d))
        rows.append(_row("pack_slowdamped", 1000, seed, p_over_kn=1e-2, mu_prep=0.3, dispersity=0.0))
        rows.append(_row("pack_slowdamped", 1000, seed, p_over_kn=1e-3, mu_prep=0.05, dispersity=0.3))
        for mp in (0.05, 0.3):    # the main study's packings (identical frictional disks, low p)
            for p in (1e-4, 1e-3):
                rows.append(_row("pack_study", 1000, seed, p_over_kn=p, mu_prep=mp, dispersity=0.0))
    # two more seeds of the LAMMPS protocol, by LAMMPS and by this engine (the two mirror each other)
    rows += [_row(prot, 1000, seed, phi=phi, dispersity=d) for seed in (4, 5) for d in (0.1, 0.3)
             for phi in (0.83, 0.86) for prot in ("lammps_prep", "dem_fixedphi")]
    big = [_row("pack_frictional", 4000, 7, p_over_kn=1e-3, mu_prep=0.3, dispersity=0.2),
           _row("minimise", 4000, 7, phi=0.87, radii="bidisperse")]
    # build order: seeds 1 and 2 of every protocol (interleaved, so that a partial corpus is
    # balanced), then the N = 4000 rows, then seeds 3 and up
    first = sorted((r for r in rows if r.seed < 3), key=lambda r: (r.seed, PROTOCOLS.index(r.protocol)))
    return first + big + [r for r in rows if r.seed >= 3]


# ---- building ------------------------------------------------------------------------------------
def _save_network(path, net, meta):
    d = {k: getattr(net, k) for k in ("positions", "radii", "cell", "pairs", "branch", "kn", "kt", "sliding")}
    for k in ("fn", "ft"):
        if getattr(net, k) is not None:
            d[k] = getattr(net, k)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp_", suffix=".npz")
    os.close(fd)
    np.savez(tmp, meta=json.dumps(meta), **d)
    os.replace(tmp, path)


def _load_network(path):
    from microhom.network import ContactNetwork
    z = np.load(path)
    kw = {k: z[k] for k in z.files if k != "meta"}
    return ContactNetwork(**kw), json.loads(str(z["meta"]))


def _minimise(row):
    """Harmonic frictionless disks at fixed phi, energy minimised from random positions."""
    from scipy.optimize import minimize
    from scipy.spatial import cKDTree
    p = row.params
    rng = np.random.default_rng(row.seed)
    n = row.n
    if p["radii"] == "bidisperse":
        rad = np.where(np.arange(n) < n // 2, 0.5, 0.7)
    elif p["radii"].startswith("uniform"):
        d = float(p["radii"][len("uniform"):])
        rad = 0.5 * (1 + d * rng.uniform(-1, 1, n))
    else:
        raise ValueError(f"radii must be 'bidisperse' or 'uniformD', got {p['radii']!r}")
    L = float(np.sqrt(np.pi * np.sum(rad ** 2) / p["phi"]))
    x0 = rng.uniform(0, L, (n, 2))
    cut = 2 * rad.max()

    def energy(flat):
        x = np.mod(flat.reshape(n, 2), L)
        tree = cKDTree(x, boxsize=L)
        pr = tree.query_pairs(cut, output_type="ndarray")
        i, j = pr[:, 0], pr[:, 1]
        d = x[j] - x[i]
        d -= L * np.round(d / L)
        dist = np.hypot(d[:, 0], d[:, 1])
        ov = rad[i] + rad[j] - dist
        m = ov > 0
        i, j, d, dist, ov = i[m], j[m], d[m], dist[m], ov[m]
        e = 0.5 * np.sum(ov ** 2)
        f = (ov / dist)[:, None] * d          # force magnitude ov along the normal i->j, on j
        g = np.zeros((n, 2))
        np.add.at(g, i, f)
        np.add.at(g, j, -f)
        return e, g.ravel()

    x = x0.ravel()
    for _ in range(20):
        r = minimize(energy, x, jac=True, method="L-BFGS-B",
                     options=dict(maxiter=20000, gtol=1e-13, ftol=0.0, maxcor=20))
        x = r.x
        if np.abs(r.jac).max() < 1e-12:
            break
    pos = np.mod(x.reshape(n, 2), L)
    return pos, rad, np.eye(2) * L, dict(grad_max=float(np.abs(energy(x)[1]).max()))


_IN_PREP = Path(__file__).resolve().parent / "lammps_bench" / "in.prep"


def _lammps_prep(row, work):
    from dem import io
    from dem.engine.lammps import run_lammps
    p = row.params
    text = _IN_PREP.read_text()
    text = text.replace("variable dmin    equal 0.9", "variable dmin    index 0.9")
    text = text.replace("variable dmax    equal 1.1", "variable dmax    index 1.1")
    if "variable dmin    index" not in text or "variable dmax    index" not in text:
        raise RuntimeError("studies/lammps_bench/in.prep changed: cannot set the radius range")
    work.mkdir(parents=True, exist_ok=True)
    (work / "in.prep").write_text(text)
    d = float(p["dispersity"])
    # LAMMPS takes its -var options from the command line: run through dem.engine.lammps with them
    cmd_vars = ["-var", "N", str(row.n), "-var", "seed", str(4242 + row.seed), "-var", "phi", str(p["phi"]),
                "-var", "dmin", f"{1 - d:.6g}", "-var", "dmax", f"{1 + d:.6g}", "-var", "out", "final.data"]
    run_lammps(work, input_name="in.prep", extra_args=cmd_vars)
    cfg = io.read(work / "final.data")
    return np.asarray(cfg.positions)[:, :2], np.asarray(cfg.radii), np.asarray(cfg.cell)[:2, :2], {}


#: the in.prep protocol in this engine's units (kn = 1, mean diameter 1, unit mass of a mean disk)
FIXEDPHI = dict(phi0=0.30, ncomp=20000, nrelax=400000, kestop=1e-12, dt=0.2, zeta=0.05, drag=0.1, mu=0.5)


class _LinearBox:
    """Cell control of ``fix deform ... final``: the (square) box side changes linearly in time at
    ``rate`` [m/s], i.e. the isotropic velocity gradient is ``rate / L`` (L the current side)."""

    def __init__(self, rate):
        self.rate = float(rate)

    def update(self, state, p, K, dt):
        e = self.rate / state.h[0, 0]
        return np.array([[e, 0.0], [0.0, e]])

    def to_meta(self):
        return {"kind": "linear_box", "rate": self.rate}


def _dem_fixedphi(row, verbose=False):
    """The ``lammps_prep`` protocol run by this engine (module docstring, ``dem_fixedphi``):
    (positions, radii, cell, meta) of the relaxed packing."""
    from dem.engine.contact_laws import LinearFriction
    from dem.engine.integrate import Simulation
    from dem.engine.packing import PackingProtocol, network_from_state, random_gas
    c, p = FIXEDPHI, row.params
    proto = PackingProtocol(n=row.n, seed=row.seed, dispersity=p["dispersity"], radius=0.5, kn=1.0,
                            phi0=c["phi0"], gas_overlaps=False)
    st = random_gas(proto, spins=True)       # areal density 4/pi: a disk of diameter 1 has mass 1
    e = float(np.exp(-np.pi * c["zeta"] / np.sqrt(1 - c["zeta"] ** 2)))   # restitution of zeta
    law = LinearFriction(kn=1.0, kt=1.0, mu=c["mu"], restitution=e, tangential_damping=True)
    sim = Simulation(st, law, dt=c["dt"], damping=0.0)
    if sim.dt > sim.dt_crit:
        raise RuntimeError(f"dt = {sim.dt} above the engine's dt_crit {sim.dt_crit}")
    m1 = 1.0                                  # mass of a mean disk (in.prep's m1)
    fac = np.exp(-c["drag"] * np.sqrt(m1) * sim.dt / st.mass)[:, None]   # fix viscous, exact per step
    L_target = float(np.sqrt(np.sum(np.pi * st.radius ** 2) / p["phi"]))
    sim.control = _LinearBox((L_target - st.h[0, 0]) / (c["ncomp"] * sim.dt))
    for k in range(c["ncomp"]):
        sim.step(tally=False)
        st.v *= fac
    st.h = np.diag([L_target, L_target])     # remove the round-off of the linear ramp
    sim.need_rebuild = True
    sim.control = None
    st.L = np.zeros((2, 2))
    nrel, ke = 0, np.inf
    while nrel < c["nrelax"]:
        for k in range(100):
            sim.step(tally=False)
            st.v *= fac
        nrel += 100
        ke = 0.5 * float(np.sum(st.mass[:, None] * st.v ** 2)) / st.n
        if ke < c["kestop"]:
            break
    if verbose:
        print(f"  dem_fixedphi: {nrel} relaxation steps, KE/N {ke:.3g}", flush=True)
    m = sim.refresh()
    net = network_from_state(st, sim.law)
    order = np.argsort(st.ids, kind="stable")
    from microhom.periodic import wrap
    pos = wrap(st.x[order], st.h)[0]
    return pos, st.radius[order].copy(), st.h.copy(), dict(
        steps_relax=nrel, ke_per_particle=ke, relaxed=bool(ke < c["kestop"]), engine_unbalanced=m["unbalanced"],
        engine_sliding_fraction=float(net.sliding.mean()) if net.n_contacts else 0.0,
        engine_p_over_kn=float(np.sum(net.fn * np.hypot(*net.branch.T)) / (2 * net.area)) if net.n_contacts else 0.0)


def packing_protocol(row: CorpusRow):
    """The :class:`dem.engine.packing.PackingProtocol` of a row made by the disk DEM (``pack_*``
    protocols): the corpus's rows of that kind are protocols plus a name."""
    from dem.engine.packing import PackingProtocol
    if not row.protocol.startswith("pack_"):
        raise ValueError(f"row protocol {row.protocol!r} is not made by dem.engine.packing.pack")
    p = row.params
    kw = dict(n=row.n, p_over_kn=p["p_over_kn"], dispersity=p["dispersity"], seed=row.seed, kn=1.0,
              kt_over_kn=1.0)
    if row.protocol == "pack_frictionless":
        kw.update(mu=0.0, mu_prep=0.0)
    else:
        kw.update(mu=0.5, mu_prep=p["mu_prep"])
    if row.protocol == "pack_slowdamped":
        kw.update(damping_compaction=None, fire=False)
    if row.protocol == "pack_study":
        from studies.cases import DEFAULTS, PROTOCOL
        kw.update(mu=DEFAULTS["mu"], **PROTOCOL)
    return PackingProtocol(**kw)


def build_network(row: CorpusRow, cache: Path):
    """The row's contact network (kn = 1, kt = kn), from the cache or built and cached."""
    from microhom.network import from_overlaps
    cache = Path(cache)
    cache.mkdir(parents=True, exist_ok=True)
    path = cache / f"{row.key}.npz"
    if path.exists():
        return _load_network(path)
    t0 = time.perf_counter()
    meta = dict(row=asdict(row))
    if row.protocol.startswith("pack_"):
        from dem.engine.packing import pack
        res = pack(packing_protocol(row))
        net = res.to_network()
        if row.protocol == "pack_frictionless":   # no contact is at a Coulomb limit: tangent springs act
            net = net.with_stiffness(kt=1.0, sliding=False)
        meta.update(converged=bool(res.report["converged"]), steps=int(res.report["steps"]))
    else:
        if row.protocol == "minimise":
            pos, rad, cell, extra = _minimise(row)
        elif row.protocol == "dem_fixedphi":
            pos, rad, cell, extra = _dem_fixedphi(row)
        else:
            pos, rad, cell, extra = _lammps_prep(row, cache / "lammps" / row.key)
            # LAMMPS lengths are in mean diameters already (mean radius 0.5): keep them
        net = from_overlaps(pos, rad, cell, kn=1.0, kt=1.0, tolerance=0.0)
        net = replace(net, fn=net.overlaps * net.kn, ft=np.zeros(net.n_contacts))
        meta.update(extra)
    meta["build_s"] = time.perf_counter() - t0
    _save_network(path, net, meta)
    return net, meta


# ---- measuring -----------------------------------------------------------------------------------
def network_features(net) -> dict:
    """Candidate statistics of a network at its own stiffnesses (rattlers per the tangent stiffness).

    Returns a dict: Z (load-bearing mean contacts), Z_iso (isostatic point implied by the mobilised
    contacts: 4 frictionless, 6 / (2 - s) with s the sliding fraction of the load-bearing contacts),
    dZ = Z - Z_iso, r, phi, rattler_fraction, sliding_fraction, dispersity (sqrt(3) std/mean of the
    radii), z_size_corr (correlation of radius and contact count over load-bearing particles),
    Z_size (radius-weighted mean contact count), f_min (fraction of load-bearing particles with the
    minimum contact count: 2 frictional, 3 frictionless), psi6 and psi6_local (bond-orientational
    order of the load-bearing contacts, global ``|<psi6_i>|`` and mean ``|psi6_i|``:
    :func:`microhom.structural_sums.bond_order`), fabric_anisotropy, force_anisotropy
    (2 (F1 - F2) of the force-weighted fabric), p_over_kn (pressure over mean kn), fn_cv (normal
    force coefficient of variation).
    """
    from microhom.structural_sums import bond_order, network_statistics, rattlers
    st = network_statistics(net)
    bo = bond_order(net, 6)
    rat, active = rattlers(net)
    n = net.n_particles
    counts = (np.bincount(net.pairs[active, 0], minlength=n) + np.bincount(net.pairs[active, 1], minlength=n))
    keep = ~rat
    fric = bool(np.any(net.effective_kt[active] > 0))
    s = float(net.sliding[active].mean()) if active.any() else 0.0
    z_iso = 6.0 / (2.0 - s) if fric else 4.0
    R = net.radii
    c = counts[keep].astype(float)
    rk = R[keep]
    zsc = float(np.corrcoef(rk, c)[0, 1]) if keep.sum() > 2 and rk.std() > 0 else 0.0
    nrm = net.normals[active]
    F = np.einsum("ci,cj->ij", nrm, nrm) / max(len(nrm), 1)
    w = np.linalg.eigvalsh(F)
    out = dict(Z=st.nc, Z_all=st.nc_all, Z_iso=z_iso, dZ=st.nc - z_iso, r=st.r, phi=st.phi,
               rattler_fraction=st.rattler_fraction, sliding_fraction=s,
               dispersity=float(np.sqrt(3) * R.std() / R.mean()), z_size_corr=zsc,
               Z_size=float(np.sum(c * rk) / np.sum(rk)) if len(c) else 0.0,
               f_min=float(np.mean(c == (2 if fric else 3))) if len(c) else 0.0,
               fabric_anisotropy=float(2 * (w[1] - w[0])), psi6=bo.psi, psi6_local=bo.psi_local)
    if net.fn is not None and active.any():
        fn = net.fn[active]
        Ff = np.einsum("c,ci,cj->ij", fn, nrm, nrm) / np.sum(fn)
        wf = np.linalg.eigvalsh(Ff)
        sig = -np.einsum("c,ci,cj->ij", fn, net.branch[active], nrm) / net.area
        out.update(force_anisotropy=float(2 * (wf[1] - wf[0])),
                   p_over_kn=float(-np.trace(sig) / 2 / np.mean(net.kn)), fn_cv=float(fn.std() / fn.mean()))
    return out


def measure_network(net, row: CorpusRow, kt_ratios=KT_RATIOS) -> list[dict]:
    """One dict per kt/kn: the row's description, the candidate statistics, the exact moduli."""
    from dem.analysis.stiffness import stiffness
    rows = []
    if row.protocol == "pack_frictionless":
        # the frictionless law flags every contact sliding (mu = 0); the corpus analyses the
        # lubricated geometry with tangential springs, none at a Coulomb limit
        net = net.with_stiffness(sliding=False)
    for kr in kt_ratios:
        nk = net.with_stiffness(kt=kr * np.asarray(net.kn))
        d = dict(protocol=row.protocol, key=row.key, seed=row.seed, n=row.n, kt_over_kn=kr,
                 **{f"knob_{k}": v for k, v in row.knobs})
        try:
            d.update(network_features(nk))
        except (ValueError, FloatingPointError) as exc:
            d.update(note=f"statistics: {exc}")
            rows.append(d)
            continue
        for ps in (False, True):
            with warnings.catch_warnings(record=True) as wl:
                warnings.simplefilter("always")
                try:
                    ex = stiffness(nk, prestress=ps)
                except (ValueError, RuntimeError) as exc:
                    d["note"] = f"stiffness: {exc}"
                    break
            sfx = "_ps" if ps else ""
            d.update({f"K{sfx}": ex.K, f"G{sfx}": ex.G})
            if not ps:
                d.update(K_aff=ex.K_affine, G_aff=ex.G_affine, n_floppy=ex.n_floppy,
                         flags=";".join(sorted(ex.flags)) if ex.flags else "",
                         warning="; ".join(str(w.message) for w in wl)[:200])
        rows.append(d)
    return rows


def _measured(row, cache, kt_ratios):
    path = Path(cache) / f"{row.key}.v{MEASURE_VERSION}.csv"
    if path.exists():
        return pd.read_csv(path, keep_default_na=False, na_values=[""])
    old = [Path(cache) / f"{row.key}.v{v}.csv" for v in FEATURES_ONLY_SINCE]
    old = [p for p in old if p.exists()]
    if old and (Path(cache) / f"{row.key}.npz").exists():
        df = _refresh_features(pd.read_csv(old[-1], keep_default_na=False, na_values=[""]), row, cache)
    else:
        net, meta = build_network(row, cache)
        df = pd.DataFrame(measure_network(net, row, kt_ratios))
        df["build_s"] = meta.get("build_s", np.nan)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp_", suffix=".csv")
    os.close(fd)
    df.to_csv(tmp, index=False)
    os.replace(tmp, path)
    return df


def _refresh_features(df, row, cache):
    """An older measurement (``FEATURES_ONLY_SINCE``) brought to the current one: the statistics
    of :func:`network_features` recomputed on the cached network at each kt/kn, the exact moduli
    kept (they do not depend on the statistics)."""
    net, _ = build_network(row, cache)
    if row.protocol == "pack_frictionless":
        net = net.with_stiffness(sliding=False)
    df = df.copy()
    notes = df["note"].fillna("").astype(str) if "note" in df else pd.Series([""] * len(df))
    for i, kr in enumerate(df.kt_over_kn.to_numpy()):
        if notes.iloc[i].startswith("statistics:"):
            continue
        for k, v in network_features(net.with_stiffness(kt=kr * np.asarray(net.kn))).items():
            df.loc[i, k] = v
    return df


def load_corpus(cache="out/closure/cache", quick=False, only=None, build=True, verbose=True,
                kt_ratios=KT_RATIOS) -> pd.DataFrame:
    """Every row of :func:`corpus_rows` measured (from the cache; built where missing unless
    ``build=False``, then missing rows are skipped)."""
    frames = []
    for row in corpus_rows(quick):
        if only and row.protocol not in only:
            continue
        have = (Path(cache) / f"{row.key}.v{MEASURE_VERSION}.csv").exists() or (Path(cache) / f"{row.key}.npz").exists()
        if not build and not have:
            continue
        t0 = time.perf_counter()
        try:
            frames.append(_measured(row, cache, kt_ratios))
        except Exception as exc:  # a failed build is reported, never silently dropped
            print(f"FAILED {row.describe()}: {type(exc).__name__}: {exc}", flush=True)
            continue
        if verbose:
            print(f"{row.describe()}: {time.perf_counter() - t0:.1f} s", flush=True)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="out/closure/cache")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", nargs="*", choices=PROTOCOLS)
    args = ap.parse_args(argv)
    df = load_corpus(args.cache, quick=args.quick, only=args.only)
    out = Path(args.cache).parent
    out.mkdir(parents=True, exist_ok=True)
    df.to_csv(out / ("corpus_quick.csv" if args.quick else "corpus.csv"), index=False)
    print(f"{len(df)} measured rows -> {out}")


if __name__ == "__main__":
    main()
