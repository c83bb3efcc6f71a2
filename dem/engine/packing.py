"""Dense random packings of disks in a periodic cell: random gas, isotropic servo compression to a
target pressure, preparation friction then test friction.

Units: any consistent set; 2D quantities per unit thickness. The pressure is a force per length,
``p = -tr(sigma)/2`` (compression positive) with the Love-Weber stress
``sigma = -(1/A) sum_c F_c (x) l_c`` (tension positive). The target is ``p_over_kn`` (p/kn,
dimensionless) with ``kn`` [N/m]; the servo's target is ``p_target = p_over_kn kn`` [N/m].

A packing is made by a :class:`PackingProtocol`, frozen data that holds every packing parameter
with its unit, default and allowed range (checked there, nowhere else)::

    proto = PackingProtocol(n=1000, p_over_kn=1e-4, mu_prep=0.05, seed=1)
    res = pack(proto)                    # pack(proto, checkpoint="run.npz") to resume/checkpoint
    res.save("packing.npz")              # the protocol travels in the file
    corpus = [proto.replace(seed=s) for s in range(5)]

The same protocol drives ``python -m dem pack`` (its options are the protocol's fields) and the
LAMMPS writer (:func:`dem.engine.lammps.write_inputs`).

Protocol (the phases :func:`phases` builds and :func:`pack` runs; names are the fields):

1. *Random gas*: N disk centres uniform in a square periodic cell at solid fraction ``phi0``
   (overlaps allowed; they are pushed apart by the contact law and the local damping in the first
   steps), drawn from ``numpy.random.default_rng(seed)``; radii identical, or uniform in
   ``r (1 +- dispersity)``. ``gas_overlaps=False`` starts instead from a cold gas without
   overlaps (random sequential addition).
2. *Compaction* (phase ``compact``) with :class:`dem.engine.cell.PressureServo`: the cell shrinks at
   ``max_strain_per_step`` (default 2e-4 per step) while there is no load, then the
   stiffness-adaptive servo holds the pressure at the target while the assembly, still below
   jamming, flows into a jammed state. This phase runs with a *light* local damping
   ``damping_compaction`` (default 0.05) and ends when the packing has jammed: ``|p - p_target| <
   jam_p p_target`` (default 1e-2) and unbalanced force ratio < ``jam_unbalanced`` (default 1e-3). The damping then
   returns to ``damping`` (default 0.7) for the equilibrium phases.

   Why: at the target pressure the unjammed assembly compacts like a dense granular flow whose
   rate scales as ``sqrt(p / rho) / d`` times a factor set by the dissipation; with ``damping =
   0.7`` all the way, 90 % of the steps of a 1e4-disk packing at p/kn = 1e-4 were spent creeping
   from phi ~ 0.76 to jamming at phi ~ 0.79 with the pressure already on target (350 900 steps);
   with a light compaction damping the same packing jams in a few 1e4 steps (numbers in
   ``docs/dem.md``). ``damping_compaction=None`` restores the single-damping protocol.

   The time step is ``dt_over_dtcrit`` (default 1) times :func:`dem.engine.integrate.critical_dt`,
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
   below 3e-7 at five checks in a row) the FIRE velocity mixing of :mod:`dem.engine.fire` runs too,
   until the phase ends or the packing moves again.
3. *Equilibrium* at ``mu_prep`` (phase ``prep``), with the local damping ``damping`` and, with
   ``fire=True`` (default), the FIRE velocity mixing of :mod:`dem.engine.fire` after every step (it
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
:class:`PackingResult` carries the final :class:`dem.engine.state.State` (a checkpoint: ``save``/``load``),
the report and :meth:`PackingResult.to_network` (a :class:`microhom.network.ContactNetwork`).
:meth:`PackingResult.save` writes one npz that is both a checkpoint (``PackingResult.load``)
and a ``dem.io`` configuration (:func:`dem.io.read`).
The phases are objects (:class:`Grow`, :class:`Restore`, :class:`Compact`, :class:`Equilibrate`),
each with its own parameters and stop criterion; :func:`pack` runs them in order and reports them
in :class:`PackReport` (``phase_steps``).
``pack(protocol, checkpoint=path)`` writes atomic checkpoints every ``checkpoint_every`` steps and/or
every ``checkpoint_seconds`` of wall time (only at check points, after the instability guard
passed, so a checkpoint is always a good state) and resumes from ``path`` if it exists: the
continuation is bit-exact whatever the checkpoint times were.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass, field, fields, replace

import numpy as np
from microhom.limits import available_memory  # noqa: F401 - part of this API (one implementation)
from numba import njit

from microhom.network import ContactNetwork
from microhom.results import Result

from .cell import PressureServo, wrap
from .contact_laws import Frictionless, LinearFriction, law_from_meta
from .fire import Fire
from .integrate import Guard, InstabilityError, Loop, Simulation, critical_dt
from ..io import Configuration
from ..io.simple import write_npz
from ..analysis.measure import hexatic_order
from ..runtime import atomic_write, remove_stale_temporaries
from .state import State

__all__ = ["PackingProtocol", "ProtocolError", "Param", "pack", "random_gas", "phases",
           "check_run_options", "PackingResult", "PackReport", "network_from_state", "hexatic_psi6",
           "Grow", "Restore", "Compact", "Equilibrate", "BYTES_PER_PARTICLE", "check_memory"]


# ---- the protocol: what makes a packing, validated and defaulted here only --------------------
class ProtocolError(ValueError):
    """A packing parameter outside its allowed range: ``field`` (its name in
    :class:`PackingProtocol`), ``allowed`` (the range, as text, with the unit) and ``value``."""

    def __init__(self, field, allowed, value):
        self.field, self.allowed, self.value = field, allowed, value
        super().__init__(f"{field} must be {allowed}, got {value!r}")


@dataclass(frozen=True)
class Param:
    """How one field of :class:`PackingProtocol` is described and checked: ``unit`` (``"-"``
    dimensionless), ``allowed`` (the range as text), ``ok`` (the test of a value), ``help``
    (one sentence), ``kind`` (``"int"``, ``"float"`` or ``"bool"``), ``optional`` (None allowed;
    the help says what it means)."""
    unit: str
    allowed: str
    ok: object
    help: str
    kind: str = "float"
    optional: bool = False

    def allowed_text(self):
        """The allowed range with its unit, as error messages and ``--help`` print it."""
        unit = "" if self.unit == "-" else f" [{self.unit}]"
        return ("None or " if self.optional else "") + self.allowed + unit


def _param(default, unit, allowed, ok, help, kind="float", optional=False):
    return field(default=default, metadata={"param": Param(unit, allowed, ok, help, kind, optional)})


def _unit_interval(v):
    return 0 <= v < 1


@dataclass(frozen=True)
class PackingProtocol(Result):
    """How a packing is made (the protocol of the module docstring): frozen, hashable data.

    Every packing parameter is a field here, with its unit, default and allowed range (the
    ``param`` metadata of each field, :class:`Param`; ``python -m dem pack --help`` prints the
    same table). A bad value raises :class:`ProtocolError` (a ``ValueError``) naming the field
    and its range, when the protocol is made: :func:`pack`, :func:`random_gas`,
    ``python -m dem pack`` and :func:`dem.engine.lammps.write_inputs` take a protocol and check nothing
    themselves. Variants: ``protocol.replace(mu=0.3)``; a corpus of packings is a list of
    protocols. Serialised by ``as_dict()`` / :meth:`from_dict` (and :meth:`to_json` /
    :meth:`from_json`); every packing npz stores its protocol (``PackingResult.protocol``).

    Units: any consistent set, 2D per unit thickness. The target pressure is ``p_over_kn``
    (p/kn, dimensionless): the geometry of a packing depends on p/kn only; ``kn`` [N/m] sets
    the scale, ``p_target = p_over_kn * kn`` [N/m] is the servo's target (a force per length,
    ``p = -tr(sigma)/2``). The tangential stiffness is ``kt_over_kn`` likewise
    (``kt = kt_over_kn * kn`` [N/m]).

    The defaults are the seed paper's conditions, which ``python -m dem pack`` has always used:
    identical disks (diameter 1 [m], unit mass), ``kt = kn``, test friction ``mu = 0.488``
    (tan 26 deg), ``p/kn = 1e-4``; preparation friction ``mu_prep = 0.1`` (amorphous identical
    disks with Nc ~ 3.9; ``docs/dem.md``). The numerical defaults (damping, FIRE, time step,
    stop criteria) are the protocol measured in ``docs/dem.md``.

    Derived (read-only properties): ``p_target`` [N/m], ``kt`` [N/m], ``areal_density``
    [kg/m^2], ``frictionless``.
    """

    n: int = field(metadata={"param": Param("-", "an integer in [2, 1e9]",
                                            lambda v: 2 <= v <= 10 ** 9, "number of disks", "int")})
    seed: int = _param(0, "-", "an integer >= 0", lambda v: v >= 0,
                       "random seed of the gas (numpy.random.default_rng)", "int")
    p_over_kn: float = _param(1e-4, "-", "in (0, 0.1]", lambda v: 0 < v <= 0.1,
                              "target pressure over kn, p/kn (p = -tr(sigma)/2, a force per "
                              "length; the servo's target is p_target = p_over_kn kn [N/m])")
    kn: float = _param(1.0, "N/m", "> 0", lambda v: v > 0,
                       "normal contact stiffness (force per overlap)")
    kt_over_kn: float = _param(1.0, "-", "in [0, 10]", lambda v: 0 <= v <= 10,
                               "tangential over normal contact stiffness, kt/kn (0: the "
                               "frictionless law)")
    mu: float = _param(0.488, "-", "in [0, 10]", lambda v: 0 <= v <= 10,
                       "test friction coefficient (0.488 = tan 26 deg, the seed paper's)")
    mu_prep: float = _param(0.1, "-", "in [0, 10]", lambda v: 0 <= v <= 10,
                            "preparation friction: the knob for the coordination number (0.1: "
                            "amorphous identical disks, Nc ~ 3.9; 0.05: Nc ~ 4.0, some packings "
                            "order; 0: densest, crystallises)")
    radius: float = _param(0.5, "m", "> 0", lambda v: v > 0, "mean disk radius")
    dispersity: float = _param(0.0, "-", "in [0, 0.5)", lambda v: 0 <= v < 0.5,
                               "radii uniform in radius (1 +- dispersity)")
    rho: float | None = _param(None, "kg/m^2", "> 0", lambda v: v > 0,
                               "areal density (None: a disk of the mean radius has unit mass)",
                               optional=True)
    phi0: float = _param(0.2, "-", "in (0, 0.9) (below 0.45 without gas overlaps)",
                         lambda v: 0 < v < 0.9, "solid fraction of the starting gas")
    gas_overlaps: bool = _param(True, "-", "True or False", lambda v: True,
                                "gas of independent uniform centres (overlaps push the disks "
                                "apart); False: random sequential addition without overlaps",
                                "bool")
    growth_dispersity: float = _param(0.0, "-", "in [0, 0.5)", lambda v: 0 <= v < 0.5,
                                      "radius spread during the first compression only (phases "
                                      "grow and restore; 0: none)")
    restore_increments: int = _param(50, "-", "an integer >= 1", lambda v: v >= 1,
                                     "checks over which the growth spread is removed", "int")
    damping_compaction: float | None = _param(0.05, "-", "in [0, 1)", _unit_interval,
                                              "local damping of the compaction phase (None: no "
                                              "compaction phase, damping throughout)",
                                              optional=True)
    jam_p: float = _param(1e-2, "-", "in (0, 1)", lambda v: 0 < v < 1,
                          "the compaction ends (jammed) when |p - p_target| < jam_p p_target ...")
    jam_unbalanced: float = _param(1e-3, "-", "in (0, 1)", lambda v: 0 < v < 1,
                                   "... and the unbalanced force ratio < jam_unbalanced")
    damping: float = _param(0.7, "-", "in [0, 1)", _unit_interval,
                            "Cundall local damping of the equilibrium phases")
    fire: bool = _param(True, "-", "True or False", lambda v: True,
                        "FIRE velocity mixing in the equilibrium phases and, once still, in the "
                        "compaction (dem.engine.fire)", "bool")
    restitution: float | None = _param(None, "-", "in (0, 1]", lambda v: 0 < v <= 1,
                                       "coefficient of restitution of a viscous contact "
                                       "dashpot (None: no dashpot)", optional=True)
    max_strain_per_step: float = _param(2e-4, "-", "in (0, 0.1)", lambda v: 0 < v < 0.1,
                                        "cap on the servo's isotropic strain per step")
    alpha: float = _param(0.5, "-", "in (0, 1]", lambda v: 0 < v <= 1,
                          "servo gain: fraction of the pressure error corrected per step")
    dt_over_dtcrit: float = _param(1.0, "-", "in (0, 1]", lambda v: 0 < v <= 1,
                                   "time step over dem.engine.integrate.critical_dt")
    tol_p: float = _param(1e-3, "-", "in (0, 1)", lambda v: 0 < v < 1,
                          "stop when |p - p_target| / p_target < tol_p ...")
    tol_unbalanced: float = _param(1e-5, "-", "in (0, 1)", lambda v: 0 < v < 1,
                                   "... and the unbalanced force ratio (mean |resultant force| "
                                   "over mean |contact force|, Yade) < tol_unbalanced ...")
    tol_ke: float = _param(1e-8, "-", "in (0, 1)", lambda v: 0 < v < 1,
                           "... and the kinetic energy of the disks in contact < tol_ke x the "
                           "elastic contact energy")
    check_every: int = _param(100, "steps", "an integer >= 1", lambda v: v >= 1,
                              "steps between checks of the criteria (at multiples of it)", "int")

    def __post_init__(self):
        for f in fields(self):
            p = f.metadata["param"]
            v = getattr(self, f.name)
            if v is None and p.optional:
                continue
            object.__setattr__(self, f.name, _coerce(f.name, v, p))
        if not self.gas_overlaps and not self.phi0 < 0.45:
            raise ProtocolError("phi0", "in (0, 0.45) for a gas without overlaps "
                                "(gas_overlaps=False)", self.phi0)

    # ---- derived quantities --------------------------------------------------------------------
    @property
    def p_target(self) -> float:
        """Target pressure [N/m] (force per length), ``p_over_kn * kn``."""
        return self.p_over_kn * self.kn

    @property
    def kt(self) -> float:
        """Tangential contact stiffness [N/m], ``kt_over_kn * kn``."""
        return self.kt_over_kn * self.kn

    @property
    def areal_density(self) -> float:
        """``rho`` [kg/m^2], or ``1 / (pi radius^2)`` (unit mass of a mean disk) when None."""
        return 1.0 / (np.pi * self.radius ** 2) if self.rho is None else self.rho

    @property
    def frictionless(self) -> bool:
        """True when the packing uses the specialised frictionless law (no spins, no history),
        that is when kt = 0 or mu = mu_prep = 0."""
        return self.kt_over_kn == 0 or (self.mu == 0 and self.mu_prep == 0)

    def laws(self):
        """(law of the preparation phases, law of the test phase): ``dem.engine.contact_laws`` laws."""
        if self.frictionless:
            law = Frictionless(kn=self.kn, restitution=self.restitution)
            return law, law
        law = LinearFriction(kn=self.kn, kt=self.kt, mu=self.mu_prep, restitution=self.restitution)
        return law, law.with_friction(self.mu)

    # ---- variants and serialisation ------------------------------------------------------------
    def replace(self, **changes) -> "PackingProtocol":
        """A copy with ``changes`` (checked as a new protocol)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def params(cls) -> dict:
        """{field name: (default, :class:`Param`)} in field order (``n`` has no default: None)."""
        return {f.name: (None if f.default is dataclasses.MISSING else f.default, f.metadata["param"])
                for f in fields(cls)}

    @classmethod
    def from_dict(cls, d) -> "PackingProtocol":
        """From ``as_dict()``'s dict (missing fields take their defaults; an unknown key raises
        ``ValueError`` naming it)."""
        unknown = sorted(set(d) - set(cls.params()))
        if unknown:
            raise ValueError(f"unknown packing protocol field(s) {unknown}; the fields are "
                             f"{list(cls.params())}")
        return cls(**d)

    def to_json(self) -> str:
        """JSON text of ``as_dict()`` (:meth:`from_json` reads it back to an equal protocol)."""
        return json.dumps(self.as_dict())

    @classmethod
    def from_json(cls, text) -> "PackingProtocol":
        """From :meth:`to_json`'s text (checked as a new protocol)."""
        return cls.from_dict(json.loads(text))


