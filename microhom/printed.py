"""The seed paper's printed results, typed in as printed: the comparison targets of the checks.

Nothing here is used to derive anything. :mod:`microhom.symbolic` derives every result from the
paper's starting points (its models and definitions) and must never import this module
(``tests/test_derivations.py`` enforces it); :mod:`microhom.derivations` compares the two.
Equation numbers ``(n)`` are those of *The incremental response of random aggregates of identical
round particles*. Where the converted text is garbled, the function says how it was read.

This module imports sympy.
"""
from __future__ import annotations

import itertools

import sympy as sp

from .symbolic import D, Nbar, Nc, S, X, Y, alpha, kn, kt, lam, phi, r, rho, v

_R2 = (0, 1)


def _d(a, b):
    return sp.Integer(1) if a == b else sp.Integer(0)


def vbar_ebar_37():
    """(37): vbar = D^2 Nc (kn + 3 kt)/8, ebar = D^2 Nc (kn - kt)/8."""
    return D ** 2 * Nc * (kn + 3 * kt) / 8, D ** 2 * Nc * (kn - kt) / 8


def mean_field_55():
    """The mean-field parts, written in phi: K_mf = Nc phi kn/(2 pi), G_mf = Nc phi (kn + kt)/(4 pi).

    The paper prints them as the first terms of (50)-(51), (2v)^-1 D^2 Nc kn/4 and
    (2v)^-1 D^2 Nc (kn + kt)/8, with v = pi D^2/(4 phi) (section 6).
    """
    vsub = sp.pi * D ** 2 / (4 * phi)
    return (D ** 2 * Nc * kn / (4 * 2 * v)).subs(v, vsub), (D ** 2 * Nc * (kn + kt) / (8 * 2 * v)).subs(v, vsub)


def T_isotropic_after_32():
    """After (32): T_ijst = 2 d_is d_jt - d_it d_js (isotropic case), as a dict (i,j,s,t) -> expr."""
    return {(i, j, s_, t): 2 * _d(i, s_) * _d(j, t) - _d(i, t) * _d(j, s_)
            for i, j, s_, t in itertools.product(_R2, repeat=4)}


def operator_26(vb, eb, k):
    """(26) in Fourier space: the operator acting on -u_hat,
    ``1/2 (vbar + ebar) k^2 d_pr + 1/2 (vbar + 3 ebar) k_p k_r``.

    (26): ``1/2 (vbar + ebar) d^2 u_p/dx_q^2 + 1/2 (vbar + 3 ebar) d^2 u_q/dx_p dx_q + dS'_pijq/dx_q E_ij = 0``.
    """
    k2 = k[0] ** 2 + k[1] ** 2
    return sp.Matrix(2, 2, lambda p, rr: (vb + eb) / 2 * k2 * _d(p, rr) + (vb + 3 * eb) / 2 * k[p] * k[rr])


def kernel_27(vb, eb, k):
    """(27) as printed (e = ebar, v = vbar):
    ``i k_s u_hat_p = 2 k_q k_s [d_pr/(k^2 (e + v)) - k_p k_r (3e + v)/(2 k^4 (e + v)(2e + v))] S_hat_rijq E_ij``.

    Returned as a dict (p, s, r, q) -> the kernel multiplying S_hat_rijq E_ij.
    """
    k2 = k[0] ** 2 + k[1] ** 2
    return {(p, s_, rr, q): 2 * k[q] * k[s_] * (_d(p, rr) / (k2 * (eb + vb))
                                                 - k[p] * k[rr] * (3 * eb + vb) / (2 * k2 ** 2 * (eb + vb) * (2 * eb + vb)))
            for p, s_, rr, q in itertools.product(_R2, repeat=4)}


def local_30(vb, eb):
    """(30) as printed (e = ebar, v = vbar): ``du'_a/dx_b = -1/2 S'_pijq E_ij
    (2 d_ap d_qb/(e + v) - 1/4 (3e + v)(d_ap d_qb + d_aq d_pb + d_ab d_pq)/((e + v)(2e + v)))``.

    The converted text has ``S'_piqq``; read as ``S'_pijq`` (the only index placement that
    contracts with E_ij and leaves a, b free). Returned as a dict (a, b, p, q) -> expr.
    """
    return {(a, b, p, q): -sp.Rational(1, 2) * (2 * _d(a, p) * _d(q, b) / (eb + vb) - sp.Rational(1, 4) * (3 * eb + vb) * (
        _d(a, p) * _d(q, b) + _d(a, q) * _d(p, b) + _d(a, b) * _d(p, q)) / ((eb + vb) * (2 * eb + vb)))
        for a, b, p, q in itertools.product(_R2, repeat=4)}


def kroner_33_34(vbar, ebar, v2, e2, ev, l=lam):
    """The bulk and shear moduli exactly as printed in (33) and (34).

    ``v2 = mean(v'^2)``, ``e2 = mean(eps'^2)``, ``ev = mean(eps' v')``; ``l`` = (lambda1..4).
    """
    l1, l2, l3, l4 = l
    K = (ebar * 3 + vbar) / (2 * v) / 2 - 1 / (2 * v) / (2 * ebar + vbar) * (
        3 * e2 * (l1 + 3 * (l2 + l3 + l4)) + 2 * ev * (2 * l1 + 3 * (l2 + 2 * l3 + l4))
        + v2 * (l1 + l2 + 3 * l3 + l4))
    G = (ebar + vbar) / (2 * v) / 2 - (5 * ebar + 3 * vbar) / (2 * v) / (
        2 * (ebar + vbar) * (2 * ebar + vbar)) * (
        e2 * (l1 + 3 * l2 + l3 + l4) + 2 * ev * (l1 + 2 * l2 + l3 + l4) + v2 * (l1 + l2 + l3 + l4))
    return K, G


