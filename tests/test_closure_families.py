"""Leave one preparation family out (studies.closure_fit.lofo): the families partition the corpus's
protocols, nothing of the held-out family leaks into the fit (while leave one protocol out does see
its twin), a branch the fit never saw is flagged, and the figures docs/results/closure.md states
(section 4, "Leave one preparation family out"; the fn_cv trial of section 2)."""
import numpy as np
import pandas as pd
import pytest

from studies.closure_fit import (FAMILIES, SUMMARY, family_of, family_trials, lofo, lofo_table, lopo,
                                 usable)
from studies.corpus import PROTOCOLS

DF = usable(pd.read_csv(SUMMARY, keep_default_na=False, na_values=[""]))


@pytest.fixture(scope="module")
def lf():
    return lofo(DF)


def test_families_partition_the_protocols():
    members = [p for ps in FAMILIES.values() for p in ps]
    assert sorted(members) == sorted(PROTOCOLS) and len(set(members)) == len(members)
    assert set(FAMILIES["fixed_phi"]) == {"lammps_prep", "dem_fixedphi"}
    assert list(family_of(["minimise", "unknown"])) == ["frictionless_minimum", "unknown"]


def test_one_protocol_per_family_is_leave_one_protocol_out():
    a = lopo(DF)
    b = lopo(DF, families={p: (p,) for p in PROTOCOLS})
    np.testing.assert_array_equal(a.err_K.to_numpy(), b.err_K.to_numpy())
    np.testing.assert_array_equal(a.err_G.to_numpy(), b.err_G.to_numpy())


def test_no_leak_of_the_held_out_family():
    """Changing the moduli of dem_fixedphi leaves the family-out predictions of its twins (LAMMPS)
    unchanged to rounding, and changes the protocol-out ones (where dem_fixedphi is fitted on)."""
    twin = DF.protocol == "dem_fixedphi"
    moved = DF.assign(K=np.where(twin, 1.5 * DF.K, DF.K), G=np.where(twin, 0.7 * DF.G, DF.G))
    fam = lambda d: lopo(d, families=FAMILIES).query("protocol == 'lammps_prep'")
    prot = lambda d: lopo(d).query("protocol == 'lammps_prep'")
    np.testing.assert_allclose(fam(moved).err_K, fam(DF).err_K, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fam(moved).err_G, fam(DF).err_G, rtol=0, atol=1e-12)
    assert np.max(np.abs(prot(moved).err_K.to_numpy() - prot(DF).err_K.to_numpy())) > 0.01
    assert np.max(np.abs(prot(moved).err_G.to_numpy() - prot(DF).err_G.to_numpy())) > 0.01


def test_an_unseen_branch_is_flagged(lf):
    """Without the frictionless families no kt = 0 row is in the fit (friction-prepared kt = 0 rows
    are not usable): the frictionless terms are unfitted, so every kt = 0 row is flagged, though
    its leverage (pseudo-inverse) would not see it."""
    g = lf[lf.held_out == "frictionless_minimum"]
    assert (g.kt_over_kn == 0).sum() >= 20
    assert not g[g.kt_over_kn == 0].valid.any() and not g[g.kt_over_kn == 0].in_box.any()
    lev_ok = (g.h_K <= 3 * g.hmax_K) & (g.h_G <= 3 * g.hmax_G)
    assert lev_ok[g.kt_over_kn == 0].any()   # the leverage alone would have let some through
    # the stated error and the overclaims, recounted
    v = lf[lf.valid]
    out = (v.err_K.abs() > v.stated_K * (1 + 1e-12)) | (v.err_G.abs() > v.stated_G * (1 + 1e-12))
    assert int(out.sum()) == int(lf.overclaim.sum()) and not lf.overclaim[~lf.valid].any()


