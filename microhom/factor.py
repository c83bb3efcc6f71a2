"""Sparse symmetric factorisation back ends, their inertia and a memory guard.

One interface over the direct solvers the exact stiffness (``dem.analysis.stiffness``) and the certified
spectral bound (:mod:`microhom.spectral`) need:

- ``"pardiso"``: Intel MKL PARDISO (the ``mkl`` wheel from PyPI, x86-64 Linux and Windows),
  supernodal, multi-threaded, METIS nested dissection. Real symmetric *indefinite* mode (matrix type
  -2, Bunch-Kaufman pivoting) reports the **inertia** of the factorised matrix (numbers of positive
  and negative pivots, ``iparm(22)``/``iparm(23)``, Sylvester's law of inertia) and predicts its
  memory in the analysis phase, before the numeric factorisation allocates.
- ``"cholmod"``: CHOLMOD supernodal Cholesky (``scikit-sparse``, optional: builds only against
  Debian's SuiteSparse headers); positive definite matrices only, inertia (n, 0, 0) when it
  succeeds.
- ``"splu"``: scipy's SuperLU with symmetric diagonal pivoting: always available; the inertia is
  read from the signs of its pivots when it pivoted symmetrically (the pivots are those of
  ``LDL^T``), and is not reported otherwise.

:func:`factor` picks ``"auto"``: PARDISO where the ``mkl`` wheel is installed, else CHOLMOD for
positive definite matrices, else SuperLU (``docs/stiffness.md``: measured candidates).
:func:`inertia` counts the eigenvalues of a symmetric matrix below zero.
:func:`memory_check` refuses a factorisation whose predicted size exceeds the available memory.
"""
from __future__ import annotations

import ctypes
import glob
import os
import sys
from ctypes.util import find_library
from dataclasses import dataclass

import numpy as np
from .limits import available_memory  # noqa: F401 - part of this API (one implementation)
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from microhom.results import Result

__all__ = ["BACKENDS", "Inertia", "Factor", "factor", "inertia", "available_backends", "have_pardiso",
           "have_cholmod", "NotPositiveDefinite", "FactorisationError", "MemoryGuardError",
           "memory_check", "predicted_factor_bytes"]

BACKENDS = ("auto", "pardiso", "cholmod", "splu")


class NotPositiveDefinite(RuntimeError):
    """A Cholesky factorisation met a non-positive pivot: the matrix is not positive definite."""


class FactorisationError(RuntimeError):
    """A back end failed (PARDISO error code, singular SuperLU) or perturbed pivots, so its
    inertia is not that of the input matrix."""


class MemoryGuardError(MemoryError):
    """The predicted memory of a factorisation exceeds what the machine has available."""


# ---- availability ----------------------------------------------------------------------------
try:    # optional: CHOLMOD (scikit-sparse, built against Debian's libsuitesparse-dev)
    import sksparse.cholmod as _cholmod
except ImportError:     # pragma: no cover - depends on the machine
    _cholmod = None

_MKL = None             # the loaded mkl_rt, or False once looked for and not found


def _load_mkl():
    """mkl_rt from the ``mkl`` wheel (``sys.prefix/lib``), the user site, or the system path;
    False when absent. The environment variable ``MICROHOM_MKL_RT`` names another file."""
    global _MKL
    if _MKL is not None:
        return _MKL
    cands = [os.environ.get("MICROHOM_MKL_RT")]
    for base in (sys.prefix, getattr(sys, "base_prefix", sys.prefix)):
        cands += sorted(glob.glob(os.path.join(base, "lib", "libmkl_rt.so*")), key=len)
        cands += sorted(glob.glob(os.path.join(base, "Library", "bin", "mkl_rt*.dll")), key=len)
    cands.append(find_library("mkl_rt"))
    for c in cands:
        if not c:
            continue
        try:
            lib = ctypes.CDLL(c)
            lib.pardiso          # noqa: B018 - the symbol must exist
        except (OSError, AttributeError):
            continue
        _setup_pardiso(lib)
        _MKL = lib
        return lib
    _MKL = False
    return False


