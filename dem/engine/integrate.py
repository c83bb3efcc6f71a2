"""Explicit time stepping of a 2D disk assembly in a periodic deformable cell.

Scheme (leapfrog / velocity Verlet in kick-drift form, as in PFC and Yade)::

    F_n      = contact forces at x_n (tangential history advanced with v_{n-1/2})
    v_{n+1/2} = v_{n-1/2} + dt (F_n + F_damp) / m          (fluctuation velocities)
    x_{n+1}   = x_n + dt (v_{n+1/2} + L x_n)               (affine field of the cell)
    h_{n+1}   = h_n + dt L h_n                             (same operator: images stay consistent)

with spins ``w`` and rotations integrated the same way with torques and ``I = m r^2 / 2``.
``Simulation(startup="lammps")`` takes the initial velocities as v(0) instead (LAMMPS' velocity
Verlet): the first force call does not advance the contact history and the first kick is dt/2,
after which the sequence is the same. With ``loop=Loop(fuse=True)`` and no cell control, each particle is
kicked and drifted inside the force loop once its force is complete (same arithmetic).

Cundall local non-viscous damping, per component: ``F_damp,k = -lambda |F_k| sign(v_k)`` (first
order, ``v = v_{n-1/2}``); default ``lambda = 0.7`` for quasi-static work, 0 for dynamics. The work
done by it is accumulated in ``Simulation.damping_work`` [J/m].

Critical time step (stated formula): ``dt_crit = min_i sqrt(m_i / K_i)`` with
``K_i = z_i * k_law`` the sum over the *possible* contacts of particle i of the law's stiffness,
``z_i = floor(pi / asin(r_min / (r_i + r_min)))`` the largest number of disks of the smallest radius
that can touch disk i (6 for identical disks) and ``k_law`` = ``law.dt_stiffness()``: ``kn``
(frictionless), ``max(kn, 2 kt)`` with friction and spins (covering the rotational modes of
disks), ``max(kn, 2 kt + 2 kr_ratio kn)`` with rolling resistance. Since the
largest eigenfrequency of the assembly obeys ``omega_max^2 <= 2 K_i / m_i`` (Gershgorin), the
leapfrog limit ``2 / omega_max`` is at least ``sqrt(2) dt_crit``. Default ``dt = 0.8 dt_crit``; a
larger user ``dt`` than ``dt_crit`` raises ``ValueError``.

Settings by what they are about: ``Simulation(state, law, dt=..., damping=..., control=...,
startup=..., guard=Guard(...), loop=Loop(...))``; :class:`Guard` the instability guard
(``check_every``, ``ke_limit``, ``unsafe_dt``, ``failure_path``), :class:`Loop` the step loop's
implementation (``skin``, ``sort_every``, ``fuse``, ``threads``), both frozen and validated when made.

Instability guard: every ``check_every`` steps the state is checked for NaN/inf and for a kinetic
energy above ``ke_limit`` (default ``N * k_law * r_min^2``: every particle as energetic as a
full-diameter overlap); a failure raises :class:`~dem.runtime.InstabilityError` carrying the last good state (and
saves it to ``failure_path`` if set).

Timing: every run ends with a per-phase table (neighbours, forces, integration, other) and the
particle-steps per second, like LAMMPS (``Simulation.timing_report()``). The stress, energy and
contact tallies of the force loop (``Simulation.out``) are computed on the steps that read them
only: every step under a cell control, on callback steps and on the last step of :meth:`Simulation.run`, and
on every :meth:`Simulation.step` called directly.
"""
from __future__ import annotations

import math
import os
import time as _time
import warnings
from dataclasses import dataclass

import numpy as np
from numba import njit

from microhom.options import Options, finite_real, flag, integer

from . import contact_models as cm
from . import neighbors
from .contact_laws import law_from_meta
from .state import State
from ..runtime import InstabilityError, RunReport, run_report  # noqa: F401 - part of this API

__all__ = ["Simulation", "Guard", "Loop", "critical_dt", "possible_contacts"]


def possible_contacts(radius) -> np.ndarray:
    """(N,) largest number of smallest disks that can touch each disk (6 for identical disks)."""
    r = np.asarray(radius, dtype=float)
    rmin = r.min()
    return np.floor(np.pi / np.arcsin(rmin / (r + rmin)) + 1e-9).astype(np.int64)


