"""The inversion of the seed's correction: closed-form round trips and sympy's solve of (50)-(51)."""
import numpy as np
import pytest

from microhom.moduli import predict_moduli
from microhom.seed_inversion import invert_seed_correction


def _case(seed=0, n=50):
    rng = np.random.default_rng(seed)
    return dict(t=rng.uniform(0, 2, n), nc=rng.uniform(3.2, 5.5, n), r=rng.uniform(0.01, 0.2, n),
                nbar=rng.uniform(4, 6, n), rho=rng.uniform(0.1, 0.9, n), phi=rng.uniform(0.8, 0.88, n))


@pytest.mark.parametrize("which", ["r", "rho", "nbar"])
def test_round_trip_recovers_the_parameter_from_both_moduli(which):
    c = _case()
    p = predict_moduli(1.0, c["t"], c["nc"], c["phi"], c["r"], rho=c["rho"], nbar=c["nbar"], warn=False)
    measured = dict(r=c["r"], nbar=c["nbar"], rho=c["rho"])
    measured[which] = measured[which] / 3.0          # the "measured" value is 3 times too small
    inv = invert_seed_correction(p.drop_K, p.drop_G, kt_over_kn=c["t"], nc=c["nc"], **measured)
    np.testing.assert_allclose(getattr(inv, f"{which}_K"), c[which], rtol=1e-12)
    np.testing.assert_allclose(getattr(inv, f"{which}_G"), c[which], rtol=1e-12)
    np.testing.assert_allclose(inv.factor_K, 3.0, rtol=1e-12)
    np.testing.assert_allclose(inv.mismatch, 1.0, rtol=1e-12)   # the theory's own drops: one fits both
    np.testing.assert_allclose(inv.ratio_measured, (2 + c["t"]) / 2, rtol=1e-12)


@pytest.mark.slow  # deriving (50)-(51) from scratch takes ~60 s on a loaded 2-core machine
def test_closed_form_equals_sympys_solve_of_50_51():
    import sympy as sp

    from microhom import symbolic as S

    f = S.final_formulas()
    dK, dG = sp.symbols("dK dG")
    rK = sp.solve(sp.Eq(f.drop_K, dK), S.r)[0]
    rG = sp.solve(sp.Eq(f.drop_G, dG), S.r)[0]
    vals = {S.kn: 1.0, S.kt: 0.37, S.Nc: 4.2, S.phi: 0.84, S.Nbar: 5.3, S.rho: 0.41, dK: 0.237, dG: 0.498}
    inv = invert_seed_correction(0.237, 0.498, kt_over_kn=0.37, nc=4.2, r=0.06, nbar=5.3, rho=0.41)
    assert float(inv.r_K) == pytest.approx(float(rK.subs(vals)), rel=1e-12)
    assert float(inv.r_G) == pytest.approx(float(rG.subs(vals)), rel=1e-12)


def test_a_shear_to_bulk_ratio_the_theory_cannot_make_is_a_mismatch():
    # kt = kn: the theory's ratio is exactly 3/2; drops 0.2 and 0.42 (ratio 2.1) need x_G/x_K = 1.4
    inv = invert_seed_correction(0.2, 0.42, kt_over_kn=1.0, nc=4.0, r=0.05, nbar=5.0, rho=0.4)
    assert float(inv.ratio_theory) == 1.5 and float(inv.mismatch) == pytest.approx(1.4, rel=1e-14)
    assert float(inv.x_K) == pytest.approx(0.2, rel=1e-14)     # kt = kn: drop_K = x
    assert float(inv.r_K) == pytest.approx(0.2 * 4.0 / (5.0 * 0.4), rel=1e-14)
    assert float(inv.nbar_G) / float(inv.nbar_K) == pytest.approx(1.4, rel=1e-14)
    assert float(inv.rho_G) / float(inv.rho_K) == pytest.approx(1.4, rel=1e-14)
    # frictionless (t = 0): drops 4/3 x for both, ratio 1
    inv0 = invert_seed_correction(0.3, 0.3, kt_over_kn=0.0, nc=4.0, r=0.05, nbar=5.0, rho=0.4)
    assert float(inv0.mismatch) == pytest.approx(1.0, rel=1e-14) and float(inv0.x_K) == pytest.approx(0.225)
    assert set(inv.as_dict()) >= {"r_K", "r_G", "mismatch"}


@pytest.mark.parametrize("kwargs, name", [(dict(drop_K=1.0), "drop_K"), (dict(drop_G=np.nan), "drop_G"),
                                          (dict(nc=0.0), "nc"), (dict(r=-0.1), "r"), (dict(nbar=0.0), "nbar"),
                                          (dict(kt_over_kn=-1.0), "kt_over_kn"), (dict(rho=np.inf), "rho")])
def test_bad_input_names_the_parameter(kwargs, name):
    args = dict(drop_K=0.2, drop_G=0.3, kt_over_kn=1.0, nc=4.0, r=0.05, nbar=5.0, rho=0.4)
    args.update(kwargs)
    dK, dG = args.pop("drop_K"), args.pop("drop_G")
    with pytest.raises(ValueError, match=rf"^{name}\b"):
        invert_seed_correction(dK, dG, **args)
