"""Sparse symmetric factorisation back ends, their inertia and a memory guard.

One interface over the direct solvers the exact stiffness (``dem.analysis.stiffness``) and the certified
spectral bound (:mod:`microhom.spectral`) need; the only implementation of each back end in the project:

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
``factor(A, shift=s, scale=d)`` factorises the shifted matrix ``A + s diag(d)`` (a Tikhonov shift
relative to a positive diagonal scale ``d``); ``Factor.reshift(s2)`` factorises ``A + s2 diag(d)``
on the same ordering (PARDISO: the same analysis; CHOLMOD: the same symbolic factor and memory).
:func:`count_zero_modes` counts the zero and negative eigenvalues of the pencil ``(A, diag d)``
from such a factor: by the inertia of PARDISO's ``LDL^T`` of ``A - eta diag(d)``, or by the
relative pivots of CHOLMOD's or SuperLU's factor of ``A + eta diag(d)`` (threshold
``ZERO_PIVOT``, or the rescaling test).
:func:`inertia` counts the eigenvalues of a symmetric matrix below zero.
:func:`memory_check` refuses a factorisation whose predicted size exceeds the available memory.
"""
from __future__ import annotations

import ctypes
import glob
import os
import sys
import warnings
from ctypes.util import find_library
from dataclasses import dataclass, field, replace

import numpy as np
from .limits import available_memory  # noqa: F401 - part of this API (one implementation)
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh, splu

from microhom.results import Result

__all__ = ["BACKENDS", "COUNTS", "ETA", "ZERO_PIVOT", "AMBIGUOUS_PIVOTS", "RESCALE", "RIGID_SV", "Inertia",
           "ZeroModes",
           "Factor", "factor", "inertia", "count_zero_modes", "available_backends", "have_pardiso",
           "have_cholmod", "NotPositiveDefinite", "FactorisationError", "MemoryGuardError",
           "memory_check", "predicted_factor_bytes", "predicted_factor_nnz", "predicted_general_bytes", "factor_general"]

BACKENDS = ("auto", "pardiso", "cholmod", "splu")
#: the rules of :func:`count_zero_modes` for the pivots of CHOLMOD and SuperLU
COUNTS = ("auto", "pivots", "rescale")
#: default relative shift ``eta`` of the zero-mode count: ``A + eta diag(d)`` is factorised (CHOLMOD,
#: SuperLU), ``A - eta diag(d)`` by PARDISO; eigenvalues of the pencil ``(A, diag d)`` in
#: ``(-eta, eta)`` are zero modes (``docs/stiffness.md``: why 1e-12 is safe)
ETA = 1e-12
#: ``count="pivots"``: a pivot below this fraction of its diagonal entry marks a zero mode
ZERO_PIVOT = 1e-8
#: relative pivots in this band are ambiguous (a delocalised zero mode or a soft rigid mode):
#: ``count="auto"`` settles them with the rescaling test
AMBIGUOUS_PIVOTS = (1e-10, 1e-6)
#: ``count="rescale"``: the second factorisation's shift, as a fraction of the first
RESCALE = 1e-2
#: the rigidity check of :func:`count_zero_modes`: a candidate zero mode is floppy iff its singular
#: value in the column-scaled rigidity factor ``R diag(d)^-1/2`` (``A = R^T R``; largest singular
#: value between 1 and the square root of the unknowns per row) is below this. The pencil's
#: eigenvalues are these singular values squared: a rigid mode at 4e-8 sits at 1.4e-15, below
#: ``ETA`` and at the rounding level of ``A`` itself, while ``R`` resolves it (docs/stiffness.md)
RIGID_SV = 1e-9
#: smallest system for which ``"auto"`` takes PARDISO, in the exact solver and the certified bound
#: (measured, one thread, CPU time of analysis + factorisation + solve: 8.8e3 unknowns PARDISO
#: 0.09 s, SuperLU 0.06 s; 2.9e4 unknowns 0.28 s against 0.25 s; 3e5 unknowns 4.1 s against 9.1 s;
#: docs/stiffness.md)
AUTO_PARDISO_DOF = 30_000
#: the same threshold for the certified bound (``microhom.spectral``), which factorises a pencil two
#: or three times on one PARDISO analysis (minimum-degree ordering) where SuperLU orders each anew
#: (measured, one thread, CPU time of the whole certificate on the benchmark network: 2.9e3 unknowns
#: PARDISO 0.04-0.06 s, SuperLU 0.05-0.06 s; 8.8e3: 0.10-0.12 s against 0.19 s; 2.9e4: 0.29-0.34 s
#: against 0.73-1.0 s; docs/results/hierarchy.md section 7)
AUTO_PARDISO_DOF_PENCIL = 5_000


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


