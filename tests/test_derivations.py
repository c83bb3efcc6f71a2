"""Every sympy derivation check is a test (python -m microhom.derivations prints the same list),
and the circularity guard can fail."""
import ast
import dataclasses
from pathlib import Path

import pytest
import sympy as sp

from microhom import derivations, printed, symbolic


@pytest.mark.parametrize("fn", derivations.CHECKS, ids=lambda f: f.__name__)
def test_derivation(fn):
    c = fn()
    assert c.ok, f"{c.ref} {c.name}: {c.detail}"
    assert derivations.circularity(c) == "", f"{c.name}: {derivations.circularity(c)}"


def test_cli_prints_every_check_with_both_sides(capsys):
    assert derivations.main([]) == 0
    out = capsys.readouterr().out
    n = len(derivations.CHECKS)
    assert out.count("[PASS]") == n
    assert out.count("derived : ") == n and out.count("compared: ") == n
    assert out.count("  lhs   : ") == n and out.count("  rhs   : ") == n
    assert f"{n} passed, 0 failed" in out and "none circular" in out


def test_symbolic_never_imports_the_printed_forms():
    """The derived side cannot lean on the typed-in paper: symbolic.py imports no 'printed'."""
    tree = ast.parse(Path(symbolic.__file__).read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            names |= {node.module or ""} | {a.name for a in node.names}
    assert not any("printed" in n for n in names), names


def test_guard_rejects_a_circular_check():
    good = derivations.mean_sum_vbar_ebar()
    assert derivations.circularity(good) == ""
    circ = dataclasses.replace(good, inputs=good.inputs + ("(37)",))
    assert "(37)" in derivations.circularity(circ)
    assert derivations.circularity(dataclasses.replace(good, rhs="")) != ""
    assert derivations.circularity(dataclasses.replace(good, targets=())) != ""
    assert derivations.circularity(dataclasses.replace(good, kind="typed")) != ""
    out = []

    class Sink:
        def write(self, t):
            out.append(t)

    orig = list(derivations.CHECKS)
    try:
        derivations.CHECKS[:] = [lambda: circ]
        res = derivations.run(verbose=False, out=Sink())
    finally:
        derivations.CHECKS[:] = orig
    assert not res[0].ok and "CIRCULAR" in res[0].detail and "1 circular" in "".join(out)


def test_sign_of_27_is_minus_the_printed_one():
    """The derived Fourier solution of (26) is minus the printed (27) (docs/theory.md)."""
    ker = symbolic.kroner_kernel()
    pr = printed.kernel_27(symbolic.vbar_s, symbolic.ebar_s, symbolic.k_vec)
    k = (1, 1, 0, 1)
    assert sp.simplify(ker[k] + pr[k]) == 0 and sp.simplify(pr[k]) != 0


def test_default_call_figures_in_the_docs():
    """docs/theory.md §6 'Defaults': what predict_moduli gives at the seed's statistics."""
    import math

    from microhom.moduli import predict_moduli
    from microhom.neighbourhood import derive_phi_of_nbar

    g = derive_phi_of_nbar()
    nbar = float(sp.nsolve(g["phi"] - sp.Rational(82, 100), g["N"], 5))  # N̄ from the derived geometry
    assert round(nbar, 4) == 4.9116

    def drops(nb, a):  # kt = kn: drop_K = x, drop_G = 3x/2 (55), x = r (N̄/Nc) cos(pi a/2)/(1 - a^2)
        x = 0.35 * nb / 4.1 * math.cos(math.pi * a / 2) / (1 - a * a)
        return round(x, 3), round(1.5 * x, 3)

    for kw, nb, a, want in ((dict(alpha=1.76, nbar=5.0), 5.0, 1.76, (0.189, 0.284)),
                            (dict(alpha=1.76), nbar, 1.76, (0.186, 0.279)),
                            (dict(), nbar, 2 * (1 - 1 / nbar), (0.219, 0.328))):
        p = predict_moduli(5e7, 5e7, 4.1, 0.82, 0.35, **kw)
        assert drops(nb, a) == want
        assert (round(float(p.drop_K), 3), round(float(p.drop_G), 3)) == want
        assert float(p.nbar) == pytest.approx(nb, rel=1e-12)
