"""Every study runs end to end in --quick mode and writes its table; key numbers are sane."""
import pandas as pd
import pytest
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True, scope="module")
def shared_cache(tmp_path_factory):
    import os

    old = os.environ.get("MICROHOM_CACHE")
    os.environ["MICROHOM_CACHE"] = str(tmp_path_factory.mktemp("packings"))
    yield
    if old is None:
        del os.environ["MICROHOM_CACHE"]
    else:
        os.environ["MICROHOM_CACHE"] = old


def test_kuhn_quick(tmp_path, capsys):
    from studies import kuhn

    kuhn.main(["--quick", "--out", str(tmp_path), "--invert"])
    out = capsys.readouterr().out
    assert "0.189 (bulk), 0.284 (shear)" in out  # the seed's table reproduced by the theory
    t = pd.read_csv(tmp_path / "table.csv")
    ref = t[t.method.str.contains("reference")]
    probe = t[t.method.str.contains("probes")]
    assert len(ref) == 2 and len(probe) == 2
    assert (probe.error_vs_DEM.abs() < 1e-3).all()  # two independent DEM routes agree
    mf = t[t.method == "theory: mean field"]
    assert (mf.error_vs_DEM > 0).all()  # the mean field over-predicts, as the paper says
    up = t[t.method.str.contains("upper bound")]
    assert len(up) == 2 and (up.error_vs_DEM >= -1e-9).all()  # the hierarchy's bound holds
    assert (t[t.method.str.contains("closure")].error_vs_DEM.abs() < 0.3).all()
    assert (tmp_path / "moduli.png").stat().st_size > 10_000
    # the closed-form inversion beside the table, and --invert's full study on the same packing
    inv = pd.read_csv(tmp_path / "inversion.csv")
    assert list(inv.parameter) == ["x = r (Nbar/Nc) rho", "r", "rho", "Nbar (rho fixed)"]
    ratio = inv["needed for G"] / inv["needed for K"]       # r, rho, Nbar enter only through x:
    assert ratio.max() == pytest.approx(ratio.min(), rel=1e-12)  # one mismatch factor for all rows
    assert (tmp_path / "inversion_full.md").exists() and "mismatch" in out


def test_error_vs_runtime_quick(tmp_path):
    from studies import error_vs_runtime

    error_vs_runtime.main(["--quick", "--out", str(tmp_path)])
    t = pd.read_csv(tmp_path / "error_vs_runtime.csv")
    best_probe = t[t.method == "strain probes"].sort_values("err_G").iloc[0]
    assert best_probe.err_G < 1e-3 and best_probe.contact_events == 0
    for name in ("hierarchy (multilevel)", "hierarchy (k shells)"):   # (was "hierarchy: upper
        up = t[t.method == f"{name}: upper bound"]                      # bound": matched no row)
        assert len(up) >= 2, name
        assert (up.K >= t.K.iloc[0] * (1 - 1e-9)).all() and (up.G >= t.G.iloc[0] * (1 - 1e-9)).all()
        assert (up.G.diff().dropna() <= 1e-12 * up.G.iloc[0]).all()  # monotone in the steps
    # issue 27: what each row is measured against; only exact solves of other packings are "other"
    other = t[t.measured_against == "other packing"]
    assert len(other) == 2 and (other.method == "exact linear response").all()
    assert (t[t.measured_against == "same packing"].parameter.str.contains("reference")).sum() == 1
    assert (tmp_path / "error_vs_runtime.png").exists()


def test_sweep_quick_resumes(tmp_path):
    from studies import sweep

    # kt/kn = 0 is on the sweep's grid: a packing prepared with friction and analysed frictionless
    # can have no rigid backbone, and the exact solve says so (asserted, and true of its row below)
    with pytest.warns(RuntimeWarning, match="not jammed: the relaxed tensor vanishes"):
        sweep.main(["--quick", "--out", str(tmp_path), "--scheduler", "serial"])
    first = pd.read_csv(tmp_path / "sweep.csv")
    assert len(first) == 8 and (first.status == "ok").sum() >= 6
    unjammed = first[(first.status == "ok") & (first.exact_K.abs() <= 1e-10 * first.affine_K)]
    assert len(unjammed) >= 1 and (unjammed.kt_ratio == 0).all() and (unjammed.n_floppy > 0).all()
    failed = first[first.status != "ok"]
    assert failed.error.str.contains("rattler").all()  # named failures only
    sweep.main(["--quick", "--out", str(tmp_path), "--scheduler", "serial"])  # all done: resumes, re-runs failures
    again = pd.read_csv(tmp_path / "sweep.csv")
    ok = first.status == "ok"
    cols = ["case_id", "nc", "exact_K", "exact_G", "theory_rho_G"]
    pd.testing.assert_frame_equal(first.loc[ok, cols].reset_index(drop=True),
                                  again.loc[again.status == "ok", cols].reset_index(drop=True))


