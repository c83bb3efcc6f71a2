"""The across-family feature search (studies.closure_transfer, issue 25 item 2): its contact
statistics on exact lattices, the committed columns equal to a recomputation, and the harness
(a candidate that is a linear combination of K's features changes nothing; the closure's own
row is the figure of studies.closure_fit.lofo_table)."""
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from microhom import lattices
from studies.closure_fit import SUMMARY, lofo, lofo_table, usable
from studies.closure_transfer import CONTACT_COLUMNS, contact_statistics, trial, with_interactions

RAW = pd.read_csv(SUMMARY, keep_default_na=False, na_values=[""])
DF = usable(RAW)


def _subset(net, keep, fn):
    return replace(net, pairs=net.pairs[keep], branch=net.branch[keep], kn=np.asarray(net.kn)[keep],
                   kt=np.asarray(net.kt)[keep], sliding=np.asarray(net.sliding)[keep], fn=fn, ft=np.zeros(keep.sum()))


def test_contact_statistics_exact_on_lattices():
    """Triangular lattice, equal forces: no weak contact, no near contact, six sticking contacts.
    The same positions with one of the three bond directions removed from the contacts: four
    contacts each, and the two removed neighbours of every disk (gap 0 < 1e-3 d) are near
    contacts; forces alternating 1 and 3 (mean 2): half of the contacts weak, none below 0.2."""
    lat = lattices.triangular(6, 6, kt=1.0)
    full = _subset(lat, np.ones(lat.n_contacts, bool), np.ones(lat.n_contacts))
    s = contact_statistics(full, True)
    assert s == dict(weak_fraction=0.0, fn_small=0.0, near_contacts=0.0, Z_stick=6.0, f_z3=0.0)
    horizontal = np.abs(lat.branch[:, 1]) < 1e-9
    assert horizontal.sum() == lat.n_particles
    keep = ~horizontal
    fn = np.where(np.arange(keep.sum()) % 2 == 0, 1.0, 3.0)
    s = contact_statistics(_subset(lat, keep, fn), True)
    assert s["near_contacts"] == pytest.approx(2.0) and s["Z_stick"] == pytest.approx(4.0)
    assert s["weak_fraction"] == pytest.approx(0.5) and s["fn_small"] == 0.0 and s["f_z3"] == 0.0
    # sliding contacts do not stick
    sl = _subset(lat, keep, fn)
    sl = replace(sl, sliding=np.arange(keep.sum()) < lat.n_particles)   # half of the 2N contacts
    assert contact_statistics(sl, True)["Z_stick"] == pytest.approx(2.0)


def test_committed_contact_columns_are_present_and_sane():
    for c in CONTACT_COLUMNS:
        assert DF[c].notna().all(), c
    assert ((DF.weak_fraction > 0.3) & (DF.weak_fraction < 0.8)).all()
    assert (DF.Z_stick <= DF.Z + 1e-12).all()
    fr = DF[DF.kt_over_kn > 0]
    np.testing.assert_allclose(fr.Z_stick, fr.Z * (1 - fr.sliding_fraction), rtol=1e-9)


def test_harness_closure_row_and_a_redundant_candidate():
    """The harness's figures for the stored closure are lofo_table's; log10(p/kn) - 2 log10 dZ, a
    linear combination of two features already in K, changes no figure."""
    base = trial(with_interactions(DF))
    tab = lofo_table(lofo(DF)).set_index("held_out")
    assert base["fixed_phi_rms_K"] == pytest.approx(tab.loc["fixed_phi", "rms_K"], rel=1e-12)
    assert base["fixed_phi_valid"] == tab.loc["fixed_phi", "valid"]
    same = trial(with_interactions(DF), ("log_p_over_dZ2",))
    for k in ("fixed_phi_rms_K", "lopo_log_K", "Q_K"):   # rank-deficient fits agree to ~1e-6
        assert same[k] == pytest.approx(base[k], rel=1e-4), k
    # the across-family scale is a grid search whose a is rounded up to 1e-6: equal to that
    assert same["across_median_K"] == pytest.approx(base["across_median_K"], rel=1e-3)