def _fields_doc(cls):
    """The field table appended to ``cls.__doc__`` (generated from the ``param`` metadata, so the
    docstring, ``--help`` and the checks cannot disagree)."""
    lines = ["", "    Fields (name [unit], default, allowed: meaning)", "    " + "-" * 48]
    for name, (default, prm) in cls.params().items():
        unit = "" if prm.unit == "-" else f" [{prm.unit}]"
        shown = "required" if default is None and not prm.optional else f"default {default!r}"
        allowed = ("None or " if prm.optional else "") + prm.allowed
        end = "" if prm.help.endswith(".") else "."
        text = prm.help.replace("|", "\\|")          # reST: a bare |x| is a substitution
        lines.append(f"    ``{name}``{unit}, {shown}, {allowed}: {text}{end}")
    return "\n".join(lines) + "\n"


PackingProtocol.__doc__ += _fields_doc(PackingProtocol)


def _coerce(name, v, p):
    """``v`` as the field's kind, or :class:`ProtocolError` naming ``name`` and its range."""
    if p.kind == "bool":
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        raise ProtocolError(name, "True or False", v)
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ProtocolError(name, p.allowed_text(), v) from None
    if p.kind == "int":
        if not (math.isfinite(x) and x == int(x)) or isinstance(v, bool):
            raise ProtocolError(name, p.allowed_text(), v)
        x = int(x)
    if not (math.isfinite(x) and p.ok(x)):
        raise ProtocolError(name, p.allowed_text(), v)
    return x