def test_stability_has_no_wrong_case(tmp_path):
    from studies import stability

    assert stability.main(["--quick", "--out", str(tmp_path)]) == 0
    t = pd.read_csv(tmp_path / "stability.csv")
    assert (t.outcome != "WRONG").all()
    assert set(t.outcome) >= {"ok", "error", "flagged"}


@pytest.mark.slow
def test_bench_hierarchy_validate_quick(tmp_path):
    from studies import bench_hierarchy

    bench_hierarchy.main(["validate", "--quick", "--out", str(tmp_path)])
    t = pd.read_csv(tmp_path / "validation.csv")
    assert len(t) == 3 and t.exact_inside_all_intervals.all()
    assert t.K_ext16_holds.all() and t.G_ext16_holds.all()


@pytest.mark.slow
def test_closure_fit_quick(tmp_path, capsys):
    from studies import closure_fit

    closure_fit.main(["--quick", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert "COEF_K =" in out and "leave one protocol out" in out
    lopo = pd.read_csv(tmp_path / "lopo.csv")
    assert len(lopo) >= 5 and (lopo.inside_K >= 0.9).all() and (lopo.inside_G >= 0.9).all()
    t = pd.read_csv(tmp_path / "quick.csv")   # one small frictionless packing, end to end
    assert len(t) == 2 and t.valid.all()
    assert (t.err_G.abs() <= t.stated_G).all()


def test_displacement_correlation_of_a_plane_wave_on_the_triangular_lattice():
    # u = (cos k x, 0) on a triangular lattice (spacing 1, rows along x): over the 6 nearest
    # neighbours at angles 0, 60, ..., 300 deg, <u_i.u_j>/<u^2> = (cos k + 2 cos(k/2))/3 exactly
    import numpy as np

    from microhom import lattices
    from studies.seed_inversion import displacement_correlation

    net = lattices.triangular(12, 12)
    L = float(net.cell[0, 0])
    k = 2 * np.pi / L
    u = np.stack([np.cos(k * net.positions[:, 0]), np.zeros(net.n_particles)], 1)
    centres, c = displacement_correlation(net, u, np.ones(net.n_particles, bool), np.array([0.9, 1.1]))
    assert c[0] == pytest.approx((np.cos(k) + 2 * np.cos(k / 2)) / 3, rel=1e-12)


def test_seed_inversion_quick_round_trips_on_a_packing(tmp_path):
    import numpy as np

    from microhom.moduli import predict_moduli
    from studies import seed_inversion

    seed_inversion.main(["--quick", "--out", str(tmp_path)])
    k = pd.read_csv(tmp_path / "kuhn_all.csv").iloc[0]
    # the r the inversion says each modulus needs gives back the exact DEM modulus
    for m, col in (("K", "r_K"), ("G", "r_G")):
        p = predict_moduli(1.0, 1.0, k.nc, k.phi, k[col], rho=k.rho, nbar=k.nbar, warn=False)
        assert float(getattr(p, m)) == pytest.approx(k[f"exact_{m}"], rel=1e-10)
    assert k.mismatch == pytest.approx(k.ratio_measured / 1.5, rel=1e-12)
    assert 1.0 < k.d0_shear < 20 and np.isfinite(k.ncl_bulk)
    curve = pd.read_csv(tmp_path / "nbar_curve.csv")
    assert len(curve) == len(seed_inversion.NBAR_GRID) and (curve.rho.abs() < 2).all()
    assert (tmp_path / "kuhn.md").exists() and (tmp_path / "inversion.png").exists()


def test_error_vs_runtime_figure_is_drawn_from_the_page(tmp_path):
    """The figure of docs/results/error_vs_runtime.md is redrawn from the page's own table
    (``--replot``): the table parses whole (3 exact solves of other packings), and the closure row it
    draws is the one the page's prose states (4.3 % / 0.7 %, stated 9.1 % / 17.9 %)."""
    import re
    from studies import error_vs_runtime
    md = ROOT / "docs" / "results" / "error_vs_runtime.md"
    df = error_vs_runtime.read_table(md)
    assert len(df) == 41 and (df.measured_against == "other packing").sum() == 3
    c = df[df.method.str.startswith("closure")].iloc[0]
    text = md.read_text()
    m = re.search(r"statistics-only closure \(([\d.]+) % / ([\d.]+) %; stated ([\d.]+) % / ([\d.]+) %", text)
    assert m, "the page no longer states the closure row in prose"
    for value, stated in zip((c.err_K, c.err_G, c.stated_err_K, c.stated_err_G), m.groups()):
        assert f"{100 * value:.1f}" == stated
    assert error_vs_runtime.main(["--replot", str(md), str(tmp_path / "f.png")]) == 0
    assert (tmp_path / "f.png").stat().st_size > 10_000
    bad = tmp_path / "bad.md"
    bad.write_text("# no table\n")
    with pytest.raises(ValueError, match="no table"):
        error_vs_runtime.read_table(bad)
