"""pyamg's V-cycle applied to several columns at once, in parallel over the columns (issue 26).

``microhom.multilevel.amg_preconditioner`` builds pyamg's smoothed-aggregation hierarchy; the
hierarchy's block CG then applies its V-cycle to the 6 (3D) or 3 (2D) load columns at every order.
pyamg's cycle (``MultilevelSolver.aspreconditioner(cycle="V")``: ``solve`` with ``maxiter=1`` from
``x = 0``) runs one column at a time in C++ that holds the GIL (measured, docs/results/spheres.md,
"Both cores for the V-cycle"), so it uses one core of two. :class:`VCycle` does the same
operations on the same arrays as numba kernels, each column's cycle sequential (the Gauss-Seidel
sweeps are), the columns spread over the threads (``numba.prange``). Per level ``l`` (``A_l``,
its prolongator ``P_l``, restriction ``P_l^T``), from ``x_0 = 0`` and ``b_0`` the column:

1. pre-smoothing: ``sweeps`` symmetric block Gauss-Seidel sweeps on ``A_l x_l = b_l`` (a forward
   then a backward sweep over the block rows; each block row ``i``:
   ``x_i = D_i^-1 (b_i - sum_{j != i} A_ij x_j)``, ``D_i^-1`` pyamg's inverted diagonal block,
   the pointwise order of pyamg's ``amg_core::block_gauss_seidel``);
2. ``b_{l+1} = P_l^T (b_l - A_l x_l)`` (residual and restriction fused, block row by block row,
   in the order of scipy's BSR product and of ``microhom.multilevel._bsr_rmatvec``);
3. ``x_{l+1} = 0``, recursively; at the coarsest level pyamg's own coarse solver (its
   pseudo-inverse, ``np.dot`` per column: the same call as pyamg's);
4. ``x_l += P_l x_{l+1}`` (scipy's BSR product order, then the sum);
5. post-smoothing as 1.

Every sum is taken in pyamg's and scipy's order (no fused multiply-add: numba does not contract
without ``fastmath``), so each column equals pyamg's V-cycle bit for bit
(tests/test_vcycle.py), whatever ``NUMBA_NUM_THREADS``. pyamg's cycle also evaluates
``||b - A x||`` twice per application (its stopping test, unused by a preconditioner): two
products with ``A_0`` that this one does not do.

Mixed precision (``amg_preconditioner(coarse_dtype=np.float32)``, issue 26): a float64 level
whose prolongator and coarse level are float32. Its residual and smoothing stay float64; step 2
sums ``P^T r`` in float64 (``P``'s float32 entries widen exactly) and rounds ``b_{l+1}`` once to
float32; the coarse levels run in float32 as a float32 hierarchy does; step 4 widens ``x_{l+1}``
to float64 (exactly) and adds ``P x_{l+1}``, summed in float64, into the float64 iterate. These
are scipy's float64 products with the widened arrays, in their order (tests/test_vcycle.py checks
the mixed cycle against such a reference to the bit).

Supported: every level's smoother ``block_gauss_seidel`` (``sweep="symmetric"``, square BSR
blocks, its ``Dinv`` in the level's dtype), prolongators BSR with the restriction their
transpose (``R = P.T`` or ``multilevel._Restriction``) in the coarse level's dtype, each level
the dtype of the one above or float32 below float64, at least two levels. :meth:`VCycle.of`
returns None otherwise (the caller keeps pyamg's cycle).

Memory: ``2 s n_l`` floats per level (iterate and right-hand side of each column) held during an
application, against two of ``n_l`` per column in turn for pyamg's.
"""
from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

__all__ = ["VCycle"]


def _groups(s):
    """(G, 2) column ranges: ``s`` columns in G = min(s, numba's threads) contiguous groups, one
    per thread (a thread applies the cycle to its group's columns together)."""
    G = max(1, min(s, numba.get_num_threads()))
    g = np.arange(G + 1) * s // G
    return np.ascontiguousarray(np.stack([g[:-1], g[1:]], axis=1), dtype=np.int64)


