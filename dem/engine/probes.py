"""Strain probes: the incremental stiffness measured by the DEM itself.

A probe applies a small homogeneous strain increment to the periodic cell of a relaxed packing
(through the cell's velocity gradient ``L`` over ``ramp_steps`` steps, so contact histories and
sliding follow the deformation as in any DEM run), then relaxes the particles with local damping
until the unbalanced force ratio is below ``tol_unbalanced``, and takes ``Delta sigma / Delta eps``.
Each of the three Mandel strain modes ``[xx, yy, sqrt2 xy]`` is probed with ``+eps`` and
``-eps``; the central difference removes the second-order (geometric) terms, so the result is
the tangent stiffness at the packing's state. It is the second, independent route to the tensor
computed by :func:`dem.analysis.stiffness.stiffness` (exact linear response): the two must agree for a
small probe. The measured stress is the DEM's Cauchy stress (Love-Weber over the current cell),
so compare with ``stiffness(..., prestress=True)``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from microhom.results import Result
from microhom.tensors import isotropic_moduli, strain_to_mandel

from .integrate import Simulation

__all__ = ["ProbeResult", "StrainResponse", "strain_probes", "strain_response"]

_MODES = (np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 0.0], [0.0, 1.0]]),
          np.array([[0.0, 1.0], [1.0, 0.0]]) / np.sqrt(2.0))  # unit Mandel strains


@dataclass(frozen=True, eq=False)
class ProbeResult(Result):
    """The stiffness measured by strain probes, and the cost of the measurement.

    Attributes
    ----------
    C_mandel : (3, 3) array
        Tangent stiffness over Mandel ``[xx, yy, sqrt2 xy]`` [N/m] (Cauchy stress increment per
        strain, pre-stress included; column k from the +- probes of mode k).
    K, G : float
        Its isotropic projection [N/m] (:func:`microhom.tensors.isotropic_moduli`).
    amplitude : float
        Strain of each probe (dimensionless).
    steps : int
        DEM steps, all probes and the initial relaxation.
    wall_time : float
        Wall time of the measurement [s].
    converged : bool
        Every relaxation met ``tol_unbalanced``.
    unbalanced : (6,) tuple of float
        Final unbalanced force ratio of each probe (+xx, -xx, +yy, -yy, +xy, -xy).
    contact_events : int
        Contacts opened or closed, summed over the six probes (0 for a tangent measurement).
    """

    C_mandel: np.ndarray
    K: float
    G: float
    amplitude: float
    steps: int
    wall_time: float
    converged: bool
    unbalanced: tuple = ()
    contact_events: int = 0

    def summary(self):
        """One line: the moduli [N/m], the cost and the convergence."""
        return (f"strain probes (amplitude {self.amplitude:g}): K = {self.K:.6g}, G = {self.G:.6g}, "
                f"{self.steps} steps in {self.wall_time:.2f} s, converged = {self.converged}, "
                f"contact events = {self.contact_events}")


@dataclass(frozen=True, eq=False)
class StrainResponse(Result):
    """Response of a relaxed packing to one imposed homogeneous displacement gradient.

    stress0 : (2, 2) Love-Weber stress of the reference state [N/m], tension positive;
    stress : (2, 2) stress after the deformation and the relaxation [N/m];
    F : (2, 2) deformation gradient of the cell ``h h0^{-1}`` actually applied;
    strain : (2, 2) linear strain ``sym(F) - I``;
    steps : ramp + relaxation steps; converged : the relaxation met ``tol_unbalanced``;
    unbalanced : final unbalanced force ratio; contact_events : contacts opened or closed.
    """

    stress0: np.ndarray
    stress: np.ndarray
    F: np.ndarray
    strain: np.ndarray
    steps: int
    converged: bool
    unbalanced: float
    contact_events: int


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


def _reference(state, law, damping, dt, tol_unbalanced, max_steps, check_every):
    """The relaxed, quiet reference copy of ``state`` under a fixed cell."""
    base = Simulation(state.copy(), law, damping=damping, dt=dt, control=None)
    base.state.L = np.zeros((2, 2))
    _quiet(base.state)
    m0, n0, ok0 = _relax(base, tol_unbalanced, max_steps, check_every)
    _quiet(base.state)
    return base, m0, n0, ok0


def _deform(ref, law, dt, grad, ramp_steps, damping, tol_unbalanced, max_steps, check_every,
            ref_contacts, stress0):
    sim = Simulation(ref.copy(), law, damping=damping, dt=dt, control=None)
    h0 = sim.state.h.copy()
    sim.state.L = np.asarray(grad, dtype=float) / (ramp_steps * sim.dt)
    sim.run(int(ramp_steps))
    sim.state.L = np.zeros((2, 2))
    m, n, ok = _relax(sim, tol_unbalanced, max_steps, check_every)
    F = sim.state.h @ np.linalg.inv(h0)
    return StrainResponse(stress0=stress0, stress=np.array(m["stress"]), F=F,
                          strain=0.5 * (F + F.T) - np.eye(2), steps=int(ramp_steps) + n,
                          converged=bool(ok), unbalanced=float(m["unbalanced"]),
                          contact_events=len(ref_contacts ^ _contact_set(sim.state)))


def _check_ramp(ramp_steps):
    if int(ramp_steps) < 1:
        raise ValueError(f"ramp_steps must be >= 1, got {ramp_steps}")


def strain_response(state, law, grad, *, ramp_steps=200, tol_unbalanced=1e-8, max_steps=200_000,
                    check_every=100, damping=0.7, dt=None) -> StrainResponse:
    """Apply the displacement gradient ``grad`` (2, 2) to the cell of a relaxed packing (velocity
    gradient ``grad / T`` over ``ramp_steps`` steps), relax, and return the stresses before and
    after. ``grad`` may be any small gradient: a symmetric strain, a rigid rotation
    ``[[0, -w], [w, 0]]`` or zero. Other parameters as :func:`strain_probes`."""
    grad = np.asarray(grad, dtype=float)
    if grad.shape != (2, 2) or not np.all(np.isfinite(grad)) or np.abs(grad).max() >= 0.01:
        raise ValueError(f"grad must be a finite (2, 2) displacement gradient with entries below 0.01, got {grad!r}")
    _check_ramp(ramp_steps)
    base, m0, n0, ok0 = _reference(state, law, damping, dt, tol_unbalanced, max_steps, check_every)
    r = _deform(base.state, law, base.dt, grad, ramp_steps, damping, tol_unbalanced, max_steps, check_every,
                _contact_set(base.state), np.array(m0["stress"]))
    return replace(r, steps=r.steps + n0, converged=r.converged and ok0)


def strain_probes(state, law, *, amplitude=1e-8, ramp_steps=200, tol_unbalanced=1e-8, max_steps=200_000,
                  check_every=100, damping=0.7, dt=None) -> ProbeResult:
    """Measure the 3x3 Mandel stiffness of a relaxed packing by +-``amplitude`` strain probes.

    Parameters
    ----------
    state : :class:`dem.engine.state.State` of an equilibrated packing (not modified; probes run on copies).
    law : its contact law (e.g. ``PackingResult.law``).
    amplitude : strain increment per probe (dimensionless), in (0, 0.01); small enough that no new
        contacts open or close: at p/kn = 1e-4 the smallest gaps are ~1e-7 D, so 1e-8 agrees with
        the exact response to ~1e-5 while 1e-6 already differs by ~1-4 % (studies.error_vs_runtime).
        ``contact_events`` in the result counts contacts that opened or closed during the probes.
    ramp_steps : steps over which the strain is applied through the cell velocity gradient, >= 1.
    tol_unbalanced : relaxation criterion (Yade's unbalanced force ratio).
    max_steps : cap on the relaxation steps of one probe (the result is then ``converged=False``).
    damping : Cundall local damping during the relaxation.
    """
    if not (np.isfinite(amplitude) and 0 < amplitude < 0.01):
        raise ValueError(f"amplitude must be in (0, 0.01), got {amplitude}")
    _check_ramp(ramp_steps)
    t0 = time.perf_counter()
    base, m0, n0, ok0 = _reference(state, law, damping, dt, tol_unbalanced, max_steps, check_every)
    ref = base.state
    s0 = np.array(m0["stress"])
    ref_contacts = _contact_set(ref)
    C = np.zeros((3, 3))
    total, all_ok, unb, events = n0, ok0, [], 0
    for k, E in enumerate(_MODES):
        r = [_deform(ref, law, base.dt, sign * amplitude * E, ramp_steps, damping, tol_unbalanced,
                     max_steps, check_every, ref_contacts, s0) for sign in (1.0, -1.0)]
        for x in r:
            total += x.steps
            all_ok &= x.converged
            unb.append(x.unbalanced)
            events += x.contact_events
        de = strain_to_mandel(r[0].strain - r[1].strain)
        C[:, k] = strain_to_mandel(r[0].stress - r[1].stress) / de[k]
    K, G = isotropic_moduli(C)
    return ProbeResult(C_mandel=C, K=K, G=G, amplitude=amplitude, steps=total,
                       wall_time=time.perf_counter() - t0, converged=bool(all_ok), unbalanced=tuple(unb),
                       contact_events=events)
