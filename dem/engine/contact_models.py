"""Contact-law sub-models and the one pair loop that numba specialises for every combination.

A contact law is a choice of four sub-models, in the pattern of LAMMPS GRANULAR
(``granular_model.cpp`` with its ``gran_sub_mod_*`` files):

==============  ===========================================================================
normal          :class:`Hooke` (``fn = kn delta``), :class:`Hertz` (``fn = kh delta^{3/2}``)
damping         :class:`NoDamping`; :class:`Viscous` (``c = 2 zeta sqrt(m_eff k_n)``, normal
                only) and :class:`ViscousTangential` (the same ``c`` on the tangential relative
                velocity too), restitution-based through :meth:`Viscous.from_restitution`;
                :class:`MassGamma` (LAMMPS: ``c_n = m_eff gamma_n``, ``c_t = m_eff gamma_t``)
tangential      :class:`NoTangential`; :class:`LinearHistory` (constant ``kt``) and
                :class:`Mindlin` (``kt = ratio * k_n(delta)``): a scalar force along the current
                tangent, cap ``mu max(fn, 0)``; :class:`LammpsHistory`: LAMMPS
                ``gran/hooke/history`` (shear displacement vector, slip added then projected on
                the tangent plane, cap ``mu |fn|``)
rolling         :class:`NoRolling`, :class:`RollingResistance` (spring-slider on the relative
                rotation, cap ``mu_r R_eff max(fn, 0)``)
==============  ===========================================================================

Each sub-model is a ``NamedTuple`` of its coefficients (that is what numba receives) with:

* ``check()``: raises ``ValueError`` naming the coefficient and its allowed range;
* ``HISTORY`` (slots per pair in the contact history) and ``PARITY`` (per slot, +1 if the slot is
  unchanged when the pair's i and j are swapped, -1 if it changes sign; used at list rebuilds);
* ``VECTOR``: True if its hooks vectorise well (no branch the compiler cannot turn into a select,
  cheap to evaluate on pairs not in contact); a law whose sub-models all say so runs the
  vectorised pair loop (:func:`pair_forces_chunked`), any other the serial one
  (:func:`pair_forces_serial`), with bit-identical results;
* ``dt_stiffness(normal)``: its stiffness for the critical time step [N/m] (see :mod:`dem.engine.integrate`);
* normal and tangential models: ``tangent(delta)`` (``tangent(normal, delta)``), the tangent
  stiffness [N/m] at overlaps ``delta`` [m]; normal models: ``fn_elastic(delta)``, the elastic
  normal force;
* its numba implementation, registered with the private decorator ``_implements`` for one of the generic hooks
  below (``normal_force``, ``pair_constants``, ``normal_damping``, ``tangential_force``,
  ``rolling_torque``).

:func:`pair_forces` is the pair loop, written once (in two strategies, serial and chunked and
vectorised, that share the law's evaluation ``_law``). numba compiles one specialisation per
combination of sub-model types (the types are part of the signature and the hooks are resolved
at compile time through ``numba.extending.overload``), so a contact never branches on the law at
run time, and the compiled loops are cached on disk like any ``cache=True`` function. A new law
is one new sub-model: see :class:`RollingResistance` (Hertz with rolling resistance,
:class:`dem.engine.contact_laws.HertzRolling`).

Geometry and sign conventions are those of :mod:`dem.engine.contact_laws`. The loop can also integrate
(``kick``): with a fused :class:`Kick` every particle is kicked and drifted as soon as its force is
complete (pairs are ordered by ``i`` and ``j > i``, so particle ``k`` is complete when the loop
reaches the first pair with ``i > k``), which saves a pass over the particle arrays (:class:`Kick`). The
arithmetic per particle is that of :func:`kick_range`, in the same order,
so fused and separate integration give bit-identical trajectories.
"""
from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
import math
import warnings
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.core.errors import NumbaIRAssumptionWarning
from numba.extending import overload

# numba's SSA check flags the branches of the hooks it inlines into the pair loops ("variable ...
# is not in scope"); it is a pedantic internal check, the compiled code is right (the loops are
# tested bit for bit), so this one message is silenced rather than shown at every compilation
warnings.filterwarnings("ignore", message=r"variable '.*' is not in scope", category=NumbaIRAssumptionWarning)

__all__ = ["Hooke", "Hertz", "NoDamping", "Viscous", "ViscousTangential", "MassGamma",
           "NoTangential", "LinearHistory", "Mindlin", "LammpsHistory", "NoRolling",
           "RollingResistance", "Contact", "Load", "Slots", "Tangential", "Rolling", "Bodies", "Forces",
           "Pairs", "Models", "PairInput", "PairForce", "Cell", "Kick", "NO_KICK", "bodies_of", "cell_of",
           "pair_forces", "pair_forces_chunked", "pair_forces_serial", "pair_forces_span",
           "pair_forces_threaded", "vectorises", "compact_list", "make_pair_constants", "kick_range",
           "kick_all", "with_arm_types", "SUBMODELS"]


def _check(name, value, low, *, low_open=False, high=math.inf):
    ok = math.isfinite(value) and (value > low if low_open else value >= low) and value <= high
    if not ok:
        lo = "(" if low_open else "["
        hi = "inf)" if high == math.inf else f"{high:g}]"
        raise ValueError(f"{name} must be in {lo}{low:g}, {hi}, got {value}")