@dataclass(frozen=True, eq=False)
class ZeroModes(Result):
    """Zero and negative eigenvalues of the pencil ``(A, diag d)`` counted by
    :func:`count_zero_modes` from a shifted factorisation.

    ``n_zero``: eigenvalues taken as zero (in ``(-eta, eta)`` by the inertia; by the pivot rule
    ``method`` otherwise); ``n_negative``: eigenvalues below ``-eta``; ``gap``: (largest relative
    pivot counted zero, smallest kept) [-], NaN for the inertia and eigen-solver counts;
    ``method``: ``"inertia"`` (PARDISO), ``"pivots"``, ``"rescale"`` (CHOLMOD, SuperLU) or
    ``"eig"`` (dense / shift-invert fallback when SuperLU left the diagonal); ``factor``: the
    factor to solve with when the count replaced its input (CHOLMOD's in-place rescaled factor,
    or SuperLU's after PARDISO perturbed pivots), else None (keep using the input).

    With the rigidity check (``rigidity=`` given): ``n_zero`` is the check's count, ``n_pencil``
    the pencil rule's count before it (-1 without the check), ``sv_gap`` (largest singular value
    counted zero, smallest candidate kept) [-] of the column-scaled rigidity factor on the
    candidate space (NaN without the check)."""

    n_zero: int
    n_negative: int
    gap: tuple
    method: str
    factor: object = field(default=None, repr=False, compare=False, metadata={"export": False})
    n_pencil: int = -1
    sv_gap: tuple = (np.nan, np.nan)


# ---- memory guard ----------------------------------------------------------------------------


#: fitted factor size of the 2D contact Hessians (nested dissection / AMD on the particle graph):
#: non-zeros of L ~ _NNZ_COEF * n * log2(n) for n unknowns (measured with PARDISO on the
#: benchmark networks: 2.95e5 unknowns -> see docs/stiffness.md "Memory guard")
_NNZ_COEF = 4.0
#: bytes per non-zero of the factor including indices and work space, per back end (measured peaks)
_BYTES_PER_NNZ = {"pardiso": 20.0, "cholmod": 12.0, "splu": 80.0}
#: fixed work space of a factorisation [bytes]
_FIXED_BYTES = 32e6


#: fitted fill of SuperLU's LU of a 3D sphere Hessian or tangent (3 translations + 3 rotations per
#: sphere; ``MMD_AT_PLUS_A``, diagonal pivots, the symmetric and the non-symmetric factor alike):
#: non-zeros of L + U ~ _NNZ_COEF_3D * n^_NNZ_EXP_3D for n unknowns. Measured on the built FCC network
#: of ``studies.bench_spheres`` (keep 0.6, Z = 6.8; ``python -m studies.bench_splu_fill``): symmetric
#: factor 1.52e6 at 2996 unknowns, 7.80e6 at 8213, 2.67e7 at 17 459, 4.62e7 at 23 944; non-symmetric
#: 4.57e7 at 23 967 and 2.28e8 at 65 811. A free power-law fit gives 3.37 n^1.63 (within 4 % of all
#: six); the stored law is 10-22 % above every measured FCC size from 1533 to 65 811 unknowns, and
#: 2.2x above a sparser LAMMPS packing (Z = 3.9: 1.89e6 at 5085). MMD's fill grows faster than
#: nested dissection's n^(4/3) here: an n^(4/3) law fitted to the same points is 1.9x high at 1533
#: and 0.65x low at 65 811 unknowns (docs/spheres.md, "The memory guard of SuperLU's factor in 3D").
_NNZ_COEF_3D = 5.0
_NNZ_EXP_3D = 1.6
#: bytes per non-zero of SuperLU's 3D factor, resident memory included (measured 22-24 on the
#: symmetric factor, 24-28 on the non-symmetric one, FCC network)
_BYTES_PER_NNZ_LU3D = 32.0


def _check_dim(dim):
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 (disks) or 3 (spheres), got {dim!r}")
    return dim


def predicted_factor_nnz(n: int, dim: int = 2) -> float:
    """Predicted non-zeros of the sparse factor of a contact Hessian with ``n`` unknowns in
    dimension ``dim``: in 2D ``_NNZ_COEF n log2 n`` (of ``L``; nested-dissection fill of a planar
    graph, ``docs/stiffness.md``, "Memory guard"), in 3D ``_NNZ_COEF_3D n^_NNZ_EXP_3D`` (of
    SuperLU's ``L + U``, measured: ``docs/spheres.md``, "The memory guard of SuperLU's factor in 3D")."""
    n = max(int(n), 2)
    if _check_dim(dim) == 2:
        return _NNZ_COEF * n * np.log2(n)
    return _NNZ_COEF_3D * n ** _NNZ_EXP_3D


