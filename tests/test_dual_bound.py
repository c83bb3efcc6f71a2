"""The complementary-energy (dual) lower bound (microhom.dual_bound; docs/theory.md section 12).

Checked against what it does not use: sympy for the inequality and the gap identity, the exact
sparse solver (dem.analysis.stiffness) for the moduli, and the assembly's own ``B^T`` for the
equilibrium of the corrected field."""
import warnings

import numpy as np
import pytest
import sympy as sp

from dem.analysis.stiffness import stiffness
from microhom.dual_bound import build_equilibrator, dual_lower_bound
from microhom.hierarchy import relaxation_hierarchy
from microhom.kinematics import assemble
from microhom.network import ContactNetwork
from studies.bench_spheres import fcc_network
from studies.bench_stiffness import diluted_triangular


def test_fenchel_inequality_and_gap_identity_sympy():
    """1/2 d.K.d - (f.d - 1/2 f.K^-1.f) = 1/2 (d - K^-1 f).K.(d - K^-1 f) >= 0, and with
    f = K d + c the dual value is 1/2 d.K.d - 1/2 c.K^-1.c (the gap is quadratic in c)."""
    a, b, c_ = sp.symbols("a b c", real=True)
    K = sp.Matrix([[a, b], [b, c_]])
    d = sp.Matrix(sp.symbols("d1 d2", real=True))
    f = sp.Matrix(sp.symbols("f1 f2", real=True))
    Ki = K.inv()
    primal = (d.T * K * d)[0] / 2
    dual = (f.T * d)[0] - (f.T * Ki * f)[0] / 2
    sq = ((d - Ki * f).T * K * (d - Ki * f))[0] / 2
    assert sp.simplify(primal - dual - sq) == 0
    cc = sp.Matrix(sp.symbols("c1 c2", real=True))
    fd = K * d + cc
    dual_c = (fd.T * d)[0] - (fd.T * Ki * fd)[0] / 2
    assert sp.simplify(dual_c - (primal - (cc.T * Ki * cc)[0] / 2)) == 0


def _with_sliding(net, frac=0.15, seed=3):
    rng = np.random.default_rng(seed)
    return net.with_stiffness(sliding=rng.random(net.n_contacts) < frac)


def _networks():
    tri = diluted_triangular(300, z=4.6, kt=0.5, seed=1)
    fcc = fcc_network(100, keep=0.65, kt=0.5, seed=2)
    loose = fcc_network(100, keep=0.4, kt=0.5, seed=4)       # rattlers
    return {"2D": tri, "2D sliding": _with_sliding(tri), "3D": fcc, "3D sliding": _with_sliding(fcc),
            "3D rattlers": loose}


NETS = _networks()


@pytest.mark.parametrize("name", list(NETS))
def test_corrected_field_is_in_equilibrium(name):
    """B^T c = r to round-off for loads r in the range of B^T, and each c_c in the range of K_c
    (along the normal on sliding contacts)."""
    asm = assemble(NETS[name], pin=False)
    eq = build_equilibrator(asm)
    g = np.random.default_rng(0).normal(size=(asm.Bs.shape[0], 4))
    r = np.asarray(asm.Bs.T @ g)
    c = eq.correct(r)
    res = np.asarray(asm.Bs.T @ c.reshape(-1, 4)) - r
    assert np.abs(res).max() <= 1e-11 * np.abs(r).max()
    slide = asm.net.effective_kt == 0
    n = asm.net.normals
    tang = c - np.einsum("cx,cxs->cs", n, c)[:, None, :] * n[:, :, None]
    assert np.abs(tang[slide]).max(initial=0.0) <= 1e-14 * np.abs(c).max()
    if "rattlers" in name:
        assert asm.rattlers.any()
    if "sliding" in name:
        assert slide.any()


def _exact_X(asm):
    H = asm.H.toarray()
    return np.linalg.lstsq(H, -asm.F, rcond=None)[0]


