"""The statistics-only closure: its limits, its isostatic points, its stated error on protocols it
was not fitted to (leave one protocol out on the committed corpus summary), flags, bad input."""
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import sympy as sp

from microhom import closure
from microhom.closure import (ALL_FEATURES, COEF_G, COEF_K, DZ_MIN, FEATURES_G, FEATURES_K, Q, RANGES,
                              features, isostatic_point, predict_closure)

ROOT = Path(__file__).resolve().parents[1]
SUMMARY = pd.read_csv(ROOT / "studies" / "closure_corpus.csv", keep_default_na=False, na_values=[""])
#: the inputs of predict_closure from a row of the corpus summary
def _args(df):
    return dict(nc=df.Z.to_numpy(), r=df.r.to_numpy(), phi=df.phi.to_numpy(), kt_over_kn=df.kt_over_kn.to_numpy(),
                dispersity=df.dispersity.to_numpy(), sliding_fraction=df.sliding_fraction.to_numpy(),
                size_coordination=(df.Z_size - df.Z).to_numpy(), rattler_fraction=df.rattler_fraction.to_numpy(),
                p_over_kn=df.p_over_kn.to_numpy(), psi6_local=df.psi6_local.to_numpy())


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
    """G -> 0 linearly at the isostatic point (the scaling G ~ dZ of the jamming literature; as
    dZ^(1 - c) between 1e-3 and the data, c the fitted exponent of dZ in a, |c| < 0.2), G -> G_mf and K -> K_mf at high Z; for
    both branches. The limits hold because the fitted exponents are inside the allowed ranges."""
    iG, iK = FEATURES_G.index("log dZ"), FEATURES_K.index("log dZ")
    assert abs(COEF_G[iG]) < 0.2 and abs(COEF_G[iG] + COEF_G[FEATURES_G.index("frictionless * log dZ")]) < 0.2
    assert COEF_K[iK] < 0 and COEF_K[iK] + COEF_K[FEATURES_K.index("frictionless * log dZ")] < 0
    # with log kt/kn * log dZ the exponent depends on kt/kn: small over the data's kt/kn 0.05-1
    c_lk = COEF_G[FEATURES_G.index("log kt/kn * log dZ")] if "log kt/kn * log dZ" in FEATURES_G else 0.0
    for kt in (0.05, 0.2, 1.0):
        assert abs(COEF_G[iG] + c_lk * np.log(kt)) < 0.3
    for kt in (0.0, 0.2, 1.0):
        ziso = float(isostatic_point(kt))
        dz = np.array([1e-7, 1e-6])
        p = predict_closure(nc=ziso + dz, r=0.04, phi=0.85, kt_over_kn=kt, dispersity=0.2, size_coordination=0.03,
                            p_over_kn=1e-3)
        # below dZ = 1e-3 (where log dZ is floored) exactly linear
        assert p.G[1] / p.G[0] == pytest.approx(10.0, rel=1e-4)
        assert not p.valid.any() and "isostatic" in p.reason[0]
        hi = predict_closure(nc=ziso + 1e8, r=0.04, phi=0.85, kt_over_kn=kt, dispersity=0.2, size_coordination=0.03,
                             p_over_kn=1e-3)
        assert float(hi.G / hi.G_mf) == pytest.approx(1.0, abs=0.05)
        assert float(hi.K / hi.K_mf) == pytest.approx(1.0, abs=1e-3)
        assert not bool(hi.valid) and "outside the data" in str(hi.reason)