@numba.njit(cache=True)
def _gs_sweep(A, Dinv, X, B, cols, rows):
    """One block Gauss-Seidel sweep on ``A x = b`` (``A`` = (indptr, indices, data) BSR, square
    blocks ``bs x bs``; ``Dinv`` (nb, bs, bs) the inverted diagonal blocks) over the block rows
    ``range(*rows)``, for the rows ``x`` of ``X`` and ``b`` of ``B`` in ``range(*cols)`` together
    (each block of ``A`` read once for them), ``X`` updated in place: per column, pyamg's
    ``block_gauss_seidel`` sum for sum (``v = A_ij x_j`` from 0, ``rsum += v``, ``x_i = Dinv_i
    (b_i - rsum)`` from 0)."""
    indptr, indices, data = A
    bs = data.shape[1]
    c0, g = cols[0], cols[1] - cols[0]
    zero = np.zeros(1, dtype=X.dtype)[0]
    rsum = np.empty((g, bs), dtype=X.dtype)
    for i in range(rows[0], rows[1], rows[2]):
        rsum[:] = zero
        for jj in range(indptr[i], indptr[i + 1]):
            j = indices[jj]
            if j == i:
                continue
            for c in range(g):
                for k in range(bs):
                    acc = zero
                    for m in range(bs):
                        acc += data[jj, k, m] * X[c0 + c, j * bs + m]
                    rsum[c, k] += acc
        for c in range(g):
            for k in range(bs):
                rsum[c, k] = B[c0 + c, i * bs + k] - rsum[c, k]
            for k in range(bs):
                acc = zero
                for m in range(bs):
                    acc += Dinv[i, k, m] * rsum[c, m]
                X[c0 + c, i * bs + k] = acc


@numba.njit(cache=True, parallel=True)
def _smooth(A, Dinv, X, B, sweeps, groups):
    """``sweeps`` symmetric block Gauss-Seidel sweeps (forward, backward) on ``A x = b`` for each
    row ``x`` of ``X`` (s, n) and ``b`` of ``B`` (s, n), in place; the groups of rows
    (``_groups``) in parallel."""
    nb = A[0].size - 1
    for t in numba.prange(groups.shape[0]):
        cols = (groups[t, 0], groups[t, 1])
        for _ in range(sweeps):
            _gs_sweep(A, Dinv, X, B, cols, (0, nb, 1))
            _gs_sweep(A, Dinv, X, B, cols, (nb - 1, -1, -1))


@numba.njit(cache=True, parallel=True)
def _restrict_residual(A, P, X, B, Bc, groups):
    """``Bc[c] += P^T (B[c] - A X[c])`` for each row ``c`` (``A``, ``P`` (indptr, indices, data)
    BSR; ``Bc`` zero on entry): the residual of a block row (scipy's BSR product order: each
    output accumulated block by block), then its share of ``P^T`` (``_bsr_rmatvec``'s order);
    groups of rows in parallel, each block read once per group."""
    ia, ja, da = A
    ip, jp, dp = P
    bs = da.shape[1]
    r, cc = dp.shape[1], dp.shape[2]
    for t in numba.prange(groups.shape[0]):
        c0, g = groups[t, 0], groups[t, 1] - groups[t, 0]
        y = np.empty((g, bs), dtype=X.dtype)
        for i in range(ia.size - 1):
            y[:] = 0
            for jj in range(ia[i], ia[i + 1]):
                j = ja[jj]
                for c in range(g):
                    for k in range(bs):
                        dot = y[c, k]
                        for m in range(bs):
                            dot += da[jj, k, m] * X[c0 + c, j * bs + m]
                        y[c, k] = dot
            for c in range(g):
                for k in range(bs):
                    y[c, k] = B[c0 + c, i * bs + k] - y[c, k]
            for kk in range(ip[i], ip[i + 1]):
                J = jp[kk]
                for c in range(g):
                    for q in range(cc):
                        dot = Bc[c0 + c, J * cc + q]
                        for p in range(r):
                            dot += dp[kk, p, q] * y[c, p]
                        Bc[c0 + c, J * cc + q] = dot