def _setup_pardiso(lib):
    i32p = ctypes.POINTER(ctypes.c_int32)
    lib.pardiso.argtypes = [ctypes.POINTER(ctypes.c_int64), i32p, i32p, i32p, i32p, i32p,
                            ctypes.c_void_p, i32p, i32p, i32p, i32p, i32p, i32p,
                            ctypes.c_void_p, ctypes.c_void_p, i32p]
    lib.pardiso.restype = None


def have_pardiso() -> bool:
    """True when MKL PARDISO is loadable (``pip install mkl``; x86-64 only)."""
    return bool(_load_mkl())


def have_cholmod() -> bool:
    """True when CHOLMOD is importable (``scikit-sparse``: needs Debian's ``libsuitesparse-dev``)."""
    return _cholmod is not None


def available_backends() -> tuple:
    """The back ends usable on this machine, in the order ``"auto"`` prefers them."""
    return tuple(b for b, ok in (("pardiso", have_pardiso()), ("cholmod", have_cholmod()),
                                 ("splu", True)) if ok)


# ---- results ---------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Inertia(Result):
    """Inertia of a real symmetric matrix ``A`` (n, n): ``n_pos``, ``n_neg`` numbers of positive and
    negative pivots of its ``LDL^T`` (Sylvester's law of inertia: the numbers of positive and
    negative eigenvalues of ``A``), ``n_zero = n - n_pos - n_neg`` (exactly zero pivots; with
    PARDISO, pivots below its perturbation threshold); ``backend`` the solver that counted."""

    n_pos: int
    n_neg: int
    n_zero: int
    backend: str


# ---- memory guard ----------------------------------------------------------------------------


#: fitted factor size of the 2D contact Hessians (nested dissection / AMD on the particle graph):
#: non-zeros of L ~ _NNZ_COEF * n * log2(n) for n unknowns (measured with PARDISO on the
#: benchmark networks: 2.95e5 unknowns -> see docs/stiffness.md "Memory guard")
_NNZ_COEF = 4.0
#: bytes per non-zero of the factor including indices and work space, per back end (measured peaks)
_BYTES_PER_NNZ = {"pardiso": 20.0, "cholmod": 12.0, "splu": 80.0}
#: fixed work space of a factorisation [bytes]
_FIXED_BYTES = 32e6


def predicted_factor_bytes(n: int, backend: str = "pardiso") -> float:
    """Predicted memory [bytes] of the sparse factorisation of a 2D contact Hessian with ``n``
    unknowns (before anything is allocated): ``_NNZ_COEF n log2 n`` non-zeros of ``L`` times the
    measured bytes per non-zero of the back end, plus ``_FIXED_BYTES`` (``docs/stiffness.md``, "Memory guard")."""
    n = max(int(n), 2)
    return _NNZ_COEF * n * np.log2(n) * _BYTES_PER_NNZ.get(backend, 40.0) + _FIXED_BYTES


def memory_check(need: float, what: str, limit: float | None = None):
    """Raise :class:`MemoryGuardError` naming the figure when ``need`` [bytes] exceeds ``limit``
    (default: :func:`microhom.limits.available_memory`; the environment variable ``MICROHOM_MEMORY_LIMIT`` [GB]
    lowers it). Returns ``need``."""
    avail = available_memory()
    env = os.environ.get("MICROHOM_MEMORY_LIMIT")
    if env:
        avail = min(avail, float(env) * 1e9)
    if limit is not None:
        avail = min(avail, float(limit))
    if need > avail:
        raise MemoryGuardError(
            f"{what}: predicted {need / 1e9:.3g} GB, available {avail / 1e9:.3g} GB; refused before "
            f"allocating (allowed: predicted size <= available memory; pass max_memory= or set "
            f"MICROHOM_MEMORY_LIMIT [GB] to change the limit)")
    return need


# ---- factor objects --------------------------------------------------------------------------
class Factor:
    """A factorisation of a real symmetric matrix ``A`` (n, n): ``solve(b)`` for (n,) or (n, k)
    ``b``; ``inertia()`` an :class:`Inertia` (or None when the back end cannot tell);
    ``pivots()`` (relative pivots, reliable?) where available; ``name`` the back end;
    ``nnz`` non-zeros of the factor (or None); ``release()`` frees its memory."""

    name = "?"
    nnz = None

    def solve(self, b):
        raise NotImplementedError

    def inertia(self):
        return None

    def pivots(self):
        return None, False

    def release(self):
        pass


