"""A correction of the CG iterate before the dual bound's statics (microhom.dual_bound ``coarse=``,
microhom.multilevel.coarse_correction, microhom.hierarchy._dual_correction; docs/theory.md
section 12, "A correction before the statics") and the best field in a span of trial relaxations
(``trial=``, "The best field in a small subspace"; on in the hierarchy).

Rigour is checked against the exact sparse solver (dem.analysis.stiffness), whatever the
correction (also a random one and a wrong coarse operator); the gain against the plain bound on
the same iterate; the Galerkin property of the coarse correction against pyamg's own prolongator."""
import warnings

import numpy as np
import pytest
import sympy as sp

import microhom.hierarchy as hi
from dem.analysis.stiffness import stiffness
from microhom.dual_bound import build_equilibrator, dual_lower_bound
from microhom.hierarchy import _BlockPCG, _iso, block_preconditioner, relaxation_hierarchy
from microhom.kinematics import assemble
from microhom.multilevel import amg_preconditioner, coarse_correction
from studies.bench_spheres import fcc_network
from studies.bench_stiffness import diluted_triangular

NETS = {"2D": diluted_triangular(300, z=4.6, kt=0.5, seed=1), "3D": fcc_network(100, keep=0.65, kt=0.5, seed=2)}


def _iterate(asm, P, steps):
    """The multilevel block CG's iterate after ``steps`` orders (as the hierarchy runs it)."""
    M, Minv = block_preconditioner(asm)[:2]
    cg = _BlockPCG(asm.H, M, P, -asm.F, full=True)
    for _ in range(steps):
        cg.step()
    return cg.X


def _poor_corrections(asm, P, rng):
    """Corrections of any quality: the V-cycle steps, the Galerkin coarse correction, that with a
    wrong coarse operator (a random symmetric positive definite one), random and huge ones."""
    ml, order, inv = P.amg
    Pr = ml.levels[0].P.toarray()
    W = rng.normal(size=(Pr.shape[1], Pr.shape[1]))
    Ac_wrong = W @ W.T + np.eye(Pr.shape[1])

    def wrong(r):
        y = np.zeros_like(r)
        y[order] = Pr @ np.linalg.solve(Ac_wrong, Pr.T @ r[order])
        return y
    return {"vcycles": hi._dual_correction(asm.H, P, steps=2), "galerkin": coarse_correction(P), "wrong A_c": wrong,
            "random": lambda r: rng.normal(size=r.shape) * np.abs(r).max(),
            "huge": lambda r: 1e3 * rng.normal(size=r.shape)}


@pytest.mark.parametrize("name", list(NETS))
def test_bound_rigorous_whatever_the_correction(name):
    """With every correction, good or deliberately poor, the bound stays below the exact tensor in
    the Loewner order (and valid: the statics balances what is left)."""
    net = NETS[name]
    ex = stiffness(net)
    asm = assemble(net, prestress=False, pin=False)
    eq = build_equilibrator(asm)
    P, _ = amg_preconditioner(asm)
    rng = np.random.default_rng(7)
    for steps in (2,):
        X = _iterate(asm, P, steps)
        for label, corr in _poor_corrections(asm, P, rng).items():
            b = dual_lower_bound(asm, X, net.volume, eq, coarse=corr)
            assert b.valid, label
            w = np.linalg.eigvalsh(ex.C_mandel - b.C_lower)
            assert w.min() >= -1e-10 * np.abs(ex.C_mandel).max(), (label, steps, w.min())
            assert b.K_lower <= ex.K * (1 + 1e-12) and b.G_lower <= ex.G * (1 + 1e-12), label
        r = -asm.F - asm.H @ X
        for label, W in (("Z", P @ r), ("Z, X", np.hstack([P @ r, X])), ("random", rng.normal(size=(asm.ndof, 4))),
                         ("exact", np.linalg.lstsq(asm.H.toarray(), r, rcond=None)[0])):
            b = dual_lower_bound(asm, X, net.volume, eq, trial=W)
            assert b.valid, label
            w = np.linalg.eigvalsh(ex.C_mandel - b.C_lower)
            assert w.min() >= -1e-10 * np.abs(ex.C_mandel).max(), (label, steps, w.min())
            if label == "exact":      # the exact relaxation's step is in the span: the bound is tight
                assert abs(b.K_lower - ex.K) <= 1e-6 * ex.K and abs(b.G_lower - ex.G) <= 1e-6 * ex.G