def test_network_statistics_input_equals_explicit():
    from microhom.structural_sums import NetworkStatistics
    st = NetworkStatistics(n_particles=10, n_contacts=20, n_rattlers=0, rattler_fraction=0.0, nc_all=4.2,
                           r_all=0.05, rho_all=0.7, nc=4.3, r=0.045, rho=0.7, phi=0.86, nbar_phi=5.0,
                           diameter=1.0, sliding_fraction=0.02)
    a = predict_closure(st, kt_over_kn=0.5, dispersity=0.2, size_coordination=0.03, p_over_kn=1e-3, psi6_local=0.6)
    b = predict_closure(nc=4.3, r=0.045, phi=0.86, kt_over_kn=0.5, dispersity=0.2, sliding_fraction=0.02,
                        size_coordination=0.03, p_over_kn=1e-3, psi6_local=0.6)
    assert float(a.G) == float(b.G) and float(a.error_K) == float(b.error_K) and bool(a.valid)
    c = predict_closure(st, kt_over_kn=0.5, dispersity=0.2)
    assert "size_coordination not given" in str(c.reason) and "p_over_kn not given" in str(c.reason)
    assert "psi6_local not given" in str(c.reason) and int(c.flags) & 32
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
    # identical frictional disks at low pressure (the main study's packings), two protocols
    mono = corpus[(corpus.dispersity < 0.05) & (corpus.p_over_kn < 2e-3)]
    assert set(mono.protocol) >= {"pack_study", "pack_frictional"} and mono.seed.nunique() >= 3
    # the LAMMPS protocol twice: by LAMMPS and by our engine, at the same target phi and radii
    fp = corpus[corpus.protocol.isin(["lammps_prep", "dem_fixedphi"])]
    knobs = fp.groupby("protocol")[["knob_phi", "knob_dispersity"]].apply(lambda g: set(map(tuple, g.to_numpy())))
    assert knobs["lammps_prep"] == knobs["dem_fixedphi"]
    assert (fp.groupby("protocol").seed.nunique() >= 5).all()


def test_leave_one_protocol_out_targets(corpus):
    """Issue 25's targets per held-out protocol, as docs/results/closure.md section 4 states them:
    valid predictions within 5 % rms (K) and 10 % rms (G) for every protocol, the LAMMPS packings
    included (7.7 % in K before their twins made by our engine, dem_fixedphi, were in the corpus);
    the stated error covers at least 90 % of each protocol's valid cases, and calibrated without
    that protocol (nested) still at least 85 %."""
    from studies.closure_fit import calibrate, lopo, lopo_table
    lo = lopo(corpus)
    q, inside = calibrate(lo)
    tab = lopo_table(lo, q, inside).set_index("protocol")
    assert (tab.rms_G <= 0.10).all(), tab.rms_G
    assert (tab.rms_K <= 0.05).all(), tab.rms_K
    assert tab.loc["lammps_prep", "rms_K"] <= 0.04
    assert (tab.inside_K >= 0.9).all() and (tab.inside_G >= 0.9).all()
    assert (tab.nested_K >= 0.85).all() and (tab.nested_G >= 0.85).all()
    assert (tab.valid >= 0.9 * tab.cases).all()


def test_stored_model_is_the_fit_of_the_committed_corpus(corpus):
    """The coefficients in microhom/closure.py are those of studies.closure_fit on the summary."""
    from studies.closure_fit import fit
    cK, cG, covK, covG = fit(corpus)
    Kp = predict_closure(**_args(corpus))
    Kf = predict_closure(**_args(corpus), model=dict(coef_K=cK, coef_G=cG, cov_K=covK, cov_G=covG))
    np.testing.assert_allclose(Kp.K, Kf.K, rtol=1e-4)
    np.testing.assert_allclose(Kp.G, Kf.G, rtol=1e-4)


def test_leave_one_protocol_out_stated_error_covers(corpus):
    """Each protocol predicted by the closure fitted on the other four (independent of the stored
    model): the stated error, calibrated on the pooled held-out cases, covers at least 90 % of
    them; and the stored Q is that calibration."""
    from studies.closure_fit import calibrate, lopo, scale
    lo = lopo(corpus)
    q, inside = calibrate(lo)
    for m in ("K", "G"):
        assert Q[m] == pytest.approx(q[m], rel=1e-5)
        for prot, g in lo[inside].groupby("protocol"):
            cover = np.mean(np.abs(g[f"err_{m}"]) <= q[m] * scale(g, m) * (1 + 1e-12))
            assert cover >= 0.9, (prot, m, cover)
        # the stored model's own stated error on the corpus (in sample) covers it too
    p = predict_closure(**_args(corpus))
    assert np.mean(np.abs(p.K / corpus.K - 1) <= p.rel_error_K) >= 0.9
    assert np.mean(np.abs(p.G / corpus.G - 1) <= p.rel_error_G) >= 0.9