class _Pardiso(Factor):
    """MKL PARDISO of a real symmetric matrix: ``spd=True`` Cholesky (matrix type 2; raises
    :class:`NotPositiveDefinite`), else Bunch-Kaufman ``LDL^T`` (type -2) with its inertia.
    The analysis (phase 11) predicts the memory; :func:`memory_check` runs before phase 22."""

    name = "pardiso"

    def __init__(self, A, spd=False, *, max_memory=None, perm=None, threads=None, upper=False,
                 matching=True):
        lib = _load_mkl()
        if not lib:
            raise RuntimeError("backend 'pardiso' needs the mkl wheel: pip install mkl (x86-64)")
        self._lib = lib
        n = A.shape[0]
        if upper:     # the caller's upper triangle (CSR, sorted indices), taken as is
            U = A
        else:
            U = sp.triu(A, format="csr")
            U.sort_indices()
        self.n = n
        self.mtype = 2 if spd else -2
        self._a = np.ascontiguousarray(U.data, dtype=np.float64)
        self._ia = (U.indptr + 1).astype(np.int32)
        self._ja = (U.indices + 1).astype(np.int32)
        self.pt = np.zeros(64, dtype=np.int64)
        ip = np.zeros(64, dtype=np.int32)
        ip[0] = 1          # iparm given
        ip[1] = 2          # METIS nested dissection
        ip[3] = 0
        ip[4] = 0 if perm is None else 1
        ip[7] = 0          # no automatic refinement (the caller refines against the true matrix)
        ip[9] = 13         # pivot perturbation 1e-13 (counted in iparm(14), checked by callers)
        # symmetric scaling and weighted matching (congruences: the inertia is kept) for strongly
        # indefinite matrices: fewer perturbed pivots; off for nearly semi-definite ones (the
        # stiffness H - eta diag H without pre-stress), where they cost 17 % of the time at 1e5
        ip[10] = 1 if matching else 0
        ip[12] = 1 if matching else 0
        ip[17] = -1        # report nnz of the factor
        ip[20] = 1         # Bunch-Kaufman 1x1 and 2x2 pivoting (type -2)
        ip[23] = 0
        ip[26] = 0
        ip[34] = 0         # one-based indices
        ip[55] = 0
        self.iparm = ip
        self._perm = (np.asarray(perm, dtype=np.int32) + 1) if perm is not None else np.zeros(n, np.int32)
        self._released = False
        if threads is not None:
            lib.MKL_Set_Num_Threads(ctypes.c_int(int(threads)))
        self._call(11)
        self.predicted_bytes = 1024.0 * (max(int(ip[14]), int(ip[15]) + int(ip[16])))
        try:
            memory_check(self.predicted_bytes, f"PARDISO factorisation of {n} unknowns "
                         f"({int(ip[17]):,} non-zeros in the factor)", max_memory)
        except MemoryGuardError:
            self.release()
            raise
        try:
            self._call(22)
        except FactorisationError as exc:
            self.release()
            if spd and "-4" in str(exc):
                raise NotPositiveDefinite(str(exc)) from None
            raise
        self.nnz = int(ip[17])
        self.n_perturbed = int(ip[13])
        if spd and (int(ip[22]) > 0 or int(ip[13]) > 0):
            self.release()
            raise NotPositiveDefinite(f"PARDISO Cholesky: {int(ip[22])} negative, {int(ip[13])} "
                                      "perturbed pivot(s)")

    def refactor(self, data):
        """Numeric factorisation of a matrix with the *same* upper-triangular pattern (``data``
        in the order of ``triu(A, format="csr")`` with sorted indices), reusing the analysis (the
        ordering and the symbolic factor); the previous factor is replaced."""
        if self._released:
            raise RuntimeError("this PARDISO factor was released")
        data = np.ascontiguousarray(data, dtype=np.float64)
        if data.shape != self._a.shape:
            raise ValueError(f"refactor needs {self._a.size} values, got {data.size}")
        self._a = data
        self._call(22)
        self.n_perturbed = int(self.iparm[13])
        return self

    def _call(self, phase, b=None):
        n = self.n
        nrhs = 1 if b is None or b.ndim == 1 else b.shape[1]
        if b is None:
            b = np.zeros(n)
        x = np.zeros_like(b)
        err = ctypes.c_int32(0)
        i32 = ctypes.c_int32
        self._lib.pardiso(self.pt.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)), ctypes.byref(i32(1)),
                          ctypes.byref(i32(1)), ctypes.byref(i32(self.mtype)), ctypes.byref(i32(phase)),
                          ctypes.byref(i32(n)), self._a.ctypes.data,
                          self._ia.ctypes.data_as(ctypes.POINTER(i32)),
                          self._ja.ctypes.data_as(ctypes.POINTER(i32)),
                          self._perm.ctypes.data_as(ctypes.POINTER(i32)), ctypes.byref(i32(nrhs)),
                          self.iparm.ctypes.data_as(ctypes.POINTER(i32)), ctypes.byref(i32(0)),
                          b.ctypes.data, x.ctypes.data, ctypes.byref(err))
        if err.value != 0:
            raise FactorisationError(f"PARDISO phase {phase} failed with error {err.value}")
        return x

    def solve(self, b):
        if self._released:
            raise RuntimeError("this PARDISO factor was released")
        b = np.asarray(b, dtype=np.float64)
        bf = np.asfortranarray(b)
        x = self._call(33, bf)
        return np.ascontiguousarray(x)

    def inertia(self):
        """Numbers of positive / negative pivots of the Bunch-Kaufman ``LDL^T`` (type -2), or
        (n, 0) for a successful Cholesky; ``n_zero`` counts perturbed pivots, which make the
        count that of a perturbed matrix (callers refuse to certify with them)."""
        ip = self.iparm
        if self.mtype == 2:
            return Inertia(self.n, 0, int(ip[13]), "pardiso")
        npos, nneg = int(ip[21]), int(ip[22])
        return Inertia(npos, nneg, self.n - npos - nneg, "pardiso")

    def release(self):
        if not self._released:
            try:
                self._call(-1)
            except FactorisationError:   # pragma: no cover
                pass
            self._released = True

    def __del__(self):
        try:
            self.release()
        except Exception:   # noqa: BLE001 - interpreter shutdown
            pass