@pytest.mark.parametrize("name", list(NETS))
def test_bound_below_exact_and_tight(name):
    """Below the exact solver's K and G for any trial X; within 1e-6 of them when X solves the
    relaxation (the CG residual is small)."""
    net = NETS[name]
    ex = stiffness(net)
    asm = assemble(net, pin=False)
    eq = build_equilibrator(asm)
    X = _exact_X(asm)
    rng = np.random.default_rng(5)
    for pert in (0.0, 1e-4, 1e-2, 0.3):
        Xp = X * (1 + pert * rng.normal(size=X.shape))
        b = dual_lower_bound(asm, Xp, net.volume, eq)
        assert b.valid
        assert b.K_lower <= ex.K * (1 + 1e-12) and b.G_lower <= ex.G * (1 + 1e-12), (pert, b.K_lower, ex.K)
        w = np.linalg.eigvalsh(ex.C_mandel - b.C_lower)
        assert w.min() >= -1e-10 * np.abs(ex.C_mandel).max()
        if pert == 0.0:
            assert abs(b.K_lower - ex.K) <= 1e-6 * ex.K and abs(b.G_lower - ex.G) <= 1e-6 * ex.G
            assert b.residual <= 1e-11


def test_prestressed_network_refused():
    net = fcc_network(250, keep=0.6, kt=0.5, seed=2)
    asm = assemble(net, prestress=True, pin=False)
    with pytest.raises(ValueError, match="pre-stressed"):
        dual_lower_bound(asm, np.zeros((asm.ndof, 6)), net.volume)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = relaxation_hierarchy(net, prestress=True, spectral_bound="none", dual_bound=True, soft_modes=0,
                                 max_order=2)
    assert any("dual lower bound not used" in r and "pre-stressed" in r for r in h.reasons)


@pytest.mark.parametrize("name", ["2D", "3D"])
def test_hierarchy_certified_by_the_dual_bound(name):
    """Without any spectral bound the hierarchy's rigorous interval holds the exact moduli."""
    net = NETS[name]
    ex = stiffness(net)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = relaxation_hierarchy(net, spectral_bound="none", dual_bound=True, soft_modes=0)
    assert h.spectral_bound_source == "dual"
    assert h.certified
    for e, x in ((h.K, ex.K), (h.G, ex.G)):
        assert e.lower <= x * (1 + 1e-12) and x <= e.upper * (1 + 1e-12)
        assert e.upper - e.lower <= 0.01 * e.upper


def test_bad_arguments():
    net = NETS["2D"]
    asm = assemble(net, pin=False)
    with pytest.raises(ValueError, match="volume"):
        dual_lower_bound(asm, np.zeros((asm.ndof, 3)), -1.0)
    with pytest.raises(ValueError, match="X must have shape"):
        dual_lower_bound(asm, np.zeros((3, 3)), net.volume)
    with pytest.raises(ValueError, match="dual_bound"):
        relaxation_hierarchy(net, dual_bound="yes")
    assert isinstance(net, ContactNetwork)


@pytest.mark.parametrize("name", ["2D sliding", "3D"])
def test_dual_bound_evaluated_only_when_due(name, monkeypatch):
    """The hierarchy evaluates the dual bound at fewer orders than it runs (the skipped ones keep
    the last evaluated bound, ``_dual_due``) and still certifies an interval that holds the exact
    moduli; forcing an evaluation at every order (``_DUAL_DUE`` infinite) gives the same orders'
    upper bounds, and at every order one of the every-order run's lower bounds so far."""
    import microhom.hierarchy as hi
    net = NETS[name]
    ex = stiffness(net)
    calls = []
    real = hi.dual_lower_bound

    def counting(*a, **k):
        calls.append(1)
        return real(*a, **k)
    monkeypatch.setattr(hi, "dual_lower_bound", counting)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = relaxation_hierarchy(net, spectral_bound="none", dual_bound=True, soft_modes=0, tol=1e-6)
        n_skip = len(calls)
        monkeypatch.setattr(hi, "_DUAL_DUE", np.inf)
        calls.clear()
        every = relaxation_hierarchy(net, spectral_bound="none", dual_bound=True, soft_modes=0, tol=1e-6)
    assert h.certified and every.certified
    assert len(calls) == every.order and n_skip < h.order        # orders were skipped
    for e, x in ((h.K, ex.K), (h.G, ex.G)):
        assert e.lower <= x * (1 + 1e-12) and x <= e.upper * (1 + 1e-12)
        assert e.upper - e.lower <= 1e-6 * e.upper
    k = min(h.order, every.order)
    np.testing.assert_array_equal(h.K_orders[:k + 1], every.K_orders[:k + 1])
    for j in range(1, k + 1):     # a skipped order keeps an earlier order's bound, bit for bit
        assert h.K_lower_orders[j] in every.K_lower_orders[1:j + 1]
        assert h.G_lower_orders[j] in every.G_lower_orders[1:j + 1]
