"""LAMMPS's own strain probes on a 3D frictional packing: the peer of the exact (6, 6) tensor.

    python -m studies.lammps_probes3d [--n 1000] [--p-over-kn 1e-3] [--mu 0 0.5]
                                      [--amplitudes 1e-7 1e-6 1e-5] [--out out/lammps_probes3d]

A 3D packing made by the project's LAMMPS deck (:func:`dem.engine.lammps.write_inputs` with
``dimension=3``, ``gran/hooke/history``, one ``write_restart`` appended so that the tangential
contact histories survive) is relaxed once more by LAMMPS to round-off (the *base* state, whose
network is read back with :func:`dem.io.lammps_run.read_run`). From the base restart LAMMPS applies
each of the six Mandel strain modes with amplitude ``+a`` and ``-a``:

* ramp: the box is deformed by ``fix deform ... remap v`` over ``ramp_steps`` steps while every
  sphere starts with the affine streaming velocity ``v = L (x - x_c)`` (so the contact histories,
  which integrate the relative velocity at the contact point, see the affine part of the motion;
  ghost spheres across the periodic boundary carry the box's velocity offset, ``remap v``);
* relaxation: velocities and spins zeroed, damped dynamics (``fix nve/sphere``, ``fix viscous`` on
  translations, contact dashpots ``gamma_n = gamma_t`` on the relative motion, rotations free,
  tangential history kept) until the unbalanced force and torque ratios are below ``tol``;
* the stress: ``compute pressure NULL virial`` (no kinetic part), printed with 17 digits.

LAMMPS's restricted triclinic box allows only upper-triangular displacement gradients ``L`` (its
edge ``a`` stays on x, ``b`` in the xy plane): a shear mode ``E_ab`` is applied as the tilt
``L_ab = 2 E_ab`` (a < b), i.e. the strain ``E`` plus the rigid rotation ``W = L - E``. The
rotation turns the pre-stress, ``d sigma = W sigma0 - sigma0 W`` at first order; that term (with
LAMMPS's own ``sigma0``) is removed from the measured increment, so that the central difference

    C[:, b] = (sigma(+a e_b) - sigma(-a e_b)) / (2 a)  - rotation term,   sigma = -P (tension positive)

is the Cauchy stiffness of ``dem.analysis.stiffness.stiffness(network, prestress=True,
spin_arm="radius")`` (``gran/hooke/history`` turns the contact point with the sphere's radius as
arm), which includes the geometric terms of the tangential forces under LAMMPS's history update
(the history projected on the turning tangent plane). On frictionless spheres the two agree to the
probes' accuracy (3e-8 of the largest entry on 300 spheres). With friction the probes differ from
it by the response to their rotations ``W`` beyond the turn of the stress (LAMMPS's history does
not follow a turn about the normal, and the radius arm slips by overlap x turn) and by reading the
non-symmetric ``P`` from its upper triangle: :func:`probe_tangent` computes both exactly, and the
probes agree with it to their own accuracy (1e-8 on 300 spheres). The figures are in
``docs/spheres.md``. Packings are prepared at ``mu_prep = min(mu, 0.05)``, then ``mu``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dem.engine.lammps import lammps_available, read_dump_local, read_run, run_lammps, write_inputs
from dem.engine.packing import PackingProtocol
from microhom.results import Result
from microhom.tensors import isotropic_moduli, mandel_to_strain, strain_to_mandel

__all__ = ["ProbesResult", "ProbeComparison", "pack_with_restart", "relax_base", "lammps_probes",
           "probe_tangent", "compare", "report", "main"]

_PCOMP = ("pxx", "pyy", "pzz", "pyz", "pxz", "pxy")   # Mandel order of LAMMPS's 6 components
_RESULT_LINE = "PROBE_RESULT"


@dataclass(frozen=True, eq=False)
class ProbesResult(Result):
    """The (6, 6) stiffness measured by LAMMPS's strain probes on one relaxed 3D packing.

    Attributes
    ----------
    C_mandel : (6, 6) array
        Cauchy stiffness over Mandel ``[xx, yy, zz, sqrt2 yz, sqrt2 xz, sqrt2 xy]`` [Pa] at the
        smallest amplitude (central differences, the rotation of the pre-stress removed; column b
        from the +- probes of mode b).
    C_by_amplitude : dict
        amplitude -> (6, 6) array [Pa], the same tensor at every amplitude probed.
    K, G : float
        Isotropic projection of ``C_mandel`` [Pa] (:func:`microhom.tensors.isotropic_moduli`).
    amplitudes : tuple of float
        Strain amplitudes probed (Mandel norm of the strain, dimensionless).
    stress0 : (3, 3) array
        LAMMPS's stress of the base state [Pa], tension positive: ``-P`` of ``compute pressure``,
        symmetric from LAMMPS's six components (``P_ab = (1/V) sum c_a f_b`` for a <= b; the full
        P is not symmetric: ``(1/V) sum -overlap (n f_t - f_t n)``, LAMMPS's torque arm being the
        radius).
    asymmetry : float
        Largest ``|sigma(+a) + sigma(-a) - 2 sigma0| / (2 a)`` over the modes at the smallest
        amplitude, over the largest entry of ``C_mandel`` (the second-order term, O(a); a probe
        that opened or closed a contact shows here).
    residual : float
        Largest stress change over the last ``tail_steps`` steps of the relaxations (the
        relaxation residual), divided by ``a``, over the largest entry of ``C_mandel``.
    unbalanced : float
        Largest final unbalanced ratio over all probes: mean |force| and mean |torque| / radius
        over the mean contact force, the larger (the relaxations stop on both: LAMMPS's pressure
        gives one of each pair of shear components, ``P_ab = (1/V) sum c_a f_b``, a < b, equal to
        the other only where the torques balance).
    contact_events : int
        Largest change of the contact count of a probe against the base state.
    sliding_by_amplitude : dict
        amplitude -> the largest number of contacts at the Coulomb limit ``|f_t| >= mu f_n`` after
        a probe (``compute pair/local``; 0 at mu = 0, where no contact carries a tangential force).
    steps : int
        LAMMPS time steps of all probes (ramps, relaxations, tails).
    lammps_time : float
        LAMMPS's own loop time of all probes [s] (from the logs: the same when the probes are
        read back from a cache).
    wall_time : float
        Wall time of this call [s] (LAMMPS's runs, one process each; small when cached).
    """

    C_mandel: np.ndarray
    C_by_amplitude: dict
    K: float
    G: float
    amplitudes: tuple
    stress0: np.ndarray
    asymmetry: float
    residual: float
    unbalanced: float
    contact_events: int
    sliding_by_amplitude: dict
    steps: int
    lammps_time: float
    wall_time: float


@dataclass(frozen=True, eq=False)
class ProbeComparison(Result):
    """LAMMPS's probes against the exact tensor of the network read back from the same state.

    Attributes
    ----------
    C_exact : (6, 6) array
        ``stiffness(network, prestress=True, spin_arm="radius").C_mandel`` [Pa].
    C_probes : (6, 6) array
        :attr:`ProbesResult.C_mandel` [Pa].
    difference : float
        ``max |C_probes - C_exact| / max |C_exact|`` (all 36 entries).
    difference_by_amplitude : dict
        amplitude -> the same figure at each amplitude.
    amplitude_spread : float
        ``max |C(a_max) - C(a_min)| / max |C_exact|``: the probes' own accuracy across amplitudes.
    K_exact, G_exact, K_probes, G_probes : float
        Isotropic projections [Pa].
    prestress_size : float
        ``max |prestress_correction(sigma0)| / max |C_exact|``: how much the comparison depends on
        the pre-stress terms (without them the difference would be about this large).
    tangential_scale : float
        ``(1/V) sum_c |f_t| |c|`` over ``max |C_exact|``: the order of the geometric terms of the
        tangential forces (0 on frictionless spheres).
    C_lammps : (6, 6) array
        :func:`probe_tangent`: what the probes measure, computed exactly from the network [Pa]
        (LAMMPS's history law under the probes' gradients ``E_b + W_b``, the upper triangle of
        ``P`` read as LAMMPS prints it).
    difference_lammps : float
        ``max |C_probes - C_lammps| / max |C_exact|``, all 36 entries.
    difference_lammps_by_amplitude : dict
        amplitude -> the same figure at each amplitude.
    rotation_size : float
        ``max |C_lammps - C_exact| / max |C_exact|``: how much the probes' rotations and the
        upper-triangle reading move the measurement off the Cauchy tensor of a pure strain.
    spin_arm : str
        The spin arm of the exact solve (``"radius"``, LAMMPS's).
    min_contacts : int or None
        The exact solve's rattler threshold (None: the solver's rule, 2 contacts with friction).
    n_unstable : int
        Negative modes of the exact solve's Hessian under the pre-stress (with tangential forces:
        of the symmetric part of its non-symmetric tangent, docs/spheres.md).
    n_contacts, n_rattlers, n_sliding : int
        Of the network read back.
    exact_time : float
        Wall time of the exact solve [s].
    """

    C_exact: np.ndarray
    C_probes: np.ndarray
    difference: float
    difference_by_amplitude: dict
    amplitude_spread: float
    K_exact: float
    G_exact: float
    K_probes: float
    G_probes: float
    prestress_size: float
    tangential_scale: float
    spin_arm: str
    min_contacts: object
    C_lammps: np.ndarray
    difference_lammps: float
    difference_lammps_by_amplitude: dict
    rotation_size: float
    n_unstable: int
    n_contacts: int
    n_rattlers: int
    n_sliding: int
    exact_time: float


def pack_with_restart(protocol, folder, *, timeout=None, **knobs):
    """The LAMMPS 3D packing of ``protocol`` in ``folder`` (reused when ``folder/params.json``
    exists): :func:`dem.engine.lammps.write_inputs` (``dimension=3``) with ``write_restart
    final.restart`` appended, run on one process; returns
    (:class:`dem.io.lammps_run.LammpsRun`, params dict, LAMMPS wall time [s] of the packing)."""
    folder = Path(folder)
    done = folder / "params.json"
    if done.exists():
        prm = json.loads(done.read_text())
        return read_run(folder, prm), prm, float(prm.get("_wall_s", float("nan")))
    prm = write_inputs(folder, protocol, dimension=3, **knobs)
    deck = folder / "in.packing"
    deck.write_text(deck.read_text() + "write_restart   final.restart\n")
    info = run_lammps(folder, np=1, timeout=timeout)
    prm["_wall_s"] = info["wall_s"]
    run = read_run(folder, prm)
    done.write_text(json.dumps(prm))
    return run, prm, info["wall_s"]


def _damping(prm):
    """(contact dashpot gamma [1/s], drag [kg/s]) of the relaxations: gamma = 0.5 sqrt(kn / m1),
    drag = 0.1 sqrt(kn m1), m1 the mass of a sphere of the mean radius."""
    return 0.5 * math.sqrt(prm["kn"] / prm["m1"]), 0.1 * math.sqrt(prm["kn"] * prm["m1"])


def _head(prm, restart) -> str:
    """The deck's common part: the restart, the damped law (history kept: same pair style
    re-issued), integration and the measurements."""
    N = repr
    gam, drag = _damping(prm)
    return f"""\
