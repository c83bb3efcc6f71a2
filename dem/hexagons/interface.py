"""Interface law between facing hexagon edges: penalty springs + generalised Mohr-Coulomb.

Units: Pa (tractions), Pa/m (kn, kt), m (jumps). Tension positive. Per unit edge length; the edge
force on cell i is ``L (sn n + tau t)``.

State of one interface: total normal traction ``sn``, shear traction ``tau``, previous tangential jump
``jt_prev``, ``broken`` (0 intact, 1 broke in tension, 2 broke in shear) and the gas pressure ``pg``
(set to 0 once the crack has opened more than ``vent_open`` — the gas escaped).

Intact (trial)::

    sn = sn0 + kn [u]n,   tau = tau_old + kt (jt - jt_prev),   sn' = sn + pg
    tension failure if sn' >= ft;  shear failure if |tau| >= c - sn' tan(phi)

Broken (also right after failing): no tension, and the contact re-closes where the intact spring
would be at zero effective stress; the faces carry the gas; Coulomb friction by return mapping::

    sn' = min(sn0 + kn [u]n + pg, 0),   sn = sn' - pg,   |tau| <= -sn' tan(phi_r)

Energy: stored e = L (sn^2/(2kn) + tau^2/(2kt)); the drop of e from the trial state at a break is
``d_break``; the plastic work ``|tau| |tau_tr - tau| / kt`` at a frictional return is ``d_fric`` (both
per unit length here, the kernel multiplies by L). While a gassy crack is open the gas does external
work pg L d[u]n.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["mc_update", "Strength", "Traction", "InterfaceLaw", "spring_stiffness_rule", "INTACT", "TENSION",
           "SHEAR"]

INTACT, TENSION, SHEAR = 0, 1, 2


@njit(cache=True, inline="always")
def _broken_law(sn_tr, tau_tr, pg, kn, tanphi_r, vent_open):
    """The broken interface: no tension, gas on the faces (vented once the crack opens more than
    ``vent_open``), Coulomb friction by return mapping. Returns (sn, tau, pg, is_open, vented)."""
    spb = sn_tr + pg
    is_open = spb > 0.0
    vented = False
    if is_open:
        spb = 0.0
        if pg > 0.0 and (sn_tr + pg) / kn > vent_open:
            vented = True
            pg = 0.0
    sn = spb - pg
    limr = -spb * tanphi_r
    tau = tau_tr
    if tau > limr:
        tau = limr
    elif tau < -limr:
        tau = -limr
    return sn, tau, pg, is_open, vented


class Strength(NamedTuple):
    """An interface's stiffness and strength: penalty springs ``kn``, ``kt`` [Pa/m], tensile
    strength ``ft`` and cohesion ``coh`` [Pa], friction ``tanphi`` (intact) and ``tanphi_r``
    (broken), and the opening ``vent_open`` [m] beyond which the gas escapes."""
    kn: float
    kt: float
    ft: float
    coh: float
    tanphi: float
    tanphi_r: float
    vent_open: float


class Traction(NamedTuple):
    """An interface's state before the update: the normal traction ``sn0`` of the spring at zero
    jump [Pa], the shear traction ``tau`` [Pa], ``broken`` (``INTACT``, ``TENSION``, ``SHEAR``) and
    the gas pressure ``pg`` [Pa]."""
    sn0: float
    tau: float
    broken: int
    pg: float


@njit(cache=True, inline="always")
def mc_update(jn, djt, state, law):
    """One update of the interface law for the normal jump ``jn`` and the tangential jump
    increment ``djt`` [m] from the :class:`Traction` ``state`` with the :class:`Strength` ``law``.
    Returns (sn, tau, broken, pg, d_break, d_fric, is_open) with energies per unit length
    [J/m^2 -> J/m per m of edge]. For an interface that was already broken, the fifth value is the
    energy of the vented gas instead of a break."""
    sn0, tau_old, broken, pg = state.sn0, state.tau, state.broken, state.pg
    kn, kt, ft, coh, tanphi = law.kn, law.kt, law.ft, law.coh, law.tanphi
    tanphi_r, vent_open = law.tanphi_r, law.vent_open
    sn_tr = sn0 + kn * jn
    tau_tr = tau_old + kt * djt
    if broken == 0:
        sp = sn_tr + pg
        lim = coh - sp * tanphi
        if sp >= ft:
            broken = 1
        elif abs(tau_tr) >= lim:
            broken = 2
        else:
            return sn_tr, tau_tr, 0, pg, 0.0, 0.0, False
        e_before = 0.5 * sn_tr * sn_tr / kn + 0.5 * tau_tr * tau_tr / kt
        # broken law below; energy drop charged to d_break
        sn, tau, pg, is_open, _ = _broken_law(sn_tr, tau_tr, pg, kn, tanphi_r, vent_open)
        e_after = 0.5 * sn * sn / kn + 0.5 * tau * tau / kt
        return sn, tau, broken, pg, e_before - e_after, 0.0, is_open
    pg_old = pg
    sn, tau, pg, is_open, vented = _broken_law(sn_tr, tau_tr, pg, kn, tanphi_r, vent_open)
    d_vent = 0.5 * pg_old * pg_old / kn if vented else 0.0
    d_fric = abs(tau) * abs(tau_tr - tau) / kt     # plastic work tau * slip (backward Euler)
    return sn, tau, broken, pg, d_vent, d_fric, is_open


def spring_stiffness_rule(materials, r_in: float, factor: float = 10.0) -> float:
    """Penalty stiffness per unit area [Pa/m]: kn = factor * max_m (K_m + 4 G_m / 3) / r_in.

    The Itasca FLAC/3DEC interface rule ("ten times the stiffest neighbouring zone", Δz_min = r_in).
    With factor 10 and the paper's rock this is 2.4e12 Pa/m = 24 E_rock / d (E_eff/E = 0.9615).
    Plane-strain: K + 4G/3 = lambda + 2 mu.
    """
    if not (factor > 0):
        raise ValueError(f"penalty factor must be > 0, got {factor}")
    best = 0.0
    for E, nu in materials:
        lam = E * nu / ((1 + nu) * (1 - 2 * nu))
        mu = E / (2 * (1 + nu))
        best = max(best, lam + 2 * mu)
    return factor * best / r_in


class InterfaceLaw:
    """Python wrapper of :func:`mc_update` for one interface (tests and documentation).

    Parameters in SI: kn, kt [Pa/m]; ft, c, pg [Pa]; phi, phi_r [deg]; sn0, tau0 [Pa] preload.
    Drive it with ``update(jn, jt)`` (total jumps [m]); it returns (sn, tau).
    """

    def __init__(self, kn, kt, ft, c, phi, phi_r=None, pg=0.0, sn0=0.0, tau0=0.0, vent_open=np.inf):
        self.kn, self.kt, self.ft, self.c = float(kn), float(kt), float(ft), float(c)
        self.tanphi = np.tan(np.radians(phi))
        self.tanphi_r = np.tan(np.radians(phi if phi_r is None else phi_r))
        self.pg = float(pg)
        self.sn0 = float(sn0)
        self.sn, self.tau = float(sn0), float(tau0)
        self.jt_prev = 0.0
        self.broken = 0
        self.vent_open = float(vent_open)
        self.d_break = 0.0
        self.d_fric = 0.0

    def update(self, jn, jt):
        sn, tau, br, pg, db, df, _ = mc_update(float(jn), float(jt) - self.jt_prev,
                                               Traction(self.sn0, self.tau, self.broken, self.pg),
                                               Strength(self.kn, self.kt, self.ft, self.c, self.tanphi,
                                                        self.tanphi_r, self.vent_open))
        self.jt_prev = float(jt)
        self.sn, self.tau, self.broken, self.pg = sn, tau, br, pg
        self.d_break += db
        self.d_fric += df
        return sn, tau
