"""Sympy derivations of the homogenisation formulas: the single source of truth.

Every closed form used by :mod:`microhom.moduli` is *derived* here by sympy from the paper's
starting points: its definitions (structural sums (10), spin elimination (15)-(16), stress (17),
X and Y (45)-(46)) and its modelling assumptions (the isotropic forms (21), (24), (32), the angular
integral (36), the models (41)-(43), the alignment density (52), the local estimate (29)).
The paper's printed results live in :mod:`microhom.printed` and are never imported here: they
are only the targets :mod:`microhom.derivations` compares with. Equation numbers ``(n)`` refer to
the seed paper *The incremental response of random aggregates of identical round particles*.

Derivation chain (see ``docs/theory.md``):

1. (36) -> (37): the isotropic mean structural sum from the angular integral with uniform contact
   density ``p = Nc/(2 pi)``, giving ``vbar``, ``ebar``; the mean stress (17) then gives ``K_mf``,
   ``G_mf``.
2. (15)-(16): spin elimination for an isotropic structural sum: ``B``, ``T``, ``Z``.
3. (22) -> (26) -> (27) -> (29)-(30) -> (31) with (32) -> (33)-(34): the Kroener estimate. The
   operator of (26) from the isotropic mean (24), its inverse in Fourier space (27), the local part
   (29) as the angular mean (a lemma proved with the Green's functions), and the mean stress (31).
4. (36) with Nc' -> (44); (33)-(34) with constant stiffnesses: the moduli depend on the lambdas
   only through ``X``, ``Y`` (45)-(46), giving (50)-(51).
5. (38)-(43): the least-squares functional for ``X``, ``Y``, its normal equations (48) and their
   solution (49).
6. (52)-(53): the alignment model for ``sum V.W / sum V^2`` and its limit at ``alpha = 1``.
7. The final working formulas, the limits (55), the frictionless pair and ``Delta``. The
   geometry phi(Nbar) of section 6 is derived in :func:`microhom.neighbourhood.derive_phi_of_nbar`.

Symbols (sympy, shared with :mod:`microhom.printed` and :mod:`microhom.derivations`): ``kn``, ``kt``
contact stiffnesses [N/m]; ``Nc`` mean contact number; ``D`` particle diameter [m]; ``phi`` solid
fraction; ``v`` area per particle [m^2] (``v = pi D^2 / (4 phi)``); ``r = mean(Nc'^2)/Nc^2``;
``Nbar`` number of near neighbours (section 6); ``rho = Nc S`` the alignment factor with
``S = sum V.W / sum V^2``; ``alpha`` the alignment parameter of (52); ``theta`` the contact angle;
``lam`` the four lambdas of (21); ``X``, ``Y`` of (45)-(46); ``k_vec`` the wave vector of (27);
``vbar_s``, ``ebar_s`` the isotropic mean (24) [N m]; ``vprime``, ``eprime`` the
fluctuation model (32) and ``v2``, ``e2``, ``ev`` its second moments; ``Ncp`` the contact-number
fluctuation ``Nc' = Nc^nu - Nc``; ``Vvec``, ``Wvec`` the odd angular distributions of (41)-(43).
Tensors are returned as dicts from index tuples (0 or 1 each) to expressions.

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

__all__ = [
    # symbols
    "kn", "kt", "Nc", "D", "phi", "v", "r", "Nbar", "rho", "S", "alpha", "theta", "lam", "X", "Y",
    "k_vec", "vbar_s", "ebar_s", "vprime", "eprime", "v2", "e2", "ev", "Ncp", "Vvec", "Wvec",
    # derivations
    "circle_integral", "mean_structural_sum", "stress_from_structural_sum", "moduli_from_stress",
    "mean_field_moduli", "spin_elimination", "iso_A", "Lambda_21", "kroner_operator", "kroner_kernel",
    "angular_mean", "local_part_lemma", "kroner_local", "kroner_moduli", "fluctuation_sums",
    "X_Y_definitions", "constant_stiffness_moduli", "odd_and_neighbour_sums", "least_squares_XY",
    "alignment_integral", "rho_model_stable", "FinalFormulas", "final_formulas", "biaxial_delta",
    "lambdify_final",
]

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


@lru_cache(maxsize=None)
def _angular_moment(a, b):
    """(1/2pi) int_0^2pi cos^a sin^b dtheta, by sympy (cached: only a handful of (a, b) occur)."""
    return sp.integrate(sp.cos(theta) ** a * sp.sin(theta) ** b, (theta, 0, 2 * sp.pi)) / (2 * sp.pi)


def circle_integral(expr):
    """int_0^2pi expr dtheta for an expression polynomial in cos(theta), sin(theta).

    The expression is expanded into monomials ``cos^a sin^b`` (coefficients free of theta), each
    integrated once by sympy (a cached angular moment): the same integral as
    ``sp.integrate(expr, (theta, 0, 2 pi))``, many times faster.
    """
    c, s_ = sp.cos(theta), sp.sin(theta)
    poly = sp.Poly(sp.expand(expr), c, s_)
    if any(theta in coef.free_symbols for coef in poly.coeffs()):
        raise ValueError("circle_integral needs a polynomial in cos(theta), sin(theta)")
    return sp.expand(2 * sp.pi * sum(coef * _angular_moment(*mono) for mono, coef in poly.terms()))


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
        A[(a, b, c, d)] = sp.cancel(circle_integral(p * K_ab * D * n[c] * D * n[d]))
    vb, eb = sp.symbols("vbar ebar")
    form = _iso4(vb, eb)
    sol = sp.solve([A[k] - form[k] for k in A], [vb, eb], dict=True)
    if len(sol) != 1:
        raise RuntimeError("mean structural sum is not of the isotropic form (37)")
    return {"A": A, "vbar": sp.cancel(sol[0][vb]), "ebar": sp.cancel(sol[0][eb])}


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


# ---- 3. Kroener correction: (22) -> (26) -> (27) -> (29)-(30) -> (31) with (32) -> (33)-(34) ------
k_vec = sp.symbols("k1 k2", real=True)  # wave vector of the Fourier transform (27)
vbar_s, ebar_s = sp.symbols("vbar ebar", positive=True)  # the isotropic mean (24)
vprime, eprime = sp.symbols("v' epsilon'", real=True)  # the isotropic fluctuation model (32)
v2, e2, ev = sp.symbols("mean(v'^2) mean(epsilon'^2) mean(epsilon'v')", real=True)


def iso_A(vb, eb):
    """(24)/(32): ``A_pijk = vb d_pi d_jk + eb (d_pk d_ij + d_pj d_ik)``: (p, i) stiffness, (j, k) branch."""
    return _iso4(vb, eb)


def Lambda_21(l=lam):
    """(21): the isotropic sixth-rank Lambda_ijklmn as a function (i, j, k, l, m, n) -> expr (a model, typed in)."""
    l1, l2, l3, l4 = l

    def Lam(i, j, k, ll, m, n):
        return (l1 * _d(i, j) * _d(ll, m) * _d(k, n) + l2 * _d(i, j) * (_d(k, ll) * _d(m, n) + _d(k, m) * _d(ll, n))
                + l3 * _d(ll, m) * (_d(i, k) * _d(j, n) + _d(j, k) * _d(i, n))
                + l4 * _d(k, n) * (_d(i, ll) * _d(j, m) + _d(i, m) * _d(j, ll)))
    return Lam


@lru_cache(maxsize=None)
def kroner_operator():
    """The operator of (26), derived from the left side of (22) with the isotropic mean (24).

    ``Abar_pijk T_ijst dE'_st/dx_k`` with ``Tbar E = E`` (check ``spin_T_isotropic``) and
    ``E' = sym grad u'`` (23) becomes, in Fourier space (d/dx -> i k),
    ``-L_pr(k) u_hat_r`` with ``L_pr = 1/2 Abar_pijk k_k (k_j d_ir + k_i d_jr)``. Returns L (2x2 Matrix).
    """
    A = iso_A(vbar_s, ebar_s)
    k = k_vec
    return sp.Matrix(2, 2, lambda p, rr: sp.expand(sum(
        A[(p, i, j, kk)] * k[kk] * (k[j] * _d(i, rr) + k[i] * _d(j, rr)) for i in _R2 for j in _R2 for kk in _R2) / 2))


@lru_cache(maxsize=None)
def kroner_kernel():
    """(27) derived: solve (26) in Fourier space for the displacement-gradient fluctuation.

    (26) reads ``-L u_hat + i k_q S_hat_rijq E_ij = 0`` (the forcing ``dS'_pijq/dx_q E_ij``), so
    ``i k_s u_hat_p = i k_s L^-1_pr i k_q S_hat_rijq E_ij = -k_s k_q L^-1_pr S_hat_rijq E_ij``.
    Returns a dict (p, s, r, q) -> ``-k_s k_q L^-1_pr`` (the factor ``i * i = -1`` included).
    """
    Linv = sp.simplify(kroner_operator().inv())
    k = k_vec
    return {(p, s_, rr, q): sp.cancel(-k[s_] * k[q] * Linv[p, rr]) for p, s_, rr, q in itertools.product(_R2, repeat=4)}


def angular_mean(expr):
    """Mean over the directions of k of a degree-0 homogeneous rational function of ``k_vec``.

    The expression is written as N(k)/(k^2)^m with N homogeneous of degree 2m; on the unit
    circle the denominator is 1 and the mean of N is a sum of moments ``<cos^a sin^b>``.
    """
    k1, k2 = k_vec
    num, den = sp.fraction(sp.cancel(expr))
    m = sp.Poly(den, k1, k2).total_degree() // 2
    if sp.expand(den - sp.LC(sp.Poly(den, k1, k2)) * (k1 ** 2 + k2 ** 2) ** m) != 0:
        raise ValueError("denominator is not a power of k^2")
    c = sp.LC(sp.Poly(den, k1, k2))
    return sp.simplify(sum(coef * _angular_moment(*mono) for mono, coef in sp.Poly(num, k1, k2).terms()) / c)


@lru_cache(maxsize=None)
def local_part_lemma():
    """The 'local' contribution (29): the integral over a small circle R of the inverse transform of
    a degree-0 kernel equals the kernel's angular mean. Derived with the Green's functions.

    With ``f(y) = (2pi)^-2 int F(k) e^{ik.y} d^2k``: the inverse transform of 1/k^2 is
    ``g2 = -log(r)/(2pi)`` and of 1/k^4 is ``g4 = r^2 (log r - 1)/(8pi)`` (sympy checks
    ``lap g4 = -g2`` and the unit flux of ``-grad g2``). Then ``k_q k_s/k^2 -> -d_q d_s g2`` and
    ``k_p k_r k_q k_s/k^4 -> d_p d_r d_q d_s g4``, and Gauss' theorem over the disk of radius R
    turns their integrals into ``-(circle) n_q d_s g2`` and ``(circle) n_p d_r d_q d_s g4``.
    Returns True when every such integral equals the angular mean of its monomial, for any R.
    """
    y1, y2 = sp.symbols("y1 y2", real=True)
    Rr = sp.symbols("R", positive=True)
    rr = sp.sqrt(y1 ** 2 + y2 ** 2)
    g2 = -sp.log(rr) / (2 * sp.pi)
    g4 = rr ** 2 * (sp.log(rr) - 1) / (8 * sp.pi)
    y = (y1, y2)
    polar = {y1: Rr * sp.cos(theta), y2: Rr * sp.sin(theta)}

    def on_circle(expr):  # the expression at y = R n(theta), as a polynomial in cos, sin
        return sp.expand_trig(sp.trigsimp(sp.simplify(expr.subs(polar))))
    normal = (sp.cos(theta), sp.sin(theta))
    lap = sp.diff(g4, y1, 2) + sp.diff(g4, y2, 2)
    ok = sp.simplify(lap + g2) == 0
    flux = circle_integral(on_circle(sum(-normal[i] * sp.diff(g2, y[i]) for i in _R2)) * Rr)
    ok = ok and sp.simplify(flux - 1) == 0
    k1, k2 = k_vec
    for q, s_ in itertools.product(_R2, repeat=2):
        local = circle_integral(on_circle(-normal[q] * sp.diff(g2, y[s_])) * Rr)
        ok = ok and sp.simplify(local - angular_mean(k_vec[q] * k_vec[s_] / (k1 ** 2 + k2 ** 2))) == 0
    for p, rrr, q, s_ in itertools.product(_R2, repeat=4):
        local = circle_integral(on_circle(normal[p] * sp.diff(g4, y[rrr], y[q], y[s_])) * Rr)
        mono = k_vec[p] * k_vec[rrr] * k_vec[q] * k_vec[s_] / (k1 ** 2 + k2 ** 2) ** 2
        ok = ok and sp.simplify(local - angular_mean(mono)) == 0
    return bool(ok)


@lru_cache(maxsize=None)
def kroner_local():
    """(30) derived: the local part (29) of the kernel of (27), i.e. its angular mean (lemma above).

    Returns a dict (a, b, p, q) -> expr with ``du'_a/dx_b = sum local[a,b,p,q] S'_pijq E_ij``.
    """
    return {key: angular_mean(val) for key, val in kroner_kernel().items()}


@lru_cache(maxsize=None)
def kroner_moduli():
    """(33)-(34) derived from (31) with the fluctuation model (32), the local estimate (30) and (21).

    * (32): ``A = Abar + A'`` with ``A' = iso_A(v', eps')``; the spin elimination (15)-(16) of
      this isotropic A gives a T independent of v', eps' (so ``T' = 0`` and the first term of S'
      (25) drops), and a Z with ``Z' E' = A' E'`` on symmetric E' (both checked here);
    * (25): ``S'_pijq = Lambda_pijlmn (A'_lmnq + A'_lmqn)``;
    * (30): ``du'_a/dx_b = local[a,b,p,q] S'_pijq E_ij``, ``E' = sym grad u'``;
    * (31): ``sigma_rq = (2v)^-1 [Abar_rijq E_ij + mean(A'_rijq E'_ij)]``, where the mean replaces
      ``v'^2, eps'^2, eps' v'`` by their averages ``v2, e2, ev``;
    * K from ``E = e I`` (sigma = 2 K e I), G from ``E_12 = E_21 = e`` (sigma_12 = 2 G e).

    Returns dict with ``K``, ``G`` (in vbar, ebar, v2, e2, ev, lambda1..4 and v), ``T_const``,
    ``Z_is_A``.
    """
    Abar = iso_A(vbar_s, ebar_s)
    Ap = iso_A(vprime, eprime)
    Afull = {key: Abar[key] + Ap[key] for key in Abar}
    # spin elimination of the isotropic A = Abar + A' (A_rijq ordering: r,i stiffness; j,q branch)
    _, T, Z = spin_elimination(Afull)
    T_const = all(not ({vprime, eprime} & sp.simplify(T[key]).free_symbols) for key in T)
    e11, e22, e12 = sp.symbols("e11 e22 e12")
    Es = [[e11, e12], [e12, e22]]
    Z_is_A = all(sp.simplify(sum((Z[(p, k, a, b)] - Afull[(p, a, b, k)]) * Es[a][b] for a in _R2 for b in _R2)) == 0
                 for p in _R2 for k in _R2)
    Lam = Lambda_21()
    Sp = {(p, i, j, q): sp.expand(sum(Lam(p, i, j, ll, m, n) * (Ap[(ll, m, n, q)] + Ap[(ll, m, q, n)])
                                      for ll in _R2 for m in _R2 for n in _R2))
          for p, i, j, q in itertools.product(_R2, repeat=4)}
    loc = kroner_local()

    def mean_stress(E):
        grad = {(a, b): sp.expand(sum(loc[(a, b, p, q)] * Sp[(p, i, j, q)] * E[i][j]
                                      for p in _R2 for q in _R2 for i in _R2 for j in _R2)) for a in _R2 for b in _R2}
        Ep = {(i, j): (grad[(i, j)] + grad[(j, i)]) / 2 for i in _R2 for j in _R2}
        sig = {}
        for rr, q in itertools.product(_R2, repeat=2):
            fluct = sp.Poly(sp.expand(sum(Ap[(rr, i, j, q)] * Ep[(i, j)] for i in _R2 for j in _R2)), vprime, eprime)
            avg = 0
            for mono, coef in fluct.terms():
                if coef == 0:
                    continue
                if mono not in ((2, 0), (0, 2), (1, 1)):
                    raise RuntimeError(f"mean(Z' E') has a term of order {mono} in (v', eps')")
                avg += coef * {(2, 0): v2, (0, 2): e2, (1, 1): ev}[mono]
            sig[(rr, q)] = (sum(Abar[(rr, i, j, q)] * E[i][j] for i in _R2 for j in _R2) + avg) / (2 * v)
        return sig

    e = sp.symbols("e")
    K = sp.simplify(mean_stress([[e, 0], [0, e]])[(0, 0)] / (2 * e))
    G = sp.simplify(mean_stress([[0, e], [e, 0]])[(0, 1)] / (2 * e))
    return {"K": K, "G": G, "T_const": bool(T_const), "Z_is_A": bool(Z_is_A)}


# ---- 4. constant stiffnesses: (36) with Nc' (41)-(42) -> (44); (33)-(34) -> (50)-(51) -----------
Ncp = sp.symbols("N_c'", real=True)  # contact-number fluctuation Nc^nu - Nc


@lru_cache(maxsize=None)
def fluctuation_sums():
    """v' and eps' of the constant-stiffness model: the integral (36) with density Nc'/(2 pi).

    (41)-(42) model A^nu as the isotropic integral (36) with ``p^nu = Nc^nu/(2 pi)``; the
    fluctuation ``A' = A^nu - Abar`` is then the same integral with ``Nc -> Nc'`` (it is linear in
    the density). We reuse :func:`mean_structural_sum` with ``Nc -> Nc'`` and identify
    ``v'``, ``eps'``. Returns dict ``A`` (the tensor), ``v``, ``eps``, ``ratio = eps'/v'``.
    """
    m = mean_structural_sum()
    A = {key: val.subs(Nc, Ncp) for key, val in m["A"].items()}
    vp, ep = m["vbar"].subs(Nc, Ncp), m["ebar"].subs(Nc, Ncp)
    form = _iso4(vp, ep)
    if any(sp.simplify(A[key] - form[key]) != 0 for key in A):
        raise RuntimeError("the fluctuation integral is not of the isotropic form (32)")
    return {"A": A, "v": vp, "eps": ep, "ratio": sp.simplify(ep / vp)}


def X_Y_definitions(l=lam):
    """X and Y as the paper defines them in (45)-(46) (definitions: starting points, not results)."""
    l1, l2, l3, l4 = l
    Xd = kn * (2 * l1 + 4 * l2 + 4 * l3 + 3 * l4) + kt * (2 * l1 + 4 * l3 + l4)
    Yd = kn * (2 * l3 + l4) + kt * (2 * l3 - l4)
    return Xd, Yd


@lru_cache(maxsize=None)
def constant_stiffness_moduli():
    """Substitute the constant-stiffness fluctuation model into the *derived* (33)-(34).

    ``v'``, ``eps'`` from :func:`fluctuation_sums` (the integral (36) with Nc'), with
    ``mean(Nc'^2) = r Nc^2``, give the three correlations. The lambdas are then eliminated in
    favour of X, Y (45)-(46): we solve (45)-(46) for lambda1 and lambda3 and check that lambda2,
    lambda4 drop out.

    Returns (K, G) as functions of X, Y (and D, Nc, kn, kt, r, v), and the ratio ``eps'/v'``.
    """
    m = mean_structural_sum()
    fl = fluctuation_sums()
    msq = r * Nc ** 2  # mean(Nc'^2)
    corr = {v2: sp.expand(fl["v"] ** 2).subs(Ncp ** 2, msq), e2: sp.expand(fl["eps"] ** 2).subs(Ncp ** 2, msq),
            ev: sp.expand(fl["eps"] * fl["v"]).subs(Ncp ** 2, msq)}
    km = kroner_moduli()
    sub = {vbar_s: m["vbar"], ebar_s: m["ebar"], **corr}
    K, G = km["K"].subs(sub), km["G"].subs(sub)
    Xd, Yd = X_Y_definitions()
    sol = sp.solve([Xd - X, Yd - Y], [lam[0], lam[2]], dict=True)[0]
    K = sp.simplify(K.subs(sol))
    G = sp.simplify(G.subs(sol))
    for expr in (K, G):
        if any(sym in expr.free_symbols for sym in (lam[1], lam[3])):
            raise RuntimeError("the moduli do not depend on the lambdas through X and Y only")
    return K, G, fl["ratio"]


# ---- 5. least squares (38)-(43) -> (48)-(49) ------------------------------------------------------
Vvec = sp.symbols("V1 V2", real=True)  # odd angular distribution of the neighbours' contact numbers
Wvec = sp.symbols("W1 W2", real=True)  # odd angular distribution of mu's own contacts


@lru_cache(maxsize=None)
def odd_and_neighbour_sums():
    """The models (41)-(43) for one particle, as integrals (no bracket typed in).

    * (43), odd sum: mu's contacts with the first-harmonic density ``W.n(theta)``:
      ``A_ijk = int (W.n) K_ij(n) D n_k dtheta``; returned divided by ``pi D`` as ``odd[i,j,k]``
      (so that ``D A_ijk = pi D^2 odd_ijk``).
    * (41)-(42), neighbour sum: each neighbour's ``A^nu`` is the integral (36) with density
      ``Nc^nu/(2 pi)`` (:func:`mean_structural_sum` with Nc -> Nc^nu), and the neighbours' contact
      numbers have the odd angular distribution ``V.n(theta)``:
      ``sum_nu n_p (A^nu_lmnp + A^nu_lmpn) -> int (V.n) n_p (a_lmnp + a_lmpn) dtheta`` with
      ``a = A^nu / Nc^nu``; returned divided by ``pi D^2`` as ``nb[l,m,n]``.
    """
    n = (sp.cos(theta), sp.sin(theta))
    Wn = sum(Wvec[i] * n[i] for i in _R2)
    Vn = sum(Vvec[i] * n[i] for i in _R2)
    odd = {}
    for i, j, k in itertools.product(_R2, repeat=3):
        K_ij = kn * n[i] * n[j] + kt * (_d(i, j) - n[i] * n[j])
        odd[(i, j, k)] = sp.expand(circle_integral(Wn * K_ij * D * n[k]) / (sp.pi * D))
    a = {key: sp.simplify(val / Nc) for key, val in mean_structural_sum()["A"].items()}  # A^nu per contact
    nb = {}
    for ll, m, nn in itertools.product(_R2, repeat=3):
        integrand = sum(Vn * n[p] * (a[(ll, m, nn, p)] + a[(ll, m, p, nn)]) for p in _R2)
        nb[(ll, m, nn)] = sp.expand(circle_integral(integrand) / (sp.pi * D ** 2))
    return odd, nb


@lru_cache(maxsize=None)
def least_squares_XY():
    """Derive X, Y from the functional (40) with the models (21), (41)-(43).

    For one particle mu, with V = V^mu and W = W^mu (2-vectors) and the sums of
    :func:`odd_and_neighbour_sums` (both divided by ``pi D^2``), the residual of (40) is
    ``odd_ijk - (1/Nbar) Lambda_ijklmn nb_lmn`` ((39) with N^mu -> Nbar).

    We check that ``Lambda . nb`` depends on the lambdas only through X, Y (45)-(46), minimise
    ``sum_mu |residual|^2`` over X and Y (the terms in ``|W|^2`` do not depend on them), and return
    the normal equations and the solution in terms of ``S = sum V.W / sum V^2``.
    """
    Vv, Wv = Vvec, Wvec
    Lam = Lambda_21()
    odd, nb = odd_and_neighbour_sums()
    idx3 = list(itertools.product(_R2, repeat=3))
    lamterm = {(i, j, k): sp.expand(sum(Lam(i, j, k, *lmn) * nb[lmn] for lmn in idx3)) for (i, j, k) in idx3}
    # Lambda . (41) == 1/2 [ (X - 2Y) d_ij V_k + Y (d_ik V_j + d_jk V_i) ]  with X, Y of (45)-(46)
    Xd, Yd = X_Y_definitions()
    xy_form = {(i, j, k): sp.Rational(1, 2) * ((X - 2 * Y) * _d(i, j) * Vv[k]
                                               + Y * (_d(i, k) * Vv[j] + _d(j, k) * Vv[i]))
               for (i, j, k) in idx3}
    depends_on_XY_only = all(sp.expand(lamterm[key] - xy_form[key].subs({X: Xd, Y: Yd})) == 0 for key in idx3)
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
    Xs = sp.cancel(sol[X].subs(VW, S * VV))
    Ys = sp.cancel(sol[Y].subs(VW, S * VV))
    return {"depends_on_XY_only": depends_on_XY_only, "invariant": invariant,
            "normal_equations": normal, "X": Xs, "Y": Ys, "VV": VV, "VW": VW}


# ---- 6. alignment model (52)-(54) ---------------------------------------------------------------
@lru_cache(maxsize=None)
def alignment_integral():
    """(53): (1/(2 alpha)) int_{-alpha pi/2}^{alpha pi/2} cos(u) cos(u/alpha) du, for alpha != 1."""
    u = sp.symbols("u", real=True)
    return sp.simplify(sp.integrate(sp.cos(u) * sp.cos(u / alpha), (u, -alpha * sp.pi / 2, alpha * sp.pi / 2),
                                    conds="none") / (2 * alpha))


def rho_model_stable(a=alpha):
    """The alignment function (54) written without the 0/0 at alpha = 1 (used by the numeric code).

    With t = 1 - alpha: cos(pi alpha/2) = sin(pi t/2) and 1 - alpha^2 = t (1 + alpha), so
    rho = (pi/2) sinc(t/2) / (1 + alpha) with sinc(x) = sin(pi x)/(pi x) (numpy's sinc).
    """
    t = 1 - a
    return sp.pi / 2 * sp.sinc(sp.pi * t / 2) / (1 + a)


# ---- 7. final formulas ------------------------------------------------------------------------
@dataclass(frozen=True)
class FinalFormulas:
    """The working formulas (50)-(51) in the symbols ``kn``, ``kt``, ``Nc``, ``phi``, ``r``, ``Nbar``
    and ``rho`` (sympy expressions; evaluated, the moduli are in N/m like ``kn``).

    Attributes
    ----------
    K_mf, G_mf : sympy.Expr
        Mean-field bulk and shear moduli [N/m] (first terms of (50)-(51)).
    K, G : sympy.Expr
        Corrected bulk and shear moduli [N/m], (50)-(51) with (49) and ``rho = Nc S``.
    drop_K, drop_G : sympy.Expr
        Fraction changes ``1 - K/K_mf`` and ``1 - G/G_mf`` (dimensionless).
    """

    K_mf: sp.Expr
    G_mf: sp.Expr
    K: sp.Expr
    G: sp.Expr
    drop_K: sp.Expr
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