units           lj
dimension       3
atom_style      sphere
boundary        p p p
comm_modify     vel yes
newton          on
read_restart    {restart}
pair_style      gran/hooke/history {N(float(prm['kn']))} {N(float(prm['kt']))} {N(gam)} {N(gam)} {N(float(prm['mu']))} 1
pair_coeff      * *
neighbor        {N(float(prm['skin']))} bin
neigh_modify    delay 0 every 1 check yes
fix             nve all nve/sphere
timestep        {N(float(prm['dt']))}
compute         pv all pressure NULL virial
compute         cn all contact/atom
compute         zsum all reduce sum c_cn
compute         pl all pair/local force
compute         fsum all reduce sum c_pl
variable        fres atom sqrt(fx*fx+fy*fy+fz*fz)
compute         fres all reduce ave v_fres
variable        nc equal c_zsum/2
variable        fmean equal c_fsum/(v_nc+1.0e-300)
variable        unbf equal c_fres/(v_fmean+1.0e-300)
compute         tq all property/atom tqx tqy tqz radius
variable        tres atom sqrt(c_tq[1]*c_tq[1]+c_tq[2]*c_tq[2]+c_tq[3]*c_tq[3])/c_tq[4]
compute         tres all reduce ave v_tres
variable        unbt equal c_tres/(v_fmean+1.0e-300)
variable        unb equal (v_unbf>v_unbt)*v_unbf+(v_unbf<=v_unbt)*v_unbt
thermo_style    custom step c_pv c_pv[1] c_pv[2] c_pv[3] c_pv[4] c_pv[5] c_pv[6] v_unbf v_unbt v_unb v_nc
thermo_modify   norm no
thermo          10000
"""


def _relax_lines(prm, tol, max_steps, check_every, tail_steps) -> str:
    gam, drag = _damping(prm)
    line = " ".join(f"{k}=$(c_pv[{i}]:%.17g)" for i, k in
                    zip((1, 2, 3, 6, 5, 4), _PCOMP))
    return f"""\
