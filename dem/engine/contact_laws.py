"""Contact laws for 2D disks, each a composition of sub-models (:mod:`dem.engine.contact_models`).

Conventions (2D, per unit thickness; any consistent units, e.g. SI: forces [N/m], stiffnesses
[N/m per m of overlap, written N/m as in the DEM literature], lengths [m]):

* branch ``l = x_j + h s - x_i``, normal ``n = l/|l|`` from i to j, tangent ``t = (-n_y, n_x)``;
* overlap ``delta = r_i + r_j - |l|`` (> 0 in contact);
* force on j ``F = fn n + ft t`` (fn > 0 repulsive), on i ``-F``; torques on i and j ``-a_i ft`` and
  ``-a_j ft`` with the spin arms ``a``: the distances to the contact point
  ``a_i = |l| r_i / (r_i + r_j)`` (``contact_arms=True``, as :mod:`microhom.kinematics`) or the
  radii ``a = r`` (``contact_arms=False``, the default, as LAMMPS ``gran/*`` and
  :class:`LammpsHookeHistory`);
* relative velocity of j's contact point w.r.t. i's: ``dv = v_j - v_i + L l - (w_i a_i + w_j a_j) t``
  (fluctuation velocities plus the affine field of the cell);
* tangential history (this project's rule, :class:`~dem.engine.contact_models.LinearHistory`): a scalar
  ``ft`` along ``t`` (the spring turns rigidly with the contact), incremented by
  ``-kt (dv . t) dt`` and capped at the Coulomb limit ``|ft| <= mu max(fn, 0)``; reset when the
  contact opens. The LAMMPS rule is :class:`~dem.engine.contact_models.LammpsHistory` (see
  :class:`LammpsHookeHistory` and ``docs/dem.md``).

Viscous normal damping from a restitution coefficient ``e`` in (0, 1]: damping ratio
``zeta = -ln e / sqrt(pi^2 + ln^2 e)``, dashpot ``c = 2 zeta sqrt(m_eff kn)`` with
``m_eff = m_i m_j / (m_i + m_j)``; for the linear law the coefficient of restitution of a binary
collision is then exactly ``e`` and the contact lasts ``pi / (omega0 sqrt(1 - zeta^2))``,
``omega0 = sqrt(kn / m_eff)``.

Laws (frozen dataclasses; ``models`` is the :class:`~dem.engine.contact_models.Models` bundle
(normal, damping, tangential, rolling) of sub-models the pair loop is compiled for):

* :class:`Frictionless` — linear normal spring, no history, no spins.
* :class:`LinearFriction` — linear normal spring kn, tangential spring kt, Coulomb mu, spins.
* :class:`HertzMindlin` — ``fn = kh delta^{3/2}`` (the 3D sphere form applied to disks, as in
  Yade/LAMMPS 2D runs), tangent ``kt = kt_ratio * dfn/ddelta``, incremental Coulomb history.
* :class:`HertzRolling` — :class:`HertzMindlin` plus rolling resistance (one extra sub-model).
* :class:`LammpsHookeHistory` — LAMMPS ``pair_style gran/hooke/history`` to round-off (issue 14).
* :class:`ContactLaw` — any other combination of sub-models.

The pair loop fills ``f`` (N, 2) (and ``torque`` (N,) if spins) with the contact resultants and
``out`` (8,) with: ``S_xx, S_xy, S_yx, S_yy`` (sum of ``F_a l_b``, so that the Love-Weber stress is
``sigma = -S/A``, tension positive), number of contacts, sum of ``|F|`` over contacts, elastic energy,
``sum kn_c |l_c|^2`` (the affine isotropic stiffness numerator used by the pressure servo).

Every law has the methods ``pair_constants`` (per-pair damping constants), ``dt_stiffness`` (the
stiffness entering the critical time step [N/m]), ``tangent(delta)`` (the tangent stiffnesses
``(kn, kt)`` [N/m] at overlaps ``delta`` [m], arrays of the shape of ``delta``), ``fn_elastic(delta)``
(the elastic normal force), ``with_friction(mu)`` (the same law with another friction coefficient)
and ``to_meta()`` (a JSON-ready dict that :func:`law_from_meta` turns back into the law).
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
        models = cm.with_arm_types(cm.Models(normal, damping, tangential, rolling))  # arms: a compiled type
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
        stiffness and the rotational one (tangential plus rolling; see :mod:`dem.engine.integrate`)."""
        normal, _, tangential, rolling = self.models
        return max(normal.dt_stiffness(), tangential.dt_stiffness(normal) + rolling.dt_stiffness(normal))

    def tangent(self, delta):
        """(kn, kt) tangent stiffnesses at overlaps delta."""
        normal, tangential = self.models[0], self.models[2]
        return normal.tangent(delta), tangential.tangent(normal, delta)

    def fn_elastic(self, delta):
        """Elastic normal force [N/m] at overlaps ``delta`` [m] (array of the same shape)."""
        return self.models[0].fn_elastic(delta)

    def with_friction(self, mu):
        """The same law with friction coefficient ``mu``."""
        return replace(self, mu=float(mu))