def test_documented_family_figures(lf):
    """docs/results/closure.md, section 4: the fixed-phi family held out is overclaimed in K (7.5 %
    rms, 61 % inside a stated 4.3 %, 80 overclaims of 188 valid), too stiff most at kt/kn = 0.05;
    the two other families are within their target in G and near it in K."""
    tab = lofo_table(lf).set_index("held_out")
    fp = tab.loc["fixed_phi"]
    assert (fp.cases, fp.valid, fp.overclaims) == (208, 188, 80)
    assert fp.rms_K == pytest.approx(0.0748, abs=2e-3) and fp.inside_K == pytest.approx(0.612, abs=0.01)
    assert fp.rms_G == pytest.approx(0.0714, abs=2e-3) and fp.Q_K == pytest.approx(0.0434, abs=1e-3)
    for f in ("servo_frictional", "frictionless_minimum"):
        assert tab.loc[f, "rms_G"] <= 0.10 and tab.loc[f, "rms_K"] <= 0.05 and tab.loc[f, "inside_G"] >= 0.9
    assert tab.loc["servo_frictional", "valid"] == 68 and tab.loc["frictionless_minimum", "valid"] == 56
    g = lf[(lf.held_out == "fixed_phi") & lf.valid]
    by_kt = g.groupby("kt_over_kn").err_K.mean()
    assert by_kt[0.05] == pytest.approx(0.120, abs=5e-3) and by_kt[1.0] == pytest.approx(0.020, abs=5e-3)
    assert (np.diff(by_kt.to_numpy()) < 0).all()   # too stiff, the more so the smaller kt/kn


def test_fn_cv_trial_as_documented():
    """The refit trial of section 2: fn_cv in G gains in G both ways (LOPO log G 0.074 -> 0.066;
    every family's rms G of its valid rows lower) and does nothing for K, the fixed-phi
    family's failure; in K and G it makes the worst held-out protocol's K worse (4.45 -> 4.85 %)."""
    t = family_trials(DF).set_index(["trial", "held_out"])
    base, g_only, both = (t.xs(n, level="trial") for n in ("the closure", "+ fn_cv (G only)", "+ fn_cv (K and G)"))
    assert base.lopo_log_G.iloc[0] == pytest.approx(0.0738, abs=1e-3)
    assert g_only.lopo_log_G.iloc[0] == pytest.approx(0.0656, abs=1e-3)
    assert both.lopo_worst_K.iloc[0] > base.lopo_worst_K.iloc[0] + 0.003
    assert (g_only.rms_G < base.rms_G).all()
    assert g_only.loc["fixed_phi", "rms_K"] > 0.07 and g_only.loc["fixed_phi", "inside_K"] < 0.7


# ---- the default stated error: across families (issue 25, item 1) ------------------------------

def _across_inside(lf, q_in, q_family, m, by_kt=False):
    """Per held-out family (and kt/kn if ``by_kt``): the fraction of its valid cases inside max(q_in, a + b ln(kn/kt))
    sqrt(1 + h/h_mean), h and h_mean those of the closure fitted without the family."""
    v = lf[lf.valid]
    kt = v.kt_over_kn.to_numpy()
    L = np.where(kt > 0, np.clip(np.log(1.0 / np.where(kt > 0, kt, 1.0)), 0.0, np.log(20.0)), np.log(20.0))
    q = np.maximum(q_in[m], q_family[m][0] + q_family[m][1] * L)   # the form, written out
    ok = v[f"err_{m}"].abs().to_numpy() <= q * np.sqrt(1 + v[f"h_{m}"] / v[f"hmean_{m}"]).to_numpy()
    return pd.Series(ok, index=v.index).groupby([v.held_out, v.kt_over_kn] if by_kt else v.held_out).mean()