velocity        all set 0.0 0.0 0.0
set             group all omega 0.0 0.0 0.0
fix             drag all viscous {drag!r}
fix             halt all halt {check_every} v_unb < {tol!r} error continue
run             {max_steps}
unfix           halt
run             0 post no
print           "{_RESULT_LINE} stage=relaxed step=$(step) unbalanced=$(v_unb:%.6e) contacts=$(v_nc) {line}"
run             {tail_steps} post no
print           "{_RESULT_LINE} stage=tail step=$(step) unbalanced=$(v_unb:%.6e) contacts=$(v_nc) {line}"
"""


def _parse(log):
    out = {}
    for raw in Path(log).read_text(errors="replace").splitlines():
        if raw.startswith(_RESULT_LINE):
            kv = dict(tok.split("=", 1) for tok in raw.split()[1:] if "=" in tok)
            stage = kv.pop("stage")
            out[stage] = {k: float(v) for k, v in kv.items()}
    return out


def _stress(rec):
    """Tension-positive (3, 3) stress from LAMMPS's six pressure components."""
    P = np.empty((3, 3))
    for (a, b), k in {(0, 0): "pxx", (1, 1): "pyy", (2, 2): "pzz", (1, 2): "pyz", (0, 2): "pxz",
                      (0, 1): "pxy"}.items():
        P[a, b] = P[b, a] = rec[k]
    return -P


