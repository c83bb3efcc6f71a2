"""The two-level statics' coarse solve without a factorisation (issue 26; docs/theory.md section 12,
"Two-level statics", "The coarse solve").

The coarse matrix ``Hc = R^T H R`` (n, n), n = b * (clusters), ``b`` unknowns per cluster (3 in 2D,
6 in 3D: its rigid translations and rotations, unknowns ordered cluster by cluster) is positive
semi-definite and singular: by the global translations and by the *local* mechanisms of the
clusters of one particle (a sphere held by two contacts spins about their axis), whose directions
are null vectors of the cluster's own b x b diagonal block. :func:`amg_solver` removes those
directions (eigenvalue of the diagonal block below ``NULL_TOL`` of its largest), scales each
block to the identity (``x = Lambda^1/2 V^T y`` on the kept directions) and solves the scaled
system by CG preconditioned with pyamg's smoothed aggregation (block size b, block Gauss-Seidel
smoothing) to a relative residual ``RTOL``; memory O(nnz(Hc)), where the factor's fill grows with
the clusters' separators. The right-hand side is projected on the complement of the global
translations (it is in the range of ``Hc`` up to round-off). When a column does not reach
``CHECK`` in the unscaled system (an indefinite ``Hc``, a pre-stressed ``H``), the solve falls back
to the factor of :func:`factor_solver` (built then, once).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sps

__all__ = ["NULL_TOL", "RTOL", "CHECK", "MAXITER", "factor_solver", "amg_solver"]

#: a diagonal block's eigenvalue below this fraction of its largest is a local mechanism (measured
#: gap on the benchmark's networks: below 3e-16 or above 1e-3)
NULL_TOL = 1e-8
#: relative residual of the scaled system at which CG stops
RTOL = 1e-14
#: relative residual ``|z - Hc y| / |z|`` (per column) above which the factor takes over
CHECK = 1e-12
#: CG steps per column before the factor takes over
MAXITER = 500


def factor_solver(Hc, dim: int, backend: str):
    """``z -> y`` with ``Hc y = z`` (z (n, s)): the factor of ``Hc + 1e-10 mean(diag) I`` by
    ``microhom.factor.factor(backend=backend)`` and three refinement steps (the former solve)."""
    from .factor import factor
    dg = Hc.diagonal()
    shift = 1e-10 * float(dg[dg > 0].mean()) if (dg > 0).any() else 1.0
    lu = factor((Hc + shift * sps.eye(Hc.shape[0])).tocsr(), spd=True, dim=dim, backend=backend)

    def solve(z):
        y = np.asarray(lu.solve(np.ascontiguousarray(z))).reshape(z.shape)
        for _ in range(3):
            y += np.asarray(lu.solve(np.ascontiguousarray(z - Hc @ y))).reshape(z.shape)
        return y
    return solve


def _scaling(Hb, b):
    """Block-diagonal ``P`` (n, n) [BSR, b x b blocks]: ``V_k diag(s_k)`` with ``D_k = V_k
    diag(w_k) V_k^T`` the k-th diagonal block of ``Hb``, ``s = w^-1/2`` on the kept directions and
    1 on the mechanisms; ``null`` (n,) bool: the mechanisms' directions."""
    nb = Hb.shape[0] // b
    rows = np.repeat(np.arange(nb), np.diff(Hb.indptr))
    D = np.zeros((nb, b, b))
    on = rows == Hb.indices
    D[rows[on]] = Hb.data[on]
    w, V = np.linalg.eigh(D)
    keep = w > NULL_TOL * np.maximum(w[:, -1:], 0.0)
    keep &= w > 0
    s = np.where(keep, 1.0 / np.sqrt(np.where(keep, w, 1.0)), 1.0)
    P = sps.bsr_matrix((V * s[:, None, :], np.arange(nb), np.arange(nb + 1)), shape=Hb.shape)
    return P, ~keep.ravel()


def amg_solver(Hc, b: int, dim: int, fallback: str = "auto"):
    """``z -> y`` with ``Hc y = z`` (z (n, s) in the range of ``Hc``; module docstring): CG on the
    block-scaled system without the local mechanisms, preconditioned by smoothed aggregation
    (``b`` unknowns per block); the factor (``fallback`` back end) where a column misses ``CHECK``."""
    import pyamg
    from pyamg.krylov import cg
    n = Hc.shape[0]
    if b < 1 or n % b:
        raise ValueError(f"b must divide the coarse unknowns ({n}), got {b}")
    Hb = sps.csr_matrix(Hc).tobsr(blocksize=(b, b))
    P, null = _scaling(Hb, b)
    A = (P.T @ Hb @ P).tocsr() + sps.diags(null.astype(float))
    ml = pyamg.smoothed_aggregation_solver(A.tobsr(blocksize=(b, b)), max_coarse=500, keep=False,
                                           presmoother=("block_gauss_seidel", {"sweep": "symmetric"}),
                                           postsmoother=("block_gauss_seidel", {"sweep": "symmetric"}))
    M = ml.aspreconditioner(cycle="V")
    T = np.zeros((n, 0))
    if dim in (2, 3):                          # the global translations, orthonormal
        T = np.zeros((n, dim))
        for a in range(dim):
            T[a::b, a] = 1.0 / np.sqrt(n // b)
    back = []

    def solve(z):
        z = np.asarray(z, dtype=float)
        zp = z - T @ (T.T @ z)
        zr = np.asarray(P.T @ zp)
        zr[null] = 0.0
        # pyamg's CG, column by column, to the relative residual RTOL
        x = np.zeros_like(zr)
        for j in range(zr.shape[1]):
            x[:, j] = cg(A, zr[:, j], tol=RTOL, criteria="rr", maxiter=MAXITER, M=M)[0]
        y = np.asarray(P @ x)
        nz = np.linalg.norm(zp, axis=0)
        if (np.linalg.norm(zp - Hc @ y, axis=0) > CHECK * np.where(nz > 0, nz, 1.0)).any():
            if not back:
                back.append(factor_solver(Hc, dim, fallback))
            return back[0](z)
        return y
    return solve