def check_run_options(*, max_steps=None, checkpoint_every=None, checkpoint_seconds=None,
                      threads=1):
    """Check the run options of :func:`pack` (how long and where a packing runs, not how it is
    made): ``max_steps`` an integer >= 1 [steps], ``checkpoint_every`` None or an integer >= 1
    [steps], ``checkpoint_seconds`` None or >= 0 [s], ``threads`` an integer in [1, 1024].
    Raises :class:`ProtocolError` naming the option; returns them as (int, int|None, float|None,
    int)."""
    run = {"max_steps": (max_steps, Param("steps", "an integer >= 1", lambda v: v >= 1, "", "int")),
           "checkpoint_every": (checkpoint_every, Param("steps", "an integer >= 1", lambda v: v >= 1,
                                                        "", "int", True)),
           "checkpoint_seconds": (checkpoint_seconds, Param("s", ">= 0", lambda v: v >= 0, "",
                                                            "float", True)),
           "threads": (threads, Param("-", "an integer in [1, 1024]", lambda v: 1 <= v <= 1024, "",
                                      "int"))}
    return tuple(None if v is None and p.optional else _coerce(k, v, p) for k, (v, p) in run.items())


def random_gas(protocol, *, spins=True) -> State:
    """The starting gas of ``protocol`` (a :class:`PackingProtocol`): ``protocol.n`` disks at
    random (seeded by ``protocol.seed``) positions in a square periodic cell at solid fraction
    ``phi0``, at rest.

    Radii ``radius`` [m], or uniform in ``radius (1 +- dispersity)``; areal density
    ``protocol.areal_density`` [kg/m^2]. ``gas_overlaps`` True: centres uniform and independent
    (disks may overlap); False: random sequential addition (uniform candidate centres, each kept
    if its disk overlaps none placed before; the protocol then requires ``phi0`` < 0.45, under
    the RSA jamming fraction 0.547 of disks). ``spins``: angular velocity and rotation arrays.
    """
    if not isinstance(protocol, PackingProtocol):
        raise TypeError(f"random_gas takes a PackingProtocol, got {type(protocol).__name__}")
    n, radius, dispersity, phi0 = protocol.n, protocol.radius, protocol.dispersity, protocol.phi0
    rng = np.random.default_rng(protocol.seed)
    r = np.full(n, float(radius))
    if dispersity > 0:
        r = radius * (1.0 + dispersity * rng.uniform(-1.0, 1.0, n))
    Lbox = math.sqrt(np.pi * np.sum(r ** 2) / phi0)
    if protocol.gas_overlaps:
        x = rng.uniform(0.0, Lbox, (n, 2))
    else:
        nc = max(1, int(Lbox / (2.0 * r.max())))
        head = np.full(nc * nc, -1, dtype=np.int64)
        nxt = np.full(n, -1, dtype=np.int64)
        x = np.zeros((n, 2))
        count = 0
        while count < n:   # candidates in seeded batches until every disk is placed
            count = _rsa_place(rng.uniform(0.0, Lbox, (2 * (n - count) + 16, 2)), r, Lbox, x,
                               Lbox / nc, head, nxt, count)
    return State.from_disks(x, r, np.diag([Lbox, Lbox]), rho=protocol.areal_density, spins=spins)


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
    ``report.get`` and ``report.items()`` read the fields. The report is read-only:
    :meth:`annotate` returns a copy with a caller's annotations in ``extra`` (saved with the
    packing), e.g. ``res = res.replace(report=res.report.annotate(wall_time=12.5))``.
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
    #: the caller's own annotations (:meth:`annotate`): scalars that travel with the packing in
    #: its npz, as keys of the earlier dict report did
    extra: dict = field(default_factory=dict, metadata={"export": False})

    # ---- read access of the earlier dict report ------------------------------------------------
    def __getitem__(self, key):
        if key in self._names():
            return getattr(self, key)
        return self.extra[key]

    def __contains__(self, key):
        return key in self._names() or key in self.extra

    def get(self, key, default=None):
        return self[key] if key in self else default

    def keys(self):
        return self._names() + list(self.extra)

    def items(self):
        return [(k, self[k]) for k in self.keys()]

    def annotate(self, **notes) -> "PackReport":
        """A copy with ``notes`` (JSON-able scalars) added to ``extra``; a field's name raises."""
        taken = sorted(set(notes) & set(self._names()))
        if taken:
            raise TypeError(f"PackReport fields {taken} are read-only (dataclasses.replace makes a "
                            f"copy); annotations take new names")
        return dataclasses.replace(self, extra={**self.extra, **notes})

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