def relax_base(folder, prm, *, tol=1e-13, max_steps=200_000, check_every=100, tail_steps=500):
    """Relax the packing in ``folder`` (its ``final.restart``) to ``tol`` in the probes' damped
    dynamics, write ``probes/base/base.restart`` and the state in ``probes/base/`` as a run folder
    (``final.dump``, ``contacts.dump``, ``log.lammps``); return (LammpsRun, log records).
    Reused when done."""
    pdir = Path(folder) / "probes" / "base"
    pdir.mkdir(parents=True, exist_ok=True)
    if not (pdir / "base.restart").exists():
        deck = _head(prm, "../../final.restart").replace(
            "pair_style", "change_box      all triclinic\npair_style", 1)
        deck += _relax_lines(prm, tol, max_steps, check_every, tail_steps) + """\
unfix           drag
velocity        all set 0.0 0.0 0.0
set             group all omega 0.0 0.0 0.0
compute         pf all pair/local dist force p1 p2 p3
compute         pp all property/local patom1 patom2
dump            d1 all custom 1 final.dump id type radius x y z vx vy vz fx fy fz c_cn
dump_modify     d1 format float %.17g sort id first yes
dump            d2 all local 1 contacts.dump c_pp[1] c_pp[2] c_pf[1] c_pf[2] c_pf[3] c_pf[4] c_pf[5]
dump_modify     d2 format float %.17g first yes
run             0
undump          d1
undump          d2
print           "PACK_RESULT N=$(atoms) pressure=$(c_pv:%.17g)"
write_restart   base.restart
"""
        (pdir / "in.base").write_text(deck)
        run_lammps(pdir, input_name="in.base")
    return read_run(pdir, prm), _parse(pdir / "log.lammps")


def _probe_deck(prm, mode, amp, ramp_steps, relax) -> str:
    """Deck of one probe: Mandel mode ``mode`` (0..5) with Mandel amplitude ``amp`` (signed)."""
    E = mandel_to_strain(amp * np.eye(6)[mode])
    L = np.triu(E) + np.triu(E, 1)                  # upper triangular, sym(L) = E
    T = ramp_steps * float(prm["dt"])

    def R(x):
        return repr(float(x))
    vel = [" + ".join(f"{R(L[a, b] / T)}*({c}-v_c{c})" for b, c in enumerate("xyz") if L[a, b] != 0)
           or "0.0" for a in range(3)]
    # box after the ramp: h' = (I + L) h, h upper triangular (orthogonal at the base: tilts 0 there
    # unless LAMMPS's base box is tilted, handled by the general formula below)
    deform = []
    for k, (a, b) in {"x": (0, 0), "y": (1, 1), "z": (2, 2)}.items():
        if L[a, b] != 0:
            deform.append(f"{k} scale {R(1.0 + L[a, b])}")
    tilt = {"xy": "(v_L00*xy+v_L01*ly)", "xz": "(v_L00*xz+v_L01*yz+v_L02*lz)",
            "yz": "(v_L11*yz+v_L12*lz)"}
    for k in tilt:
        deform.append(f"{k} delta $({tilt[k]})")
    lvars = "\n".join(f"variable        L{a}{b} equal {R(L[a, b])}" for a in range(3) for b in range(3)
                      if b >= a)
    return (_head(prm, "base/base.restart") + f"""\
{lvars}
variable        cx equal 0.5*(xlo+xhi)
variable        cy equal 0.5*(ylo+yhi)
variable        cz equal 0.5*(zlo+zhi)
variable        vx atom {vel[0]}
variable        vy atom {vel[1]}
variable        vz atom {vel[2]}
velocity        all set v_vx v_vy v_vz
set             group all omega 0.0 0.0 0.0
fix             def all deform 1 {' '.join(deform)} remap v
run             {ramp_steps}
unfix           def
""" + relax)


