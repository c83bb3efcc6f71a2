"""The prediction API: the seed's table, limits, stability at the traps, bad input, broadcasting."""
import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from microhom.moduli import PHI_MAX, nbar_from_phi, predict_moduli, rho_from_alpha

SEED = dict(nc=4.1, phi=0.82, r=0.35, nbar=5.0, alpha=1.76)


def test_seed_table_fraction_changes():
    # Seed paper: "fraction changes ~0.19 (bulk) and ~0.28 (shear)", ratio exactly 3/2, kt = kn
    p = predict_moduli(1e8, 1e8, **SEED)
    assert round(float(p.drop_K), 2) == 0.19
    assert round(float(p.drop_G), 2) == 0.28
    assert float(p.drop_G / p.drop_K) == pytest.approx(1.5, rel=1e-14)
    # hand evaluation: x = r Nbar/Nc cos(0.88 pi)/(1 - 1.76^2)
    x = 0.35 * 5 / 4.1 * math.cos(0.88 * math.pi) / (1 - 1.76 ** 2)
    assert float(p.drop_K) == pytest.approx(x, rel=1e-13)
    assert bool(p.valid) and p.reason == "ok"


def test_mean_field_closed_form_and_equal_stiffness_delta():
    p = predict_moduli(2.0, 2.0, 4.0, 0.8, 0.0, nbar=5)
    assert float(p.K_mf) == pytest.approx(4.0 * 0.8 * 2.0 / (2 * math.pi), rel=1e-15)
    assert float(p.G_mf) == pytest.approx(4.0 * 0.8 * 4.0 / (4 * math.pi), rel=1e-15)
    assert float(p.K) == float(p.K_mf) and float(p.G) == float(p.G_mf)  # r = 0: exactly the mean field
    assert float(p.delta_mf) == 0.0  # kt = kn: no volume change in the mean field


def test_triangular_lattice_poisson_one_third():
    p = predict_moduli(1.0, 0.0, 6.0, PHI_MAX, 0.0)
    assert float(p.K) == pytest.approx(math.sqrt(3) / 2, rel=1e-14)
    assert float(p.G) == pytest.approx(math.sqrt(3) / 4, rel=1e-14)
    assert float(p.poisson) == pytest.approx(1 / 3, rel=1e-14)
    assert float(nbar_from_phi(PHI_MAX)) == pytest.approx(6.0, rel=1e-12)


@pytest.mark.parametrize("ratio", [0.0, 1e-12, 1e-3, 1.0, 10.0])
@pytest.mark.parametrize("kn", [1e-3, 1.0, 1e6, 1e15])
def test_finite_and_scale_invariant(kn, ratio):
    p = predict_moduli(kn, ratio * kn, 4.1, 0.82, 0.2, alpha=1.5)
    q = predict_moduli(1.0, ratio, 4.1, 0.82, 0.2, alpha=1.5)
    for name in ("K_mf", "G_mf", "K", "G"):
        a, b = float(getattr(p, name)), float(getattr(q, name))
        assert np.isfinite(a) and a > 0
        assert a / kn == pytest.approx(b, rel=1e-14)
    # frictionless limit: factor 4/3 in both
    if ratio == 0.0:
        x = 0.2 * float(p.nbar) / 4.1 * float(p.rho)
        assert float(p.drop_K) == pytest.approx(4 / 3 * x, rel=1e-14)
        assert float(p.drop_G) == pytest.approx(4 / 3 * x, rel=1e-14)


def test_alpha_at_and_around_one():
    a = np.array([1 - 1e-12, 1 - 1e-6, 1.0, 1 + 1e-6, 1 + 1e-12])
    rho = rho_from_alpha(a)
    assert np.all(np.isfinite(rho))
    assert rho[2] == pytest.approx(math.pi / 4, rel=1e-15)
    assert np.max(np.abs(rho - math.pi / 4)) < 1e-6
    # far from 1 the printed form is well conditioned: compare
    for x in (0.0, 0.3, 1.5, 1.76, 2.0 - 1e-9):
        printed = math.cos(math.pi * x / 2) / (1 - x * x)
        assert float(rho_from_alpha(x)) == pytest.approx(printed, rel=1e-12)
    assert float(rho_from_alpha(2.0)) == pytest.approx(1 / 3, rel=1e-14)  # alpha -> 2 limit


