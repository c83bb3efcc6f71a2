"""Dense random packings of disks in a periodic cell: random gas, isotropic servo compression to a
target pressure, preparation friction then test friction.

Units: any consistent set; 2D quantities per unit thickness. The pressure is a force per length,
``p = -tr(sigma)/2`` (compression positive) with the Love-Weber stress
``sigma = -(1/A) sum_c F_c (x) l_c`` (tension positive). Give the target either as ``p_over_kn``
(dimensionless, p/kn) or as ``pressure`` [N/m] together with ``kn`` [N/m].

Protocol (default, :func:`pack`):

1. *Random gas*: N disk centres uniform in a square periodic cell at solid fraction ``phi0``
   (overlaps allowed; they are pushed apart by the contact law and the local damping in the first
   steps), drawn from ``numpy.random.default_rng(seed)``; radii identical, or uniform in
   ``r (1 +- dispersity)``.
2. *Fast isotropic compression* with :class:`dem.cell.PressureServo`: the cell shrinks at
   ``max_strain_per_step`` (default 2e-4 per step) while there is no load, then the
   stiffness-adaptive servo brings the pressure to the target. The fast start from a gas is the
   choice made against crystallisation of identical disks (2D monodisperse disks order easily
   when compressed slowly; an optional ``growth_dispersity`` spreads the radii during this first
   compression only and restores them once the target pressure is reached); the hexatic order ``psi6 = |mean_i (1/n_i) sum_j exp(6 i theta_ij)|``
   (Delaunay neighbours) is reported for every packing. Measured (N = 500-2000, p/kn = 1e-4):
   with friction (mu_prep = 0.5) psi6 ~ 0.01-0.13, mean local |psi6_i| ~ 0.56-0.68 (amorphous);
   frictionless identical disks still come out polycrystalline (psi6 ~ 0.15-0.23, local ~ 0.85)
   because they creep and order at constant pressure after the fast compression, with or
   without the growth dispersity: use ``dispersity`` > 0 for amorphous frictionless packings. Friction ``mu_prep`` during this phase
   is the knob for the coordination number (``mu_prep = 0``: densest, highest Z).
3. *Equilibrium* at ``mu_prep``: stop when all three criteria hold (checked every ``check_every``
   steps):

   - ``|p - p_target| / p_target < tol_p`` (default 1e-3);
   - unbalanced force ratio < ``tol_unbalanced`` (default 1e-5), Yade's definition: the mean over
     all particles of the magnitude of the resultant contact force, divided by the mean contact
     force magnitude; the max-based variant (``max_i |F_i|`` over the same mean) is reported too;
   - kinetic energy (translation + rotation, fluctuations) < ``tol_ke`` times the elastic energy
     stored in the contacts (default 1e-8).
4. If ``mu != mu_prep``, switch to the test friction ``mu`` and repeat 3.

Same seed, same parameters -> bit-identical packing (serial kernels, fixed summation order).
:class:`PackingResult` carries the final :class:`dem.state.State` (a checkpoint: ``save``/``load``),
the report and :meth:`PackingResult.to_network` (a :class:`microhom.network.ContactNetwork`).
``pack(..., checkpoint=path)`` writes atomic checkpoints every ``checkpoint_every`` steps and
resumes from ``path`` if it exists (bit-exact continuation).
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from .cell import PressureServo
from .contact_laws import Frictionless, LinearFriction, law_from_meta
from .integrate import Simulation
from .state import State

__all__ = ["pack", "random_gas", "PackingResult", "network_from_state", "hexatic_psi6"]


def random_gas(n, *, radius=0.5, dispersity=0.0, phi0=0.2, rho=None, seed=0, spins=True) -> State:
    """N disks at random (seeded) positions in a square periodic cell at solid fraction phi0.

    radius [m]: mean radius; dispersity: radii uniform in radius*(1 +- dispersity), in [0, 0.5);
    rho [kg/m^2]: areal density (default: a disk of the mean radius has unit mass).
    """
    if int(n) != n or n < 2:
        raise ValueError(f"n must be an integer >= 2, got {n}")
    if not (0 < phi0 < 0.9):
        raise ValueError(f"phi0 must be in (0, 0.9), got {phi0}")
    if not (0 <= dispersity < 0.5):
        raise ValueError(f"dispersity must be in [0, 0.5), got {dispersity}")
    if not (radius > 0):
        raise ValueError(f"radius must be > 0, got {radius}")
    n = int(n)
    rng = np.random.default_rng(seed)
    r = np.full(n, float(radius))
    if dispersity > 0:
        r = radius * (1.0 + dispersity * rng.uniform(-1.0, 1.0, n))
    Lbox = math.sqrt(np.pi * np.sum(r ** 2) / phi0)
    x = rng.uniform(0.0, Lbox, (n, 2))
    rho = 1.0 / (np.pi * radius ** 2) if rho is None else rho
    return State.from_disks(x, r, np.diag([Lbox, Lbox]), rho=rho, spins=spins)


def _contacts(state, law):
    """Current contacts (overlap > 0) of the Verlet list: i, j, branch, delta, index into the list."""
    i, j, s = state.nl_i, state.nl_j, state.nl_shift
    br = state.x[j] + s @ state.h.T - state.x[i]
    d = np.hypot(br[:, 0], br[:, 1])
    delta = state.radius[i] + state.radius[j] - d
    k = np.nonzero(delta > 0)[0]
    return i[k], j[k], br[k], delta[k], k


def _contact_kinetic_energy(state, law):
    """Kinetic energy (translation + rotation) of the particles with at least one contact: free
    rattlers carry no force, so local damping cannot stop them; they are excluded from the
    kinetic-energy criterion (their total is reported separately)."""
    i, j, _, _, _ = _contacts(state, law)
    has = np.zeros(state.n, bool)
    has[i] = True
    has[j] = True
    ke = 0.5 * float(np.sum(state.mass[has, None] * state.v[has] ** 2))
    if state.omega is not None:
        ke += 0.5 * float(np.sum(state.inertia[has] * state.omega[has] ** 2))
    return ke


def network_from_state(state, law):
    """ContactNetwork of the contacts of ``state`` (read-only): particles in original-label order
    (``state.ids``), positions wrapped into the cell, branch ``x_j - x_i`` (image resolved), elastic
    ``fn`` (compression positive), ``ft`` (history, force on j along t, clipped to the Coulomb
    limit of the current ``fn``), tangent ``kn``, ``kt``,
    ``sliding = |ft| >= mu fn (1 - 1e-9)``."""
    from microhom.network import ContactNetwork
    from .cell import wrap

    if state.nl_i is None:
        raise ValueError("the state has no neighbour list yet (run at least one step)")
    i, j, br, delta, k = _contacts(state, law)
    fn = law.fn_elastic(delta)
    ft = np.zeros_like(fn) if state.nl_ft is None else state.nl_ft[k].copy()
    # the history was capped with fn of the last force evaluation, one drift before these positions:
    # project it on the current Coulomb disc (read-only; the state keeps its history)
    ft = np.clip(ft, -law.mu * fn, law.mu * fn)
    kn, kt = law.tangent(delta)
    sliding = np.abs(ft) >= law.mu * fn * (1 - 1e-9)
    perm = np.argsort(state.ids, kind="stable")
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    a, b = inv[i], inv[j]
    swap = a > b
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    br = np.where(swap[:, None], -br, br)  # ft is invariant under the swap (2D scalar along t)
    order = np.lexsort((b, a))
    xw, _ = wrap(state.x[perm], state.h)
    return ContactNetwork(positions=xw, radii=state.radius[perm], cell=state.h.copy(),
                          pairs=np.stack([a, b], 1)[order], branch=br[order], kn=kn[order],
                          kt=kt[order], sliding=sliding[order], fn=fn[order], ft=ft[order])


def hexatic_psi6(net) -> dict:
    """psi6 (global |mean|) and mean local |psi6_i| over periodic Delaunay neighbours."""
    from .measure import hexatic_order
    return hexatic_order(net)


@dataclass
class PackingResult:
    """Final state of a packing run with its law and report (see :func:`pack`)."""
    state: State
    law: object
    report: dict = field(default_factory=dict)

    def to_network(self):
        """The :class:`microhom.network.ContactNetwork` of the packing (forces included)."""
        return network_from_state(self.state, self.law)

    def save(self, path):
        self.state.meta["packing_report"] = {k: v for k, v in self.report.items()
                                             if isinstance(v, (int, float, str, bool)) or v is None}
        self.state.meta["packing_law"] = self.law.to_meta()
        self.state.save(path)

    @classmethod
    def load(cls, path):
        st = State.load(path)
        return cls(st, law_from_meta(st.meta["packing_law"]), dict(st.meta.get("packing_report", {})))


def _make_law(kn, kt, mu, restitution):
    if kt == 0 or mu is None:
        return Frictionless(kn=kn, restitution=restitution)
    return LinearFriction(kn=kn, kt=kt, mu=mu, restitution=restitution)


def pack(n, *, p_over_kn=1e-4, pressure=None, kn=1.0, kt=None, mu=0.5, mu_prep=None, radius=0.5,
         dispersity=0.0, rho=None, seed=0, phi0=0.2, damping=0.7, restitution=None,
         max_strain_per_step=2e-4, alpha=0.5, tol_p=1e-3, tol_unbalanced=1e-5, tol_ke=1e-8,
         max_steps=2_000_000, check_every=100, checkpoint=None, checkpoint_every=20000,
         verbose=False, frictionless=None, growth_dispersity=0.0, restore_increments=50) -> PackingResult:
    """Dense random packing of ``n`` disks at a target pressure (protocol in the module docstring).

    Parameters (units consistent; 2D per unit thickness)
    ----------
    n : number of disks.  p_over_kn : target p/kn (used if ``pressure`` is None).
    pressure : target pressure [N/m] (force per length, compression positive).
    kn, kt : contact stiffnesses [N/m]; ``kt=None`` -> kt = kn.  mu : test friction;
    mu_prep : preparation friction (default: mu).  frictionless : force the specialised
        frictionless law (no spins, no history); default True when mu == mu_prep == 0.
    radius [m], dispersity, rho [kg/m^2], seed, phi0 : see :func:`random_gas`.
    damping : Cundall local damping.  restitution : optional viscous contact damping.
    max_strain_per_step : cap on the isotropic strain per step of the servo.
    alpha : servo gain (fraction of the pressure error corrected per step, affine stiffness).
    tol_p, tol_unbalanced, tol_ke : stop criteria.  max_steps : cap on the total step count
        (the result then has ``report['converged'] = False``).
    growth_dispersity : relative radius spread used only during the first compression (radii
        ``r_i (1 + g u_i)``, ``u_i`` uniform in [-1, 1], masses of the final disks), removed in
        ``restore_increments`` steps of ``check_every`` steps once the target pressure is first
        reached (within 5 %); 0 disables it.
    checkpoint : path of an npz checkpoint (written atomically every ``checkpoint_every`` steps;
        resumed from if it exists).
    """
    t_start = time.perf_counter()
    kt = kn if kt is None else kt
    mu_prep = mu if mu_prep is None else mu_prep
    p_target = float(pressure) if pressure is not None else float(p_over_kn) * kn
    if not (p_target > 0 and np.isfinite(p_target)):
        raise ValueError(f"target pressure must be > 0, got {p_target} (p_over_kn={p_over_kn}, "
                         f"pressure={pressure})")
    for name, val in (("mu", mu), ("mu_prep", mu_prep)):
        if not (val >= 0):
            raise ValueError(f"{name} must be >= 0, got {val}")
    if frictionless is None:
        frictionless = mu == 0 and mu_prep == 0
    law_prep = Frictionless(kn=kn, restitution=restitution) if frictionless else \
        LinearFriction(kn=kn, kt=kt, mu=mu_prep, restitution=restitution)
    law_test = law_prep if frictionless else law_prep.with_friction(mu)

    resumed = checkpoint is not None and os.path.exists(os.fspath(checkpoint))
    if resumed:
        st0 = State.load(checkpoint)
        pk = st0.meta["packing"]
        phase = pk["phase"]
        ctl = PressureServo(**{k: v for k, v in st0.meta["sim"]["control"].items() if k != "kind"})
        sim = Simulation.load(checkpoint, control=ctl)
        history = pk.get("history", [])
    else:
        st = random_gas(n, radius=radius, dispersity=dispersity, phi0=phi0, rho=rho, seed=seed,
                        spins=not frictionless)
        if not (0 <= growth_dispersity < 0.5):
            raise ValueError(f"growth_dispersity must be in [0, 0.5), got {growth_dispersity}")
        if growth_dispersity > 0:
            u = np.random.default_rng([seed, 1]).uniform(-1.0, 1.0, st.n)
            st.meta["growth"] = {"r0": st.radius.tolist(), "u": u.tolist(), "g": growth_dispersity, "s": 1.0}
            st.radius = st.radius * (1.0 + growth_dispersity * u)
        sim = Simulation(st, law_prep, damping=damping, check_every=0)
        ctl = PressureServo(p_target=p_target, max_rate=max_strain_per_step / sim.dt, alpha=alpha)
        sim.control = ctl
        phase = "grow" if growth_dispersity > 0 else "prep"
        history = []
    sim.check_every = 0  # guard is done in the callback below (every check_every steps)
    state = sim.state

    last = {}

    def converged(m):
        e_p = abs(m["pressure"] - p_target) / p_target
        ke = _contact_kinetic_energy(state, sim.law)
        ke_rel = ke / m["elastic_energy"] if m["elastic_energy"] > 0 else float("inf")
        last.update(m, rel_p_err=e_p, ke_rel=ke_rel, kinetic_energy_in_contact=ke)
        return e_p < tol_p and m["unbalanced"] < tol_unbalanced and ke_rel < tol_ke

    def callback(s):
        nonlocal phase
        s._guard()
        m = s.measure()
        if verbose and state.step % (10 * check_every) == 0:
            print(f"[pack] step {state.step} phase {phase} phi {state.solid_fraction:.4f} "
                  f"p/p0 {m['pressure'] / p_target:.5f} unb {m['unbalanced']:.3g} "
                  f"Z {2 * m['n_contacts'] / state.n:.3f}", flush=True)
        if phase == "grow":
            if abs(m["pressure"] - p_target) < 0.05 * p_target:
                history.append({"phase": phase, "step": int(state.step)})
                phase = "restore"
        elif phase == "restore":
            gr = state.meta["growth"]
            gr["s"] = max(0.0, gr["s"] - 1.0 / restore_increments)
            r0, u = np.asarray(gr["r0"]), np.asarray(gr["u"])
            state.radius = r0 * (1.0 + gr["g"] * gr["s"] * u)
            s.need_rebuild = True
            if gr["s"] == 0.0:
                state.radius = r0.copy()
                history.append({"phase": phase, "step": int(state.step)})
                phase = "prep"
        elif converged(m):
            history.append({"phase": phase, "step": int(state.step)})
            if phase == "prep" and law_test is not law_prep and mu != mu_prep:
                s.set_law(law_test)
                phase = "test"
            else:
                phase = "done"
                return True
        if checkpoint is not None and state.step % checkpoint_every == 0:
            state.meta["packing"] = {"phase": phase, "history": history}
            s.save(checkpoint)
        return False

    if resumed and phase == "test":
        sim.set_law(law_test)
    if phase != "done":
        remaining = max_steps - state.step
        if remaining > 0:
            sim.run(remaining, callback=callback, every=check_every)
    if not last or "rel_p_err" not in last:
        converged(sim.measure())
    net = network_from_state(state, sim.law)
    try:
        hx = hexatic_psi6(net)
    except Exception as exc:  # pragma: no cover - psi6 is informative only
        hx = {"psi6": float("nan"), "psi6_local": float("nan"), "psi6_error": str(exc)}
    nc = net.n_contacts
    report = {
        "n": state.n, "seed": seed, "converged": phase == "done", "steps": int(state.step),
        "phase_steps": history, "wall_s": time.perf_counter() - t_start, "resumed": resumed,
        "p_target": p_target, "pressure": last["pressure"], "rel_p_err": last["rel_p_err"],
        "p_over_kn": last["pressure"] / kn, "unbalanced": last["unbalanced"],
        "unbalanced_max": last["unbalanced_max"], "ke_rel": last["ke_rel"],
        "kinetic_energy": last["kinetic_energy"],
        "kinetic_energy_in_contact": last["kinetic_energy_in_contact"], "elastic_energy": last["elastic_energy"],
        "phi": state.solid_fraction, "n_contacts": nc, "Z": 2.0 * nc / state.n,
        "sliding_fraction": float(net.sliding.mean()) if nc and not frictionless else float("nan"),
        "dt": sim.dt, "dt_over_dtcrit": sim.dt / sim.dt_crit, "mu": mu, "mu_prep": mu_prep,
        "kn": kn, "kt": 0.0 if frictionless else kt, "tol_p": tol_p, "tol_unbalanced": tol_unbalanced,
        "tol_ke": tol_ke, "damping_work": sim.damping_work, **hx,
        "timing": sim.timing_report()["table"],
        "particle_steps_per_s": sim.timing_report()["particle_steps_per_s"],
    }
    res = PackingResult(state, sim.law, report)
    if checkpoint is not None:
        state.meta["packing"] = {"phase": phase, "history": history}
        sim.save(checkpoint)
    return res