def _run_probe(pdir, prm, mode, amp, ramp_steps, relax):
    name = f"p{mode}{'+' if amp > 0 else '-'}{abs(amp):.0e}"
    log = pdir / f"log.{name}"
    if not log.exists() or "tail" not in _parse(log) or not (pdir / f"slide.{name}.dump").exists():
        (pdir / f"in.{name}").write_text(_probe_deck(prm, mode, amp, ramp_steps, relax) + f"""\
compute         ps all pair/local force p1 p2 p3
dump            ds all local 1 slide.{name}.dump c_ps[1] c_ps[2] c_ps[3] c_ps[4]
dump_modify     ds format float %.17g first yes
run             0
""")
        run_lammps(pdir, input_name=f"in.{name}", extra_args=())
        os.replace(pdir / "log.lammps", log)
    return _parse(log), log, _sliding(pdir / f"slide.{name}.dump", float(prm["mu"]))


def _sliding(path, mu) -> int:
    """Contacts at the Coulomb limit |f_t| >= mu f_n (1 - 1e-9) in a probe's final state (0 when
    mu = 0: every contact is frictionless there)."""
    if mu == 0:
        return 0
    _, arr = read_dump_local(path)
    fn, ft = arr[:, 0], np.linalg.norm(arr[:, 1:4], axis=1)
    return int(np.sum((fn > 0) & (ft >= mu * fn * (1 - 1e-9))))


def _loops(log):
    """(steps, seconds) of a LAMMPS log's ``Loop time of T on P procs for S steps`` lines."""
    found = re.findall(r"Loop time of (\S+) on \d+ procs for (\d+) steps with", Path(log).read_text())
    return sum(int(n) for _, n in found), sum(float(t) for t, _ in found)