def critical_dt(state, law) -> float:
    """dt_crit = min_i sqrt(m_i / K_i), K_i = possible_contacts_i * law.dt_stiffness() [s]."""
    K = possible_contacts(state.radius) * law.dt_stiffness()
    return float(np.min(np.sqrt(state.mass / K)))


# --------------------------------------------------------------------------------------------------
@njit(cache=True)
def _resultants(f):
    s = 0.0
    m = 0.0
    for i in range(f.shape[0]):
        a = math.sqrt(f[i, 0] * f[i, 0] + f[i, 1] * f[i, 1])
        s += a
        if a > m:
            m = a
    return s, m


def _compact(st):
    """(pi32, jc) of the state's Verlet list (:func:`dem.engine.contact_models.compact_list`)."""
    if st.n >= 2 ** (31 - cm.SHIFT_BITS):
        raise ValueError(f"at most {2 ** (31 - cm.SHIFT_BITS) - 1} particles, got {st.n}")
    pi32, jc, ok = cm.compact_list(st.nl_i, st.nl_j, st.nl_shift)
    if not ok:
        raise ValueError("the Verlet list must be ordered by nl_i with image shifts in {-1, 0, 1} "
                         "(as dem.engine.neighbors.rebuild makes it); rebuild it")
    return pi32, jc


_NO_KICK = tuple(cm.NO_KICK)  # plain tuples: the fast form of the kernels' bundles (cm.pair_forces)


def _new_history(npairs, law):
    """Zero contact history: (P,) for one slot per pair (the layout of older checkpoints), else
    (P, slots)."""
    k = law.history_size
    return np.zeros(npairs) if k == 1 else np.zeros((npairs, k))


def _history_fits(hist, law):
    k = law.history_size
    return hist is not None and (hist.ndim == 1 if k == 1 else hist.ndim == 2 and hist.shape[1] == k)


def _norm2_2x2(a, b, c, d):
    """Spectral norm of [[a, b], [c, d]]."""
    s = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return math.sqrt(max(0.0, 0.5 * (s + math.sqrt(max(0.0, s * s - 4 * det * det)))))


@dataclass(frozen=True)
class Guard(Options):
    """The instability guard of a :class:`Simulation`: frozen, validated when made (a value outside
    its range raises :class:`~microhom.options.OptionError`, a ``ValueError`` naming the field).

    Attributes
    ----------
    check_every : int
        Steps between instability checks (NaN/inf, kinetic energy above ``ke_limit``), >= 0; 0:
        never.
    ke_limit : float or None
        Kinetic-energy bound [J/m], > 0; None: ``N * k_law * r_min^2`` (every particle as
        energetic as a full-diameter overlap).
    unsafe_dt : bool
        Allow ``dt`` above ``critical_dt`` (for tests of the guard itself).
    failure_path : str, path or None
        Where the last good state is saved when the guard trips (None: not saved).
    """

    check_every: int = 200
    ke_limit: float | None = None
    unsafe_dt: bool = False
    failure_path: str | os.PathLike | None = None

    RULES = {
        "check_every": ("an integer >= 0", lambda v: integer(v) and v >= 0),
        "ke_limit": ("None or finite and > 0", lambda v: v is None or (finite_real(v) and v > 0)),
        "unsafe_dt": ("True or False", flag),
        "failure_path": ("None or a path", lambda v: v is None or isinstance(v, (str, os.PathLike))),
    }