def predicted_factor_bytes(n: int, backend: str = "pardiso", dim: int = 2) -> float:
    """Predicted memory [bytes] of the sparse factorisation of a contact Hessian with ``n``
    unknowns (before anything is allocated): :func:`predicted_factor_nnz` times the measured
    bytes per non-zero of the back end, plus ``_FIXED_BYTES``. ``dim = 3`` changes SuperLU's
    figure only (``_NNZ_COEF_3D n^1.6`` non-zeros, ``_BYTES_PER_NNZ_LU3D`` each): PARDISO and
    CHOLMOD order by nested dissection or AMD, whose 3D fill is not calibrated, and keep the 2D
    figure (PARDISO's own analysis then guards its factorisation). ``docs/stiffness.md``, "Memory
    guard"; ``docs/spheres.md``."""
    n = max(int(n), 2)
    if _check_dim(dim) == 3 and backend == "splu":
        return predicted_factor_nnz(n, 3) * _BYTES_PER_NNZ_LU3D + _FIXED_BYTES
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
class _Pencil:
    """``H - s M`` on the union of the upper-triangular patterns, for any ``s``: ``pattern`` a CSR
    upper triangle with sorted indices, ``at(s)`` its values (``data`` order), so that one
    PARDISO analysis serves every shift (:mod:`microhom.spectral`, and the diagonal shift of
    :func:`factor`, ``M = -diag(scale)``)."""

    def __init__(self, H, M):
        Hu, Mu = sp.triu(H, format="csr"), sp.triu(M, format="csr")
        for X in (Hu, Mu):
            X.sum_duplicates()
            X.sort_indices()
        ones = lambda X: sp.csr_matrix((np.ones(X.nnz), X.indices, X.indptr), shape=X.shape)  # noqa: E731
        U = (ones(Hu) + ones(Mu)).tocsr()          # entries >= 1: no cancellation
        U.sort_indices()
        ids = sp.csr_matrix((np.arange(1, U.nnz + 1, dtype=float), U.indices, U.indptr), shape=U.shape)
        self.hpos = self._positions(ones(Hu), ids)
        self.mpos = self._positions(ones(Mu), ids)
        self.hv, self.mv = Hu.data, Mu.data
        self.pattern = sp.csr_matrix((np.zeros(U.nnz), U.indices, U.indptr), shape=U.shape)

    @staticmethod
    def _positions(X1, ids):
        P = X1.multiply(ids).tocsr()               # X's pattern, with U's entry ids
        P.sort_indices()
        return np.rint(P.data).astype(np.int64) - 1

    def at(self, s):
        v = np.zeros(self.pattern.nnz)
        v[self.hpos] += self.hv
        v[self.mpos] -= s * self.mv
        return v

    def matrix(self, s):
        A = self.pattern.copy()
        A.data = self.at(s)
        return A


class Factor:
    """A factorisation of a real symmetric matrix: ``solve(b)`` for (n,) or (n, k) ``b``;
    ``inertia()`` an :class:`Inertia` (or None when the back end cannot tell); ``pivots()``
    (relative pivots, reliable?) where available; ``name`` the back end; ``nnz`` non-zeros of
    the factor (or None); ``release()`` frees its memory.

    Made by :func:`factor` with a diagonal shift (``scale`` given), it factorises
    ``A + shift diag(scale)``: ``A`` (n, n) the unshifted input, ``scale`` (n,), ``shift`` are
    kept, and ``reshift(s)`` gives the factor of ``A + s diag(scale)`` on the same ordering
    (``reshifts_in_place``: the result replaces this object, whose memory it reuses)."""

    name = "?"
    nnz = None
    dim = 2     # the dimension of the contact network (SuperLU's memory guard, set by factor())
    A = None
    scale = None
    shift = 0.0
    reshifts_in_place = False

    def solve(self, b):
        raise NotImplementedError

    def inertia(self):
        return None

    def pivots(self):
        return None, False

    def reshift(self, shift):
        raise NotImplementedError(f"{self.name} cannot refactorise with another shift")

    def release(self):
        pass

    def _need_scale(self):
        if self.scale is None:
            raise ValueError("reshift needs a factor made with a diagonal shift: factor(A, shift=, scale=)")


#: PARDISO fill-reducing orderings (``iparm(2)``): "metis" nested dissection (least fill) and "mmd"
#: minimum degree (measured on the 1e5-disk benchmark network, 2.95e5 unknowns, one thread: its
#: analysis about 1.3 s CPU against 2.2-2.9 s for METIS, 8 % more fill, the same numeric
#: factorisation time within the noise; the certificate, which factorises once or twice on
#: one analysis, takes "mmd"; docs/results/hierarchy.md section 7)
_ORDERINGS = {"metis": 2, "mmd": 0}


