"""The sympy derivation checks: run ``python -m microhom.derivations`` to see each identity checked.

Every check *derives* a result with :mod:`microhom.symbolic` (or
:func:`microhom.neighbourhood.derive_phi_of_nbar`) from the paper's starting points, and compares it
with something that was not used to derive it: the paper's printed result (typed in, as printed,
in :mod:`microhom.printed`), a reading of a garbled print (said so), an independent closed form,
an exact lattice value, or the numeric code of :mod:`microhom.moduli`. Equation numbers are those
of the seed paper.

**Circularity guard.** Each check records its ``inputs`` (the equations it starts from: the paper's
definitions and models) and its ``targets`` (the printed equations it is compared with), what was
derived and what it was compared with, and both expressions; :func:`circularity` rejects a check
whose targets are among its inputs, or that lacks either side, and ``tests/test_derivations.py``
checks that :mod:`microhom.symbolic` never imports :mod:`microhom.printed`. Where the printed
paper and the derivation differ, the check says so and ``docs/theory.md`` records the decision
(the derivation wins).

The test suite runs every check (``tests/test_derivations.py``).
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import sympy as sp

from . import moduli
from . import printed as P
from . import symbolic as s
from .neighbourhood import derive_phi_of_nbar, nbar_from_phi


def _show(expr):
    """A readable, deterministic form of ``expr`` for the printed sides of a check: numerator and
    denominator expanded and cancelled (``sp.cancel``). Not ``sp.factor``: its multivariate
    algorithm (Wang's) draws random evaluation points and, for some draws, ran for many minutes on
    the Kroener moduli (33)-(34) in CI."""
    return sp.cancel(expr)


__all__ = ["KINDS", "CHECKS", "Check", "circularity", "check", "run", "main"]

#: What the compared side of a :class:`Check` is: key -> description.
KINDS = {
    "printed": "the paper's printed formula (microhom.printed)",
    "reading": "our stated reading of a garbled print (microhom.printed, labelled a reconstruction)",
    "closed form": "an independent closed form (by hand or a second computation)",
    "lattice": "the exact value of a perfect lattice",
    "numeric": "the numeric code of microhom.moduli",
}


@dataclass
class Check:
    """One identity: what was derived (from which inputs) and what it was compared with.

    Attributes
    ----------
    name : str
        Name of the check (the function that made it).
    ref : str
        The equations involved, for the one-line summary, e.g. ``"(36)-(37)"``.
    ok : bool
        Whether the derived and the compared sides agree (set to False by :func:`run` when
        :func:`circularity` rejects the check).
    derived : str
        What sympy computed, in words.
    compared : str
        What it was compared with, in words.
    kind : str
        Key of :data:`KINDS`: the nature of the compared side.
    inputs : tuple of str
        Equations the derivation starts from (the paper's definitions and models).
    targets : tuple of str
        Printed equations compared with (must not be among the inputs).
    lhs : str
        The derived expression, printed.
    rhs : str
        The compared expression, printed.
    detail : str
        Extra information: an error, a numeric discrepancy, or why the check is circular.
    """

    name: str
    ref: str
    ok: bool
    derived: str
    compared: str
    kind: str
    inputs: tuple = ()
    targets: tuple = ()
    lhs: str = ""
    rhs: str = ""
    detail: str = ""


def circularity(c: Check) -> str:
    """Why a check is circular or unlabelled ("" if it is not): targets among inputs, a missing side."""
    if c.kind not in KINDS:
        return f"unknown kind {c.kind!r}"
    if not (c.derived and c.compared and c.lhs and c.rhs):
        return "the derived or the compared side is not stated"
    if c.kind in ("printed", "reading") and not c.targets:
        return "compared with the paper but names no printed equation"
    both = set(c.inputs) & set(c.targets)
    if both:
        return f"compared with {sorted(both)}, which it also starts from"
    return ""


def _zero(expr) -> bool:
    return sp.simplify(expr) == 0


def _all_zero(a: dict, b: dict, sign=1) -> bool:
    return all(_zero(a[k] - sign * b[k]) for k in a)


def _vsub():
    return {s.v: sp.pi * s.D ** 2 / (4 * s.phi)}


#: Every registered check, in the order :func:`run` runs them (functions returning a :class:`Check`).
CHECKS: list[Callable[[], Check]] = []


def check(fn):
    """Decorator: register ``fn`` (no arguments, returns a :class:`Check`) in :data:`CHECKS`."""
    CHECKS.append(fn)
    return fn


# ---- 1. mean structural sum and mean field ------------------------------------------------------
@check
def mean_sum_vbar_ebar():
    m = s.mean_structural_sum()
    vb, eb = P.vbar_ebar_37()
    return Check("isotropic mean structural sum from the angular integral: vbar, ebar", "(36)->(37)",
                 _zero(m["vbar"] - vb) and _zero(m["ebar"] - eb),
                 "the integral (36) with p = Nc/(2 pi), c = D n, identified with the isotropic form",
                 "vbar, ebar as printed in (37)", "printed", ("(35)", "(36)"), ("(37)",),
                 f"vbar = {m['vbar']}, ebar = {m['ebar']}", f"vbar = {vb}, ebar = {eb}")


@check
def mean_field_moduli():
    K, G = s.mean_field_moduli()
    Kp, Gp = P.mean_field_55()
    return Check("mean-field K = Nc phi kn/(2 pi), G = Nc phi (kn+kt)/(4 pi)", "(17),(37)->(50)-(51)",
                 _zero(K - Kp) and _zero(G - Gp),
                 "the stress map E -> (2v)^-1 Abar E of the derived (37), checked isotropic, with v = pi D^2/(4 phi)",
                 "the first (mean-field) terms of (50)-(51) as printed, in phi", "printed",
                 ("(17)", "(36)", "v(phi)"), ("(50)", "(51)"), f"K_mf = {K}, G_mf = {G}", f"K_mf = {Kp}, G_mf = {Gp}")


# ---- 2. spin elimination ------------------------------------------------------------------------
@check
def spin_B():
    m = s.mean_structural_sum()
    B, _, _ = s.spin_elimination(m["A"])
    closed = -s.Nc * s.D ** 2 * s.kt
    return Check("spin elimination: B = -Nc D^2 kt for the isotropic sum (singular when kt = 0)", "(15)",
                 _zero(B - closed) and _zero(B.subs(s.kt, 0)),
                 "B = eps_3qr eps_ij3 A_rijq (15) of the derived mean sum (37)",
                 "the hand closed form -Nc D^2 kt (the paper only says B is diagonal)", "closed form",
                 ("(15)", "(36)"), (), f"B = {B}", f"B = {closed}")


@check
def spin_Z_isotropic():
    m = s.mean_structural_sum()
    _, _, Z = s.spin_elimination(m["A"])
    e11, e22, e12 = sp.symbols("e11 e22 e12")
    E = [[e11, e12], [e12, e22]]
    ok = all(_zero(sum((Z[(p, k, a, b)] - m["A"][(p, a, b, k)]) * E[a][b] for a in (0, 1) for b in (0, 1)))
             for p in (0, 1) for k in (0, 1))
    return Check("isotropic sum: the spin term of Z vanishes on a symmetric strain (Z E = A E)",
                 "(16),after (30)", ok, "Z (16) of the derived mean sum applied to a general symmetric E",
                 "the paper's statement after (30): eps eps A B^-1 A E = 0 with isotropy, i.e. Z E = A E",
                 "printed", ("(16)", "(36)"), ("after (30)",), "Z_pkst E_st - A_pstk E_st = 0 (all p, k)",
                 "eps_nqr eps_ijl A_pijk B^-1_ln A_rstq E_st = 0")


@check
def spin_T_isotropic():
    m = s.mean_structural_sum()
    _, T, _ = s.spin_elimination(m["A"])
    idx = [(i, j, a, b) for i in (0, 1) for j in (0, 1) for a in (0, 1) for b in (0, 1)]
    sym = all(_zero(T[k] - sp.Rational(1, 2) * ((k[0] == k[2]) * (k[1] == k[3]) + (k[0] == k[3]) * (k[1] == k[2])))
              for k in idx)
    printed = P.T_isotropic_after_32()
    same_on_sym = all(
        _zero(T[(i, j, 0, 1)] + T[(i, j, 1, 0)] - printed[(i, j, 0, 1)] - printed[(i, j, 1, 0)])
        and _zero(T[(i, j, 0, 0)] - printed[(i, j, 0, 0)]) and _zero(T[(i, j, 1, 1)] - printed[(i, j, 1, 1)])
        for i in (0, 1) for j in (0, 1))
    return Check("isotropic T_ijst = (d_is d_jt + d_it d_js)/2; the printed 2 d_is d_jt - d_it d_js "
                 "differs on antisymmetric strain only (documented)", "(22),(32)", sym and same_on_sym,
                 "T (22) of the derived mean sum: the symmetric projector",
                 "T as printed after (32); equal on every symmetric strain (the difference is documented)",
                 "printed", ("(15)", "(16)", "(36)"), ("after (32)",),
                 "T = (d_is d_jt + d_it d_js)/2", "T = 2 d_is d_jt - d_it d_js")


# ---- 3. Kroener: (22) -> (26) -> (27) -> (29)-(30) -> (31) -> (33)-(34) ----------------------------
@check
def kroner_operator_26():
    L = s.kroner_operator()
    Pm = P.operator_26(s.vbar_s, s.ebar_s, s.k_vec)
    return Check("the operator of (26) from the left side of (22) with the isotropic mean (24)", "(22)-(24)->(26)",
                 all(_zero(L[i, j] - Pm[i, j]) for i in (0, 1) for j in (0, 1)),
                 "Abar_pijk dE'_ij/dx_k with E' = sym grad u' (23), Abar of (24), in Fourier space",
                 "the operator of (26) as printed, 1/2(v+e) lap u_p + 1/2(v+3e) grad div u", "printed",
                 ("(22)", "(23)", "(24)"), ("(26)",), f"L = {L.tolist()}", f"L = {Pm.tolist()}")


@check
def kroner_sign_27():
    ker = s.kroner_kernel()
    pr = P.kernel_27(s.vbar_s, s.ebar_s, s.k_vec)
    minus = _all_zero(ker, pr, sign=-1)
    plus = _all_zero(ker, pr, sign=+1)
    key = (0, 0, 0, 0)
    return Check("(26) solved in Fourier space: i k_s u_hat_p = -2 k_q k_s [...] S_hat E; the printed (27) "
                 "lacks the minus sign (from i*i = -1), which (30) has (documented)", "(26)->(27)",
                 minus and not plus,
                 "i k_s L^-1(k) i k_q S_hat_rijq E_ij with L the derived operator of (26)",
                 "the kernel of (27) as printed: equal to minus the derived one", "printed",
                 ("(26)",), ("(27)",), f"kernel[0000] = {_show(ker[key])}",
                 f"printed kernel[0000] = {_show(pr[key])} (derived = -printed)")


@check
def local_part_lemma():
    return Check("local part (29): the integral over a small circle of the inverse transform of a degree-0 "
                 "kernel is its angular mean", "(29)", s.local_part_lemma(),
                 "Gauss' theorem on the Green's functions -log r/(2 pi) of 1/k^2 and r^2 (log r - 1)/(8 pi) "
                 "of 1/k^4 for every monomial k_q k_s/k^2, k_p k_r k_q k_s/k^4",
                 "the angular mean of the same monomial (a second computation)", "closed form",
                 ("(29)",), (), "int_R d^2y FT^-1[k_p k_r k_q k_s/k^4] = (circle) n_p d_r d_q d_s g4",
                 "<n_p n_r n_q n_s> over the unit circle")


@check
def kroner_local_30():
    loc = s.kroner_local()
    pr = P.local_30(s.vbar_s, s.ebar_s)
    key = (0, 0, 0, 0)
    return Check("local displacement-gradient fluctuation (30) from the derived (27) and the lemma (29)",
                 "(27),(29)->(30)", _all_zero(loc, pr),
                 "the angular mean of the derived kernel of (27) (sign included)",
                 "(30) as printed (S'_piqq read as S'_pijq)", "printed", ("(26)", "(29)"), ("(30)",),
                 f"local[0000] = {_show(loc[key])}", f"printed[0000] = {_show(pr[key])}")


@check
def kroner_33_34():
    km = s.kroner_moduli()
    Kp, Gp = P.kroner_33_34(s.vbar_s, s.ebar_s, s.v2, s.e2, s.ev)
    ok = _zero(km["K"] - Kp) and _zero(km["G"] - Gp) and km["T_const"] and km["Z_is_A"]
    return Check("the Kroener moduli (33)-(34) derived from (31) with the fluctuation model (32)",
                 "(21),(25),(30)-(32)->(33)-(34)", ok,
                 "mean stress (31) with A' isotropic (32) (T' = 0, Z'E' = A'E' checked), S' of (25) with Lambda "
                 "of (21), the derived local estimate (30); K, G from isotropic and shear E",
                 "(33) and (34) as printed", "printed", ("(21)", "(24)", "(25)", "(29)", "(31)", "(32)"),
                 ("(33)", "(34)"), f"K = {_show(km['K'])}; G = {_show(km['G'])}",
                 f"K = {Kp}; G = {Gp}")


# ---- 4. constant stiffnesses ----------------------------------------------------------------------
@check
def fluctuation_ratio():
    fl = s.fluctuation_sums()
    A42 = P.A_nu_42(s.Ncp)
    ok = _all_zero(fl["A"], A42) and _zero(fl["ratio"] - P.eps_ratio_44())
    return Check("constant stiffness: A' is the integral (36) with Nc'; eps'/v' = (kn - kt)/(kn + 3 kt)",
                 "(36),(41)->(42),(44)", ok,
                 "the integral (36) with density Nc'/(2 pi) (mean_structural_sum with Nc -> Nc'), identified as "
                 "v' d d + eps' (d d + d d)", "A^nu of (42) with Nc^nu -> Nc', and the ratio (44), as printed",
                 "printed", ("(36)", "(41)"), ("(42)", "(44)"),
                 f"v' = {fl['v']}, eps' = {fl['eps']}, eps'/v' = {fl['ratio']}",
                 f"A'_1111 = {_show(A42[(0, 0, 0, 0)])}, eps'/v' = {P.eps_ratio_44()}")


@check
def closed_forms_50_51():
    K, G, _ = s.constant_stiffness_moduli()
    Kp, Gp = P.moduli_50_51()
    return Check("the derived (33)-(34) with the constant-stiffness fluctuations depend on lambda only via X, Y "
                 "and equal (50)-(51)", "(33)-(34),(44),(45)-(46)->(50)-(51)", _zero(K - Kp) and _zero(G - Gp),
                 "the derived (33)-(34) with v', eps' of the derived (44), mean(Nc'^2) = r Nc^2, lambda1, lambda3 "
                 "eliminated through the definitions (45)-(46)", "(50)-(51) as printed", "printed",
                 ("(33) derived", "(34) derived", "(44) derived", "(45)", "(46)"), ("(50)", "(51)"),
                 f"K = {K}; G = {G}", f"K = {Kp}; G = {Gp}")


# ---- 5. least squares ------------------------------------------------------------------------------
@check
def least_squares_structure():
    ls = s.least_squares_XY()
    return Check("Lambda . (41) depends on the lambdas only through X and Y; the functional is rotation "
                 "invariant", "(21),(40)-(46)", bool(ls["depends_on_XY_only"] and ls["invariant"]),
                 "Lambda (21) contracted with the neighbour sum of (41)-(42) (integrals), and the squared residual "
                 "of (40) as a quadratic form in V, W",
                 "the combinations X, Y the paper prints in (45)-(46); rotation invariance", "printed",
                 ("(21)", "(36)", "(38)-(43)"), ("(45)", "(46)"),
                 "Lambda.nb = 1/2[(X - 2Y) d_ij V_k + Y (d_ik V_j + d_jk V_i)]",
                 "X = kn(2l1+4l2+4l3+3l4) + kt(2l1+4l3+l4), Y = kn(2l3+l4) + kt(2l3-l4)")


@check
def least_squares_solution():
    ls = s.least_squares_XY()
    Xp, Yp = P.XY_49()
    sat = all(_zero(e.subs({s.X: ls["X"], s.Y: ls["Y"]}).subs(ls["VW"], s.S * ls["VV"]))
              for e in P.normal_equations_48(ls["VV"], ls["VW"]))
    return Check("least squares: the minimiser solves the printed normal equations (48) and is (49)",
                 "(40)->(48)->(49)", _zero(ls["X"] - Xp) and _zero(ls["Y"] - Yp) and sat,
                 "the minimiser over X, Y of the functional (40) with the integral models (41)-(43)",
                 "(48) and (49) as printed", "printed", ("(21)", "(38)-(43)", "(45)", "(46)"), ("(48)", "(49)"),
                 f"X = {ls['X']}, Y = {ls['Y']}", f"X = {Xp}, Y = {Yp}")


# ---- 6. alignment model ------------------------------------------------------------------------------
@check
def alignment_model():
    integral = s.alignment_integral()
    pr = P.rho_54()
    lim = sp.limit(integral, s.alpha, 1)
    stable = s.rho_model_stable()
    same = all(abs(float((stable - integral).subs(s.alpha, a))) < 1e-14 for a in (0.3, 0.9, 1.2, 1.76, 1.99))
    ok = _zero(integral - pr) and _zero(lim - sp.pi / 4) and _zero(stable.subs(s.alpha, 1) - sp.pi / 4) and same
    return Check("alignment integral = cos(pi alpha/2)/(1 - alpha^2); limit pi/4 at alpha = 1; "
                 "stable sinc form agrees", "(52)-(54)", ok,
                 "the integral (53) with the density (52), p0 = 1/(2 alpha); its limit at alpha = 1",
                 "(54) as printed; pi/4 (closed form); the sinc form of moduli.py at 5 points", "printed",
                 ("(52)",), ("(54)",), f"integral = {integral}, limit = {lim}", f"(54) = {pr}")


# ---- 7. final formulas and limits ---------------------------------------------------------------------
@check
def final_working_formulas():
    f = s.final_formulas()
    x = s.r * s.Nbar * s.rho / s.Nc
    wK, wG = 4 * s.kn / (3 * s.kn + s.kt) * x, 2 * (2 * s.kn + s.kt) / (3 * s.kn + s.kt) * x
    return Check("K = K_mf [1 - 4kn/(3kn+kt) r (Nbar/Nc) rho], G = G_mf [1 - 2(2kn+kt)/(3kn+kt) r (Nbar/Nc) rho]",
                 "(49)-(51),(54)", _zero(f.drop_K - wK) and _zero(f.drop_G - wG),
                 "the derived (50)-(51) with the derived (49) and rho = Nc S",
                 "the working formulas of microhom.moduli (its docstring; the numeric check compares the code)",
                 "closed form", ("(50) derived", "(51) derived", "(49) derived"), (),
                 f"drop_K = {f.drop_K}, drop_G = {f.drop_G}", f"drop_K = {wK}, drop_G = {wG}")


@check
def limit_equal_stiffness():
    f = s.final_formulas()
    K55, G55 = P.limits_55()
    K, G = f.K.subs(s.kt, s.kn), f.G.subs(s.kt, s.kn)
    ratio = sp.simplify(f.drop_G.subs(s.kt, s.kn) / f.drop_K.subs(s.kt, s.kn))
    return Check("kt = kn gives (55); shear/bulk drop ratio exactly 3/2", "(55)",
                 _zero(K - K55) and _zero(G - G55) and ratio == sp.Rational(3, 2),
                 "the derived working formulas at kt = kn", "(55) as printed, in phi; the ratio 3/2 the text states",
                 "printed", ("(50) derived", "(51) derived"), ("(55)",),
                 f"K = {_show(K)}, G = {_show(G)}, ratio = {ratio}", f"K = {_show(K55)}, G = {_show(G55)}")


@check
def limit_frictionless():
    f = s.final_formulas()
    K0, G0 = P.frictionless_56()
    K, G = f.K.subs(s.kt, 0), f.G.subs(s.kt, 0)
    return Check("kt = 0 gives the frictionless pair, factor 4/3 in both", "(56)", _zero(K - K0) and _zero(G - G0),
                 "the derived working formulas at kt = 0", "the frictionless pair as printed after (55), in phi",
                 "printed", ("(50) derived", "(51) derived"), ("(56)",),
                 f"K = {_show(K)}, G = {_show(G)}", f"K = {_show(K0)}, G = {_show(G0)}")


@check
def biaxial_delta():
    Kk, Gg = sp.symbols("K G", positive=True)
    d = s.biaxial_delta(Kk, Gg)
    f = s.final_formulas()
    d_mf = s.biaxial_delta(f.K_mf, f.G_mf).subs(s.kt, s.kn)
    d_eq = sp.simplify(s.biaxial_delta(f.K.subs(s.kt, s.kn), f.G.subs(s.kt, s.kn)))
    reading = P.delta_section6_reading()
    ok = _zero(d - (Gg - Kk) / (Gg + Kk)) and _zero(d_mf) and _zero(d_eq - reading)
    return Check("Delta derived: (G - K)/(G + K) from sigma_2 = 0; 0 in the mean field at kt = kn; at kt = kn "
                 "-x/(4 - 5x), x = r (Nbar/Nc) rho, equal to our reading of the garbled print", "section 6", ok,
                 "Delta = e2/e1 with sigma_2 = (K - G) e1 + (K + G) e2 = 0, then the derived K, G at kt = kn",
                 "Delta = (G - K)/(G + K) as printed, and the kt = kn value as READ: -(x/2)/(2[1 - (5/4)x]) "
                 "(the converted print is garbled; docs/theory.md states the reading)", "reading",
                 ("(50) derived", "(51) derived", "sigma_2 = 0"), ("Delta (section 6)",),
                 f"Delta = {d}; Delta(kt = kn) = {d_eq}", f"Delta(kt = kn) read as {sp.simplify(reading)}")


@check
def nbar_from_phi_geometry():
    g = derive_phi_of_nbar()
    N = g["N"]
    rel = P.phi_nbar_section6(N)
    ok = (g["angle_ok"] and _zero(g["phi"] - rel) and _zero(g["area"] - P.polygon_area_section6(N))
          and _zero(g["solids"] - P.solids_section6(N)))
    nb = sp.nsolve(g["phi"] - sp.Rational(82, 100), N, 5)
    ok = ok and abs(float(nb) - float(nbar_from_phi(0.82))) < 1e-12 and round(float(nb)) == 5
    ok = ok and _zero(g["phi"].subs(N, 6) - sp.pi / (2 * sp.sqrt(3))) and _zero(g["phi"].subs(N, 4) - sp.pi / 4)
    return Check("phi(Nbar) derived from the polygon and its sectors; Nbar = 6 -> pi/(2 sqrt 3), 4 -> pi/4; "
                 "phi = 0.82 -> Nbar = 4.91 (the paper rounds to 5), equal to moduli.nbar_from_phi", "section 6", ok,
                 "area of the regular N-gon of circumradius D from its vertices, interior angle from the edge "
                 "dot product, solids = central disk + N sectors; phi = solids/area",
                 "the polygon area, the solids pi Nbar D^2/8 and phi(Nbar) as printed; the numeric inverse",
                 "printed", ("regular polygon", "v(phi)"), ("phi(Nbar) (section 6)",),
                 f"area = {g['area']}, solids = {g['solids']}, phi = {g['phi']}, Nbar(0.82) = {float(nb):.6f}",
                 f"phi = {rel}, nbar_from_phi(0.82) = {float(nbar_from_phi(0.82)):.6f}")


@check
def triangular_lattice_mean_field():
    K, G = s.mean_field_moduli()
    sub = {s.Nc: 6, s.phi: sp.pi / (2 * sp.sqrt(3))}
    Kt, Gt = K.subs(sub), G.subs(sub)
    nu = sp.simplify(((Kt - Gt) / (Kt + Gt)).subs(s.kt, 0))
    return Check("triangular lattice (Nc = 6, phi = pi/(2 sqrt 3)): K = (sqrt3/2) kn, G = (sqrt3/4)(kn+kt); "
                 "Poisson 1/3 at kt = 0", "exact",
                 _zero(Kt - sp.sqrt(3) / 2 * s.kn) and _zero(Gt - sp.sqrt(3) / 4 * (s.kn + s.kt))
                 and nu == sp.Rational(1, 3),
                 "the derived mean field at Nc = 6, phi = pi/(2 sqrt 3)",
                 "the exact affine moduli of the triangular lattice", "lattice", ("(36)", "(17)"), (),
                 f"K = {Kt}, G = {Gt}, nu(kt=0) = {nu}", "K = sqrt(3)/2 kn, G = sqrt(3)/4 (kn + kt), nu = 1/3")


@check
def numeric_matches_symbolic():
    f = s.lambdify_final()
    rng = np.random.default_rng(0)
    n = 200
    knv = 10 ** rng.uniform(-3, 12, n)
    ktv = knv * rng.choice([0.0, 1e-12, 1e-3, 0.25, 1.0, 10.0], n)
    ncv = rng.uniform(3.0, 6.0, n)
    phiv = rng.uniform(0.79, 0.9, n)
    rv = rng.uniform(0.0, 0.4, n)
    nbv = nbar_from_phi(phiv)
    rhov = rng.uniform(0.2, 1.0, n)
    Kmf, Gmf, K, G = (np.asarray(a, dtype=float) for a in f(knv, ktv, ncv, phiv, rv, nbv, rhov))
    p = moduli.predict_moduli(knv, ktv, ncv, phiv, rv, rho=rhov, warn=False)
    err = max(np.max(np.abs(p.K_mf / Kmf - 1)), np.max(np.abs(p.G_mf / Gmf - 1)),
              np.max(np.abs(p.K - K) / Kmf), np.max(np.abs(p.G - G) / Gmf))
    integral = s.alignment_integral()
    alphas = ["0", "0.5", "0.999999999", "1", "1.000000001", "1.76", "2"]
    ref = np.array([float(sp.limit(integral, s.alpha, 1)) if a == "1" else
                    float(integral.subs(s.alpha, sp.Float(a, 40)).evalf(30)) for a in alphas])
    err_rho = np.max(np.abs(moduli.rho_from_alpha(np.array(alphas, dtype=float)) / ref - 1))
    return Check("numeric moduli.py equals the lambdified symbolic formulas (200 random sets, kn over 15 decades)",
                 "(50)-(54)", err < 1e-12 and err_rho < 1e-14,
                 "the derived working formulas and the derived alignment integral, evaluated (30 digits for rho)",
                 "microhom.moduli.predict_moduli and rho_from_alpha", "numeric",
                 ("(50) derived", "(51) derived", "(53) derived"), (),
                 f"max rel err {err:.2e}", f"rho err {err_rho:.2e}")


def _lammps_history_step(arm):
    """The rate of the generalized forces of one sphere contact under LAMMPS's
    ``gran/hooke/history`` update, by sympy: frame with ``n = e_z`` at ``t = 0``, branch
    ``c = (0, 0, l) + (v_j - v_i) t``, turns ``w t``; the history ``s0 = (s1, s2, 0)`` gets the
    increment ``vtr dt`` (tangential relative velocity of the contact points at the new normal)
    and is projected on the new tangent plane; forces ``f = kn (R - |c|) n - kt s`` on ``j``,
    ``-f`` on ``i``, torques ``-a n x f``. Returns (d/dt of the 12 generalized forces, the
    12 unknown rates, symbols)."""
    l, R, kn, kt, ri, rj, dt, s1, s2 = sp.symbols("l R k_n k_t r_i r_j dt s_1 s_2", positive=True)
    vi, vj, wi, wj = (sp.Matrix(sp.symbols(f"{k}1:4", real=True)) for k in ("vi", "vj", "wi", "wj"))
    c = sp.Matrix([0, 0, l]) + (vj - vi) * dt
    L = sp.sqrt(c.dot(c))
    n = c / L

    def first_order(e):                      # e(0) + e'(0) dt: the rates need no more
        return e.subs(dt, 0) + sp.diff(e, dt).subs(dt, 0) * dt
    L, n = first_order(L), n.applyfunc(first_order)
    ai, aj = (ri, rj) if arm == "radius" else (L * ri / (ri + rj), L * rj / (ri + rj))
    vt = (vj - vi) - n * n.dot(vj - vi)
    s = sp.Matrix([s1, s2, 0]) + (vt - (ai * wi + aj * wj).cross(n)) * dt
    s = s - n * n.dot(s)
    f = kn * (R - L) * n - kt * s
    Q = sp.Matrix.vstack(-f, -ai * n.cross(f), f, -aj * n.cross(f))
    rate = Q.diff(dt).subs(dt, 0)
    return rate, sp.Matrix.vstack(vi, wi, vj, wj), (l, R, kn, kt, ri, rj, s1, s2)


def _history_closed_form(arm, z, syms):
    """The same rate from the assembly's closed forms (docs/spheres.md): ``-(B^T K B +
    Bc^T (K_g + G_t) Bc + X Bc) z`` with ``K = kn n n + kt P``, ``K_g = -(fn/l) P``,
    ``G_t = n ft^T / l``, ``X_i = -a_i [ft]x P / l + kappa_i (n x ft) n^T``."""
    l, R, kn, kt, ri, rj, s1, s2 = syms
    n = sp.Matrix([0, 0, 1])
    P = sp.eye(3) - n * n.T
    ft = -kt * sp.Matrix([s1, s2, 0])
    fn = kn * (R - l)
    ai, aj = (ri, rj) if arm == "radius" else (l * ri / (ri + rj), l * rj / (ri + rj))
    kap = (0, 0) if arm == "radius" else (ri / (ri + rj), rj / (ri + rj))

    def cross(v):
        return sp.Matrix([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    Z = sp.zeros(3)
    B = sp.Matrix.hstack(-sp.eye(3), ai * cross(n), sp.eye(3), aj * cross(n))
    Bc = sp.Matrix.hstack(-sp.eye(3), Z, sp.eye(3), Z)
    K = kn * n * n.T + kt * P
    Kg = -(fn / l) * P
    Gt = n * ft.T / l
    X = sp.Matrix.vstack(Z, -ai * cross(ft) * P / l + kap[0] * n.cross(ft) * n.T,
                         Z, -aj * cross(ft) * P / l + kap[1] * n.cross(ft) * n.T)
    return -(B.T * K * B + Bc.T * (Kg + Gt) * Bc + X * Bc) * z


@check
def tangential_history_rates():
    ok = True
    shown = []
    for arm in ("radius", "contact"):
        rate, z, syms = _lammps_history_step(arm)
        closed = _history_closed_form(arm, z, syms)
        ok = ok and all(sp.expand(sp.cancel(a - b)) == 0 for a, b in zip(rate, closed))
        shown.append((arm, sp.expand(rate[5]), sp.expand(closed[5])))
    return Check("3D contact with a tangential history: the rates of its forces and torques under "
                 "LAMMPS's update are the assembly's K, K_g, G_t and X_i (radius and contact arms)",
                 "spheres", ok,
                 "d/dt of the forces and torques after one LAMMPS gran/hooke/history step (increment "
                 "vtr dt, projection on the new tangent plane, f = kn overlap n - kt s), n = e_z",
                 "-(B^T K B + Bc^T (K_g + G_t) Bc + X Bc) z with G_t = n ft^T/l, "
                 "X_i = -a_i [ft]x P/l + kappa_i (n x ft) n^T (docs/spheres.md)", "closed form",
                 ("LAMMPS gran/hooke/history update",), (),
                 f"z torque rate on i (radius arm): {shown[0][1]}",
                 f"closed form: {shown[0][2]}")


def run(verbose=True, out=None):
    """Run every check, print what was derived and what it was compared with; return the list of Check.

    ``verbose=False`` prints the failures and the summary only; ``out`` is a text stream
    (default ``sys.stdout``).

    A check that raises, or that :func:`circularity` rejects, fails with the reason shown.
    """
    out = sys.stdout if out is None else out
    results = []
    for fn in CHECKS:
        t0 = time.perf_counter()
        try:
            c = fn()
        except Exception as exc:  # a crashing derivation is a failed check, shown with its reason
            c = Check(fn.__name__, "?", False, "?", "?", "closed form", detail=f"{type(exc).__name__}: {exc}")
        why = circularity(c) if c.derived != "?" else ""
        if why:
            c.ok, c.detail = False, f"CIRCULAR: {why}"
        dt = time.perf_counter() - t0
        results.append(c)
        if verbose or not c.ok:
            mark = "PASS" if c.ok else "FAIL"
            print(f"[{mark}] {c.ref:>24}  {c.name}  ({dt:.1f} s)", file=out)
            if verbose:
                pad = " " * 8
                print(f"{pad}derived : {c.derived}", file=out)
                print(f"{pad}   from : {', '.join(c.inputs) or '-'}", file=out)
                print(f"{pad}compared: {c.compared} [{c.kind}: {KINDS.get(c.kind, '?')}]"
                      + (f"; printed {', '.join(c.targets)}" if c.targets else ""), file=out)
                print(f"{pad}  lhs   : {c.lhs}", file=out)
                print(f"{pad}  rhs   : {c.rhs}", file=out)
            if c.detail:
                print(f"{' ' * 8}{c.detail}", file=out)
    n_ok = sum(c.ok for c in results)
    kinds = {k: sum(c.kind == k for c in results) for k in KINDS}
    n_circ = sum(bool(circularity(c)) for c in results if c.derived != "?")
    print(f"derivations: {n_ok} passed, {len(results) - n_ok} failed; compared with: "
          + ", ".join(f"{v} {k}" for k, v in kinds.items() if v)
          + (f"; {n_circ} circular" if n_circ else "; none circular"), file=out)
    return results


def main(argv=None):
    """Command line ``python -m microhom.derivations [--quiet]``; returns the exit code (0: all passed)."""
    ap = argparse.ArgumentParser(prog="python -m microhom.derivations",
                                 description="Check every homogenisation formula by sympy derivation: for each "
                                             "identity, what was derived (from which equations) and what it was "
                                             "compared with.")
    ap.add_argument("--quiet", action="store_true", help="print failures and the summary only")
    args = ap.parse_args(argv)
    res = run(verbose=not args.quiet)
    return 0 if all(c.ok for c in res) else 1


if __name__ == "__main__":
    sys.exit(main())
