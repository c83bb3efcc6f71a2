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
   ``r (1 +- dispersity)``. ``gas_overlaps=False`` starts instead from a cold gas without
   overlaps (random sequential addition).
2. *Compaction* (phase ``compact``) with :class:`dem.cell.PressureServo`: the cell shrinks at
   ``max_strain_per_step`` (default 2e-4 per step) while there is no load, then the
   stiffness-adaptive servo holds the pressure at the target while the assembly, still below
   jamming, flows into a jammed state. This phase runs with a *light* local damping
   ``damping_compaction`` (default 0.05) and ends when the packing has jammed: ``|p - p_target| <
   1e-2 p_target`` and unbalanced force ratio < ``jam_unbalanced`` (default 1e-3). The damping then
   returns to ``damping`` (default 0.7) for the equilibrium phases.

   Why: at the target pressure the unjammed assembly compacts like a dense granular flow whose
   rate scales as ``sqrt(p / rho) / d`` times a factor set by the dissipation; with ``damping =
   0.7`` all the way, 90 % of the steps of a 1e4-disk packing at p/kn = 1e-4 were spent creeping
   from phi ~ 0.76 to jamming at phi ~ 0.79 with the pressure already on target (350 900 steps);
   with a light compaction damping the same packing jams in a few 1e4 steps (numbers in
   ``docs/dem.md``). ``damping_compaction=None`` restores the single-damping protocol.

   The time step is ``dt_over_dtcrit`` (default 1) times :func:`dem.integrate.critical_dt`,
   which is itself at least sqrt(2) below the leapfrog limit of the stiffest possible contacts.

   The fast start from a gas is the choice made against crystallisation of identical disks (2D
   monodisperse disks order easily when compressed slowly; an optional ``growth_dispersity``
   spreads the radii during this first compression only and restores them once the target
   pressure is reached); the hexatic order ``psi6 = |mean_i (1/n_i) sum_j exp(6 i theta_ij)|``
   (Delaunay neighbours) is reported for every packing. Frictional preparation comes out
   amorphous or weakly ordered (psi6 ~ 0.02-0.1 for N = 1e4; 0.02-0.53 for N = 1000,
   mu_prep = 0.02-0.1, over seeds); frictionless identical disks order (psi6 up to ~0.97): use
   ``dispersity`` > 0 for amorphous frictionless packings. Friction ``mu_prep`` during this phase
   is the knob for the coordination number (``mu_prep = 0``: densest, highest Z).
   With ``fire=True`` (default), once the solid fraction has stopped changing (relative change
   below 3e-7 at five checks in a row) the FIRE velocity mixing of :mod:`dem.fire` runs too,
   until the phase ends or the packing moves again.
3. *Equilibrium* at ``mu_prep`` (phase ``prep``), with the local damping ``damping`` and, with
   ``fire=True`` (default), the FIRE velocity mixing of :mod:`dem.fire` after every step (it
   quenches the velocities whenever the power ``F . v`` turns negative: the ringing of the
   lightly damped compaction is stopped in a few hundred steps instead of several thousand).
   Stop when all three criteria hold (checked every ``check_every`` steps, at absolute step
   numbers that are multiples of ``check_every``):

   - ``|p - p_target| / p_target < tol_p`` (default 1e-3);
   - unbalanced force ratio < ``tol_unbalanced`` (default 1e-5), Yade's definition: the mean over
     all particles of the magnitude of the resultant contact force, divided by the mean contact
     force magnitude; the max-based variant (``max_i |F_i|`` over the same mean) is reported too;
   - kinetic energy (translation + rotation, fluctuations) of the particles in contact <
     ``tol_ke`` times the elastic energy stored in the contacts (default 1e-8). This one costs a
     pass over the neighbour list, so it is evaluated only when the two others hold (and every
     tenth check for the progress report).
4. If ``mu != mu_prep``, switch to the test friction ``mu`` (phase ``test``) and repeat 3.

The protocol before issue 12.3 is ``damping_compaction=0.1, dt_over_dtcrit=0.8, fire=False``
(bit-identical to it). Same seed, same parameters -> bit-identical packing (serial kernels,
fixed summation order).
:class:`PackingResult` carries the final :class:`dem.state.State` (a checkpoint: ``save``/``load``),
the report and :meth:`PackingResult.to_network` (a :class:`microhom.network.ContactNetwork`).
:meth:`PackingResult.save` writes one npz that is both a checkpoint (``PackingResult.load``)
and a ``dem.io`` configuration (:func:`dem.io.read`).
The phases are objects (:class:`Grow`, :class:`Compact`, :class:`Equilibrate`), each with its own
parameters and stop criterion; :func:`pack` runs them in order and reports them in
:class:`PackReport` (``phase_steps``).
``pack(..., checkpoint=path)`` writes atomic checkpoints every ``checkpoint_every`` steps and/or
every ``checkpoint_seconds`` of wall time (only at check points, after the instability guard
passed, so a checkpoint is always a good state) and resumes from ``path`` if it exists: the
continuation is bit-exact whatever the checkpoint times were.
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field, fields