def A_nu_42(Nc_nu):
    """(41)-(42): A^nu_lmnp = 1/2 Nc^nu D^2 [1/4 (kn - kt)(d_lm d_np + d_ln d_mp + d_lp d_mn) + kt d_lm d_np]."""
    return {(l, m, n, p): Nc_nu * D ** 2 / 2 * ((kn - kt) / 4 * (_d(l, m) * _d(n, p) + _d(l, n) * _d(m, p)
                                                                 + _d(l, p) * _d(m, n)) + kt * _d(l, m) * _d(n, p))
            for l, m, n, p in itertools.product(_R2, repeat=4)}


def eps_ratio_44():
    """(44): eps' = v' (kn - kt)/(kn + 3 kt)."""
    return (kn - kt) / (kn + 3 * kt)


def normal_equations_48(VV, VW):
    """(48): (X - Y) sum V^2 - Nbar (kn + kt) sum V.W = 0, (X - 3Y) sum V^2 - 2 Nbar kt sum V.W = 0."""
    return [(X - Y) * VV - Nbar * (kn + kt) * VW, (X - 3 * Y) * VV - 2 * Nbar * kt * VW]


def XY_49():
    """(49): X = (3kn + kt) Nbar S/2, Y = (kn - kt) Nbar S/2 with S = sum V.W / sum V^2."""
    return (3 * kn + kt) * Nbar * S / 2, (kn - kt) * Nbar * S / 2


def moduli_50_51():
    """(50)-(51) as printed, with ``mean(Nc'^2) = r Nc^2``."""
    K = D ** 2 * Nc * kn / (4 * 2 * v) - D ** 2 * r * Nc ** 2 * kn * (X + Y) / (2 * v * 2 * Nc * (3 * kn + kt))
    G = D ** 2 * Nc * (kn + kt) / (8 * 2 * v) - D ** 2 * r * Nc ** 2 * (2 * kn + kt) * (X - Y) / (
        2 * v * 4 * Nc * (3 * kn + kt))
    return K, G


def rho_54(a=alpha):
    """(54): sum V.W / sum V^2 = cos(pi alpha/2) / (Nc (1 - alpha^2)), i.e. rho = cos(pi alpha/2)/(1 - alpha^2)."""
    return sp.cos(sp.pi * a / 2) / (1 - a ** 2)


def limits_55():
    """(55), kt = kn: K = D^2 Nc kn/(8v) [1 - x], G = D^2 Nc kn/(8v) [1 - 3x/2], x = r (Nbar/Nc) rho; in phi."""
    x = r * Nbar * rho / Nc
    pre = (D ** 2 * Nc * kn / (8 * v)).subs(v, sp.pi * D ** 2 / (4 * phi))
    return pre * (1 - x), pre * (1 - sp.Rational(3, 2) * x)


def frictionless_56():
    """kt = 0 (after (55)): K = D^2 Nc kn/(8v) [1 - 4x/3], G = D^2 Nc kn/(16v) [1 - 4x/3]; in phi."""
    x = r * Nbar * rho / Nc
    vsub = {v: sp.pi * D ** 2 / (4 * phi)}
    return ((D ** 2 * Nc * kn / (8 * v)) * (1 - sp.Rational(4, 3) * x)).subs(vsub), \
        ((D ** 2 * Nc * kn / (16 * v)) * (1 - sp.Rational(4, 3) * x)).subs(vsub)


def delta_section6_reading():
    """Delta at kt = kn (section 6), as *read* from a garbled print: Delta = -(x/2) / (2 [1 - (5/4) x]).

    The converted text shows a fraction whose numerator is ``-r (Nbar/Nc) rho`` and whose
    denominator is ``2 [1 - 5/(2 ...) r (Nbar/Nc) rho]``, followed by a stray
    ``- r/2 (Nbar/Nc) rho``. We read the stray term as the true numerator ``-x/2`` (displaced by
    the conversion) and the denominator as ``2 [1 - (5/4) x]``, x = r (Nbar/Nc) rho. It is a
    reconstruction, not a print: the check labels it so.
    """
    x = r * Nbar * rho / Nc
    return -(x / 2) / (2 * (1 - sp.Rational(5, 4) * x))


def phi_nbar_section6(n=Nbar):
    """Section 6: phi = (pi/4) / sin(pi (Nbar - 2)/Nbar), from the polygon area (1/2) Nbar D^2 sin(pi (Nbar-2)/Nbar)
    and the solids pi Nbar D^2/8."""
    return sp.pi / 4 / sp.sin(sp.pi * (n - 2) / n)


def polygon_area_section6(n=Nbar):
    """Section 6: the area of the assembly, (1/2) Nbar D^2 sin(pi (Nbar - 2)/Nbar)."""
    return n * D ** 2 * sp.sin(sp.pi * (n - 2) / n) / 2


def solids_section6(n=Nbar):
    """Section 6: the solids area of a particle plus its neighbours, pi Nbar D^2/8."""
    return sp.pi * n * D ** 2 / 8
