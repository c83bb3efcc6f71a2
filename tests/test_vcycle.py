"""The parallel V-cycle (``microhom.vcycle``, issue 26): pyamg's V-cycle bit for bit, column by
column, in 2D and 3D, float64 and float32, for one and several columns and any thread count; the
hierarchy gives the same orders and interval with it as with pyamg's."""
import os
import subprocess
import sys
import pathlib

import numpy as np
import pytest

from microhom import lattices, multilevel
from microhom.kinematics import assemble
from microhom.multilevel import amg_preconditioner
from microhom.network import from_overlaps
from microhom.vcycle import VCycle
from tests.test_hierarchy_3d import packing

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _disks(kt=0.5, seed=3, m=12):
    lat = lattices.triangular(m, m)
    rng = np.random.default_rng(seed)
    return from_overlaps(lat.positions * 0.97 + rng.normal(scale=0.01, size=lat.positions.shape),
                         np.full(lat.n_particles, 0.5), lat.cell * 0.97, kn=1.0, kt=kt, tolerance=0.0)


NETWORKS = {"2d": lambda: _disks(), "2d frictionless": lambda: _disks(kt=0.0),
            "3d": lambda: packing(5, n=3, kt=0.5, keep=0.7), "3d frictionless": lambda: packing(6, n=3, keep=0.9)}


def _pyamg_columns(ml, B):
    """pyamg's own V-cycle, one column (row of B) at a time."""
    vc = ml.aspreconditioner(cycle="V")
    return np.stack([vc @ np.ascontiguousarray(b) for b in B])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("name", list(NETWORKS))
def test_vcycle_equals_pyamg_bit_for_bit(name, dtype):
    """Each column of the parallel V-cycle is pyamg's V-cycle of that column, array_equal, for 1
    and 6 columns; through the preconditioner (assembly order, float64 in and out) as well."""
    asm = assemble(NETWORKS[name](), pin=False)
    P, info = amg_preconditioner(asm, dtype=dtype)
    ml, order, inv = P.amg
    assert info.levels >= 2
    vc = VCycle.of(ml)
    assert vc is not None
    rng = np.random.default_rng(7)
    r = rng.standard_normal((asm.ndof, 6))
    B = np.ascontiguousarray(r[order].T, dtype=dtype)
    ref = _pyamg_columns(ml, B)
    assert np.abs(ref).max() > 0
    assert np.array_equal(vc(B), ref)
    assert np.array_equal(vc(B[2:3]), ref[2:3])
    # the preconditioner's apply: float64 in the assembly's order, one column and several
    expect = ref.T.astype(float)[inv]
    assert np.array_equal(P @ r, expect)
    assert np.array_equal(P @ r[:, 4], expect[:, 4])
    assert (P @ r[:, :2]).shape == (asm.ndof, 2)
    rf = np.asfortranarray(r)                      # the block CG's layout: kept, as pyamg's path did
    assert np.array_equal(P @ rf, expect) and (P @ rf).flags.f_contiguous


def test_not_taken_where_pyamg_smooths_pointwise():
    """Disks with and without spins in one network (block size 1: pyamg's pointwise Gauss-Seidel)
    and a one-level hierarchy keep pyamg's cycle (``VCycle.of`` is None); the operator still works."""
    import pyamg
    net = _disks()
    asm = assemble(net, pin=False)
    P, info = amg_preconditioner(asm)
    ml = P.amg[0]
    sm = ("gauss_seidel", {"sweep": "symmetric", "iterations": 2})
    A = ml.levels[0].A.tocsr()
    ml_pt = pyamg.smoothed_aggregation_solver(A, B=np.ones((A.shape[0], 1)), presmoother=sm, postsmoother=sm)
    assert VCycle.of(ml_pt) is None
    ml_one = pyamg.smoothed_aggregation_solver(ml.levels[0].A, max_coarse=10 ** 6)
    assert len(ml_one.levels) == 1 and VCycle.of(ml_one) is None


def test_bad_shape_is_refused_by_name():
    asm = assemble(NETWORKS["3d"](), pin=False)
    vc = VCycle.of(amg_preconditioner(asm)[0].amg[0])
    with pytest.raises(ValueError, match="VCycle: B must have shape"):
        vc(np.zeros((2, asm.ndof + 1)))


_THREADS_SCRIPT = """
import hashlib, numpy as np, numba
from microhom.kinematics import assemble
from microhom.multilevel import amg_preconditioner
from tests.test_hierarchy_3d import packing
asm = assemble(packing(5, n=3, kt=0.5, keep=0.7), pin=False)
P, _ = amg_preconditioner(asm)
r = np.random.default_rng(7).standard_normal((asm.ndof, 6))
print(numba.get_num_threads(), hashlib.sha256((P @ r).tobytes()).hexdigest())
"""