def test_default_error_covers_every_held_out_family(lf):
    """The stored across-family error (Q, Q_FAMILY of microhom.closure), applied to the
    leave-one-family-out predictions recomputed from the committed corpus, covers at least 90 %
    of the valid cases of every family in K and in G; the in-family error does not (fixed phi, K:
    0.61), and at every kt/kn of every family (the error is stated as a function of kt/kn).
    Narrowing Q_FAMILY by 10 % breaks it (the check has teeth), and the stored values are the
    calibration of studies.closure_fit."""
    from microhom.closure import Q, Q_FAMILY
    from studies.closure_fit import calibrate, calibrate_family
    for m in ("K", "G"):
        inside = _across_inside(lf, Q, Q_FAMILY, m)
        assert len(inside) == 3 and (inside >= 0.9).all(), (m, inside.to_dict())
        by_kt = _across_inside(lf, Q, Q_FAMILY, m, by_kt=True)   # and at every kt/kn of every family
        assert len(by_kt) == 12 and (by_kt >= 0.9).all(), (m, by_kt.to_dict())
    for m in ("K", "G"):
        narrow = {k: (0.9 * Q_FAMILY[k][0], 0.9 * Q_FAMILY[k][1]) for k in ("K", "G")}
        assert (_across_inside(lf, Q, narrow, m, by_kt=True) < 0.9).any(), m
    assert Q_FAMILY["K"][1] > 0   # K's error grows as kt/kn falls, where the families disagree
    q, _ = calibrate(lopo(DF))
    qf = calibrate_family(lf, q)
    for m in ("K", "G"):
        assert Q_FAMILY[m][0] == pytest.approx(qf[m][0], rel=1e-5, abs=1e-7)
        assert Q_FAMILY[m][1] == pytest.approx(qf[m][1], abs=1e-9)
    # before: the in-family error of the closure fitted without the family (section 4's table)
    v = lf[lf.valid & (lf.held_out == "fixed_phi")]
    assert np.mean(v.err_K.abs() <= v.stated_K) == pytest.approx(0.612, abs=0.01)


def test_across_family_error_in_predictions():
    """predict_closure states the across-family error by default and the in-family one beside it:
    equal where a + b L <= Q (kt/kn >= 0.5 in K), wider at small kt/kn (closed form at kt/kn =
    0.05: a + b ln 20), widest at kt = 0 (L = ln 20; checked in-family only); the leverage growth is the same."""
    from microhom.closure import Q, Q_FAMILY, family_error_scale, predict_closure
    kt = np.array([0.0, 0.05, 0.2, 0.5, 1.0])
    p = predict_closure(nc=4.2, r=0.04, phi=0.85, kt_over_kn=kt, dispersity=0.2, size_coordination=0.05,
                        rattler_fraction=0.03, p_over_kn=1e-3, psi6_local=0.6)
    for m in ("K", "G"):
        rel, rin = getattr(p, f"rel_error_{m}"), getattr(p, f"rel_error_{m}_in_family")
        lev = rin / Q[m]                                   # sqrt(1 + h / H_MEAN)
        a, b = Q_FAMILY[m]
        want = np.maximum(Q[m], a + b * np.log(1 / np.where(kt > 0, kt, 0.05)))
        np.testing.assert_allclose(rel / lev, want, rtol=1e-12)
        np.testing.assert_allclose(rel, family_error_scale(kt, Q[m], Q_FAMILY[m]) * lev, rtol=1e-12)
        assert np.all(rel >= rin) and np.all(lev >= 1)
        np.testing.assert_allclose(getattr(p, f"error_{m}"), rel * getattr(p, m), rtol=1e-12)
        np.testing.assert_allclose(getattr(p, f"error_{m}_in_family"), rin * getattr(p, m), rtol=1e-12)
    assert p.rel_error_K[1] > 1.8 * p.rel_error_K_in_family[1]
    np.testing.assert_allclose(p.rel_error_K[3:], p.rel_error_K_in_family[3:], rtol=1e-12)
    assert p.rel_error_K[0] == pytest.approx(p.rel_error_K[1] / np.sqrt(1 + p.leverage_K[1] / 0.0182119)
                                             * np.sqrt(1 + p.leverage_K[0] / 0.0182119), rel=1e-4)