@dataclass(frozen=True, eq=False)
class PackingResult(Result):
    """Final state of a packing run (see :func:`pack`); read-only (``replace`` makes a variant).

    Attributes
    ----------
    state : the final :class:`dem.engine.state.State` (positions [m], velocities [m/s], cell [m], ...).
    law : the contact law of the last phase (a ``dem.engine.contact_laws`` law, stiffnesses in N/m).
    report : the :class:`PackReport` of the run (criteria, counts, timings).
    protocol : the :class:`PackingProtocol` that made it (None for a file written before
        protocols were stored).
    """
    state: State = field(metadata={"export": False})
    law: object = field(metadata={"export": False})
    report: PackReport = None
    protocol: PackingProtocol | None = None

    def to_network(self):
        """The :class:`microhom.network.ContactNetwork` of the packing (forces included)."""
        return network_from_state(self.state, self.law)

    def replace(self, **changes) -> "PackingResult":
        """A copy with some fields replaced (e.g. ``report=res.report.annotate(...)``)."""
        return replace(self, **changes)

    def save(self, path):
        """One npz that is a checkpoint (``load``, bit-exact state) and a ``dem.io``
        configuration (:func:`dem.io.read`: positions, radii, cell, ids, velocities; its meta
        holds the report, the law and the protocol); atomic. Returns the path written."""
        self.state.meta["packing_report"] = self.report.scalars()
        self.state.meta["packing_law"] = self.law.to_meta()
        path = os.fspath(path)
        path = path if path.endswith(".npz") else path + ".npz"
        st = self.state
        meta = {"source": "dem.engine.packing", "note": _CONFIG_NOTE, "timestep": int(st.step),
                **self.report.scalars(), "law": st.meta["packing_law"],
                "protocol": None if self.protocol is None else self.protocol.as_dict()}
        cfg = Configuration(positions=wrap(st.x, st.h)[0], radii=st.radius, cell=st.h, ids=st.ids,
                            velocities=st.v, meta=meta)
        extra = {k: v for k, v in st.arrays().items() if k != "ids"}   # ids: the schema's own
        # the contact network is stored too (the analysis reads it without the simulator); it
        # numbers the particles in id order (network_from_state), the file's rows are the state's
        net = self.to_network()
        rows = np.argsort(st.ids, kind="stable")
        atomic_write(path, lambda fh: write_npz(fh, cfg, extra=extra, network=net, network_rows=rows))
        return path

    @classmethod
    def load(cls, path):
        st = State.load(path)
        proto = st.meta.get("packing_protocol")
        return cls(st, law_from_meta(st.meta["packing_law"]),
                   PackReport.from_dict(st.meta.get("packing_report", {})),
                   None if proto is None else PackingProtocol.from_dict(proto))