class _Pardiso(Factor):
    """MKL PARDISO of a real symmetric matrix: ``spd=True`` Cholesky (matrix type 2; raises
    :class:`NotPositiveDefinite`), else Bunch-Kaufman ``LDL^T`` (type -2) with its inertia.
    The analysis (phase 11) predicts the memory; :func:`memory_check` runs before phase 22.
    With ``scale``, the factorised matrix is ``A + shift diag(scale)`` on the pattern of a
    :class:`_Pencil`, so that :meth:`reshift` reuses the analysis; ``inertias`` maps every shift
    factorised on this analysis to its (:class:`Inertia`, number of perturbed pivots)."""

    name = "pardiso"
    reshifts_in_place = True

    def __init__(self, A, spd=False, *, max_memory=None, perm=None, threads=None, upper=False,
                 matching=True, shift=0.0, scale=None, ordering="metis", general=False):
        lib = _load_mkl()
        if not lib:
            raise RuntimeError("backend 'pardiso' needs the mkl wheel: pip install mkl (x86-64)")
        self._lib = lib
        n = A.shape[0]
        self._pencil = None
        if general:     # real non-symmetric (matrix type 11): the whole matrix, CSR, sorted
            if scale is not None or spd:
                raise ValueError("general=True takes the matrix as is (no scale, not spd)")
            U = sp.csr_matrix(A, dtype=np.float64, copy=True)
            U.sum_duplicates()
            U.sort_indices()
        elif scale is not None:     # A + shift diag(scale) = the pencil (A, -diag(scale)) at shift
            self.A, self.scale, self.shift = A, scale, shift
            self._pencil = _Pencil(A, sp.diags(-scale).tocsr())
            U = self._pencil.matrix(shift)
        elif upper:     # the caller's upper triangle (CSR, sorted indices), taken as is
            U = A
        else:
            U = sp.triu(A, format="csr")
            U.sort_indices()
        self.n = n
        self.mtype = 11 if general else 2 if spd else -2
        self._a = np.ascontiguousarray(U.data, dtype=np.float64)
        self._ia = (U.indptr + 1).astype(np.int32)
        self._ja = (U.indices + 1).astype(np.int32)
        self.pt = np.zeros(64, dtype=np.int64)
        ip = np.zeros(64, dtype=np.int32)
        ip[0] = 1          # iparm given
        if ordering not in _ORDERINGS:
            raise ValueError(f"ordering must be one of {list(_ORDERINGS)}, got {ordering!r}")
        ip[1] = _ORDERINGS[ordering]   # METIS nested dissection (2) or minimum degree (0)
        ip[3] = 0
        ip[4] = 0 if perm is None else 1
        ip[7] = 0          # no automatic refinement (the caller refines against the true matrix)
        ip[9] = 13         # pivot perturbation 1e-13 (counted in iparm(14), checked by callers)
        # symmetric scaling and weighted matching (congruences: the inertia is kept) for strongly
        # indefinite matrices: fewer perturbed pivots; off for nearly semi-definite ones (the
        # stiffness H - eta diag H without pre-stress), where they cost 17 % of the time at 1e5
        ip[10] = 1 if matching or general else 0
        ip[12] = 1 if matching or general else 0
        ip[17] = -1        # report nnz of the factor
        ip[20] = 1         # Bunch-Kaufman 1x1 and 2x2 pivoting (type -2)
        ip[23] = 0
        ip[26] = 0
        ip[34] = 0         # one-based indices
        ip[55] = 0
        self.iparm = ip
        self._perm = (np.asarray(perm, dtype=np.int32) + 1) if perm is not None else np.zeros(n, np.int32)
        self._released = False
        self.inertias = {}
        if threads is not None:
            lib.MKL_Set_Num_Threads(ctypes.c_int(int(threads)))
        self._call(11)
        self.predicted_bytes = 1024.0 * (max(int(ip[14]), int(ip[15]) + int(ip[16])))
        try:
            memory_check(self.predicted_bytes, f"PARDISO {'non-symmetric ' if general else ''}factorisation of {n} unknowns "
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
        self._record()

    def _record(self):
        if self._pencil is not None:
            self.inertias[self.shift] = (self.inertia(), self.n_perturbed)

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

    def reshift(self, shift):
        """``A + shift diag(scale)`` factorised in place on the same analysis; returns self."""
        self._need_scale()
        self.refactor(self._pencil.at(shift))
        self.shift = shift
        self._record()
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
        count that of a perturbed matrix (callers refuse to certify with them). None for a
        non-symmetric matrix (type 11)."""
        ip = self.iparm
        if self.mtype == 11:
            return None
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
    their signs give the inertia. Always available. With ``scale``, of ``A + shift diag(scale)``."""

    name = "splu"

    def __init__(self, A, *, max_memory=None, shift=0.0, scale=None, _guard=True, dim=2):
        self.dim = dim
        if _guard:
            memory_check(predicted_factor_bytes(A.shape[0], "splu", dim),
                         f"SuperLU factorisation of {A.shape[0]} unknowns ({dim}D)", max_memory)
        if scale is not None:
            self.A, self.scale, self.shift = A, scale, shift
            A = A + sp.diags(shift * scale)
        A = sp.csc_matrix(A)
        try:
            self.lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options=dict(SymmetricMode=True))
        except RuntimeError as exc:       # exactly singular
            raise FactorisationError(f"SuperLU: {exc}") from None
        self.symmetric = bool(np.array_equal(self.lu.perm_r, self.lu.perm_c))
        self._A = A
        self.nnz = int(self.lu.L.nnz + self.lu.U.nnz)

    def reshift(self, shift):
        """The factor of ``A + shift diag(scale)`` (a new object; this one stays valid), or None
        if SuperLU chose another ordering (its pivots would not compare one to one)."""
        self._need_scale()
        new = _SuperLU(self.A, shift=shift, scale=self.scale, _guard=False, dim=self.dim)
        return new if np.array_equal(new.lu.perm_c, self.lu.perm_c) else None

    def _diag_pivots(self):
        lu = self.lu
        u = lu.U.diagonal()
        # diagonal of Pr M Pc: row perm_r^-1, column perm_c^-1 -> entry M[q_r[k], q_c[k]]
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
    given ordering ``perm`` (new position -> old index; or CHOLMOD's own); raises
    :class:`NotPositiveDefinite`. With ``scale``, of ``A + shift diag(scale)``: ``A`` is permuted
    once, and :meth:`reshift` reuses the permuted matrix, the symbolic analysis and the memory."""

    name = "cholmod"
    reshifts_in_place = True

    def __init__(self, A, *, perm=None, max_memory=None, shift=0.0, scale=None, _base=None):
        if _cholmod is None:
            raise RuntimeError("backend 'cholmod' needs scikit-sparse (CHOLMOD): apt-get install "
                               "libsuitesparse-dev, then pip install 'scikit-sparse==0.4.16'")
        if _base is None:
            memory_check(predicted_factor_bytes(A.shape[0], "cholmod"),
                         f"CHOLMOD factorisation of {A.shape[0]} unknowns", max_memory)
            self.A, self.scale, self.n = A, scale, A.shape[0]
            self._Ap = (A[perm][:, perm] if perm is not None else A).tocsc()
            self._dp = None if scale is None else (scale[perm] if perm is not None else scale)
            self.f = None
        else:   # take over the base's permuted matrix and factor (numeric values replaced)
            self.A, self.scale, self.n, self.dim = _base.A, _base.scale, _base.n, _base.dim
            self._Ap, self._dp, self.f = _base._Ap, _base._dp, _base.f
        self.perm, self.shift = perm, shift
        Mp = self._Ap if self._dp is None else (self._Ap + sp.diags(shift * self._dp)).tocsc()
        self._diag = Mp.diagonal()
        if self.f is None:
            self.f = _cholmod.analyze(Mp, mode="supernodal",
                                      ordering_method="natural" if perm is not None else "default")
        try:
            self.f.cholesky_inplace(Mp)
        except _cholmod.CholmodNotPositiveDefiniteError as exc:
            raise NotPositiveDefinite(str(exc)) from None

    def reshift(self, shift):
        """The factor of ``A + shift diag(scale)`` on the same pattern, computed *in place*: the
        symbolic analysis and the memory are reused and this object must not be used afterwards.
        Returns None (and this object refactored back to its own shift) if the new matrix is not
        positive definite."""
        self._need_scale()
        try:
            new = _Cholmod(None, perm=self.perm, shift=shift, _base=self)
        except NotPositiveDefinite:
            _Cholmod(None, perm=self.perm, shift=self.shift, _base=self)
            return None
        self.f = None
        return new

    def pivots(self):
        """(relative pivots, reliable?): D of LDL^T = diag(L)^2 over the matching diagonal."""
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


def _check_scale(scale, shift, n):
    """The diagonal shift's arguments: ``scale`` (n,) finite and positive, ``shift`` finite."""
    scale = np.asarray(scale, dtype=np.float64)
    if scale.shape != (n,) or not np.all(np.isfinite(scale)) or not np.all(scale > 0):
        raise ValueError(f"scale must be a finite positive diagonal of shape ({n},), got shape "
                         f"{scale.shape}" + ("" if scale.shape != (n,) else f", min {scale.min():.3g}"))
    if not np.isfinite(shift):
        raise ValueError(f"shift must be a finite number, got {shift!r}")
    return scale


def factor(A, *, backend="auto", spd=False, perm=None, max_memory=None, matching=True, shift=0.0,
           scale=None, dim=2) -> Factor:
    """Factorise the real symmetric sparse matrix ``A`` (n, n), or ``A + shift diag(scale)``.

    backend: one of ``BACKENDS``; ``"auto"`` takes PARDISO (Bunch-Kaufman ``LDL^T``, with the
    inertia) when available, else CHOLMOD when ``spd``, else SuperLU. ``spd``: the caller
    expects a positive definite matrix (CHOLMOD raises :class:`NotPositiveDefinite` otherwise).
    ``perm``: a fill-reducing ordering (new position -> old index) for CHOLMOD.
    ``max_memory`` [bytes]: refuse (:class:`MemoryGuardError`) a predicted factor above it or
    above the available memory. ``matching``: PARDISO's symmetric scaling and weighted matching
    (default on; off saves time on nearly semi-definite matrices).
    ``scale`` (n,) positive and ``shift`` [-]: factorise ``A + shift diag(scale)`` (a Tikhonov
    shift relative to the diagonal scale); the factor keeps ``A``, ``scale`` and ``shift`` and
    its ``reshift(s)`` factorises ``A + s diag(scale)`` on the same ordering, as
    :func:`count_zero_modes` needs. ``dim``: 2 (disks) or 3 (spheres), the dimension of the
    network whose Hessian ``A`` is; SuperLU's memory guard predicts its fill by it
    (:func:`predicted_factor_bytes`), and the factor keeps it (``dim``) for the factors made from it."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")
    if not sp.issparse(A) or A.format not in ("csr", "csc"):
        A = sp.csr_matrix(A)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"A must be square, got shape {A.shape}")
    if scale is not None:
        scale = _check_scale(scale, shift, A.shape[0])
    _check_dim(dim)
    if backend == "auto":
        backend = available_backends()[0]
        if backend == "cholmod" and not spd:
            backend = "splu"
    if backend == "pardiso":
        f = _Pardiso(A, spd=False, max_memory=max_memory, matching=matching, shift=shift, scale=scale)
    elif backend == "cholmod":
        f = _Cholmod(A, perm=perm, max_memory=max_memory, shift=shift, scale=scale)
    else:
        return _SuperLU(A, max_memory=max_memory, shift=shift, scale=scale, dim=dim)
    f.dim = dim
    return f


def predicted_general_bytes(n: int, backend: str = "splu", dim: int = 3) -> float:
    """Predicted memory [bytes] of the LU factorisation of a non-symmetric contact tangent with
    ``n`` unknowns (before anything is allocated): in 3D ``_NNZ_COEF_3D n^1.6`` non-zeros of
    ``L + U`` times the measured bytes per non-zero (SuperLU: ``_BYTES_PER_NNZ_LU3D``), plus
    ``_FIXED_BYTES``; in 2D
    :func:`predicted_factor_bytes`. PARDISO predicts its own in its analysis (this is its
    fallback's figure)."""
    if _check_dim(dim) == 2:
        return predicted_factor_bytes(n, backend)
    n = max(int(n), 2)
    per = _BYTES_PER_NNZ_LU3D if backend == "splu" else _BYTES_PER_NNZ.get(backend, 40.0)
    return predicted_factor_nnz(n, 3) * per + _FIXED_BYTES


class _SuperLUGeneral(Factor):
    """scipy SuperLU of a real non-symmetric matrix with a symmetric pattern: diagonal pivots on
    ``MMD_AT_PLUS_A`` first (3-5x less fill than COLAMD), partial pivoting on COLAMD when a
    diagonal pivot is exactly zero."""

    name = "splu"

    def __init__(self, A):
        A = sp.csc_matrix(A)
        try:
            self.lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options=dict(SymmetricMode=True))
        except RuntimeError:
            try:
                self.lu = splu(A)
            except RuntimeError as exc:       # exactly singular
                raise FactorisationError(f"SuperLU: {exc}") from None
        self.nnz = int(self.lu.L.nnz + self.lu.U.nnz)

    def solve(self, b):
        return self.lu.solve(np.asarray(b, dtype=np.float64))


def factor_general(A, *, backend="auto", max_memory=None, dim=3) -> Factor:
    """Factorise the real **non-symmetric** sparse matrix ``A`` (n, n) (its pattern symmetric, as
    a contact tangent's): ``backend`` ``"pardiso"`` (MKL PARDISO, matrix type 11: METIS ordering,
    weighted matching and scaling, pivot perturbation 1e-13; its analysis predicts the memory),
    ``"splu"`` (scipy SuperLU) or ``"auto"`` (PARDISO when loadable, else SuperLU; CHOLMOD is for
    positive definite matrices only). ``max_memory`` [bytes]: refuse a predicted factor above it
    or above the available memory (:class:`MemoryGuardError`, before allocating; SuperLU's figure
    is :func:`predicted_general_bytes` for the dimension ``dim``). The factor's ``solve(b)``
    takes (n,) or (n, k) ``b``; callers refine against ``A`` (PARDISO's perturbed pivots,
    ``n_perturbed``, make its factor that of a nearby matrix)."""
    if backend not in ("auto", "pardiso", "splu"):
        raise ValueError(f"unknown backend {backend!r} for a non-symmetric matrix; allowed: auto, "
                         "pardiso, splu")
    if not sp.issparse(A):
        A = sp.csr_matrix(A)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"A must be square, got shape {A.shape}")
    if backend == "auto":
        backend = "pardiso" if have_pardiso() else "splu"
    if backend == "pardiso":
        return _Pardiso(A, max_memory=max_memory, general=True)
    memory_check(predicted_general_bytes(A.shape[0], "splu", dim),
                 f"SuperLU non-symmetric factorisation of {A.shape[0]} unknowns", max_memory)
    return _SuperLUGeneral(A)


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


