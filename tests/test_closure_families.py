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