_CONFIG_NOTE = ("configuration view for dem.io.read: positions wrapped into the cell, in the "
                "state's (spatially sorted) order; ids = original labels, 0-based")


#: bytes per particle held by a packing run (state, Verlet list, history, engine buffers),
#: measured by ``studies.bench_scaling``; the memory guard of :func:`check_memory` uses it
BYTES_PER_PARTICLE = 247




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
    pressure is within ``tol_p`` (5 %) of the target; phase :class:`Restore` follows."""
    tol_p: float = 0.05
    name = "grow"

    def enter(self, run):
        pass

    def done(self, run, m):
        return abs(m["pressure"] - run.p_target) < self.tol_p * run.p_target


@dataclass(frozen=True)
class Restore:
    """Phase ``restore``: shrink the growth spread of the radii to zero in ``increments`` checks
    (one increment per check, the protocol's ``restore_increments``); done when the radii are
    back."""
    increments: int
    name = "restore"

    def enter(self, run):
        pass

    def done(self, run, m):
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
    ``|p - p_t| < tol_p p_t`` and unbalanced ratio < ``jam_unbalanced`` (the protocol's
    ``jam_p`` and ``jam_unbalanced``: :func:`phases` fills them in).

    Once the packing has stopped compacting (the solid fraction changed by less than
    ``still_tol`` (relative) between consecutive checks, ``still_checks`` times in a row), the
    FIRE mixing (:mod:`dem.engine.fire`) runs on top of the damping until the phase ends or the packing
    moves again (``still_tol = 0``: never). It stops the ringing of the jammed, lightly damped
    packing; during the flow it would stop the flow, hence the gate.
    """
    damping: float
    jam_unbalanced: float
    tol_p: float
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
    fire : FIRE velocity mixing after every step (:mod:`dem.engine.fire`, a fresh :class:`~dem.engine.fire.Fire` at the
        start of the phase), on top of the damping.

    The values are the protocol's (:func:`phases` fills them in); the phase has no defaults.
    """
    name: str
    law: object
    damping: float
    tol_p: float
    tol_unbalanced: float
    tol_ke: float
    fire: bool

    def enter(self, run):
        if run.sim.law is not self.law and run.sim.law.to_meta() != self.law.to_meta():
            run.sim.set_law(self.law)
        run.sim.damping = float(self.damping)
        run.fire = Fire() if self.fire else None

    def done(self, run, m):
        return run.criteria(m, self)


def phases(protocol):
    """The named phases of ``protocol``, in order: [:class:`Grow`, :class:`Restore`] (with a
    growth spread), [:class:`Compact`] (with a compaction damping), :class:`Equilibrate`
    ``prep``, and ``test`` when the test friction differs."""
    p = protocol
    law_prep, law_test = p.laws()
    out = [Grow(), Restore(p.restore_increments)] if p.growth_dispersity > 0 else []
    if p.damping_compaction is not None:
        out.append(Compact(p.damping_compaction, p.jam_unbalanced, p.jam_p,
                           still_tol=3e-7 if p.fire else 0.0))
    eq = dict(damping=p.damping, tol_p=p.tol_p, tol_unbalanced=p.tol_unbalanced, tol_ke=p.tol_ke,
              fire=p.fire)
    out.append(Equilibrate("prep", law_prep, **eq))
    if law_test is not law_prep and p.mu != p.mu_prep:
        out.append(Equilibrate("test", law_test, **eq))
    return out


def _new_run(protocol, threads, meta):
    """A new run of ``protocol``: the gas (radii spread by the growth dispersity, if any), the
    simulation with the servo, and the first phase entered."""
    p = protocol
    law_prep = p.laws()[0]
    st = random_gas(p, spins=not p.frictionless)
    if p.growth_dispersity > 0:
        u = np.random.default_rng([p.seed, 1]).uniform(-1.0, 1.0, st.n)
        st.meta["growth"] = {"r0": st.radius.tolist(), "u": u.tolist(), "g": p.growth_dispersity,
                             "s": 1.0}
        st.radius = st.radius * (1.0 + p.growth_dispersity * u)
    if meta:
        st.meta.update(meta)
    st.meta["packing_protocol"] = p.as_dict()
    sim = Simulation(st, law_prep, dt=p.dt_over_dtcrit * critical_dt(st, law_prep),
                     damping=p.damping if p.damping_compaction is None else p.damping_compaction,
                     guard=Guard(check_every=0), loop=Loop(threads=threads))
    sim.control = PressureServo(p_target=p.p_target, max_rate=p.max_strain_per_step / sim.dt,
                                alpha=p.alpha)
    run = _Run(sim, p, phases(p), 0, [])
    run.current.enter(run)
    return run


class _Run:
    """A pack run between its checks: simulation, protocol, phases (``current`` is
    ``phases[index]``; ``index == len(phases)``: done), history, last criteria, FIRE state."""

    def __init__(self, sim, protocol, phase_list, index, history):
        self.sim, self.state, self.protocol = sim, sim.state, protocol
        self.p_target = protocol.p_target
        self.phases, self.index, self.history = phase_list, index, history
        self.last = {}
        self.fire = None     # the FIRE mixing of the current phase (dem.engine.fire.Fire) or None
        self.last_phi = None  # solid fraction at the last check (Compact's stillness gate)
        self.n_still = 0      # consecutive checks without compaction
        self.n_checks = 0
        sim.check_every = 0   # the instability guard runs at the checks (check)

    @property
    def done(self):
        return self.index >= len(self.phases)

    @property
    def current(self):
        return None if self.done else self.phases[self.index]

    @property
    def phase(self):
        return "done" if self.done else self.current.name

    def advance(self, k):
        """``k`` time steps, with the FIRE mixing after each one if the phase has it."""
        if self.fire is None:
            self.sim.run(k)
        else:
            self.sim.run(k, callback=self.fire.update, every=1)

    def check(self, verbose=False):
        """A check (at a multiple of ``check_every``): guard, measure, the phase's stop
        criterion (the next phase entered when it holds). Returns the measurements."""
        self.sim._guard()
        m = self.sim.measure()
        self.n_checks += 1
        self.last["ke_rel"] = None
        st = self.state
        if verbose and st.step % (10 * self.protocol.check_every) == 0:
            print(f"[pack] step {st.step} phase {self.phase} phi {st.solid_fraction:.4f} "
                  f"p/p0 {m['pressure'] / self.p_target:.5f} unb {m['unbalanced']:.3g} "
                  f"Z {2 * m['n_contacts'] / st.n:.3f}", flush=True)
        if self.current.done(self, m):
            self.history.append({"phase": self.phase, "step": int(st.step)})
            self.index += 1
            if not self.done:
                self.current.enter(self)
        return m

    def info(self, m, max_steps, checkpoint_step):
        """The dict given to ``progress`` (see :func:`pack`)."""
        if self.last["ke_rel"] is None and self.n_checks % 10 == 0:
            self.ke_rel(m)
        st = self.state
        return {"step": int(st.step), "max_steps": int(max_steps), "phase": self.phase,
                "phi": st.solid_fraction, "Z": 2.0 * m["n_contacts"] / st.n,
                "rel_p_err": abs(m["pressure"] - self.p_target) / self.p_target,
                "unbalanced": m["unbalanced"], "ke_rel": self.last["ke_rel"],
                "checkpoint_step": checkpoint_step}

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

    def to_meta(self):
        """What a checkpoint keeps of the run (beside the simulation)."""
        return {"phase": self.phase, "history": self.history,
                "protocol": self.protocol.as_dict(),
                "fire": None if self.fire is None else self.fire.to_meta(),
                "last_phi": self.last_phi, "n_still": self.n_still}

    def report(self, t_start, resumed):
        """The :class:`PackReport` of the run as it stands (final values of the criteria)."""
        sim, state, p = self.sim, self.state, self.protocol
        m = sim.measure() if sim.steps_timed else sim.refresh()   # forces exist only after a step
        self.criteria(m, self.phases[-1], force_ke=True)
        last = self.last
        net = network_from_state(state, sim.law)
        try:
            hx = hexatic_psi6(net)
        except Exception:  # noqa: BLE001 - psi6 is informative only
            hx = {"psi6": float("nan"), "psi6_local": float("nan")}
        nc = net.n_contacts
        compact_end = [h["step"] for h in self.history if h["phase"] == "compact"]
        timing = sim.timing_report()
        return PackReport(
            n=state.n, seed=p.seed, converged=self.done, steps=int(state.step),
            phase_steps=self.history, compaction_steps=compact_end[0] if compact_end else None,
            wall_s=time.perf_counter() - t_start, resumed=resumed,
            p_target=self.p_target, pressure=last["pressure"], rel_p_err=last["rel_p_err"],
            p_over_kn=last["pressure"] / p.kn, unbalanced=last["unbalanced"],
            unbalanced_max=last["unbalanced_max"], ke_rel=last["ke_rel"],
            kinetic_energy=last["kinetic_energy"],
            kinetic_energy_in_contact=last["kinetic_energy_in_contact"],
            elastic_energy=last["elastic_energy"],
            phi=state.solid_fraction, n_contacts=nc, Z=2.0 * nc / state.n,
            sliding_fraction=(float(net.sliding.mean()) if nc and not p.frictionless
                              else float("nan")),
            dt=sim.dt, dt_over_dtcrit=sim.dt / sim.dt_crit, mu=p.mu, mu_prep=p.mu_prep,
            kn=p.kn, kt=0.0 if p.frictionless else p.kt, tol_p=p.tol_p,
            tol_unbalanced=p.tol_unbalanced, tol_ke=p.tol_ke, damping=p.damping,
            damping_compaction=p.damping_compaction, damping_work=sim.damping_work,
            psi6=hx["psi6"], psi6_local=hx["psi6_local"], timing=timing["table"],
            particle_steps_per_s=timing["particle_steps_per_s"])


class _Checkpoints:
    """Atomic checkpoints of a run at ``path`` (None: none), every ``every`` steps and/or every
    ``seconds`` of wall time, at checks only (after the guard passed); and the resume."""

    def __init__(self, path, every, seconds):
        self.path, self.every, self.seconds = path, every, seconds
        self.step, self.t = None, time.perf_counter()   # the last one written (None: none yet)

    def resume(self, protocol, threads):
        """The run stored at ``path`` (None if there is none; temporaries of a killed write are
        removed first), or ``(state, report)`` of a finished run. A checkpoint of another
        protocol raises ``ValueError`` naming the fields that differ."""
        if self.path is None:
            return None
        remove_stale_temporaries(self.path)
        if not os.path.exists(os.fspath(self.path)):
            return None
        st0 = State.load(self.path)
        pk = st0.meta["packing"]
        stored = pk.get("protocol")
        if stored is not None and stored != protocol.as_dict():
            diff = sorted(k for k in stored if stored[k] != protocol.as_dict().get(k))
            raise ValueError(f"checkpoint {os.fspath(self.path)} was made by another protocol "
                             f"(fields {diff} differ): resume it with its own protocol "
                             f"(PackingResult.load(...).protocol) or remove it")
        self.step = st0.step
        if pk["phase"] == "done" and pk.get("report"):   # a finished run: nothing to compute
            return st0, PackReport.from_dict(dict(pk["report"], phase_steps=pk.get("history", []),
                                                  resumed=True, already_converged=True))
        ctl = PressureServo(**{k: v for k, v in st0.meta["sim"]["control"].items() if k != "kind"})
        sim = Simulation.load(self.path, control=ctl, threads=threads)
        ph = phases(protocol)
        names = [q.name for q in ph] + ["done"]
        run = _Run(sim, protocol, ph, names.index(pk["phase"]), pk.get("history", []))
        run.fire = Fire.from_meta(pk["fire"]) if pk.get("fire") else None
        run.last_phi, run.n_still = pk.get("last_phi"), pk.get("n_still", 0)
        if run.phase == "test":
            sim.set_law(run.current.law)
        return run

    def due(self, run):
        if self.path is None or run.done:
            return False
        by_steps = self.every and run.state.step % self.every == 0
        return bool(by_steps) or (self.seconds is not None and
                                  time.perf_counter() - self.t >= self.seconds)

    def save(self, run, report=None):
        if self.path is None:
            return
        run.state.meta["packing"] = run.to_meta()
        if report is not None:
            run.state.meta["packing"]["report"] = {k: v for k, v in report.scalars().items()
                                                   if k not in ("resumed", "already_converged")}
        run.sim.save(self.path)
        self.step, self.t = run.state.step, time.perf_counter()


def pack(protocol, *, max_steps=2_000_000, checkpoint=None, checkpoint_every=20000,
         checkpoint_seconds=None, progress=None, verbose=False, meta=None,
         threads=1) -> PackingResult:
    """The dense random packing made by ``protocol`` (a :class:`PackingProtocol`; the phases
    in the module docstring). ``protocol.n`` is checked against the available memory first
    (:func:`check_memory`, ValueError).

    The keywords are run options (how long and where it runs, not how the packing is made;
    :func:`check_run_options`): ``max_steps`` cap on the total step count (then
    ``report.converged`` is False); ``checkpoint`` path of an npz checkpoint, written
    atomically every ``checkpoint_every`` steps and/or ``checkpoint_seconds`` [s] of wall time
    (either None: off) and at the end, and resumed from if it exists (bit-exact; it must hold
    the same protocol; a finished run's returns its stored report with
    ``already_converged=True``); ``progress(info)`` called at every check (dict ``step``,
    ``max_steps``, ``phase``, ``phi``, ``Z``, ``rel_p_err``, ``unbalanced``, ``ke_rel`` (None
    when not evaluated), ``checkpoint_step``); ``verbose`` prints a line every tenth check;
    ``meta`` JSON-able dict merged into ``state.meta`` of a new run; ``threads`` of the
    contact-force loop, in [1, 1024] (reproducible for a given number of threads).

    An unstable run raises :class:`dem.runtime.InstabilityError` (``state`` = last good state);
    its ``checkpoint``/``checkpoint_step`` attributes name the last checkpoint written (None if
    none), which the error never overwrites.
    """
    t_start = time.perf_counter()
    if not isinstance(protocol, PackingProtocol):
        raise TypeError(f"pack takes a PackingProtocol (dem.engine.packing.PackingProtocol(n=..., ...)), "
                        f"got {type(protocol).__name__}")
    max_steps, every, seconds, threads = check_run_options(
        max_steps=max_steps, checkpoint_every=checkpoint_every,
        checkpoint_seconds=checkpoint_seconds, threads=threads)
    check_memory(protocol.n)
    ck = _Checkpoints(checkpoint, every, seconds)
    run = ck.resume(protocol, threads)
    if isinstance(run, tuple):                                  # a finished run
        return PackingResult(run[0], protocol.laws()[1], run[1], protocol)
    resumed = run is not None
    run = run or _new_run(protocol, threads, meta)
    state, check_every = run.state, protocol.check_every
    try:
        # steps in chunks ending at absolute multiples of check_every: the checks (and therefore
        # the trajectory) do not depend on where a run was interrupted and resumed
        while not run.done and state.step < max_steps:
            run.advance(min(check_every - state.step % check_every, max_steps - state.step))
            if state.step % check_every:
                continue
            m = run.check(verbose)
            if progress is not None:
                progress(run.info(m, max_steps, ck.step))
            if ck.due(run):
                ck.save(run)
    except InstabilityError as exc:
        exc.checkpoint = None if ck.step is None else os.fspath(checkpoint)
        exc.checkpoint_step = ck.step
        raise
    res = PackingResult(state, run.sim.law, run.report(t_start, resumed), protocol)
    ck.save(run, res.report if run.done else None)
    return res
