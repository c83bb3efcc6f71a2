"""One copy of ``H`` (issue 26): the hierarchy's CG reads ``H`` from the multilevel hierarchy's
level-0 matrix ``A = P H P^T + s I`` (``microhom.shared_h.ShiftedCopy``) in 3D where nothing
else reads the assembly's ``H`` (``_lean``), which is dropped before pyamg's setup.

Checked: the product against ``H`` itself within its stated round-off bound (which the shift, if
not subtracted, exceeds by orders of magnitude), the bound of ``|H| |x|``, the CG's residual
error bound ``E`` against the residual in extended precision, the hierarchy on the shared path
against the former one (the same orders, the intervals to 1e-12), ``H`` freed before pyamg's
setup, and ``M^-1``, ``M^-1/2`` and ``E`` not held on that path.
"""
import gc
import warnings
import weakref

import numpy as np
import pytest
import scipy.sparse as sp

import microhom.hierarchy as hi
from microhom.kinematics import assemble
from microhom.multilevel import amg_preconditioner
from microhom.shared_h import ShiftedCopy
from studies.bench_spheres import fcc_network

U = np.finfo(float).eps
DUAL = dict(spectral_bound="none", dual_bound=True, soft_modes=0, tol=1e-4)


@pytest.fixture(scope="module")
def net():
    return fcc_network(100, keep=0.65, kt=0.5, seed=2)


@pytest.fixture(scope="module")
def shared(net):
    asm = assemble(net, pin=False)
    op, _ = amg_preconditioner(asm)
    ml, order, _ = op.amg
    return asm, ShiftedCopy(ml.levels[0].A, order, op.shift), op.shift


def test_product_within_its_bound(shared):
    asm, S, s = shared
    H = asm.H
    x = np.random.default_rng(0).normal(size=(asm.ndof, 6))
    y = S @ x
    ref = H @ x
    bound = (S.m_row + 3) * U * S.abs_bound(np.abs(x))
    assert np.all(np.abs(y - ref) <= bound)
    # the shift is far above the bound: a product that did not subtract it would fail above
    assert s > 0 and np.mean(np.abs(y + s * x - ref) > bound) > 0.99
    np.testing.assert_allclose(S @ x[:, 0], y[:, 0], rtol=0, atol=0)     # vectors as columns
    assert S.T is S and S.shape == H.shape


def test_abs_bound_covers_abs_h(shared):
    asm, S, s = shared
    x = np.abs(np.random.default_rng(1).normal(size=(asm.ndof, 3)))
    absH = abs(asm.H) @ x
    assert np.all(S.abs_bound(x) >= absH + s * x * (1 - 1e-12))


def test_csr_and_bad_input(shared):
    asm, S, s = shared
    A = S.A.tocsr()
    C = ShiftedCopy(A, S.order, s)
    x = np.random.default_rng(2).normal(size=asm.ndof)
    np.testing.assert_allclose(C @ x, asm.H @ x, rtol=1e-12, atol=1e-12 * np.abs(asm.H).max())
    with pytest.raises(ValueError, match="float64 BSR"):
        ShiftedCopy(S.A.astype(np.float32), S.order, s)
    with pytest.raises(ValueError, match="shift"):
        ShiftedCopy(S.A, S.order, -1.0)
    with pytest.raises(ValueError, match="order"):
        ShiftedCopy(S.A, S.order[:-1], s)
    with pytest.raises(ValueError, match="rows"):
        S @ np.ones(3)


def test_residual_error_bound_in_extended_precision(shared):
    """``_roundoff``'s ``E`` bounds ``|fl(B - H X) - (B - H X)|`` computed through the copy, the
    exact residual taken in long double from the dense ``H``."""
    asm, S, s = shared
    rng = np.random.default_rng(3)
    cg = hi._BlockPCG(S, sp.identity(asm.ndof, format="csr"), sp.identity(asm.ndof, format="csr"), -asm.F,
                      full=False)
    cg.X = rng.normal(size=cg.B.shape) * 1e3
    cg.Rt = cg.B - S @ cg.X
    hi._roundoff(cg)
    Hd = asm.H.toarray().astype(np.longdouble)
    exact = cg.B.astype(np.longdouble) - Hd @ cg.X.astype(np.longdouble)
    err = np.abs(cg.Rt.astype(np.longdouble) - exact)
    assert np.all(err <= cg.E)
    assert cg.m_row == S.m_row + 3