def test_documented_default_error_figures(lf):
    """docs/results/closure.md, section 4 ("The default stated error"): overclaims 80 / 12 / 5 with
    the in-family error, 14 / 1 / 1 with the across-family one; calibrated without the fixed-phi
    family the across-family error covers only 70 % of its K (three families do not certify a
    fourth: a documented limit, not a pass)."""
    from microhom.closure import Q, Q_FAMILY
    from studies.closure_fit import family_error_table
    t = family_error_table(lf, Q, Q_FAMILY)
    t = t[t.protocol == "all"].set_index("held_out")
    fams = ["fixed_phi", "servo_frictional", "frictionless_minimum"]
    assert t.loc[fams, "before_overclaims"].tolist() == [80, 12, 5]
    assert t.loc[fams, "after_overclaims"].tolist() == [14, 1, 1]
    assert t.loc["fixed_phi", "nested_inside_K"] == pytest.approx(0.702, abs=0.01)
    assert t.loc["fixed_phi", "nested_inside_K"] < 0.9 <= t.loc["fixed_phi", "after_inside_K"]


def test_frictionless_error_is_defined_and_checked_in_family():
    """kt = 0, where ln(kn/kt) is infinite: the across-family error takes L = L_MAX = ln 20 (finite,
    the closed form a + b ln 20 and continuous from kt -> 0+), bad kt/kn is refused by name, and
    on the frictionless family's own leave-one-protocol-out kt = 0 cases (the only ones there are)
    the stated figure holds: docs/results/closure.md, section 4, "At kt = 0"."""
    from microhom.closure import Q, Q_FAMILY, family_error_scale, predict_closure
    from studies.closure_fit import calibrate, scale
    p = predict_closure(nc=[4.3, 4.3], r=0.04, phi=0.85, kt_over_kn=[0.0, 1e-300], dispersity=0.2,
                        size_coordination=0.05, rattler_fraction=0.03, p_over_kn=1e-3, psi6_local=0.6)
    for m in ("K", "G"):
        a, b = Q_FAMILY[m]
        s0 = family_error_scale(0.0, Q[m], Q_FAMILY[m])
        assert np.isfinite(s0) and s0 == pytest.approx(max(Q[m], a + b * np.log(20.0)), rel=1e-12)
        assert family_error_scale(1e-300, Q[m], Q_FAMILY[m]) == s0          # continuous from kt -> 0+
        rel = getattr(p, f"rel_error_{m}")
        assert np.all(np.isfinite(rel)) and np.all(np.isfinite(getattr(p, f"error_{m}")))
        assert rel[0] == pytest.approx(s0 * np.sqrt(1 + getattr(p, f"leverage_{m}")[0] / 0.0182119), rel=1e-4)
    assert family_error_scale(0.0, Q["K"], Q_FAMILY["K"]) == pytest.approx(0.1245, abs=5e-4)   # 12.4 %
    assert family_error_scale(0.0, Q["G"], Q_FAMILY["G"]) == pytest.approx(0.1016, abs=5e-4)   # 10.2 %
    for bad in (np.nan, -0.1, np.inf):
        with pytest.raises(ValueError, match="kt_over_kn"):
            family_error_scale(bad, Q["K"], Q_FAMILY["K"])
    lo = lopo(DF)
    _, inside = calibrate(lo)
    v = lo[inside & (lo.kt_over_kn == 0)]
    assert v.protocol.value_counts().to_dict() == {"minimise": 13, "pack_frictionless": 10}
    for m, rms in (("K", 0.037), ("G", 0.104)):
        z = v[f"err_{m}"].abs() / scale(v, m)
        assert np.all(np.isfinite(z))
        assert (z <= family_error_scale(0.0, Q[m], Q_FAMILY[m])).all(), m     # every case inside
        assert np.sqrt(np.mean(v[f"err_{m}"] ** 2)) == pytest.approx(rms, abs=2e-3)