def test_held_out_rows_are_better_than_mean_field(corpus):
    from studies.closure_fit import lopo, mean_field
    lo = lopo(corpus).merge(corpus[["key", "kt_over_kn", "K", "G", "Z", "phi", "rattler_fraction"]],
                            on=["key", "kt_over_kn"])
    K_mf, G_mf = mean_field(lo)
    assert np.sqrt(np.mean(lo.err_G ** 2)) < 0.5 * np.sqrt(np.mean((G_mf / lo.G - 1) ** 2))


def test_flags():
    p = predict_closure(nc=np.array([3.02, 4.3, 4.3, 3.8, 4.3, 6.0]), r=np.array([0.05, 0.04, 0.04, 0.04, 0.04, 0.0]),
                        phi=np.array([0.84, 0.86, 0.86, 0.84, 0.86, 0.9069]),
                        kt_over_kn=np.array([0.5, 0.5, 0.0, 0.0, 1e-3, 1.0]), dispersity=np.array([0.2, 0.2, 0.2, 0.2, 0.2, 0.0]),
                        size_coordination=0.03, rattler_fraction=0.02, p_over_kn=1e-3, psi6_local=0.6)
    assert list(p.valid) == [False, True, True, False, False, False]
    assert "isostatic" in p.reason[0] and "isostatic" in p.reason[3]    # frictionless below Z = 4
    assert "outside the data" in p.reason[4]                           # kt/kn far below the corpus
    assert "outside the data" in p.reason[5]                           # the triangular lattice
    assert np.all(np.isfinite(p.K)) and np.all(np.isfinite(p.G)) and np.all(p.G >= 0)
    assert np.all(p.rel_error_G[p.valid] > 0)
    assert DZ_MIN > 0 and RANGES["dispersity"][1] >= 0.5


def test_error_grows_away_from_the_data():
    kw = dict(phi=0.85, kt_over_kn=0.5, dispersity=0.2, size_coordination=0.03, p_over_kn=1e-3, psi6_local=0.6)
    p = predict_closure(nc=np.linspace(3.6, 5.5, 20), r=0.04, **kw)
    q = predict_closure(nc=4.4, r=np.linspace(0.03, 0.2, 20), **kw)
    assert q.rel_error_G[-1] > 2 * q.rel_error_G[0] and not q.valid[-1]
    assert np.all(p.rel_error_K >= Q["K"]) and np.all(p.rel_error_G >= Q["G"])


@pytest.mark.parametrize("kwargs, name", [(dict(nc=-1.0), "nc"), (dict(r=-0.1), "r"), (dict(phi=1.2), "phi"),
                                          (dict(kt_over_kn=np.nan), "kt_over_kn"), (dict(kn=0.0), "kn"),
                                          (dict(dispersity=-0.1), "dispersity"),
                                          (dict(sliding_fraction=1.0), "sliding_fraction"),
                                          (dict(rattler_fraction=-0.1), "rattler_fraction"),
                                          (dict(p_over_kn=0.0), "p_over_kn"),
                                          (dict(size_coordination=np.inf), "size_coordination"),
                                          (dict(psi6_local=1.5), "psi6_local")])
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
    assert X.shape == (len(ALL_FEATURES),) and dz == pytest.approx(1.2)
    json.dumps(predict_closure(nc=4.2, r=0.04).as_dict())


