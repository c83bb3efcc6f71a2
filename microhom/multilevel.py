"""Multilevel preconditioner for the Hessian of a contact network (smoothed-aggregation AMG).

The relaxation hierarchy (``microhom.hierarchy``) runs block conjugate gradients on
``H X = -F`` (``microhom.kinematics``). Its upper bounds hold for *any* iterate ``X`` and grow
monotonically for *any* fixed preconditioner (``docs/theory.md``, section 9.6), so the
preconditioner decides only how fast they converge. The particle-block Jacobi ``M`` makes order k
the relaxation that k contact shells carry, and converges slowly where the relaxation is carried
by soft, extended modes (near isostaticity, small kt/kn). This module builds the multilevel
alternative: pyamg's smoothed aggregation (Vanek, Mandel & Brezina 1996) with

* the near-null space of a disk network, four vectors per particle: the two translations, the
  rigid rotation of a neighbourhood (``u = omega x x``, spin ``omega``: ``(-y, x, 1)``) and a spin
  alone (the rolling mode of a particle between its neighbours). An aggregate's coarse unknowns are
  these four motions of its particles (rotation about the aggregate's own centre after pyamg's
  local QR);
* energy-minimising prolongation smoothing (deterministic: no random spectral-radius estimate);
* symmetric block Gauss-Seidel smoothing (two sweeps each way) on the particles' 3 x 3 (or 2 x 2)
  blocks (6 x 6 or 3 x 3 for spheres), so that one V-cycle is a symmetric operator.

``amg_preconditioner``'s options (issue 26) change the setup's cost and the CG's speed; their
defaults are the call above. Its memory (issue 26, docs/results/spheres.md, "Memory at 1e6
spheres"): pyamg gets the permuted, shifted ``H`` built once in blocks (``blocked_copy``, int32
indices, no transient CSR copies) and keeps no transposed copy of each prolongator (``R @ x`` is
computed from ``P``); after the setup every level drops what only the setup reads (its near-null
space ``B``, ...) and every ``P`` gets compact arrays (pyamg's Jacobi smoother leaves it a view of
a buffer 1.3 times its size): 622.8 MB -> 554.4 MB held at 1.08e5 spheres; all give the former
V-cycle bit for bit. ``coarse_dtype=np.float32`` stores the levels past the first in float32
(a mixed-precision V-cycle, level 0 float64): 417.9 MB.

The V-cycle is applied by ``microhom.vcycle.VCycle`` (issue 26): pyamg's cycle, sum for sum, as
numba kernels that spread the columns of a block (the CG's 6 load columns in 3D, 3 in 2D) over
the threads (``NUMBA_NUM_THREADS``); pyamg's C++ cycle holds the GIL and takes the columns one at a
time on one core. The result is pyamg's to the bit, in 2D and 3D, float64 and float32, whatever
the number of threads (tests/test_vcycle.py; measured in docs/results/spheres.md, "Both cores for
the V-cycle"). Hierarchies outside what it does (pointwise Gauss-Seidel where the particle blocks
differ in size, a single level) keep pyamg's cycle.

Spheres (3D) use the same code with the dimension from the network: nine vectors per particle
(three translations, three rigid rotations with their spins, three spins alone).

The near-null space does not contain the motions that slip at no contact (rolling without
sliding, about ``3n - N_c`` of them), which cost only kn: at kt >> kn they form a cluster of the
pencil near kn/kt that the V-cycle does not remove, and CG needs many more steps there
(docs/theory.md, section 9, "Stiffness ratios far from 1"; docs/results/hierarchy.md, section 6).

Measured (docs/results/hierarchy.md): on N = 3000 DEM packings the upper bound after 8 steps is
within 2.3 % of the exact shear modulus on every frictional packing (block Jacobi: up to 68 %).

Shapes: ``asm.ndof`` unknowns; the operator applies to (ndof,) or (ndof, s) arrays.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .kinematics import Assembly, rotational_dofs
from .results import Result
from .vcycle import VCycle

__all__ = ["near_null_space", "amg_preconditioner", "AMGInfo", "dof_layout", "blocked_copy", "coarse_correction"]

_SHIFT = 1e-10        # H + shift * mean(diag H) * I: removes the two global translations (pin=False)


def dof_layout(asm: Assembly):
    """(particle, component), two (ndof,) int arrays: the particle of every reduced unknown and its
    component (0 .. d-1 = translations x, y[, z]; d .. = spins: 2 for a disk's spin, 3, 4, 5 for
    a sphere's rotation about x, y, z). The full numbering of ``microhom.kinematics.assemble`` is
    all translations (d per particle), then all rotations (1 per disk, 3 per sphere)."""
    N = asm.net.n_particles
    dim = asm.net.dim
    rot = rotational_dofs(dim)
    full = np.flatnonzero(asm.dof_map >= 0)
    red = asm.dof_map[full]
    part = np.empty(asm.ndof, dtype=np.int64)
    comp = np.empty(asm.ndof, dtype=np.int64)
    isx = full < dim * N
    part[red] = np.where(isx, full // dim, (full - dim * N) // rot)
    comp[red] = np.where(isx, full % dim, dim + (full - dim * N) % rot)
    return part, comp


def near_null_space(asm: Assembly) -> np.ndarray:
    """(ndof, m) candidate low-energy motions of the particles (zero columns, e.g. without spins,
    dropped); the translations come first (``[:, :d]``).

    2D (disks), m = 4: translation x, translation y, rigid rotation ``(-y, x)`` with unit spin,
    unit spin alone.
    3D (spheres), m = 9: translations x, y, z; the three rigid rotations ``u = e_a x x`` with
    unit spin ``omega = e_a`` (a = x, y, z); the three unit spins alone (a sphere rolling
    between its neighbours) [m for the rotations' translation entries, 1 otherwise].
    Positions are those of the network (inside the cell)."""
    part, comp = dof_layout(asm)
    dim = asm.net.dim
    x = np.asarray(asm.net.positions, dtype=float)[part]
    if dim == 2:
        B = np.zeros((asm.ndof, 4))
        B[comp == 0, 0] = 1.0
        B[comp == 1, 1] = 1.0
        B[comp == 0, 2] = -x[comp == 0, 1]
        B[comp == 1, 2] = x[comp == 1, 0]
        B[comp == 2, 2] = 1.0
        B[comp == 2, 3] = 1.0
        return B[:, np.abs(B).sum(axis=0) > 0]
    B = np.zeros((asm.ndof, 9))
    for a in range(3):
        B[comp == a, a] = 1.0                              # translations
        e = np.zeros(3)
        e[a] = 1.0
        u = np.cross(e, x)                                 # (ndof, 3): e_a x x at each unknown's particle
        for b in range(3):
            B[comp == b, 3 + a] = u[comp == b, b]          # rigid rotation: translation part ...
        B[comp == 3 + a, 3 + a] = 1.0                      # ... and its spin
        B[comp == 3 + a, 6 + a] = 1.0                      # spin alone
    return B[:, np.abs(B).sum(axis=0) > 0]


def _n_rigid(dim, m):
    """Columns of ``near_null_space`` that are rigid motions: translations and rigid rotations
    (3 of 4 in 2D, 6 of 9 in 3D; fewer where the spins are absent and those columns dropped)."""
    return min(m, 3 if dim == 2 else 6)


@dataclass(frozen=True)
class AMGInfo(Result):
    """What was built.

    Attributes
    ----------
    levels : int
        Levels of the hierarchy (1 = the coarse solve only, for tiny systems).
    operator_complexity : float
        Non-zeros of all level matrices over those of ``H`` [-].
    blocksize : int
        Unknowns per particle block (3 with spins, 2 without in 2D; 6 and 3 in 3D; 1 when mixed).
    setup_time : float
        Wall time of the setup [s].
    """

    levels: int
    operator_complexity: float
    blocksize: int
    setup_time: float


@numba.njit(cache=True)
def _blocked_pattern(indptr, indices, data, order, inv, bs):
    """Block rows' lengths of ``P H P^T`` in ``bs x bs`` blocks (``H`` CSC, exact zeros dropped,
    every diagonal block kept): (n/bs + 1,) int64 row pointer."""
    nb = order.size // bs
    count = np.zeros(nb + 1, dtype=np.int64)
    mark = np.full(nb, -1, dtype=np.int64)
    for J in range(nb):
        mark[J] = J                                    # the diagonal block (the shift's entries)
        count[J + 1] += 1
        for bj in range(bs):
            c = order[J * bs + bj]
            for k in range(indptr[c], indptr[c + 1]):
                if data[k] == 0.0:
                    continue
                I = inv[indices[k]] // bs
                if mark[I] != J:
                    mark[I] = J
                    count[I + 1] += 1
    for I in range(nb):
        count[I + 1] += count[I]
    return count


@numba.njit(cache=True)
def _blocked_fill(indptr, indices, data, order, inv, bs, shift, bptr, out):
    """Fill ``out = (bind, bdata, key)`` (a tuple: the kernel argument rule): ``bind`` (block
    columns, ascending per block row) and ``bdata`` (blocks, bs x bs) of ``P H P^T + shift I``
    (see ``_blocked_pattern``); an entry that becomes 0.0 is left 0.0 in its block (as ``tobsr``
    of a CSR matrix without it). ``key`` (blocks,) gets each block's first position in a scan of
    its block row's rows (top down) each in descending column of ``H``."""
    bind, bdata, key = out
    nb = order.size // bs
    n = order.size
    fill = bptr[:-1].copy()
    mark = np.full(nb, -1, dtype=np.int64)
    slot = np.zeros(nb, dtype=np.int64)
    for J in range(nb):
        mark[J] = J
        slot[J] = fill[J]
        bind[fill[J]] = J
        fill[J] += 1
        for bj in range(bs):
            col = J * bs + bj
            c = order[col]
            diag = False
            for k in range(indptr[c], indptr[c + 1]):
                v = data[k]
                if v == 0.0:
                    continue
                row = inv[indices[k]]
                I = row // bs
                if mark[I] != J:
                    mark[I] = J
                    slot[I] = fill[I]
                    bind[fill[I]] = J
                    fill[I] += 1
                if row == col:
                    v = v + shift
                    diag = True
                bdata[slot[I], row - I * bs, bj] = v
                key[slot[I]] = min(key[slot[I]], (row - I * bs) * n + (n - 1 - c))
            if not diag:
                bdata[slot[J], bj, bj] = shift
                key[slot[J]] = min(key[slot[J]], bj * n + (n - 1 - c))


@numba.njit(cache=True)
def _permuted_sorted(indptr, indices, inv):
    """Whether every row of ``H[order][:, order]`` (``H`` CSC with sorted indices, ``inv`` the
    inverse of ``order``) lists its columns in ascending order when taken in the order of ``H``'s
    columns (what scipy's fancy indexing does)."""
    n = inv.size
    last = np.full(n, -1, dtype=np.int64)
    for c in range(n):
        for k in range(indptr[c], indptr[c + 1]):
            r = indices[k]
            if inv[c] <= last[r]:
                return False
            last[r] = inv[c]
    return True


@numba.njit(cache=True)
def _reorder_blocks(bptr, bind, bdata, key):
    """Within each block row, put the blocks in ascending ``key`` (in place)."""
    for I in range(bptr.size - 1):
        a, b = bptr[I], bptr[I + 1]
        p = np.argsort(key[a:b], kind="mergesort")
        bind[a:b] = bind[a:b][p]
        bdata[a:b] = bdata[a:b][p]


def blocked_copy(H, order, bs, shift, dtype=np.float64, sort=True):
    """``P H P^T + shift I`` as a BSR matrix of ``bs x bs`` blocks (or CSR when ``bs == 1``), int32
    indices, built in one pass over ``H``'s CSC form without intermediate copies (issue 26).

    ``P`` is the permutation ``(P x)[i] = x[order[i]]`` (``order`` (n,) ints, n a multiple of
    ``bs``), ``shift`` [N/m] is added to the diagonal, ``dtype`` float64 or float32 (the sum is
    taken in float64, then rounded). Entries of ``H`` equal to 0.0 are dropped and no block is
    made of them alone; every diagonal block is kept. ``sort``: block columns ascending in each
    block row; else in the order the former path of ``amg_preconditioner`` left them where the
    permutation unsorted the rows (scipy's sum of a non-canonical CSR matrix lists a row's entries
    in descending column of ``H``, and
    ``tobsr`` takes the blocks in order of first appearance), which pyamg's setup does not fully
    undo: its hierarchy depends on it in the last bits. With ``sort=False`` and float64 the result
    equals ``(H.tocsr()[order][:, order] + shift * I).tocsr().tobsr((bs, bs))`` array for array;
    with ``sort=True`` and float32 the former ``.astype(np.float32)`` of it, which sorted
    (tests/test_multilevel_options.py). It needs 8 (or 4) bytes per stored block entry and 12 per
    block, against three transient CSR copies of ``H`` before.
    """
    H = sp.csc_matrix(H)
    if not H.has_canonical_format:
        H = H.copy()
        H.sum_duplicates()
    n = H.shape[0]
    order = np.ascontiguousarray(order, dtype=np.int64)
    if H.shape != (n, n) or order.shape != (n,) or bs < 1 or n % bs:
        raise ValueError(f"blocked_copy needs a square H, order of shape ({n},) and n a multiple of bs, "
                         f"got H {H.shape}, order {order.shape}, bs {bs}")
    inv = np.empty_like(order)
    inv[order] = np.arange(n)
    data = np.asarray(H.data, dtype=np.float64)
    bptr = _blocked_pattern(H.indptr, H.indices, data, order, inv, bs)
    nblk = int(bptr[-1])
    itype = np.int32 if max(nblk, n) < 2 ** 31 - 1 else np.int64
    bind = np.empty(nblk, dtype=np.int64)
    bdata = np.zeros((nblk, bs, bs), dtype=np.float64 if np.dtype(dtype) == np.float64 else np.float32)
    key = np.full(nblk, np.iinfo(np.int64).max, dtype=np.int64)
    _blocked_fill(H.indptr, H.indices, data, order, inv, bs, float(shift), bptr, (bind, bdata, key))
    if not sort:
        _reorder_blocks(bptr, bind, bdata, key)
    del key
    bptr, bind = bptr.astype(itype), bind.astype(itype)
    if bs == 1:
        return sp.csr_matrix((bdata.reshape(-1), bind, bptr), shape=(n, n))
    return sp.bsr_matrix((bdata, bind, bptr), shape=(n, n))


@numba.njit(cache=True)
def _bsr_rmatvec(indptr, indices, data, x, y):
    """``y += P^T x`` for a BSR ``P`` (blocks (nblk, r, c)), summed in the order of scipy's BSR
    product with the transposed copy ``P.T`` (each output's blocks by ascending block row of
    ``P``, each block's entries in turn)."""
    r, c = data.shape[1], data.shape[2]
    for I in range(indptr.size - 1):
        for k in range(indptr[I], indptr[I + 1]):
            J = indices[k]
            for q in range(c):
                dot = y[J * c + q]
                for p in range(r):
                    dot += data[k, p, q] * x[I * r + p]
                y[J * c + q] = dot


class _Restriction:
    """``P^T`` of a multilevel level without its transposed copy (pyamg keeps ``R = P.T``, as
    many bytes as ``P``: 6 per non-zero of ``H`` at the finest level of a sphere network; issue
    26). ``R @ x`` for a vector gives the same numbers as the copy (``_bsr_rmatvec``)."""

    def __init__(self, P):
        self.P = P
        self.shape = (P.shape[1], P.shape[0])
        self.dtype = P.dtype

    def __matmul__(self, x):
        if x.ndim != 1:
            return self.P.T @ x
        y = np.zeros(self.shape[0], dtype=np.result_type(self.dtype, x.dtype))
        _bsr_rmatvec(self.P.indptr, self.P.indices, self.P.data, x, y)
        return y


def _share_restrictions(ml):
    """Replace each level's ``R`` by ``_Restriction(P)`` where ``R`` is exactly the transpose of
    a BSR ``P`` (pyamg's symmetric setup; checked array for array); returns the bytes freed."""
    freed = 0
    for lvl in ml.levels[:-1]:
        P, R = getattr(lvl, "P", None), getattr(lvl, "R", None)
        if not (sp.issparse(P) and P.format == "bsr" and sp.issparse(R) and R.format == "bsr"):
            continue
        T = P.T
        same = (T.blocksize == R.blocksize and T.shape == R.shape and T.dtype == R.dtype
                and all(np.array_equal(a, b) for a, b in ((T.indptr, R.indptr), (T.indices, R.indices),
                                                          (T.data, R.data))))
        del T
        if same:
            freed += R.data.nbytes + R.indices.nbytes + R.indptr.nbytes
            lvl.R = _Restriction(P)
    return freed


#: what pyamg's setup leaves on a level that no V-cycle reads (near-null candidates, tentative
#: prolongator, aggregates, strength): dropped after the setup (issue 26)
_SETUP_ONLY = ("B", "BH", "T", "AggOp", "C")


def _buffer_bytes(a):
    """Bytes of the array that owns ``a``'s memory (``a``'s own where it is not a view)."""
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a.nbytes


def _compact(M, dtype=None):
    """The sparse matrix ``M`` (BSR or CSR) with its entries cast to ``dtype`` (None: kept) and
    every array owning exactly its entries: pyamg's Jacobi prolongation smoother leaves ``P`` a
    view of a buffer sized for ``nnz(A) + nnz(T)`` blocks (scipy's BSR difference, then
    ``prune``), up to 40 % more than ``P``'s (issue 26). ``M`` itself when nothing changes; the
    same numbers otherwise."""
    data = M.data if dtype is None or M.dtype == dtype else M.data.astype(dtype)
    new = [a if _buffer_bytes(a) == a.nbytes else a.copy() for a in (data, M.indices, M.indptr)]
    if all(a is b for a, b in zip(new, (M.data, M.indices, M.indptr))):
        return M
    if M.format == "bsr":
        return type(M)(tuple(new), shape=M.shape, blocksize=M.blocksize)
    return type(M)(tuple(new), shape=M.shape)


def _cast_smoothers(lvl, dtype):
    """Cast the ``Dinv`` (inverted diagonal blocks) of a level's pre- and post-smoother to
    ``dtype``, one array for both where pyamg shares it."""
    cast = {}
    for name in ("presmoother", "postsmoother"):
        f = getattr(lvl, name, None)
        D = (getattr(f, "keywords", None) or {}).get("Dinv")
        if not isinstance(D, np.ndarray) or D.dtype == dtype:
            continue
        cast.setdefault(id(D), D.astype(dtype))
        setattr(lvl, name, functools.partial(f.func, *f.args, **{**f.keywords, "Dinv": cast[id(D)]}))


def _slim_levels(ml, coarse_dtype=None):
    """After pyamg's setup and ``_share_restrictions``: drop what only the setup reads
    (``_SETUP_ONLY``), give every ``P`` (and an unshared ``R``) and the coarse levels' ``A``
    compact arrays (``_compact``), and with ``coarse_dtype`` store the levels past the first
    (their ``A``, smoothers' ``Dinv``, and every ``P``, ``R``) in it; level 0's ``A`` (the CG's
    ``H``, ``microhom.shared_h``) and smoother stay as they are. The V-cycle's numbers do not
    change without ``coarse_dtype`` (tests/test_vcycle.py)."""
    for i, lvl in enumerate(ml.levels):
        for k in _SETUP_ONLY:
            lvl.__dict__.pop(k, None)
        if i > 0:
            lvl.A = _compact(lvl.A, coarse_dtype)
            if coarse_dtype is not None:
                _cast_smoothers(lvl, coarse_dtype)
        P, R = getattr(lvl, "P", None), getattr(lvl, "R", None)
        if sp.issparse(P):
            lvl.P = _compact(P, coarse_dtype)
            if isinstance(R, _Restriction):
                lvl.R = _Restriction(lvl.P)
            elif sp.issparse(R):
                lvl.R = _compact(R, coarse_dtype)


def _pyamg_options(bs, sweeps, theta, max_coarse, improve):
    """(smoother, extra keywords) of pyamg's ``smoothed_aggregation_solver`` for
    ``amg_preconditioner``'s options: only what differs from pyamg's defaults is passed."""
    smoother = ("block_gauss_seidel" if bs > 1 else "gauss_seidel",
                {"sweep": "symmetric", "iterations": int(sweeps)})
    extra = {}
    if theta != 0.0:
        extra["strength"] = ("symmetric", {"theta": float(theta)})
    if max_coarse != 10:
        extra["max_coarse"] = int(max_coarse)
    if not improve:
        extra["improve_candidates"] = None
    return smoother, extra


def _slimmed(ml, coarse_dtype):
    """Share the restrictions, slim the levels (``_slim_levels``, the coarse ones in
    ``coarse_dtype``) and return ``VCycle.of(ml)``; a mixed hierarchy needs that V-cycle."""
    _share_restrictions(ml)
    mixed = coarse_dtype != ml.levels[0].A.dtype and len(ml.levels) > 1
    if mixed and VCycle.of(ml) is None:
        raise ValueError(f"coarse_dtype={coarse_dtype} needs microhom.vcycle.VCycle (block Gauss-Seidel on "
                         "particles of one block size); this network's hierarchy is not one: use coarse_dtype=None")
    _slim_levels(ml, coarse_dtype if mixed else None)
    return VCycle.of(ml)


#: smooth= of amg_preconditioner: pyamg's prolongation smoother (Jacobi: local weighting, no random
#: spectral-radius estimate; deterministic like the energy minimisation)
SMOOTHERS = {"energy": ("energy", {}), "jacobi": ("jacobi", {"omega": 4.0 / 3.0, "weighting": "local"}),
             "none": None}
#: candidates= of amg_preconditioner: the near-null vectors kept (columns of near_null_space)
CANDIDATES = ("all", "rigid")


def _check_coarse_dtype(coarse_dtype, dtype):
    """``coarse_dtype`` as a numpy dtype (None: ``dtype``); float32 under float64, or ``dtype``."""
    if coarse_dtype is None:
        return np.dtype(dtype)
    try:
        cd = np.dtype(coarse_dtype)
    except TypeError:
        cd = None
    if cd is None or cd not in (np.dtype(np.float32), np.dtype(dtype)):
        raise ValueError(f"coarse_dtype must be None, float32 or dtype ({np.dtype(dtype)}), got {coarse_dtype!r}")
    return cd


def _check_options(sweeps, candidates, smooth, theta, max_coarse, dtype):
    if int(sweeps) != sweeps or not 1 <= sweeps <= 10:
        raise ValueError(f"sweeps must be an integer in [1, 10], got {sweeps!r}")
    if candidates not in CANDIDATES:
        raise ValueError(f"candidates must be one of {CANDIDATES}, got {candidates!r}")
    if smooth not in SMOOTHERS:
        raise ValueError(f"smooth must be one of {tuple(SMOOTHERS)}, got {smooth!r}")
    if not (isinstance(theta, (int, float)) and 0.0 <= theta < 1.0):
        raise ValueError(f"theta must be a number in [0, 1), got {theta!r}")
    if int(max_coarse) != max_coarse or not 1 <= max_coarse <= 10 ** 6:
        raise ValueError(f"max_coarse must be an integer in [1, 1e6], got {max_coarse!r}")
    if np.dtype(dtype) not in (np.dtype(np.float64), np.dtype(np.float32)):
        raise ValueError(f"dtype must be float64 or float32, got {dtype!r}")


def _per_column(f, r, order, inv, dtype):
    """``f`` (a linear map in the particle-major order, ``dtype`` in) applied to each column of
    ``r`` ((ndof,) or (ndof, s), float64, the assembly's order): ``f(r[order].astype(dtype))``
    back in float64 and in the assembly's order (``[inv]``)."""
    r = np.asarray(r, dtype=float)
    if r.ndim == 1:
        return np.asarray(f(r[order].astype(dtype, copy=False)), dtype=float)[inv]
    out = np.empty_like(r)
    for j in range(r.shape[1]):
        out[:, j] = np.asarray(f(r[order, j].astype(dtype, copy=False)), dtype=float)[inv]
    return out


def amg_preconditioner(asm: Assembly, *, sweeps: int = 2, candidates: str = "all", smooth: str = "energy",
                       theta: float = 0.0, max_coarse: int = 10, improve: bool = True, dtype=np.float64,
                       coarse_dtype=None, release=None):
    """Smoothed-aggregation V-cycle approximating ``H^-1`` (see the module docstring).

    The bounds of ``microhom.hierarchy`` hold for any preconditioner (each CG block is
    H-orthonormalised explicitly and the energy estimate is that of the iterate), so the options
    below change the speed of convergence only, never the rigour of an interval.

    Parameters
    ----------
    asm : Assembly
        From ``microhom.kinematics.assemble`` (``pin=False`` or True).
    sweeps : int
        Symmetric Gauss-Seidel sweeps before and after each coarse correction, 1..10.
    candidates : {"all", "rigid"}
        Near-null vectors: all of ``near_null_space`` (4 per disk, 9 per sphere) or the rigid
        motions only (translations and rigid rotations with their spins: 3 per disk, 6 per sphere).
    smooth : {"energy", "jacobi", "none"}
        Prolongation smoother: energy minimisation, one weighted-Jacobi step (omega 4/3, local
        weighting), or none (plain aggregation).
    theta : float
        Strength-of-connection threshold of pyamg's symmetric measure, in [0, 1) (0: every
        coupling is strong).
    max_coarse : int
        Largest coarsest level (block rows), solved directly; 1..1e6.
    improve : bool
        Relax the candidates on ``H B = 0`` before the first aggregation (pyamg's default, four
        symmetric block Gauss-Seidel sweeps).
    dtype : float64 or float32
        Precision of the hierarchy (its matrices, transfer operators and V-cycle); residuals
        come in and corrections go out in float64. float32 (issue 26, docs/results/spheres.md,
        "The multilevel setup"): at 1.08e5 spheres and tol = 0.01 the setup's peak 1.0 GiB lower,
        17 CG orders instead of 19, the hierarchy's CPU 188 s instead of 247 s; but at tol = 1e-3
        on 256 frictional spheres the CG stagnates near 1e-8 (not certified after 23 orders: the
        iterate grows along nearly floppy directions and so does its energy's round-off margin,
        which covers the computed energies' drift below the exact one; every reported bound
        stays rigorous, ``HierarchyResult.margin_orders``): not the default.
    coarse_dtype : None or float32
        Precision of the levels past the first (None: ``dtype``, the default, nothing changes):
        with float32 under ``dtype`` float64 (a mixed-precision V-cycle, issue 26) every
        prolongator ``P_l`` ((n_l, n_{l+1}) BSR) and restriction, and every coarser level's
        ``A_l`` ((n_l, n_l)), smoother's ``Dinv`` ((n_l / b, b, b)) and the coarsest level's
        pseudo-inverse are float32, converted from pyamg's float64 hierarchy after its setup
        (rounded once); level 0's ``A`` (``P H P^T + shift I``, the CG's ``H``,
        ``microhom.shared_h``: its residuals must be float64 for the bounds' round-off margins)
        and its smoother's ``Dinv`` stay float64, so the fine-level residual and smoothing are
        float64; ``P_0^T r`` is summed in float64 and rounded to float32, the coarse correction
        widened back and added into the float64 iterate (``microhom.vcycle``). It needs
        ``microhom.vcycle.VCycle`` (block Gauss-Seidel smoothing: particles of one block size)
        and raises ``ValueError`` for a hierarchy it does not take. Measured in
        docs/results/spheres.md, "A float32 coarse hierarchy".
    release : callable or None
        Called as ``release(A, order, shift)`` once the blocked copy ``A = P H P^T + shift I``
        (``(P x)[i] = x[order[i]]``, ``shift`` [N/m]; pyamg's level-0 matrix) is made and ``asm``
        is no longer referenced here, before pyamg's setup: the caller may drop its ``H`` there
        and read it from ``A`` (issue 26, ``microhom.shared_h``; the relaxation hierarchy does
        where ``A`` is float64).

    Returns
    -------
    (LinearOperator (ndof, ndof), AMGInfo)
        The operator also carries ``op.amg = (pyamg hierarchy, order, inv)`` and ``op.shift``
        [N/m], the shift of its level-0 matrix ``P H P^T + shift I``.
    """
    try:
        import pyamg
    except ImportError as exc:  # pragma: no cover - pyamg is a core dependency
        raise ImportError("preconditioner='amg' needs pyamg (pip install pyamg); "
                          "preconditioner='block' works without it") from exc
    _check_options(sweeps, candidates, smooth, theta, max_coarse, dtype)
    dtype, coarse_dtype = np.dtype(dtype), _check_coarse_dtype(coarse_dtype, dtype)
    t0 = time.perf_counter()
    n = asm.ndof
    part, comp = dof_layout(asm)
    order = np.lexsort((comp, part))                     # particle-major: (x, y[, z], spins) per particle
    inv = np.empty_like(order)
    inv[order] = np.arange(n)
    counts = np.bincount(part)[np.unique(part)]
    bs = int(counts[0]) if counts.size and np.all(counts == counts[0]) else 1
    # particle-major, shifted copy of H in bs x bs blocks, built once (issue 26: formerly three
    # transient CSR copies); float32: the shift is below its precision, the coarsest level's
    # pseudo-inverse takes the translations
    # (the block order of the former path: sorted where the permutation kept H's rows sorted, and
    # in float32, whose astype sorted them; see blocked_copy)
    B = near_null_space(asm)
    if candidates == "rigid":
        B = B[:, :_n_rigid(asm.net.dim, B.shape[1])]
    Hc = sp.csc_matrix(asm.H)
    sort = dtype == np.float32 or (Hc.has_sorted_indices and _permuted_sorted(Hc.indptr, Hc.indices, inv))
    shift = _SHIFT * float(Hc.diagonal()[order].mean())
    H = blocked_copy(Hc, order, bs, shift, dtype, sort=sort)
    del Hc
    if release is not None:
        asm = None                                       # nothing below reads it: the caller may drop H
        release(H, order, shift)
    smoother, extra = _pyamg_options(bs, sweeps, theta, max_coarse, improve)
    ml = pyamg.smoothed_aggregation_solver(H,
                                           B=np.ascontiguousarray(B[order], dtype=dtype),
                                           presmoother=smoother, postsmoother=smoother,
                                           smooth=SMOOTHERS[smooth], **extra)
    del H
    fast = _slimmed(ml, coarse_dtype)
    vcycle = ml.aspreconditioner(cycle="V")

    def apply(r):
        if fast is not None:                             # the same numbers, the columns in parallel
            return fast.apply(r, order)
        return _per_column(lambda x: vcycle @ x, r, order, inv, dtype)

    op = sla.LinearOperator((n, n), matvec=apply, matmat=apply, dtype=float)
    op.amg = (ml, order, inv)                          # for coarse_correction (already held by the V-cycle)
    op.shift = shift                                   # of ml.levels[0].A (microhom.shared_h)
    info = AMGInfo(levels=len(ml.levels), operator_complexity=float(ml.operator_complexity()),
                   blocksize=bs, setup_time=time.perf_counter() - t0)
    return op, info


def coarse_correction(op, *, rtol: float = 1e-6, maxiter: int = 30):
    """The Galerkin coarse-grid correction of the V-cycle ``op`` of :func:`amg_preconditioner`:
    a function ``r -> P A_c^-1 P^T r`` ((ndof,) or (ndof, s) in and out), ``P`` pyamg's
    prolongator from level 0 to level 1 and ``A_c = P^T H P`` (H shifted by 1e-10 of its mean
    diagonal) its level-1 operator, solved by CG preconditioned by the V-cycle of the remaining
    levels to ``rtol`` (at most ``maxiter`` steps, 1..1000). ``y = P A_c^-1 P^T r`` minimises
    the energy ``1/2 y^T H y - y^T r`` over the coarse space (``microhom.dual_bound``'s coarse
    correction, docs/theory.md section 12; measured there: it shrinks the dual gap only 1-2 times
    for more than a CG order's cost, so the hierarchy does not use it). None when the hierarchy has
    a single level.
    ``op`` without pyamg's hierarchy (not from ``amg_preconditioner``) raises ``ValueError``."""
    if not (isinstance(rtol, (int, float)) and 0.0 < rtol < 1.0):
        raise ValueError(f"rtol must be a number in (0, 1), got {rtol!r}")
    if int(maxiter) != maxiter or not 1 <= maxiter <= 1000:
        raise ValueError(f"maxiter must be an integer in [1, 1000], got {maxiter!r}")
    if not hasattr(op, "amg"):
        raise ValueError("coarse_correction: op must be the operator of amg_preconditioner")
    from pyamg.multilevel import MultilevelSolver
    ml, order, inv = op.amg
    if len(ml.levels) < 2:
        return None
    P = ml.levels[0].P
    A1 = ml.levels[1].A
    if len(ml.levels) > 2:
        sub = MultilevelSolver(ml.levels[1:], coarse_solver="pinv")
        sub.coarse_solver = ml.coarse_solver
        prec = sub.aspreconditioner(cycle="V")
    else:
        prec = None
    dt = A1.dtype

    def solve(b):
        if prec is None:
            return ml.coarse_solver(A1, b.astype(dt)).astype(float)
        z, _ = sla.cg(A1, b.astype(dt), M=prec, rtol=rtol, maxiter=int(maxiter))
        return np.asarray(z, dtype=float)

    def apply(r):
        return _per_column(lambda x: P @ solve(np.asarray(P.T @ x, dtype=float)).astype(P.dtype, copy=False),
                           r, order, inv, P.dtype)

    return apply