@dataclass(frozen=True)
class Loop(Options):
    """How a :class:`Simulation`'s step loop is carried out (never what it computes, except
    ``threads``: round-off): frozen, validated when made.

    Attributes
    ----------
    skin : float or None
        Verlet skin [m], > 0; None: 0.2 * mean radius.
    sort_every : int
        Spatially sort the particles every this many list rebuilds, >= 0 (0: never).
    fuse : bool
        Kick and drift inside the force loop when the cell has no control (bit-identical to
        the separate pass, one pass over the particle arrays fewer; measured no faster on the
        benchmark scene, see ``docs/dem.md``, hence off by default).
    threads : int
        Threads of the contact-force loop, in [1, 1024] (default 1). With 2 or more
        (:func:`dem.engine.contact_models.pair_forces_threaded`) the forces agree with one thread's to
        round-off, not bit for bit, and a run is reproducible for a given number of threads; the
        kick, the list builds and the rest of the step stay on one thread (measured speed-up in
        ``docs/dem.md``).
    """

    skin: float | None = None
    sort_every: int = 20
    fuse: bool = False
    threads: int = 1

    RULES = {
        "skin": ("None or finite and > 0", lambda v: v is None or (finite_real(v) and v > 0)),
        "sort_every": ("an integer >= 0", lambda v: integer(v) and v >= 0),
        "fuse": ("True or False", flag),
        "threads": ("an integer in [1, 1024]", lambda v: integer(v) and 1 <= v <= 1024),
    }


def _bundle(cls, value, name):
    """``value`` (a ``cls`` or None: its defaults); a TypeError names the keyword otherwise."""
    if value is None:
        return cls()
    if not isinstance(value, cls):
        raise TypeError(f"Simulation's {name} must be a dem.engine.integrate.{cls.__name__} or None, got "
                        f"{type(value).__name__} (e.g. {name}={cls.__name__}({', '.join(cls.names())}=...))")
    return value