def test_size_coordination_and_dispersity_exact():
    """Hand-computed: radii (1, 1, 2), the big disk touching both small ones: z = (1, 1, 2),
    sum z R / sum R - mean z = 6/4 - 4/3 = 1/6; dispersity sqrt(3) std/mean."""
    from microhom.closure import dispersity, size_coordination
    from microhom.network import from_pairs
    pos = np.array([[3.0, 0.0], [-3.0, 0.0], [0.0, 0.0]])
    rad = np.array([1.0, 1.0, 2.0])
    net = from_pairs(pos, rad, None, np.array([[0, 2], [1, 2]]))
    assert size_coordination(net, min_contacts=0) == pytest.approx(1 / 6, rel=1e-14)
    assert dispersity(net) == pytest.approx(np.sqrt(3) * np.std(rad) / np.mean(rad), rel=1e-14)
    assert size_coordination(net.with_stiffness(kt=0.0), min_contacts=0) == pytest.approx(1 / 6)


def test_minimise_protocol_is_a_force_balanced_energy_minimum(tmp_path):
    """The corpus's energy-minimisation protocol (harmonic, frictionless) on a small cell: every
    disk in force balance to the minimiser's tolerance, the packing cached and reloaded identical,
    and the closure's inputs measured on it (frictionless: Z_iso = 4)."""
    from microhom.closure import closure_inputs, isostatic_point
    from studies.corpus import _row, build_network
    row = _row("minimise", 64, 3, phi=0.9, radii="bidisperse")
    net, meta = build_network(row, tmp_path)
    f = net.fn[:, None] * net.normals
    res = np.zeros((net.n_particles, 2))
    np.add.at(res, net.pairs[:, 0], -f)
    np.add.at(res, net.pairs[:, 1], f)
    # the residual recomputed from the network agrees with the minimiser's, and is 1e-6 of the forces
    assert np.abs(res).max() == pytest.approx(meta["grad_max"], rel=1e-6, abs=1e-13)
    assert np.abs(res).max() < 1e-6 * net.fn.mean()
    again, _ = build_network(row, tmp_path)
    np.testing.assert_array_equal(again.positions, net.positions)
    x = closure_inputs(net.with_stiffness(kt=0.0))
    assert x["kt_over_kn"] == 0.0 and x["nc"] > float(isostatic_point(0.0))
    assert x["dispersity"] == pytest.approx(np.sqrt(3) * 0.1 / 0.6, rel=1e-12)   # radii 0.5, 0.7


def test_main_study_packings_predicted_with_their_protocol_left_out(corpus):
    """The main study's packings (pack_study at mu_prep = 0.05, p/kn = 1e-4: identical disks, its
    damping protocol; the same packings as python -m studies.kuhn's seeds 1-3) predicted by the
    closure fitted without that protocol: valid (flag 32 now only says psi6_local is missing),
    within 10 % (K) and 20 % (G) at every kt/kn and within the stated error in >= 90 % of the
    cases. Before the corpus held them and psi6_local, K came out 15-17 % too stiff."""
    from studies.closure_fit import calibrate, lopo, scale
    lo = lopo(corpus)
    q, inside = calibrate(lo)
    keys = corpus[(corpus.protocol == "pack_study") & (corpus.knob_mu_prep == 0.05)
                  & (corpus.knob_p_over_kn == 1e-4)].key.unique()
    assert len(keys) == 3
    m = lo.key.isin(keys)
    assert inside[m].all()
    assert np.abs(lo.err_K[m]).max() < 0.10 and np.abs(lo.err_G[m]).max() < 0.20
    for mod in ("K", "G"):
        cover = np.mean(np.abs(lo[f"err_{mod}"][m]) <= q[mod] * scale(lo[m], mod))
        assert cover >= 0.9, (mod, cover)
    # the stored closure, measured inputs given: valid on them
    p = predict_closure(**_args(corpus[corpus.key.isin(keys)]))
    assert p.valid.all()