def lammps_probes(folder, prm, base_log, *, amplitudes=(1e-6, 1e-5), ramp_steps=200, tol=1e-13,
                  max_steps=200_000, check_every=100, tail_steps=500, progress=None) -> ProbesResult:
    """Run the 12 probes per amplitude from ``folder/probes/base/base.restart`` (made by
    :func:`relax_base`) and build the (6, 6) Cauchy stiffness [Pa]; see the module docstring.
    Probes already run (their logs) are reused."""
    checks = (("amplitudes", amplitudes, "one or more values in (0, 1e-2)",
               len(amplitudes) >= 1 and all(0 < a < 1e-2 for a in amplitudes)),
              ("ramp_steps", ramp_steps, "an integer >= 1", int(ramp_steps) == ramp_steps >= 1),
              ("tol", tol, "in (0, 1)", 0 < tol < 1))
    for name, val, allowed, ok in checks:
        if not ok:
            raise ValueError(f"{name} must be {allowed}, got {val!r}")
    pdir = Path(folder) / "probes"
    relax = _relax_lines(prm, tol, max_steps, check_every, tail_steps)
    s0 = _stress(base_log["relaxed"])
    n0 = base_log["relaxed"]["contacts"]
    t0 = time.perf_counter()
    Cs, asym, resid, unb, events, steps, sliding, lammps_time = {}, 0.0, 0.0, 0.0, 0, 0, {}, 0.0
    amps = tuple(sorted(float(a) for a in amplitudes))
    for a in amps:
        C = np.empty((6, 6))
        second = np.empty(6)
        res_a = np.empty(6)
        for m in range(6):
            rec = {}
            for sgn in (1, -1):
                r, log, n_slide = _run_probe(pdir, prm, m, sgn * a, ramp_steps, relax)
                sliding[a] = max(sliding.get(a, 0), n_slide)
                rec[sgn] = r
                n_steps, secs = _loops(log)
                steps += n_steps
                lammps_time += secs
                unb = max(unb, r["relaxed"]["unbalanced"])
                events = max(events, int(abs(r["relaxed"]["contacts"] - n0)))
                res_a[m] = max(res_a[m] if sgn == -1 else 0.0, np.abs(strain_to_mandel(
                    _stress(r["tail"]) - _stress(r["relaxed"]))).max() / a)
            sp, sm = _stress(rec[1]["relaxed"]), _stress(rec[-1]["relaxed"])
            E = mandel_to_strain(np.eye(6)[m])
            W = np.triu(E) + np.triu(E, 1) - E             # the rigid rotation per unit amplitude
            C[:, m] = strain_to_mandel((sp - sm) / (2 * a) - (W @ s0 - s0 @ W))
            second[m] = np.abs(strain_to_mandel(sp + sm - 2 * s0)).max() / (2 * a)
            if progress:
                progress(f"  amplitude {a:g}, mode {m}: done")
        Cs[a] = C
        scale = np.abs(C).max()
        if a == amps[0]:
            asym = float(second.max() / scale)
        resid = max(resid, float(res_a.max() / scale))
    C = Cs[amps[0]]
    K, G = isotropic_moduli(C)
    return ProbesResult(C_mandel=C, C_by_amplitude=Cs, K=K, G=G, amplitudes=amps, stress0=s0,
                        asymmetry=asym, residual=resid, unbalanced=unb, contact_events=events,
                        sliding_by_amplitude=sliding, steps=steps, lammps_time=lammps_time,
                        wall_time=time.perf_counter() - t0)


def _upper(M):
    """The symmetric matrix of the upper triangle of M (LAMMPS's six pressure components)."""
    return np.triu(M) + np.triu(M, 1).T


def probe_tangent(net, min_contacts=None, *, rotation=True, upper=True) -> np.ndarray:
    """(6, 6) [Pa]: what the probes measure, computed exactly from the network -- the relaxed
    first-order response under LAMMPS's history law (``microhom.kinematics``, pre-stress, radius
    arm) to the probes' displacement gradients ``L_b = triu(E_b) + triu(E_b, 1)`` (strain plus
    rotation ``W_b``), of the symmetric stress built from the upper triangle of
    ``-P = -(1/V) sum c f^T``, with ``W_b sigma0 - sigma0 W_b`` removed as the probes do. Differs
    from the Cauchy tensor of ``stiffness`` by the response to ``W_b`` beyond the rotation of the
    stress (LAMMPS's history does not follow a turn about the normal, and the radius arm slips by
    overlap x turn) and by the upper-triangle reading of the non-symmetric ``P``. ``rotation=False``
    applies the strains alone (``L_b = E_b``), ``upper=False`` reads ``sym(P)``: the two parts of
    that difference apart."""
    from dataclasses import replace

    from dem.analysis.stiffness import reduce_system, relax_tangential
    from microhom.kinematics import assemble, contact_forces

    asm = assemble(net, prestress=True, min_contacts=min_contacts, spin_arm="radius")
    n = asm.net
    c, f, V = n.branch, contact_forces(n), n.volume
    Pi0 = c.T @ f
    part = _upper if upper else (lambda M: 0.5 * (M + M.T))
    s0 = -part(Pi0) / V
    A = (asm.Kgs + asm.Gts) if asm.Gts is not None else asm.Kgs
    Hs = asm.H if asm.Hn is None else (asm.H + 0.5 * (asm.Hn + asm.Hn.T)).tocsc()
    asm_t = asm if asm.Hn is not None else replace(asm, Hn=asm.H * 0.0)
    C = np.empty((6, 6))
    for b in range(6):
        E = mandel_to_strain(np.eye(6)[b])
        L = np.triu(E) + np.triu(E, 1) if rotation else E
        DL = (c @ L.T).ravel()
        FL = asm.Bs.T @ (asm.Ks @ DL) + asm.Bcs.T @ (asm.Kgs @ DL)
        if asm.Ns is not None:
            FL = FL + asm.Ns @ DL
        red = reduce_system(replace(asm, H=Hs, F=np.asarray(FL)[:, None]))
        X, _, _ = relax_tangential(asm_t, red, asm.F_scale)
        q = np.zeros(asm.ndof)
        q[red.idx] = X[:, 0]
        delta, dc = asm.Bs @ q + DL, asm.Bcs @ q + DL
        fdot = -(asm.Ks @ delta + A @ dc).reshape(-1, 3)
        Pidot = dc.reshape(-1, 3).T @ f + c.T @ fdot
        sdot = -part(Pidot - np.trace(L) * Pi0) / V
        W = L - E
        C[:, b] = strain_to_mandel(sdot - (W @ s0 - s0 @ W))
    return C


