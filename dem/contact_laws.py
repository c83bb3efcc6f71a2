"""Contact laws for 2D disks, each a composition of sub-models (:mod:`dem.contact_models`).

Conventions (2D, per unit thickness; any consistent units, e.g. SI: forces [N/m], stiffnesses
[N/m per m of overlap, written N/m as in the DEM literature], lengths [m]):

* branch ``l = x_j + h s - x_i``, normal ``n = l/|l|`` from i to j, tangent ``t = (-n_y, n_x)``;
* overlap ``delta = r_i + r_j - |l|`` (> 0 in contact);
* force on j ``F = fn n + ft t`` (fn > 0 repulsive), on i ``-F``; torques on i and j ``-r_i ft`` and
  ``-r_j ft`` (lever arms = radii);
* relative velocity of j's contact point w.r.t. i's: ``dv = v_j - v_i + L l - (w_i r_i + w_j r_j) t``
  (fluctuation velocities plus the affine field of the cell);
* tangential history (this project's rule, :class:`~dem.contact_models.LinearHistory`): a scalar
  ``ft`` along ``t`` (the spring turns rigidly with the contact), incremented by
  ``-kt (dv . t) dt`` and capped at the Coulomb limit ``|ft| <= mu max(fn, 0)``; reset when the
  contact opens. The LAMMPS rule is :class:`~dem.contact_models.LammpsHistory` (see
  :class:`LammpsHookeHistory` and ``docs/dem.md``).

Viscous normal damping from a restitution coefficient ``e`` in (0, 1]: damping ratio
``zeta = -ln e / sqrt(pi^2 + ln^2 e)``, dashpot ``c = 2 zeta sqrt(m_eff kn)`` with
``m_eff = m_i m_j / (m_i + m_j)``; for the linear law the coefficient of restitution of a binary
collision is then exactly ``e`` and the contact lasts ``pi / (omega0 sqrt(1 - zeta^2))``,
``omega0 = sqrt(kn / m_eff)``.

Laws (frozen dataclasses; ``models`` is the tuple (normal, damping, tangential, rolling) of
sub-models the pair loop is compiled for):

* :class:`Frictionless` — linear normal spring, no history, no spins.
* :class:`LinearFriction` — linear normal spring kn, tangential spring kt, Coulomb mu, spins.
* :class:`HertzMindlin` — ``fn = kh delta^{3/2}`` (the 3D sphere form applied to disks, as in
  Yade/LAMMPS 2D runs), tangent ``kt = kt_ratio * dfn/ddelta``, incremental Coulomb history.
* :class:`HertzRolling` — :class:`HertzMindlin` plus rolling resistance (one extra sub-model).
* :class:`LammpsHookeHistory` — LAMMPS ``pair_style gran/hooke/history`` to round-off (issue 14).
* :class:`ContactLaw` — any other combination of sub-models.

The pair loop fills ``f`` (N, 2) (and ``torque`` (N,) if spins) with the contact resultants and
``out`` (8,) with: ``S_xx, S_xy, S_yx, S_yy`` (sum of F_a l_b, so that the Love-Weber stress is
``sigma = -S/A``, tension positive), number of contacts, sum of |F| over contacts, elastic energy,
``sum kn_c |l_c|^2`` (the affine isotropic stiffness numerator used by the pressure servo).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from . import contact_models as cm
from .contact_models import damping_ratio

__all__ = ["Frictionless", "LinearFriction", "HertzMindlin", "HertzRolling", "LammpsHookeHistory",
           "ContactLaw", "damping_ratio", "law_from_meta"]


def _viscous(restitution, tangential=False):
    if restitution is None:
        return cm.NoDamping()
    cls = cm.ViscousTangential if tangential else cm.Viscous
    return cls.from_restitution(restitution)


class _Composed:
    """What every law derives from its sub-models ``self.models``."""

    def _compose(self, normal, damping, tangential, rolling=cm.NoRolling()):
        models = (normal, damping, tangential, rolling)
        for m in models:
            m.check()
        parity = tuple(tangential.PARITY) + tuple(rolling.PARITY)
        for name, value in (("models", models),
                            # spins: a tangential force or a rolling torque
                            ("needs_spin", bool(tangential.SPIN) or not isinstance(rolling, cm.NoRolling)),
                            # per history slot: +1 if unchanged when the pair's i and j are swapped,
                            # -1 if negated
                            ("history_parity", parity),
                            ("history_size", len(parity)),
                            ("needs_history", len(parity) > 0)):
            object.__setattr__(self, name, value)

    def pair_constants(self, mass, pi, pj):
        """Per-pair constants of the damping model (recomputed at each list build)."""
        normal, damping = self.models[0], self.models[1]
        return cm.make_pair_constants(damping, normal, mass, pi, pj, damping.NPC)

    def dt_stiffness(self):
        """Stiffness per possible contact entering the critical time step: the largest of the normal
        stiffness and the rotational one (tangential plus rolling; see :mod:`dem.integrate`)."""
        normal, _, tangential, rolling = self.models
        return max(normal.dt_stiffness(), tangential.dt_stiffness(normal) + rolling.dt_stiffness(normal))

    def tangent(self, delta):
        """(kn, kt) tangent stiffnesses at overlaps delta."""
        normal, tangential = self.models[0], self.models[2]
        return normal.tangent(delta), tangential.tangent(normal, delta)

    def fn_elastic(self, delta):
        return self.models[0].fn_elastic(delta)

    def with_friction(self, mu):
        return replace(self, mu=float(mu))


@dataclass(frozen=True)
class Frictionless(_Composed):
    """Linear normal spring ``fn = kn delta`` [N/m], no tangential force, no spins, no history.

    restitution : optional coefficient of restitution e in (0, 1] (viscous normal damping).
    """
    kn: float
    restitution: float | None = None

    def __post_init__(self):
        self._compose(cm.Hooke(self.kn), _viscous(self.restitution), cm.NoTangential())

    @property
    def mu(self):
        return 0.0

    @property
    def kt(self):
        return 0.0

    def with_friction(self, mu):
        if mu != 0:
            raise ValueError("Frictionless law: mu must be 0")
        return self

    def to_meta(self):
        return {"law": "Frictionless", "kn": self.kn, "restitution": self.restitution}


@dataclass(frozen=True)
class LinearFriction(_Composed):
    """Linear spring kn [N/m], tangential spring kt [N/m] with Coulomb limit mu, with spins.

    restitution : optional e in (0, 1] for viscous normal damping (see module docstring).
    tangential_damping : if True the same dashpot also acts on the tangential relative velocity
        (the Coulomb cap applies to the total tangential force).
    """
    kn: float
    kt: float
    mu: float
    restitution: float | None = None
    tangential_damping: bool = False

    def __post_init__(self):
        self._compose(cm.Hooke(self.kn), _viscous(self.restitution, self.tangential_damping),
                      cm.LinearHistory(self.kt, self.mu))

    def to_meta(self):
        return {"law": "LinearFriction", "kn": self.kn, "kt": self.kt, "mu": self.mu,
                "restitution": self.restitution, "tangential_damping": self.tangential_damping}


@dataclass(frozen=True)
class HertzMindlin(_Composed):
    """Hertz normal force ``fn = kh delta^{3/2}`` (kh [N/m^{3/2}]), Mindlin tangent stiffness
    ``kt = kt_ratio * 1.5 kh sqrt(delta)`` (incremental, no-slip), Coulomb mu, with spins.

    delta_ref : overlap [m] at which the tangent stiffness enters the critical time step.
    """
    kh: float
    mu: float
    delta_ref: float
    kt_ratio: float = 2.0 / 3.0
    restitution: float | None = None

    def __post_init__(self):
        self._compose(cm.Hertz(self.kh, self.delta_ref), _viscous(self.restitution),
                      cm.Mindlin(self.kt_ratio, self.mu))

    def to_meta(self):
        return {"law": "HertzMindlin", "kh": self.kh, "mu": self.mu, "delta_ref": self.delta_ref,
                "kt_ratio": self.kt_ratio, "restitution": self.restitution}


@dataclass(frozen=True)
class HertzRolling(_Composed):
    """:class:`HertzMindlin` with rolling resistance (:class:`~dem.contact_models.RollingResistance`):
    a torque spring ``k_r = kr_ratio k_n(delta) R_eff^2`` on the relative rotation of the two disks,
    capped at ``mu_r R_eff max(fn, 0)`` (``mu_r`` dimensionless rolling friction)."""
    kh: float
    mu: float
    delta_ref: float
    mu_r: float
    kr_ratio: float = 0.25
    kt_ratio: float = 2.0 / 3.0
    restitution: float | None = None

    def __post_init__(self):
        self._compose(cm.Hertz(self.kh, self.delta_ref), _viscous(self.restitution),
                      cm.Mindlin(self.kt_ratio, self.mu), cm.RollingResistance(self.kr_ratio, self.mu_r))

    def to_meta(self):
        return {"law": "HertzRolling", "kh": self.kh, "mu": self.mu, "delta_ref": self.delta_ref,
                "mu_r": self.mu_r, "kr_ratio": self.kr_ratio, "kt_ratio": self.kt_ratio,
                "restitution": self.restitution}


@dataclass(frozen=True)
class LammpsHookeHistory(_Composed):
    """LAMMPS ``pair_style gran/hooke/history kn kt gamma_n gamma_t mu dampflag``, followed to
    round-off (``tests/test_lammps_equivalence.py``).

    kn, kt [N/m]; gamma_n, gamma_t [1/s] (dashpots ``m_eff gamma``; ``gamma_t = None`` is LAMMPS'
    ``NULL``, meaning ``gamma_n / 2``; ``dampflag = 0`` drops the tangential dashpot); mu.
    Differences from :class:`LinearFriction` (see ``docs/dem.md``): dashpot ``m_eff gamma`` instead of
    ``2 zeta sqrt(m_eff kn)``; Coulomb cap ``mu |fn|`` instead of ``mu max(fn, 0)``; the shear
    displacement is a vector, projected on the tangent plane each step (it shrinks by ``cos`` of
    the contact's rotation) instead of a scalar turning rigidly with the contact. For LAMMPS'
    start-up convention (velocities at the integer time, no history increment in the setup force
    call), run it with ``Simulation(..., startup="lammps")``.
    """
    kn: float
    kt: float
    gamma_n: float
    mu: float
    gamma_t: float | None = None
    dampflag: int = 1

    def __post_init__(self):
        if self.dampflag not in (0, 1):
            raise ValueError(f"dampflag must be 0 or 1, got {self.dampflag}")
        self._compose(cm.Hooke(self.kn), cm.MassGamma.lammps(self.gamma_n, self.gamma_t, self.dampflag),
                      cm.LammpsHistory(self.kt, self.mu))

    def to_meta(self):
        return {"law": "LammpsHookeHistory", "kn": self.kn, "kt": self.kt, "gamma_n": self.gamma_n,
                "mu": self.mu, "gamma_t": self.gamma_t, "dampflag": self.dampflag}


@dataclass(frozen=True)
class ContactLaw(_Composed):
    """Any combination of sub-models of :mod:`dem.contact_models` (normal, damping, tangential,
    rolling), e.g. ``ContactLaw(Hertz(1e5, 0.01), MassGamma(5.0, 2.5), LammpsHistory(1e4, 0.5))``."""
    normal: object
    damping: object = cm.NoDamping()
    tangential: object = cm.NoTangential()
    rolling: object = cm.NoRolling()

    def __post_init__(self):
        for role, m, allowed in (("normal", self.normal, (cm.Hooke, cm.Hertz)),
                                 ("damping", self.damping, (cm.NoDamping, cm.Viscous, cm.ViscousTangential,
                                                            cm.MassGamma)),
                                 ("tangential", self.tangential, (cm.NoTangential, cm.LinearHistory,
                                                                  cm.Mindlin, cm.LammpsHistory)),
                                 ("rolling", self.rolling, (cm.NoRolling, cm.RollingResistance))):
            if not isinstance(m, allowed):
                raise ValueError(f"{role} model must be one of {[c.__name__ for c in allowed]}, got {m!r}")
        self._compose(self.normal, self.damping, self.tangential, self.rolling)

    @property
    def mu(self):
        return self.tangential.mu

    def with_friction(self, mu):
        if isinstance(self.tangential, cm.NoTangential):
            return Frictionless.with_friction(self, mu)
        return replace(self, tangential=self.tangential._replace(mu=float(mu)))

    def to_meta(self):
        def d(m):
            return {"model": type(m).__name__, **{k: float(v) for k, v in m._asdict().items()}}
        return {"law": "ContactLaw", "normal": d(self.normal), "damping": d(self.damping),
                "tangential": d(self.tangential), "rolling": d(self.rolling)}


_LAWS = {c.__name__: c for c in (Frictionless, LinearFriction, HertzMindlin, HertzRolling,
                                 LammpsHookeHistory, ContactLaw)}


def law_from_meta(meta: dict):
    """Rebuild a law from its ``to_meta()`` dict (used by checkpoints)."""
    meta = dict(meta)
    kind = meta.pop("law")
    if kind not in _LAWS:
        raise ValueError(f"unknown contact law {kind!r} (known: {sorted(_LAWS)})")
    if kind == "ContactLaw":
        meta = {role: cm.SUBMODELS[m.pop("model")](**m) for role, m in ((r, dict(v)) for r, v in meta.items())}
    return _LAWS[kind](**meta)