def test_bond_order_exact_lattices_and_delaunay():
    """psi_m of the load-bearing contacts (microhom.structural_sums.bond_order), exact cases: a
    triangular lattice gives psi6 = 1 and psi4 = 0, a square lattice psi6 = 0 and psi4 = 1 (global
    and local), in any orientation (the global modulus and the local one are rotation invariant);
    second method: on the triangular lattice the contacts are the Delaunay neighbours, so the
    contact psi6 equals dem.analysis.measure.hexatic_order's; bad m is refused."""
    from dem.analysis.measure import hexatic_order
    from microhom.lattices import square, triangular
    from microhom.structural_sums import bond_order
    for angle in (0.0, 0.37):
        tri, sq = triangular(6, 6, kt=1.0, angle=angle), square(5, 5, kt=1.0, angle=angle)
        for net, m, want in ((tri, 6, 1.0), (tri, 4, 0.0), (sq, 6, 0.0), (sq, 4, 1.0)):
            b = bond_order(net, m)
            assert b.psi == pytest.approx(want, abs=1e-12) and b.psi_local == pytest.approx(want, abs=1e-12)
            assert b.n_particles == net.n_particles
        hx = hexatic_order(tri)
        assert bond_order(tri).psi == pytest.approx(hx.psi6, abs=1e-9)
    # amorphous: a corpus packing of the committed summary is not needed; random bond angles give
    # |<psi6>| ~ N^-1/2 and <|psi6_i|> ~ z^-1/2 (the mean modulus of a random walk of z unit steps)
    rng = np.random.default_rng(0)
    from microhom.network import ContactNetwork
    n = 4000
    pairs = np.stack([np.arange(n), (np.arange(n) + 1) % n], 1)
    th = rng.uniform(0, 2 * np.pi, n)
    pos = rng.uniform(0, 100, (n, 2))
    net = ContactNetwork(positions=pos, radii=np.full(n, 0.5), cell=np.eye(2) * 100, pairs=pairs,
                         branch=np.stack([np.cos(th), np.sin(th)], 1), kn=np.ones(n), kt=np.ones(n),
                         sliding=np.zeros(n, bool))
    b = bond_order(net, 6)
    assert b.psi < 4 / np.sqrt(n)
    # two independent unit steps: E|e^{ia} + e^{ib}| / 2 = 2/pi
    assert b.psi_local == pytest.approx(2 / np.pi, abs=0.02)
    with pytest.raises(ValueError, match="m must be an integer >= 1"):
        bond_order(net, 0)


def test_pack_study_rows_are_the_main_study_packings():
    """The corpus's pack_study protocol at mu_prep 0.05, p/kn 1e-4 is the packing protocol
    studies.cases builds the main study's packings with (same PackingProtocol, field by field)."""
    from dem.engine.packing import PackingProtocol
    from studies.cases import DEFAULTS, PROTOCOL
    from studies.corpus import _row, packing_protocol
    for seed in (1, 2, 3):
        row = _row("pack_study", 1000, seed, p_over_kn=1e-4, mu_prep=0.05, dispersity=0.0)
        main = PackingProtocol(n=DEFAULTS["n"], p_over_kn=DEFAULTS["p_over_kn"], kn=1.0,
                               kt_over_kn=DEFAULTS["kt_over_kn"], mu=DEFAULTS["mu"], mu_prep=DEFAULTS["mu_prep"],
                               dispersity=DEFAULTS["dispersity"], seed=seed, **PROTOCOL)
        assert packing_protocol(row) == main


def test_small_packings_are_flagged():
    """Bit 64: fewer particles than the corpus's smallest packings (N_MIN = 1000). Not given, a
    large packing is assumed; measured from a network by closure_inputs."""
    from microhom.closure import N_MIN
    kw = dict(nc=4.3, r=0.04, phi=0.85, kt_over_kn=0.5, dispersity=0.2, size_coordination=0.05,
              rattler_fraction=0.05, p_over_kn=1e-3, psi6_local=0.6)
    base = predict_closure(**kw)
    assert base.valid and not (int(base.flags) & 64)
    small = predict_closure(**kw, n_particles=64)
    assert not small.valid and int(small.flags) == 64
    assert "n_particles" in small.reason
    big = predict_closure(**kw, n_particles=N_MIN)
    assert big.valid and float(big.G) == float(base.G)
    v = predict_closure(**kw, n_particles=np.array([64, 999, 1000, 4000]))
    assert v.valid.tolist() == [False, False, True, True]
    with pytest.raises(ValueError, match="n_particles"):
        predict_closure(**kw, n_particles=0)