# ---- zero and negative modes of the pencil (A, diag scale) -----------------------------------
def count_zero_modes(f, count="auto", *, eta=None, psd=False, max_memory=None, rigidity=None) -> ZeroModes:
    """Zero and negative eigenvalues of the pencil ``(A, diag d)`` from a shifted factor ``f``
    made by ``factor(A, shift=, scale=d)`` (Sylvester's law of inertia: ``A + s diag d`` is
    congruent to the diagonal of its ``LDL^T``). ``eta`` [-]: the zero threshold (default
    ``|f.shift|``).

    PARDISO (``method == "inertia"``, ``f`` the Bunch-Kaufman ``LDL^T`` of ``A - eta diag d``):
    its negative pivots are the eigenvalues below ``eta`` (zero and negative modes); unless
    ``psd`` (``A`` known to be positive semi-definite), those below ``-eta`` (negative modes)
    come from the factorisation of ``A + eta diag d`` made on the same analysis before
    (``f.inertias``), or from a new one. A factor with perturbed pivots counts another matrix:
    the count falls back to SuperLU (with a warning) and ``ZeroModes.factor`` is SuperLU's.

    CHOLMOD and SuperLU (``f`` the factor of ``A + eta diag d``), by the rule ``count``:
    ``"pivots"``: a relative pivot below ``ZERO_PIVOT`` (1e-8) is a zero mode. ``"rescale"``: a
    second factorisation with the shift ``RESCALE * eta``; a pivot belongs to a zero mode iff it
    scales with the shift (shrunk below a tenth: no threshold to tune). With
    CHOLMOD the second factorisation replaces the first in place (memory reused): solve with
    ``ZeroModes.factor`` then. ``"auto"``: ``"pivots"``, switching to ``"rescale"`` when a relative
    pivot falls in the ambiguous band ``AMBIGUOUS_PIVOTS`` (1e-10..1e-6). Negative pivots not
    counted as zero are negative modes. When SuperLU left the diagonal (no symmetric pivots), a
    dense (n <= 3000) or shift-invert eigen-solve of the pencil counts instead (a warning).

    ``rigidity`` (r, n) sparse, with ``A = R^T R`` (a Gram matrix, e.g. the stiffness-weighted
    compatibility of a network without pre-stress; needs ``psd``): the **rigidity check**. The
    pencil's eigenvalues are the squared singular values of ``R diag(d)^-1/2``, so a rigid mode
    whose singular value is below ``sqrt(eta)`` (1e-6) counts as zero by any rule on ``A``, and
    one below about 1e-7 is at the rounding level of ``A``. The check finds every eigenvalue of
    the pencil below ``eta`` by subspace iteration with the factor, and counts the singular
    values of ``R`` on that space below ``RIGID_SV`` (1e-9): the zero modes of ``R`` itself, as
    a dense SVD of the rigidity matrix counts them (``docs/stiffness.md``)."""
    if count not in COUNTS:
        raise ValueError(f"unknown count {count!r}; allowed: {', '.join(COUNTS)}")
    if f.scale is None:
        raise ValueError("count_zero_modes needs a factor made with a diagonal shift: "
                         "factor(A, shift=, scale=)")
    if rigidity is not None and not psd:
        raise ValueError("rigidity= needs psd=True (A = R^T R is positive semi-definite)")
    eta = abs(f.shift) if eta is None else eta
    if f.name == "pardiso":
        z = _count_inertia(f, count, eta, psd, max_memory)
    else:
        z = _count_pivots(f, count, eta)
    if rigidity is None:
        return z
    return _rigidity_check(z.factor or f, z, rigidity, eta)


