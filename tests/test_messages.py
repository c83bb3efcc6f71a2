"""Issue 27, "nothing silent, round two": numbers that used to change silently (overflow,
underflow, lost JSON digits, unbounded broadcasts) and the message walk over the public API with
the fault campaign's bad inputs (every error names its parameter, file or particle, and none is a
bare numpy/pandas/scipy text)."""
import json
import math
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
        # a fresh parent per measurement: RUSAGE_CHILDREN is the largest child of the process so
        # far, so in a long test session it must not be this process's
        code = ("import resource, subprocess, sys; "
                "r = subprocess.run([sys.executable, '-m', 'microhom', 'predict', *sys.argv[1:], '--json'], "
                "capture_output=True); "
                "print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
        out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                             timeout=120).stdout.split()
        assert int(out[0]) in (0, 3), out
        return int(out[1]) * 1024, None
    base, _ = peak([])
    big, _ = peak(["--kn", *map(str, range(1, 101)), "--nc", *map(str, range(1, 101)),
                   "--r", *[str(0.01 * i) for i in range(10)], "--nbar", "5"])
    per_row = (big - base) / 1e5
    assert 0 < per_row < BYTES_PER_ROW, per_row


# ---- the message walk (issue 27 (d)) -------------------------------------------------------
# The campaign's bad inputs (and more) through the public API: each must raise a clean error
# type whose message names the parameter (or file, particle) and is not a bare library text.

#: texts of numpy, scipy, pandas and Python internals that must never reach a user alone
BARE_LIBRARY_TEXTS = (
    "Singular matrix", "zero-size array", "could not convert string to float",
    "operands could not be broadcast", "allow_pickle", "np.float64(", "has no attribute",
    "not subscriptable", "unsupported operand", "invalid literal for int", "is out of bounds",
    "setting an array element with a sequence", "Cannot load file", "truth value of an array",
    "return arrays must be of ArrayType", "Index(...) must be called", "object of type",
    "float() argument must be",
)
CLEAN_TYPES = (ValueError, TypeError, MemoryError, FileNotFoundError)


def _walk_cases():
    from dem.analysis.stiffness import stiffness
    from microhom import lattices
    from microhom.closure import predict_closure
    from microhom.hierarchy import relaxation_hierarchy
    from microhom.moduli import predict_from_network
    from microhom.network import from_overlaps

    p2 = np.array([[0.5, 0.5], [1.5, 0.5]])
    r2 = np.array([0.55, 0.55])
    box = np.eye(2) * 4
    net = lattices.triangular(4, 4)
    pm = dict(SEED)
    yield "from_overlaps singular cell", lambda: from_overlaps(p2, r2, np.zeros((2, 2))), "cell"
    yield "from_overlaps 3x3 cell", lambda: from_overlaps(p2, r2, np.eye(3)), "cell"
    yield "from_overlaps empty", lambda: from_overlaps(np.zeros((0, 2)), np.zeros(0), box), \
        "positions"
    yield "from_overlaps coincident", lambda: from_overlaps(
        np.array([[1.0, 1.0], [1.0, 1.0]]), 0.5, box), "particles 0 and 1"
    yield "from_overlaps negative radius", lambda: from_overlaps(p2, [-1.0, 0.5], box), \
        "particle 0"
    yield "from_overlaps text radius", lambda: from_overlaps(p2, "x", box), "radii"
    yield "from_overlaps positions shape", lambda: from_overlaps(np.zeros((3, 3)), 0.5, box), \
        "positions"
    yield "from_overlaps NaN kn", lambda: from_overlaps(p2, r2, box, kn=np.nan), "kn"
    yield "stiffness(None)", lambda: stiffness(None), "network"
    yield "stiffness rtol=-1", lambda: stiffness(net, rtol=-1), "rtol"
    yield "stiffness max_refine=0", lambda: stiffness(net, max_refine=0), "max_refine"
    yield "stiffness spin_arm", lambda: stiffness(net, spin_arm="centre"), "spin_arm"
    yield "predict_from_network(None)", lambda: predict_from_network(None), "network"
    yield "relaxation_hierarchy(None)", lambda: relaxation_hierarchy(None), "network"
    yield "relaxation_hierarchy tol", lambda: relaxation_hierarchy(net, tol=-1), "tol"
    yield "predict_moduli kn='1e8'", lambda: predict_moduli(**{**pm, "kn": "1e8"}), "kn"
    yield "predict_moduli kn='x'", lambda: predict_moduli(**{**pm, "kn": "x"}), "kn"
    yield "predict_moduli kn=None", lambda: predict_moduli(**{**pm, "kn": None}), "kn"
    yield "predict_moduli ragged", lambda: predict_moduli(**{**pm, "nc": [[1, 2], [3]]}), "nc"
    yield "predict_moduli complex", lambda: predict_moduli(**{**pm, "r": 1j}), "r"
    yield "predict_moduli shapes", lambda: predict_moduli(
        **{**pm, "kn": [1.0, 2.0], "nc": [3.0, 4.0, 5.0]}), "nc (3,)"
    yield "predict_moduli phi", lambda: predict_moduli(**{**pm, "phi": 1.2}), "phi"
    yield "predict_moduli alpha and rho", lambda: predict_moduli(**{**pm, "rho": 0.5}), "rho"
    yield "predict_closure phi=1.2", lambda: predict_closure(nc=4.1, r=0.05, phi=1.2), "phi"
    yield "predict_closure nc='x'", lambda: predict_closure(nc="x", r=0.05), "nc"
    yield "predict_closure r=None", lambda: predict_closure(nc=4.1, r=None), "r"


