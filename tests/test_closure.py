"""The statistics-only closure: its limits, its isostatic points, its stated error on protocols it
was not fitted to (leave one protocol out on the committed corpus summary), flags, bad input."""
import json

import numpy as np
import pandas as pd
import pytest
import sympy as sp

from microhom import closure
from microhom.closure import (DZ_MIN, FEATURES, Q, RANGES, features, isostatic_point, predict_closure)

SUMMARY = pd.read_csv("studies/closure_corpus.csv", keep_default_na=False, na_values=[""])


def test_isostatic_point_from_constraint_counting():
    """Z_iso from Maxwell counting, derived by sympy: N Z / 2 contacts, each fixing 2 relative
    motions (1 if sliding or frictionless), against 3 (frictional) or 2 (frictionless) degrees of
    freedom per disk."""
    Z, s = sp.symbols("Z s", positive=True)
    z_fric = sp.solve(sp.Eq(Z / 2 * (2 * (1 - s) + s), 3), Z)[0]
    z_free = sp.solve(sp.Eq(Z / 2 * 1, 2), Z)[0]
    for sv in (0.0, 0.1, 0.5, 0.9):
        assert isostatic_point(0.3, sv) == pytest.approx(float(z_fric.subs(s, sv)), rel=1e-14)
    assert isostatic_point(0.0, 0.4) == float(z_free) == 4.0
    assert isostatic_point(1.0) == 3.0


def test_limits_of_the_form():
    """G -> 0 linearly at the isostatic point (G / dZ finite), G -> G_mf at high Z; K finite at the
    isostatic point; for both branches."""
    for kt in (0.0, 0.2, 1.0):
        ziso = float(isostatic_point(kt))
        dz = np.array([1e-6, 1e-5])
        p = predict_closure(nc=ziso + dz, r=0.04, phi=0.85, kt_over_kn=kt, dispersity=0.2)
        slope = p.G / dz
        assert slope[0] == pytest.approx(slope[1], rel=1e-3) and slope[0] > 0
        assert np.all(p.K > 0.05 * p.K_mf) and not p.valid.any()
        assert "isostatic" in p.reason[0]
        hi = predict_closure(nc=ziso + 1e6, r=0.04, phi=0.85, kt_over_kn=kt, dispersity=0.2)
        assert float(hi.G / hi.G_mf) == pytest.approx(1.0, abs=1e-2)
        assert not bool(hi.valid) and "outside the data" in str(hi.reason)


def test_network_statistics_input_equals_explicit():
    from microhom.structural_sums import NetworkStatistics
    st = NetworkStatistics(n_particles=10, n_contacts=20, n_rattlers=0, rattler_fraction=0.0, nc_all=4.2,
                           r_all=0.05, rho_all=0.7, nc=4.3, r=0.045, rho=0.7, phi=0.86, nbar_phi=5.0,
                           diameter=1.0, sliding_fraction=0.02)
    a = predict_closure(st, kt_over_kn=0.5, dispersity=0.2)
    b = predict_closure(nc=4.3, r=0.045, phi=0.86, kt_over_kn=0.5, dispersity=0.2, sliding_fraction=0.02)
    assert float(a.G) == float(b.G) and float(a.error_K) == float(b.error_K)
    with pytest.raises(ValueError, match="^r must not"):
        predict_closure(st, r=0.1)


@pytest.fixture(scope="module")
def corpus():
    from studies.closure_fit import usable
    return usable(SUMMARY)


def test_corpus_is_what_the_issue_asks(corpus):
    assert SUMMARY.protocol.nunique() >= 5
    assert SUMMARY.n.min() >= 1000
    assert (SUMMARY.kt_over_kn == 0).any() and (SUMMARY.kt_over_kn == 1).any()
    assert SUMMARY.dispersity.max() >= 0.45 and SUMMARY.dispersity.min() <= 0.05
    assert corpus.groupby("protocol").seed.nunique().min() >= 2


def test_stored_model_is_the_fit_of_the_committed_corpus(corpus):
    """The coefficients in microhom/closure.py are those of studies.closure_fit on the summary."""
    from studies.closure_fit import fit
    cK, cG, cov = fit(corpus)
    Kp = predict_closure(nc=corpus.Z, r=corpus.r, phi=corpus.phi, kt_over_kn=corpus.kt_over_kn,
                         dispersity=corpus.dispersity, sliding_fraction=corpus.sliding_fraction)
    Kf = predict_closure(nc=corpus.Z, r=corpus.r, phi=corpus.phi, kt_over_kn=corpus.kt_over_kn,
                         dispersity=corpus.dispersity, sliding_fraction=corpus.sliding_fraction,
                         model=dict(coef_K=cK, coef_G=cG, cov_K=cov, cov_G=cov))
    np.testing.assert_allclose(Kp.K, Kf.K, rtol=1e-4)
    np.testing.assert_allclose(Kp.G, Kf.G, rtol=1e-4)