def _check_bool(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")


# --------------------------------------------------------------------------------------------------
# hooks: stubs that the loop calls, resolved at compile time from the sub-model's type
# --------------------------------------------------------------------------------------------------
def _hook(name):
    """A stub the pair loop calls; its implementations are registered with :func:`_implements`."""
    def stub(*args):  # pragma: no cover - only numba calls it
        raise NotImplementedError(name)

    stub.__name__ = stub.__qualname__ = name
    return stub


normal_force = _hook("normal_force")
pair_constant = _hook("pair_constant")
normal_damping = _hook("normal_damping")
tangential_force = _hook("tangential_force")
rolling_torque = _hook("rolling_torque")
force_magnitude = _hook("force_magnitude")
history_slots = _hook("history_slots")
tangential_slots = _hook("tangential_slots")
torque_terms = _hook("torque_terms")


def _implements(hook, *classes):
    """Register ``typer`` as the numba implementation of ``hook`` when its first argument (the
    sub-model) is an instance of one of ``classes``.

    ``typer(model, *args)`` receives the numba types and returns the implementation (numba's
    ``overload`` protocol), so an implementation can specialise on the other models' types, e.g.
    the tangential model on whether the damping has a tangential part."""
    def deco(typer):
        @functools.wraps(typer)
        def guarded(*args):
            return typer(*args) if _cls(args[0]) in classes else None

        overload(hook, jit_options={"cache": True}, inline="always")(guarded)
        return typer
    return deco


def _cls(t):
    return getattr(t, "instance_class", None)


# --------------------------------------------------------------------------------------------------
# normal models: normal_force(model, delta) -> (fn elastic, k_n tangent stiffness, elastic energy)
# --------------------------------------------------------------------------------------------------
class Hooke(NamedTuple):
    """Linear normal spring ``fn = kn delta``, ``kn`` [N/m] (force per unit overlap)."""
    kn: float

    HISTORY = 0
    VECTOR = True
    PARITY = ()

    def check(self):
        _check("kn", self.kn, 0.0, low_open=True)

    def dt_stiffness(self):
        return self.kn

    def tangent(self, delta):
        return np.full_like(np.asarray(delta, dtype=float), self.kn)

    def fn_elastic(self, delta):
        return self.kn * delta

    def stiffness_scale(self):
        """The constant normal stiffness (for stiffnesses given as a ratio of it)."""
        return self.kn


@_implements(normal_force, Hooke)
def _hooke_force(model, delta):
    def impl(model, delta):
        kn = model.kn
        return kn * delta, kn, 0.5 * kn * delta * delta
    return impl


class Hertz(NamedTuple):
    """Hertz normal force ``fn = kh delta^{3/2}`` (``kh`` [N/m^{3/2}]; the 3D sphere form applied
    to disks, as in Yade/LAMMPS 2D runs), tangent ``k_n = 1.5 kh sqrt(delta)``. ``delta_ref`` [m]:
    the overlap at which the tangent stiffness enters the critical time step."""
    kh: float
    delta_ref: float

    HISTORY = 0
    VECTOR = True
    PARITY = ()

    def check(self):
        _check("kh", self.kh, 0.0, low_open=True)
        _check("delta_ref", self.delta_ref, 0.0, low_open=True)

    def dt_stiffness(self):
        return 1.5 * self.kh * math.sqrt(self.delta_ref)

    def tangent(self, delta):
        return 1.5 * self.kh * np.sqrt(np.maximum(delta, 0.0))

    def fn_elastic(self, delta):
        return self.kh * np.maximum(delta, 0.0) ** 1.5

    def stiffness_scale(self):
        return self.dt_stiffness()


@_implements(normal_force, Hertz)
def _hertz_force(model, delta):
    def impl(model, delta):
        kh = model.kh
        sq = math.sqrt(delta)
        return kh * delta * sq, 1.5 * kh * sq, 0.4 * kh * delta * delta * sq
    return impl


# --------------------------------------------------------------------------------------------------
# damping models.
#   pair_constant(model, normal, meff, pc, q): fills the per-pair constants pc[q], pc[q + 1], ...
#       computed at each list build;
#   normal_damping(model, normal, pc, p, k_n, fn, vn) -> (fn with dashpot, tangential c_t).
# --------------------------------------------------------------------------------------------------
class NoDamping(NamedTuple):
    """No contact dashpot."""
    zero: float = 0.0

    NPC = 0
    VECTOR = True
    TANGENTIAL = False

    def check(self):
        pass


@_implements(pair_constant, NoDamping)
def _nodamp_pc(model, normal, meff, pc, q):
    def impl(model, normal, meff, pc, q):
        pass
    return impl


@_implements(normal_damping, NoDamping)
def _nodamp(model, normal, pc, p, kn, fn, vn):
    def impl(model, normal, pc, p, kn, fn, vn):
        return fn, 0.0
    return impl


class Viscous(NamedTuple):
    """Normal dashpot ``c = 2 zeta sqrt(m_eff k_n)`` (damping ratio ``zeta`` in [0, 1)), with
    ``m_eff = m_i m_j / (m_i + m_j)`` and ``k_n`` the normal tangent stiffness; for Hooke ``c`` is a
    per-pair constant computed at list builds, for Hertz ``m_eff`` is."""
    zeta: float

    NPC = 1
    VECTOR = True
    TANGENTIAL = False

    def check(self):
        _check("damping ratio zeta", self.zeta, 0.0, high=1.0)

    @classmethod
    def from_restitution(cls, e):
        """The damping ratio giving the restitution coefficient ``e`` of a linear contact."""
        return cls(damping_ratio(e))


class ViscousTangential(NamedTuple):
    """:class:`Viscous` on the normal and, with the same ``c``, on the tangential relative velocity
    (the Coulomb cap then applies to the total tangential force)."""
    zeta: float

    NPC = 1
    VECTOR = True
    TANGENTIAL = True

    check = Viscous.check

    @classmethod
    def from_restitution(cls, e):
        return cls(damping_ratio(e))


def _viscous_pc(model, normal, meff, pc, q):
    if _cls(normal) is Hooke:
        def impl(model, normal, meff, pc, q):
            pc[q] = 2.0 * model.zeta * math.sqrt(meff * normal.kn)
    else:
        def impl(model, normal, meff, pc, q):
            pc[q] = meff
    return impl


def _viscous(model, normal, pc, p, kn, fn, vn):
    if _cls(normal) is Hooke:
        def impl(model, normal, pc, p, kn, fn, vn):
            c = pc[p]
            return fn - c * vn, c
    else:
        def impl(model, normal, pc, p, kn, fn, vn):
            c = 2.0 * model.zeta * math.sqrt(pc[p] * kn)
            return fn - c * vn, c
    return impl


_implements(pair_constant, Viscous, ViscousTangential)(_viscous_pc)
_implements(normal_damping, Viscous, ViscousTangential)(_viscous)


class MassGamma(NamedTuple):
    """LAMMPS ``gran/*/history`` dashpots: ``c_n = m_eff gamma_n``, ``c_t = m_eff gamma_t``
    (``gamma`` [1/s], one value for all pairs). :meth:`lammps` maps LAMMPS's ``NULL`` gamma_t to
    ``gamma_n / 2`` and its ``dampflag = 0`` to ``gamma_t = 0``."""
    gamma_n: float
    gamma_t: float

    NPC = 2
    VECTOR = True
    TANGENTIAL = True

    def check(self):
        _check("gamma_n", self.gamma_n, 0.0)
        _check("gamma_t", self.gamma_t, 0.0)

    @classmethod
    def lammps(cls, gamma_n, gamma_t=None, dampflag=1):
        """As LAMMPS reads ``pair_style gran/hooke/history kn kt gamma_n gamma_t mu dampflag``."""
        gt = 0.5 * gamma_n if gamma_t is None else gamma_t
        return cls(float(gamma_n), float(gt) if dampflag else 0.0)


@_implements(pair_constant, MassGamma)
def _massgamma_pc(model, normal, meff, pc, q):
    def impl(model, normal, meff, pc, q):
        pc[q] = meff * model.gamma_n
        pc[q + 1] = meff * model.gamma_t
    return impl


@_implements(normal_damping, MassGamma)
def _massgamma(model, normal, pc, p, kn, fn, vn):
    def impl(model, normal, pc, p, kn, fn, vn):
        return fn - pc[2 * p] * vn, pc[2 * p + 1]
    return impl


def damping_ratio(e) -> float:
    """Damping ratio zeta of a linear spring-dashpot giving the restitution coefficient e (0 < e <= 1)."""
    if e is None:
        return 0.0
    if not (0 < e <= 1):
        raise ValueError(f"restitution must be in (0, 1], got {e}")
    le = math.log(e)
    return -le / math.sqrt(math.pi ** 2 + le * le)


# --------------------------------------------------------------------------------------------------
# what the tangential and rolling hooks read and return: named bundles of scalars, built per pair
# inside the loop (numba inlines the hooks, LLVM then keeps the fields in registers: no tuple is
# stored), so that a hook reads ``c.nx`` or ``load.fn`` as a LAMMPS GRANULAR sub-model reads its
# model's ``nx`` and ``Fnormal``, and adding a quantity is one field, not ten signatures.
#
# Arrays a kernel writes are never put in a bundle built inside a kernel (the history ``hist``
# goes beside ``Slots``, not in it): numba's dead-code elimination, which runs when an overload
# is inlined, drops a store into an array it cannot trace back to an argument, and a tuple built
# in the function hides that trace (numba 0.68: ``ir_utils.find_potential_aliases`` follows
# getattr and getitem of arguments, not tuple construction). Array bundles are built in Python or
# in thin entry functions and reach the loops as arguments.
# --------------------------------------------------------------------------------------------------
class Contact(NamedTuple):
    """A pair's kinematics as the tangential and rolling hooks read them (one pair, scalars).
    Lengths [m], velocities [m/s], spins [1/s]; frame of :mod:`dem.engine.contact_laws`."""
    lx: float    #: branch ``l = x_j + h s - x_i``
    ly: float
    d: float     #: ``|l|``
    nx: float    #: unit normal ``n = l / |l|``, from i to j
    ny: float
    ri: float    #: radii
    rj: float
    dvx: float   #: ``v_j - v_i + L l`` (fluctuation velocities plus the cell's affine field)
    dvy: float
    vn: float    #: its normal component ``dv . n``
    wi: float    #: spins
    wj: float


class Load(NamedTuple):
    """The normal stage's results that the tangential and rolling hooks read: ``fn`` the normal
    force on j along n [N/m] (dashpot included, > 0 repulsive), ``kn`` the normal tangent stiffness
    [N/m], ``ct`` the tangential dashpot coefficient [N s/m^2] (0 if the damping has none)."""
    fn: float
    kn: float
    ct: float


class Slots(NamedTuple):
    """Where a sub-model's contact history lives in the flat history array ``hist`` (passed
    beside it): slot k of the pair at ``hist[q + k * hs]`` (``hs`` 1 in the pair-by-pair layout,
    ``CHUNK`` in a chunk's slot-by-slot one)."""
    q: int
    hs: int


class Tangential(NamedTuple):
    """What ``tangential_force`` returns: the tangential force on j ``(fx, fy)`` [N/m], its elastic
    energy ``U`` [J/m], the torque terms ``mi``, ``mj`` [N] (the torques on i and j are ``-mi`` and
    ``-mj``) and ``ok`` (False if a ``fast`` call skipped a rare branch: then the results are
    not valid)."""
    fx: float
    fy: float
    U: float
    mi: float
    mj: float
    ok: bool


class Rolling(NamedTuple):
    """What ``rolling_torque`` returns: its elastic energy ``U`` [J/m] and the torque ``m`` [N] on
    j (``-m`` on i)."""
    U: float
    m: float


# --------------------------------------------------------------------------------------------------
# tangential models.
#   tangential_force(model, damping, c: Contact, load: Load, hist, slots: Slots, dt, fast) -> Tangential
#   the torques of the tangential force on i and j are -mi and -mj (the loop subtracts them, in
#   this order); the pair's history slots are ``slots`` (the tangential model's first). The
#   loop calls it for every pair of the list, in contact or not (it keeps the results of the
#   pairs in contact only and zeroes the others' history), so it must not branch on the contact.
#   ``fast`` (a compile-time constant): the vectorised loop's call, where a model may skip a rare
#   and costly branch and return ``ok = False`` instead; the loop then recomputes that pair with
#   ``fast = False`` from its saved history. Otherwise ``ok`` is True.
# --------------------------------------------------------------------------------------------------
class NoTangential(NamedTuple):
    """No tangential force (no spins needed)."""
    zero: float = 0.0

    HISTORY = 0
    VECTOR = True
    PARITY = ()
    SPIN = False

    def check(self):
        pass

    def dt_stiffness(self, normal):
        return 0.0

    def tangent(self, normal, delta):
        return np.zeros_like(np.asarray(delta, dtype=float))

    @property
    def mu(self):
        return 0.0


@_implements(tangential_force, NoTangential)
def _notang(model, damping, c, load, hist, slots, dt, fast):
    def impl(model, damping, c, load, hist, slots, dt, fast):
        return Tangential(0.0, 0.0, 0.0, 0.0, 0.0, True)
    return impl


@_implements(force_magnitude, NoTangential)
def _notang_mag(model, fn, fx, fy):
    def impl(model, fn, fx, fy):
        return abs(fn)
    return impl


class LinearHistory(NamedTuple):
    """Tangential spring ``kt`` [N/m] with history, Coulomb ``mu``: a scalar force ``ft`` along the
    current tangent ``t`` (the spring turns rigidly with the contact), incremented by
    ``-kt vt dt`` and capped at ``mu max(fn, 0)``; reset when the contact opens.

    ``contact_arms``: the spin arms (in the contact point's velocity ``w_i a_i + w_j a_j`` and in
    the torques ``-a ft``). False: the radii ``a = r`` (LAMMPS ``gran/*``); True: the distances
    to the contact point ``a_i = |l| r_i / (r_i + r_j)`` (as :mod:`microhom.kinematics` and the
    exact stiffness), with ``a_i + a_j = |l|``, so that a rigid rotation of overlapping disks
    slides no contact."""
    kt: float
    mu: float
    contact_arms: bool = False

    HISTORY = 1
    VECTOR = True
    PARITY = (1,)
    SPIN = True

    def check(self):
        _check("kt", self.kt, 0.0)
        _check("mu", self.mu, 0.0)
        _check_bool("contact_arms", self.contact_arms)

    def dt_stiffness(self, normal):
        # rotational modes of disks (I = m r^2 / 2): z contacts resisting one rotation give
        # omega^2 = 4 z kt / m, hence 2 kt
        return 2.0 * self.kt

    def tangent(self, normal, delta):
        return np.full_like(np.asarray(delta, dtype=float), self.kt)


class Mindlin(NamedTuple):
    """As :class:`LinearHistory` (``contact_arms`` included) with the incremental Mindlin stiffness
    ``kt = kt_ratio k_n(delta)``."""
    kt_ratio: float
    mu: float
    contact_arms: bool = False

    HISTORY = 1
    VECTOR = True
    PARITY = (1,)
    SPIN = True

    def check(self):
        _check("kt_ratio", self.kt_ratio, 0.0)
        _check("mu", self.mu, 0.0)
        _check_bool("contact_arms", self.contact_arms)

    def dt_stiffness(self, normal):
        return 2.0 * self.kt_ratio * normal.dt_stiffness()

    def tangent(self, normal, delta):
        return self.kt_ratio * normal.tangent(delta)


# The spin arms are a compile-time choice, as LAMMPS GRANULAR makes them a sub-model: the loops
# receive a LinearHistory or Mindlin whose ``contact_arms`` is True as the private subclass below
# (same fields; :func:`with_arm_types`, applied by the laws when they compose their ``models`` and
# by :func:`pair_forces`), so numba compiles the pair loop once per choice and the default, radius
# arms, does not execute the arm division ``|l| / (r_i + r_j)``: the vectorised loop used to
# compute it for every pair and select (measured in docs/dem.md). It has to be a Python class:
# numba's dispatcher keys a tuple argument on its class and its fields' types, not their values.
# Every hook of the scalar models is registered for the subclasses too (``_implements`` matches
# exact classes).
class _LinearHistoryArms(LinearHistory):
    """A :class:`LinearHistory` with ``contact_arms=True`` as the pair loop receives it."""
    __slots__ = ()


class _MindlinArms(Mindlin):
    """A :class:`Mindlin` with ``contact_arms=True`` as the pair loop receives it."""
    __slots__ = ()


_WITH_ARMS = {LinearHistory: _LinearHistoryArms, Mindlin: _MindlinArms}
#: the scalar-history tangential models as the loops see them (with and without contact arms)
_SCALAR = (LinearHistory, Mindlin, _LinearHistoryArms, _MindlinArms)


def with_arm_types(models):
    """``models`` (:class:`Models`) with a LinearHistory or Mindlin whose ``contact_arms`` is True
    replaced by its arms subclass (equal as a tuple, an instance of the same class), the form the
    loops are compiled for; ``models`` itself when there is nothing to replace."""
    t = models.tangential
    arms = _WITH_ARMS.get(type(t))
    if arms is None or not t.contact_arms:
        return models
    return models._replace(tangential=arms(*t))


@njit(cache=True, inline="always")
def _coulomb_scalar(fs, lim, ct, vt, with_damping):
    """Scalar Coulomb cap. Returns (spring force kept in the history, total tangential force)."""
    if with_damping:
        ftot = fs - ct * vt
        if abs(ftot) > lim:
            ftot = lim if ftot > 0.0 else -lim
            fs = ftot + ct * vt
        return fs, ftot
    if abs(fs) > lim:
        fs = lim if fs > 0.0 else -lim
    return fs, fs


def _scalar_tangential(model, damping, c, load, hist, slots, dt, fast):
    tdamp = bool(_cls(damping).TANGENTIAL)
    mindlin = issubclass(_cls(model), Mindlin)
    arms = _cls(model) in (_LinearHistoryArms, _MindlinArms)  # compile-time: see with_arm_types

    def impl(model, damping, c, load, hist, slots, dt, fast):
        tx = -c.ny
        ty = c.nx
        ri = c.ri
        rj = c.rj
        ai = ri
        aj = rj
        if arms:
            s = c.d / (ri + rj)
            ai = s * ri
            aj = s * rj
        vt = c.dvx * tx + c.dvy * ty - (c.wi * ai + c.wj * aj)
        if mindlin:
            kt = model.kt_ratio * load.kn
        else:
            kt = model.kt
        fn = load.fn
        fc = fn if fn > 0.0 else 0.0
        lim = model.mu * fc
        q = slots.q
        fs, ftot = _coulomb_scalar(hist[q] - kt * vt * dt, lim, load.ct, vt, tdamp)
        hist[q] = fs
        U = 0.5 * fs * fs / kt if kt > 0.0 else 0.0
        return Tangential(ftot * tx, ftot * ty, U, ai * ftot, aj * ftot, True)
    return impl


def _frictional_mag(model, fn, fx, fy):
    def impl(model, fn, fx, fy):
        return math.sqrt(fx * fx + fy * fy)
    return impl


class LammpsHistory(NamedTuple):
    """LAMMPS ``gran/hooke/history`` tangential rule (``pair_gran_hooke_history.cpp``): the shear
    displacement vector ``s`` (history, 2 slots) gets the slip ``vt dt`` added, is then projected
    on the current tangent line (which shrinks it by ``cos`` of the contact's rotation since the
    last step), the force ``-(kt s + c_t vt)`` is capped at ``mu |fn|`` (``fn`` including the
    dashpot, so a tensile dashpot force still allows friction) by rescaling ``s``. ``kt`` > 0
    [N/m]. With ``dt = 0`` (LAMMPS' setup force call) neither the slip nor the projection is
    applied."""
    kt: float
    mu: float

    HISTORY = 2
    VECTOR = True  # its slip branch (a sqrt, three divisions) is left to the exact path (``fast``)
    PARITY = (-1, -1)
    SPIN = True

    def check(self):
        _check("kt", self.kt, 0.0, low_open=True)
        _check("mu", self.mu, 0.0)

    dt_stiffness = LinearHistory.dt_stiffness
    tangent = LinearHistory.tangent


@_implements(tangential_force, LammpsHistory)
def _lammps_tangential(model, damping, c, load, hist, slots, dt, fast):
    # Written in this project's frame (branch l = x_j - x_i, relative velocity of j w.r.t. i): every
    # quantity is the negative of LAMMPS's (del = x_i - x_j, v_i - v_j), the pair's history slots
    # hold minus LAMMPS's shear. The operations are LAMMPS's with the unit normal n = del / r in
    # place of del and 1/r^2 (fewer divisions), the slip test |fs| > mu |fn| on squares and
    # |shear| != 0 as |shear|^2 != 0: round-off is all that changes
    # (tests/test_lammps_equivalence.py bounds it by LAMMPS' own newton on/off round-off).
    def impl(model, damping, c, load, hist, slots, dt, fast):
        kt = model.kt
        nx = c.nx
        ny = c.ny
        vn = c.vn
        ri = c.ri
        rj = c.rj
        ct = load.ct
        q = slots.q
        hs = slots.hs
        # LAMMPS: vn = del (v . del) / r^2, vtr = vt - del x (r_i w_i + r_j w_j) z / r
        vt1 = c.dvx - nx * vn
        vt2 = c.dvy - ny * vn
        ws = ri * c.wi + rj * c.wj
        vtr1 = vt1 + ny * ws
        vtr2 = vt2 - nx * ws
        s1 = hist[q]
        s2 = hist[q + hs]
        if dt > 0.0:
            s1 += vtr1 * dt
            s2 += vtr2 * dt
        shr2 = s1 * s1 + s2 * s2
        if dt > 0.0:
            rsht = s1 * nx + s2 * ny
            s1 -= rsht * nx
            s2 -= rsht * ny
        fs1 = -(kt * s1 + ct * vtr1)
        fs2 = -(kt * s2 + ct * vtr2)
        fs2sum = fs1 * fs1 + fs2 * fs2
        lim = model.mu * abs(load.fn)
        ok = True
        if fast:
            # the vectorised loop: a sliding contact is flagged and recomputed by the exact path
            ok = not fs2sum > lim * lim
        elif fs2sum > lim * lim:
            # (LAMMPS compares |fs| > lim and tests the shear magnitude before the projection)
            if shr2 != 0.0:
                r = lim / math.sqrt(fs2sum)
                a1 = ct * vtr1 / kt
                a2 = ct * vtr2 / kt
                s1 = r * (s1 + a1) - a1
                s2 = r * (s2 + a2) - a2
                fs1 *= r
                fs2 *= r
            else:
                fs1 = 0.0
                fs2 = 0.0
        hist[q] = s1
        hist[q + hs] = s2
        tor = nx * fs2 - ny * fs1
        return Tangential(fs1, fs2, 0.5 * kt * (s1 * s1 + s2 * s2), ri * tor, rj * tor, ok)
    return impl


_implements(tangential_force, *_SCALAR)(_scalar_tangential)
_implements(force_magnitude, *_SCALAR, LammpsHistory)(_frictional_mag)


def _history_slots(model, rolling):
    n = int(_cls(model).HISTORY + _cls(rolling).HISTORY)

    def impl(model, rolling):
        return n
    return impl


_implements(history_slots, NoTangential, *_SCALAR, LammpsHistory)(_history_slots)


def _tangential_slots(model):
    n = int(_cls(model).HISTORY)

    def impl(model):
        return n
    return impl


_implements(tangential_slots, NoTangential, *_SCALAR, LammpsHistory)(_tangential_slots)


# --------------------------------------------------------------------------------------------------
# rolling resistance: rolling_torque(model, c: Contact, load: Load, hist, slots: Slots, dt) -> Rolling
#   its slots are ``slots`` of ``hist`` (after the tangential model's); returns its elastic energy and the
#   torque m on j (-m on i), which the loop applies after the tangential torques.
# --------------------------------------------------------------------------------------------------
class NoRolling(NamedTuple):
    """No rolling resistance."""
    zero: float = 0.0

    HISTORY = 0
    VECTOR = True
    PARITY = ()

    def check(self):
        pass

    def dt_stiffness(self, normal):
        return 0.0


@_implements(rolling_torque, NoRolling)
def _noroll(model, c, load, hist, slots, dt):
    def impl(model, c, load, hist, slots, dt):
        return Rolling(0.0, 0.0)
    return impl


class RollingResistance(NamedTuple):
    """Elastic-plastic rolling resistance: a torque ``M`` (on j; ``-M`` on i) with history,
    incremented by ``-k_r (omega_j - omega_i) dt`` and capped at ``|M| <= mu_r R_eff max(fn, 0)``,
    ``R_eff = r_i r_j / (r_i + r_j)``, ``k_r = kr_ratio k_n(delta) R_eff^2``. A disk rolling without
    slip on another (``omega_j r_j = -omega_i r_i`` for a fixed pair axis) turns at a relative rate
    ``omega_j - omega_i != 0`` and is resisted; a rigid rotation of the pair is not."""
    kr_ratio: float
    mu_r: float

    HISTORY = 1
    VECTOR = False  # measured slower vectorised (docs/dem.md)
    PARITY = (-1,)

    def check(self):
        _check("kr_ratio", self.kr_ratio, 0.0)
        _check("mu_r", self.mu_r, 0.0)

    def dt_stiffness(self, normal):
        # k_r <= kr_ratio k_n r_i^2 (R_eff <= r_i), I_i = m_i r_i^2 / 2: as a tangential spring 2 kr_ratio k_n
        return 2.0 * self.kr_ratio * normal.dt_stiffness()


@_implements(rolling_torque, RollingResistance)
def _roll(model, c, load, hist, slots, dt):
    def impl(model, c, load, hist, slots, dt):
        q = slots.q
        ri = c.ri
        rj = c.rj
        fn = load.fn
        reff = ri * rj / (ri + rj)
        kr = model.kr_ratio * load.kn * reff * reff
        fc = fn if fn > 0.0 else 0.0
        lim = model.mu_r * reff * fc
        m = hist[q] - kr * (c.wj - c.wi) * dt
        if abs(m) > lim:
            m = lim if m > 0.0 else -lim
        hist[q] = m
        U = 0.5 * m * m / kr if kr > 0.0 else 0.0
        return Rolling(U, m)
    return impl


# --------------------------------------------------------------------------------------------------
# the bundles of the loops: what the pair loop and the kick read and write
# --------------------------------------------------------------------------------------------------
class Bodies(NamedTuple):
    """The particle arrays of the pair loop and the kick (a view of :class:`dem.engine.state.State`).
    Inside the loops ``x``, ``v`` and ``x_ref`` are flat (2N,) views."""
    x: np.ndarray        #: (N, 2) positions [m]
    v: np.ndarray        #: (N, 2) fluctuation velocities [m/s] (the total is ``v + L x``)
    omega: np.ndarray    #: (N,) spins [1/s], or empty without spins
    theta: np.ndarray    #: (N,) rotations, or empty
    radius: np.ndarray   #: (N,) [m]
    mass: np.ndarray     #: (N,) [kg/m]
    inertia: np.ndarray  #: (N,) [kg m], or empty
    x_ref: np.ndarray    #: (N, 2) positions at the last list build (the rebuild test)


class Forces(NamedTuple):
    """What the pair loop writes: ``f`` (N, 2) contact forces [N/m], ``torque`` (N,) [N] (empty
    without spins), ``out`` (8,) the tallies (:mod:`dem.engine.contact_laws`), ``acc`` (5,) the sums of
    :func:`kick_range` of a fused kick. Inside the loops ``f`` is a flat (2N,) view."""
    f: np.ndarray
    torque: np.ndarray
    out: np.ndarray
    acc: np.ndarray


class Pairs(NamedTuple):
    """The Verlet list as the pair loop reads it (:func:`compact_list`: ``pi``, ``jc`` (P,) int32,
    ordered by i, ``j > i``), with the contact history ``hist`` (P * H,) flat (H slots per pair,
    the tangential model's then the rolling model's) and the damping model's per-pair constants
    ``pc`` (P * NPC,)."""
    pi: np.ndarray
    jc: np.ndarray
    hist: np.ndarray
    pc: np.ndarray


class Models(NamedTuple):
    """The four sub-models of a law (``law.models``), the types the pair loop is compiled for."""
    normal: tuple
    damping: tuple
    tangential: tuple
    rolling: tuple


class PairInput(NamedTuple):
    """What the loops gather for a pair before the law: branch ``(lx, ly)`` and ``d2 = |l|^2``,
    radii, ``v_j - v_i`` (fluctuation velocities) and spins."""
    lx: float
    ly: float
    d2: float
    ri: float
    rj: float
    vx: float
    vy: float
    wi: float
    wj: float


class PairForce(NamedTuple):
    """The law's result on a pair (``_law``): the force on j ``(fx, fy)`` [N/m]; the torque terms
    ``mi``, ``mj``, ``mr`` [N] (torques ``-mi - mr`` on i and ``-mj + mr`` on j, subtracted and
    added in this order); the elastic energies ``Un``, ``Ut``, ``Ur`` [J/m]; the normal force
    ``fn`` and tangent stiffness ``kn``; ``ok`` False if a ``fast`` call skipped a rare branch."""
    fx: float
    fy: float
    mi: float
    mj: float
    mr: float
    Un: float
    Ut: float
    Ur: float
    fn: float
    kn: float
    ok: bool


class Layout(NamedTuple):
    """Compile-time constants of a law: spins, tangential torques, rolling torques, history slots."""
    spin: bool
    tq_t: bool
    tq_r: bool
    nh: int


class Cell(NamedTuple):
    """Velocity gradient L and shape matrix h of the cell, by entries."""
    L00: float
    L01: float
    L10: float
    L11: float
    h00: float
    h01: float
    h10: float
    h11: float


def bodies_of(state, spin):
    """The :class:`Bodies` of a :class:`dem.engine.state.State` (spins, rotations, inertias empty unless
    ``spin``) as a plain tuple in field order, the fast form for the kernels (see
    :func:`pair_forces`)."""
    e = _EMPTY
    return (state.x, state.v, state.omega if spin else e, state.theta if spin else e, state.radius, state.mass,
            state.inertia if spin else e, state.x_ref)


def cell_of(h, L):
    """The :class:`Cell` of shape matrix ``h`` and velocity gradient ``L`` ((2, 2) arrays), as a
    plain tuple in field order (the fast form for the kernels)."""
    return (L[0, 0], L[0, 1], L[1, 0], L[1, 1], h[0, 0], h[0, 1], h[1, 0], h[1, 1])


_EMPTY = np.zeros(0)


# --------------------------------------------------------------------------------------------------
# integration hooks (fused kick)
# --------------------------------------------------------------------------------------------------
class Kick(NamedTuple):
    """Integration inside the force loop (``fused``): kick step ``dtk``, drift step ``dt``, Cundall
    ``damping``, the cell's ``L`` and the deformation ``F = h_{n+1} h_ref^{-1}`` of the rebuild
    test; ``tally``: sum the kinetic energy. ``fused = False``: the loop computes forces only."""
    fused: bool
    dtk: float
    dt: float
    damping: float
    L00: float
    L01: float
    L10: float
    L11: float
    F00: float
    F01: float
    F10: float
    F11: float
    tally: bool = True


NO_KICK = Kick(False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, False)


KICK_BLOCK = 64


#: particles per block of :func:`kick_range` (its scratch rows stay in the L1 cache)
KICK_CHUNK = 256
# rows of the kick's scratch (flat, offsets as unsigned constants): per particle, the squared
# non-affine displacement, the kinetic-energy and damping-work terms of x, y and the spin
_KD2, _KEX, _KEY, _KWX, _KWY, _KER, _KWR = (np.uint64(KICK_CHUNK * k) for k in range(7))
KICK_SCRATCH = 7 * KICK_CHUNK


@njit(cache=True, inline="always")
def _kick_dof(F, vo, m, dtk, dt, damping):
    """One degree of freedom of :func:`kick_range` (a velocity component with its mass, or a spin
    with its inertia): the new velocity ``vo + dtk (F + F_damp) / m`` with the Cundall damping
    ``F_damp = -damping |F| sign(vo)``, the kinetic-energy term ``m vm^2 / 2`` at the integer time
    (``vm`` the mean of the old and new velocities) and the damping-work term ``F_damp vm dt``."""
    Fd = 0.0
    if damping > 0.0:
        if vo > 0.0:
            Fd = -damping * abs(F)
        elif vo < 0.0:
            Fd = damping * abs(F)
    vn = vo + dtk * (F + Fd) / m
    vm = 0.5 * (vo + vn)
    return vn, 0.5 * m * vm * vm, Fd * vm * dt


@njit(cache=True, inline="always")
def _kick_trans(b0, b1, xf, vf, ff, rf, mass, kick, terms, kb):
    """The translational updates of particles b0..b1-1 of :func:`kick_range` (no reduction:
    vectorised), the squared non-affine displacements into ``kb`` and, if ``terms`` (a constant
    where inlined), the kinetic-energy and damping-work terms. The arrays come as arguments, not
    in a bundle: see :func:`kick_range`."""
    dtk = kick.dtk
    dt = kick.dt
    damping = kick.damping
    L00, L01, L10, L11 = kick.L00, kick.L01, kick.L10, kick.L11
    F00, F01, F10, F11 = kick.F00, kick.F01, kick.F10, kick.F11
    one = np.uint64(1)
    for k in range(b0, b1):
        q = k - b0
        k2 = k + k
        m = mass[k]
        v0, ex, wx = _kick_dof(ff[k2], vf[k2], m, dtk, dt, damping)
        v1, ey, wy = _kick_dof(ff[k2 + one], vf[k2 + one], m, dtk, dt, damping)
        vf[k2] = v0
        vf[k2 + one] = v1
        x0 = xf[k2]
        x1 = xf[k2 + one]
        y0 = x0 + dt * (v0 + L00 * x0 + L01 * x1)
        y1 = x1 + dt * (v1 + L10 * x0 + L11 * x1)
        xf[k2] = y0
        xf[k2 + one] = y1
        r0 = rf[k2]
        r1 = rf[k2 + one]
        dx = y0 - (F00 * r0 + F01 * r1)
        dy = y1 - (F10 * r0 + F11 * r1)
        kb[_KD2 + q] = dx * dx + dy * dy
        if terms:
            kb[_KEX + q] = ex
            kb[_KEY + q] = ey
            kb[_KWX + q] = wx
            kb[_KWY + q] = wy


@njit(cache=True, inline="always")
def _kick_spin(b0, b1, omega, theta, torque, inertia, kick, terms, kb):
    """The rotational updates of particles b0..b1-1 of :func:`kick_range`, their terms into ``kb``
    if ``terms`` (as :func:`_kick_trans`)."""
    dtk = kick.dtk
    dt = kick.dt
    damping = kick.damping
    for k in range(b0, b1):
        q = k - b0
        wn, er, wr = _kick_dof(torque[k], omega[k], inertia[k], dtk, dt, damping)
        omega[k] = wn
        theta[k] += dt * wn
        if terms:
            kb[_KER + q] = er
            kb[_KWR + q] = wr


@njit(cache=True, error_model="numpy")
def kick_range(lo, hi, fb, fo, kick, sums, kb):
    """Kick and drift particles lo..hi-1 (``fb``: :class:`Bodies` with flat (2N,) x, v, x_ref;
    ``fo``: :class:`Forces` with a flat f), then their spins if ``fb.omega`` is not empty:

    * ``v += dtk (F + F_damp) / m``, ``x += dt (v + L x)`` with the Cundall damping
      ``F_damp,c = -damping |F_c| sign(v_c)`` per component;
    * ``omega += dtk (T + T_damp) / I``, ``theta += dt omega``.

    ``sums`` = (max non-affine displacement^2 ``|x - F x_ref|^2``, translational KE at the integer
    time, its damping work, rotational KE, its damping work) is returned updated; the kinetic
    energies only if ``kick.tally``, the damping work only if ``kick.damping > 0`` (it is 0
    otherwise). ``kb``: scratch of ``KICK_SCRATCH`` floats.

    The particles go in blocks of ``KICK_CHUNK`` (256): the updates of a block have no reduction,
    so the compiler vectorises them (their terms of the sums go to the scratch rows), then the
    sums are added to particle by particle, in order, so that any split into blocks or ranges
    gives the same bits as one pass.
    """
    # The arrays leave their bundles here, once per call: a field read inside the loop over blocks
    # (as an inlined helper taking the bundles does) is a new reference, and numba's reference
    # counting then put about 30 atomic NRT_incref/NRT_decref calls into every block, which also
    # kept LLVM from unswitching the loop (10-16 % of the kick; see docs/dem.md, throughput).
    xf, vf, rf, mass, ff = fb.x, fb.v, fb.x_ref, fb.mass, fo.f
    omega, theta, torque, inertia = fb.omega, fb.theta, fo.torque, fb.inertia
    d2m, ke, wd, ker, wdr = sums
    damping = kick.damping
    tally = kick.tally
    spins = omega.shape[0] > 0
    terms = tally or damping > 0.0
    a = np.uint64(lo)
    z = np.uint64(hi)
    for b0 in range(a, z, np.uint64(KICK_CHUNK)):
        b1 = min(z, b0 + np.uint64(KICK_CHUNK))
        if terms:
            _kick_trans(b0, b1, xf, vf, ff, rf, mass, kick, True, kb)
            if spins:
                _kick_spin(b0, b1, omega, theta, torque, inertia, kick, True, kb)
        else:
            _kick_trans(b0, b1, xf, vf, ff, rf, mass, kick, False, kb)
            if spins:
                _kick_spin(b0, b1, omega, theta, torque, inertia, kick, False, kb)
        for q in range(b1 - b0):
            d2 = kb[_KD2 + q]
            if d2 > d2m:
                d2m = d2
            if tally:
                ke += kb[_KEX + q]
                ke += kb[_KEY + q]
            if damping > 0.0:
                wd += kb[_KWX + q]
                wd += kb[_KWY + q]
            if spins:
                if tally:
                    ker += kb[_KER + q]
                if damping > 0.0:
                    wdr += kb[_KWR + q]
    return d2m, ke, wd, ker, wdr


@njit(cache=True, inline="always")
def _flat(bodies, forces):
    """The bundles with flat (2N,) views of x, v, x_ref and f."""
    b = bodies
    fb = Bodies(b.x.reshape(-1), b.v.reshape(-1), b.omega, b.theta, b.radius, b.mass, b.inertia,
                b.x_ref.reshape(-1))
    return fb, Forces(forces.f.reshape(-1), forces.torque, forces.out, forces.acc)


@njit(cache=True)
def kick_all(bodies, forces, kick):
    """:func:`kick_range` over every particle of ``bodies`` (:class:`Bodies`) with the forces and
    torques of ``forces`` (:class:`Forces`) and the :class:`Kick` ``kick``. Returns its five sums.
    (In this module, next to :func:`kick_range`: numba's disk cache of a function is invalidated
    by changes to its own file only.) The bundles may come as plain tuples in field order, which
    numba types faster (see :func:`pair_forces`)."""
    fb, fo = _flat(Bodies(*bodies), Forces(*forces))
    return kick_range(0, fb.mass.shape[0], fb, fo, Kick(*kick), (0.0, 0.0, 0.0, 0.0, 0.0), np.empty(KICK_SCRATCH))


# --------------------------------------------------------------------------------------------------
# the pair loop
# --------------------------------------------------------------------------------------------------
SHIFT_BITS = 4


@njit(cache=True)
def compact_list(pi, pj, ps):
    """The Verlet list (ordered by ``pi``, ``pj > pi``, image shifts in {-1, 0, 1}) as the pair
    loop reads it, 8 bytes per pair instead of 32: ``pi32`` (P,) int32 and ``jc`` (P,) int32
    ``pj << SHIFT_BITS | code`` with ``code = 3 (s_a + 1) + (s_b + 1)``. Returns
    ``(pi32, jc, ok)``, ``ok = False`` if the list is not ordered by ``pi`` (the fused kick needs
    that order) or has a shift outside {-1, 0, 1}."""
    m = pi.shape[0]
    pi32 = np.empty(m, np.int32)
    jc = np.empty(m, np.int32)
    ok = True
    for p in range(m):
        i = pi[p]
        if p > 0 and i < pi[p - 1]:
            ok = False
        sa = ps[p, 0]
        sb = ps[p, 1]
        if sa < -1 or sa > 1 or sb < -1 or sb > 1:
            ok = False
        pi32[p] = np.int32(i)
        jc[p] = np.int32((pj[p] << SHIFT_BITS) | (3 * (sa + 1) + (sb + 1)))
    return pi32, jc, ok


@njit(cache=True, inline="always")
def _image_offsets(h00, h01, h10, h11):
    """(36,) per shift code: h00 s_a, h01 s_b, h10 s_a, h11 s_b (the branch is summed in this order)."""
    o = np.empty(36)
    for c in range(9):
        sa = float(c // 3 - 1)
        sb = float(c % 3 - 1)
        o[4 * c] = h00 * sa
        o[4 * c + 1] = h01 * sb
        o[4 * c + 2] = h10 * sa
        o[4 * c + 3] = h11 * sb
    return o


def _torque_terms(model, rolling):
    flags = (bool(_cls(model).SPIN), _cls(rolling) is not NoRolling)

    def impl(model, rolling):
        return flags
    return impl


_implements(torque_terms, NoTangential, *_SCALAR, LammpsHistory)(_torque_terms)

#: pairs per chunk of :func:`pair_forces_chunked` (its scratch rows stay in the L1 cache)
CHUNK = 128
# scratch of a chunk, flat (rows of CHUNK: one-dimensional indexing is what the compiler vectorises):
# gathered inputs, per-pair results, tally terms; the offsets of the rows
(_LX, _LY, _RI, _RJ, _VX, _VY, _WI, _WJ, _FX, _FY, _MI, _MJ, _MR, _TOUCH, _UN, _UT, _UR, _FM, _KD,
 _NROWS) = (CHUNK * k for k in range(20))


@njit(cache=True, inline="always")
def _branch(p, pi, jc, xf, off):
    """(i, j, 2i, 2j, lx, ly) of pair p: the branch ``l = x_j + h s - x_i`` summed as
    ``((x_j + h00 s_a) + h01 s_b) - x_i``. Unsigned indices: numba then skips its negative-index
    wraparound on every access."""
    one = np.uint64(1)
    i = np.uint64(np.uint32(pi[p]))
    c = np.uint32(jc[p])
    j = np.uint64(c >> np.uint32(SHIFT_BITS))
    o = np.uint64(4) * np.uint64(c & np.uint32((1 << SHIFT_BITS) - 1))
    i2 = i + i
    j2 = j + j
    lx = xf[j2] + off[o] + off[o + one] - xf[i2]
    ly = xf[j2 + one] + off[o + np.uint64(2)] + off[o + np.uint64(3)] - xf[i2 + one]
    return i, j, i2, j2, lx, ly


@njit(cache=True, inline="always")
def _slot0(p, nh, hs):
    """Index of the first history slot of pair p of a chunk: ``p`` in the slot-by-slot layout
    (``hs = CHUNK``, more than one slot), ``nh p`` in the pair-by-pair one (``hs = 1``)."""
    return p if hs > 1 else nh * p


@njit(cache=True, inline="always")
def _law(g, hist, slots, pc, p, cell, models, dt, fast):
    """The contact law on a pair (:class:`PairInput` ``g``; per-pair constants ``pc[p]``; history
    :class:`Slots` of ``hist``, the tangential model's first), with the cell's ``L``. Returns a
    :class:`PairForce`; with ``fast`` (a compile-time constant) a tangential model may skip a rare
    branch and flag it (``ok`` False; see ``tangential_force``)."""
    lx = g.lx
    ly = g.ly
    rs = g.ri + g.rj
    d = math.sqrt(g.d2)
    nx = lx / d
    ny = ly / d
    delta = rs - d
    dvx = g.vx + cell.L00 * lx + cell.L01 * ly
    dvy = g.vy + cell.L10 * lx + cell.L11 * ly
    normal, damping, tangential, rolling = models
    fn, kn, Un = normal_force(normal, delta)
    vn = dvx * nx + dvy * ny
    fn, ct = normal_damping(damping, normal, pc, p, kn, fn, vn)
    c = Contact(lx, ly, d, nx, ny, g.ri, g.rj, dvx, dvy, vn, g.wi, g.wj)
    load = Load(fn, kn, ct)
    t = tangential_force(tangential, damping, c, load, hist, slots, dt, fast)
    r = rolling_torque(rolling, c, load, hist, Slots(slots.q + tangential_slots(tangential) * slots.hs, slots.hs),
                       dt)
    fx = fn * nx + t.fx
    fy = fn * ny + t.fy
    return PairForce(fx, fy, t.mi, t.mj, r.m, Un, t.U, r.U, fn, kn, t.ok)


@njit(cache=True, inline="always")
def _apply(i, j, fx, fy, mi, mj, mr, lay, ff, torque):
    """Add a pair's force (fx, fy on j, the opposite on i) and torques (:class:`PairForce`'s
    terms) to the particles' flat (2N,) forces ``ff`` and torques, as :class:`Layout` ``lay``
    says."""
    one = np.uint64(1)
    i2 = i + i
    j2 = j + j
    if lay.spin:
        ti = torque[i]
        tj = torque[j]
        if lay.tq_t:
            ti -= mi
            tj -= mj
        if lay.tq_r:
            tj += mr
            ti -= mr
        torque[i] = ti
        torque[j] = tj
    ff[j2] += fx
    ff[j2 + one] += fy
    ff[i2] -= fx
    ff[i2 + one] -= fy


@njit(cache=True, inline="always")
def _gather(p0, m, pairs, fb, off, spin, ij, buf):
    """Pass 1 of a chunk: the branches, radii, ``v_j - v_i`` and spins of pairs p0..p0+m-1,
    gathered into contiguous rows of ``buf`` (and i, j into ``ij``)."""
    one = np.uint64(1)
    pi, jc, xf, vf, radius, omega = pairs.pi, pairs.jc, fb.x, fb.v, fb.radius, fb.omega
    for q in range(m):
        i, j, i2, j2, lx, ly = _branch(p0 + q, pi, jc, xf, off)
        buf[_LX + q] = lx
        buf[_LY + q] = ly
        buf[_RI + q] = radius[i]
        buf[_RJ + q] = radius[j]
        buf[_VX + q] = vf[j2] - vf[i2]
        buf[_VY + q] = vf[j2 + one] - vf[i2 + one]
        if spin:
            buf[_WI + q] = omega[i]
            buf[_WJ + q] = omega[j]
        ij[q] = i
        ij[CHUNK + q] = j


@njit(cache=True, inline="always")
def _store(buf, p, r, d2, tangential, tally):
    """Pair p's :class:`PairForce` ``r`` into its rows of the chunk's scratch (the tally terms
    only if ``tally``)."""
    buf[_FX + p] = r.fx
    buf[_FY + p] = r.fy
    buf[_MI + p] = r.mi
    buf[_MJ + p] = r.mj
    buf[_MR + p] = r.mr
    if tally:
        buf[_UN + p] = r.Un
        buf[_UT + p] = r.Ut
        buf[_UR + p] = r.Ur
        buf[_FM + p] = force_magnitude(tangential, r.fn, r.fx, r.fy)
        buf[_KD + p] = r.kn * d2


@njit(cache=True, inline="always")
def _gathered(buf, p, lx, ly, d2):
    """Pair p's :class:`PairInput` from the chunk's rows."""
    return PairInput(lx, ly, d2, buf[_RI + p], buf[_RJ + p], buf[_VX + p], buf[_VY + p], buf[_WI + p],
                     buf[_WJ + p])


@njit(cache=True, inline="always")
def _contact_forces(m, hist, hs, pc, cell, models, dt, tally, buf):
    """Pass 2 of a chunk of m pairs (``hist``: the chunk's history, slot k of pair p at
    ``hist[_slot0(p, nh, hs) + k hs]``; ``pc``: the chunk's pair constants): the contact law on
    every pair, without a branch on the contact, so that the compiler vectorises it. The pairs
    not in contact get zero history and a zero ``_TOUCH`` row (pass 3 skips them). ``tally`` (a
    constant where this is inlined) also stores the energy, force-magnitude and stiffness terms.
    A pair whose tangential model skipped a rare branch (``ok`` False) is marked 2 in ``_TOUCH``."""
    nh = history_slots(models.tangential, models.rolling)
    for p in range(m):
        lx = buf[_LX + p]
        ly = buf[_LY + p]
        ri = buf[_RI + p]
        rj = buf[_RJ + p]
        rs = ri + rj
        d2 = lx * lx + ly * ly
        touch = d2 < rs * rs
        r = _law(_gathered(buf, p, lx, ly, d2), hist, Slots(_slot0(p, nh, hs), hs), pc, p, cell, models, dt, True)
        for k in range(nh):
            h = _slot0(p, nh, hs) + k * hs
            hist[h] = hist[h] if touch else 0.0
        _store(buf, p, r, d2, models.tangential, tally)
        buf[_TOUCH + p] = (1.0 if r.ok else 2.0) if touch else 0.0


@njit(cache=True, inline="always")
def _exact(p, hist, hs, hbak, pc, cell, models, dt, tally, buf):
    """Pass 3's exact path for pair p of a chunk marked 2 by pass 2: its history back from
    ``hbak`` (the chunk's history before pass 2), the law evaluated with ``fast = False`` (the
    serial loop's operations), its rows of ``buf`` overwritten."""
    nh = history_slots(models.tangential, models.rolling)
    for k in range(nh):
        h = _slot0(p, nh, hs) + k * hs
        hist[h] = hbak[h]
    lx = buf[_LX + p]
    ly = buf[_LY + p]
    d2 = lx * lx + ly * ly
    r = _law(_gathered(buf, p, lx, ly, d2), hist, Slots(_slot0(p, nh, hs), hs), pc, p, cell, models, dt, False)
    _store(buf, p, r, d2, models.tangential, tally)


@njit(cache=True, inline="always")
def _begin(cell, forces):
    """Clear the forces and torques; the image offsets."""
    forces.f[:, :] = 0.0
    forces.torque[:] = 0.0
    return _image_offsets(cell.h00, cell.h01, cell.h10, cell.h11)


@njit(cache=True, inline="always")
def _layout(models):
    """The :class:`Layout` of a law: compile-time constants (spins exactly when some sub-model
    exerts a torque)."""
    tq_t, tq_r = torque_terms(models.tangential, models.rolling)
    return Layout(tq_t or tq_r, tq_t, tq_r, history_slots(models.tangential, models.rolling))


@njit(cache=True, inline="always")
def _tally_add(t, Un, Ut, Ur, fx, fy, lx, ly, fm, kd):
    """The tallies t = (s00, s01, s10, s11, nc, fsum, U, kl2) with one contact added: its energies,
    ``f (x) l`` [N m], one contact, ``|f|`` and ``k_n |l|^2`` (in the serial loop's order)."""
    s00, s01, s10, s11, nc, fsum, U, kl2 = t
    U += Un
    U += Ut
    U += Ur
    return s00 + fx * lx, s01 + fx * ly, s10 + fy * lx, s11 + fy * ly, nc + 1.0, fsum + fm, U, kl2 + kd


@njit(cache=True, inline="always")
def _end(done, fb, fo, forces, kick, sums, kb, tally, t):
    """A fused kick's last particles (from ``done``; ``fb``, ``fo`` the flat bundles) and its sums
    into ``forces.acc``; the tallies ``t`` into ``forces.out[:8]``."""
    if kick.fused:
        sums = kick_range(done, np.uint64(fb.mass.shape[0]), fb, fo, kick, sums, kb)
        for k in range(5):
            forces.acc[k] = sums[k]
    if tally:
        for k in range(8):
            forces.out[k] = t[k]


_PAIR_FORCES_DOC = """Contact forces (and, with ``kick``, the integration) of one step.

    bodies: :class:`Bodies` (x, v (N, 2); omega, theta, inertia (N,) or empty); pairs:
    :class:`Pairs` (the list, its history and per-pair constants); cell: :class:`Cell`; models:
    :class:`Models` (the law's four sub-models, ``law.models``: contact arms as their compiled type,
    see :func:`with_arm_types`, which :func:`pair_forces` applies); kick: :class:`Kick`; dt: the history increment
    step (0: history not advanced); tally: whether to fill ``out``. Fills ``forces``
    (:class:`Forces`): f (N, 2), torque (N,), ``out`` (8,) (see :mod:`dem.engine.contact_laws`; only
    if ``tally``, as LAMMPS tallies energy and virial only on the steps that need them) and, with a
    fused kick, ``acc`` (5,) = the sums of :func:`kick_range`. Every bundle but ``models`` may be
    a plain tuple in field order, the fast form: numba types a plain tuple of arrays or floats in
    C, a NamedTuple through Python (microseconds per call; :func:`bodies_of`, :func:`cell_of` and
    :class:`dem.engine.integrate.Simulation` pass plain tuples).
"""


@njit(cache=True, error_model="numpy", nogil=True)
def _chunked(p_lo, p_hi, bodies, pairs, cell, models, kick, dt, tally, forces):
    """The chunked loop over pairs p_lo..p_hi-1 (a fused kick needs the whole list); the bundles
    are :class:`Bodies`, :class:`Pairs` and :class:`Forces` (arguments: see the note on arrays
    in bundles above)."""
    off = _begin(cell, forces)
    fb, fo = _flat(bodies, forces)  # read here, written only inside kick_range
    ff, torque = forces.f.reshape(-1), forces.torque
    lay = _layout(models)
    nh = lay.nh
    hist, pc, pi = pairs.hist, pairs.pc, pairs.pi
    t = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # the tallies, see _tally_add
    fused, sums, done, block = kick.fused, (0.0, 0.0, 0.0, 0.0, 0.0), np.uint64(0), np.uint64(KICK_BLOCK)
    kb = np.empty(KICK_SCRATCH)
    buf = np.zeros(_NROWS)
    ij = np.empty(2 * CHUNK, np.uint64)
    hb = np.zeros(max(nh, 1) * CHUNK)
    hbak = np.empty(max(nh, 1) * CHUNK)
    hstride = CHUNK if nh > 1 else 1
    npair = pairs.jc.shape[0]
    npc = pc.shape[0] // npair if npair > 0 else 0
    for p0 in range(p_lo, p_hi, CHUNK):
        m = min(CHUNK, p_hi - p0)
        _gather(p0, m, pairs, fb, off, lay.spin, ij, buf)
        if nh > 1:
            # more than one slot: the chunk's history slot by slot (unit stride for the compiler)
            for k in range(nh):
                for q in range(m):
                    hb[q + k * CHUNK] = hist[nh * (p0 + q) + k]
            hc = hb
        else:
            hc = hist[p0 * nh:(p0 + m) * nh]
        hbak[:hc.shape[0]] = hc
        pcs = pc[npc * p0:npc * (p0 + m)]
        if tally:
            _contact_forces(m, hc, hstride, pcs, cell, models, dt, True, buf)
        else:
            _contact_forces(m, hc, hstride, pcs, cell, models, dt, False, buf)
        for q in range(m):
            if buf[_TOUCH + q] == 0.0:
                continue
            if buf[_TOUCH + q] == 2.0:
                _exact(q, hc, hstride, hbak, pcs, cell, models, dt, tally, buf)
            fx = buf[_FX + q]
            fy = buf[_FY + q]
            _apply(ij[q], ij[CHUNK + q], fx, fy, buf[_MI + q], buf[_MJ + q], buf[_MR + q], lay, ff, torque)
            if tally:
                t = _tally_add(t, buf[_UN + q], buf[_UT + q], buf[_UR + q], fx, fy, buf[_LX + q], buf[_LY + q],
                               buf[_FM + q], buf[_KD + q])
        if nh > 1:
            for k in range(nh):
                for q in range(m):
                    hist[nh * (p0 + q) + k] = hb[q + k * CHUNK]
        if fused:
            # particles below the next pair's i have all their forces (pairs are ordered by i, j > i)
            nxt = np.uint64(np.uint32(pi[p0 + m])) if p0 + m < npair else done
            if nxt >= done + block:
                sums = kick_range(done, nxt, fb, fo, kick, sums, kb)
                done = nxt
    _end(done, fb, fo, forces, kick, sums, kb, tally, t)


@njit(cache=True, error_model="numpy")
def pair_forces_chunked(bodies, pairs, cell, models, kick, dt, tally, forces):
    pl = Pairs(*pairs)
    _chunked(0, pl.jc.shape[0], Bodies(*bodies), pl, Cell(*cell), models, Kick(*kick), dt, tally, Forces(*forces))


@njit(cache=True, error_model="numpy", nogil=True)
def pair_forces_span(p_lo, p_hi, bodies, pairs, cell, models, dt, tally, forces):
    """The forces of pairs p_lo..p_hi-1 alone, into their own ``forces`` (the chunked loop, no
    kick). Releases the GIL: :func:`pair_forces_threaded` runs one per thread."""
    _chunked(p_lo, p_hi, Bodies(*bodies), Pairs(*pairs), Cell(*cell), models, NO_KICK, dt, tally, Forces(*forces))


@njit(cache=True, nogil=True)
def _sum_parts(parts, lo, hi, forces, spin, tally):
    """Add the other threads' parts (:class:`Forces` of (threads - 1, N, 2), (threads - 1, N) and
    (threads - 1, 8) arrays, in thread order) to the first thread's ``forces`` (particles lo..hi-1,
    and the tallies when ``lo == 0``)."""
    F, T, O = parts.f, parts.torque, parts.out
    ff = forces.f.reshape(-1)
    for t in range(F.shape[0]):
        Ft = F[t].reshape(-1)
        for k in range(2 * lo, 2 * hi):
            ff[k] += Ft[k]
        if spin:
            Tt = T[t]
            for k in range(lo, hi):
                forces.torque[k] += Tt[k]
        if tally and lo == 0:
            for q in range(8):
                forces.out[q] += O[t, q]


pair_forces_chunked.__doc__ = _PAIR_FORCES_DOC + """
    The pairs go in chunks of ``CHUNK`` (128), each in three passes: gather the pairs' positions and
    velocities into contiguous rows (``_gather``), evaluate the law on all of them without a
    branch on the contact (``_contact_forces``, which the compiler vectorises: 4 pairs per
    instruction with AVX2), then add the forces and torques to the particles, and the tallies to
    their sums, pair by pair in list order, the pairs not in contact skipped. Every floating-point
    operation and every sum is that of :func:`pair_forces_serial`, in the same order: the results
    are bit-identical (tested for every law).
    """


@njit(cache=True, error_model="numpy")
def _serial(bodies, pairs, cell, models, kick, dt, tally, forces):
    """The serial loop (bundles as arguments: see the note on arrays in bundles above)."""
    off = _begin(cell, forces)
    fb, fo = _flat(bodies, forces)  # read here, written only inside kick_range
    ff, torque = forces.f.reshape(-1), forces.torque
    pi, jc, hist, pc = pairs.pi, pairs.jc, pairs.hist, pairs.pc
    lay = _layout(models)
    spin, nh = lay.spin, lay.nh
    xf, vf, omega, radius = fb.x, fb.v, fb.omega, fb.radius
    t = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # the tallies, see _tally_add
    fused, sums, done, block = kick.fused, (0.0, 0.0, 0.0, 0.0, 0.0), np.uint64(0), np.uint64(KICK_BLOCK)
    kb = np.empty(KICK_SCRATCH)
    one = np.uint64(1)
    for p in range(jc.shape[0]):
        i, j, i2, j2, lx, ly = _branch(p, pi, jc, xf, off)
        if fused and i >= done + block:
            # particles below i have all their forces (pairs are ordered by i, j > i)
            sums = kick_range(done, i, fb, fo, kick, sums, kb)
            done = i
        ri = radius[i]
        rj = radius[j]
        rs = ri + rj
        d2 = lx * lx + ly * ly
        if d2 >= rs * rs:
            for k in range(nh * p, nh * p + nh):
                hist[k] = 0.0
            continue
        wi = 0.0
        wj = 0.0
        if spin:
            wi = omega[i]
            wj = omega[j]
        r = _law(PairInput(lx, ly, d2, ri, rj, vf[j2] - vf[i2], vf[j2 + one] - vf[i2 + one], wi, wj), hist,
                 Slots(nh * p, 1), pc, p, cell, models, dt, False)
        _apply(i, j, r.fx, r.fy, r.mi, r.mj, r.mr, lay, ff, torque)
        if tally:
            t = _tally_add(t, r.Un, r.Ut, r.Ur, r.fx, r.fy, lx, ly, force_magnitude(models.tangential, r.fn, r.fx, r.fy),
                           r.kn * d2)
    _end(done, fb, fo, forces, kick, sums, kb, tally, t)


@njit(cache=True, error_model="numpy")
def pair_forces_serial(bodies, pairs, cell, models, kick, dt, tally, forces):
    _serial(Bodies(*bodies), Pairs(*pairs), Cell(*cell), models, Kick(*kick), dt, tally, Forces(*forces))


pair_forces_serial.__doc__ = _PAIR_FORCES_DOC + """
    One flat loop over the pairs: i's force is added to in memory pair by pair (summing it in
    registers per block of i's pairs was measured slower: the block's end is a branch that the
    processor mispredicts about once per particle). For laws whose sub-models do not all
    vectorise (:func:`vectorises`).
    """


class _Threads:
    """Worker threads and the per-thread force, torque and tally buffers of
    :func:`pair_forces_threaded`, kept between calls (one set per number of threads and N)."""

    def __init__(self):
        self.key = None
        self.pool = None
        self.workers = 0

    def get(self, threads, n, spin):
        key = (threads, n, spin)
        if key != self.key:
            if self.workers != threads - 1:
                if self.pool is not None:
                    self.pool.shutdown()
                self.pool = ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="dem-pairs")
                self.workers = threads - 1
            self.parts = Forces(np.zeros((threads - 1, n, 2)), np.zeros((threads - 1, n if spin else 0)),
                                np.zeros((threads - 1, 8)), np.zeros((threads - 1, 5)))
            self.key = key
        return self.pool, self.parts


_THREADS = _Threads()


def pair_forces_threaded(bodies, pairs, cell, models, kick, dt, tally, forces, threads):
    bodies, pairs, forces, kick = Bodies(*bodies), Pairs(*pairs), Forces(*forces), Kick(*kick)
    models = with_arm_types(models)
    n = bodies.x.shape[0]
    spin = bodies.omega.shape[0] > 0
    pool, parts = _THREADS.get(threads, n, spin)
    npair = pairs.jc.shape[0]
    # contiguous ranges of pairs, cut at chunk boundaries: the same cut for the same list
    cuts = [min(npair, CHUNK * int(round(k * npair / (threads * CHUNK)))) for k in range(threads + 1)]
    cuts[-1] = npair
    common = (tuple(bodies), tuple(pairs), tuple(cell), models, dt, tally)
    # the first range into forces itself, the others into their own buffers
    jobs = [pool.submit(pair_forces_span, cuts[k], cuts[k + 1], *common,
                        tuple(Forces(*(a[k - 1] for a in parts))))
            for k in range(1, threads)]
    pair_forces_span(cuts[0], cuts[1], *common, tuple(forces))
    for job in jobs:
        job.result()
    _sum_parts(parts, 0, n, forces, spin, tally)
    if kick.fused:
        forces.acc[:] = kick_all(tuple(bodies), tuple(forces), tuple(kick))


pair_forces_threaded.__doc__ = _PAIR_FORCES_DOC + """
    Multi-core mode (``threads`` >= 2): the list is cut into ``threads`` contiguous ranges of
    pairs (at chunk boundaries); each thread runs the chunked loop on its range into its own force,
    torque and tally buffers (:func:`pair_forces_span`, which releases the GIL; the first range
    into ``forces`` itself), and the others' parts are added particle by particle, in
    thread order. The contact history and every pair's force are
    those of the one-thread loops; the particles' sums are ordered differently (by thread, then by
    pair), so forces agree with the one-thread loops to round-off, not bit for bit, and a run is
    reproducible for a given number of threads (and list). A fused kick runs after the forces.
    About 24 bytes per particle per thread more.
    """


def vectorises(models) -> bool:
    """True if every sub-model of ``models`` declares ``VECTOR = True``: its hooks have no
    branch the compiler cannot turn into a select, and evaluating them on pairs not in contact
    is cheap. :func:`pair_forces` then runs :func:`pair_forces_chunked`, else
    :func:`pair_forces_serial` (the two give bit-identical results; the flag only chooses the
    faster one, measured in ``docs/dem.md``)."""
    return all(getattr(type(m), "VECTOR", False) for m in models)


def pair_forces(bodies, pairs, cell, models, kick, dt, tally, forces, threads=1):
    models = with_arm_types(models)
    if threads > 1:
        pair_forces_threaded(bodies, pairs, cell, models, kick, dt, tally, forces, threads)
        return
    loop = pair_forces_chunked if vectorises(models) else pair_forces_serial
    loop(bodies, pairs, cell, models, kick, dt, tally, forces)


pair_forces.__doc__ = _PAIR_FORCES_DOC + """
    With ``threads`` > 1, :func:`pair_forces_threaded`; else :func:`pair_forces_chunked`
    (vectorised) when the law's sub-models allow it (:func:`vectorises`), else
    :func:`pair_forces_serial` (the two give the same bits).
    """


@njit(cache=True)
def make_pair_constants(damping, normal, mass, pi, pj, npc):
    """(P * npc,) per-pair constants of the damping model (m_eff = m_i m_j / (m_i + m_j))."""
    pc = np.zeros(pi.shape[0] * npc)
    if npc > 0:
        for p in range(pi.shape[0]):
            i = pi[p]
            j = pj[p]
            meff = mass[i] * mass[j] / (mass[i] + mass[j])
            pair_constant(damping, normal, meff, pc, npc * p)
    return pc


SUBMODELS = {c.__name__: c for c in (Hooke, Hertz, NoDamping, Viscous, ViscousTangential, MassGamma,
                                     NoTangential, LinearHistory, Mindlin, LammpsHistory, NoRolling,
                                     RollingResistance)}
