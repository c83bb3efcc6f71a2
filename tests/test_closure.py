"""The statistics-only closure: its stated error holds on held-out packings, flags, bad input."""
import numpy as np
import pytest

from microhom.closure import ERROR, RANGES, predict_closure

# held-out packings (N = 3000, studies.bench_hierarchy cases, not in the fit): measured statistics
# and the exact moduli from dem.stiffness (no pre-stress), kn = 1
HELD_OUT = [  # nc, r, phi, kt/kn, dispersity, exact K, exact G
    (4.0407, 0.0630, 0.8530, 1.0, 0.0, 0.4240, 0.2804),
    (3.2209, 0.0638, 0.8050, 0.25, 0.2, 0.2307, 0.04022),
    (4.5245, 0.0330, 0.8630, 0.5, 0.2, 0.5560, 0.3806),
]


@pytest.mark.parametrize("nc, r, phi, kt, disp, K, G", HELD_OUT)
def test_held_out_packings_within_a_few_stated_errors(nc, r, phi, kt, disp, K, G):
    p = predict_closure(nc=nc, r=r, phi=phi, kt_over_kn=kt, dispersity=disp)
    assert bool(p.valid), p.reason
    assert abs(float(p.K) / K - 1) <= 3 * ERROR["K"]
    assert abs(float(p.G) / G - 1) <= 3 * ERROR["G"]
    assert float(p.error_K) == pytest.approx(ERROR["K"] * float(p.K))
    # and much closer than the mean field at the same statistics
    assert abs(float(p.G) / G - 1) < 0.5 * abs(float(p.G_mf) / G - 1)


def test_flags():
    p = predict_closure(nc=np.array([3.05, 4.0, 4.0, 4.0, 6.0]), r=np.array([0.05, 0.05, 0.2, 0.05, 0.05]),
                        kt_over_kn=np.array([0.5, 0.5, 0.5, 0.0, 0.5]))
    assert list(p.valid) == [False, True, False, False, False]
    assert "near isostatic" in p.reason[0]
    assert "outside the fitted range" in p.reason[2] and "outside the fitted range" in p.reason[4]
    assert "frictionless" in p.reason[3]
    assert np.all(np.isfinite(p.K)) and np.all(np.isfinite(p.G))
    assert RANGES["dz"][0] > 0


@pytest.mark.parametrize("kwargs, name", [(dict(nc=-1.0), "nc"), (dict(r=-0.1), "r"), (dict(phi=1.2), "phi"),
                                          (dict(kt_over_kn=np.nan), "kt_over_kn"), (dict(kn=0.0), "kn")])
def test_bad_input(kwargs, name):
    args = dict(nc=4.0, r=0.05)
    args.update(kwargs)
    with pytest.raises(ValueError, match=rf"^{name}\b"):
        predict_closure(**args)


def test_vectorised_and_json_ready():
    import json
    rng = np.random.default_rng(0)
    n = 100_000
    p = predict_closure(nc=rng.uniform(3.3, 5.3, n), r=rng.uniform(0.02, 0.06, n), kt_over_kn=rng.uniform(0.1, 1, n))
    assert p.K.shape == (n,) and p.valid.all()
    one = predict_closure(nc=4.2, r=0.04)
    json.dumps(one.as_dict())