class Simulation:
    """A disk assembly, a contact law and an integrator in a periodic cell.

    Parameters
    ----------
    state : :class:`dem.engine.state.State` (modified in place).
    law : a contact law from :mod:`dem.engine.contact_laws`.
    dt : time step [s]; default ``0.8 * critical_dt``; refused (ValueError) above ``critical_dt``
        unless ``guard=Guard(unsafe_dt=True)`` (for tests of the instability guard).
    damping : Cundall local damping lambda in [0, 1); ``None`` (default) means 0.7, or 0 for a law
        that follows another code's equations (``LAMMPS_EQUIVALENT``: the
        :class:`~dem.engine.contact_laws.LammpsHookeHistory` law, since LAMMPS has no Cundall damping).
        An explicit ``damping > 0`` with such a law runs with a ``RuntimeWarning``: the run leaves
        LAMMPS's equations (dv/v_rms of 0.1 at the first step with 0.7).
    control : cell control (:class:`dem.engine.cell.StrainRate`, :class:`dem.engine.cell.PressureServo`) or None
        (the cell keeps its current ``L``).
    startup : ``"leapfrog"`` (default): ``state.v`` holds the half-step velocities v(n - 1/2), as
        this engine stores them. ``"lammps"``: ``state.v`` and ``state.omega`` are the velocities at
        the integer time, as LAMMPS (velocity Verlet) stores them; the first step then computes
        the forces with them without advancing the contact history (LAMMPS' setup force call) and
        kicks by dt/2, after which the two schemes coincide.
    guard : :class:`Guard` or None
        The instability guard (``check_every``, ``ke_limit``, ``unsafe_dt``, ``failure_path``);
        None: its defaults.
    loop : :class:`Loop` or None
        The step loop's implementation (``skin``, ``sort_every``, ``fuse``, ``threads``); None: its
        defaults.

    The settings in use are the attributes ``dt``, ``damping``, ``control``, ``skin``,
    ``sort_every``, ``check_every``, ``ke_limit`` (resolved), ``failure_path``, ``fuse`` and
    ``threads``.
    """

    def __init__(self, state, law, *, dt=None, damping=None, control=None, startup="leapfrog",
                 guard=None, loop=None):
        guard, loop = _bundle(Guard, guard, "guard"), _bundle(Loop, loop, "loop")
        self.state = state
        self.law = law
        lammps_law = getattr(law, "LAMMPS_EQUIVALENT", False)
        if damping is None:
            damping = 0.0 if lammps_law else 0.7
        if not (isinstance(damping, (int, float, np.floating)) and 0 <= damping < 1):
            raise ValueError(f"damping must be in [0, 1), got {damping!r}")
        if lammps_law and damping > 0:   # asked for: allowed (kernel tests use it), never silent
            warnings.warn(f"damping = {damping!r} with {type(law).__name__}: LAMMPS has no "
                          "Cundall local damping, so this run leaves LAMMPS's equations; leave "
                          "damping unset (0 for this law) to follow LAMMPS", RuntimeWarning,
                          stacklevel=2)
        self.damping = float(damping)
        self.skin = float(0.2 * np.mean(state.radius) if loop.skin is None else loop.skin)
        self.dt_crit = critical_dt(state, law)
        if dt is None:
            dt = 0.8 * self.dt_crit
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be > 0, got {dt}")
        if dt > self.dt_crit and not guard.unsafe_dt:
            raise ValueError(f"dt = {dt:.6g} exceeds the stable time step dt_crit = {self.dt_crit:.6g} "
                             f"(dt_crit = min_i sqrt(m_i/K_i); allowed range (0, {self.dt_crit:.6g}])")
        self.dt = float(dt)
        self.control = control
        self.sort_every = int(loop.sort_every)
        self.check_every = int(guard.check_every)
        rmin = float(np.min(state.radius))
        self.ke_limit = float(state.n * law.dt_stiffness() * rmin * rmin if guard.ke_limit is None
                              else guard.ke_limit)
        self.failure_path = guard.failure_path
        self.rc = neighbors.list_cutoff(state.radius, self.skin)
        if law.needs_spin and state.omega is None:
            state.omega = np.zeros(state.n)
            state.theta = np.zeros(state.n)
        if startup not in ("leapfrog", "lammps"):
            raise ValueError(f"startup must be 'leapfrog' or 'lammps', got {startup!r}")
        self.fuse = bool(loop.fuse)
        self.threads = int(loop.threads)
        if law.needs_history and state.nl_i is not None and not _history_fits(state.nl_ft, law):
            state.nl_ft = _new_history(state.nl_i.shape[0], law)
        meta = state.meta.get("sim", {})
        self.startup_pending = bool(meta.get("startup_pending", startup == "lammps"))
        self.n_rebuilds = int(meta.get("n_rebuilds", 0))
        self.need_rebuild = bool(meta.get("need_rebuild", state.nl_i is None))
        self.damping_work = float(meta.get("damping_work", 0.0))
        self._alloc()
        self.last_good = None
        self.timers = {"neighbours": 0.0, "forces": 0.0, "integration": 0.0, "other": 0.0}
        self.steps_timed = 0
        self.ke_n = float("nan")          # kinetic energy at the integer time of the last tallied step
        self.energy_n = float("nan")      # elastic + kinetic energy at the last integer time

    # ---- buffers --------------------------------------------------------------------------------
    def _alloc(self):
        n = self.state.n
        self.f = np.zeros((n, 2))
        self.torque = np.zeros(n if self.law.needs_spin else 0)
        self.out = np.zeros(8)
        self.acc = np.zeros(5)
        self._empty = np.zeros(0)
        self._pc = None          # per-pair law constants, valid for (self._pc_list, self._pc_mass)
        self._pc_list = None
        self._pc_mass = None
        self._list32 = None         # (pi32, jc) of the list self._list32_of (contact_models.compact_list)
        self._list32_of = None
        self._href_inv = None if self.state.h_ref is None else np.linalg.inv(self.state.h_ref)

    def set_law(self, law):
        """Switch the contact law (e.g. preparation friction -> test friction); dt is re-checked."""
        if law.needs_spin != self.law.needs_spin or law.history_parity != self.law.history_parity:
            raise ValueError("set_law: the new law must have the same spin and history layout")
        dtc = critical_dt(self.state, law)
        if self.dt > dtc:
            raise ValueError(f"dt = {self.dt:.6g} exceeds the stable time step {dtc:.6g} of the new law")
        self.law = law
        self.dt_crit = dtc
        self._pc = None

    # ---- pieces of a step ------------------------------------------------------------------------
    def rebuild(self):
        """Rebuild the Verlet neighbour list now (carrying the contact history over); every
        ``sort_every``-th rebuild also sorts the particles spatially."""
        sort = self.sort_every > 0 and self.n_rebuilds % self.sort_every == 0
        neighbors.rebuild(self.state, self.skin, sort=sort, history=self.law.history_parity)
        self.n_rebuilds += 1
        self.need_rebuild = False
        self._href_inv = np.linalg.inv(self.state.h_ref)

    def _pair_loop(self, kick, dt_history, tally=True):
        st = self.state
        if self.need_rebuild or st.nl_i is None:
            self.rebuild()
        h, L = st.h, st.L
        law = self.law
        if self._pc is None or self._pc_list is not st.nl_i or self._pc_mass is not st.mass:
            self._pc = law.pair_constants(st.mass, st.nl_i, st.nl_j)
            self._pc_list = st.nl_i
            self._pc_mass = st.mass
        if self._list32_of is not st.nl_i:
            self._list32 = _compact(st)
            self._list32_of = st.nl_i
        pi32, jc = self._list32
        # the bundles as plain tuples in field order (cm.Pairs, cm.Forces): numba types those fastest
        pairs = (pi32, jc, st.nl_ft.reshape(-1) if law.needs_history else self._empty, self._pc)
        cm.pair_forces(cm.bodies_of(st, law.needs_spin), pairs, cm.cell_of(h, L), law.models, kick, dt_history,
                       tally, (self.f, self.torque, self.out, self.acc), threads=self.threads)

    def compute_forces(self):
        """Contact forces at the current positions (advances the tangential history: call it only
        as part of a step; use :meth:`measure` for read-only quantities)."""
        self._pair_loop(_NO_KICK, self.dt)

    def _deformation(self, L, dt):
        """h_{n+1} = (I + dt L) h_n and F = h_{n+1} h_ref^{-1} by entries."""
        h = self.state.h
        h00 = h[0, 0] + dt * (L[0, 0] * h[0, 0] + L[0, 1] * h[1, 0])
        h01 = h[0, 1] + dt * (L[0, 0] * h[0, 1] + L[0, 1] * h[1, 1])
        h10 = h[1, 0] + dt * (L[1, 0] * h[0, 0] + L[1, 1] * h[1, 0])
        h11 = h[1, 1] + dt * (L[1, 0] * h[0, 1] + L[1, 1] * h[1, 1])
        r = self._href_inv
        F00 = h00 * r[0, 0] + h01 * r[1, 0]
        F01 = h00 * r[0, 1] + h01 * r[1, 1]
        F10 = h10 * r[0, 0] + h11 * r[1, 0]
        F11 = h10 * r[0, 1] + h11 * r[1, 1]
        return (h00, h01, h10, h11), (F00, F01, F10, F11)

    def step(self, tally=True):
        """One time step. ``tally=False`` skips the stress, energy and contact sums of ``out`` and
        the kinetic energy (as LAMMPS skips energy and virial on steps without output; ``ke_n`` and
        ``energy_n`` are NaN then); a cell control always tallies, and :meth:`measure` refers to the
        last tallied step."""
        st = self.state
        tally = tally or self.control is not None
        dt = self.dt
        dtk, dth = dt, dt
        if self.startup_pending:  # LAMMPS start-up: setup force call, half kick
            dtk, dth = 0.5 * dt, 0.0
        t0 = _time.perf_counter()
        if self.need_rebuild or st.nl_i is None:
            self.rebuild()
        t1 = _time.perf_counter()
        acc = self.acc
        if self.fuse and self.control is None:
            L = st.L
            hn, Fd = self._deformation(L, dt)
            self._pair_loop((True, dtk, dt, self.damping, L[0, 0], L[0, 1], L[1, 0], L[1, 1], *Fd, tally), dth,
                            tally)  # a cm.Kick, as a plain tuple
            t2 = t3 = t4 = _time.perf_counter()
        else:
            self._pair_loop(_NO_KICK, dth, tally)
            t2 = _time.perf_counter()
            A = st.h[0, 0] * st.h[1, 1] - st.h[0, 1] * st.h[1, 0]
            if self.control is not None:
                p = (self.out[0] + self.out[3]) / (2.0 * A)  # p = -tr(sigma)/2, sigma = -S/A
                st.L = np.asarray(self.control.update(st, p, self.out[7] / (2.0 * A), dt), dtype=float)
            L = st.L
            hn, Fd = self._deformation(L, dt)
            t3 = _time.perf_counter()
            acc[:] = cm.kick_all(cm.bodies_of(st, self.law.needs_spin), (self.f, self.torque, self.out, self.acc),
                                 (True, dtk, dt, self.damping, L[0, 0], L[0, 1], L[1, 0], L[1, 1], *Fd, tally))
            t4 = _time.perf_counter()
        d2, ke, wd = acc[0], acc[1], acc[2]
        if self.law.needs_spin:
            ke += acc[3]
            wd += acc[4]
        st.h = np.array([[hn[0], hn[1]], [hn[2], hn[3]]])
        self.startup_pending = False
        self.damping_work += wd
        self.ke_n = ke if tally else float("nan")
        self.energy_n = ke + self.out[6] if tally else float("nan")
        dF = _norm2_2x2(Fd[0] - 1.0, Fd[1], Fd[2], Fd[3] - 1.0)
        if 2.0 * math.sqrt(d2) + dF * self.rc > self.skin:
            self.need_rebuild = True
        st.step += 1
        st.time += dt
        if self.check_every > 0 and st.step % self.check_every == 0:
            self._guard()
        t5 = _time.perf_counter()
        tm = self.timers
        tm["neighbours"] += t1 - t0
        tm["forces"] += t2 - t1
        tm["integration"] += t4 - t3
        tm["other"] += (t3 - t2) + (t5 - t4)
        self.steps_timed += 1

    def _guard(self):
        st = self.state
        reason = None
        if not (np.isfinite(st.x).all() and np.isfinite(st.v).all()
                and (st.omega is None or np.isfinite(st.omega).all()) and np.isfinite(st.h).all()):
            reason = "NaN or inf in positions/velocities"
        else:
            ke = st.kinetic_energy()
            if ke > self.ke_limit:
                reason = (f"kinetic energy blow-up: KE = {ke:.4g} > ke_limit = {self.ke_limit:.4g} "
                          f"(dt = {self.dt:.4g}, dt/dt_crit = {self.dt / self.dt_crit:.3g})")
        if reason is not None:
            good = self.last_good
            if good is not None and self.failure_path is not None:
                good.save(self.failure_path)
            raise InstabilityError(reason, good, st.step)
        self.last_good = self.snapshot()

    def snapshot(self):
        """A copy of the state with the simulation's own counters in ``meta`` (for checkpoints)."""
        self.state.meta["sim"] = self.meta()
        return self.state.copy()

    def meta(self):
        """JSON-ready dict of the run parameters and counters (``dt`` [s], damping, skin [m], law,
        cell control, ...), stored in checkpoints."""
        return {"dt": self.dt, "damping": self.damping, "skin": self.skin, "sort_every": self.sort_every,
                "check_every": self.check_every, "ke_limit": self.ke_limit,
                "n_rebuilds": self.n_rebuilds, "need_rebuild": self.need_rebuild,
                "damping_work": self.damping_work, "law": self.law.to_meta(),
                "startup_pending": self.startup_pending,
                "control": None if self.control is None else self.control.to_meta()}

    # ---- runs -------------------------------------------------------------------------------------
    def run(self, nsteps, *, callback=None, every=0):
        """Advance ``nsteps`` steps. ``callback(sim)`` is called every ``every`` steps; a truthy
        return value stops the run. Returns a :class:`~dem.runtime.RunReport` (timing table included)."""
        nsteps = int(nsteps)
        if nsteps < 0:
            raise ValueError(f"nsteps must be >= 0, got {nsteps}")
        before = dict(self.timers)
        s0 = self.steps_timed
        w0 = _time.perf_counter()
        stopped = False
        cb = callback is not None and every > 0
        for k in range(nsteps):
            # tally the stress and energy sums only where they are read: callbacks and the last step
            self.step(tally=k == nsteps - 1 or (cb and (k + 1) % every == 0))
            if cb and (k + 1) % every == 0:
                if callback(self):
                    stopped = True
                    break
        wall = _time.perf_counter() - w0
        steps = self.steps_timed - s0
        phases = {k: self.timers[k] - before[k] for k in self.timers}
        return self._report(steps, wall, phases, stopped)

    def _report(self, steps, wall, phases, stopped=False):
        return run_report(self.state.n, steps, wall, phases,
                          f"(dt = {self.dt:.4g}, dt/dt_crit = {self.dt / self.dt_crit:.3f}, "
                          f"{self.n_rebuilds} neighbour builds so far)", stopped=stopped)

    def timing_report(self):
        """Timing table of all steps run by this Simulation so far."""
        wall = sum(self.timers.values())
        return self._report(self.steps_timed, wall, dict(self.timers))

    # ---- read-only measurements ---------------------------------------------------------------
    def measure(self):
        """Stress and balance of the *last computed* forces (read-only).

        Returns a dict with ``stress`` ((2, 2) [N/m], tension positive, Love-Weber static part),
        ``pressure`` (``-tr/2`` [N/m]), ``n_contacts``, ``mean_contact_force``, ``unbalanced`` (Yade:
        mean over particles of the resultant contact force ``|F_i|`` over the mean contact-force
        magnitude, dimensionless), ``unbalanced_max`` (same with ``max_i |F_i|``),
        ``kinetic_energy``, ``elastic_energy`` and ``iso_stiffness`` (the affine isotropic
        stiffness the pressure servo uses [N/m])."""
        st = self.state
        A = st.area
        o = self.out
        sig = -np.array([[o[0], o[1]], [o[2], o[3]]]) / A
        sig = 0.5 * (sig + sig.T)
        nc = int(o[4])
        fbar = o[5] / nc if nc else 0.0
        s, m = _resultants(self.f)
        return {"stress": sig, "pressure": float(-np.trace(sig) / 2), "n_contacts": nc,
                "mean_contact_force": fbar,
                "unbalanced": (s / st.n) / fbar if fbar > 0 else float("inf"),
                "unbalanced_max": m / fbar if fbar > 0 else float("inf"),
                "kinetic_energy": st.kinetic_energy(), "elastic_energy": float(o[6]),
                "iso_stiffness": float(o[7] / (2 * A))}

    def refresh(self):
        """Recompute forces at the current state without changing the tangential history (the
        history is restored afterwards); use before :meth:`measure` on a freshly loaded state."""
        st = self.state
        keep = None if st.nl_ft is None else st.nl_ft.copy()
        try:
            self._pair_loop(_NO_KICK, 0.0)  # no history increment
        finally:
            if keep is not None and st.nl_ft is not None and keep.shape == st.nl_ft.shape:
                st.nl_ft[:] = keep
        return self.measure()

    # ---- checkpoints ----------------------------------------------------------------------------
    def save(self, path):
        """Atomic npz checkpoint of the state and the simulation settings (bit-exact restart)."""
        self.state.meta["sim"] = self.meta()
        self.state.save(path)

    @classmethod
    def load(cls, path, *, control=None, **changes):
        """Restart from :meth:`save`. The cell control object is passed again by the caller (its
        settings are in ``state.meta['sim']['control']`` for reference). ``changes`` replace stored
        settings: ``dt``, ``damping`` or ``startup``, or a field of :class:`Guard` or :class:`Loop`
        by name (``Simulation.load(path, threads=2)``: the stored loop with 2 threads; the fields
        not stored, ``fuse``, ``threads``, ``unsafe_dt`` and ``failure_path``, start at their
        defaults)."""
        st = State.load(path)
        m = st.meta["sim"]
        law = law_from_meta(m["law"])
        own = {k: changes.pop(k) for k in ("dt", "damping", "startup") if k in changes}
        guard = Guard(check_every=m["check_every"], ke_limit=m["ke_limit"])
        loop = Loop(skin=m["skin"], sort_every=m["sort_every"])
        unknown = sorted(set(changes) - set(Guard.names()) - set(Loop.names()))
        if unknown:
            raise TypeError(f"Simulation.load: unknown setting {unknown[0]!r}; the settings are dt, damping, "
                            f"startup, {', '.join(Guard.names() + Loop.names())}")
        guard = guard.replace(**{k: v for k, v in changes.items() if k in Guard.names()})
        loop = loop.replace(**{k: v for k, v in changes.items() if k in Loop.names()})
        kw = dict(dict(dt=m["dt"], damping=m["damping"]), **own)
        return cls(st, law, control=control, guard=guard, loop=loop, **kw)
