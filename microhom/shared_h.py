"""Products with the Hessian ``H`` read from the multilevel hierarchy's own copy of it (issue 26).

``microhom.multilevel.amg_preconditioner`` hands pyamg ``A = P H P^T + s I``: ``H`` permuted to
the particle-major order (``(P x)[i] = x[order[i]]``), shifted by ``s`` (1e-10 of its mean
diagonal) and stored in the particles' ``b x b`` blocks (BSR, 8 bytes per stored entry and 4 per
block). The V-cycle keeps it as its level-0 matrix for the whole CG. :class:`ShiftedCopy` computes
``H x = P^T (A - s I) P x`` from it, so that the relaxation hierarchy can drop the assembly's CSC
``H`` (12 bytes per non-zero: 2.9 GiB at 1e6 spheres) before pyamg's setup
(``docs/results/spheres.md``, "Memory at 1e6 spheres").

The products are not those of ``H`` to the bit: the stored diagonal is ``fl(h_ii + s)``, the sums
run in another order and ``s x`` is subtracted. :meth:`ShiftedCopy.abs_bound` gives what the
hierarchy's round-off margin (``microhom.hierarchy._roundoff``) needs to cover that: for ``x >= 0``
it returns ``|A| x + 2 s x``, and the computed ``y = fl(fl(A x) - fl(s x))`` satisfies, to first
order in the unit round-off ``u``,

    ``|y - H x| <= (m + 3) u (|A| + 2 s I) |x|``

(``m`` = ``m_row``, the stored entries of a row of ``A``: ``u |A|`` for the rounded diagonal,
``m u |A|`` for the sum, ``u s`` for ``fl(s x)``, ``u (|A| + s I)`` for the subtraction).

Shapes: ``n`` unknowns (a multiple of the block size); vectors (n,) or blocks (n, k), float64.
"""
from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

__all__ = ["ShiftedCopy"]


@numba.njit(parallel=True, cache=True)
def _product(A, order, x, shift, absolute, out):
    """``out[order] = (A - shift I) x[order]`` (``absolute``: ``(|A| + shift I) x[order]``) for a
    BSR ``A = (indptr, indices, data)`` (a tuple: the kernel argument rule), ``x`` and ``out``
    (n, k) C-contiguous; one block row per iteration of ``prange`` (the rows are independent)."""
    indptr, indices, data = A
    bs = data.shape[1]
    k = x.shape[1]
    for I in numba.prange(indptr.size - 1):
        acc = np.zeros((bs, k))
        for t in range(indptr[I], indptr[I + 1]):
            J = indices[t]
            for q in range(bs):
                xj = order[J * bs + q]
                for p in range(bs):
                    a = data[t, p, q]
                    if absolute:
                        a = abs(a)
                    for c in range(k):
                        acc[p, c] += a * x[xj, c]
        for p in range(bs):
            i = order[I * bs + p]
            for c in range(k):
                if absolute:
                    out[i, c] = acc[p, c] + shift * x[i, c]
                else:
                    out[i, c] = acc[p, c] - shift * x[i, c]


class ShiftedCopy:
    """``H`` (n, n) as ``P^T (A - s I) P`` from the multilevel hierarchy's level-0 matrix (module
    docstring); symmetric, so ``.T`` is itself.

    Parameters
    ----------
    A : scipy.sparse.bsr_matrix (n, n), float64
        ``P H P^T + s I`` in ``b x b`` blocks (``amg_preconditioner``'s ``op.amg[0].levels[0].A``;
        a CSR one, for mixed particle blocks, is read as 1 x 1 blocks without a copy).
    order : (n,) int array
        The permutation: ``(P x)[i] = x[order[i]]``.
    shift : float
        ``s`` [N/m] (``op.shift``), >= 0.
    """

    def __init__(self, A, order, shift):
        if not (sp.issparse(A) and A.format in ("bsr", "csr") and A.dtype == np.float64):
            raise ValueError(f"A must be a float64 BSR (or CSR) matrix, got {type(A).__name__}"
                             f" {getattr(A, 'format', '')} {getattr(A, 'dtype', '')}")
        if A.format == "csr":            # mixed particle blocks: 1 x 1 blocks, the same arrays
            A = sp.bsr_matrix((A.data.reshape(-1, 1, 1), A.indices, A.indptr), shape=A.shape)
        n = A.shape[0]
        order = np.ascontiguousarray(order, dtype=np.int64)
        if A.shape != (n, n) or order.shape != (n,):
            raise ValueError(f"A must be square and order of shape (n,), got A {A.shape}, order {order.shape}")
        if not (np.isfinite(shift) and shift >= 0):
            raise ValueError(f"shift must be a finite number >= 0, got {shift!r}")
        self.A, self.order, self.shift = A, order, float(shift)
        self.shape, self.dtype, self.ndim = (n, n), np.dtype(np.float64), 2
        #: stored entries in a row of A (an upper bound of the non-zeros of a row of H)
        self.m_row = int(A.blocksize[1] * np.diff(A.indptr).max(initial=0))

    @property
    def T(self):
        return self

    def _apply(self, x, absolute):
        x = np.asarray(x, dtype=np.float64)
        one = x.ndim == 1
        xc = np.ascontiguousarray(x[:, None] if one else x)
        if xc.shape[0] != self.shape[0]:
            raise ValueError(f"x must have {self.shape[0]} rows, got shape {x.shape}")
        out = np.empty_like(xc)
        A = self.A
        _product((A.indptr, A.indices, A.data), self.order, xc, self.shift, absolute, out)
        return out[:, 0] if one else out

    def __matmul__(self, x):
        """``H x`` [N/m times the unit of x], (n,) or (n, k)."""
        return self._apply(x, False)

    def dot(self, x):
        return self._apply(x, False)

    def abs_bound(self, x):
        """``|A| x + 2 s x`` for ``x >= 0`` (n,) or (n, k): entrywise at least ``(|H| + s I) x``
        to first order in u (``|h_ii| <= |a_ii| (1 + u) + s``); what the round-off margin of a
        product takes in place of ``|H| x`` (module docstring)."""
        y = self._apply(x, True)
        return y + self.shift * np.asarray(x, dtype=np.float64)