@dataclass(frozen=True)
class Frictionless(_Composed):
    """Linear normal spring ``fn = kn delta``, no tangential force, no spins, no history.

    Parameters
    ----------
    kn : float
        Normal stiffness [N/m], > 0.
    restitution : float or None
        Coefficient of restitution ``e`` in (0, 1] of a viscous normal dashpot (module docstring);
        None: no damping.
    """
    kn: float
    restitution: float | None = None

    def __post_init__(self):
        self._compose(cm.Hooke(self.kn), _viscous(self.restitution), cm.NoTangential())

    @property
    def mu(self):
        """The friction coefficient (always 0)."""
        return 0.0

    @property
    def kt(self):
        """The tangential stiffness [N/m] (always 0)."""
        return 0.0

    def with_friction(self, mu):
        """This law (only ``mu = 0`` is allowed; anything else raises ``ValueError``)."""
        if mu != 0:
            raise ValueError("Frictionless law: mu must be 0")
        return self

    def to_meta(self):
        """JSON-ready dict of the law's parameters (:func:`law_from_meta` rebuilds the law)."""
        return {"law": "Frictionless", "kn": self.kn, "restitution": self.restitution}


@dataclass(frozen=True)
class LinearFriction(_Composed):
    """Linear normal spring, tangential spring with a Coulomb limit, with spins.

    Parameters
    ----------
    kn : float
        Normal stiffness [N/m], > 0.
    kt : float
        Tangential stiffness [N/m], >= 0.
    mu : float
        Coulomb friction coefficient (dimensionless), >= 0.
    restitution : float or None
        Coefficient of restitution ``e`` in (0, 1] of a viscous normal dashpot (module docstring);
        None: no damping.
    tangential_damping : bool
        If True the same dashpot also acts on the tangential relative velocity (the Coulomb cap
        applies to the total tangential force).
    contact_arms : bool
        Spin arms: False (default) the radii, as LAMMPS ``gran/*``; True the distances to the
        contact point ``|l| r_i / (r_i + r_j)``, as the exact stiffness (:mod:`microhom.kinematics`)
        takes them, so that a rigid rotation slides no contact (see ``docs/dem.md``).
    """
    kn: float
    kt: float
    mu: float
    restitution: float | None = None
    tangential_damping: bool = False
    contact_arms: bool = False

    def __post_init__(self):
        self._compose(cm.Hooke(self.kn), _viscous(self.restitution, self.tangential_damping),
                      cm.LinearHistory(self.kt, self.mu, self.contact_arms))

    def to_meta(self):
        """JSON-ready dict of the law's parameters (:func:`law_from_meta` rebuilds the law)."""
        return {"law": "LinearFriction", "kn": self.kn, "kt": self.kt, "mu": self.mu,
                "restitution": self.restitution, "tangential_damping": self.tangential_damping,
                "contact_arms": self.contact_arms}


@dataclass(frozen=True)
class HertzMindlin(_Composed):
    """Hertz normal force ``fn = kh delta^{3/2}``, Mindlin tangent stiffness
    ``kt = kt_ratio * 1.5 kh sqrt(delta)`` (incremental, no-slip), Coulomb limit, with spins.

    Parameters
    ----------
    kh : float
        Hertz constant [N/m^{3/2}], > 0.
    mu : float
        Coulomb friction coefficient (dimensionless), >= 0.
    delta_ref : float
        Overlap [m] at which the tangent stiffness enters the critical time step, > 0.
    kt_ratio : float
        Ratio of the tangential to the normal tangent stiffness (default 2/3).
    restitution : float or None
        Coefficient of restitution ``e`` in (0, 1] of a viscous normal dashpot; None: no damping.
    contact_arms : bool
        Spin arms, as in :class:`LinearFriction` (default False: the radii).
    """
    kh: float
    mu: float
    delta_ref: float
    kt_ratio: float = 2.0 / 3.0
    restitution: float | None = None
    contact_arms: bool = False

    def __post_init__(self):
        self._compose(cm.Hertz(self.kh, self.delta_ref), _viscous(self.restitution),
                      cm.Mindlin(self.kt_ratio, self.mu, self.contact_arms))

    def to_meta(self):
        """JSON-ready dict of the law's parameters (:func:`law_from_meta` rebuilds the law)."""
        return {"law": "HertzMindlin", "kh": self.kh, "mu": self.mu, "delta_ref": self.delta_ref,
                "kt_ratio": self.kt_ratio, "restitution": self.restitution, "contact_arms": self.contact_arms}