def _count_pivots(f, count, eta):
    """The CHOLMOD and SuperLU branch of :func:`count_zero_modes` (pivot rules)."""
    piv, ok = f.pivots()
    if not ok:
        warnings.warn("SuperLU did not pivot symmetrically: mode counts from an eigen-solver "
                      "fallback", RuntimeWarning, stacklevel=5)
        nz, nn = _count_eig(f.A, f.scale)
        return ZeroModes(nz, nn, (np.nan, np.nan), "eig")
    small = np.abs(piv) < ZERO_PIVOT
    a = np.abs(piv)
    if count == "auto":
        count = "rescale" if np.any((a > AMBIGUOUS_PIVOTS[0]) & (a < AMBIGUOUS_PIVOTS[1])) else "pivots"
    f2 = None
    if count == "rescale":
        f2 = f.reshift(RESCALE * eta)
        if f2 is not None:
            piv2, ok2 = f2.pivots()
            if ok2:
                # the scaling alone decides: a zero mode's pivot is eta times its delocalisation,
                # measured up to 1.3e-2 on corpus packings (the former cap |piv| < 1e-4 lost it)
                small = np.abs(piv2) < 0.1 * np.abs(piv)
        if f2 is not None and not f2.reshifts_in_place:   # a separate object: the input stays valid
            f2 = None
    gap = (float(np.abs(piv[small]).max()) if small.any() else 0.0,
           float(np.abs(piv[~small]).min()) if (~small).any() else np.inf)
    return ZeroModes(int(small.sum()), int(((piv < 0) & ~small).sum()), gap, count, factor=f2)