def test_best_coefficients_sympy():
    """L(beta) = L0 + b^T beta + beta^T b - beta^T S beta (the dual bound of G0 + Phi beta, with
    b = Phi^T (D - K^+ G0), S = Phi^T K^+ Phi) equals L(beta*) - (beta - beta*)^T S (beta - beta*)
    with beta* = S^-1 b: beta* is the best in the Loewner order (sympy, 3 contact components,
    2 trial fields, 2 strain columns)."""
    Kp = sp.Matrix(3, 3, lambda i, j: sp.Symbol(f"k{min(i, j)}{max(i, j)}", real=True))
    Dm = sp.Matrix(3, 2, lambda i, j: sp.Symbol(f"d{i}{j}", real=True))
    G0 = sp.Matrix(3, 2, lambda i, j: sp.Symbol(f"g{i}{j}", real=True))
    Phi = sp.Matrix(3, 2, lambda i, j: sp.Symbol(f"p{i}{j}", real=True))
    beta = sp.Matrix(2, 2, lambda i, j: sp.Symbol(f"b{i}{j}", real=True))

    def L(G):
        return G.T * Dm + Dm.T * G - G.T * Kp * G
    S = Phi.T * Kp * Phi
    b = Phi.T * (Dm - Kp * G0)
    assert (L(G0 + Phi * beta) - (L(G0) + b.T * beta + beta.T * b - beta.T * S * beta)).expand() == sp.zeros(2, 2)
    # completing the square, for a generic symmetric S and b (the quadratic above in beta)
    Sg = sp.Matrix(2, 2, lambda i, j: sp.Symbol(f"s{min(i, j)}{max(i, j)}", real=True))
    bg = sp.Matrix(2, 2, lambda i, j: sp.Symbol(f"c{i}{j}", real=True))
    star = Sg.inv() * bg

    def q(x):
        return bg.T * x + x.T * bg - x.T * Sg * x
    assert sp.simplify(q(beta) - (q(star) - (beta - star).T * Sg * (beta - star))) == sp.zeros(2, 2)


def test_coarse_correction_is_galerkin():
    """``y = coarse_correction(P)(r)`` lies in the range of pyamg's prolongator and makes the
    residual orthogonal to it (``P^T (r - H y) = 0`` to 1e-5 of ``P^T r``: the coarse operator has
    the near-translations of the 1e-10 shift; the energy minimum over the coarse space),
    checked with the prolongator and ``H`` themselves (dense), not with the coarse solver."""
    net = NETS["3D"]
    asm = assemble(net, prestress=False, pin=False)
    P, _ = amg_preconditioner(asm)
    ml, order, inv = P.amg
    Pr = ml.levels[0].P.toarray()
    corr = coarse_correction(P, rtol=1e-12, maxiter=500)
    r = np.random.default_rng(3).normal(size=(asm.ndof, 2))
    y = corr(r)
    Hs = ml.levels[0].A.toarray()           # the shifted, permuted H of the hierarchy
    z = np.linalg.lstsq(Pr, y[order], rcond=None)[0]
    np.testing.assert_allclose(Pr @ z, y[order], atol=1e-9 * np.abs(y).max())
    g = Pr.T @ (r[order] - Hs @ y[order])
    assert np.abs(g).max() <= 1e-5 * np.abs(Pr.T @ r[order]).max()      # y = 0 would give 1
    assert np.allclose(corr(r[:, 0]), y[:, 0])


def test_bad_arguments():
    net = NETS["2D"]
    asm = assemble(net, prestress=False, pin=False)
    X = np.zeros((asm.ndof, 3))
    with pytest.raises(ValueError, match="coarse"):
        dual_lower_bound(asm, X, net.volume, coarse=lambda r: r[:, :1])
    with pytest.raises(ValueError, match="non-finite"):
        dual_lower_bound(asm, X, net.volume, coarse=lambda r: r * np.nan)
    with pytest.raises(ValueError, match="coarse must be"):
        dual_lower_bound(asm, X, net.volume, coarse=3)
    P, _ = amg_preconditioner(asm)
    with pytest.raises(ValueError, match="rtol"):
        coarse_correction(P, rtol=0.0)
    with pytest.raises(ValueError, match="maxiter"):
        coarse_correction(P, maxiter=0)
    with pytest.raises(ValueError, match="amg_preconditioner"):
        coarse_correction(block_preconditioner(asm)[1])