@dataclass(frozen=True)
class HertzRolling(_Composed):
    """:class:`HertzMindlin` with rolling resistance (:class:`~dem.engine.contact_models.RollingResistance`):
    a torque spring ``k_r = kr_ratio k_n(delta) R_eff^2`` on the relative rotation of the two disks,
    capped at ``mu_r R_eff max(fn, 0)``.

    Parameters
    ----------
    kh, mu, delta_ref, kt_ratio, restitution
        As in :class:`HertzMindlin` (kh [N/m^{3/2}], delta_ref [m]).
    mu_r : float
        Rolling friction coefficient (dimensionless), >= 0.
    kr_ratio : float
        Rolling stiffness in units of ``k_n(delta) R_eff^2`` (default 0.25).
    contact_arms : bool
        Spin arms, as in :class:`LinearFriction` (default False: the radii).
    """
    kh: float
    mu: float
    delta_ref: float
    mu_r: float
    kr_ratio: float = 0.25
    kt_ratio: float = 2.0 / 3.0
    restitution: float | None = None
    contact_arms: bool = False

    def __post_init__(self):
        self._compose(cm.Hertz(self.kh, self.delta_ref), _viscous(self.restitution),
                      cm.Mindlin(self.kt_ratio, self.mu, self.contact_arms),
                      cm.RollingResistance(self.kr_ratio, self.mu_r))

    def to_meta(self):
        """JSON-ready dict of the law's parameters (:func:`law_from_meta` rebuilds the law)."""
        return {"law": "HertzRolling", "kh": self.kh, "mu": self.mu, "delta_ref": self.delta_ref,
                "mu_r": self.mu_r, "kr_ratio": self.kr_ratio, "kt_ratio": self.kt_ratio,
                "restitution": self.restitution, "contact_arms": self.contact_arms}


@dataclass(frozen=True)
class LammpsHookeHistory(_Composed):
    """LAMMPS ``pair_style gran/hooke/history kn kt gamma_n gamma_t mu dampflag``, followed to
    round-off (``tests/test_lammps_equivalence.py``).

    Parameters
    ----------
    kn, kt : float
        Normal and tangential stiffnesses [N/m].
    gamma_n : float
        Normal damping rate [1/s] (dashpot ``m_eff gamma_n``).
    mu : float
        Coulomb friction coefficient (dimensionless).
    gamma_t : float or None
        Tangential damping rate [1/s]; None is LAMMPS' ``NULL``, meaning ``gamma_n / 2``.
    dampflag : int
        1 (LAMMPS' default) or 0 (no tangential dashpot).

    Notes
    -----
    Differences from :class:`LinearFriction` (see ``docs/dem.md``): dashpot ``m_eff gamma`` instead of
    ``2 zeta sqrt(m_eff kn)``; Coulomb cap ``mu |fn|`` instead of ``mu max(fn, 0)``; the shear
    displacement is a vector, projected on the tangent plane each step (it shrinks by ``cos`` of
    the contact's rotation) instead of a scalar turning rigidly with the contact. For LAMMPS'
    start-up convention (velocities at the integer time, no history increment in the setup force
    call), run it with ``Simulation(..., startup="lammps")``. ``Simulation``'s damping defaults
    to 0 for this law (LAMMPS has no Cundall local damping) and a non-zero one is warned about:
    with the 0.7 of the other laws dv/v_rms was 0.1 after one step.
    """
    #: read by ``dem.engine.integrate.Simulation``: damping defaults to 0, a non-zero one is warned about
    LAMMPS_EQUIVALENT = True

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
        """JSON-ready dict of the law's parameters (:func:`law_from_meta` rebuilds the law)."""
        return {"law": "LammpsHookeHistory", "kn": self.kn, "kt": self.kt, "gamma_n": self.gamma_n,
                "mu": self.mu, "gamma_t": self.gamma_t, "dampflag": self.dampflag}


@dataclass(frozen=True)
class ContactLaw(_Composed):
    """Any combination of sub-models of :mod:`dem.engine.contact_models`, e.g.
    ``ContactLaw(Hertz(1e5, 0.01), MassGamma(5.0, 2.5), LammpsHistory(1e4, 0.5))``.

    Parameters
    ----------
    normal : Hooke or Hertz
        Normal force model.
    damping : NoDamping, Viscous, ViscousTangential or MassGamma
        Dashpot model (default none).
    tangential : NoTangential, LinearHistory, Mindlin or LammpsHistory
        Tangential force model (default none: frictionless, no spins).
    rolling : NoRolling or RollingResistance
        Rolling resistance model (default none).
    """
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
        """Friction coefficient of the tangential sub-model."""
        return self.tangential.mu

    def with_friction(self, mu):
        """The same law with the tangential sub-model's friction coefficient set to ``mu``."""
        if isinstance(self.tangential, cm.NoTangential):
            return Frictionless.with_friction(self, mu)
        return replace(self, tangential=self.tangential._replace(mu=float(mu)))

    def to_meta(self):
        """JSON-ready dict of the sub-models and their coefficients (:func:`law_from_meta` rebuilds
        the law)."""
        def d(m):
            return {"model": type(m).__name__,
                    **{k: v if isinstance(v, bool) else float(v) for k, v in m._asdict().items()}}
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