def _count_inertia(f, count, eta, psd, max_memory):
    """The PARDISO branch of :func:`count_zero_modes`."""
    if f.shift >= 0:
        raise ValueError(f"the inertia count needs PARDISO's factor of A - eta diag(scale) (shift < 0), "
                         f"got shift {f.shift!r}")
    if f.n_perturbed:   # the inertia is that of a perturbed matrix: count with SuperLU
        warnings.warn(f"PARDISO perturbed {f.n_perturbed} pivot(s): modes counted with SuperLU",
                      RuntimeWarning, stacklevel=5)
        slu = _SuperLU(f.A, max_memory=max_memory, shift=eta, scale=f.scale, dim=f.dim)
        m = count_zero_modes(slu, count, eta=eta)
        return replace(m, factor=m.factor or slu)
    n_below = f.inertia().n_neg
    n_neg = 0
    first = f.inertias.get(eta)
    if not psd and first is not None and not first[1]:
        n_neg = first[0].n_neg       # counted at +eta on this analysis before the solve factor
    elif not psd:
        f2 = _Pardiso(f.A, max_memory=max_memory, matching=False, shift=eta, scale=f.scale)
        n_neg = f2.inertia().n_neg
        f2.release()
    return ZeroModes(n_below - n_neg, n_neg, (np.nan, np.nan), "inertia")


