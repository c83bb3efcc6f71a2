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
defaults are the call above.

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

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .kinematics import Assembly, rotational_dofs
from .results import Result

__all__ = ["near_null_space", "amg_preconditioner", "AMGInfo", "dof_layout", "coarse_correction"]

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


#: smooth= of amg_preconditioner: pyamg's prolongation smoother (Jacobi: local weighting, no random
#: spectral-radius estimate; deterministic like the energy minimisation)
SMOOTHERS = {"energy": ("energy", {}), "jacobi": ("jacobi", {"omega": 4.0 / 3.0, "weighting": "local"}),
             "none": None}
#: candidates= of amg_preconditioner: the near-null vectors kept (columns of near_null_space)
CANDIDATES = ("all", "rigid")


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


def amg_preconditioner(asm: Assembly, *, sweeps: int = 2, candidates: str = "all", smooth: str = "energy",
                       theta: float = 0.0, max_coarse: int = 10, improve: bool = True, dtype=np.float64):
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
        on 256 frictional spheres the CG stagnates near 1e-8 (not certified after 23 orders, the
        upper bounds up to 6e-9 of the modulus below the exact one): not the default.

    Returns
    -------
    (LinearOperator (ndof, ndof), AMGInfo)
    """
    try:
        import pyamg
    except ImportError as exc:  # pragma: no cover - pyamg is a core dependency
        raise ImportError("preconditioner='amg' needs pyamg (pip install pyamg); "
                          "preconditioner='block' works without it") from exc
    _check_options(sweeps, candidates, smooth, theta, max_coarse, dtype)
    dtype = np.dtype(dtype)
    t0 = time.perf_counter()
    n = asm.ndof
    part, comp = dof_layout(asm)
    order = np.lexsort((comp, part))                     # particle-major: (x, y[, z], spins) per particle
    inv = np.empty_like(order)
    inv[order] = np.arange(n)
    counts = np.bincount(part)[np.unique(part)]
    bs = int(counts[0]) if counts.size and np.all(counts == counts[0]) else 1
    H = asm.H.tocsr()[order][:, order]
    H = (H + _SHIFT * float(H.diagonal().mean()) * sp.identity(n, format="csr")).tocsr()
    if dtype != H.dtype:                                 # float32: the shift is below its precision; the
        H = H.astype(dtype)                              # coarsest level's pseudo-inverse takes the translations
    B = near_null_space(asm)
    if candidates == "rigid":
        B = B[:, :_n_rigid(asm.net.dim, B.shape[1])]
    smoother = ("block_gauss_seidel" if bs > 1 else "gauss_seidel",
                {"sweep": "symmetric", "iterations": int(sweeps)})
    extra = {}                                           # only what differs from pyamg's defaults
    if theta != 0.0:
        extra["strength"] = ("symmetric", {"theta": float(theta)})
    if max_coarse != 10:
        extra["max_coarse"] = int(max_coarse)
    if not improve:
        extra["improve_candidates"] = None
    ml = pyamg.smoothed_aggregation_solver(H.tobsr(blocksize=(bs, bs)) if bs > 1 else H,
                                           B=np.ascontiguousarray(B[order], dtype=dtype),
                                           presmoother=smoother, postsmoother=smoother,
                                           smooth=SMOOTHERS[smooth], **extra)
    del H
    vcycle = ml.aspreconditioner(cycle="V")

    def apply(r):
        r = np.asarray(r, dtype=float)
        if r.ndim == 1:
            return np.asarray(vcycle @ r[order].astype(dtype, copy=False), dtype=float)[inv]
        out = np.empty_like(r)
        for j in range(r.shape[1]):
            out[:, j] = np.asarray(vcycle @ r[order, j].astype(dtype, copy=False), dtype=float)[inv]
        return out

    op = sla.LinearOperator((n, n), matvec=apply, matmat=apply, dtype=float)
    op.amg = (ml, order, inv)                          # for coarse_correction (already held by the V-cycle)
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
        r = np.asarray(r, dtype=float)
        one = r.ndim == 1
        R = r[:, None] if one else r
        out = np.empty_like(R)
        for j in range(R.shape[1]):
            rc = np.asarray(P.T @ R[order, j].astype(P.dtype, copy=False), dtype=float)
            out[:, j] = np.asarray(P @ solve(rc).astype(P.dtype, copy=False), dtype=float)[inv]
        return out[:, 0] if one else out

    return apply