def test_thread_count_does_not_change_the_numbers():
    """NUMBA_NUM_THREADS = 1, 2 and 3 (subprocesses): the same bytes (each column's cycle is
    sequential; the threads share out the columns)."""
    out = set()
    for t in ("1", "2", "3"):
        env = dict(os.environ, NUMBA_NUM_THREADS=t)
        res = subprocess.run([sys.executable, "-c", _THREADS_SCRIPT], cwd=ROOT, env=env, capture_output=True,
                             text=True, check=True)
        threads, digest = res.stdout.split()
        assert threads == t
        out.add(digest)
    assert len(out) == 1


def test_hierarchy_same_orders_and_interval_as_with_pyamg(monkeypatch):
    """A 3D hierarchy (108 frictional spheres, dual bound, tol 1e-6): the same orders, upper bounds
    per order and interval, bit for bit, with the parallel V-cycle as with pyamg's."""
    from microhom.hierarchy import relaxation_hierarchy
    net = packing(11, n=3, kt=0.5, keep=0.6)
    calls = {"fast": 0, "pyamg": 0}

    def counted(key, f):
        def wrapped(*a, **k):
            calls[key] += 1
            return f(*a, **k)
        return wrapped

    def run():
        return relaxation_hierarchy(net, tol=1e-6, preconditioner="amg", max_order=60, soft_modes=0,
                                    spectral_bound="none", dual_bound=True)
    monkeypatch.setattr(multilevel.VCycle, "apply", counted("fast", multilevel.VCycle.apply))
    monkeypatch.setattr(multilevel, "_per_column", counted("pyamg", multilevel._per_column))
    h_fast = run()
    assert calls["fast"] > 0 and calls["pyamg"] == 0
    monkeypatch.setattr(multilevel.VCycle, "of", classmethod(lambda cls, ml: None))
    h_pyamg = run()
    assert calls["pyamg"] > 0
    assert h_fast.certified and h_fast.order >= 3
    assert h_fast.order == h_pyamg.order
    assert np.array_equal(h_fast.K_orders, h_pyamg.K_orders) and np.array_equal(h_fast.G_orders, h_pyamg.G_orders)
    for a, b in ((h_fast.K, h_pyamg.K), (h_fast.G, h_pyamg.G)):
        assert (a.lower, a.upper) == (b.lower, b.upper)


def _owns(a):
    """Whether ``a`` is (a view of) an array of exactly its bytes."""
    return multilevel._buffer_bytes(a) == a.nbytes


@pytest.mark.parametrize("smooth", ["energy", "jacobi"])
@pytest.mark.parametrize("name", ["2d", "3d"])
def test_slimmed_hierarchy_gives_the_same_cycle(name, smooth, monkeypatch):
    """After pyamg's setup the preconditioner drops what only the setup reads (near-null space B,
    ...) and gives every prolongator compact arrays (``multilevel._slim_levels``, issue 26): the
    V-cycle is array_equal to that of the hierarchy as pyamg left it (the same pyamg setup with
    ``_slim_levels`` a no-op), in 2D and 3D, float64 and float32."""
    asm = assemble(NETWORKS[name](), pin=False)
    r = np.random.default_rng(5).standard_normal((asm.ndof, 6))
    for dtype in (np.float64, np.float32):
        kw = dict(smooth=smooth, candidates="rigid", dtype=dtype)
        with monkeypatch.context() as m:
            m.setattr(multilevel, "_slim_levels", lambda ml, coarse_dtype=None: None)
            P0, _ = amg_preconditioner(asm, **kw)
        ml0 = P0.amg[0]
        assert any(hasattr(lvl, "B") for lvl in ml0.levels)            # pyamg keeps B: there is something to drop
        P1, info = amg_preconditioner(asm, **kw)
        ml1 = P1.amg[0]
        assert info.levels >= 2
        for lvl, lvl0 in zip(ml1.levels, ml0.levels):
            assert not any(hasattr(lvl, k) for k in multilevel._SETUP_ONLY)
            if hasattr(lvl, "P"):
                assert all(_owns(a) for a in (lvl.P.data, lvl.P.indices, lvl.P.indptr))
                for a in ("data", "indices", "indptr"):
                    assert np.array_equal(getattr(lvl.P, a), getattr(lvl0.P, a))
                assert lvl.R.P is lvl.P
        assert ml1.levels[0].A is not None and np.array_equal(ml1.levels[0].A.data, ml0.levels[0].A.data)
        assert np.array_equal(P1 @ r, P0 @ r)
        assert np.array_equal(P1 @ r[:, 0], P0 @ r[:, 0])
        if smooth == "jacobi":                                          # pyamg's oversize buffer, now freed
            assert not _owns(ml0.levels[0].P.data)