import numpy as np
from numba import njit

from microhom.network import ContactNetwork
from microhom.results import Result

from .cell import PressureServo, wrap
from .contact_laws import Frictionless, LinearFriction, law_from_meta
from .fire import Fire
from .integrate import InstabilityError, Simulation, critical_dt
from .measure import hexatic_order
from .runtime import atomic_write, remove_stale_temporaries
from .state import State

__all__ = ["pack", "random_gas", "PackingResult", "PackReport", "network_from_state", "hexatic_psi6",
           "Grow", "Compact", "Equilibrate", "BYTES_PER_PARTICLE", "check_memory"]


def random_gas(n, *, radius=0.5, dispersity=0.0, phi0=0.2, rho=None, seed=0, spins=True,
               overlaps=True) -> State:
    """N disks at random (seeded) positions in a square periodic cell at solid fraction phi0, at
    rest.

    radius [m]: mean radius; dispersity: radii uniform in radius*(1 +- dispersity), in [0, 0.5);
    rho [kg/m^2]: areal density (default: a disk of the mean radius has unit mass).
    overlaps: True: centres uniform and independent (disks may overlap); False: random sequential
    addition (uniform candidate centres, each kept if its disk overlaps none placed before;
    ``phi0`` must then be below 0.45, under the RSA jamming fraction 0.547 of disks).
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
    if overlaps:
        x = rng.uniform(0.0, Lbox, (n, 2))
    else:
        if not phi0 < 0.45:
            raise ValueError(f"phi0 must be in (0, 0.45) for a gas without overlaps, got {phi0}")
        nc = max(1, int(Lbox / (2.0 * r.max())))
        head = np.full(nc * nc, -1, dtype=np.int64)
        nxt = np.full(n, -1, dtype=np.int64)
        x = np.zeros((n, 2))
        count = 0
        while count < n:   # candidates in seeded batches until every disk is placed
            count = _rsa_place(rng.uniform(0.0, Lbox, (2 * (n - count) + 16, 2)), r, Lbox, x,
                               Lbox / nc, head, nxt, count)
    rho = 1.0 / (np.pi * radius ** 2) if rho is None else rho
    return State.from_disks(x, r, np.diag([Lbox, Lbox]), rho=rho, spins=spins)


@njit(cache=True)
def _rsa_place(cand, r, Lbox, out, cell, head, nxt, count):
    """Random sequential addition in a square periodic box of side ``Lbox`` [m]: candidate centres
    ``cand`` (M, 2) are tried in order for disk ``count`` (radius ``r[count]``) and kept when the
    disk overlaps none of those already placed (``out[:count]``), until all ``r.size`` disks are
    placed. ``head`` (nc*nc) and ``nxt`` (N) are the linked cells (side ``cell`` >= the largest
    diameter) of the placed disks, updated in place. Returns the new count."""
    nc = int(round(math.sqrt(head.shape[0])))
    n = r.shape[0]
    for k in range(cand.shape[0]):
        if count >= n:
            break
        x0 = cand[k, 0]
        y0 = cand[k, 1]
        r0 = r[count]
        cx = min(int(x0 / cell), nc - 1)
        cy = min(int(y0 / cell), nc - 1)
        ok = True
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                j = head[((cx + dx) % nc) * nc + (cy + dy) % nc]
                while j >= 0 and ok:
                    ex = out[j, 0] - x0
                    ey = out[j, 1] - y0
                    ex -= Lbox * round(ex / Lbox)
                    ey -= Lbox * round(ey / Lbox)
                    rr = r0 + r[j]
                    ok = ex * ex + ey * ey >= rr * rr
                    j = nxt[j]
        if ok:
            out[count, 0] = x0
            out[count, 1] = y0
            c = cx * nc + cy
            nxt[count] = head[c]
            head[c] = count
            count += 1
    return count


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
    """psi6 (global ``|mean|``) and mean local ``|psi6_i|`` over periodic Delaunay neighbours (dict)."""
    return hexatic_order(net).as_dict()


_CONFIG_NOTE = ("configuration view for dem.io.read: positions wrapped into the cell, in the "
                "state's (spatially sorted) order; ids = original labels, 0-based")


def _write_packing_npz(path, state):
    """Write ``state`` (a checkpoint, :meth:`State.save`) plus the ``dem.io`` npz configuration
    keys (``format``, ``positions``, ``radii``, ``cell``, ...; schema in :mod:`dem.io.simple`) into
    one npz, atomically (:func:`dem.runtime.atomic_write`)."""
    path = os.fspath(path)
    if not path.endswith(".npz"):
        path += ".npz"
    xw, _ = wrap(state.x, state.h)
    meta = {"source": "dem.packing", "note": _CONFIG_NOTE, "timestep": int(state.step)}
    meta.update({k: v for k, v in state.meta.get("packing_report", {}).items()
                 if isinstance(v, (int, float, str, bool)) or v is None})
    meta["law"] = state.meta.get("packing_law")
    arrays = state.arrays()
    # ``ids`` is already among the state's arrays (its own labels, same order as ``positions``)
    arrays.update({"format": np.array("microhom-configuration"), "format_version": np.array(1),
                   "positions": xw, "radii": state.radius, "cell": state.h,
                   "origin": np.zeros(2), "types": np.ones(state.n, dtype=np.int64),
                   "velocities": state.v, "meta_json": np.array(json.dumps(meta))})
    atomic_write(path, lambda fh: np.savez(fh, **arrays))
    return path


@dataclass(frozen=True)
class PackReport(Result):
    """What :func:`pack` reports (units consistent with the inputs; 2D per unit thickness).

    Run: ``n`` disks, ``seed``, ``converged`` (the last phase met its stop criteria),
    ``already_converged`` (resumed from a checkpoint of a finished run: nothing was computed),
    ``steps`` total time steps, ``phase_steps`` list of {phase, step at its end},
    ``compaction_steps`` step at the end of the compaction (None without one), ``wall_s`` [s],
    ``resumed``, ``particle_steps_per_s``, ``timing`` (table of the engine's sections), ``dt`` [s],
    ``dt_over_dtcrit``.
    Stop criteria (final values): ``p_target``, ``pressure`` [N/m], ``rel_p_err`` ``|p - p_t|``/p_t,
    ``p_over_kn``, ``unbalanced`` (Yade mean ratio), ``unbalanced_max``, ``ke_rel`` (kinetic
    energy of particles in contact over elastic energy), ``kinetic_energy``,
    ``kinetic_energy_in_contact``, ``elastic_energy`` [J/m], their tolerances ``tol_p``,
    ``tol_unbalanced``, ``tol_ke``.
    Packing: ``phi`` solid fraction, ``n_contacts``, ``Z`` = 2 C / N, ``sliding_fraction``
    (NaN when frictionless), ``psi6``, ``psi6_local`` (hexatic order).
    Parameters: ``mu``, ``mu_prep``, ``kn``, ``kt`` [N/m], ``damping``, ``damping_compaction``,
    ``damping_work`` [J/m].

    For the code written against the earlier dict report, ``report["key"]``, ``key in report``,
    ``report.get`` and ``report.items()`` read the fields; ``report["new_key"] = value`` adds a
    caller's annotation to ``extra`` (saved with the packing, as the dict's keys were), and
    assigning a field raises.
    """

    n: int
    seed: int
    converged: bool
    steps: int
    phase_steps: list = field(default_factory=list)
    compaction_steps: int | None = None
    wall_s: float = float("nan")
    resumed: bool = False
    p_target: float = float("nan")
    pressure: float = float("nan")
    rel_p_err: float = float("nan")
    p_over_kn: float = float("nan")
    unbalanced: float = float("nan")
    unbalanced_max: float = float("nan")
    ke_rel: float | None = None
    kinetic_energy: float = float("nan")
    kinetic_energy_in_contact: float = float("nan")
    elastic_energy: float = float("nan")
    phi: float = float("nan")
    n_contacts: int = 0
    Z: float = float("nan")
    sliding_fraction: float = float("nan")
    dt: float = float("nan")
    dt_over_dtcrit: float = float("nan")
    mu: float = float("nan")
    mu_prep: float = float("nan")
    kn: float = float("nan")
    kt: float = float("nan")
    tol_p: float = float("nan")
    tol_unbalanced: float = float("nan")
    tol_ke: float = float("nan")
    damping: float = float("nan")
    damping_compaction: float | None = None
    damping_work: float = float("nan")
    psi6: float = float("nan")
    psi6_local: float = float("nan")
    timing: str = ""
    particle_steps_per_s: float = float("nan")
    already_converged: bool = False
    #: the caller's own annotations (``report["wall_time"] = ...``): scalars that travel with the
    #: packing in its npz, as keys of the earlier dict report did
    extra: dict = field(default_factory=dict, metadata={"export": False})

    # ---- read access of the earlier dict report ------------------------------------------------
    def __getitem__(self, key):
        if key in self._names():
            return getattr(self, key)
        return self.extra[key]

    def __setitem__(self, key, value):
        if key in self._names():
            raise TypeError(f"PackReport.{key} is read-only (dataclasses.replace makes a copy); "
                            f"only new keys can be added as annotations")
        self.extra[key] = value

    def __contains__(self, key):
        return key in self._names() or key in self.extra

    def get(self, key, default=None):
        return self[key] if key in self else default

    def keys(self):
        return self._names() + list(self.extra)

    def items(self):
        return [(k, self[k]) for k in self.keys()]

    @classmethod
    def _names(cls):
        return [f.name for f in fields(cls) if f.name != "extra"]

    def scalars(self) -> dict:
        """The scalar fields (what travels in the npz meta, NaN kept; ``already_converged`` is
        a property of a resumed call, not of the packing, and stays out)."""
        return {k: v for k, v in self.items() if (isinstance(v, (int, float, str, bool)) or v is None)
                and k != "already_converged"}

    @classmethod
    def from_dict(cls, d):
        """From a stored (possibly partial) report dict; unknown keys are ignored."""
        names = set(cls._names())
        kw = {k: v for k, v in d.items() if k in names}
        kw["extra"] = {k: v for k, v in d.items() if k not in names}
        kw.setdefault("n", 0)
        kw.setdefault("seed", 0)
        kw.setdefault("converged", False)
        kw.setdefault("steps", 0)
        return cls(**kw)


@dataclass
class PackingResult:
    """Final state of a packing run (see :func:`pack`).

    Attributes
    ----------
    state : the final :class:`dem.state.State` (positions [m], velocities [m/s], cell [m], ...).
    law : the contact law of the last phase (a ``dem.contact_laws`` law, stiffnesses in N/m).
    report : the :class:`PackReport` of the run (criteria, counts, timings).
    """
    state: State
    law: object
    report: PackReport

    def to_network(self):
        """The :class:`microhom.network.ContactNetwork` of the packing (forces included)."""
        return network_from_state(self.state, self.law)

    def save(self, path):
        """One npz that is a checkpoint (``load``, bit-exact state) and a ``dem.io``
        configuration (:func:`dem.io.read`: positions, radii, cell, ids, velocities); atomic."""
        self.state.meta["packing_report"] = self.report.scalars()
        self.state.meta["packing_law"] = self.law.to_meta()
        return _write_packing_npz(path, self.state)

    @classmethod
    def load(cls, path):
        st = State.load(path)
        return cls(st, law_from_meta(st.meta["packing_law"]),
                   PackReport.from_dict(st.meta.get("packing_report", {})))


#: bytes per particle held by a packing run (state, Verlet list, history, engine buffers),
#: measured by ``studies.bench_scaling``; the memory guard of :func:`check_memory` uses it
BYTES_PER_PARTICLE = 247


def available_memory() -> int:
    """Available memory [bytes] (``MemAvailable`` of /proc/meminfo; total physical memory
    elsewhere)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(n, fraction=0.8):
    """Refuse (ValueError naming ``n``) a packing whose estimated memory,
    ``BYTES_PER_PARTICLE * n`` plus 30 % for the analysis after the run, exceeds ``fraction`` of
    the available memory."""
    need = 1.3 * BYTES_PER_PARTICLE * n
    avail = available_memory()
    if need > fraction * avail:
        raise ValueError(f"n = {n} disks need about {need / 1e9:.3g} GB ({BYTES_PER_PARTICLE} B per "
                         f"particle and 30 % for the analysis) but only {avail / 1e9:.3g} GB are "
                         f"available; allowed: n <= {int(fraction * avail / (1.3 * BYTES_PER_PARTICLE))}")