def _hier(net, monkeypatch, share, probe=None):
    monkeypatch.setattr(hi, "SHARE_H", share)
    if probe is not None:
        real = hi._cg_step

        def step(run, *a, **k):
            probe(run)
            return real(run, *a, **k)
        monkeypatch.setattr(hi, "_cg_step", step)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = hi.relaxation_hierarchy(net, **DUAL)
    monkeypatch.undo()
    return h


def _sliding(net, frac=0.4, seed=3):
    return net.with_stiffness(sliding=np.random.default_rng(seed).random(net.n_contacts) < frac)


@pytest.mark.parametrize("sliding", [False, True])
def test_hierarchy_on_the_shared_copy(net, monkeypatch, sliding):
    """The shared path against the former one; with sliding contacts too (particles without
    rotational unknowns where all their contacts slide: the copy may be in 1 x 1 blocks)."""
    net = _sliding(net) if sliding else net
    seen = {}

    def probe(run):
        seen.update(H=run.asm.H, shared=run.H_shared, Minv=run.Minv, Msq=run.Msq, blocks=run.blocks,
                    lean=run.lean)
    a = _hier(net, monkeypatch, True, probe)
    assert seen["H"] is None and isinstance(seen["shared"], ShiftedCopy) and seen["lean"]
    assert seen["shared"].A.blocksize == ((1, 1) if sliding else (6, 6))
    assert seen["Minv"] is None and seen["Msq"] is None and seen["blocks"][1:3] == (None, None)
    b = _hier(net, monkeypatch, False)
    assert a.certified and b.certified and a.order == b.order
    # the CG's trajectory differs by round-off (measured: 1e-14 per order without sliding contacts,
    # up to 1.4e-10 at the middle orders with them); the lower bounds carry the dual bound's cancellation
    for f, rtol in (("K_orders", 1e-9), ("G_orders", 1e-9), ("K_lower_orders", 1e-8), ("G_lower_orders", 1e-8)):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=rtol, err_msg=f)
    for e, f in ((a.K, b.K), (a.G, b.G)):
        assert e.lower == pytest.approx(f.lower, rel=1e-8) and e.upper == pytest.approx(f.upper, rel=1e-10)
    # the intervals are both rigorous: each holds the other's midpoint region
    assert a.K.lower <= b.K.upper and b.K.lower <= a.K.upper
    np.testing.assert_array_equal(a.C_first_order, b.C_first_order)       # M^-1 used before it is dropped


def test_h_freed_before_pyamg(net, monkeypatch):
    """The assembly's ``H`` is garbage by the time pyamg's setup starts (its transient is the
    run's peak), not only after it."""
    import pyamg
    real = pyamg.smoothed_aggregation_solver
    refs, alive = [], []
    real_assemble = hi.assemble

    def assemble_(*a, **k):
        asm = real_assemble(*a, **k)
        refs.append(weakref.ref(asm.H.data))
        return asm

    def sa(*a, **k):
        gc.collect()
        alive.append(refs[0]() is not None)
        return real(*a, **k)
    monkeypatch.setattr(hi, "assemble", assemble_)
    monkeypatch.setattr(pyamg, "smoothed_aggregation_solver", sa)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = hi.relaxation_hierarchy(net, **DUAL)
    assert alive == [False] and h.certified
    monkeypatch.setattr(hi, "SHARE_H", False)
    refs.clear(), alive.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hi.relaxation_hierarchy(net, **DUAL)
    assert alive == [True]                   # the former path holds it (the check can fail)


def test_not_lean_where_h_is_read_later(net, monkeypatch):
    """A soft-mode search, a spectral bound of the pencil or a user's bound read ``H`` or ``M^-1``
    after the setup: the assembly keeps them."""
    for kw in (dict(soft_modes=3), dict(spectral_bound=0.01), dict(spectral_bound="auto", dense_max=10_000)):
        seen = {}
        monkeypatch.setattr(hi, "_cg_step", lambda run, *a, _r=hi._cg_step, **k: (
            seen.update(H=run.asm.H, Minv=run.Minv, lean=run.lean), _r(run, *a, **k))[1])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            hi.relaxation_hierarchy(net, **{**DUAL, "preconditioner": "amg", **kw})
        monkeypatch.undo()
        assert not seen["lean"] and seen["H"] is not None and seen["Minv"] is not None, kw