def test_leave_one_protocol_out_stated_error_covers(corpus):
    """Each protocol predicted by the closure fitted on the other four (independent of the stored
    model): the stated error, calibrated on the pooled held-out cases, covers at least 90 % of
    them; and the stored Q is that calibration."""
    from studies.closure_fit import calibrate, lopo
    lo = lopo(corpus)
    q, inside = calibrate(lo)
    s = np.sqrt(1 + lo.h / lo.h_mean)
    for m in ("K", "G"):
        cover = np.mean(np.abs(lo[f"err_{m}"][inside]) <= q[m] * s[inside] * (1 + 1e-12))
        assert cover >= 0.9
        assert Q[m] == pytest.approx(q[m], rel=2e-3)


def test_held_out_rows_are_better_than_mean_field(corpus):
    from studies.closure_fit import lopo, mean_field
    lo = lopo(corpus).merge(corpus[["key", "kt_over_kn", "K", "G", "Z", "phi"]], on=["key", "kt_over_kn"])
    K_mf, G_mf = mean_field(lo)
    assert np.sqrt(np.mean(lo.err_G ** 2)) < 0.5 * np.sqrt(np.mean((G_mf / lo.G - 1) ** 2))


def test_flags():
    p = predict_closure(nc=np.array([3.02, 4.3, 4.3, 3.8, 4.3, 6.0]), r=np.array([0.05, 0.04, 0.04, 0.04, 0.04, 0.0]),
                        phi=np.array([0.84, 0.86, 0.86, 0.84, 0.86, 0.9069]),
                        kt_over_kn=np.array([0.5, 0.5, 0.0, 0.0, 1e-3, 1.0]), dispersity=np.array([0.2, 0.2, 0.2, 0.2, 0.2, 0.0]))
    assert list(p.valid) == [False, True, True, False, False, False]
    assert "isostatic" in p.reason[0] and "isostatic" in p.reason[3]    # frictionless below Z = 4
    assert "outside the data" in p.reason[4]                           # kt/kn far below the corpus
    assert "outside the data" in p.reason[5]                           # the triangular lattice
    assert np.all(np.isfinite(p.K)) and np.all(np.isfinite(p.G)) and np.all(p.G >= 0)
    assert np.all(p.rel_error_G[p.valid] > 0)
    assert DZ_MIN > 0 and RANGES["dispersity"][1] >= 0.5


def test_error_grows_away_from_the_data():
    nc = np.linspace(3.6, 5.5, 20)
    p = predict_closure(nc=nc, r=0.04, phi=0.85, kt_over_kn=0.5, dispersity=0.2)
    q = predict_closure(nc=4.4, r=np.linspace(0.03, 0.2, 20), phi=0.85, kt_over_kn=0.5, dispersity=0.2)
    assert q.rel_error_G[-1] > 2 * q.rel_error_G[0] and not q.valid[-1]
    assert np.all(p.rel_error_K >= Q["K"]) and np.all(p.rel_error_G >= Q["G"])


@pytest.mark.parametrize("kwargs, name", [(dict(nc=-1.0), "nc"), (dict(r=-0.1), "r"), (dict(phi=1.2), "phi"),
                                          (dict(kt_over_kn=np.nan), "kt_over_kn"), (dict(kn=0.0), "kn"),
                                          (dict(dispersity=-0.1), "dispersity"),
                                          (dict(sliding_fraction=1.0), "sliding_fraction")])
def test_bad_input(kwargs, name):
    args = dict(nc=4.0, r=0.05)
    args.update(kwargs)
    with pytest.raises(ValueError, match=rf"^{name}\b"):
        predict_closure(**args)


def test_vectorised_and_json_ready():
    rng = np.random.default_rng(0)
    n = 100_000
    p = predict_closure(nc=rng.uniform(3.3, 5.3, n), r=rng.uniform(0.02, 0.06, n), kt_over_kn=rng.uniform(0.1, 1, n))
    assert p.K.shape == (n,) and p.error_G.shape == (n,)
    X, dz = features(4.2, 0.5, 0.1, 0.04)
    assert X.shape == (len(FEATURES),) and dz == pytest.approx(1.2)
    json.dumps(predict_closure(nc=4.2, r=0.04).as_dict())
