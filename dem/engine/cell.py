"""Periodic deformable cell (2D): shape matrix, velocity gradient, wrapping and cell control.

The cell is the parallelogram spanned by the columns of the shape matrix ``h`` (2x2) [m], with its
origin at (0, 0). Fractional coordinates are ``s = h^{-1} x``; a position is wrapped by ``s -> s -
floor(s)`` (``heights``, ``fractional`` and ``wrap`` are those of :mod:`microhom.periodic`). The cell deforms with the velocity gradient ``L`` [1/s]: ``dh/dt = L h``. Particle
velocities are stored as fluctuations about the affine field (total velocity ``v + L x``, Yade
``homoDeform`` style) and one explicit step maps both the cell and the positions with the same
operator ``(I + dt L)``, so branch vectors ``x_j + h s - x_i`` are identical whichever image
represents a particle.

Cell control (called once per step with the measured stress):

* :class:`StrainRate` — imposed constant velocity gradient ``L``.
* :class:`PressureServo` — isotropic servo on the mean stress, target pressure ``p_target > 0``
  (compression positive, ``p = -tr(sigma)/2``, 2D: force per length [N/m]). Stiffness-adaptive
  gain: the isotropic strain rate is ``edot = -alpha (p_target - p) / (K dt)`` where
  ``K = sum_c kn_c |l_c|^2 / (2 A)`` is the affine isotropic stiffness ``dp/d(eps)`` of the contact
  network (``eps`` the strain per direction), capped at ``max_rate`` [1/s]; with no contacts the
  cell compresses (or expands) at ``max_rate``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from microhom.periodic import fractional, heights, wrap  # noqa: F401  (the cell's geometry, re-exported)

__all__ = ["heights", "wrap", "fractional", "StrainRate", "PressureServo", "rotation"]


def rotation(angle) -> np.ndarray:
    """(2, 2) rotation matrix by ``angle`` [rad], counter-clockwise."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


@dataclass
class StrainRate:
    """Imposed constant velocity gradient L (2, 2) [1/s] (e.g. ``[[-e, 0], [0, -e]]`` compresses)."""
    L: np.ndarray

    def __post_init__(self):
        self.L = np.array(self.L, dtype=float).reshape(2, 2)
        if not np.all(np.isfinite(self.L)):
            raise ValueError("L must be finite")

    def update(self, state, p, K, dt):
        """The velocity gradient (2, 2) [1/s] for the next step: ``L`` (the arguments are unused)."""
        return self.L

    def to_meta(self):
        """JSON-ready dict of the control (stored in checkpoints)."""
        return {"kind": "strain_rate", "L": self.L.tolist()}


@dataclass
class PressureServo:
    """Isotropic servo-control of the pressure p = -tr(sigma)/2 [N/m] to ``p_target`` (> 0).

    Parameters
    ----------
    p_target : float
        Target pressure [N/m], > 0 (compression positive).
    max_rate : float
        Cap on the isotropic strain rate ``|edot|`` [1/s], > 0 (also the rate used while there are
        no contacts).
    alpha : float
        Fraction of the pressure error corrected per step with the affine stiffness, in (0, 1].
    """
    p_target: float
    max_rate: float
    alpha: float = 0.5

    def __post_init__(self):
        if not (np.isfinite(self.p_target) and self.p_target > 0):
            raise ValueError(f"p_target must be > 0 (compression positive), got {self.p_target}")
        if not (np.isfinite(self.max_rate) and self.max_rate > 0):
            raise ValueError(f"max_rate must be > 0 [1/s], got {self.max_rate}")
        if not (0 < self.alpha <= 1):
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")

    def rate(self, p, K, dt) -> float:
        """Isotropic strain rate [1/s] (negative = compression) for measured pressure ``p`` [N/m],
        affine isotropic stiffness ``K`` [N/m] and time step ``dt`` [s], capped at ``max_rate``."""
        err = self.p_target - p
        if K > 0:
            e = -self.alpha * err / (K * dt)
        else:
            e = -self.max_rate if err > 0 else self.max_rate
        return max(-self.max_rate, min(self.max_rate, e))

    def update(self, state, p, K, dt):
        """Velocity gradient (2, 2) [1/s] ``rate(p, K, dt) I`` for measured pressure ``p`` [N/m],
        affine isotropic stiffness ``K`` [N/m] and time step ``dt`` [s] (``state`` unused)."""
        e = self.rate(p, K, dt)
        return np.array([[e, 0.0], [0.0, e]])

    def to_meta(self):
        """JSON-ready dict of the control (stored in checkpoints)."""
        return {"kind": "pressure_servo", "p_target": self.p_target, "max_rate": self.max_rate,
                "alpha": self.alpha}