def test_bench_wrappers_hold_no_h(net, monkeypatch):
    """``studies.bench_spheres``' phase wrapper (``--phases``) and ``--amg`` wrapper keep no
    reference to the assembly through pyamg's setup, so the phases measure the dropped ``H``;
    ``--amg`` passes its options (the smoother reaches pyamg)."""
    import pyamg
    from studies import bench_spheres
    real = pyamg.smoothed_aggregation_solver
    refs, alive = [], []
    real_assemble = hi.assemble

    def assemble_(*a, **k):
        asm = real_assemble(*a, **k)
        refs.append(weakref.ref(asm.H.data))
        return asm

    def sa(*a, **k):
        gc.collect()
        alive.append((refs[-1]() is not None, k["smooth"][0] if k.get("smooth") else None))
        return real(*a, **k)
    monkeypatch.setattr(hi, "assemble", assemble_)
    monkeypatch.setattr(pyamg, "smoothed_aggregation_solver", sa)
    undo = bench_spheres._hierarchy_amg(bench_spheres.SETUP_OPTIONS["jacobi+rigid"])
    restore = bench_spheres.instrument_phases()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            h = hi.relaxation_hierarchy(net, **DUAL)
    finally:
        restore()
        undo()
    assert alive == [(False, "jacobi")] and h.certified


@pytest.mark.parametrize("full", [False, True])
def test_last_block_spans_the_last_step(full):
    """``_BlockPCG.last_block``: ``X_k - X_{k-1}`` lies in the span of the last search block, at
    every step (least squares residual at round-off); a block of another step does not hold it."""
    asm = assemble(fcc_network(100, keep=0.65, kt=0.5, seed=4), prestress=False, pin=False)
    M, Minv = hi.block_preconditioner(asm)[:2]
    cg = hi._BlockPCG(asm.H, M, Minv, -asm.F, full=full, true_residual=True)
    assert cg.last_block() is None
    blocks, steps = [], []
    for _ in range(5):
        prev = cg.X.copy()
        cg.step()
        blocks.append(cg.last_block().copy())
        steps.append(cg.X - prev)
    for k, (Pk, dX) in enumerate(zip(blocks, steps)):
        for Q, own in ((Pk, True), (blocks[k - 1], False)):
            coef = np.linalg.lstsq(Q, dX, rcond=None)[0]
            rel = np.linalg.norm(Q @ coef - dX) / np.linalg.norm(dX)
            assert (rel < 1e-10) if own else (rel > 1e-3 or k == 0), (k, own, rel)


def test_lean_path_trial_is_the_last_block(net, monkeypatch):
    """On the shared (lean) path the dual bound's trial is ``[Z, P_k]`` (the next preconditioned
    residual and the last search block, views of the CG's own arrays: no copy of ``X``), the CG
    iterates on its true residual, and the interval is certified around the exact moduli."""
    from dem.analysis.stiffness import stiffness
    seen = []
    real = hi.dual_lower_bound

    def spy(asm, X, volume, eq, **k):
        seen.append(k["trial"])
        return real(asm, X, volume, eq, **k)
    cgs = []
    real_cg = hi._BlockPCG

    def make(*a, **k):
        cgs.append(real_cg(*a, **k))
        return cgs[-1]
    monkeypatch.setattr(hi, "dual_lower_bound", spy)
    monkeypatch.setattr(hi, "_BlockPCG", make)
    h = _hier(net, monkeypatch, True)
    cg = cgs[-1]
    assert cg.true_residual and cg.R is cg.Rt
    assert seen and all(len(t) == 2 and t[0].shape[1] == 6 and 0 < t[1].shape[1] <= 6 for t in seen)
    assert seen[-1][0] is cg.Z and np.shares_memory(seen[-1][1], cg._chunks[-1][0])
    ex = stiffness(net)
    assert h.certified
    for e, x in ((h.K, ex.K), (h.G, ex.G)):
        assert e.lower <= x * (1 + 1e-12) and x <= e.upper * (1 + 1e-12)