class _SuperLU(Factor):
    """scipy SuperLU with symmetric diagonal pivoting (``SymmetricMode``, ``MMD_AT_PLUS_A``,
    ``diag_pivot_thresh=0``): when it pivoted symmetrically, its pivots are those of ``LDL^T`` and
    their signs give the inertia. Always available."""

    name = "splu"

    def __init__(self, A, *, max_memory=None):
        A = sp.csc_matrix(A)
        memory_check(predicted_factor_bytes(A.shape[0], "splu"),
                     f"SuperLU factorisation of {A.shape[0]} unknowns", max_memory)
        try:
            self.lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options=dict(SymmetricMode=True))
        except RuntimeError as exc:       # exactly singular
            raise FactorisationError(f"SuperLU: {exc}") from None
        self.symmetric = bool(np.array_equal(self.lu.perm_r, self.lu.perm_c))
        self._A = A
        self.nnz = int(self.lu.L.nnz + self.lu.U.nnz)

    def _diag_pivots(self):
        lu = self.lu
        u = lu.U.diagonal()
        qr = np.empty_like(lu.perm_r)
        qr[lu.perm_r] = np.arange(qr.size)
        qc = np.empty_like(lu.perm_c)
        qc[lu.perm_c] = np.arange(qc.size)
        dm = np.asarray(self._A[qr, qc]).ravel() if qr.size else np.zeros(0)
        return u, dm

    def pivots(self):
        """(pivots / matching diagonal entry, reliable?): reliable when symmetric pivoting held
        and the diagonal is positive."""
        u, dm = self._diag_pivots()
        ok = self.symmetric and np.all(dm > 0)
        return u / np.where(dm != 0, dm, 1.0), ok

    def inertia(self):
        if not self.symmetric:
            return None
        u, _ = self._diag_pivots()
        return Inertia(int((u > 0).sum()), int((u < 0).sum()), int((u == 0).sum()), "splu")

    def solve(self, b):
        return self.lu.solve(np.asarray(b, dtype=np.float64))