def compare(base_run, probes: ProbesResult, min_contacts=None) -> ProbeComparison:
    """The exact tensor of the base state's network (``prestress=True``, ``spin_arm="radius"``,
    the rattler threshold ``min_contacts``: None is the solver's rule, 2 keeps the frictional
    spheres with two contacts, which carry stiffness in LAMMPS) against LAMMPS's probes."""
    from dem.analysis.stiffness import stiffness
    from microhom.tensors import prestress_correction

    net = base_run.network
    t0 = time.perf_counter()
    with warnings.catch_warnings():      # the 2-contact spheres' rolling modes: "unstable" flags
        warnings.simplefilter("ignore")
        ex = stiffness(net, prestress=True, spin_arm="radius", min_contacts=min_contacts)
    t_ex = time.perf_counter() - t0
    Ce = ex.C_mandel
    scale = np.abs(Ce).max()
    diff = {a: float(np.abs(C - Ce).max() / scale) for a, C in probes.C_by_amplitude.items()}
    amps = probes.amplitudes
    V = abs(np.linalg.det(net.cell))
    Kp, Gp = isotropic_moduli(probes.C_mandel)
    Cl = probe_tangent(net, min_contacts)
    diff_l = {a: float(np.abs(C - Cl).max() / scale) for a, C in probes.C_by_amplitude.items()}
    tscale = float(np.sum(np.linalg.norm(net.ft, axis=1) * net.lengths) / V / scale)
    return ProbeComparison(
        C_exact=Ce, C_probes=probes.C_mandel, difference=diff[amps[0]], difference_by_amplitude=diff,
        amplitude_spread=float(np.abs(probes.C_by_amplitude[amps[-1]] - probes.C_by_amplitude[amps[0]]).max()
                               / scale),
        K_exact=float(ex.K), G_exact=float(ex.G), K_probes=Kp, G_probes=Gp,
        prestress_size=float(np.abs(prestress_correction(probes.stress0)).max() / scale),
        tangential_scale=tscale, spin_arm="radius", min_contacts=min_contacts, C_lammps=Cl,
        difference_lammps=diff_l[amps[0]], difference_lammps_by_amplitude=diff_l,
        rotation_size=float(np.abs(Cl - Ce).max() / scale), n_unstable=int(ex.n_unstable),
        n_contacts=int(net.n_contacts),
        n_rattlers=int(ex.n_rattlers), n_sliding=int(np.sum(net.sliding)), exact_time=t_ex)


def _matrix(C) -> str:
    return "\n".join("    " + " ".join(f"{v:+.6e}" for v in row) for row in C)


