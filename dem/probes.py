"""Strain probes: the incremental stiffness measured by the DEM itself.

A probe applies a small homogeneous strain increment to the periodic cell of a relaxed packing
(through the cell's velocity gradient ``L`` over ``ramp_steps`` steps, so contact histories and
sliding follow the deformation as in any DEM run), then relaxes the particles with local damping
until the unbalanced force ratio is below ``tol_unbalanced``, and takes ``Delta sigma / Delta eps``.
Each of the three Mandel strain modes ``[xx, yy, sqrt2 xy]`` is probed with ``+eps`` and
``-eps``; the central difference removes the second-order (geometric) terms, so the result is
the tangent stiffness at the packing's state. It is the second, independent route to the tensor
computed by :func:`dem.stiffness.stiffness` (exact linear response): the two must agree for a
small probe. The measured stress is the DEM's Cauchy stress (Love-Weber over the current cell),
so compare with ``stiffness(..., prestress=True)``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .integrate import Simulation

__all__ = ["ProbeResult", "strain_probes"]

_MODES = (np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 0.0], [0.0, 1.0]]),
          np.array([[0.0, 1.0], [1.0, 0.0]]) / np.sqrt(2.0))  # unit Mandel strains


@dataclass
class ProbeResult:
    """C_mandel (3x3) [N/m], K, G (isotropic projection) and the cost of the measurement."""
    C_mandel: np.ndarray
    K: float
    G: float
    amplitude: float
    steps: int
    wall_time: float
    converged: bool
    unbalanced: list = field(default_factory=list)  # final unbalanced ratio of each probe
    contact_events: int = 0  # contacts opened + closed, summed over the six probes

    def summary(self):
        return (f"strain probes (amplitude {self.amplitude:g}): K = {self.K:.6g}, G = {self.G:.6g}, "
                f"{self.steps} steps in {self.wall_time:.2f} s, converged = {self.converged}, "
                f"contact events = {self.contact_events}")


def _contact_set(state):
    """Set of touching pairs (original particle ids, image shift) of a state's neighbour list."""
    i, j, sh = state.nl_i, state.nl_j, state.nl_shift
    br = state.x[j] + sh @ state.h.T - state.x[i]
    touch = np.hypot(br[:, 0], br[:, 1]) < state.radius[i] + state.radius[j]
    ids = state.ids
    return {(int(a), int(b)) for a, b in zip(ids[i[touch]], ids[j[touch]])}


def _quiet(state):
    """Zero the fluctuation velocities: free rattlers feel no force (local damping cannot stop
    them), and one drifting into a neighbour would add a contact during the probe."""
    state.v[:] = 0.0
    if state.omega is not None:
        state.omega[:] = 0.0


def _relax(sim, tol_unbalanced, max_steps, check_every):
    steps = 0
    m = sim.measure()
    while steps < max_steps:
        sim.run(check_every)
        steps += check_every
        m = sim.measure()
        if m["unbalanced"] < tol_unbalanced:
            return m, steps, True
    return m, steps, False


def strain_probes(state, law, *, amplitude=1e-8, ramp_steps=200, tol_unbalanced=1e-8, max_steps=200_000,
                  check_every=100, damping=0.7, dt=None) -> ProbeResult:
    """Measure the 3x3 Mandel stiffness of a relaxed packing by +-``amplitude`` strain probes.

    Parameters
    ----------
    state : :class:`dem.state.State` of an equilibrated packing (not modified; probes run on copies).
    law : its contact law (e.g. ``PackingResult.law``).
    amplitude : strain increment per probe (dimensionless), > 0; small enough that no new contacts
        open or close: at p/kn = 1e-4 the smallest gaps are ~1e-7 D, so 1e-8 agrees with the
        exact response to ~1e-5 while 1e-6 already differs by ~1-4 % (studies.error_vs_runtime).
        ``contact_events`` in the result counts contacts that opened or closed during the probes.
    ramp_steps : steps over which the strain is applied through the cell velocity gradient.
    tol_unbalanced : relaxation criterion (Yade's unbalanced force ratio).
    max_steps : cap on the relaxation steps of one probe (the result is then ``converged=False``).
    damping : Cundall local damping during the relaxation.
    """
    from microhom.tensors import isotropic_moduli

    if not (np.isfinite(amplitude) and 0 < amplitude < 0.01):
        raise ValueError(f"amplitude must be in (0, 0.01), got {amplitude}")
    if int(ramp_steps) < 1:
        raise ValueError(f"ramp_steps must be >= 1, got {ramp_steps}")
    t0 = time.perf_counter()
    base = Simulation(state.copy(), law, damping=damping, dt=dt, control=None)
    base.state.L = np.zeros((2, 2))
    _quiet(base.state)
    m0, n0, ok0 = _relax(base, tol_unbalanced, max_steps, check_every)
    ref = base.state
    _quiet(ref)
    C = np.zeros((3, 3))
    total, all_ok, unb, events = n0, ok0, [], 0
    ref_contacts = _contact_set(ref)
    for k, E in enumerate(_MODES):
        sig = []
        for sign in (1.0, -1.0):
            sim = Simulation(ref.copy(), law, damping=damping, dt=base.dt, control=None)
            h0 = sim.state.h.copy()
            sim.state.L = sign * amplitude * E / (ramp_steps * sim.dt)
            sim.run(int(ramp_steps))
            sim.state.L = np.zeros((2, 2))
            m, n, ok = _relax(sim, tol_unbalanced, max_steps, check_every)
            total += int(ramp_steps) + n
            all_ok &= ok
            unb.append(m["unbalanced"])
            events += len(ref_contacts ^ _contact_set(sim.state))
            F = sim.state.h @ np.linalg.inv(h0)
            eps = 0.5 * (F + F.T) - np.eye(2)
            sig.append((m["stress"], eps))
        (s_p, e_p), (s_m, e_m) = sig
        de = e_p - e_m
        de_mandel = np.array([de[0, 0], de[1, 1], np.sqrt(2) * de[0, 1]])
        ds = s_p - s_m
        C[:, k] = np.array([ds[0, 0], ds[1, 1], np.sqrt(2) * ds[0, 1]]) / de_mandel[k]
    K, G = isotropic_moduli(C)
    return ProbeResult(C_mandel=C, K=K, G=G, amplitude=amplitude, steps=total,
                       wall_time=time.perf_counter() - t0, converged=bool(all_ok), unbalanced=unb,
                       contact_events=events)
