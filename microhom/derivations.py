"""The sympy derivation checks: run ``python -m microhom.derivations`` to see each identity checked.

Every check derives a result with :mod:`microhom.symbolic` and compares it with the paper's
printed formula (equation numbers of the seed paper), with a closed form, or with the numeric
code in :mod:`microhom.moduli`. Where the printed paper and the derivation differ, the check
says so and ``docs/theory.md`` records the decision (the derivation wins).

The test suite runs every check (``tests/test_derivations.py``).
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from typing import Callable

import sympy as sp

from . import symbolic as s


@dataclass
class Check:
    name: str
    ref: str  # paper equation(s)
    ok: bool
    detail: str = ""


def _zero(expr) -> bool:
    return sp.simplify(expr) == 0


CHECKS: list[Callable[[], Check]] = []


def check(fn):
    CHECKS.append(fn)
    return fn


@check
def mean_sum_vbar_ebar():
    m = s.mean_structural_sum()
    vb = s.D ** 2 * s.Nc * (s.kn + 3 * s.kt) / 8
    eb = s.D ** 2 * s.Nc * (s.kn - s.kt) / 8
    return Check("isotropic mean structural sum from the angular integral: vbar, ebar", "(36)->(37)",
                 _zero(m["vbar"] - vb) and _zero(m["ebar"] - eb), f"vbar = {m['vbar']}, ebar = {m['ebar']}")


@check
def mean_field_moduli():
    K, G = s.mean_field_moduli()
    ok = _zero(K - s.Nc * s.phi * s.kn / (2 * sp.pi)) and _zero(G - s.Nc * s.phi * (s.kn + s.kt) / (4 * sp.pi))
    m = s.mean_structural_sum()
    vsub = {s.v: sp.pi * s.D ** 2 / (4 * s.phi)}
    first_33 = ((3 * m["ebar"] + m["vbar"]) / (2 * s.v) / 2).subs(vsub)
    first_34 = ((m["ebar"] + m["vbar"]) / (2 * s.v) / 2).subs(vsub)
    ok = ok and _zero(K - first_33) and _zero(G - first_34)
    return Check("mean-field K = Nc phi kn/(2 pi), G = Nc phi (kn+kt)/(4 pi); equal the first terms of (33)-(34)",
                 "(17),(33),(34),(37)", ok, f"K_mf = {K}, G_mf = {G}")


@check
def spin_B():
    m = s.mean_structural_sum()
    B, _, _ = s.spin_elimination(m["A"])
    ok = _zero(B + s.Nc * s.D ** 2 * s.kt) and _zero(B.subs(s.kt, 0))
    return Check("spin elimination: B = -Nc D^2 kt for the isotropic sum (singular when kt = 0)", "(15)", ok,
                 f"B = {B}")


@check
def spin_Z_isotropic():
    m = s.mean_structural_sum()
    _, _, Z = s.spin_elimination(m["A"])
    e11, e22, e12 = sp.symbols("e11 e22 e12")
    E = [[e11, e12], [e12, e22]]
    ok = all(_zero(sum((Z[(p, k, a, b)] - m["A"][(p, a, b, k)]) * E[a][b] for a in (0, 1) for b in (0, 1)))
             for p in (0, 1) for k in (0, 1))
    return Check("isotropic sum: the spin term of Z vanishes on a symmetric strain (Z E = A E)",
                 "(16),(30)", ok)


@check
def spin_T_isotropic():
    m = s.mean_structural_sum()
    _, T, _ = s.spin_elimination(m["A"])
    sym = all(_zero(T[(i, j, a, b)] - sp.Rational(1, 2) * ((i == a) * (j == b) + (i == b) * (j == a)))
              for i in (0, 1) for j in (0, 1) for a in (0, 1) for b in (0, 1))
    printed = {(i, j, a, b): 2 * (i == a) * (j == b) - (i == b) * (j == a)
               for i in (0, 1) for j in (0, 1) for a in (0, 1) for b in (0, 1)}
    same_on_sym = all(
        _zero(T[(i, j, 0, 1)] + T[(i, j, 1, 0)] - printed[(i, j, 0, 1)] - printed[(i, j, 1, 0)])
        and _zero(T[(i, j, 0, 0)] - printed[(i, j, 0, 0)]) and _zero(T[(i, j, 1, 1)] - printed[(i, j, 1, 1)])
        for i in (0, 1) for j in (0, 1))
    return Check("isotropic T_ijst = (d_is d_jt + d_it d_js)/2; the printed 2 d_is d_jt - d_it d_js "
                 "differs on antisymmetric strain only (documented)", "(22),(32)", sym and same_on_sym)


@check
def fluctuation_ratio():
    _, _, ratio = s.constant_stiffness_moduli()
    return Check("constant stiffness: eps'/v' = (kn - kt)/(kn + 3 kt)", "(42)->(44)",
                 _zero(ratio - (s.kn - s.kt) / (s.kn + 3 * s.kt)), f"{ratio}")


@check
def closed_forms_50_51():
    K, G, _ = s.constant_stiffness_moduli()
    Kp, Gp = s.printed_50_51()
    return Check("(33)-(34) with the isotropic fluctuation model depend on lambda only via X, Y and "
                 "equal (50)-(51)", "(32)-(34),(45)-(46)->(50)-(51)", _zero(K - Kp) and _zero(G - Gp))


@check
def least_squares_structure():
    ls = s.least_squares_XY()
    return Check("Lambda . (41) depends on the lambdas only through X and Y; the functional is rotation "
                 "invariant", "(21),(40)-(46)", bool(ls["depends_on_XY_only"] and ls["invariant"]))


@check
def least_squares_solution():
    ls = s.least_squares_XY()
    Xp = (3 * s.kn + s.kt) * s.Nbar * s.S / 2
    Yp = (s.kn - s.kt) * s.Nbar * s.S / 2
    sat = all(_zero(e.subs({s.X: ls["X"], s.Y: ls["Y"]}).subs(ls["VW"], s.S * ls["VV"]))
              for e in ls["printed_48"])
    return Check("least squares: the minimiser solves the printed normal equations (48) and is (49)",
                 "(40)->(48)->(49)", _zero(ls["X"] - Xp) and _zero(ls["Y"] - Yp) and sat,
                 f"X = {ls['X']}, Y = {ls['Y']}")


@check
def alignment_model():
    integral = s.alignment_integral()
    ok = _zero(integral - s.rho_model())
    lim = sp.limit(s.rho_model(), s.alpha, 1)
    stable = s.rho_model_stable()
    same = all(abs(float((stable - s.rho_model()).subs(s.alpha, a))) < 1e-14 for a in (0.3, 0.9, 1.2, 1.76, 1.99))
    return Check("alignment integral = cos(pi alpha/2)/(1 - alpha^2); limit pi/4 at alpha = 1; "
                 "stable sinc form agrees", "(52)-(54)",
                 ok and _zero(lim - sp.pi / 4) and _zero(stable.subs(s.alpha, 1) - sp.pi / 4) and same,
                 f"integral = {integral}")


@check
def final_working_formulas():
    f = s.final_formulas()
    x = s.r * s.Nbar * s.rho / s.Nc
    ok = _zero(f.drop_K - 4 * s.kn / (3 * s.kn + s.kt) * x) and _zero(
        f.drop_G - 2 * (2 * s.kn + s.kt) / (3 * s.kn + s.kt) * x)
    return Check("K = K_mf [1 - 4kn/(3kn+kt) r (Nbar/Nc) rho], G = G_mf [1 - 2(2kn+kt)/(3kn+kt) r (Nbar/Nc) rho]",
                 "(49)-(51),(54)", ok, f"drop_K = {f.drop_K}, drop_G = {f.drop_G}")


@check
def limit_equal_stiffness():
    f = s.final_formulas()
    x = s.r * s.Nbar * s.rho / s.Nc
    pre = s.D ** 2 * s.Nc * s.kn / (8 * s.v)
    vsub = {s.v: sp.pi * s.D ** 2 / (4 * s.phi)}
    K55 = (pre * (1 - x)).subs(vsub)
    G55 = (pre * (1 - sp.Rational(3, 2) * x)).subs(vsub)
    K, G = f.K.subs(s.kt, s.kn), f.G.subs(s.kt, s.kn)
    ratio = sp.simplify(f.drop_G.subs(s.kt, s.kn) / f.drop_K.subs(s.kt, s.kn))
    return Check("kt = kn gives (55); shear/bulk drop ratio exactly 3/2", "(55)",
                 _zero(K - K55) and _zero(G - G55) and ratio == sp.Rational(3, 2), f"ratio = {ratio}")


@check
def limit_frictionless():
    f = s.final_formulas()
    x = s.r * s.Nbar * s.rho / s.Nc
    vsub = {s.v: sp.pi * s.D ** 2 / (4 * s.phi)}
    K0 = (s.D ** 2 * s.Nc * s.kn / (8 * s.v) * (1 - sp.Rational(4, 3) * x)).subs(vsub)
    G0 = (s.D ** 2 * s.Nc * s.kn / (16 * s.v) * (1 - sp.Rational(4, 3) * x)).subs(vsub)
    return Check("kt = 0 gives the frictionless pair, factor 4/3 in both", "(56)",
                 _zero(f.K.subs(s.kt, 0) - K0) and _zero(f.G.subs(s.kt, 0) - G0))


@check
def biaxial_delta():
    Kk, Gg = sp.symbols("K G", positive=True)
    d = s.biaxial_delta(Kk, Gg)
    f = s.final_formulas()
    x = s.r * s.Nbar * s.rho / s.Nc
    d_mf = s.biaxial_delta(f.K_mf, f.G_mf).subs(s.kt, s.kn)
    d_eq = s.biaxial_delta(f.K.subs(s.kt, s.kn), f.G.subs(s.kt, s.kn))
    printed = -x / 2 / (2 * (1 - sp.Rational(5, 4) * x))
    return Check("Delta = (G - K)/(G + K); 0 in the mean field for kt = kn; kt = kn value as printed",
                 "section 6", _zero(d - (Gg - Kk) / (Gg + Kk)) and _zero(d_mf) and _zero(d_eq - printed),
                 f"Delta(kt=kn) = {sp.simplify(d_eq)}")


@check
def nbar_from_phi():
    rel = s.nbar_phi_relation()
    ok = _zero(rel.subs(s.Nbar, 6) - sp.pi / (2 * sp.sqrt(3))) and _zero(rel.subs(s.Nbar, 4) - sp.pi / 4)
    nb = sp.nsolve(rel - sp.Rational(82, 100), s.Nbar, 5)
    ok = ok and abs(float(nb) - 4.9116) < 1e-3 and round(float(nb)) == 5
    return Check("phi = (pi/4)/sin(pi (Nbar-2)/Nbar): Nbar = 6 -> pi/(2 sqrt 3), 4 -> pi/4, phi = 0.82 -> Nbar ~ 5",
                 "section 6", ok, f"Nbar(0.82) = {float(nb):.4f}")


@check
def triangular_lattice_mean_field():
    K, G = s.mean_field_moduli()
    sub = {s.Nc: 6, s.phi: sp.pi / (2 * sp.sqrt(3))}
    Kt, Gt = K.subs(sub), G.subs(sub)
    nu = sp.simplify(((Kt - Gt) / (Kt + Gt)).subs(s.kt, 0))
    return Check("triangular lattice (Nc = 6, phi = pi/(2 sqrt 3)): K = (sqrt3/2) kn, G = (sqrt3/4)(kn+kt); "
                 "Poisson 1/3 at kt = 0", "exact",
                 _zero(Kt - sp.sqrt(3) / 2 * s.kn) and _zero(Gt - sp.sqrt(3) / 4 * (s.kn + s.kt))
                 and nu == sp.Rational(1, 3))


@check
def numeric_matches_symbolic():
    import numpy as np

    from . import moduli

    f = s.lambdify_final()
    rng = np.random.default_rng(0)
    n = 200
    knv = 10 ** rng.uniform(-3, 12, n)
    ktv = knv * rng.choice([0.0, 1e-12, 1e-3, 0.25, 1.0, 10.0], n)
    ncv = rng.uniform(3.0, 6.0, n)
    phiv = rng.uniform(0.79, 0.9, n)
    rv = rng.uniform(0.0, 0.4, n)
    nbv = moduli.nbar_from_phi(phiv)
    rhov = rng.uniform(0.2, 1.0, n)
    Kmf, Gmf, K, G = (np.asarray(a, dtype=float) for a in f(knv, ktv, ncv, phiv, rv, nbv, rhov))
    p = moduli.predict_moduli(knv, ktv, ncv, phiv, rv, rho=rhov, warn=False)
    err = max(np.max(np.abs(p.K_mf / Kmf - 1)), np.max(np.abs(p.G_mf / Gmf - 1)),
              np.max(np.abs(p.K - K) / Kmf), np.max(np.abs(p.G - G) / Gmf))
    alphas = ["0", "0.5", "0.999999999", "1", "1.000000001", "1.76", "2"]
    ref = np.array([float(sp.limit(s.rho_model(), s.alpha, 1)) if a == "1" else
                    float(s.rho_model().subs(s.alpha, sp.Float(a, 40)).evalf(30)) for a in alphas])
    err_rho = np.max(np.abs(moduli.rho_from_alpha(np.array(alphas, dtype=float)) / ref - 1))
    return Check("numeric moduli.py equals the lambdified symbolic formulas (200 random sets, kn over 15 decades)",
                 "(50)-(54)", err < 1e-12 and err_rho < 1e-14, f"max rel err {err:.2e}, rho err {err_rho:.2e}")


def run(verbose=True, out=None):
    """Run every check, print one line each; return the list of :class:`Check`."""
    out = sys.stdout if out is None else out
    results = []
    for fn in CHECKS:
        t0 = time.perf_counter()
        try:
            c = fn()
        except Exception as exc:  # a crashing derivation is a failed check, shown with its reason
            c = Check(fn.__name__, "?", False, f"{type(exc).__name__}: {exc}")
        dt = time.perf_counter() - t0
        results.append(c)
        if verbose or not c.ok:
            mark = "PASS" if c.ok else "FAIL"
            print(f"[{mark}] {c.ref:>24}  {c.name}  ({dt:.1f} s)", file=out)
            if c.detail and verbose:
                print(f"{'':>32}{c.detail}", file=out)
    n_ok = sum(c.ok for c in results)
    print(f"derivations: {n_ok} passed, {len(results) - n_ok} failed", file=out)
    return results


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m microhom.derivations",
                                 description="Check every homogenisation formula by sympy derivation.")
    ap.add_argument("--quiet", action="store_true", help="print failures and the summary only")
    args = ap.parse_args(argv)
    res = run(verbose=not args.quiet)
    return 0 if all(c.ok for c in res) else 1


if __name__ == "__main__":
    sys.exit(main())