# ---- the phases of pack ----------------------------------------------------------------------
@dataclass(frozen=True)
class Grow:
    """Phase ``grow`` (only with ``growth_dispersity`` > 0): compress with spread radii until the
    pressure is within ``tol_p`` (5 %) of the target, then phase ``restore`` shrinks the spread to
    zero in ``increments`` checks."""
    growth_dispersity: float
    tol_p: float = 0.05
    increments: int = 50
    name = "grow"

    def enter(self, run):
        pass

    def done(self, run, m):
        return abs(m["pressure"] - run.p_target) < self.tol_p * run.p_target

    def restore(self, run):
        """One restore increment (phase ``restore``); True when the radii are back."""
        state = run.state
        gr = state.meta["growth"]
        gr["s"] = max(0.0, gr["s"] - 1.0 / self.increments)
        r0, u = np.asarray(gr["r0"]), np.asarray(gr["u"])
        state.radius = r0 * (1.0 + gr["g"] * gr["s"] * u)
        run.sim.need_rebuild = True
        if gr["s"] == 0.0:
            state.radius = r0.copy()
            return True
        return False


@dataclass(frozen=True)
class Compact:
    """Phase ``compact``: the servo drives the pressure to the target under the light damping
    ``damping`` (set when the simulation is built); ends when the packing has jammed:
    ``|p - p_t| < tol_p p_t`` (1e-2) and unbalanced ratio < ``jam_unbalanced``.

    Once the packing has stopped compacting (the solid fraction changed by less than
    ``still_tol`` (relative) between consecutive checks, ``still_checks`` times in a row), the
    FIRE mixing (:mod:`dem.fire`) runs on top of the damping until the phase ends or the packing
    moves again (``still_tol = 0``: never). It stops the ringing of the jammed, lightly damped
    packing; during the flow it would stop the flow, hence the gate.
    """
    damping: float
    jam_unbalanced: float = 1e-3
    tol_p: float = 1e-2
    still_tol: float = 3e-7
    still_checks: int = 5
    name = "compact"

    def enter(self, run):
        pass

    def done(self, run, m):
        if self.still_tol > 0:
            phi = run.state.solid_fraction
            prev, run.last_phi = run.last_phi, phi
            run.n_still = run.n_still + 1 if prev is not None and abs(phi - prev) < \
                self.still_tol * phi else 0
            if run.n_still < self.still_checks:
                run.fire = None
            elif run.fire is None:
                run.fire = Fire()
        return abs(m["pressure"] - run.p_target) < self.tol_p * run.p_target and \
            m["unbalanced"] < self.jam_unbalanced


