"""Every sympy derivation check is a test (python -m microhom.derivations prints the same list)."""
import pytest

from microhom import derivations


@pytest.mark.parametrize("fn", derivations.CHECKS, ids=lambda f: f.__name__)
def test_derivation(fn):
    c = fn()
    assert c.ok, f"{c.ref} {c.name}: {c.detail}"


def test_cli_prints_every_check(capsys):
    assert derivations.main([]) == 0
    out = capsys.readouterr().out
    assert out.count("[PASS]") == len(derivations.CHECKS)
    assert f"{len(derivations.CHECKS)} passed, 0 failed" in out
