"""Normal contact laws of a static contact network: force and tangent stiffness from the overlap.

A law gives, per contact, the normal force ``fn`` (compression positive) and the tangent normal
stiffness ``kn = d fn / d delta`` from the radii ``r_i, r_j`` [m] and the overlap
``delta = r_i + r_j - |c|`` [m] (positive when the disks overlap), so that a network built from
positions and radii (``microhom.network.from_overlaps(..., law=...)``) carries forces consistent
with its stiffnesses, as the pre-stressed stiffness (``prestress=True``) needs. 2D: forces [N],
stiffnesses [N/m] (``docs/theory.md``, "Conventions").

* :class:`Linear` -- ``fn = kn delta`` (this project's DEM, LAMMPS ``gran/hooke``; Kuhn's OVAL
  ``kn`` multiplies half the overlap: see :mod:`microhom.conventions`).
* :class:`SoftSphere` -- jax-md's ``energy.soft_sphere``: ``U = eps/alpha (1 - d/sigma)^alpha`` with
  ``sigma = r_i + r_j``; ``alpha = 2`` is the harmonic law (:func:`harmonic`,
  ``kn = eps / sigma^2``), ``alpha = 5/2`` jax-md's Hertzian one.
* :class:`Hertz` -- ``fn = kh delta^{3/2}`` (``dem.engine.contact_models.Hertz``), or with
  ``reff=True`` LAMMPS ``gran/hertz/history``: ``fn = kn sqrt(R_eff delta) delta``,
  ``R_eff = r_i r_j / (r_i + r_j)``.

Every law also carries the tangential-to-normal stiffness ratio ``kt_ratio`` used when a network
is built with it and no ``kt`` is given (0 for jax-md, which has no friction), and has two
methods taking (C,) arrays ``ri``, ``rj``, ``overlap`` [m] (or scalars, broadcast):
``force(ri, rj, overlap)``, the (C,) normal force ``fn`` [N] (0 where ``overlap <= 0``), and
``stiffness(ri, rj, overlap)``, the (C,) tangent stiffness ``kn = d fn / d overlap`` [N/m].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Linear", "SoftSphere", "Hertz", "harmonic"]


def _positive(name, v, allow_zero=False):
    v = float(v)
    ok = np.isfinite(v) and (v >= 0 if allow_zero else v > 0)
    if not ok:
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'} and finite, got {v}")
    return v


class _Law:
    kt_ratio: float

    def __post_init__(self):
        _positive("kt_ratio", self.kt_ratio, allow_zero=True)

    def force(self, ri, rj, overlap) -> np.ndarray:
        """(C,) normal force fn [N], compression positive (0 where ``overlap <= 0``)."""
        d = np.clip(np.asarray(overlap, dtype=float), 0.0, None)
        return self._force(np.asarray(ri, float), np.asarray(rj, float), d)

    def stiffness(self, ri, rj, overlap) -> np.ndarray:
        """(C,) tangent normal stiffness kn = d fn / d overlap [N/m] (0 where ``overlap < 0``)."""
        o = np.asarray(overlap, dtype=float)
        k = self._stiffness(np.asarray(ri, float), np.asarray(rj, float), np.clip(o, 0.0, None))
        return np.where(o < 0, 0.0, k)

    def energy(self, ri, rj, overlap) -> np.ndarray:
        """(C,) contact energy U [J/m] with ``fn = dU/d overlap``."""
        d = np.clip(np.asarray(overlap, dtype=float), 0.0, None)
        return self._energy(np.asarray(ri, float), np.asarray(rj, float), d)


@dataclass(frozen=True)
class Linear(_Law):
    """``fn = kn delta``, constant ``kn`` [N/m] > 0; ``kt = kt_ratio kn`` (default 1)."""

    kn: float = 1.0
    kt_ratio: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        _positive("kn", self.kn)

    def _force(self, ri, rj, d):
        return self.kn * d

    def _stiffness(self, ri, rj, d):
        return np.full(np.broadcast(ri, rj, d).shape, self.kn)

    def _energy(self, ri, rj, d):
        return 0.5 * self.kn * d ** 2


@dataclass(frozen=True)
class SoftSphere(_Law):
    """jax-md's soft sphere: ``U = epsilon/alpha (1 - d/sigma)^alpha`` for ``d < sigma = r_i + r_j``.

    ``fn = (epsilon/sigma) (delta/sigma)^(alpha-1)``, ``kn = (alpha-1) (epsilon/sigma^2)
    (delta/sigma)^(alpha-2)``. epsilon [J/m] > 0; alpha >= 2 (2: harmonic, 5/2: Hertzian).
    ``kt_ratio`` defaults to 0: jax-md's particles have no friction and no spins.
    """

    epsilon: float = 1.0
    alpha: float = 2.0
    kt_ratio: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        _positive("epsilon", self.epsilon)
        if not (np.isfinite(self.alpha) and self.alpha >= 2):
            raise ValueError(f"alpha must be >= 2 (2 harmonic, 2.5 Hertzian), got {self.alpha}")

    def _force(self, ri, rj, d):
        s = ri + rj
        return self.epsilon / s * (d / s) ** (self.alpha - 1)

    def _stiffness(self, ri, rj, d):
        s = ri + rj
        return (self.alpha - 1) * self.epsilon / s ** 2 * (d / s) ** (self.alpha - 2)

    def _energy(self, ri, rj, d):
        return self.epsilon / self.alpha * (d / (ri + rj)) ** self.alpha


def harmonic(epsilon=1.0) -> SoftSphere:
    """jax-md's harmonic soft disks: ``kn = epsilon / (r_i + r_j)^2`` [N/m], ``fn = kn delta``, no
    friction (``epsilon`` [J/m] > 0: :class:`SoftSphere` with ``alpha = 2``)."""
    return SoftSphere(epsilon=epsilon, alpha=2.0)


@dataclass(frozen=True)
class Hertz(_Law):
    """Hertzian normal law ``fn = kh delta^{3/2}`` (``kn = 3/2 kh delta^{1/2}``), kh [N/m^{3/2}].

    ``reff=True``: LAMMPS ``gran/hertz/history``, ``fn = kh sqrt(R_eff) delta^{3/2}`` with
    ``R_eff = r_i r_j / (r_i + r_j)`` (kh is then LAMMPS's ``kn`` [N/m^2]). ``kt_ratio`` defaults to
    1; LAMMPS's default is 2/7 (:data:`microhom.conventions.LAMMPS_KT_RATIO`).
    """

    kh: float = 1.0
    reff: bool = False
    kt_ratio: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        _positive("kh", self.kh)

    def _k(self, ri, rj):
        return self.kh * np.sqrt(ri * rj / (ri + rj)) if self.reff else self.kh

    def _force(self, ri, rj, d):
        return self._k(ri, rj) * d ** 1.5

    def _stiffness(self, ri, rj, d):
        return 1.5 * self._k(ri, rj) * np.sqrt(d)

    def _energy(self, ri, rj, d):
        return 0.4 * self._k(ri, rj) * d ** 2.5