@dataclass(frozen=True)
class Equilibrate:
    """Phase ``prep`` (at the preparation friction) or ``test`` (at the test friction): hold the
    target pressure with the equilibrium ``damping`` until all three criteria hold:
    ``|p - p_t|/p_t < tol_p``, unbalanced ratio < ``tol_unbalanced``, kinetic energy of the
    particles in contact < ``tol_ke`` x elastic energy (evaluated only when the first two hold).

    Attributes
    ----------
    name : ``"prep"`` or ``"test"``, the phase's name in the report and the progress lines.
    law : the contact law of the phase (its friction is the phase's friction).
    damping : Cundall local damping of the phase, in [0, 1).
    tol_p, tol_unbalanced, tol_ke : the three stop criteria above [-].
    fire : FIRE velocity mixing after every step (:mod:`dem.fire`, a fresh :class:`~dem.fire.Fire` at the
        start of the phase), on top of the damping.
    """
    name: str
    law: object
    damping: float
    tol_p: float = 1e-3
    tol_unbalanced: float = 1e-5
    tol_ke: float = 1e-8
    fire: bool = False

    def enter(self, run):
        if run.sim.law is not self.law and run.sim.law.to_meta() != self.law.to_meta():
            run.sim.set_law(self.law)
        run.sim.damping = float(self.damping)
        run.fire = Fire() if self.fire else None

    def done(self, run, m):
        return run.criteria(m, self)