@numba.njit(cache=True, parallel=True)
def _prolong(P, Xc, X, groups):
    """``X[c] += P Xc[c]`` for each row ``c`` (``P`` (indptr, indices, data) BSR): scipy's BSR
    product into a block row, then the sum, as ``x += P @ xc``; groups of rows in parallel."""
    ip, jp, dp = P
    r, cc = dp.shape[1], dp.shape[2]
    for t in numba.prange(groups.shape[0]):
        c0, g = groups[t, 0], groups[t, 1] - groups[t, 0]
        y = np.empty((g, r), dtype=X.dtype)
        for i in range(ip.size - 1):
            y[:] = 0
            for kk in range(ip[i], ip[i + 1]):
                J = jp[kk]
                for c in range(g):
                    for p in range(r):
                        dot = y[c, p]
                        for q in range(cc):
                            dot += dp[kk, p, q] * Xc[c0 + c, J * cc + q]
                        y[c, p] = dot
            for c in range(g):
                for p in range(r):
                    X[c0 + c, i * r + p] = X[c0 + c, i * r + p] + y[c, p]


@numba.njit(cache=True, parallel=True)
def _gather(r, order, B):
    """``B[c, i] = r[order[i], c]`` (cast to ``B``'s dtype), ``r`` (n, s), ``B`` (s, n)."""
    for c in numba.prange(B.shape[0]):
        for i in range(order.size):
            B[c, i] = r[order[i], c]


@numba.njit(cache=True, parallel=True)
def _scatter(X, order, out):
    """``out[order[i], c] = X[c, i]`` (cast to float64), ``X`` (s, n), ``out`` (n, s)."""
    for c in numba.prange(X.shape[0]):
        for i in range(order.size):
            out[order[i], c] = X[c, i]


def _bsr(M):
    """(indptr, indices, data) of a BSR matrix."""
    return (M.indptr, M.indices, M.data)


def _smoother(f):
    """(sweeps, Dinv) of pyamg's symmetric ``block_gauss_seidel`` smoother ``f``, else None."""
    kw = getattr(f, "keywords", None)
    func = getattr(f, "func", None)
    if kw is None or func is None or func.__name__ != "block_gauss_seidel" or f.args:
        return None
    if kw.get("sweep") != "symmetric" or kw.get("Dinv") is None or int(kw.get("iterations", 0)) < 1:
        return None
    return int(kw["iterations"]), np.ascontiguousarray(kw["Dinv"])