def test_phi_at_close_packing_and_explicit_nbar():
    # at close packing Nbar(phi) = 6 exactly; alpha = 1 gives rho = pi/4 (the 0/0 point of (54)):
    # x = r (Nbar/Nc) rho = 0.1 pi/4, drops 4/(3+1) x (bulk) and 2 (2+1)/(3+1) x (shear), by hand
    p = predict_moduli(1.0, 1.0, 6.0, PHI_MAX, 0.1, alpha=1.0)
    x = 0.1 * (6.0 / 6.0) * math.pi / 4
    assert float(p.nbar) == pytest.approx(6.0, rel=1e-12)
    assert float(p.K_mf) == pytest.approx(math.sqrt(3) / 2, rel=1e-14)   # 6 phi/(2 pi), phi = pi/(2 sqrt3)
    assert float(p.K) == pytest.approx(math.sqrt(3) / 2 * (1 - x), rel=1e-13)
    assert float(p.G) == pytest.approx(math.sqrt(3) / 2 * (1 - 1.5 * x), rel=1e-13)
    # below pi/4 Nbar(phi) does not exist: the explicit nbar is what the correction uses
    q = predict_moduli(1.0, 1.0, 3.5, 0.5, 0.1, nbar=4.5, alpha=1.0)
    xq = 0.1 * (4.5 / 3.5) * math.pi / 4
    assert float(q.nbar) == 4.5
    assert float(q.K) == pytest.approx(3.5 * 0.5 / (2 * math.pi) * (1 - xq), rel=1e-13)
    assert float(q.drop_G) == pytest.approx(1.5 * xq, rel=1e-13)
    # without nbar: Nbar = 4 (its value at pi/4) is used, flagged (bit 256) and named in the reason
    with pytest.warns(RuntimeWarning, match="outside"):
        s = predict_moduli(1.0, 1.0, np.array([3.5, 3.5]), np.array([0.5, 0.82]), 0.1, alpha=1.0)
    assert list(s.nbar) == [4.0, pytest.approx(4.91159, abs=1e-4)]
    assert list(s.valid) == [False, True] and int(s.flags[0]) == 256
    assert "below pi/4" in s.reason[0] and "Nbar = 4" in s.reason[0]
    x4 = 0.1 * (4.0 / 3.5) * math.pi / 4
    assert float(s.drop_K[0]) == pytest.approx(x4, rel=1e-13)   # kt = kn: drop_K = x


@pytest.mark.parametrize("kwargs, name", [
    (dict(kn=-1.0), "kn"), (dict(kn=0.0), "kn"), (dict(kt=-1e-9), "kt"), (dict(nc=-4.0), "nc"),
    (dict(r=-0.1), "r"), (dict(phi=0.0), "phi"), (dict(phi=0.95), "phi"),
    (dict(alpha=2.5), "alpha"), (dict(kn=np.nan), "kn"), (dict(kt=np.inf), "kt"),
    (dict(r=np.array([0.1, np.nan])), "r"), (dict(diameter=0.0), "diameter"),
])
def test_bad_input_names_parameter(kwargs, name):
    args = dict(kn=1.0, kt=1.0, nc=4.1, phi=0.82, r=0.35, alpha=1.76)
    args.update(kwargs)
    with pytest.raises(ValueError, match=rf"^{name}\b"):
        predict_moduli(**args)


def test_alpha_and_rho_exclusive():
    with pytest.raises(ValueError, match="alpha"):
        predict_moduli(1.0, 1.0, 4.1, 0.82, 0.35, alpha=1.0, rho=0.5)


def test_large_correction_flagged_not_silent():
    with pytest.warns(RuntimeWarning, match="outside the first-order"):
        p = predict_moduli(1.0, 1.0, np.array([4.1, 4.1, 4.1]), 0.82, np.array([0.1, 0.5, 3.0]), rho=1.0)
    assert list(p.valid) == [True, False, False]
    assert p.reason[0] == "ok"
    assert "max_correction" in p.reason[1] and "negative" not in p.reason[1]
    assert "negative modulus" in p.reason[2]
    assert p.K[2] < 0  # the first-order value is returned, but flagged