class _Run:
    """The state a pack run carries between its checks: simulation, target, last criteria,
    phase history."""

    def __init__(self, sim, p_target, history):
        self.sim = sim
        self.state = sim.state
        self.p_target = p_target
        self.history = history
        self.last = {}
        self.fire = None     # the FIRE mixing of the current phase (dem.fire.Fire) or None
        self.last_phi = None  # solid fraction at the last check (Compact's stillness gate)
        self.n_still = 0      # consecutive checks without compaction

    def advance(self, k):
        """``k`` time steps, with the FIRE mixing after each one if the phase has it."""
        if self.fire is None:
            self.sim.run(k)
        else:
            self.sim.run(k, callback=self.fire.update, every=1)

    def ke_rel(self, m):
        ke = _contact_kinetic_energy(self.state, self.sim.law)
        ke_rel = ke / m["elastic_energy"] if m["elastic_energy"] > 0 else float("inf")
        self.last.update(ke_rel=ke_rel, kinetic_energy_in_contact=ke)
        return ke_rel

    def criteria(self, m, eq, force_ke=False):
        """The three stop criteria of :class:`Equilibrate` ``eq`` (the kinetic-energy pass only
        when it can decide, or when ``force_ke``)."""
        e_p = abs(m["pressure"] - self.p_target) / self.p_target
        self.last.update(m, rel_p_err=e_p)
        ok = e_p < eq.tol_p and m["unbalanced"] < eq.tol_unbalanced
        if ok or force_ke:
            ok = self.ke_rel(m) < eq.tol_ke and ok
        return ok