def report(probes: ProbesResult, cmp: ProbeComparison) -> str:
    """The figures of one packing as printed text."""
    amps = probes.amplitudes
    a0 = amps[0]
    lines = [f"exact tensor (prestress, spin arm {cmp.spin_arm}) [Pa]:", _matrix(cmp.C_exact),
             f"LAMMPS probes at amplitude {a0:g} minus exact [Pa]:", _matrix(cmp.C_probes - cmp.C_exact),
             "difference max|C_probes - C_exact| / max|C_exact| per amplitude: "
             + ", ".join(f"{a:g}: {cmp.difference_by_amplitude[a]:.2e}" for a in amps),
             "difference from the exact probe tangent (LAMMPS's law under E + W, upper triangle of P) "
             "per amplitude: " + ", ".join(f"{a:g}: {cmp.difference_lammps_by_amplitude[a]:.2e}" for a in amps)
             + f"; probe tangent minus Cauchy tensor {cmp.rotation_size:.2e}"]
    for a, b in zip(amps[:-1], amps[1:]):
        d = np.abs(probes.C_by_amplitude[b] - probes.C_by_amplitude[a]).max() / np.abs(cmp.C_exact).max()
        lines.append(f"probes' amplitude spread {a:g} -> {b:g}: {d:.2e}")
    lines += [f"+/- asymmetry at {a0:g} (second-order term): {probes.asymmetry:.2e}; relaxation "
              f"residual: {probes.residual:.2e}; largest unbalanced force ratio {probes.unbalanced:.1e}; "
              f"contact events {probes.contact_events}; contacts at the Coulomb limit after a probe: "
              + ", ".join(f"{a:g}: {v}" for a, v in probes.sliding_by_amplitude.items()),
              f"pre-stress terms' size {cmp.prestress_size:.2e}; tangential-force stress scale "
              f"{cmp.tangential_scale:.2e} (both over max|C_exact|)",
              f"K: exact {cmp.K_exact:.8g}, probes {cmp.K_probes:.8g} (rel {cmp.K_probes / cmp.K_exact - 1:+.1e}); "
              f"G: exact {cmp.G_exact:.8g}, probes {cmp.G_probes:.8g} (rel {cmp.G_probes / cmp.G_exact - 1:+.1e})",
              f"network: {cmp.n_contacts} contacts, {cmp.n_rattlers} rattlers, {cmp.n_sliding} sliding; "
              f"probes {probes.steps} LAMMPS steps, LAMMPS loop time {probes.lammps_time:.1f} s, exact solve "
              f"{cmp.exact_time:.2f} s"]
    return "\n".join(lines)


def main(argv=None):
    """``python -m studies.lammps_probes3d``: per packing (one per pressure and friction), the
    probes at every amplitude, the comparison printed and written under ``--out``."""
    from studies.common import add_out, cli_out_dir, report_to

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1000, help="spheres (default 1000)")
    ap.add_argument("--p-over-kn", type=float, nargs="+", default=[1e-3], help="p D / kn of the packings")
    ap.add_argument("--mu", type=float, nargs="+", default=[0.0, 0.5],
                    help="test frictions (prepared at min(mu, 0.05), then mu)")
    ap.add_argument("--amplitudes", type=float, nargs="+", default=[1e-7, 1e-6, 1e-5])
    ap.add_argument("--seed", type=int, default=1)
    add_out(ap, "lammps_probes3d")
    a = ap.parse_args(argv)
    out = cli_out_dir(a.out, cache=False)
    report_to(out)
    if not lammps_available():
        print("lmp (LAMMPS) not on PATH: nothing to compare (Debian: apt-get install -y lammps)")
        return 1
    rows = []
    for pk in a.p_over_kn:
        for mu in a.mu:
            proto = PackingProtocol(n=a.n, p_over_kn=pk, kn=1.0, mu=mu, mu_prep=min(mu, 0.05),
                                    dispersity=0.2, seed=a.seed)
            folder = out / f"n{a.n}_p{pk:g}_mu{mu:g}_s{a.seed}"
            run, prm, wall = pack_with_restart(proto, folder, max_steps=2_000_000)
            print(f"\n== N = {a.n}, pD/kn = {pk:g}, mu = {mu:g} (mu_prep {min(mu, 0.05):g}): packing "
                  f"{wall:.1f} s, Z = {run.lammps['Z']:.4f}, phi = {run.lammps['phi']:.4f}", flush=True)
            base, blog = relax_base(folder, prm)
            pr = lammps_probes(folder, prm, blog, amplitudes=a.amplitudes)
            cmp = compare(base, pr)
            print(report(pr, cmp), flush=True)
            rows.append(dict(N=a.n, p_over_kn=pk, mu=mu, difference=cmp.difference,
                             difference_lammps=cmp.difference_lammps, rotation_size=cmp.rotation_size,
                             **{f"difference_{k:g}": v for k, v in cmp.difference_by_amplitude.items()},
                             asymmetry=pr.asymmetry, residual=pr.residual,
                             prestress_size=cmp.prestress_size, tangential_scale=cmp.tangential_scale,
                             K_exact=cmp.K_exact, K_probes=cmp.K_probes, G_exact=cmp.G_exact,
                             G_probes=cmp.G_probes, probes_s=pr.lammps_time, exact_s=cmp.exact_time))
            (folder / "probes" / "comparison.json").write_text(json.dumps(
                {"probes": pr.as_dict(), "comparison": cmp.as_dict()}))
    import pandas as pd
    from studies.common import write_table
    write_table(pd.DataFrame(rows), out, "probes", "LAMMPS's strain probes against the exact tensor")
    return 0


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
