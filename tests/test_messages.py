"""Issue 27, "nothing silent, round two": numbers that used to change silently (overflow,
underflow, lost JSON digits, unbounded broadcasts) and the message walk over the public API with
the fault campaign's bad inputs (every error names its parameter, file or particle, and none is a
bare numpy/pandas/scipy text)."""
import json
import math
import resource
import subprocess
import sys
import warnings
from fractions import Fraction

import numpy as np
import pytest

from microhom import limits
from microhom.moduli import KT_OVER_KN_MAX, predict_moduli

SEED = dict(kn=1e8, kt=1e8, nc=4.1, phi=0.82, r=0.35, alpha=1.76, nbar=5.0)


def predict(**kw):
    return predict_moduli(**{**SEED, "warn": False, **kw})


def run_predict(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "microhom", "predict", *args],
                          capture_output=True, text=True, timeout=timeout)


# ---- overflow and underflow (issue 27 (b)) ----------------------------------------------------

def test_huge_kn_is_exact_not_inf():
    """kn = 1e308 gave inf with valid=True (kn + kt overflowed): the moduli are proportional to kn,
    so the result must be 1e308 times the kn = 1 result, to round-off."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # no numpy overflow warning either
        big = predict(kn=1e308, kt=1e308)
    one = predict(kn=1.0, kt=1.0)
    for name in ("K_mf", "G_mf", "K", "G"):
        assert math.isclose(float(getattr(big, name)), 1e308 * float(getattr(one, name)),
                            rel_tol=1e-14)
    assert bool(big.valid)


def test_true_overflow_is_flagged_with_reason():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = predict(kn=1.7e308, kt=1e308, nc=100.0)
    assert not bool(p.valid) and int(p.flags) & 32
    assert "overflow" in str(p.reason) and "float64" in str(p.reason)


def test_subnormal_kn_is_flagged():
    """kn = 1e-320 was off in the 4th digit with valid=True (a subnormal number has lost digits)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = predict(kn=1e-320, kt=1e-320)
    # exact arithmetic: K / kn of the subnormal result against K of kn = 1 (moduli ~ kn)
    k_over_kn = Fraction(float(p.K)) / Fraction(float(1e-320))
    one = Fraction(float(predict(kn=1.0, kt=1.0).K))
    assert abs(k_over_kn - one) / one > 1e-6                  # the loss is real ...
    assert not bool(p.valid) and int(p.flags) & 64 and "underflow" in str(p.reason)   # ... and said
    assert bool(predict(kn=1e-300, kt=1e-300).valid)          # a small normal kn is fine


def test_kt_far_above_kn_is_flagged():
    """--kn 1 --kt 1e12 said valid with G = 1.7e11."""
    p = predict(kn=1.0, kt=1e12)
    assert not bool(p.valid) and int(p.flags) & 128 and "kt/kn" in str(p.reason)
    assert not int(predict(kn=1.0, kt=KT_OVER_KN_MAX).flags) & 128     # the limit itself is in
    r = run_predict("--kn", "1", "--kt", "1e12", "--nbar", "5")
    assert r.returncode == 3 and "kt/kn above" in r.stdout


def test_json_full_precision():
    """--nc 1e-12 --json printed "nc": 0.0 (pandas' 10 digits): every float now round-trips."""
    r = run_predict("--nc", "1e-12", "--kn", "123456789.12345678", "--json")
    row = json.loads(r.stdout)[0]
    assert row["nc"] == 1e-12 and row["kn"] == 123456789.12345678
    p = predict_moduli(kn=123456789.12345678, kt=123456789.12345678, nc=1e-12, phi=0.82, r=0.35,
                       alpha=1.76, warn=False)
    assert row["K"] == float(p.K) and row["G_mf"] == float(p.G_mf)   # bit for bit


def test_json_broadcast_matches_library_row_by_row():
    """Second method for the vectorised command line: each row equals a scalar library call."""
    r = run_predict("--kt", "0", "5e7", "--nc", "3.9", "4.4", "--r", "0", "0.3", "--json")
    rows = json.loads(r.stdout)
    assert len(rows) == 8
    for row in rows:
        p = predict_moduli(kn=row["kn"], kt=row["kt"], nc=row["nc"], phi=row["phi"], r=row["r"],
                           alpha=1.76, warn=False)
        assert row["K"] == float(p.K) and row["G"] == float(p.G) and row["valid"] == bool(p.valid)


# ---- broadcast size guard ------------------------------------------------------------------

def test_broadcast_too_large_refused_before_allocating():
    big = np.ones(10 ** 6)
    with pytest.raises(MemoryError, match="kn .*nc|entries") as err:
        predict_moduli(kn=big, kt=1.0, nc=big[:, None], phi=0.82, r=0.3, nbar=5)
    assert "GB" in str(err.value) and "give fewer values" in str(err.value)


def test_broadcast_shapes_named():
    with pytest.raises(ValueError, match=r"kn \(2,\), nc \(3,\)") as err:
        predict_moduli(kn=[1.0, 2.0], kt=1.0, nc=[3.0, 4.0, 5.0], phi=0.82, r=0.3, nbar=5)
    assert "operands" not in str(err.value)


def test_check_broadcast_counts_exactly(monkeypatch):
    """The guard's arithmetic: shape (3, 4) at 10 bytes an entry is 120 bytes, refused below that
    and accepted at it."""
    named = {"a": np.zeros(3)[:, None], "b": np.zeros(4)}
    monkeypatch.setattr(limits, "available_memory", lambda: int(120 / limits.MEMORY_FRACTION))
    assert limits.check_broadcast(named, bytes_per_element=10) == (3, 4)
    monkeypatch.setattr(limits, "available_memory", lambda: int(119 / limits.MEMORY_FRACTION))
    with pytest.raises(MemoryError, match="12 entries"):
        limits.check_broadcast(named, bytes_per_element=10)


def test_cli_four_long_lists_refused_at_once():
    """200 x 200 x 201 x 201 combinations reached 4.6 GB in 9 s: refused before computing."""
    vals = lambda n, x0: [str(x0 + 0.001 * k) for k in range(n)]   # noqa: E731
    r = run_predict("--kn", *vals(200, 1), "--kt", *vals(200, 1), "--nc", *vals(201, 3),
                    "--phi", *vals(201, 0.8), "--nbar", "5", timeout=60)
    assert r.returncode == 2, r.stderr
    assert "1,616,040,000 combinations" in r.stderr and "--kn" in r.stderr
    assert "Traceback" not in r.stderr


def test_predict_row_memory_estimate():
    """BYTES_PER_ROW (the CLI guard's estimate) covers the measured peak per row (1e4 rows)."""
    from microhom.__main__ import BYTES_PER_ROW

    def peak(args):
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        r = run_predict(*args, "--json")
        assert r.returncode in (0, 3), r.stderr
        return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024, before
    base, _ = peak([])
    big, _ = peak(["--kn", *map(str, range(1, 101)), "--nc", *map(str, range(1, 101)),
                   "--r", *[str(0.01 * i) for i in range(10)], "--nbar", "5"])
    per_row = (big - base) / 1e5
    assert 0 < per_row < BYTES_PER_ROW, per_row