#: the rigidity check: dense SVD of the scaled rigidity factor up to this many unknowns
_DENSE_RIGIDITY = 400
#: the rigidity check: subspace iterations at most (measured: the counts settle after 2)
_MAX_SUBSPACE_IT = 12


def _rigidity_operand(R, A, d):
    """``R diag(d)^-1/2`` (CSR), after checking ``A = R^T R`` on two random vectors (relative
    1e-8 of the diagonal energy): a wrong factor is refused, not silently counted."""
    if not sp.issparse(R):
        R = sp.csr_matrix(R)
    n = A.shape[0]
    if R.ndim != 2 or R.shape[1] != n:
        raise ValueError(f"rigidity must have shape (rows, {n}) (A = R^T R), got {R.shape}")
    x = np.random.default_rng(1).standard_normal((n, 2))
    lhs = np.einsum("ij,ij->j", R @ x, R @ x)
    rhs = np.einsum("ij,ij->j", x, A @ x)
    if not np.all(np.abs(lhs - rhs) <= 1e-8 * np.einsum("ij,i,ij->j", x, d, x)):
        raise ValueError("rigidity: R^T R differs from A (relative energy difference "
                         f"{float(np.abs(lhs - rhs).max() / (d @ (x ** 2)).max()):.2g} > 1e-8); "
                         "pass R with A = R^T R, no pre-stress")
    return sp.csr_matrix(R @ sp.diags(1.0 / np.sqrt(d)))


def _rigidity_check(f, z, R, eta):
    """Recount ``z.n_zero`` on the rigidity factor (see :func:`count_zero_modes`): subspace
    iteration ``Z <- (A + s D)^-1 D^1/2 Z`` (scaled coordinates, ``s = f.shift``) with a
    Rayleigh-Ritz step done as an SVD of ``R D^-1/2 Q``: its singular values are the square roots
    of the Ritz values, computed without squaring. The candidates are the Ritz values below
    ``eta``; the space is enlarged until it holds one Ritz value above ``2 eta`` (so every
    eigenvalue below ``eta`` is inside) and the counts repeat."""
    d = f.scale
    Rs = _rigidity_operand(R, f.A, d)
    n = Rs.shape[1]
    if n <= _DENSE_RIGIDITY:
        sv = _padded_sv(Rs.toarray(), n)
        return _with_sv(z, sv, sv ** 2 < eta)
    sq = np.sqrt(d)
    rng = np.random.default_rng(0)
    k = min(n, z.n_zero + max(8, z.n_zero // 4))
    Z = rng.standard_normal((n, k))
    last = None
    for it in range(_MAX_SUBSPACE_IT):
        X = f.solve(sq[:, None] * Z)
        Q, _ = np.linalg.qr(sq[:, None] * X)
        _, sv, Vt = np.linalg.svd(np.asarray(Rs @ Q), full_matrices=False)
        sv = np.concatenate([sv, np.zeros(Q.shape[1] - sv.size)])
        Z = Q @ Vt.T if Vt.shape[0] == Q.shape[1] else Q
        cand = sv ** 2 < eta
        key = (int(cand.sum()), int((sv[cand] < RIGID_SV).sum()))
        if sv.max() ** 2 <= 2 * eta and k < n:        # every Ritz value a candidate: enlarge
            k = min(n, 2 * k)
            Z = np.hstack([Z, rng.standard_normal((n, k - Z.shape[1]))])
            last = None
            continue
        if key == last and it >= 2:
            break
        last = key
    else:
        warnings.warn(f"rigidity check: the counts did not settle in {_MAX_SUBSPACE_IT} subspace "
                      f"iterations (last {key}); counted as they stand", RuntimeWarning, stacklevel=4)
    return _with_sv(z, sv, cand)


def _padded_sv(M, n):
    """All n singular values of M (r, n), zeros added when r < n."""
    sv = np.linalg.svd(M, compute_uv=False) if M.size else np.zeros(0)
    return np.concatenate([sv, np.zeros(n - sv.size)])


def _with_sv(z, sv, cand):
    """``z`` with the rigidity check's count from the singular values ``sv`` of the candidates."""
    c = sv[cand]
    zero = c < RIGID_SV
    gap = (float(c[zero].max()) if zero.any() else 0.0, float(c[~zero].min()) if (~zero).any() else np.inf)
    return replace(z, n_zero=int(zero.sum()), n_pencil=z.n_zero, sv_gap=gap)


def _count_eig(A, d):
    """Zero / negative eigenvalues of the pencil (A, diag d) by a dense (n <= 3000) or
    shift-invert eigen-solve: the fallback when SuperLU left the diagonal."""
    s = 1.0 / np.sqrt(d)
    B = sp.diags(s) @ A @ sp.diags(s)
    if B.shape[0] <= 3000:
        w = np.linalg.eigvalsh(B.toarray())
    else:   # pragma: no cover - large fallback
        w = eigsh(B, k=min(200, B.shape[0] - 1), sigma=-1e-3, return_eigenvectors=False)
    small = np.abs(w) < ZERO_PIVOT
    return int(small.sum()), int(((w < 0) & ~small).sum())
