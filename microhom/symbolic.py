"""Sympy derivations of the homogenisation formulas: the single source of truth.

Every closed form used by :mod:`microhom.moduli` is *derived* here by sympy from the paper's
starting points, and compared with what the paper prints. Equation numbers ``(n)`` refer to the
seed paper *The incremental response of random aggregates of identical round particles*.

Derivation chain (see ``docs/theory.md``):

1. (36) -> (37): the isotropic mean structural sum from the angular integral with uniform contact
   density ``p = Nc/(2 pi)``, giving ``vbar``, ``ebar``; the mean stress (17) then gives ``K_mf``,
   ``G_mf``.
2. (15)-(16): spin elimination for an isotropic structural sum: ``B``, ``T``, ``Z``.
3. (33)-(34) with the isotropic fluctuation model (32) and constant contact stiffnesses (42)-(44):
   the moduli depend on the lambdas only through ``X``, ``Y`` (45)-(46), giving (50)-(51).
4. (40)-(43): the least-squares functional for ``X``, ``Y``, its normal equations (48) and their
   solution (49).
5. (52)-(54): the alignment model for ``sum V.W / sum V^2`` and its limit at ``alpha = 1``.
6. The final working formulas, the limits (55), the frictionless pair and ``Delta``.

This module imports sympy; ``import microhom`` does not import it.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache

import sympy as sp

# ---- symbols ---------------------------------------------------------------------------------
kn, kt = sp.symbols("k_n k_t", positive=True)
Nc, D, phi, v = sp.symbols("N_c D phi v", positive=True)
r, Nbar, rho, S = sp.symbols("r Nbar rho S", positive=True)  # S = sum V.W / sum V^2
alpha = sp.symbols("alpha", positive=True)
theta = sp.symbols("theta", real=True)
lam = sp.symbols("lambda1:5", real=True)
X, Y = sp.symbols("X Y", real=True)

_R2 = (0, 1)


def _d(a, b):
    return sp.Integer(1) if a == b else sp.Integer(0)


def _iso4(a, b):
    """Isotropic 4th-rank form a d_pq d_rs + b (d_pr d_qs + d_ps d_qr) as a dict (p,q,r,s)->expr.

    Paper (24)/(37): ``A_pqrs = vbar d_pq d_rs + ebar (d_pr d_qs + d_ps d_qr)``, where (p, q) are
    the contact-stiffness indices and (r, s) the branch-vector indices.
    """
    return {(p, q, rr, s): a * _d(p, q) * _d(rr, s) + b * (_d(p, rr) * _d(q, s) + _d(p, s) * _d(q, rr))
            for p, q, rr, s in itertools.product(_R2, repeat=4)}


def _levi3(i, j, k):
    return sp.LeviCivita(i, j, k)


# ---- 1. mean structural sum (36) -> (37) and the mean field ------------------------------------
@lru_cache(maxsize=None)
def mean_structural_sum():
    """Evaluate (36) with p(theta) = Nc/(2 pi), n = (cos, sin), c = D n.

    Returns a dict with the tensor ``A`` (p,q,r,s)->expr and the identified ``vbar``, ``ebar``.
    """
    n = (sp.cos(theta), sp.sin(theta))
    p = Nc / (2 * sp.pi)
    A = {}
    for a, b, c, d in itertools.product(_R2, repeat=4):
        K_ab = kn * n[a] * n[b] + kt * (_d(a, b) - n[a] * n[b])
        A[(a, b, c, d)] = sp.simplify(sp.integrate(p * K_ab * D * n[c] * D * n[d], (theta, 0, 2 * sp.pi)))
    vb, eb = sp.symbols("vbar ebar")
    form = _iso4(vb, eb)
    sol = sp.solve([A[k] - form[k] for k in A], [vb, eb], dict=True)
    if len(sol) != 1:
        raise RuntimeError("mean structural sum is not of the isotropic form (37)")
    return {"A": A, "vbar": sp.factor(sol[0][vb]), "ebar": sp.factor(sol[0][eb])}


def stress_from_structural_sum(A, E):
    """Mean stress (17) with the spin term absent: sigma_rq = (2v)^-1 A_rijq E_ij."""
    return {(rr, q): sp.expand(sum(A[(rr, i, j, q)] * E[i][j] for i in _R2 for j in _R2) / (2 * v))
            for rr in _R2 for q in _R2}


def moduli_from_stress(A):
    """2D bulk and shear moduli of the linear map E -> sigma of :func:`stress_from_structural_sum`.

    K from an isotropic strain (sigma = 2 K e I under E = e I), G from a pure shear
    (sigma_12 = 2 G E_12). The map is checked to be isotropic (C1111 = K + G, C1122 = K - G).
    """
    e = sp.symbols("e")
    iso = stress_from_structural_sum(A, [[e, 0], [0, e]])
    shear = stress_from_structural_sum(A, [[0, e], [e, 0]])
    uni = stress_from_structural_sum(A, [[e, 0], [0, 0]])
    K = sp.simplify(iso[(0, 0)] / (2 * e))
    G = sp.simplify(shear[(0, 1)] / (2 * e))
    iso_ok = (sp.simplify(uni[(0, 0)] / e - (K + G)) == 0 and sp.simplify(uni[(1, 1)] / e - (K - G)) == 0
              and sp.simplify(iso[(0, 1)]) == 0 and sp.simplify(shear[(0, 0)]) == 0)
    if not iso_ok:
        raise RuntimeError("structural sum does not give an isotropic stiffness")
    return K, G


@lru_cache(maxsize=None)
def mean_field_moduli():
    """K_mf, G_mf in terms of kn, kt, Nc and phi (v = pi D^2 / (4 phi))."""
    m = mean_structural_sum()
    K, G = moduli_from_stress(m["A"])
    vsub = sp.pi * D ** 2 / (4 * phi)
    return sp.simplify(K.subs(v, vsub)), sp.simplify(G.subs(v, vsub))


# ---- 2. spin elimination (15)-(16) -----------------------------------------------------------
def spin_elimination(A):
    """B, T and Z of (15)-(16) for a 2D structural sum ``A`` (p,q,r,s)->expr.

    In 2D the spin has only the out-of-plane component 3, so ``B = B_33`` is a scalar:
    ``B = eps_3qr eps_ij3 A_rijq`` (15). With ``M_st = eps_3qr A_rstq`` the spin is
    ``Omega_3 = -M_st E_st / B``, and (16)
    ``Z_pkst = A_pstk - (eps_ij3 A_pijk) M_st / B``,  ``T_ijst = d_is d_jt - eps_ij3 M_st / B``.
    Returns (B, T, Z) with T and Z as dicts.
    """
    B = sp.simplify(sum(_levi3(2, q, rr) * _levi3(i, j, 2) * A[(rr, i, j, q)]
                        for q in _R2 for rr in _R2 for i in _R2 for j in _R2))
    M = {(s, t): sum(_levi3(2, q, rr) * A[(rr, s, t, q)] for q in _R2 for rr in _R2)
         for s in _R2 for t in _R2}
    T = {(i, j, s, t): sp.simplify(_d(i, s) * _d(j, t) - _levi3(i, j, 2) * M[(s, t)] / B)
         for i, j, s, t in itertools.product(_R2, repeat=4)}
    Z = {(p, k, s, t): sp.simplify(A[(p, s, t, k)] - sum(_levi3(i, j, 2) * A[(p, i, j, k)]
                                                           for i in _R2 for j in _R2) * M[(s, t)] / B)
         for p, k, s, t in itertools.product(_R2, repeat=4)}
    return B, T, Z


# ---- 3. Kroener correction (33)-(34) -> (50)-(51) ---------------------------------------------
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


def X_Y_definitions(l=lam):
    """X and Y as defined in (45)-(46)."""
    l1, l2, l3, l4 = l
    Xd = kn * (2 * l1 + 4 * l2 + 4 * l3 + 3 * l4) + kt * (2 * l1 + 4 * l3 + l4)
    Yd = kn * (2 * l3 + l4) + kt * (2 * l3 - l4)
    return Xd, Yd


@lru_cache(maxsize=None)
def constant_stiffness_moduli():
    """Substitute the constant-stiffness fluctuation model into (33)-(34).

    (42) with ``Nc^nu -> Nc'`` gives ``v' = Nc' D^2 (kn + 3 kt)/8``, ``eps' = Nc' D^2 (kn - kt)/8``
    (so (44) ``eps' = v' (kn - kt)/(kn + 3 kt)``), hence with ``mean(Nc'^2) = r Nc^2``
    the three correlations. The lambdas are then eliminated in favour of X, Y (45)-(46): we solve
    (45)-(46) for lambda1 and lambda3 and check that lambda2, lambda4 drop out.

    Returns (K, G) as functions of X, Y, and the intermediate ``eps'/v'`` ratio.
    """
    m = mean_structural_sum()
    vbar, ebar = m["vbar"], m["ebar"]
    Ncp = sp.symbols("N_c'", real=True)
    vp = Ncp * D ** 2 * (kn + 3 * kt) / 8
    ep = Ncp * D ** 2 * (kn - kt) / 8
    ratio = sp.simplify(ep / vp)
    msq = r * Nc ** 2  # mean(Nc'^2)
    v2 = sp.expand(vp ** 2).subs(Ncp ** 2, msq)
    e2 = sp.expand(ep ** 2).subs(Ncp ** 2, msq)
    ev = sp.expand(ep * vp).subs(Ncp ** 2, msq)
    K, G = kroner_33_34(vbar, ebar, v2, e2, ev)
    Xd, Yd = X_Y_definitions()
    sol = sp.solve([Xd - X, Yd - Y], [lam[0], lam[2]], dict=True)[0]
    K = sp.simplify(K.subs(sol))
    G = sp.simplify(G.subs(sol))
    for expr in (K, G):
        if any(sym in expr.free_symbols for sym in (lam[1], lam[3])):
            raise RuntimeError("the moduli do not depend on the lambdas through X and Y only")
    return K, G, ratio


def printed_50_51():
    """(50)-(51) as printed, with ``mean(Nc'^2) = r Nc^2``."""
    K = D ** 2 * Nc * kn / (4 * 2 * v) - D ** 2 * r * Nc ** 2 * kn * (X + Y) / (2 * v * 2 * Nc * (3 * kn + kt))
    G = D ** 2 * Nc * (kn + kt) / (8 * 2 * v) - D ** 2 * r * Nc ** 2 * (2 * kn + kt) * (X - Y) / (
        2 * v * 4 * Nc * (3 * kn + kt))
    return K, G


# ---- 4. least squares (40)-(49) ----------------------------------------------------------------
@lru_cache(maxsize=None)
def least_squares_XY():
    """Derive X, Y from the functional (40) with the models (21), (41)-(43).

    For one particle mu, with V = V^mu and W = W^mu (2-vectors):

    * odd sum (43): ``D A_ijk = pi D^2 W_p [ (kn-kt)/4 (d_ij d_kp + d_ip d_jk + d_ik d_jp) + kt d_ij d_kp ]``
    * neighbour sum (41): ``sum_nu n_p (A_lmnp + A_lmpn) = pi D^2 [ ... ]_lmnp V_p``
    * residual of (40): ``D A_ijk - (1/Nbar) Lambda_ijklmn (41)_lmn``.

    We check that ``Lambda . (41)`` depends on the lambdas only through X, Y, minimise
    ``sum_mu |residual|^2`` over X and Y (the terms in |W|^2 do not depend on them), and return
    the normal equations and the solution in terms of ``S = sum V.W / sum V^2``.
    """
    l1, l2, l3, l4 = lam
    Vv = sp.symbols("V1 V2", real=True)
    Wv = sp.symbols("W1 W2", real=True)

    def Lam(i, j, k, l, m, n):  # (21)
        return (l1 * _d(i, j) * _d(l, m) * _d(k, n) + l2 * _d(i, j) * (_d(k, l) * _d(m, n) + _d(k, m) * _d(l, n))
                + l3 * _d(l, m) * (_d(i, k) * _d(j, n) + _d(j, k) * _d(i, n))
                + l4 * _d(k, n) * (_d(i, l) * _d(j, m) + _d(i, m) * _d(j, l)))

    def bracket(l, m, n, p):  # the bracket of (41)-(43)
        return (kn - kt) / 4 * (_d(l, m) * _d(n, p) + _d(l, n) * _d(m, p) + _d(l, p) * _d(m, n)) \
            + kt * _d(l, m) * _d(n, p)

    idx3 = list(itertools.product(_R2, repeat=3))
    nb = {(l, m, n): sum(bracket(l, m, n, p) * Vv[p] for p in _R2) for (l, m, n) in idx3}
    lamterm = {(i, j, k): sp.expand(sum(Lam(i, j, k, *lmn) * nb[lmn] for lmn in idx3)) for (i, j, k) in idx3}
    # Lambda . (41) == 1/2 [ (X - 2Y) d_ij V_k + Y (d_ik V_j + d_jk V_i) ]  with X, Y of (45)-(46)
    Xd, Yd = X_Y_definitions()
    xy_form = {(i, j, k): sp.Rational(1, 2) * ((X - 2 * Y) * _d(i, j) * Vv[k]
                                               + Y * (_d(i, k) * Vv[j] + _d(j, k) * Vv[i]))
               for (i, j, k) in idx3}
    depends_on_XY_only = all(sp.expand(lamterm[key] - xy_form[key].subs({X: Xd, Y: Yd})) == 0 for key in idx3)
    odd = {(i, j, k): sum(bracket(i, j, k, p) * Wv[p] for p in _R2) for (i, j, k) in idx3}
    residual2 = sp.expand(sum((odd[key] - xy_form[key] / Nbar) ** 2 for key in idx3))  # / (pi D^2)^2
    # The squared residual is a quadratic form in (V, W). It must be rotation invariant, i.e.
    # c_VV |V|^2 + c_VW V.W + c_WW |W|^2 with no other monomials; summing over the particles mu
    # then replaces |V|^2 -> sum |V|^2 = VV and V.W -> sum V.W = VW.
    VV = sp.symbols("SVV", positive=True)
    VW = sp.symbols("SVW", real=True)
    c = {mono: coeff for mono, coeff in sp.Poly(residual2, *Vv, *Wv).terms()}
    c_vv, c_vw, c_ww = c.get((2, 0, 0, 0), 0), c.get((1, 0, 1, 0), 0), c.get((0, 0, 2, 0), 0)
    expected = {(2, 0, 0, 0): c_vv, (0, 2, 0, 0): c_vv, (1, 0, 1, 0): c_vw, (0, 1, 0, 1): c_vw,
                (0, 0, 2, 0): c_ww, (0, 0, 0, 2): c_ww}
    invariant = (set(c) <= set(expected)
                 and all(sp.simplify(c.get(m, 0) - e) == 0 for m, e in expected.items()))
    functional = c_vv * VV + c_vw * VW
    normal = [sp.expand(sp.diff(functional, X)), sp.expand(sp.diff(functional, Y))]
    sol = sp.solve(normal, [X, Y], dict=True)[0]
    Xs = sp.factor(sol[X].subs(VW, S * VV))
    Ys = sp.factor(sol[Y].subs(VW, S * VV))
    printed_48 = [(X - Y) * VV - Nbar * (kn + kt) * VW, (X - 3 * Y) * VV - 2 * Nbar * kt * VW]
    return {"depends_on_XY_only": depends_on_XY_only, "invariant": invariant,
            "normal_equations": normal, "X": Xs, "Y": Ys, "printed_48": printed_48,
            "VV": VV, "VW": VW}


# ---- 5. alignment model (52)-(54) ---------------------------------------------------------------
@lru_cache(maxsize=None)
def alignment_integral():
    """(53): (1/(2 alpha)) int_{-alpha pi/2}^{alpha pi/2} cos(u) cos(u/alpha) du, for alpha != 1."""
    u = sp.symbols("u", real=True)
    return sp.simplify(sp.integrate(sp.cos(u) * sp.cos(u / alpha), (u, -alpha * sp.pi / 2, alpha * sp.pi / 2),
                                    conds="none") / (2 * alpha))


def rho_model(a=alpha):
    """(54) as printed: rho = Nc * sum V.W / sum V^2 = cos(pi alpha / 2) / (1 - alpha^2)."""
    return sp.cos(sp.pi * a / 2) / (1 - a ** 2)


def rho_model_stable(a=alpha):
    """The same function written without the 0/0 at alpha = 1 (used by the numeric code).

    With t = 1 - alpha: cos(pi alpha/2) = sin(pi t/2) and 1 - alpha^2 = t (1 + alpha), so
    rho = (pi/2) sinc(t/2) / (1 + alpha) with sinc(x) = sin(pi x)/(pi x) (numpy's sinc).
    """
    t = 1 - a
    return sp.pi / 2 * sp.sinc(sp.pi * t / 2) / (1 + a)


# ---- 6. final formulas ------------------------------------------------------------------------
@dataclass(frozen=True)
class FinalFormulas:
    K_mf: sp.Expr
    G_mf: sp.Expr
    K: sp.Expr  # corrected, in terms of r, Nbar, Nc and rho
    G: sp.Expr
    drop_K: sp.Expr  # fraction change 1 - K/K_mf
    drop_G: sp.Expr


@lru_cache(maxsize=None)
def final_formulas() -> FinalFormulas:
    """(50)-(51) with (49) and rho = Nc S: the working formulas of :mod:`microhom.moduli`."""
    Kxy, Gxy, _ = constant_stiffness_moduli()
    ls = least_squares_XY()
    vsub = sp.pi * D ** 2 / (4 * phi)
    sub = {X: ls["X"], Y: ls["Y"]}
    K = sp.simplify(Kxy.subs(sub).subs(S, rho / Nc).subs(v, vsub))
    G = sp.simplify(Gxy.subs(sub).subs(S, rho / Nc).subs(v, vsub))
    Kmf, Gmf = mean_field_moduli()
    return FinalFormulas(K_mf=Kmf, G_mf=Gmf, K=K, G=G,
                         drop_K=sp.simplify(1 - K / Kmf), drop_G=sp.simplify(1 - G / Gmf))


def nbar_phi_relation(n=Nbar):
    """phi(Nbar) = (pi/4) / sin(pi (Nbar - 2)/Nbar) (section 6)."""
    return sp.pi / 4 / sp.sin(sp.pi * (n - 2) / n)


def biaxial_delta(K, G):
    """Delta: ratio of minor to major principal strain increment when the minor stress increment is 0.

    2D isotropic: sigma_2 = (K - G) e1 + (K + G) e2 = 0  ->  Delta = e2/e1.
    """
    e1, e2 = sp.symbols("e1 e2")
    sol = sp.solve((K - G) * e1 + (K + G) * e2, e2)[0]
    return sp.simplify(sol / e1)


def lambdify_final():
    """Numeric functions (numpy) generated from the final symbolic formulas.

    Returns f(kn, kt, Nc, phi, r, Nbar, rho) -> (K_mf, G_mf, K, G), used to check moduli.py.
    """
    f = final_formulas()
    args = (kn, kt, Nc, phi, r, Nbar, rho)
    return sp.lambdify(args, (f.K_mf, f.G_mf, f.K, f.G), modules="numpy")
