"""The multilevel setup's one-pass blocked copy of ``H`` (issue 26, ``microhom.multilevel.blocked_copy``)
and the CG's round-off margin without a copy of ``|H|`` (``microhom.hierarchy._abs_times``): the
same arrays and the same V-cycle, bit for bit, as the former CSR copies, in 2D and 3D, float64 and
float32, uniform and mixed particle blocks; int32 indices; bad input refused by name."""
import numpy as np
import pytest
import scipy.sparse as sp

import microhom.multilevel as ml
from microhom import lattices
from microhom.hierarchy import _abs_times
from microhom.kinematics import assemble
from microhom.network import from_overlaps, from_pairs
from tests.test_hierarchy_3d import packing


def _disks(kt=0.5, seed=3):
    lat = lattices.triangular(12, 12)
    rng = np.random.default_rng(seed)
    return from_overlaps(lat.positions * 0.97 + rng.normal(scale=0.01, size=lat.positions.shape),
                         np.full(lat.n_particles, 0.5), lat.cell * 0.97, kn=1.0, kt=kt, tolerance=0.0)


def _mixed():
    """Disks where particles 0..39 have only frictionless contacts (no spin): blocks of 2 and 3."""
    net = _disks()
    kt = np.full(net.n_contacts, 0.5)
    kt[np.any(net.pairs < 40, axis=1)] = 0.0
    return from_pairs(net.positions, net.radii, net.cell, net.pairs, shifts=net.image_shifts(), kn=1.0, kt=kt)


NETS = {"2d": lambda: _disks(), "2d frictionless": lambda: _disks(kt=0.0), "2d mixed": _mixed,
        "3d": lambda: packing(5, n=3, kt=0.5, keep=0.7), "3d frictionless": lambda: packing(5, n=3, kt=0.0, keep=0.9)}


def _layout(asm):
    part, comp = ml.dof_layout(asm)
    order = np.lexsort((comp, part))
    counts = np.bincount(part)[np.unique(part)]
    bs = int(counts[0]) if np.all(counts == counts[0]) else 1
    return order, bs


def _former_copy(asm, order, bs, dtype):
    """The former path of amg_preconditioner: three CSR copies, then tobsr."""
    H = asm.H.tocsr()[order][:, order]
    H = (H + ml._SHIFT * float(H.diagonal().mean()) * sp.identity(asm.ndof, format="csr")).tocsr()
    if dtype != H.dtype:
        H = H.astype(dtype)
    return H.tobsr(blocksize=(bs, bs)) if bs > 1 else H


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("name", list(NETS))
def test_blocked_copy_is_the_former_copy_array_for_array(name, dtype):
    asm = assemble(NETS[name](), pin=False)
    order, bs = _layout(asm)
    if name == "2d mixed":
        assert bs == 1
    old = _former_copy(asm, order, bs, dtype)
    # the block order: the former path's, which amg_preconditioner reproduces
    Hc = sp.csc_matrix(asm.H)
    inv = np.empty_like(order)
    inv[order] = np.arange(asm.ndof)
    sort = dtype == np.float32 or ml._permuted_sorted(Hc.indptr, Hc.indices, inv)
    new = ml.blocked_copy(asm.H, order, bs, ml._SHIFT * float(asm.H.diagonal()[order].mean()), dtype, sort=sort)
    assert type(new) is type(old) and new.dtype == old.dtype
    assert new.indices.dtype == np.int32 and new.indptr.dtype == np.int32
    assert np.array_equal(new.indptr, old.indptr) and np.array_equal(new.indices, old.indices)
    assert np.array_equal(new.data, old.data)
    # sorted or not, the same matrix
    other = ml.blocked_copy(asm.H, order, bs, ml._SHIFT * float(asm.H.diagonal()[order].mean()), dtype,
                            sort=not sort)
    assert (abs(other - old)).max() == 0


@pytest.mark.parametrize("opts", [{}, {"dtype": np.float32}, {"smooth": "jacobi"}, {"candidates": "rigid"}])
@pytest.mark.parametrize("name", ["2d", "3d", "2d mixed", "3d frictionless"])
def test_vcycle_is_the_former_one_bit_for_bit(name, opts, monkeypatch):
    """The whole preconditioner (pyamg's setup on the copy) equals the former one to the last bit."""
    asm = assemble(NETS[name](), pin=False)
    r = np.random.default_rng(1).standard_normal((asm.ndof, 2))
    P_new, info_new = ml.amg_preconditioner(asm, **opts)
    monkeypatch.setattr(ml, "blocked_copy", lambda H, order, bs, shift, dtype, sort: _former_copy(asm, order, bs, dtype))
    monkeypatch.setattr(ml, "_share_restrictions", lambda m: 0)     # pyamg's own R = P.T copies
    P_old, info_old = ml.amg_preconditioner(asm, **opts)
    assert info_new.levels == info_old.levels and info_new.operator_complexity == info_old.operator_complexity
    assert np.array_equal(P_new @ r, P_old @ r)