class _Cholmod(Factor):
    """CHOLMOD supernodal Cholesky ``LL^T`` (scikit-sparse) of a positive definite matrix in the
    given ordering ``perm`` (or CHOLMOD's own); raises :class:`NotPositiveDefinite`."""

    name = "cholmod"

    def __init__(self, A, *, perm=None, max_memory=None):
        if _cholmod is None:
            raise RuntimeError("backend 'cholmod' needs scikit-sparse (CHOLMOD): apt-get install "
                               "libsuitesparse-dev, then pip install 'scikit-sparse==0.4.16'")
        memory_check(predicted_factor_bytes(A.shape[0], "cholmod"),
                     f"CHOLMOD factorisation of {A.shape[0]} unknowns", max_memory)
        self.perm = perm
        Ap = (A[perm][:, perm] if perm is not None else A).tocsc()
        self._diag = Ap.diagonal()
        try:
            self.f = _cholmod.cholesky(Ap, mode="supernodal",
                                       ordering_method="natural" if perm is not None else "default")
        except _cholmod.CholmodNotPositiveDefiniteError as exc:
            raise NotPositiveDefinite(str(exc)) from None
        self.n = A.shape[0]

    def pivots(self):
        return self.f.D() / self._diag[self.f.P()], True

    def inertia(self):
        return Inertia(self.n, 0, 0, "cholmod")

    def solve(self, b):
        b = np.asarray(b, dtype=np.float64)
        if self.perm is None:
            return self.f(b)
        x = np.empty_like(b)
        x[self.perm] = self.f(np.ascontiguousarray(b[self.perm]))
        return x


def factor(A, *, backend="auto", spd=False, perm=None, max_memory=None, matching=True) -> Factor:
    """Factorise the real symmetric sparse matrix ``A`` (n, n).

    backend: one of ``BACKENDS``; ``"auto"`` takes PARDISO (Bunch-Kaufman ``LDL^T``, with the
    inertia) when available, else CHOLMOD when ``spd``, else SuperLU. ``spd``: the caller
    expects a positive definite matrix (CHOLMOD raises :class:`NotPositiveDefinite` otherwise).
    ``perm``: a fill-reducing ordering (new position -> old index) for CHOLMOD.
    ``max_memory`` [bytes]: refuse (:class:`MemoryGuardError`) a predicted factor above it or
    above the available memory. ``matching``: PARDISO's symmetric scaling and weighted matching
    (default on; off saves time on nearly semi-definite matrices)."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")
    A = sp.csr_matrix(A)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"A must be square, got shape {A.shape}")
    if backend == "auto":
        backend = available_backends()[0]
        if backend == "cholmod" and not spd:
            backend = "splu"
    if backend == "pardiso":
        return _Pardiso(A, spd=False, max_memory=max_memory, matching=matching)
    if backend == "cholmod":
        return _Cholmod(A.tocsc(), perm=perm, max_memory=max_memory)
    return _SuperLU(A, max_memory=max_memory)


def inertia(A, *, backend="auto", max_memory=None) -> Inertia:
    """Inertia (numbers of positive, negative, zero eigenvalues) of the real symmetric sparse
    matrix ``A`` from one ``LDL^T`` (Sylvester's law of inertia). Raises
    :class:`FactorisationError` when the back end cannot count (SuperLU left the diagonal,
    PARDISO perturbed a pivot)."""
    f = factor(A, backend="splu" if backend == "cholmod" else backend, max_memory=max_memory)
    try:
        ine = f.inertia()
        if ine is None:
            raise FactorisationError(f"{f.name} did not pivot symmetrically: no inertia")
        if f.name == "pardiso" and f.n_perturbed:
            raise FactorisationError(f"PARDISO perturbed {f.n_perturbed} pivot(s): the inertia is "
                                     "that of a perturbed matrix")
        return ine
    finally:
        f.release()