def pack(n, *, p_over_kn=1e-4, pressure=None, kn=1.0, kt=None, mu=0.5, mu_prep=None, radius=0.5,
         dispersity=0.0, rho=None, seed=0, phi0=0.2, gas_overlaps=True, damping=0.7,
         damping_compaction=0.05, jam_unbalanced=1e-3, restitution=None, max_strain_per_step=2e-4,
         alpha=0.5, dt_over_dtcrit=1.0, fire=True, tol_p=1e-3, tol_unbalanced=1e-5, tol_ke=1e-8,
         max_steps=2_000_000, check_every=100, checkpoint=None, checkpoint_every=20000,
         checkpoint_seconds=None, progress=None, verbose=False, frictionless=None,
         growth_dispersity=0.0, restore_increments=50, meta=None, threads=1) -> PackingResult:
    """Dense random packing of ``n`` disks at a target pressure (protocol in the module docstring).

    Units are any consistent set, 2D per unit thickness. The run is a sequence of named phases
    (:class:`Grow`, :class:`Compact`, :class:`Equilibrate` "prep" and "test"), each with its own
    parameters and stop criterion. ``n`` is checked against the available memory first
    (:func:`check_memory`, ValueError).

    Parameters
    ----------
    n : int
        Number of disks.
    p_over_kn : float
        Target p/kn [-] (used if ``pressure`` is None).
    pressure : float or None
        Target pressure [N/m] (force per length, compression positive).
    kn, kt : float
        Contact stiffnesses [N/m]; ``kt=None`` means kt = kn.
    mu, mu_prep : float
        Test friction and preparation friction (default: mu) [-].
    frictionless : bool or None
        Force the specialised frictionless law (no spins, no history); default True when
        mu == mu_prep == 0.
    radius, dispersity, rho, seed, phi0 :
        Radius [m], relative radius spread [-], areal density [kg/m^2], random seed, initial
        solid fraction [-] (default 0.2): see :func:`random_gas`.
    gas_overlaps : bool
        True (default): independent uniform centres; the overlaps push the disks apart and
        heat the gas, which works against crystallisation. False: a cold gas by random
        sequential addition, without overlaps and at rest (``phi0`` < 0.45; with ``phi0=0.4``
        it saves the first few thousand steps, but small packings of identical disks order
        more often, see ``docs/dem.md``).
    damping : float
        Cundall local damping of the equilibrium phases, in [0, 1) (default 0.7).
    damping_compaction : float or None
        Local damping of the compaction phase, in [0, 1) (default 0.05); None: no separate
        compaction phase (``damping`` throughout: the protocol before the compaction phase).
    jam_unbalanced : float
        Unbalanced force ratio (with ``|p - p_target| < 1e-2 p_target``) that ends the
        compaction phase [-].
    restitution : float or None
        Optional viscous contact damping (coefficient of restitution, [-]).
    max_strain_per_step : float
        Cap on the isotropic strain per step of the servo [-].
    alpha : float
        Servo gain: fraction of the pressure error corrected per step, with the affine
        stiffness [-].
    dt_over_dtcrit : float
        Time step over the engine's stable step ``dem.integrate.critical_dt``, in (0, 1]
        (default 1; ``dt_crit`` is itself at least sqrt(2) below the leapfrog limit of the
        stiffest possible contact set, see :mod:`dem.integrate`).
    fire : bool
        FIRE velocity mixing (:mod:`dem.fire`) in the equilibrium phases and, once the packing
        has stopped compacting, in the compaction phase (:class:`Compact`), on top of the
        damping (default True; False: damping alone, the earlier protocol).
    tol_p, tol_unbalanced, tol_ke : float
        Stop criteria [-] (module docstring).
    max_steps : int
        Cap on the total step count (the report then has ``converged = False``).
    check_every : int
        Steps between checks of the criteria and of the instability guard.
    growth_dispersity : float
        Relative radius spread used only during the first compression (radii
        ``r_i (1 + g u_i)``, ``u_i`` uniform in [-1, 1], masses of the final disks), removed in
        ``restore_increments`` steps of ``check_every`` steps once the target pressure is first
        reached (within 5 %); 0 disables it.
    checkpoint : path or None
        Path of an npz checkpoint, written atomically every ``checkpoint_every`` time steps
        and/or every ``checkpoint_seconds`` seconds of wall time, and at the end; resumed from
        if it exists (the CLI's ``--checkpoint-every`` and ``--checkpoint-seconds`` have the
        same units). Either trigger may be None. The final checkpoint of a converged run holds
        its report: resuming it returns that report with ``already_converged=True``. Temporary
        files of a killed checkpoint write are removed on resume.
    progress : callable or None
        ``progress(info)`` called at every check with a dict (``step``, ``max_steps``,
        ``phase``, ``phi``, ``Z``, ``rel_p_err``, ``unbalanced``, ``ke_rel`` (None when not
        evaluated at this check), ``checkpoint_step``).
    meta : dict or None
        JSON-able dict merged into ``state.meta`` of a new run (it travels in every checkpoint;
        a resumed run keeps the checkpoint's).
    threads : int
        Threads of the contact-force loop, in [1, 1024] (default 1; see
        :class:`dem.integrate.Simulation`). With more than one, the run is reproducible for that
        number of threads only (forces agree with one thread's to round-off), and a resumed run
        continues bit for bit only with the same number.

    An unstable run raises :class:`dem.runtime.InstabilityError` (``state`` = last good state);
    its ``checkpoint``/``checkpoint_step`` attributes name the last checkpoint written (None if
    none), which the error never overwrites.
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
    if damping_compaction is not None and not (0 <= damping_compaction < 1):
        raise ValueError(f"damping_compaction must be in [0, 1) or None, got {damping_compaction}")
    if not (0 < dt_over_dtcrit <= 1):
        raise ValueError(f"dt_over_dtcrit must be in (0, 1], got {dt_over_dtcrit}")
    if not (0 < jam_unbalanced < 1):
        raise ValueError(f"jam_unbalanced must be in (0, 1), got {jam_unbalanced}")
    if int(check_every) != check_every or check_every < 1:
        raise ValueError(f"check_every must be an integer >= 1, got {check_every}")
    if not (0 <= growth_dispersity < 0.5):
        raise ValueError(f"growth_dispersity must be in [0, 0.5), got {growth_dispersity}")
    for name, val in (("checkpoint_every", checkpoint_every), ("checkpoint_seconds", checkpoint_seconds)):
        if val is not None and not (val >= 0 and math.isfinite(val)):
            raise ValueError(f"{name} must be None or >= 0 ({'steps' if name == 'checkpoint_every' else 's'}), "
                             f"got {val}")
    check_memory(n)
    check_every = int(check_every)
    if frictionless is None:
        frictionless = mu == 0 and mu_prep == 0
    law_prep = Frictionless(kn=kn, restitution=restitution) if frictionless else \
        LinearFriction(kn=kn, kt=kt, mu=mu_prep, restitution=restitution)
    law_test = law_prep if frictionless else law_prep.with_friction(mu)
    params = {"n": int(n), "p_target": p_target, "kn": kn, "kt": kt, "mu": mu, "mu_prep": mu_prep,
              "seed": seed, "dispersity": dispersity, "phi0": phi0, "damping": damping,
              "damping_compaction": damping_compaction, "tol_p": tol_p,
              "tol_unbalanced": tol_unbalanced, "tol_ke": tol_ke, "check_every": check_every,
              "gas_overlaps": bool(gas_overlaps), "dt_over_dtcrit": dt_over_dtcrit, "fire": bool(fire)}

    # the named phases, in order (each with its own parameters and stop criterion)
    phases = []
    if growth_dispersity > 0:
        phases.append(Grow(growth_dispersity, increments=restore_increments))
    if damping_compaction is not None:
        phases.append(Compact(damping_compaction, jam_unbalanced,
                              still_tol=3e-7 if fire else 0.0))
    eq = dict(damping=damping, tol_p=tol_p, tol_unbalanced=tol_unbalanced, tol_ke=tol_ke,
              fire=bool(fire))
    phases.append(Equilibrate("prep", law_prep, **eq))
    if law_test is not law_prep and mu != mu_prep:
        phases.append(Equilibrate("test", law_test, **eq))
    by_name = {ph.name: ph for ph in phases}

    resumed = checkpoint is not None and os.path.exists(os.fspath(checkpoint))
    if checkpoint is not None:
        remove_stale_temporaries(checkpoint)
    if resumed:
        st0 = State.load(checkpoint)
        pk = st0.meta["packing"]
        phase = pk["phase"]
        if phase == "done" and pk.get("report"):   # a finished run: nothing to compute
            rep = PackReport.from_dict(dict(pk["report"], phase_steps=pk.get("history", []),
                                            resumed=True, already_converged=True))
            return PackingResult(st0, law_test, rep)
        ctl = PressureServo(**{k: v for k, v in st0.meta["sim"]["control"].items() if k != "kind"})
        sim = Simulation.load(checkpoint, control=ctl, threads=threads)
        history = pk.get("history", [])
    else:
        st = random_gas(n, radius=radius, dispersity=dispersity, phi0=phi0, rho=rho, seed=seed,
                        spins=not frictionless, overlaps=gas_overlaps)
        if growth_dispersity > 0:
            u = np.random.default_rng([seed, 1]).uniform(-1.0, 1.0, st.n)
            st.meta["growth"] = {"r0": st.radius.tolist(), "u": u.tolist(), "g": growth_dispersity, "s": 1.0}
            st.radius = st.radius * (1.0 + growth_dispersity * u)
        if meta:
            st.meta.update(meta)
        sim = Simulation(st, law_prep, dt=dt_over_dtcrit * critical_dt(st, law_prep),
                         damping=damping if damping_compaction is None else damping_compaction,
                         check_every=0, threads=threads)
        ctl = PressureServo(p_target=p_target, max_rate=max_strain_per_step / sim.dt, alpha=alpha)
        sim.control = ctl
        phase = phases[0].name
        history = []
    sim.check_every = 0  # guard is done in the callback below (every check_every steps)
    state = sim.state
    run = _Run(sim, p_target, history)
    if resumed:
        run.fire = Fire.from_meta(pk["fire"]) if pk.get("fire") else None
        run.last_phi, run.n_still = pk.get("last_phi"), pk.get("n_still", 0)
    else:
        by_name[phase].enter(run)
    ck_state = {"step": state.step if resumed else None, "t": time.perf_counter()}
    n_checks = [0]
    order = [ph.name for ph in phases]

    def next_phase(name):
        if name == "grow":
            return "restore"
        nxt = order.index("grow" if name == "restore" else name) + 1
        return order[nxt] if nxt < len(order) else "done"

    def save_checkpoint(report=None):
        state.meta["packing"] = {"phase": phase, "history": history, "params": params,
                                 "fire": None if run.fire is None else run.fire.to_meta(),
                                 "last_phi": run.last_phi, "n_still": run.n_still}
        if report is not None:
            state.meta["packing"]["report"] = {k: v for k, v in report.scalars().items()
                                               if k not in ("resumed", "already_converged")}
        sim.save(checkpoint)
        ck_state["step"] = state.step
        ck_state["t"] = time.perf_counter()

    def callback(s):
        nonlocal phase
        s._guard()
        m = s.measure()
        n_checks[0] += 1
        run.last["ke_rel"] = None
        if verbose and state.step % (10 * check_every) == 0:
            print(f"[pack] step {state.step} phase {phase} phi {state.solid_fraction:.4f} "
                  f"p/p0 {m['pressure'] / p_target:.5f} unb {m['unbalanced']:.3g} "
                  f"Z {2 * m['n_contacts'] / state.n:.3f}", flush=True)
        ph = by_name["grow"] if phase == "restore" else by_name[phase]
        finished = ph.restore(run) if phase == "restore" else ph.done(run, m)
        if finished:
            history.append({"phase": phase, "step": int(state.step)})
            phase = next_phase(phase)
            if phase in by_name:
                by_name[phase].enter(run)
        if progress is not None:
            if run.last["ke_rel"] is None and n_checks[0] % 10 == 0:
                run.ke_rel(m)
            progress({"step": int(state.step), "max_steps": int(max_steps), "phase": phase,
                      "phi": state.solid_fraction, "Z": 2.0 * m["n_contacts"] / state.n,
                      "rel_p_err": abs(m["pressure"] - p_target) / p_target,
                      "unbalanced": m["unbalanced"],
                      "ke_rel": run.last["ke_rel"], "checkpoint_step": ck_state["step"]})
        done = phase == "done"
        if checkpoint is not None and not done:
            by_steps = checkpoint_every and state.step % checkpoint_every == 0
            by_time = checkpoint_seconds is not None and \
                time.perf_counter() - ck_state["t"] >= checkpoint_seconds
            if by_steps or by_time:
                save_checkpoint()
        return done

    if resumed and phase == "test":
        sim.set_law(law_test)
    try:
        # steps in chunks ending at absolute multiples of check_every: the checks (and therefore
        # the trajectory) do not depend on where a run was interrupted and resumed
        while phase != "done" and state.step < max_steps:
            k = min(check_every - state.step % check_every, max_steps - state.step)
            run.advance(k)
            if state.step % check_every == 0 and callback(sim):
                break
    except InstabilityError as exc:
        exc.checkpoint = os.fspath(checkpoint) if ck_state["step"] is not None else None
        exc.checkpoint_step = ck_state["step"]
        raise
    m = sim.measure() if sim.steps_timed else sim.refresh()   # forces exist only after a step
    run.criteria(m, phases[-1], force_ke=True)  # the final values of the three criteria
    last = run.last
    net = network_from_state(state, sim.law)
    try:
        hx = hexatic_psi6(net)
    except Exception as exc:  # noqa: BLE001 - psi6 is informative only
        hx = {"psi6": float("nan"), "psi6_local": float("nan")}
    nc = net.n_contacts
    compact_end = [h["step"] for h in history if h["phase"] == "compact"]
    timing = sim.timing_report()
    report = PackReport(
        n=state.n, seed=seed, converged=phase == "done", steps=int(state.step),
        phase_steps=history, compaction_steps=compact_end[0] if compact_end else None,
        wall_s=time.perf_counter() - t_start, resumed=resumed,
        p_target=p_target, pressure=last["pressure"], rel_p_err=last["rel_p_err"],
        p_over_kn=last["pressure"] / kn, unbalanced=last["unbalanced"],
        unbalanced_max=last["unbalanced_max"], ke_rel=last["ke_rel"],
        kinetic_energy=last["kinetic_energy"],
        kinetic_energy_in_contact=last["kinetic_energy_in_contact"], elastic_energy=last["elastic_energy"],
        phi=state.solid_fraction, n_contacts=nc, Z=2.0 * nc / state.n,
        sliding_fraction=float(net.sliding.mean()) if nc and not frictionless else float("nan"),
        dt=sim.dt, dt_over_dtcrit=sim.dt / sim.dt_crit, mu=mu, mu_prep=mu_prep,
        kn=kn, kt=0.0 if frictionless else kt, tol_p=tol_p, tol_unbalanced=tol_unbalanced,
        tol_ke=tol_ke, damping=damping, damping_compaction=damping_compaction,
        damping_work=sim.damping_work, psi6=hx["psi6"], psi6_local=hx["psi6_local"],
        timing=timing["table"], particle_steps_per_s=timing["particle_steps_per_s"])
    res = PackingResult(state, sim.law, report)
    if checkpoint is not None:
        save_checkpoint(report if phase == "done" else None)
    return res
