"""FIRE velocity mixing (Bitzek, Koskinen, Gähler, Moseler and Gumbsch, PRL 97, 170201 (2006)) for
the packing phases of :mod:`dem.engine.packing`, at a fixed time step.

After each time step of the engine (forces ``F_n`` at ``x_n``, velocities ``v_{n+1/2}``), with the
generalised velocity ``u = (v_i, r_i w_i)`` and acceleration ``a = (F_i / m_i, r_i T_i / I_i)``
of every disk (translations and spins share one vector; ``r w`` is the rim speed, a velocity):

* the power ``P = sum_i F_i . v_i + T_i w_i`` [W/m];
* if ``P > 0``: ``u <- (1 - alpha) u + alpha |u| a / |a|`` (the velocity turned towards the
  force, its norm kept); after ``n_min`` consecutive steps with ``P > 0``,
  ``alpha <- alpha f_alpha``;
* if ``P <= 0``: every velocity and spin is set to zero and ``alpha <- alpha_start``.

FIRE's time-step growth is left out (the engine's ``dt`` is already 0.8 of the stability bound);
what remains is the velocity mixing and the quench on uphill motion, which stops the bouncing of
an underdamped assembly without the drag of a heavy damping. The velocities are fluctuations
about the affine field of the cell (``dem.engine.cell``): the quench does not stop the cell.
Defaults are those of Bitzek et al.: ``n_min = 5``, ``f_alpha = 0.99``, ``alpha_start = 0.1``.

The state of the mixing (``alpha``, the count of steps with ``P > 0``) is two numbers carried in
checkpoints (:meth:`Fire.to_meta`), so that a resumed run is bit-exact.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["Fire", "fire_mix"]


@njit(cache=True)
def fire_mix(v, f, mass, omega, torque, inertia, radius, alpha):
    """One FIRE mixing of ``v`` (N, 2) [m/s] and ``omega`` (N,) [1/s] (size 0: no spins) in place
    with forces ``f`` (N, 2) [N/m] and torques ``torque`` (N,) [N]; returns the power ``P`` [W/m]
    before the mixing. ``P <= 0`` zeroes the velocities and spins."""
    n = v.shape[0]
    spin = omega.shape[0] > 0
    p = 0.0
    u2 = 0.0
    a2 = 0.0
    for i in range(n):
        fx = f[i, 0]
        fy = f[i, 1]
        vx = v[i, 0]
        vy = v[i, 1]
        p += fx * vx + fy * vy
        u2 += vx * vx + vy * vy
        im = 1.0 / mass[i]
        a2 += (fx * fx + fy * fy) * im * im
        if spin:
            p += torque[i] * omega[i]
            rw = radius[i] * omega[i]
            ra = radius[i] * torque[i] / inertia[i]
            u2 += rw * rw
            a2 += ra * ra
    if p <= 0.0:
        for i in range(n):
            v[i, 0] = 0.0
            v[i, 1] = 0.0
            if spin:
                omega[i] = 0.0
        return p
    if a2 <= 0.0:
        return p
    c = 1.0 - alpha
    s = alpha * math.sqrt(u2 / a2)
    for i in range(n):
        im = s / mass[i]
        v[i, 0] = c * v[i, 0] + im * f[i, 0]
        v[i, 1] = c * v[i, 1] + im * f[i, 1]
        if spin:
            omega[i] = c * omega[i] + s * torque[i] / inertia[i]
    return p


@dataclass
class Fire:
    """FIRE mixing state and parameters (module docstring).

    Parameters: ``alpha_start`` [-] (mixing fraction after a quench, in (0, 1)), ``f_alpha`` [-]
    (factor on ``alpha`` per step with ``P > 0`` once ``n_min`` such steps followed each other),
    ``n_min`` (steps). State, changed as it runs: ``alpha`` [-], ``n_pos`` (steps with ``P > 0``
    since the last quench) and ``n_quench`` (number of quenches, informative)."""
    alpha_start: float = 0.1
    f_alpha: float = 0.99
    n_min: int = 5
    alpha: float = 0.1
    n_pos: int = 0
    n_quench: int = 0

    def __post_init__(self):
        if not (0 < self.alpha_start < 1):
            raise ValueError(f"alpha_start must be in (0, 1), got {self.alpha_start}")
        if not (0 < self.f_alpha <= 1):
            raise ValueError(f"f_alpha must be in (0, 1], got {self.f_alpha}")
        if int(self.n_min) != self.n_min or self.n_min < 0:
            raise ValueError(f"n_min must be an integer >= 0, got {self.n_min}")

    def update(self, sim):
        """Mix the velocities of ``sim`` (a :class:`dem.engine.integrate.Simulation`) after a step."""
        st = sim.state
        spin = sim.law.needs_spin
        e = _EMPTY
        p = fire_mix(st.v, sim.f, st.mass, st.omega if spin else e, sim.torque if spin else e,
                     st.inertia, st.radius, self.alpha)
        if p > 0:
            self.n_pos += 1
            if self.n_pos > self.n_min:
                self.alpha *= self.f_alpha
        else:
            self.n_pos = 0
            self.alpha = self.alpha_start
            self.n_quench += 1

    def to_meta(self) -> dict:
        """JSON-ready dict (stored in checkpoints; ``Fire.from_meta`` restores it bit-exactly)."""
        return {"alpha_start": self.alpha_start, "f_alpha": self.f_alpha, "n_min": self.n_min,
                "alpha": self.alpha, "n_pos": self.n_pos, "n_quench": self.n_quench}

    @classmethod
    def from_meta(cls, d):
        return cls(**d)


_EMPTY = np.zeros(0)