def test_restriction_without_copy_is_the_transpose_bit_for_bit():
    """_Restriction(P) @ x is P.T @ x to the last bit (float64 and float32), and
    _share_restrictions frees the copies of R only where R is P's transpose."""
    import pyamg
    asm = assemble(NETS["3d"](), pin=False)
    order, bs = _layout(asm)
    for dtype in (np.float64, np.float32):
        A = _former_copy(asm, order, bs, dtype)
        m = pyamg.smoothed_aggregation_solver(A, B=ml.near_null_space(asm)[order].astype(dtype))
        x = np.random.default_rng(4).standard_normal(A.shape[0]).astype(dtype)
        R0, P0 = m.levels[0].R, m.levels[0].P
        assert np.array_equal(ml._Restriction(P0) @ x, R0 @ x)
        assert ml._share_restrictions(m) > 0 and isinstance(m.levels[0].R, ml._Restriction)
        m.levels[0].P = P0 * 2.0                          # no longer R's transpose: kept
        m.levels[0].R = R0
        ml._share_restrictions(m)
        assert m.levels[0].R is R0


def test_blocked_copy_refuses_bad_shapes_by_name():
    H = sp.identity(7, format="csc")
    with pytest.raises(ValueError, match="multiple of bs"):
        ml.blocked_copy(H, np.arange(7), 3, 0.0)
    with pytest.raises(ValueError, match="order of shape"):
        ml.blocked_copy(H, np.arange(6), 1, 0.0)
    with pytest.raises(ValueError, match="bs"):
        ml.blocked_copy(H, np.arange(7), 0, 0.0)


def test_blocked_copy_of_a_known_matrix():
    """A 4 x 4 matrix by hand: order (2, 3, 0, 1), 2 x 2 blocks, shift 0.5, a zero block absent."""
    A = np.array([[4.0, 1.0, 0.0, 0.0], [1.0, 5.0, 0.0, 0.0], [0.0, 0.0, 6.0, 2.0], [0.0, 0.0, 2.0, 7.0]])
    B = ml.blocked_copy(sp.csc_matrix(A), np.array([2, 3, 0, 1]), 2, 0.5)
    assert B.indices.tolist() == [0, 1] and B.indptr.tolist() == [0, 1, 2]
    assert np.array_equal(B.toarray(), np.array([[6.5, 2, 0, 0], [2, 7.5, 0, 0], [0, 0, 4.5, 1], [0, 0, 1, 5.5]]))


def test_abs_times_is_abs_H_times_X_bit_for_bit():
    asm = assemble(NETS["3d"](), pin=False)
    H = asm.H.T                                          # the CG's CSR form
    X = np.random.default_rng(2).standard_normal((asm.ndof, 6))
    ref = abs(H) @ np.abs(X)
    for chunk in (1, 37, 1000, 1 << 22):
        assert np.array_equal(_abs_times(H, np.abs(X), chunk=chunk), ref)


def test_bench_spheres_stop_after(capsys):
    """``--stop-after`` stops the hierarchy after that many CG orders, restores the hierarchy's
    functions, and is refused without --phases or below 1."""
    import microhom.hierarchy as hi
    from studies import bench_spheres
    step = hi._BlockPCG.step
    (row,) = bench_spheres.main(["--n", "100", "--bound", "dual", "--exact", "no", "--tol", "1e-9", "--phases",
                                   "--stop-after", "2"])   # a tol no order 2 meets (the span certifies 1 % at order 1)
    out = capsys.readouterr().out
    assert row["stopped"] and out.count("phase CG order") == 2 and "stopped after 2 CG order(s)" in out
    from microhom import kinematics
    assert hi._BlockPCG.step is step and hi.assemble is kinematics.assemble
    for bad in (["--stop-after", "0", "--phases"], ["--stop-after", "2"]):
        with pytest.raises(SystemExit):
            bench_spheres.main(["--n", "100", "--exact", "no"] + bad)
    assert "--stop-after needs --phases" in capsys.readouterr().err
    with pytest.raises(ValueError, match="stop_after must be an integer >= 1"):
        bench_spheres.instrument_phases(0)