def _mixed_reference(ml, b, level=0):
    """An independent V-cycle of ``ml`` on one column ``b`` (level ``level``'s dtype): pyamg's
    own smoothers (C++), scipy's products with the prolongator widened to the level's dtype,
    ``P^T r`` rounded to the coarse level's dtype, the coarse correction widened back."""
    lvl = ml.levels[level]
    if level == len(ml.levels) - 1:
        return ml.coarse_solver(lvl.A, b.copy())
    x = np.zeros_like(b)
    lvl.presmoother(lvl.A, x, b)
    P = lvl.P.astype(b.dtype)
    bc = (P.T @ (b - lvl.A @ x)).astype(lvl.P.dtype)
    x += P @ _mixed_reference(ml, bc, level + 1).astype(b.dtype)
    lvl.postsmoother(lvl.A, x, b)
    return x


def _projected(asm, z):
    """``z`` without its global translations (the null space of ``H``, pin=False; the shifted
    level-0 matrix's pseudo-inverse amplifies them by 1e10 in float64 and drops them in float32)."""
    Q, _ = np.linalg.qr(multilevel.near_null_space(asm)[:, :asm.net.dim])
    return z - Q @ (Q.T @ z)


@pytest.mark.parametrize("name", list(NETWORKS))
def test_mixed_precision_cycle(name):
    """``coarse_dtype=float32``: level 0's A and Dinv float64, every P and coarser level float32;
    the V-cycle equals the independent reference ``_mixed_reference`` bit for bit (same casts,
    same sums), and differs from the float64 cycle at float32 round-off: below 1e-6 relative for
    columns without global translations (H's null space; the CG's residuals), compared without
    them (measured 1e-8 .. 6e-8; the all-float32 cycle differs by 3e-3 .. 2e-2 here)."""
    asm = assemble(NETWORKS[name](), pin=False)
    P, info = amg_preconditioner(asm, coarse_dtype=np.float32)
    ml, order, inv = P.amg
    assert info.levels >= 2
    assert ml.levels[0].A.dtype == np.float64 and ml.levels[0].presmoother.keywords["Dinv"].dtype == np.float64
    assert all(lvl.A.dtype == np.float32 for lvl in ml.levels[1:])
    assert all(lvl.P.dtype == np.float32 and lvl.R.P is lvl.P for lvl in ml.levels[:-1])
    assert all(lvl.presmoother.keywords["Dinv"].dtype == np.float32 for lvl in ml.levels[1:-1])
    r = _projected(asm, np.random.default_rng(11).standard_normal((asm.ndof, 6)))   # as the CG's residuals
    z = P @ r
    ref = np.stack([_mixed_reference(ml, np.ascontiguousarray(r[order, j])) for j in range(6)], axis=1)[inv]
    assert np.abs(ref).max() > 0
    assert np.array_equal(z, ref)
    assert np.array_equal(P @ r[:, 3], ref[:, 3])
    z64 = amg_preconditioner(asm)[0] @ r
    a, b = _projected(asm, z), _projected(asm, z64)
    assert 0 < np.abs(a - b).max() < 1e-6 * np.abs(b).max()


def test_mixed_precision_keeps_the_float64_and_float32_paths():
    """``coarse_dtype`` None or equal to ``dtype``: the hierarchy is the plain one, bit for bit."""
    asm = assemble(NETWORKS["3d"](), pin=False)
    r = np.random.default_rng(2).standard_normal((asm.ndof, 6))
    for dt in (np.float64, np.float32):
        z = amg_preconditioner(asm, dtype=dt)[0] @ r
        assert np.array_equal(amg_preconditioner(asm, dtype=dt, coarse_dtype=dt)[0] @ r, z)


def test_coarse_dtype_is_checked_by_name(monkeypatch):
    asm = assemble(NETWORKS["3d"](), pin=False)
    for bad, dt in (("float16", np.float64), (np.float64, np.float32), ("nonsense", np.float64), (3, np.float64)):
        with pytest.raises(ValueError, match="coarse_dtype"):
            amg_preconditioner(asm, dtype=dt, coarse_dtype=bad)
    monkeypatch.setattr(multilevel.VCycle, "of", classmethod(lambda cls, ml: None))
    with pytest.raises(ValueError, match="coarse_dtype"):
        amg_preconditioner(asm, coarse_dtype=np.float32)