class VCycle:
    """pyamg's V-cycle of a hierarchy ``ml`` (``pyamg.MultilevelSolver``) on many columns at
    once (module docstring). Build it with :meth:`of`; ``vc(B)`` for ``B`` (s, n) in ``ml``'s
    dtype and unknowns' order returns ``X`` (s, n), each row the V-cycle of that row of ``B``."""

    def __init__(self, ml, levels, coarse):
        self.ml = ml
        self.levels = levels             # per level but the coarsest: (A, P, pre, post, coarse n, coarse dtype)
        self.coarse = coarse             # the coarsest level's matrix (pyamg's coarse solver's input)
        self.dtype = ml.levels[0].A.dtype
        self.n = ml.levels[0].A.shape[0]

    @classmethod
    def of(cls, ml):
        """The parallel V-cycle of ``ml``, or None where it is outside what this module does
        (module docstring: then pyamg's ``aspreconditioner`` is the one to use)."""
        if len(ml.levels) < 2:
            return None
        levels = []
        for lvl, coarse in zip(ml.levels[:-1], ml.levels[1:]):
            A, P, R = lvl.A, getattr(lvl, "P", None), getattr(lvl, "R", None)
            if not (sp.issparse(A) and A.format == "bsr" and A.blocksize[0] == A.blocksize[1] > 1
                    and sp.issparse(P) and P.format == "bsr" and P.blocksize[0] == A.blocksize[0]
                    and P.dtype == coarse.A.dtype and _precisions(A.dtype, P.dtype)):
                return None
            # R: multilevel._Restriction (P^T from P) or pyamg's transposed copy
            if getattr(R, "P", None) is not P and not _is_transpose(R, P):
                return None
            pre, post = _smoother(lvl.presmoother), _smoother(lvl.postsmoother)
            shape = (A.shape[0] // A.blocksize[0],) + A.blocksize
            if any(f is None or f[1].shape != shape or f[1].dtype != A.dtype for f in (pre, post)):
                return None
            if any(getattr(f, "keywords", {}).get("blocksize") not in (None, A.blocksize[0])
                   for f in (lvl.presmoother, lvl.postsmoother)):
                return None                              # pyamg would re-block A: not this cycle
            levels.append((_bsr(A), _bsr(P), pre, post, P.shape[1], P.dtype))
        return cls(ml, levels, ml.levels[-1].A)

    def __call__(self, B):
        B = np.ascontiguousarray(B, dtype=self.dtype)
        if B.ndim != 2 or B.shape[1] != self.n:
            raise ValueError(f"VCycle: B must have shape (s, {self.n}), got {B.shape}")
        return self._cycle(B)

    def _cycle(self, B):
        s = B.shape[0]
        groups = _groups(s)
        xs, bs = [], [B]
        for A, P, pre, _, nc, cdt in self.levels:
            b = bs[-1]
            x = np.zeros((s, b.shape[1]), dtype=b.dtype)
            _smooth(A, pre[1], x, b, pre[0], groups)
            bc = np.zeros((s, nc), dtype=b.dtype)             # summed in this level's precision ...
            _restrict_residual(A, P, x, b, bc, groups)
            xs.append(x)
            bs.append(bc.astype(cdt, copy=False))             # ... then rounded to the coarse one
        solve = self.ml.coarse_solver
        xc = np.empty_like(bs[-1])
        for c in range(s):
            xc[c] = solve(self.coarse, bs[-1][c].copy())
        for (A, P, _, post, _, _), x, b in zip(self.levels[::-1], xs[::-1], bs[-2::-1]):
            _prolong(P, xc.astype(x.dtype, copy=False), x, groups)   # exact widening: P x_c in x's precision
            _smooth(A, post[1], x, b, post[0], groups)
            xc = x
        return xc

    def apply(self, r, order):
        """The V-cycle of each column of ``r`` ((n,) or (n, s), float64, unknowns in the order
        ``order`` maps from: ``ml``'s unknown ``i`` is ``r[order[i]]``), cast to ``ml``'s dtype;
        the result in ``r``'s order and float64, shaped and laid out (C or Fortran) as ``r``."""
        r = np.asarray(r, dtype=float)
        r2 = r.reshape(r.shape[0], -1)
        B = np.empty((r2.shape[1], self.n), dtype=self.dtype)
        _gather(r2, order, B)
        X = self._cycle(B)
        out = np.empty_like(r2)                            # r's memory layout, as pyamg's path kept it
        _scatter(X, order, out)
        return out.reshape(r.shape)


def _precisions(fine, coarse):
    """Whether a level of dtype ``fine`` may have its coarse level (and ``P``) in ``coarse``: the
    same, or float64 over float32 (the mixed cycle)."""
    return fine == coarse or (fine == np.float64 and coarse == np.float32)


def _is_transpose(R, P):
    """Whether the BSR ``R`` is exactly ``P.T`` (array for array)."""
    if not (sp.issparse(R) and R.format == "bsr"):
        return False
    T = P.T
    return (T.blocksize == R.blocksize and T.shape == R.shape and T.dtype == R.dtype
            and all(np.array_equal(a, b) for a, b in ((T.indptr, R.indptr), (T.indices, R.indices),
                                                      (T.data, R.data))))