def test_correction_shrinks_the_gap_on_2000_spheres():
    """On 2048 spheres, at the CG orders where the plain gap is below the modulus, the width
    ``C(X) - C_dual`` with two V-cycle steps before the statics is at least 3 times smaller than
    without (K and G), the best field in the span of the next preconditioned residual and the last
    step at least 10 times; the Galerkin coarse correction alone shrinks it too. Fails if any were
    a no-op."""
    net = fcc_network(2000, keep=0.6, kt=0.5)
    asm = assemble(net, prestress=False, pin=False)
    eq = build_equilibrator(asm)
    P, _ = amg_preconditioner(asm)
    M, Minv = block_preconditioner(asm)[:2]
    cg = _BlockPCG(asm.H, M, P, -asm.F, full=True)
    V = net.volume
    seen = 0
    prev = 0.0
    for order in range(1, 12):
        cg.step()
        up = np.array(_iso(hi._tensor(hi._affine_kept(asm, V), cg.Rk, V, 0.0)))
        widths = {}
        trial = np.hstack([cg.Z, cg.X - prev])
        prev = cg.X.copy()
        for label, kw in (("plain", {}), ("vcycles", dict(coarse=hi._dual_correction(asm.H, P, steps=2))),
                          ("galerkin", dict(coarse=coarse_correction(P))), ("span", dict(trial=trial))):
            b = dual_lower_bound(asm, cg.X, V, eq, **kw)
            assert b.valid
            widths[label] = up - np.array([b.K_lower, b.G_lower])
        if np.all(widths["plain"] < np.abs(up)):
            seen += 1
            assert np.all(widths["vcycles"] * 3 < widths["plain"]), (order, widths)
            assert np.all(widths["galerkin"] < widths["plain"]), (order, widths)
            assert np.all(widths["span"] * 10 < widths["plain"]), (order, widths)
        if seen == 3:
            break
    assert seen == 3


def test_hierarchy_uses_the_trial_span_and_certifies():
    """The hierarchy (multilevel CG, dual bound) passes the span of its next preconditioned residual
    and last step to the bound (and no V-cycle correction by default), and its certified interval
    holds the exact moduli; with it off (``DUAL_TRIAL`` False) the same upper bounds order by
    order, and no fewer orders."""
    net = fcc_network(500, keep=0.6, kt=0.5, seed=1)
    ex = stiffness(net)
    seen = []
    real = hi.dual_lower_bound

    def spy(*a, **k):
        seen.append((k.get("trial"), k.get("coarse")))
        return real(*a, **k)
    with warnings.catch_warnings(), pytest.MonkeyPatch.context() as mp:
        warnings.simplefilter("ignore")
        mp.setattr(hi, "dual_lower_bound", spy)
        h = relaxation_hierarchy(net, spectral_bound="none", dual_bound=True, soft_modes=0, tol=1e-4)
        assert seen and all(t is not None and sum(w.shape[1] for w in t) == 12 and c is None for t, c in seen)
        mp.setattr(hi, "DUAL_TRIAL", False)
        off = relaxation_hierarchy(net, spectral_bound="none", dual_bound=True, soft_modes=0, tol=1e-4)
    assert h.certified and off.certified
    for e, x in ((h.K, ex.K), (h.G, ex.G)):
        assert e.lower <= x * (1 + 1e-12) and x <= e.upper * (1 + 1e-12)
    assert h.order <= off.order
    k = min(h.order, off.order)
    np.testing.assert_array_equal(h.K_orders[:k + 1], off.K_orders[:k + 1])


@pytest.mark.parametrize("name", list(NETS))
def test_trial_blocks_give_the_stacked_trial_bit_for_bit(name):
    """``trial`` as a list of blocks (the hierarchy's ``[Z, X_k - X_{k-1}]``, not stacked to save a
    copy) gives the same bound as the stacked array, to the last bit; a bad block is refused by name."""
    net = NETS[name]
    asm = assemble(net, prestress=False, pin=False)
    eq = build_equilibrator(asm)
    rng = np.random.default_rng(3)
    X = rng.normal(size=(asm.ndof, asm.Df.shape[1]))
    Z, D = rng.normal(size=(asm.ndof, asm.Df.shape[1])), rng.normal(size=(asm.ndof, 2))
    a = dual_lower_bound(asm, X, net.volume, eq, trial=np.hstack([Z, D]))
    b = dual_lower_bound(asm, X, net.volume, eq, trial=[Z, D])
    assert np.array_equal(a.C_lower, b.C_lower) and a.margin == b.margin
    c = dual_lower_bound(asm, X, net.volume, eq)
    assert not np.array_equal(a.C_lower, c.C_lower)          # the trial did act
    with pytest.raises(ValueError, match="trial"):
        dual_lower_bound(asm, X, net.volume, eq, trial=[Z, np.full((asm.ndof, 1), np.nan)])