def test_broadcast_numpy_and_pandas():
    df = pd.DataFrame({"nc": [3.5, 4.1, 5.0], "r": [0.3, 0.35, 0.1], "kt": [0.0, 0.5, 1.0]}, index=list("abc"))
    p = predict_moduli(1.0, df["kt"], df["nc"], 0.82, df["r"], alpha=1.76)
    f = p.to_frame()
    assert list(f.index) == list("abc")
    for i, row in df.iterrows():
        one = predict_moduli(1.0, row.kt, row.nc, 0.82, row.r, alpha=1.76)
        assert f.loc[i, "K"] == pytest.approx(float(one.K), rel=1e-15)
        assert f.loc[i, "G"] == pytest.approx(float(one.G), rel=1e-15)
    grid = predict_moduli(1.0, np.array([[0.0], [1.0]]), np.array([4.0, 4.5, 5.0]), 0.82, 0.2)
    assert grid.K.shape == (2, 3)


def test_import_does_not_import_sympy_or_pandas():
    code = "import sys, microhom, microhom.moduli, microhom.structural_sums, microhom.network; " \
           "print('sympy' in sys.modules, 'pandas' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


# ---- predict_from_network: flags instead of errors, and never valid near jamming --------------
def test_overlapping_network_flagged_not_raised():
    from microhom import lattices
    from microhom.moduli import predict_from_network
    from microhom.network import from_overlaps

    lat = lattices.triangular(6, 6)
    net = from_overlaps(lat.positions, 0.56, lat.cell)   # overlaps: phi = 0.907 * 1.12^2 > close packing
    assert net.solid_fraction > PHI_MAX
    with pytest.warns(RuntimeWarning, match="close packing"):
        p = predict_from_network(net)
    assert not bool(p.valid) and "close packing" in str(p.reason)
    assert np.isfinite(float(p.K)) and float(p.nbar) == pytest.approx(6.0)


def test_perfect_lattice_prediction_is_valid_and_equals_the_bound():
    from microhom import lattices
    from microhom.moduli import predict_from_network

    p = predict_from_network(lattices.triangular(6, 6, kt=0.4))
    assert bool(p.valid), p.reason
    assert float(p.G) == pytest.approx(math.sqrt(3) / 4 * 1.4, rel=1e-12)


@pytest.fixture(scope="module")
def near_jamming():
    """Frictionless polydisperse packing at p/kn = 1e-4: exact G/G_affine is a few per cent."""
    from dem.engine.packing import PackingProtocol, pack
    return pack(PackingProtocol(n=200, p_over_kn=1e-4, kt_over_kn=0.0, mu=0.0, mu_prep=0.0,
                                dispersity=0.2, seed=2)).to_network()


def test_near_jamming_never_valid(near_jamming):
    from dem.analysis.stiffness import stiffness
    from microhom.moduli import predict_from_network

    ex = stiffness(near_jamming)
    assert ex.G < 0.1 * ex.G_affine            # the case the issue names: G -> 0 near jamming
    with pytest.warns(RuntimeWarning, match=r"isostatic|upper bound"):
        p = predict_from_network(near_jamming)
    assert float(p.G) > 5 * ex.G                # the first-order theory is far too stiff here...
    assert not bool(p.valid)                    # ...and says so
    assert "isostatic" in str(p.reason) or "upper bound" in str(p.reason)
    q = predict_from_network(near_jamming, warn=False)
    assert "upper bound" in str(q.reason)       # the rigorous hierarchy bound alone catches it too


def test_prediction_is_a_read_only_result():
    """Prediction is frozen like every result type, and exports through Result.as_dict()."""
    import dataclasses

    p = predict_moduli(kn=1e8, kt=1e8, nc=4.1, phi=0.82, r=0.35, alpha=1.76, nbar=5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.K = 0.0
    d = p.as_dict()
    assert d["K"] == pytest.approx(float(p.K)) and d["valid"] is True
    assert list(p.to_frame()["reason"]) == ["ok"]