@pytest.mark.parametrize("case", list(_walk_cases()), ids=lambda c: c[0])
def test_message_walk(case):
    name, call, must_name = case
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            call()
        except CLEAN_TYPES as exc:
            msg = str(exc)
        else:
            pytest.fail(f"{name}: no error")
    for bare in BARE_LIBRARY_TEXTS:
        assert bare not in msg, f"{name}: bare library text {bare!r} in {msg!r}"
    assert must_name in msg, f"{name}: the message does not name {must_name!r}: {msg!r}"


def test_walk_catches_a_bare_message():
    """The walk can fail: numpy's own message for the singular cell is caught by its list."""
    with pytest.raises(np.linalg.LinAlgError) as err:
        np.linalg.solve(np.zeros((2, 2)), np.ones(2))
    assert any(b in str(err.value) for b in BARE_LIBRARY_TEXTS)


def test_closure_flags_overlap_inflated_phi():
    """predict_closure(phi=1.008) raised with np.float64(...) in the text, where
    predict_from_network flags the same overlap-inflated phi: now flagged (bit 16), with the
    moduli computed as for phi <= 1 (the mean field scales with phi)."""
    from microhom.closure import predict_closure
    kw = dict(kt_over_kn=1.0, p_over_kn=1e-3, dispersity=0.2, size_coordination=0.03, psi6_local=0.6)
    p = predict_closure(nc=4.1, r=0.05, phi=1.008, **kw)
    q = predict_closure(nc=4.1, r=0.05, phi=0.9, **kw)
    assert not bool(p.valid) and int(p.flags) & 16 and "phi above 1" in str(p.reason)
    assert float(p.K) / float(q.K) == pytest.approx(1.008 / 0.9, rel=1e-14)
    assert bool(q.valid)


def test_meshio_prints_nothing_on_stdout(tmp_path, capfd):
    """meshio printed "Error: Couldn't read file..." on stdout before the clean error."""
    pytest.importorskip("meshio")
    from dem import io
    bad = tmp_path / "bad.vtu"
    bad.write_bytes(b"<VTKFile garbage")
    with pytest.raises(io.FormatError, match="bad.vtu"):
        io.read(bad)
    out, _ = capfd.readouterr()
    assert out == ""


_D0001 = str(__import__("pathlib").Path(__file__).parent / "data" / "D0001")


@pytest.mark.parametrize("cli, argv, must_name", [
    ("microhom", ["predict", "--kn", "x"], "kn"),
    ("microhom", ["predict", "--nc", "0"], "nc"),
    ("microhom", ["predict", "--kn", "1e400"], "kn"),
    ("dem", ["analyse", _D0001, "--kn", "-1"], "--kn"),
    ("dem", ["analyse", "/nonexistent/packing.dump"], "/nonexistent/packing.dump"),
    ("dem", ["analyse", _D0001, "--hierarchy-tol", "2"], "--hierarchy-tol"),
    ("dem", ["analyse", _D0001, "--frame", "0"], "--frame"),
    ("dem", ["analyse", _D0001, "--spin-arm", "centre"], "--spin-arm"),
    ("dem", ["pack", "--n", "1e9", "--out", "/nonexistent/x.npz"], "--n"),
    ("dem", ["pack", "--n", "1.5"], "--n"),
])
def test_cli_message_walk(cli, argv, must_name, capsys):
    """The two command lines on bad options: exit 2, one line naming the option, no library
    text, no traceback (argparse's own usage errors also exit 2 and name the option)."""
    if cli == "microhom":
        from microhom.__main__ import main
    else:
        from dem.__main__ import main
    try:
        rc = main(argv)
    except SystemExit as exc:      # argparse: usage line + one error line
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2, err
    assert must_name in err and "Traceback" not in err, err
    for bare in BARE_LIBRARY_TEXTS:
        assert bare not in err, err


def test_loose_phi_is_flagged_not_refused(capsys):
    """Below phi = pi/4 N-bar(phi) does not exist: the prediction uses N-bar = 4, exits 3
    (flagged) and says which N-bar it used and how to choose another (issue 25's decision)."""
    from microhom.__main__ import main
    rc = main(["predict", "--phi", "0.5"])
    out = capsys.readouterr().out
    assert rc == 3 and "FLAGGED" in out and "Nbar = 4" in out and "pass nbar" in out


def test_stiffness_near_float64_top():
    """stiffness gave K = inf with only numpy's overflow warning: the moduli of a triangular
    lattice are kn sqrt(3)/2 (closed form), also at kn = 1e308; a tensor entry past the float64
    range is flagged with the reason; a kn without a power-of-two scale is refused by name."""
    from dem.analysis.stiffness import stiffness
    from microhom import lattices

    exact = np.sqrt(3.0) / 2.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = stiffness(lattices.triangular(4, 4, kn=1e308, kt=1e308))
    assert r.ok and r.K == pytest.approx(exact * 1e308, rel=1e-13) and r.G == pytest.approx(
        exact * 1e308, rel=1e-13)
    with pytest.warns(RuntimeWarning, match="overflow"):
        r = stiffness(lattices.triangular(4, 4, kn=1.2e308, kt=1.2e308))
    assert not r.ok and any(f.startswith("overflow") for f in r.flags)
    assert r.K == pytest.approx(exact * 1.2e308, rel=1e-13)      # the moduli themselves fit
    with pytest.raises(ValueError, match="kn must be in") as err:
        stiffness(lattices.triangular(4, 4, kn=1.5e308, kt=1.5e308))
    assert "np.float64" not in str(err.value)
