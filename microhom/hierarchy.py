"""Relaxation hierarchy: from the affine tensor to the exact moduli, with bounds and stated errors.

For a periodic :class:`~microhom.network.ContactNetwork` the exact incremental stiffness is
(``microhom.kinematics``; ``docs/theory.md``, section "Relaxation hierarchy")::

    C = C_aff - R / A,     R = F^T H^+ F   (3 x 3, the relaxation of the three Mandel strain modes),

with ``H`` the Hessian in translations and spins and ``F`` the load per unit strain. This module
estimates ``R`` without factorising ``H``:

* order 0: ``R_0 = 0``, the affine tensor of the load-bearing contacts;
* first order (the seed's Kroener-type correction with each particle's measured out-of-balance
  loads): ``R_fo = F^T M^-1 F``, ``M`` the block diagonal of ``H`` (each particle's own 3 x 3
  block): every particle relaxes alone in its affinely displaced neighbourhood. It is a
  first-order perturbation estimate, not a bound;
* order k >= 1: ``R_k = F^T X_k`` after k steps of block conjugate gradients on ``H X = -F``
  preconditioned by ``M`` (the k-point block Gauss quadrature of the moment expansion
  ``mu_j = b^T (M^-1 H)^j M^-1 b``, which uses the moments ``mu_0 .. mu_{2k-1}``).

Proved in docs/theory.md and checked by tests/test_hierarchy.py: if ``H`` is positive
semi-definite, ``R_k`` increases with k in the Loewner order and ``R_k <= R``, so every
``C_k`` (and each modulus ``K_k``, ``G_k``, which are positive combinations of quadratic forms of
``C``) is a rigorous **upper** bound, monotone in k. A rigorous **lower** bound needs a certified
lower bound ``lam`` of the non-zero spectrum of the pencil ``(H, M)``:
``R - R_k <= Res_k^T M^-1 Res_k / lam`` (``Res_k = -F - H X_k``, the residual). ``lam`` is
computed exactly (dense eigen-decomposition) for small systems, certified by Sylvester's inertia
(``microhom.spectral``) up to ``CERTIFIED_MAX_DOF`` unknowns, may be passed by the user, or is
unavailable (then ``lower`` is None and the reason is stated). With a certified ``lam`` only the
rigorous interval (with its round-off margins) stops CG, and steps preconditioned by the
certificate's factorisation of ``H - s M`` close it where the soft modes hold the multilevel CG
back (issue 22; docs/theory.md, section 9, "Certified intervals that meet the tolerance"); by
default (``max_order="auto"``), where the sparse certificate kept that factorisation, one
block-Jacobi step precedes them and no multilevel step is taken. Far from kt = kn the pencil has a
cluster near ``min(kt/kn, kn/kt)`` (rolling without sliding, or the spins) and a *companion* bound
replaces it: the pencil of the same network at ``min(kn, kt)`` in both directions
(``_companion_bound``; docs/theory.md, section 9, "Stiffness ratios far from 1"). An extrapolated
value (geometric tail of the decreasing sequence) carries a stated, non-rigorous error, trusted
(for stopping and for ``valid``) only in the regime where it was calibrated
(``CALIBRATED_KT_OVER_KN``); ``HierarchyResult.valid`` is the rule of docs/theory.md section 9,
"What valid means". The predicted memory is checked before anything large is allocated
(:func:`plan_memory`).

Spheres (3D) run the same code with the dimension taken from the network (docs/spheres.md,
"The relaxation hierarchy on spheres"): 6 unknowns per sphere, particle blocks of 6 x 6, the
multilevel near-null space of rigid sphere motions, (6, 6) Mandel tensors [Pa]; the
extrapolation's stated error is calibrated on disks only, so a 3D result is valid only when its
rigorous interval meets ``tol``.

This module imports numpy and scipy only (and never ``dem``).
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .kinematics import SPIN_ARMS, Assembly, affine_tensor, assemble, contact_matrices, rotational_dofs, stress0
from .dual_bound import build_equilibrator, dual_lower_bound
from .limits import available_memory  # noqa: F401 - part of this API (one implementation)
from .limits import release_free_memory
from .multilevel import amg_preconditioner, dof_layout, near_null_space
from .shared_h import ShiftedCopy
from .network import ContactNetwork
from .options import Options, finite_real, flag, integer, merged
from .results import Result
from .tensors import isotropic_moduli, prestress_correction

__all__ = ["DEFAULT_TOL", "Estimate", "HierarchyResult", "HierarchyOptions", "relaxation_hierarchy",
           "block_preconditioner", "spectral_lower_bound", "lowest_modes", "isotropic_weights", "moments",
           "plan_memory", "MemoryPlan", "HierarchyMemoryError", "CALIBRATED_KT_OVER_KN"]

_NEG_CURV = 1e-10     # p^T H p < -_NEG_CURV p^T M p: negative curvature (unstable pre-stressed network)
_NULL_CURV = 1e-13    # |p^T H p| < _NULL_CURV p^T M p: a (numerically) floppy direction, dropped
_CHUNK = 48          # columns per storage chunk of the re-orthogonalisation basis
SOFT_MODES_AUTO_MAX = 20_000   # soft_modes="auto": search 3 soft modes up to this many unknowns
_FAST_RATIO = 0.3     # increment ratios below this: geometric convergence, geometric tail (k >= 4)
_ZERO_EIG_MIN = 1e-12  # dense bound: pencil eigenvalues below max(round-off margin, this fraction of the
                       # largest) are floppy modes (the sparse certificate's zero threshold is 1e-12 too)
#: the hierarchy's sparse certificate: the shift at half the Lanczos estimate (a loose estimate, 6
#: Lanczos vectors, suffices). The bound is half as tight, but the factorised CG steps converge
#: faster with it (the preconditioned spectrum lambda/(lambda - s) in (1, 2] instead of an outlier
#: near 1e3): measured at 1e3 disks, 2 factorised steps instead of 4, widths 10 times smaller at
#: 3000 disks (docs/results/hierarchy.md section 7; docs/theory.md section 9)
_LEAN_CERTIFICATE = dict(rel_gap=0.5, tol=1e-2, ncv=6)
_TRUST_RATIO = 1e-4   # dense (H, M) bound trusted down to min(kt/kn, kn/kt) = this (its soft cluster
                      # sits near 0.02 x the ratio, 1e3 x above the dense zero threshold of 1e-9 used when this was measured)


# ---- result types ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Estimate(Result):
    """One modulus with its interval [N/m, the unit of kn].

    Attributes
    ----------
    value : float
        Best estimate (the extrapolated value, clipped into [lower, upper]) [N/m].
    upper : float
        Rigorous upper bound (Gauss quadrature / CG; requires a stable network, H >= 0) [N/m].
    lower : float or None
        Rigorous lower bound [N/m], or None when no certified spectral bound is available.
    error : float
        Stated error of ``value`` [N/m]: the half-width of the rigorous interval (then ``value`` is
        its midpoint) when that is the tighter claim, else the extrapolation's estimated error;
        inf when neither is available (then ``value = upper``).
    error_rigorous : bool
        True if ``|value - exact| <= error`` is guaranteed (rigorous interval).
    """

    value: float
    upper: float
    lower: float | None
    error: float
    error_rigorous: bool

    @property
    def rel_width(self) -> float:
        """Relative width ``(upper - lower)/upper`` of the rigorous interval (inf without lower)."""
        if self.lower is None:
            return float("inf")
        return (self.upper - self.lower) / abs(self.upper) if self.upper != 0 else 0.0


@dataclass(frozen=True, eq=False)
class HierarchyResult(Result):
    """Result of :func:`relaxation_hierarchy` (moduli in the unit of kn, N/m for 2D disks).

    ``k`` is the number of CG steps taken (``order``); tensors are (m, m) Mandel matrices
    (``microhom.tensors``): m = 3 for disks (2D, moduli in N/m), m = 6 for spheres (3D, moduli in
    Pa, [xx, yy, zz, sqrt2 yz, sqrt2 xz, sqrt2 xy]); the shapes below are the 2D ones.

    Attributes
    ----------
    K, G : Estimate
        Bulk and shear moduli with their intervals (isotropic projections, see
        ``microhom.tensors.isotropic_moduli``) [N/m].
    K_orders, G_orders : ndarray, shape (k+1,)
        Upper bounds of orders 0..k (order 0 = affine, non-increasing) [N/m], each up to its
        order's floating-point margin (``margin_orders``): the energy of the computed iterate is
        evaluated in floating point, and ``K.upper``, ``G.upper`` and ``C_upper`` add the last
        order's margin.
    K_lower_orders, G_lower_orders : ndarray, shape (k+1,)
        Rigorous lower bounds per order (NaN where unavailable; with the dual bound, an order
        where it was not evaluated keeps the last evaluated one, ``docs/theory.md`` section 12)
        [N/m].
    C_orders : ndarray, shape (k+1, 3, 3)
        Mandel tensors of orders 0..k [N/m]; ``C_orders[j] + margin_orders[j] I`` bounds the exact
        tensor from above in the Loewner order.
    margin_orders : ndarray, shape (k+1,)
        A-priori round-off margin of each order's energy [N/m] (0 at the affine order): it grows
        with the iterate's size, e.g. when a CG that has stagnated at its preconditioner's
        precision keeps stepping along nearly floppy directions (docs/results/spheres.md, "The
        multilevel setup").
    C_upper, C_lower : ndarray, shape (3, 3)
        Tensors at the last order [N/m]; ``C_lower`` None without a spectral bound.
        ``C_upper - C_exact`` and ``C_exact - C_lower`` are positive semi-definite.
    K_first_order, G_first_order : float
        Single-particle (first-order Kroener) estimate of the moduli [N/m] (not a bound).
    C_first_order : ndarray, shape (3, 3)
        Its tensor ``C_aff - F^T M^-1 F / A`` [N/m].
    K_affine_all, G_affine_all : float
        Affine moduli of all contacts (rattlers' included), as ``dem.analysis.stiffness`` reports them [N/m].
    order : int
        CG steps taken (Gauss points).
    n_moments : int
        Moments used, ``2 * order``.
    tol : float
        Requested relative width [-].
    converged : bool
        True if K and G met ``tol`` (with the rigorous interval if available, else with the
        extrapolation's stated error: see ``reasons``).
    spectral_bound : float or None
        Certified lower bound of the non-zero spectrum of ``M^-1 H`` used for the lower bounds
        [unit of kn], or None.
    spectral_bound_source : str
        The certified bound of (H, M): ``"dense"`` (a dense eigen-decomposition, up to ``dense_max``
        unknowns), ``"inertia"`` (Sylvester's inertia of sparse factorisations above),
        ``"user"``, ``"companion"`` (only the bound of the min-stiffness twin network,
        docs/theory.md section 9, "Stiffness ratios far from 1"; ``spectral_bound`` is then None),
        ``"dense+companion"`` / ``"inertia+companion"`` (both; each order keeps the better lower
        bound) or ``"none"``.
    reasons : tuple of str
        Every condition that limits the result (empty = none).
    unstable : bool
        Negative curvature met (pre-stressed network not stable): the bounds are void.
    empty : bool
        No contacts or no load-bearing backbone (the zero tensor is returned, flagged).
    n_floppy_directions : int
        Search directions dropped as floppy (zero stiffness).
    n_dof, n_rattlers, n_particles, n_contacts : int
        Problem size (contacts kept).
    prestress : bool
        Pre-stress terms included (geometric stiffness and the Cauchy-increment correction).
    assembly_time, solve_time, bound_time : float
        Wall times [s].
    preconditioner : str
        ``"amg"`` (smoothed-aggregation multilevel, ``microhom.multilevel``) or ``"block"``
        (particle-block Jacobi ``M``: order k = the relaxation k contact shells carry).
    preconditioner_time : float
        Wall time of the preconditioner's setup [s] (included in ``solve_time``).
    n_factor_steps : int
        CG steps (included in ``order``) preconditioned by the certificate's factorisation of
        ``H - s M`` past ``max_order`` (``factor_steps``); 0 when the multilevel CG met ``tol``.
    certificate_factorisations : int
        Numeric factorisations the sparse certificate made (1 when a ``spectral_guess`` was
        confirmed, 2 on its usual path, more when a shift was lowered; 0 without it).
    n_soft_modes : int
        Soft modes deflated (``soft_modes`` > 0): their span augments every order's space.
    certified : bool
        The rigorous interval met ``tol`` for K and G (``(upper - lower) <= tol |upper|``).
    calibrated : bool
        The extrapolation's stated error was measured honest in this regime: kt/kn in
        ``CALIBRATED_KT_OVER_KN`` and soft modes searched (docs/results/hierarchy.md), on a 2D
        network (it was measured on disks; always False for spheres). Where it is False the
        estimates are the rigorous interval only.
    kt_over_kn : float
        Median of kt_eff/kn over the load-bearing contacts (sliding ones count 0) [-]; NaN without.
    jammed : bool
        False when there is no load-bearing backbone or the upper bound of the tensor vanishes
        (largest eigenvalue <= 1e-10 of the affine scale): "not jammed", no modulus is claimed.
    floppy : bool
        The tensor has a zero eigenvalue (a mechanism: some strain costs no energy).
    negative : bool
        A modulus estimate is negative.
    """

    K: Estimate
    G: Estimate
    K_orders: np.ndarray
    G_orders: np.ndarray
    K_lower_orders: np.ndarray
    G_lower_orders: np.ndarray
    C_orders: np.ndarray = field(repr=False)
    C_upper: np.ndarray = field(repr=False)
    C_lower: np.ndarray | None = field(repr=False)
    K_first_order: float
    G_first_order: float
    C_first_order: np.ndarray = field(repr=False)
    K_affine_all: float
    G_affine_all: float
    order: int
    n_moments: int
    tol: float
    converged: bool
    spectral_bound: float | None
    spectral_bound_source: str
    reasons: tuple
    unstable: bool
    empty: bool
    n_floppy_directions: int
    n_dof: int
    n_rattlers: int
    n_particles: int
    n_contacts: int
    prestress: bool
    assembly_time: float
    solve_time: float
    bound_time: float
    preconditioner: str = "block"
    preconditioner_time: float = 0.0
    n_soft_modes: int = 0
    n_factor_steps: int = 0
    certificate_factorisations: int = 0
    certified: bool = False
    calibrated: bool = False
    kt_over_kn: float = float("nan")
    jammed: bool = True
    floppy: bool = False
    negative: bool = False
    margin_orders: np.ndarray = field(default=None, repr=False)

    @property
    def valid(self) -> bool:
        """Whether the claim is backed and nothing voids it. True only when the rigorous interval met
        ``tol`` (``certified``) or the calibrated extrapolation did (``converged`` and
        ``calibrated``), and the network is jammed, not floppy, stable, with non-negative moduli.
        Every other result states why in ``reasons``."""
        return bool(self.converged and (self.certified or self.calibrated) and not self.unstable
                    and not self.empty and self.jammed and not self.floppy and not self.negative)

    def summary(self) -> str:
        """One line of text: order, tolerance met or not, valid or not (the rule of ``valid``), K and
        G with their intervals [N/m], and every reason."""
        lo = lambda e: "n/a" if e.lower is None else f"{e.lower:.6g}"  # noqa: E731
        state = ("valid, certified" if self.certified else "valid, extrapolated") if self.valid else "NOT valid"
        return (f"hierarchy ({self.preconditioner}, order {self.order}, {self.n_moments} moments, tol {self.tol:g}, "
                f"{'met' if self.converged else 'NOT met'}, {state}): K = {self.K.value:.6g} "
                f"[{lo(self.K)}, {self.K.upper:.6g}] +- {self.K.error:.2g}, G = {self.G.value:.6g} "
                f"[{lo(self.G)}, {self.G.upper:.6g}] +- {self.G.error:.2g}"
                + (f"; {'; '.join(self.reasons)}" if self.reasons else ""))


# ---- building blocks -------------------------------------------------------------------------
def isotropic_weights():
    """Quadratic forms of the 2D isotropic projection: ``K = sum_a wK_a e_a^T C e_a`` and the same
    for G, with Mandel strain vectors ``e_a``. Returns (eK (1, 3), wK (1,), eG (2, 3), wG (2,)).
    (In 3D, ``K = 1.C.1/9`` and ``G = tr(P_dev C)/10`` are positive forms too: docs/spheres.md.)

    K = (C11 + C22 + 2 C12)/4 = e^T C e with e = (1, 1, 0)/2;
    G = ((C11 + C22 - 2 C12)/4 + C1212)/2 = 1/2 e1^T C e1 + 1/4 e3^T C e3, e1 = (1, -1, 0)/2,
    e3 = (0, 0, 1) (C1212 = C_mandel[2, 2]/2). Positive weights: a Loewner bound on C bounds K, G.
    """
    eK = np.array([[0.5, 0.5, 0.0]])
    eG = np.array([[0.5, -0.5, 0.0], [0.0, 0.0, 1.0]])
    return eK, np.array([1.0]), eG, np.array([0.5, 0.25])


def block_preconditioner(asm: Assembly, floppy_shift: bool = False, *, M=None, sqrt: bool = True):
    """Block diagonal ``M`` of ``H`` (each particle's own unknowns, up to 3 x 3 for disks and
    6 x 6 for spheres) and its inverse.

    Returns (M, Minv, Minv_sqrt, n_bad): CSR matrices (ndof, ndof) ``M``, ``M^-1``, ``M^-1/2``
    and the number of singular or indefinite blocks (their inverse is taken on the positive part
    only; 0 for a well-posed network).

    ``M``: the particle blocks of ``H`` when the caller has them (``_own_blocks(asm.H, owner)``,
    the same matrix; ``asm.H`` is then not read and may be None: issue 26). ``sqrt=False``:
    ``Minv_sqrt`` is not computed (None; the relaxation hierarchy's dual-bound path never reads it).

    ``floppy_shift=True`` (for the inertia certificate): a positive semi-definite singular block
    (a frictional sphere with two contacts turns about their chord without deforming them) gets
    its largest eigenvalue on its null directions in ``M``, and only indefinite blocks count in
    ``n_bad``. Without pre-stress such a null direction ``q`` of a block is one of ``H``
    (``q^T H_pp q = sum_c |K_c^1/2 B_c q|^2 = 0``), so ``H q = 0`` and ``q^T F = 0``: the pencil's
    non-zero eigenvalues and the iterates are those of the pseudo-inverse ``M^-1`` returned.
    """
    owner = dof_layout(asm)[0]
    M = _own_blocks(asm.H, owner) if M is None else M
    # group unknowns by particle, pad to b x b with identity, invert in one batch
    nbk = asm.net.dim + rotational_dofs(asm.net.dim)           # 3 (disk) or 6 (sphere)
    order = np.argsort(owner, kind="stable")
    parts, start, counts = np.unique(owner[order], return_index=True, return_counts=True)
    nb = parts.size
    slot = np.empty(asm.ndof, dtype=np.int64)
    slot[order] = np.arange(asm.ndof) - np.repeat(start, counts)
    blk = np.zeros((nb, nbk, nbk))
    bi = np.searchsorted(parts, owner)
    Mc = M.tocoo()
    blk[bi[Mc.row], slot[Mc.row], slot[Mc.col]] = Mc.data
    pad = np.arange(nbk)[None, :] >= counts[:, None]        # unused slots: identity, decoupled
    idx = np.arange(nbk)
    blk[:, idx, idx] = np.where(pad, 1.0, blk[:, idx, idx])
    w, V = np.linalg.eigh(blk)
    scale = np.maximum(np.abs(w).max(axis=1, keepdims=True), 1e-300)
    good = w > 1e-12 * scale
    n_bad = int(np.count_nonzero(~good.all(axis=1)))
    if floppy_shift:
        indefinite = (w < -1e-12 * scale).any(axis=1)
        n_bad = int(np.count_nonzero(indefinite))
        shift = np.where(good | indefinite[:, None], 0.0, scale - w)     # null directions only
        dM = np.einsum("nij,nj,nkj->nik", V, shift, V)
        has_shift = shift.any(axis=1)
    winv = np.where(good, 1.0 / np.where(good, w, 1.0), 0.0)
    inv = np.einsum("nij,nj,nkj->nik", V, winv, V)
    isq = np.einsum("nij,nj,nkj->nik", V, np.sqrt(winv), V) if sqrt else None
    members = np.full((nb, nbk), -1, dtype=np.int64)           # unknown at (block, slot)
    members[bi[order], slot[order]] = order
    r = np.broadcast_to(members[:, :, None], (nb, nbk, nbk)).ravel()
    c = np.broadcast_to(members[:, None, :], (nb, nbk, nbk)).ravel()
    ok = (r >= 0) & (c >= 0)
    if floppy_shift and has_shift.any():       # M itself is untouched where no block is singular
        sel = ok & np.broadcast_to(has_shift[:, None, None], (nb, nbk, nbk)).ravel()
        M = (M + sp.csr_matrix((dM.ravel()[sel], (r[sel], c[sel])), shape=M.shape)).tocsr()
    Minv = sp.csr_matrix((inv.ravel()[ok], (r[ok], c[ok])), shape=M.shape)
    Minv_sqrt = sp.csr_matrix((isq.ravel()[ok], (r[ok], c[ok])), shape=M.shape) if sqrt else None
    return M, Minv, Minv_sqrt, n_bad


def _own_blocks(H, owner, chunk=1 << 22):
    """CSR of the entries of ``H`` (ndof, ndof) whose row and column belong to the same particle
    (``owner``, (ndof,)), read in slices of about ``chunk`` non-zeros of its CSC form: the
    temporaries are bounded by the slice, not by the non-zeros of ``H`` (a full COO copy and
    two index gathers were 33 bytes per non-zero, 0.8 GiB at 1e5 spheres); the entries come in the
    column-major order of ``H.tocoo()``, so ``M`` is the same matrix bit for bit."""
    H = H.tocsc()
    n = H.shape[1]
    ptr = H.indptr
    data, rows, cols = [], [], []
    a = 0
    while a < n:
        b = int(np.searchsorted(ptr, ptr[a] + chunk, side="right")) - 1
        b = min(max(b, a + 1), n)
        lo, hi = ptr[a], ptr[b]
        r = H.indices[lo:hi]
        c = np.repeat(np.arange(a, b, dtype=r.dtype), np.diff(ptr[a:b + 1]))
        keep = owner[r] == owner[c]
        data.append(H.data[lo:hi][keep])
        rows.append(r[keep])
        cols.append(c[keep])
        a = b
    if not data:
        return sp.csr_matrix(H.shape)
    return sp.csr_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))), shape=H.shape)


def spectral_lower_bound(asm: Assembly, Minv_sqrt=None, *, dense_max=3000, return_max=False,
                         return_factor=False, guess=None, blocks=None):
    """Smallest non-zero eigenvalue of the pencil ``(H, M)`` (floppy modes excluded), computed
    exactly by a dense eigen-decomposition of ``M^-1/2 H M^-1/2`` when ``ndof <= dense_max``.

    Returns (lam, n_zero, n_negative): ``lam`` reduced by a round-off margin
    (``1e3 * eps * ndof * lam_max``) so that it is a certified lower bound; None if the system is
    too large, or if the margin swallows it. ``n_negative`` > 0 means ``H`` is indefinite.
    With ``return_max``, (lam, lam_max + margin, n_zero, n_negative). With ``return_factor`` one
    more item: the factorisation of ``H - s M`` at the certified shift of the sparse path (a
    :class:`microhom.factor.Factor`; the caller releases it), None on the dense path or when not
    certified. ``guess``: an estimate of the bound for the sparse path (one factorisation when it
    is at most twice the eigenvalue and the null space is the global translations:
    ``microhom.spectral.certified_bound``). ``blocks``: ``block_preconditioner(asm)`` when the
    caller has it (not recomputed when no block is singular).
    """
    out = _spectral_lower_bound(asm, Minv_sqrt, dense_max, return_factor, guess, blocks)[:5]
    fac = out[-1]
    out = out[:-1] if return_max else (out[0], out[2], out[3])
    return out + (fac,) if return_factor else out


def _spectral_lower_bound(asm, Minv_sqrt, dense_max, keep, guess=None, blocks=None, lean=False):
    """(lam, lam_max, n_zero, n_negative, factor or None, numeric factorisations made) of
    :func:`spectral_lower_bound`. ``lean`` (the hierarchy's own call): the sparse certificate's
    shift at half the Lanczos estimate (``_LEAN_CERTIFICATE``)."""
    n = asm.ndof
    if n == 0:
        return None, None, 0, 0, None, 0
    if n > dense_max:
        # above the dense limit: certified by Sylvester's law of inertia (microhom.spectral),
        # up to CERTIFIED_MAX_DOF unknowns (1e5 particles); two or three sparse factorisations
        from microhom import spectral
        from microhom.factor import FactorisationError, MemoryGuardError
        none = (None, None, 0, 0, None, 0)
        if n > spectral.CERTIFIED_MAX_DOF:
            return none
        if blocks is None or blocks[3]:     # a singular block: shifted on its null directions
            blocks = block_preconditioner(asm, floppy_shift=asm.Kgs is None)
        M, _, S, n_bad = blocks
        if n_bad:
            return none
        S = S if Minv_sqrt is None else Minv_sqrt
        psd = asm.Kgs is None                     # no pre-stress: H = B^T K B >= 0
        # the global translations are exact null vectors (B t = 0): with a good guess one
        # factorisation certifies (docs/theory.md section 9, "One factorisation"); M's blocks are
        # positive definite (their eigenvalues, n_bad = 0); H <= 2M bounds the top without pre-stress
        Z = near_null_space(asm)[:, :asm.net.dim] if psd and asm.pinned < 0 else None
        try:
            b, fac = spectral.certified_bound(asm.H, M, psd=psd, Minv_sqrt=None if psd else S,
                                              lam_max=2.0 if psd else None, keep_factor=True, guess=guess,
                                              null_basis=Z, check_m=False, dim=asm.net.dim,
                                              **(_LEAN_CERTIFICATE if lean else {}))
        except (FactorisationError, MemoryGuardError, ValueError):
            return none
        if fac is not None and not keep:
            fac.release()
            fac = None
        hi = b.upper if b.upper is not None else None
        if psd:   # H <= 2M without pre-stress (docs/theory.md section 9)
            hi = 2.0 + b.margin if hi is None else min(hi, 2.0 + b.margin)
        return b.lower, hi, b.n_zero, b.n_negative, fac, b.n_factorisations
    S = block_preconditioner(asm)[2] if Minv_sqrt is None else Minv_sqrt   # M^-1/2
    A = (S @ asm.H @ S).toarray()
    lam = np.linalg.eigvalsh(0.5 * (A + A.T))
    lmax = float(np.abs(lam).max()) if lam.size else 0.0
    margin = 1e3 * np.finfo(float).eps * n * lmax
    # zero = within the round-off margin: an eigenvalue above it is certified non-zero, however
    # small (a fixed 1e-9 lmax threshold took a near-mechanism at 8e-10 lmax for a floppy mode and
    # returned a "lower bound" 2e5 times its eigenvalue: docs/theory.md section 9, issue 22)
    zero = np.abs(lam) <= max(margin, _ZERO_EIG_MIN * lmax)
    neg = (lam < 0) & ~zero
    pos = lam[(lam > 0) & ~zero]
    hi = float(lam.max()) + margin
    lo = float(pos.min()) - margin if pos.size else -1.0
    return (lo if lo > 0 else None), hi, int(zero.sum()), int(neg.sum()), None, 0


def lowest_modes(asm: Assembly, M=None, P=None, *, Minv=None, k: int = 6, maxiter: int = 40,
                 seed: int = 0, return_vectors: bool = False):
    """Lowest eigenvalues of the pencil ``(H, M)`` by LOBPCG, the two global translations deflated.

    LOBPCG runs twice, preconditioned by the multilevel V-cycle ``P`` (default
    ``amg_preconditioner``: fast on nearly stable packings) and by ``M^-1`` (positive definite
    however indefinite ``H`` is: it finds strongly negative modes the V-cycle of an indefinite
    ``H`` cannot), and the Ritz vectors of both are kept.

    Returns (rq, lam), or (rq, lam, V) with ``return_vectors``: ``rq`` (2k,) the exact Rayleigh
    quotients ``v^T H v / v^T M v`` of the Ritz vectors, sorted [-], ``lam`` the smallest, ``V``
    (ndof, 2k) the Ritz vectors in the same order. A negative ``rq`` *proves* that ``H`` has a negative
    eigenvalue (the network is not stable); a positive ``lam`` estimates the smallest non-zero
    eigenvalue from above (not a certified lower bound: LOBPCG may miss a lower one). About 2 s for
    8000 unknowns.
    """
    if M is None or Minv is None:                 # the caller's blocks, or build them once here
        M, Minv = block_preconditioner(asm)[:2]
    if P is None:
        P = amg_preconditioner(asm)[0]
    n = asm.ndof
    k = int(min(k, max(n // 5 - 1, 1)))
    Y = near_null_space(asm)[:, :asm.net.dim] if asm.pinned < 0 else None   # the global translations
    rq, Vs = [], []
    for prec in (P, Minv):
        X = np.random.default_rng(seed).standard_normal((n, k))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # LOBPCG warns when it stops at maxiter: expected here
            _, V = sla.lobpcg(asm.H, X, B=M, M=prec, Y=Y, largest=False, maxiter=int(maxiter), tol=1e-12)
        rq.append(np.einsum("ij,ij->j", V, asm.H @ V) / np.einsum("ij,ij->j", V, M @ V))
        Vs.append(V)
    rq, V = np.concatenate(rq), np.hstack(Vs)
    order = np.argsort(rq)
    rq, V = rq[order], V[:, order]
    return (rq, float(rq[0]), V) if return_vectors else (rq, float(rq[0]))


def moments(asm: Assembly, e, j_max=3, Minv=None):
    """Moments ``mu_j = b^T (M^-1 H)^j M^-1 b``, j = 0..j_max, of the load ``b = -F e`` of a Mandel
    strain ``e`` (3,) [N m per unit strain, squared over N/m]; ``mu_0`` is the first-order
    relaxation (``C_fo = C_aff - mu_0 / A`` along ``e``)."""
    if Minv is None:
        Minv = block_preconditioner(asm)[1]
    b = -(asm.F @ np.asarray(e, dtype=float))
    vals = []
    y = Minv @ b
    for _ in range(j_max + 1):
        vals.append(float(b @ y))
        y = Minv @ (asm.H @ y)
    return np.array(vals)


# ---- block preconditioned conjugate gradients ------------------------------------------------
def _iso(C):
    return isotropic_moduli(C)


def _tall(A, T):
    """``A @ T`` for a tall ``A`` (ndof, m) and a small ``T`` (m, s): computed as ``(T^T A^T)^T``,
    several times faster with OpenBLAS than the direct product on this machine."""
    return (T.T @ A.T).T


class _BlockPCG:
    """Block PCG on ``H X = B`` (B = -F, s <= 3 columns) preconditioned by ``Minv = M^-1``.

    Each step (i) M-orthonormalises the new search block, dropping columns that vanish or depend
    on the others (zero load: e.g. the bulk mode of an affine lattice), (ii) H-orthonormalises it
    by an eigen-decomposition of ``P^T H P`` (negative curvature is detected there, floppy
    directions ``p^T H p ~ 0`` are dropped: breakdown-free block CG), and (iii) H-conjugates it
    against every earlier block (``full``: re-orthogonalisation, the iterates are the Galerkin
    solutions on the block Krylov space as in exact arithmetic; memory 2 k s ndof floats) or
    against the last one only (the block CG recurrence; identical to 5 digits over 40 steps on
    our N = 3000 packings, and what large systems use).
    ``Rk`` is the energy estimate ``2 B^T X - X^T H X`` of the iterate, a rigorous lower bound of
    ``B^T H^+ B`` for any ``X`` when ``H >= 0``.
    """

    def __init__(self, H, M, Minv, B, full=True, deflate=None, passes=1, true_residual=False):
        # H is symmetric: its transpose is the CSR form of the same matrix, without a copy (or H
        # read from the multilevel copy, microhom.shared_h: issue 26)
        self.H = H if isinstance(H, ShiftedCopy) else H.T if sp.isspmatrix_csc(H) else H.tocsr()
        self.M, self.Minv, self.full = M, Minv, full
        self.passes, self.true_residual = int(passes), bool(true_residual)
        B = np.asfortranarray(B)
        self.B = B
        self.X = np.zeros_like(B)
        self.R = B.copy()
        self.Rt = self.R
        self.m_row, self.E = 0, None
        z0 = Minv @ self.R
        zz = np.einsum("ij,ij->j", z0, self.R)
        self.scale2 = float(max(zz.max(initial=0.0), 1e-300))
        self.Rk = np.zeros((B.shape[1], B.shape[1]))
        self._chunks = []                                # earlier H-orthonormal blocks and H times them
        self._last = 0                                   # columns of the last block (last_block)
        self._deflation = []                             # soft modes: conjugated against at every step
        self.unstable = False
        self.n_floppy = 0
        self.n_deflated = 0
        self.done = False
        if deflate is not None and deflate.shape[1]:
            # augmented Krylov space: span(V) first (deflated CG); kept in every later conjugation
            got = self._take(np.asfortranarray(deflate, dtype=float), scale2=1.0)
            if got is not None:
                self._deflation.append(got)
                self.n_deflated = got[0].shape[1]
        self.Z = Minv @ self.R if self.n_deflated else z0
        self.P = self.Z.copy()

    def step(self):
        got = self._take(self.P)
        if got is None:
            return
        self._append(*got)
        self.Z = self.Minv @ self.R
        self.P = self.Z

    def _take(self, P, scale2=None):
        """Conjugate, M- and H-orthonormalise the block ``P`` and move the iterate along it.
        Returns (P, HP) H-orthonormal, or None (converged, floppy only, or negative curvature)."""
        P = self._conjugate(P)                           # full H-conjugation (re-orthogonalisation)
        Gm = P.T @ (self.M @ P)
        wm, Vm = np.linalg.eigh(0.5 * (Gm + Gm.T))
        keep = wm > max(1e-24 * (self.scale2 if scale2 is None else scale2), 1e-12 * wm.max(initial=0.0))
        if not keep.any():
            self.done = True                              # converged: no new direction
            return None
        P = _tall(P, Vm[:, keep] / np.sqrt(wm[keep]))   # M-orthonormal
        HP = self.H @ P
        Gh = P.T @ HP
        wh, Uh = np.linalg.eigh(0.5 * (Gh + Gh.T))
        if np.any(wh < -_NEG_CURV):
            self.unstable = True
            self.done = True
            return None
        ok = wh > _NULL_CURV
        self.n_floppy += int(np.count_nonzero(~ok))
        if not ok.any():
            self.done = True
            return None
        T = Uh[:, ok] / np.sqrt(wh[ok])                  # P T is H-orthonormal
        P, HP = _tall(P, T), _tall(HP, T)
        alpha = P.T @ self.R
        self.X += _tall(P, alpha)
        # the bounds use the true residual B - H X (one product with 3 columns): the recursive one
        # drifts by round-off once it is small, and the lower bound must be that of X itself
        self.Rt = self.B - self.H @ self.X
        if self.true_residual:
            self.R = self.Rt                              # no drift in the iteration either
        else:
            self.R -= _tall(HP, alpha)
        R = self.B.T @ self.X + self.X.T @ self.Rt       # 2 B^T X - X^T H X  (H X = B - Rt)
        self.Rk = 0.5 * (R + R.T)
        return P, HP

    def _append(self, P, HP):
        """Store the block in fixed-size column chunks (no re-allocation, no copies); without full
        re-orthogonalisation only the last block is kept (the block CG recurrence)."""
        s = P.shape[1]
        self._last = s
        if not self.full:
            self._chunks = [[P, HP, s]]
            return
        if not self._chunks or self._chunks[-1][2] + s > _CHUNK:
            self._chunks.append([np.empty((P.shape[0], _CHUNK), order="F"),
                                 np.empty((P.shape[0], _CHUNK), order="F"), 0])
        c = self._chunks[-1]
        c[0][:, c[2]:c[2] + s] = P
        c[1][:, c[2]:c[2] + s] = HP
        c[2] += s

    def last_block(self):
        """The last H-orthonormal search block ``P_k`` (ndof, s), a view of the stored one (None
        before the first step): the last step is ``X_k - X_{k-1} = P_k alpha_k``, so its columns
        span a subspace of ``P_k``'s."""
        if not self._chunks:
            return None
        Pc, _, m = self._chunks[-1]
        return Pc[:, m - self._last:m]

    def _conjugate(self, P):
        """``P - sum_j P_j (HP_j^T P)`` over every stored block (full H-conjugation) and the
        deflated soft modes."""
        for _ in range(self.passes):
            for Pc, HPc in self._deflation:
                P = P - _tall(Pc, HPc.T @ P)
            for Pc, HPc, m in self._chunks:
                P = P - _tall(Pc[:, :m], HPc[:, :m].T @ P)
        return P


def _affine_kept(asm: Assembly, area: float) -> np.ndarray:
    """(m, m) affine tensor ``Df^T (K + K_g) Df / A`` of the load-bearing contacts (m = 3 Mandel
    components in 2D, 6 in 3D), from the assembly's own matrices (the same as
    ``kinematics.affine_tensor(asm.net, prestress)``)."""
    if asm.net.n_contacts == 0:
        m = _n_mandel(asm.net.dim)
        return np.zeros((m, m))
    C = asm.Df.T @ (asm.Ks @ asm.Df)
    if asm.Kgs is not None:
        C = C + asm.Df.T @ (asm.Kgs @ asm.Df)
    return C / area


def _n_mandel(dim):
    """Mandel strain components: 3 in 2D, 6 in 3D."""
    return 3 if dim == 2 else 6


def _tensor(C_aff_kept, Rk, area, corr):
    C = C_aff_kept - Rk / area
    C = 0.5 * (C + C.T)
    return C + corr


def _extrapolate(seq):
    """Tail extrapolation of a non-increasing sequence of upper bounds ``u_1 .. u_k`` (CG steps
    1..k): (value, error), error = inf when no estimate can be made.

    The increments ``d_j = u_{j-1} - u_j`` of CG on a packing decay neither geometrically (the
    spectrum of ``M^-1 H`` reaches down to the long-wavelength modes) nor as a clean power law.
    Measured on our packings (docs/results/hierarchy.md), the tail predicted by a geometric fit
    (ratio = geometric mean of the last two ratios) is too small and the tail of a power law
    ``d_j ~ c j^-s`` (least squares on the last six increments, summed from ``k + 1/2`` to
    infinity) too large (capped at 4 times the geometric one: with ``s`` near 1 it blows up on
    noisy increments). The value is the mean of the two extrapolations and the stated error the
    extrapolated tail itself (plus 1e-6 relative for round-off): the claim is that the exact value
    lies in ``[u_k - 2 tail, u_k]``. On 10 packings (orders 7..64, 1134 values of K and G) the
    error was within the stated error in 99.8 % of the cases (every frictional one) and at most
    1.24 times it (frictionless near jamming). An estimate, not a bound. Needs k >= 7 (six increments) and ``s > 1.05``.

    Fast convergence (the multilevel preconditioner): when the last two increment ratios are both
    at most ``_FAST_RATIO`` (k >= 4), the tail is the geometric one with the larger ratio and the
    stated error twice that tail. A round-off floor of 1e-12 relative is added to every stated error.
    """
    u = np.asarray(seq, dtype=float)
    k = u.size
    if k < 2:
        return float(u[-1]), float("inf")
    d = -np.diff(u)
    roundoff = 1e-12 * max(abs(u[0]), 1e-300)
    if d[-1] <= 1e-14 * max(abs(u[0]), 1e-300):            # stagnated: converged to round-off
        return float(u[-1]), float(max(d[-1], 0.0) + roundoff)
    if k >= 4 and np.all(d[-3:] > 0):
        r1, r2 = d[-1] / d[-2], d[-2] / d[-3]
        if max(r1, r2) <= _FAST_RATIO:                     # fast geometric convergence (multilevel)
            q = max(r1, r2)
            tail = d[-1] * q / (1 - q)
            return float(u[-1] - tail), float(2 * tail + roundoff)
    if k < 7 or np.any(d[-6:] <= 0):
        return float(u[-1]), float("inf")
    r1, r2 = d[-1] / d[-2], d[-2] / d[-3]
    q = min(np.sqrt(r1 * r2), 0.99)
    tail_g = d[-1] * q / (1 - q)
    j = np.arange(1, d.size + 1, dtype=float)[-6:]
    slope, logc = np.polyfit(np.log(j), np.log(d[-6:]), 1)
    s_ = -slope
    if not (s_ > 1.05):                                    # no summable tail: no estimate
        return float(u[-1]), float("inf")
    tail_p = np.exp(logc) * (j[-1] + 0.5) ** (1 - s_) / (s_ - 1)
    tail_p = min(tail_p, 4.0 * tail_g)     # s -> 1 from noisy increments: the power tail blows up
    tail = 0.5 * (tail_g + tail_p)
    return float(u[-1] - tail), float(tail + 1e-6 * abs(u[-1]))


# ---- memory ----------------------------------------------------------------------------------
class HierarchyMemoryError(MemoryError):
    """The predicted memory of :func:`relaxation_hierarchy` exceeds what is available (raised
    before anything large is allocated; the message gives both figures in bytes)."""


@dataclass(frozen=True)
class MemoryPlan(Result):
    """Predicted peak memory of :func:`relaxation_hierarchy`, by part [bytes].

    Per-unit figures measured with ``tracemalloc`` on a 300-disk packing (840 unknowns) and rounded
    up (docs/results/hierarchy.md, section "Memory guard"); checked against the measured peak by
    tests/test_hierarchy.py.

    Attributes
    ----------
    assembly : int
        ``H``, ``F`` and the contact matrices: 128 bytes per predicted non-zero of ``H``
        (``9 N + 18 N_c``; spheres: 48 bytes per non-zero, ``36 N + 72 N_c``) [bytes].
    preconditioner : int
        Particle blocks ``M``, ``M^-1``, ``M^-1/2`` (700 bytes per unknown) plus, with "amg", the
        multilevel hierarchy (600 bytes per non-zero of ``H``; spheres: 80, 70 with ``shared_h``) [bytes].
    basis : int
        Re-orthogonalisation basis ``P``, ``HP`` (2 x 8 bytes x ndof x (3 max_order + soft modes),
        in chunks of 48 columns), or the recurrence's 12 blocks of 3 columns [bytes].
    soft_modes : int
        LOBPCG on the pencil: 1000 bytes per unknown and mode searched [bytes].
    dense : int
        Dense spectral bound: 24 bytes x (3N)^2 (matrix, copy and eigen-solver workspace) [bytes];
        ``relaxation_hierarchy`` checks it after the assembly with the actual ndof.
    factor : int
        The sparse certificate's factorisation of ``H - s M``, kept for the factorised CG steps
        (``microhom.factor.predicted_factor_bytes``: about 0.47 GB for 1e5 disks with PARDISO),
        0 when no sparse certificate is made [bytes].
    total : int
        Sum of the parts [bytes].
    available : int or None
        The limit compared with: ``max_memory`` or the system's available memory
        (``MemAvailable`` of /proc/meminfo), None when unknown (then nothing is refused) [bytes].
    """

    assembly: int
    preconditioner: int
    basis: int
    soft_modes: int
    dense: int
    total: int
    available: int | None
    factor: int = 0




def plan_memory(n_particles: int, n_contacts: int, *, max_order: int = 16, full: bool = True,
                preconditioner: str = "amg", soft_modes: int = 3, dense: bool = True,
                available: int | None = None, dim: int = 2, factor: bool = False,
                shared_h: bool = False) -> MemoryPlan:
    """Predicted peak memory of :func:`relaxation_hierarchy` before anything is assembled (see
    :class:`MemoryPlan` for the figures); ``ndof <= b n_particles`` with ``b = 3`` unknowns per
    disk (``dim = 2``) and 6 per sphere (``dim = 3``). In 3D the per-non-zero and per-unknown
    figures of 2D are kept except per non-zero (``b^2 N + 2 b^2 N_c`` of them): 48 bytes for the
    assembly and 80 for the multilevel hierarchy, the peaks measured on the built FCC networks
    of ``studies.bench_spheres`` (1.1e4 and 1.08e5 spheres: 33 bytes per non-zero for the
    assembly; the multilevel setup's transient and hierarchy 69 since its one-pass copy of ``H``
    (issue 26), 79-90 before; rounded up; docs/results/spheres.md, "Cost" and "Memory at 1e6
    spheres"); ``m = 6`` load columns. ``factor``: the sparse
    certificate's factorisation of ``H - s M`` is made and kept for the factorised steps
    (``microhom.factor.predicted_factor_bytes`` of the back end it takes). ``shared_h`` (3D, "amg"):
    the hierarchy drops the assembly's ``H`` once the setup has its copy and reads ``H`` from it
    (``microhom.shared_h``, issue 26): 70 bytes per non-zero for the multilevel setup's transient
    and hierarchy instead of 80 (measured 58.8 at 1.08e5 spheres, 68 before; docs/results/spheres.md,
    "Memory at 1e6 spheres")."""
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    N, Nc = int(n_particles), int(n_contacts)
    b = 3 if dim == 2 else 6
    m = 3 if dim == 2 else 6
    ndof = b * N
    nnz = b * b * N + 2 * b * b * Nc
    per_asm, per_amg = (128, 600) if dim == 2 else (48, 70 if shared_h else 80)
    asm = per_asm * nnz
    prec = 700 * ndof * (b // 3) + (per_amg * nnz if preconditioner == "amg" else 0)
    cols = m * int(max_order) + int(soft_modes) * 2
    basis = 16 * ndof * (_CHUNK * -(-cols // _CHUNK) if full else 12 * m)
    soft = 1000 * ndof * int(soft_modes) * 2
    dns = 24 * ndof * ndof if dense else 0
    fac = 0
    if factor:
        from microhom.factor import AUTO_PARDISO_DOF_PENCIL, have_pardiso, predicted_factor_bytes
        fac = int(predicted_factor_bytes(ndof, "pardiso" if have_pardiso() and ndof >= AUTO_PARDISO_DOF_PENCIL
                                         else "splu", dim))
    return MemoryPlan(assembly=asm, preconditioner=prec, basis=basis, soft_modes=soft, dense=dns,
                      total=asm + prec + basis + soft + dns + fac, available=available, factor=fac)


def _gb(b):
    return f"{b:.3g} bytes ({b / 2 ** 30:.3g} GiB)"


# ---- main entry ------------------------------------------------------------------------------
#: The one default target width of the hierarchy's interval (``relaxation_hierarchy``, ``dem
#: analyse``): 1 %, below the errors of the predictions it judges (the theory's and the closure's
#: are several %: docs/results/hierarchy.md); a smaller ``tol`` costs more CG orders.
DEFAULT_TOL = 1e-2


#: kt/kn range (median over the load-bearing contacts, sliding ones at 0) where the extrapolation's
#: stated error was measured honest (docs/results/hierarchy.md, sections 1 and 6)
CALIBRATED_KT_OVER_KN = (0.1, 1.0)
_DEGENERATE = 1e-10   # tensor eigenvalue within this fraction of the affine scale: zero (as dem.analysis.stiffness)


@dataclass
class _Run:
    """Mutable state of one run, filled step by step by relaxation_hierarchy's helpers."""

    network: ContactNetwork
    prestress: bool
    tol: float
    reasons: list = field(default_factory=list)
    asm: Assembly = None
    area: float = 0.0
    corr: np.ndarray = None
    C_aff: np.ndarray = None
    C_aff_all: np.ndarray = None
    C0: np.ndarray = None
    C_fo: np.ndarray = None
    M: object = None
    Minv: object = None
    Msq: object = None
    empty: bool = False
    lam: float | None = None
    lam_hi: float | None = None
    lam_n: float | None = None       # companion bound: pencil (H, N), N = blocks of the min-stiffness network
    Ninv: object = None
    best_low: np.ndarray = None      # running max over orders of the lower bounds of (K, G)
    far_ratio: bool = False          # some contact has |log10(kt/kn)| > 1
    src: str = "none"
    unstable: bool = False
    V_soft: np.ndarray | None = None
    P_amg: object = None
    t_bound: float = 0.0
    t_prec: float = 0.0
    t_early: float = 0.0             # the multilevel setup's wall time when built in _setup [s]
    Cs: list = field(default_factory=list)
    lowers: list = field(default_factory=list)
    converged: bool = False
    trivial: bool = False
    order: int = 0
    n_floppy: int = 0
    n_soft: int = 0
    kt_over_kn: float = float("nan")
    calibrated: bool = False
    min_contacts: object = None
    limit: int | None = None         # memory limit [bytes] (max_memory or available), None: unknown
    planned: int = 0                 # predicted peak without the dense bound [bytes]
    factor: object = None            # factor of H - s M at the certified shift (sparse certificate)
    factor_steps: int = 4            # at most this many CG steps preconditioned by it
    n_factor_steps: int = 0          # taken
    max_order: int = 16
    certify_max_order: int = 200
    spin_arm: str = "contact"
    margins: list = field(default_factory=list)   # round-off margin of each order's energy [unit of C]
    blocks: tuple = None             # block_preconditioner(asm): (M, M^-1, M^-1/2, n_bad)
    lean: bool = False               # nothing after the setup reads asm.H, M^-1, M^-1/2 (_lean)
    M_own: object = None             # the particle blocks of H taken before H was dropped (_early_multilevel)
    H_shared: object = None          # H read from the multilevel copy (microhom.shared_h), or None
    spectral_guess: float | None = None
    n_cert_fact: int = 0             # numeric factorisations of the sparse certificate
    no_certificate: bool = False     # its factor does not fit in memory (_memory_guard)
    dual: object = None              # microhom.dual_bound.Equilibrator (the dual lower bound), or None
    dual_last: tuple = None          # the last evaluated dual bound: (C_lower, gap (K, G), CG residual norm)
    n_dual: int = 0                  # dual bounds evaluated
    dual_coarse: object = None       # r -> y before the dual bound's statics (_dual_correction), or None
    dual_prev_X: np.ndarray = None   # the iterate of the previous order (the dual bound's trial step; not on the lean path)


def _max_order_ok(v):
    if isinstance(v, str):
        return v == "auto"
    try:
        return int(v) == v and 1 <= v <= 10000
    except (TypeError, ValueError, OverflowError):
        return False


def _spectral_bound_ok(v):
    if isinstance(v, str):
        return v in ("auto", "none")
    try:
        lam = float(v)
    except (TypeError, ValueError):
        return False
    return bool(np.isfinite(lam) and lam > 0)


def _positive(v):
    return finite_real(v) and v > 0


def _int_in(lo, hi):
    return lambda v: integer(v) and lo <= v <= hi


@dataclass(frozen=True)
class HierarchyOptions(Options):
    """How :func:`relaxation_hierarchy` runs: frozen, validated when made (a value outside its range
    raises :class:`~microhom.options.OptionError`, a ``ValueError`` naming the field and its range).

    ``relaxation_hierarchy(net, tol=1e-3)`` is ``relaxation_hierarchy(net, HierarchyOptions(tol=1e-3))``;
    keywords given with an options object replace its values. Variants: ``options.replace(tol=1e-4)``;
    ``as_dict()`` records them.

    Attributes
    ----------
    prestress : bool
        Include the geometric stiffness of the normal forces and the pre-stress
        correction of the Cauchy increment (needs ``network.fn``), as ``dem.analysis.stiffness`` does.
    tol : float
        Target relative width of the interval of K and of G, in (0, 1). The iteration stops at
        the first order where both meet it, or at ``max_order``; the result says which.
    max_order : int or "auto"
        Maximum number of CG steps (Gauss points) with the chosen preconditioner, 1..10000; order
        k uses 2k moments. "auto" (default): 1 where the sparse certificate kept its factorisation
        (``dense_max < ndof <= CERTIFIED_MAX_DOF``, ``factor_steps > 0``, it fits in memory), else
        16. Without a certified spectral bound the iteration stops here (or earlier,
        where the calibrated extrapolation meets ``tol``). With one, only the rigorous interval
        stops it (issue 22): past ``max_order`` it goes on with ``factor_steps`` or
        ``certify_max_order``, and ``reasons`` says when even that cap was not enough.
    spectral_bound : {"auto", "none"} or float
        "auto" (exact dense bound if ``ndof <= dense_max``, else the sparse certificate by
        Sylvester's inertia, ``microhom.spectral.certified_bound``, up to
        ``microhom.spectral.CERTIFIED_MAX_DOF`` unknowns; none above), "none", or a
        positive finite float: a certified lower bound of the non-zero spectrum of ``M^-1 H`` (the
        caller's responsibility).
    dense_max : int
        Largest number of unknowns for the dense spectral bound, >= 0 (docs/results/hierarchy.md §7).
    min_contacts : int, "rigid" or None
        Contacts below which a particle is a rattler (as in ``dem.analysis.stiffness``), >= 0.
    reorthogonalize : bool or "auto"
        H-conjugate each new search block against all earlier ones (True), only the last (False:
        the block CG recurrence, O(ndof) memory), or "auto" (full up to 50 000 unknowns if it fits).
    preconditioner : {"auto", "amg", "block"}
        Preconditioner of the conjugate gradients. "auto" (default): "block" where ``max_order``
        "auto" resolved to 1, else "amg". "amg": smoothed-aggregation multilevel
        (``microhom.multilevel``), converges in a few steps even near isostaticity. "block": the
        particle-block Jacobi ``M`` (each particle's 3 x 3 block, 6 x 6 for a sphere): order k is
        the relaxation k contact shells carry (the local ladder of docs/theory.md, section 9).
        The bounds are rigorous with either; the lower bound and the first-order estimate use ``M``.
    soft_modes : int or "auto"
        Number of lowest modes of the pencil (H, M) to search per preconditioner (:func:`lowest_modes`,
        LOBPCG; 0..50), or "auto" (default): none when the automatic spectral bound of (H, M) is
        certified (its inertia proves stability and only the rigorous interval stops CG; if that
        interval misses ``tol`` the extrapolation is then not calibrated and ``reasons`` says so),
        else 3 up to ``SOFT_MODES_AUTO_MAX`` unknowns (0.2-1 s for 1000-8000 unknowns), 0 above
        (then the extrapolation is not calibrated: ``reasons`` says so). A negative Rayleigh
        quotient proves that the (pre-stressed) network is unstable: it is flagged ``unstable``
        with the eigenvalue. The soft modes found are deflated: the CG space is augmented with them, so that
        a near-mechanism the load barely excites cannot leave the iteration on a plateau that the
        extrapolation would take for convergence (docs/results/hierarchy.md, the sweep).
    max_memory : float or None
        Memory limit [bytes] for the predicted peak (:func:`plan_memory`), > 0; None (default) the
        system's available memory. A prediction above it raises :class:`HierarchyMemoryError` naming
        both figures before anything large is allocated (with ``reorthogonalize="auto"`` the
        recurrence is tried first; a dense bound or a sparse certificate's factor that does not fit
        is skipped; ``reasons`` says so).
    certify_max_order : int
        Cap on the CG steps when a certified bound is available but no factorisation is (dense,
        user or companion bound), 1..10000 (values below ``max_order`` act as ``max_order``).
        The basis is fully re-orthogonalised past ``max_order`` only while it fits in memory.
    factor_steps : int
        Steps past ``max_order`` preconditioned by the sparse certificate's factorisation of
        ``H - s M`` (``microhom.spectral.certified_bound``, ``ndof > dense_max``), 0..100; 0
        releases the factorisation at once and continues with the multilevel CG instead. 1-3
        such steps meet ``tol`` where the multilevel CG plateaus on the soft modes.
    spectral_guess : float or None
        Estimate of the smallest non-zero eigenvalue of (H, M) for the sparse certificate (e.g. the
        ``spectral_bound`` of a similar network), > 0 [-]: at most twice it, with the translations
        as the only null space, one numeric factorisation certifies half of it (docs/theory.md
        section 9, "One factorisation"; passed to ``certified_bound(guess=)``). Never trusted: a
        wrong guess costs a factorisation, not the bound.
    spin_arm : ``"contact"`` (default) or ``"radius"``
        Spin arms of the assembly (:mod:`microhom.kinematics`); the bounds are of that tensor.
    dual_bound : {"auto", True, False}
        The complementary-energy lower bound (``microhom.dual_bound``, docs/theory.md section 12):
        "auto" where "auto" found no spectral bound, True always, False never.
    """

    prestress: bool = False
    tol: float = DEFAULT_TOL
    max_order: int | str = "auto"
    spectral_bound: float | str = "auto"
    dense_max: int = 1000
    min_contacts: int | str | None = None
    reorthogonalize: bool | str = "auto"
    preconditioner: str = "auto"
    soft_modes: int | str = "auto"
    max_memory: float | None = None
    certify_max_order: int = 200
    factor_steps: int = 4
    spectral_guess: float | None = None
    spin_arm: str = "contact"
    dual_bound: bool | str = "auto"

    RULES = {
        "prestress": ("True or False", flag),
        "tol": ("a relative width in (0, 1)",
                lambda v: isinstance(v, (int, float)) and bool(np.isfinite(v)) and 0 < v < 1),
        "max_order": ("'auto' or an integer in [1, 10000]", _max_order_ok),
        "spectral_bound": ("'auto', 'none' or a positive finite float", _spectral_bound_ok),
        "dense_max": ("an integer >= 0", lambda v: integer(v) and v >= 0),
        "min_contacts": ("None, 'rigid' or an integer >= 0",
                         lambda v: (integer(v) and v >= 0) or v is None or (isinstance(v, str) and v == "rigid")),
        "reorthogonalize": ("'auto', True or False", lambda v: flag(v) or (isinstance(v, str) and v == "auto")),
        "preconditioner": ("'auto', 'amg' or 'block'", lambda v: isinstance(v, str) and v in ("auto", "amg", "block")),
        "soft_modes": ("'auto' or an integer in [0, 50]",
                       lambda v: (isinstance(v, str) and v == "auto")
                       or (isinstance(v, (int, np.integer)) and 0 <= v <= 50)),
        "max_memory": ("None or a positive number of bytes", lambda v: v is None or _positive(v)),
        "certify_max_order": ("an integer in [1, 10000]", _int_in(1, 10000)),
        "factor_steps": ("an integer in [0, 100]", _int_in(0, 100)),
        "spectral_guess": ("None or a positive finite float", lambda v: v is None or _positive(v)),
        "spin_arm": (f"one of {SPIN_ARMS}", lambda v: isinstance(v, str) and v in SPIN_ARMS),
        "dual_bound": ("'auto', True or False", lambda v: isinstance(v, bool) or (isinstance(v, str) and v == "auto")),
    }

    @property
    def user_bound(self) -> float | None:
        """The caller's certified spectral bound (``spectral_bound`` as a float), else None."""
        return None if isinstance(self.spectral_bound, str) else float(self.spectral_bound)


def relaxation_hierarchy(network: ContactNetwork, options: HierarchyOptions | None = None,
                         **overrides) -> HierarchyResult:
    """Estimates of the stiffness of ``network`` of increasing order, with bounds.

    The result is ``valid`` only where its claim is backed: the rigorous interval met ``tol``
    (``certified``), or the extrapolation met it in the regime where its stated error was measured
    honest (``calibrated``: kt/kn in ``CALIBRATED_KT_OVER_KN`` with the soft-mode search), and
    nothing voids it (not jammed, floppy, unstable, a negative modulus). Every other result says
    why in ``reasons``. Outside the calibrated regime the estimate is the rigorous interval itself
    (midpoint, half-width; ``upper`` and an infinite error without a spectral bound).

    Why the extrapolation is trusted only where calibrated, and why with a certified spectral bound
    only the rigorous interval stops CG: docs/theory.md section 9, docs/results/hierarchy.md §6-7.

    Parameters
    ----------
    network : ContactNetwork
        A periodic network (sliding contacts have kt_eff = 0, exactly as in the exact
        solver; rattlers are removed iteratively, ``min_contacts`` as in ``dem.analysis.stiffness``).
    options : HierarchyOptions, optional
        The settings (:class:`HierarchyOptions`: tolerance, orders, spectral bound, preconditioner,
        soft modes, memory, ...); None: the defaults.
    **overrides
        Any field of :class:`HierarchyOptions` as a keyword (``relaxation_hierarchy(net, tol=1e-3,
        prestress=True)``), replacing the value of ``options``. A value outside its range raises
        :class:`~microhom.options.OptionError` (a ``ValueError``) naming it; an unknown name a
        ``TypeError``.

    Returns
    -------
    HierarchyResult
        Moduli [unit of kn, N/m] with bounds, orders, flags and the validity.
    """
    t0 = time.perf_counter()
    o = merged(HierarchyOptions, options, overrides, "relaxation_hierarchy")
    _check_network(network, o.prestress)
    run, full = _start(network, o)
    _setup(run, o.min_contacts, o)
    t_asm = (t1 := time.perf_counter()) - t0 - run.t_early
    _spectral_step(run, o.user_bound, o.spectral_bound, o.dense_max, o.dual_bound)
    max_order, preconditioner = _resolve_auto(run, o.max_order == "auto", o.preconditioner == "auto",
                                              run.max_order, o.preconditioner)
    soft = _soft_mode_step(run, o.soft_modes)
    _calibration(run, preconditioner, soft)
    _cg_step(run, max_order, full, preconditioner)
    t_solve = time.perf_counter() - t1 - run.t_bound + run.t_early
    return _finish(run, preconditioner, t_asm, t_solve)


def _check_network(network, prestress):
    """The network's own checks (the options are checked by :class:`HierarchyOptions`)."""
    if not isinstance(network, ContactNetwork):
        raise TypeError(f"network must be a microhom.network.ContactNetwork, got {type(network).__name__}")
    if network.cell is None:
        raise ValueError("network must be periodic (cell is None): the hierarchy estimates the "
                         "stiffness of a periodic cell")
    if prestress and network.fn is None:
        raise ValueError("prestress=True needs the normal forces fn of the network (ContactNetwork.fn)")


def _start(network, o):
    """The run's state from the options (``max_order="auto"`` as 16 and ``preconditioner="auto"``
    as "amg" until :func:`_resolve_auto`), then the memory guard; returns (run, full
    re-orthogonalisation)."""
    max_order = 16 if o.max_order == "auto" else o.max_order
    prec0 = "amg" if o.preconditioner == "auto" else o.preconditioner
    run = _Run(network=network, prestress=o.prestress, tol=float(o.tol), min_contacts=o.min_contacts,
               max_order=int(max_order), certify_max_order=int(o.certify_max_order),
               factor_steps=int(o.factor_steps), spectral_guess=o.spectral_guess, spin_arm=o.spin_arm)
    full = _memory_guard(run, max_order, o.reorthogonalize, prec0, o.soft_modes, o.max_memory,
                         o.spectral_bound == "auto" and o.factor_steps > 0, o.dense_max, _shared_planned(network, o))
    return run, full


def _resolve_auto(run, auto_order, auto_prec, max_order, preconditioner):
    """``max_order="auto"``: 1 when the sparse certificate kept its factorisation (the factorised
    steps close the interval), else 16; ``preconditioner="auto"``: "block" for that one step, else
    "amg"."""
    lean = run.factor is not None and auto_order
    if auto_order:
        max_order = 1 if lean else 16
        run.max_order = max_order
    if auto_prec:
        preconditioner = "block" if lean else "amg"
    return max_order, preconditioner


def _shared_planned(network, o):
    """Whether the run will read ``H`` from the multilevel copy (:func:`_early_multilevel`), as far
    as the options and the sizes tell before the assembly (for :func:`plan_memory`'s ``shared_h``)."""
    from microhom.spectral import CERTIFIED_MAX_DOF
    ndof = (network.dim + rotational_dofs(network.dim)) * network.n_particles
    soft = o.soft_modes == 0 or (o.soft_modes == "auto" and ndof > SOFT_MODES_AUTO_MAX)
    return bool(SHARE_H and network.dim == 3 and o.preconditioner in ("amg", "auto") and soft
                and not DUAL_VCYCLES and (o.spectral_bound == "none" or (o.spectral_bound == "auto"
                                                                        and ndof > CERTIFIED_MAX_DOF)))


def _memory_guard(run, max_order, reorthogonalize, preconditioner, soft_modes, max_memory, certify=False,
                  dense_max=1000, shared_h=False):
    """Refuse before allocating when the predicted peak (:func:`plan_memory`, from N and N_c
    alone) exceeds the limit; returns whether the basis is fully re-orthogonalised (with "auto",
    the recurrence is tried before refusing). The dense bound is checked after the assembly."""
    net = run.network
    N, Nc = net.n_particles, net.n_contacts
    ndof = (net.dim + rotational_dofs(net.dim)) * N
    limit = int(max_memory) if max_memory is not None else available_memory()
    full = ndof <= 50_000 if reorthogonalize == "auto" else bool(reorthogonalize)
    soft = (3 if ndof <= SOFT_MODES_AUTO_MAX else 0) if soft_modes == "auto" else int(soft_modes)

    from microhom.spectral import CERTIFIED_MAX_DOF
    cert = bool(certify and dense_max < ndof <= CERTIFIED_MAX_DOF)

    def plan(f, c=cert):
        return plan_memory(N, Nc, max_order=max_order, full=f, preconditioner=preconditioner,
                           soft_modes=soft, dense=False, available=limit, dim=net.dim, factor=c,
                           shared_h=shared_h)
    p = plan(full)
    if limit is not None and cert and p.total > limit and plan(full, False).total <= limit:
        run.reasons.append(f"the sparse certificate's factor of {_gb(p.factor)} does not fit (available "
                           f"{_gb(limit)}): no certified spectral bound")
        run.no_certificate = True
        p = plan(full, False)
    if limit is not None and p.total > limit and full and reorthogonalize == "auto" \
            and plan(False).total <= limit:
        run.reasons.append(f"re-orthogonalisation basis of {_gb(p.basis)} does not fit (available "
                           f"{_gb(limit)}): the block CG recurrence is used")
        full = False
        p = plan(full, p.factor > 0)
    run.limit, run.planned = limit, p.total
    if limit is not None and p.total > limit:
        raise HierarchyMemoryError(
            f"relaxation_hierarchy needs about {_gb(p.total)} for N = {N} particles, {Nc} contacts "
            f"(assembly {_gb(p.assembly)}, preconditioner {_gb(p.preconditioner)}, basis "
            f"{_gb(p.basis)}, soft modes {_gb(p.soft_modes)}) but {_gb(limit)} are available "
            "(max_memory); reduce max_order, pass reorthogonalize=False, preconditioner='block' "
            "or soft_modes=0" + (_LARGE_3D_NOTE if shared_h else ""))
    return full


#: what the guard's message adds where the 3D figures are known to overestimate (the lean path of
#: large sphere networks; docs/results/spheres.md, "The third run at 1e6 spheres")
_LARGE_3D_NOTE = ("; on large sphere networks these figures overestimate: 1e6 spheres peaked at 14.5 GiB "
                  "(the benchmark's multilevel options) where 45 GiB are planned, so a larger max_memory "
                  "may well fit (the run then is not guarded)")


def _setup(run, min_contacts, o=None):
    """Assembly (without its dense per-contact ``B`` and ``K``: :func:`_slim`), the multilevel
    preconditioner where the CG is certain to use it (:func:`_amg_certain`, options ``o``), affine
    and first-order tensors, particle blocks."""
    net, prestress = run.network, run.prestress
    # no local reference to the assembly before the multilevel setup: it may drop H (_early_multilevel)
    run.asm = _slim(assemble(net, prestress=prestress, min_contacts=min_contacts, pin=False, spin_arm=run.spin_arm))
    run.area = net.volume                        # area of a 2D cell [m^2], volume of a 3D one [m^3]
    if o is not None and _amg_certain(run, o):
        _early_multilevel(run, o)
    asm = run.asm
    nm = _n_mandel(net.dim)
    run.corr = prestress_correction(stress0(net)) if prestress else np.zeros((nm, nm))
    run.C_aff = _affine_kept(asm, run.area)
    run.C_aff_all = (affine_tensor(net, prestress) if asm.net.n_contacts < net.n_contacts
                     else run.C_aff) + run.corr
    run.C0 = _tensor(run.C_aff, np.zeros((nm, nm)), run.area, run.corr)
    run.empty = net.n_contacts == 0 or asm.ndof == 0 or asm.net.n_contacts == 0
    if net.n_contacts == 0:
        run.reasons.append("not jammed: no contacts, the network carries no load")
    elif run.empty:
        run.reasons.append("not jammed: no load-bearing backbone, every particle is a rattler")
    if asm.ndof:
        run.blocks = block_preconditioner(asm, M=run.M_own, sqrt=not run.lean)
        run.M_own = None
        run.M, run.Minv, run.Msq, n_bad = run.blocks
        if n_bad:
            run.reasons.append(f"{n_bad} particle block(s) of H singular or indefinite (floppy particle "
                               "or pre-stress larger than the contact stiffness)")
        Rfo = run.asm.F.T @ (run.Minv @ run.asm.F)
        if run.lean:            # nothing after the first-order tensor reads M^-1 (_lean): not held
            run.Minv, run.blocks = None, (run.M, None, None, n_bad)
    else:
        Rfo = np.zeros((nm, nm))
    run.C_fo = _tensor(run.C_aff, 0.5 * (Rfo + Rfo.T), run.area, run.corr)
    kept = asm.net
    run.far_ratio = kept.n_contacts > 0 and _min_ratio(kept) < 0.1    # some |log10(kt/kn)| > 1
    if kept.n_contacts:
        run.kt_over_kn = float(np.median(kept.effective_kt / np.maximum(np.asarray(kept.kn, float)
                                                                          * np.ones(kept.n_contacts), 1e-300)))


#: in 3D, where nothing else reads it (_lean), the CG reads H from the multilevel hierarchy's copy and
#: the assembly's H is dropped before pyamg's setup (issue 26, microhom.shared_h; the products differ
#: from the CSC ones in the last bits, the round-off margin covers it; 2D keeps its H: bit for bit)
SHARE_H = True


def _early_multilevel(run, o):
    """The multilevel preconditioner built right after the assembly (issue 26: its setup's
    transient, the run's peak on large networks, does not stack on the particle blocks and the
    dual bound's statics; the same V-cycle: it reads the assembly only). Where nothing later reads
    the assembly's ``H`` (:func:`_lean`) in 3D, ``H`` is dropped once the setup has its blocked
    copy, before pyamg's transient, and the CG reads ``H`` from that copy
    (``run.H_shared``, :class:`microhom.shared_h.ShiftedCopy`); the particle blocks ``M`` are
    taken from ``H`` before (``run.M_own``: the same matrix)."""
    run.lean = _lean(run, o)
    share = SHARE_H and run.lean and run.asm.net.dim == 3
    if share:
        run.M_own = _own_blocks(run.asm.H, dof_layout(run.asm)[0])

    def drop(A, order, shift):                # a float64 copy only (not a float32 hierarchy)
        if sp.issparse(A) and A.format in ("bsr", "csr") and A.dtype == np.float64:
            run.H_shared = ShiftedCopy(A, order, shift)
            run.asm = replace(run.asm, H=None)
    run.P_amg, info = amg_preconditioner(run.asm, release=drop if share else None)
    release_free_memory()      # the setup's freed small blocks (issue 26)
    run.t_prec = run.t_early = info.setup_time


def _lean(run, o):
    """Whether, past the multilevel setup and the first-order tensor, nothing reads the assembly's
    ``H`` (other than the CG's products and round-off margins), ``M^-1`` or ``M^-1/2`` (issue 26):
    no soft-mode search, no spectral bound of the pencil (``spectral_bound="none"``, or "auto"
    above ``CERTIFIED_MAX_DOF`` unknowns or where its factor does not fit), no V-cycle before the
    dual bound's statics (``DUAL_VCYCLES`` 0); called where the CG is certain to use the
    multilevel preconditioner (:func:`_amg_certain`)."""
    from microhom.spectral import CERTIFIED_MAX_DOF
    ndof = run.asm.ndof
    soft = o.soft_modes == 0 or (o.soft_modes == "auto" and ndof > SOFT_MODES_AUTO_MAX)
    spectral = o.spectral_bound == "none" or (o.spectral_bound == "auto" and (
        ndof > CERTIFIED_MAX_DOF or (ndof > o.dense_max and run.no_certificate)))
    return bool(soft and spectral and not DUAL_VCYCLES and ndof)


def _slim(asm):
    """``asm`` without the dense per-contact ``B`` and ``K`` of ``asm.matrices`` (issue 26: 360
    bytes per sphere contact, copies of the sparse ``Bs`` and ``Ks``); the hierarchy reads them
    only in the dual bound's statics, which recomputes them (:func:`_full_matrices`). ``D`` stays:
    ``Df`` is a view of it. Nor the contacts' unknowns ``ldof`` (read by the exact solver only:
    96 bytes per sphere contact, 0.3 GiB at 1e6)."""
    m = asm.matrices
    return replace(asm, matrices=replace(m, B=None, K=None), ldof=None)


def _full_matrices(run):
    """``run.asm`` with its per-contact matrices recomputed (:func:`_slim`): the same function on
    the same contacts as the assembly's, so the same numbers."""
    m = contact_matrices(run.asm.net, run.prestress, run.spin_arm)
    return replace(run.asm, matrices=m)


def _amg_certain(run, o):
    """Whether the CG will use the multilevel preconditioner whatever the spectral step finds:
    ``preconditioner="amg"``, or "auto" where the sparse certificate cannot keep a factorisation
    (``max_order`` given, a user's or no spectral bound, ``factor_steps=0``, no certificate, or
    unknowns outside (``dense_max``, ``CERTIFIED_MAX_DOF``]); not on an empty or trivial system
    (no CG)."""
    asm = run.asm
    if o.preconditioner not in ("amg", "auto") or asm.net.n_contacts == 0 or _trivial(asm):
        return False
    if o.preconditioner == "amg":
        return True
    from microhom.spectral import CERTIFIED_MAX_DOF
    return (o.max_order != "auto" or o.user_bound is not None or o.spectral_bound != "auto"
            or o.factor_steps == 0 or run.no_certificate
            or not o.dense_max < asm.ndof <= CERTIFIED_MAX_DOF)


def _trivial(asm):
    """Nothing to relax: no load on the unknowns (``_cg_step``'s test; e.g. an affine lattice)."""
    scale_F = asm.F_scale if asm.F_scale > 0 else 1.0
    return asm.ndof == 0 or float(np.abs(asm.F).max(initial=0.0)) <= 1e-13 * scale_F


def _spectral_step(run, user_lam, spectral_bound, dense_max, dual_bound="auto"):
    """The certified lower bound of the pencil's non-zero spectrum (user's, dense, or none), then
    the dual bound's statics where it applies (:func:`_dual_step`)."""
    tb = time.perf_counter()
    asm = run.asm
    run.lam_hi = None if run.prestress else 2.0   # H <= 2M without pre-stress (docs/theory.md section 9)
    if user_lam is not None:
        run.lam, run.src = user_lam, "user"
    elif spectral_bound == "auto" and 0 < asm.ndof <= dense_max and not _dense_fits(run, asm.ndof):
        pass
    elif spectral_bound == "auto" and asm.ndof > dense_max and run.no_certificate:
        pass
    elif spectral_bound == "auto" and asm.ndof:
        run.lam, run.lam_hi, _, n_neg, run.factor, run.n_cert_fact = _spectral_lower_bound(
            asm, run.Msq, dense_max, True, run.spectral_guess, run.blocks, lean=True)
        if run.factor is not None and run.factor_steps == 0:
            run.factor.release()
            run.factor = None
        run.src = ("dense" if asm.ndof <= dense_max else "inertia") if run.lam is not None else "none"
        run.unstable = n_neg > 0
        if n_neg and run.factor is not None:
            run.factor.release()
            run.factor = None
        if n_neg:
            run.reasons.append(f"unstable: negative curvature, the pencil (H, M) has {n_neg} negative "
                               "eigenvalue(s) (dense check: H indefinite); the bounds are void")
        if not run.unstable:
            _companion_bound(run, dense_max)
            r = _min_ratio(run.asm.net)
            if run.lam is not None and r < _TRUST_RATIO and asm.ndof <= dense_max:
                # the cluster near min(kt/kn, kn/kt) of (H, M) reaches the dense zero threshold
                # (1e-9 of the largest eigenvalue): modes below it would be taken for floppy ones
                # and the "smallest non-zero" eigenvalue would be too large (found at kt/kn = 1e9)
                run.lam = None
                run.reasons.append(f"dense bound of (H, M) not trusted at a stiffness ratio {r:.3g} < "
                                   f"{_TRUST_RATIO:g} (its soft cluster reaches the zero threshold)"
                                   + ("; the companion bound is used" if run.lam_n is not None else ""))
            if run.lam_n is not None:
                run.src = "companion" if run.lam is None else run.src + "+companion"
        if run.lam is None and run.lam_n is None and asm.ndof > dense_max:
            run.reasons.append(f"no certified spectral bound (ndof = {asm.ndof} > dense_max = {dense_max} and "
                               "the sparse certificate failed or the system is above its limit "
                               "microhom.spectral.CERTIFIED_MAX_DOF; pass spectral_bound=): the lower bounds are "
                               "not available")
    run.t_bound += time.perf_counter() - tb
    _dual_step(run, dual_bound, spectral_bound == "auto" and asm.ndof > dense_max)


def _dual_step(run, dual_bound, large):
    """The complementary-energy bound's statics (``microhom.dual_bound``) where it applies: always
    with ``dual_bound=True``; with "auto" when the spectral route was "auto" on a system above
    ``dense_max`` and gave no bound (``spectral_bound="none"`` keeps meaning no lower bound)."""
    if dual_bound is False or not run.asm.ndof or run.empty:
        return
    if dual_bound == "auto" and (run.lam is not None or run.lam_n is not None or not large):
        return
    if run.prestress:
        run.reasons.append("dual lower bound not used: the network is pre-stressed (the geometric stiffness "
                           "is not of the form B^T K B with K >= 0); only the spectral certificate applies")
        return
    tb = time.perf_counter()
    run.dual = build_equilibrator(_full_matrices(run), clusters=DUAL_CLUSTERS if run.asm.net.dim == 3 else None)
    release_free_memory()      # the statics' many small arrays left free heap pages behind (issue 26)
    if not run.dual.block_solved:
        run.reasons.append(f"dual lower bound not used: {run.dual.n_stalled} particles could not be attached "
                           "by statics and their block is above block_max (microhom.dual_bound)")
        run.dual = None
        run.t_bound += time.perf_counter() - tb
        return
    run.src = "dual" if run.src == "none" else run.src + "+dual"
    if run.lam is None and run.lam_n is None:
        run.reasons[:] = [r for r in run.reasons if not r.startswith("no certified spectral bound")]
    run.t_bound += time.perf_counter() - tb


def _dense_fits(run, ndof):
    """Memory check of the dense bound (24 ndof^2 bytes on top of the planned peak); says why not."""
    need = plan_memory(0, 0, max_order=0, preconditioner="block", soft_modes=0, dense=False).total \
        + 24 * ndof * ndof
    if run.limit is None or run.planned + need <= run.limit:
        return True
    run.reasons.append(f"dense spectral bound skipped: it needs {_gb(need)} on top of {_gb(run.planned)} "
                       f"(available {_gb(run.limit)}): the lower bounds are not available")
    return False


def _min_ratio(net):
    """Smallest ``min(kt/kn, kn/kt)`` over the sticking contacts (1 without any) [-]."""
    kn = np.asarray(net.kn, float) * np.ones(net.n_contacts)
    kt = net.effective_kt
    stick = kt > 0
    if not stick.any():
        return 1.0
    q = kt[stick] / kn[stick]
    return float(np.minimum(q, 1 / q).min())


def _companion_bound(run, dense_max):
    """A second certified lower bound for stiffness ratios far from 1 (docs/theory.md, section 9,
    "Stiffness ratios far from 1").

    ``H'`` is the Hessian of the same network with every contact at ``k' = min(kn, kt_eff)`` in
    both directions (``kn`` kept where ``kt_eff = 0``): ``H - H' = sum_c B_c^T (K_c - K'_c) B_c``
    is positive semi-definite and ``H'`` has the null space of ``H`` (the same contacts carry
    normal and tangential stiffness), so ``x^T H x >= lam' x^T N x`` on range(H), with ``N`` the
    particle blocks of ``H'`` and ``lam'`` the smallest non-zero eigenvalue of ``(H', N)``: a
    pencil whose spectrum is that of a kt = kn network, without the cluster near
    ``min(kt/kn, kn/kt)`` that makes ``lam`` of ``(H, M)`` vanish. Then
    ``Res^T H^+ Res <= Res^T N^-1 Res / lam'``."""
    net = run.asm.net
    if not net.n_contacts:
        return
    kn = np.asarray(net.kn, float) * np.ones(net.n_contacts)
    kt = net.effective_kt
    stick = kt > 0
    if not run.far_ratio:
        return                                            # ratios near 1: (H, M) is well conditioned
    from microhom.spectral import CERTIFIED_MAX_DOF
    if run.asm.ndof > CERTIFIED_MAX_DOF:
        return            # spectral_lower_bound certifies no larger system: no twin
    kmin = np.where(stick, np.minimum(kn, kt), kn)
    twin = net.with_stiffness(kn=kmin, kt=np.where(stick, kmin, 0.0))
    asm2 = assemble(twin, prestress=run.prestress, min_contacts=run.min_contacts, pin=False,
                    spin_arm=run.spin_arm)
    if asm2.ndof != run.asm.ndof or not np.array_equal(asm2.dof_map, run.asm.dof_map):
        return                                            # not the same unknowns: no companion
    lam_n, _, n_neg = spectral_lower_bound(asm2, dense_max=dense_max)
    if lam_n is not None and not n_neg:
        run.lam_n = lam_n
        run.Ninv = block_preconditioner(asm2)[1]


def _soft_mode_step(run, soft_modes):
    """LOBPCG soft modes (deflated later) and the instability proof; returns the number searched."""
    asm = run.asm
    if soft_modes == "auto" and run.lam is not None and run.src != "user":
        # the certificate of (H, M) already counted the negative eigenvalues (a proof of stability,
        # which LOBPCG is not) and only its rigorous interval stops CG: the search (half the time to
        # a certified interval at N = 3000, docs/results/hierarchy.md section 7) would buy nothing
        return 0
    if soft_modes == "auto":
        soft_modes = 3 if asm.ndof <= SOFT_MODES_AUTO_MAX else 0
        if not soft_modes and asm.ndof:
            run.reasons.append(f"soft modes not searched (ndof = {asm.ndof} > {SOFT_MODES_AUTO_MAX}; pass "
                               "soft_modes=3): a near-mechanism plateau of CG could hide from the stated error")
    if not (soft_modes and asm.ndof and not run.unstable):
        return int(soft_modes)
    ts = time.perf_counter()
    if run.P_amg is None:
        run.P_amg, info = amg_preconditioner(asm)
    rq, lam_est, V = lowest_modes(asm, run.M, run.P_amg, Minv=run.Minv, k=int(soft_modes), return_vectors=True)
    run.V_soft = V[:, rq > _NULL_CURV]                  # floppy (zero) modes carry no load
    if lam_est < -_NEG_CURV:
        run.unstable = True
        run.reasons.append(f"unstable: negative eigenvalue {lam_est:.3g} of the pencil (H, M) found (a "
                           "negative Rayleigh quotient: the pre-stressed network is not stable); the bounds are void")
    run.t_bound += time.perf_counter() - ts
    return int(soft_modes)


def _calibration(run, preconditioner, soft):
    """Is the extrapolation's stated error calibrated for this network (docs/results/hierarchy.md)?"""
    lo, hi = CALIBRATED_KT_OVER_KN
    r = run.kt_over_kn
    # measured on disk packings only: on spheres (3D) only the rigorous interval counts
    run.calibrated = bool(soft > 0 and np.isfinite(r) and lo <= r <= hi and run.network.dim == 2)


def _cg_step(run, max_order, full, preconditioner):
    """Block PCG, one order per step, until the stopping rule is met or the cap.

    With a certified lower bound (``run.lam`` or the companion ``run.lam_n``) only the rigorous
    interval stops the iteration (issue 22): the multilevel CG runs up to ``max_order`` steps; if
    the interval is still wider than ``tol``, up to ``factor_steps`` more steps preconditioned by
    the certificate's factorisation of ``H - s M`` (when the sparse certificate made one), else the
    multilevel CG continues up to ``certify_max_order``. Without one, the calibrated extrapolation
    may stop it as before (``_met``)."""
    asm = run.asm
    B = -asm.F if asm.ndof else np.zeros((0, _n_mandel(asm.net.dim)))
    run.Cs, run.lowers, run.margins = [run.C0], [None], [0.0]
    run.trivial = _trivial(asm)
    if run.trivial:
        # nothing to relax (affine network, e.g. a perfect triangular lattice): exact at order 0
        run.lowers[0] = run.C0.copy()
        run.best_low = np.array(_iso(run.C0))
        run.converged = True
        if run.factor is not None:
            run.factor.release()
            run.factor = None
        return
    P = run.Minv
    if preconditioner == "amg":
        P = run.P_amg
        if P is None:
            P, info = amg_preconditioner(asm)
            run.t_prec = info.setup_time
    # far from kt = kn: two conjugation passes and the true residual every step (round-off of the
    # kt/kn-scaled products otherwise drifts the residual and stalls the lower bound; docs/theory.md section 9)
    far = run.lam_n is not None or run.far_ratio
    H = run.H_shared if run.H_shared is not None and preconditioner == "amg" else asm.H
    # the 3D lean path (H read from the multilevel copy) iterates on the true residual too: one
    # (ndof, 6) block fewer (the recursive one; issue 26: 0.27 GiB at 1e6 spheres)
    cg = _BlockPCG(H, run.M, P, B, full=full, deflate=run.V_soft, passes=2 if far else 1,
                   true_residual=far or _lean_cg(run))
    if _lean_cg(run):     # nothing reads F past here on the lean path: B = -F is the CG's (issue 26: 0.27 GiB at 1e6)
        run.asm = asm = replace(asm, F=None)
    if run.dual is not None and preconditioner == "amg":
        run.dual_coarse = _dual_correction(H, P)
    rigorous = run.lam is not None or run.lam_n is not None or run.dual is not None
    cap = int(max_order) + (run.factor_steps if run.factor is not None else 0)
    if rigorous and run.factor is None:
        cap = max(int(max_order), int(run.certify_max_order))
    order = 0
    for order in range(1, cap + 1):
        if order > max_order:
            _continue_certifying(run, cg, full)
        cg.step()
        if cg.unstable:
            run.unstable = True
            order -= 1
            break
        C = _tensor(run.C_aff, cg.Rk, run.area, run.corr)
        run.Cs.append(C)
        run.margins.append(_roundoff(cg, keep=run.lam is not None or run.lam_n is not None) / run.area)
        run.lowers.append(_best_lower(run, C, cg))
        mI = run.margins[-1] * np.eye(C.shape[0])
        if _met(C + mI, run.best_low, run.tol, run.Cs, run.calibrated and not rigorous, run.prestress,
                floor=2 * np.array(_iso(mI))):
            run.converged = True
            break
        if cg.done:
            break
    if not run.converged and rigorous and not run.unstable:
        # the rigorous interval did not meet tol: the calibrated extrapolation still may (as before)
        run.converged = _met(run.Cs[-1], None, run.tol, run.Cs, run.calibrated, run.prestress)
    if run.factor is not None:
        run.factor.release()
        run.factor = None
    run.order, run.n_floppy, run.n_soft = order, cg.n_floppy, cg.n_deflated


def _continue_certifying(run, cg, full):
    """Past ``max_order`` with a certified bound: switch the preconditioner to the certificate's
    factorisation (``PH`` then has its spectrum at 1 up to the few eigenvalues near the shift),
    or keep the multilevel one; the true residual drives the iteration from here (each step then
    minimises the energy exactly along its block, so the upper bounds stay monotone whatever the
    conjugation), and the full basis is kept only while it fits in memory."""
    cg.true_residual = True
    cg.R = cg.Rt
    if run.factor is not None:
        if run.n_factor_steps == 0:
            fac, n = run.factor, cg.H.shape[0]
            cg.Minv = sla.LinearOperator((n, n), matvec=fac.solve, matmat=fac.solve, dtype=float)
            cg.Z = cg.Minv @ cg.R          # this step's block already from the factorisation
            cg.P = cg.Z
        run.n_factor_steps += 1
    elif full and run.limit is not None:
        cols = sum(c[2] for c in cg._chunks) + 3 * cg.B.shape[1]
        if 16 * cg.H.shape[0] * cols + run.planned > run.limit:
            cg.full = False


def _estimates(run, KG, KGl):
    """(K, G) Estimates: the rigorous interval, or the extrapolation where it is calibrated."""
    ests = []
    for m in range(2):
        seq = KG[:, m]
        mI = run.margins[-1] * np.eye(run.C0.shape[0])
        up = float(seq[-1]) + float(_iso(mI)[m])          # + the round-off margin of the energy
        lo = None if run.best_low is None else float(run.best_low[m])   # every order's bound holds
        if lo is not None and not run.prestress:
            lo = max(lo, 0.0)       # without pre-stress C = min of an energy >= 0: K, G >= 0
        if run.trivial:
            val, err = up, 0.0
        elif run.calibrated and seq.size > 1:
            val, err = _extrapolate(seq[1:])
        else:
            val, err = up, float("inf")
        rig = False
        if lo is not None:
            half = 0.5 * (up - lo)
            if not np.isfinite(err) or half <= err:        # the rigorous interval is the tighter claim
                val, err, rig = 0.5 * (up + lo), half, True
            else:                                          # extrapolation inside it, estimated error
                val = min(max(val, lo), up)
        ests.append(Estimate(value=float(val), upper=up, lower=lo, error=float(err), error_rigorous=rig))
    return ests


def _verdict(run, ests, C_upper):
    """Validity flags and their reasons: (certified, jammed, floppy, negative)."""
    tol, reasons = run.tol, run.reasons
    scale = float(np.abs(run.C_aff_all).max())
    w = np.linalg.eigvalsh(0.5 * (C_upper + C_upper.T))
    jammed = not run.empty
    floppy = negative = False
    if jammed and scale > 0 and w.max() <= _DEGENERATE * scale and not run.unstable:
        jammed = False
        reasons.append(f"not jammed: the upper bound of the tensor vanishes (largest eigenvalue "
                       f"{w.max():.3g}, affine scale {scale:.3g}): no rigid backbone")
    elif jammed and scale > 0 and abs(w.min()) <= _DEGENERATE * scale and not run.unstable:
        floppy = True
        reasons.append(f"floppy: the tensor has a zero eigenvalue ({w.min():.3g}, affine scale "
                       f"{scale:.3g}): a deformation mode costs no energy")
    if jammed and scale > 0 and w.min() < -_DEGENERATE * scale:
        run.unstable = True
        reasons.append(f"unstable: the upper bound of the tensor has a negative eigenvalue ({w.min():.4g}), "
                       "so the exact tensor has one too: the state is not stable under this pre-stress")
    if run.unstable and not any(r.startswith("unstable") for r in reasons):
        reasons.append("unstable: negative curvature met by CG (H indefinite); the bounds are void")
    for name, e in zip("KG", ests):
        if e.value < -_DEGENERATE * max(scale, 1e-300):
            negative = True
            reasons.append(f"negative modulus: {name} = {e.value:.4g} (interval [{_fmt(e.lower)}, {e.upper:.4g}])")
    floor = 2 * np.array(_iso(run.margins[-1] * np.eye(C_upper.shape[0])))   # round-off alone (_met)
    certified = all(e.lower is not None and e.upper - e.lower <= tol * abs(e.upper) + f
                    for e, f in zip(ests, floor)) or run.trivial
    if run.n_floppy:
        reasons.append(f"{run.n_floppy} floppy search direction(s) dropped (zero-stiffness modes)")
    if not jammed or run.unstable:
        return certified, jammed, floppy, negative
    if not certified:
        wide = [f"{n} {e.rel_width:.3g}" for n, e, f in zip("KG", ests, floor) if e.lower is not None
                and e.upper - e.lower > tol * abs(e.upper) + f]
        if wide:
            reasons.append(f"interval wider than tol {tol:g}: relative width {', '.join(wide)}")
        if run.calibrated and run.converged:
            reasons.append(f"extrapolated: the estimate rests on the extrapolation, calibrated at kt/kn = "
                           f"{run.kt_over_kn:.3g} in {list(CALIBRATED_KT_OVER_KN)} (docs/results/hierarchy.md)")
        elif not run.calibrated:
            why = ("3D: it was calibrated on disk packings only" if run.network.dim != 2 else
                   f"kt/kn = {run.kt_over_kn:.3g} outside {list(CALIBRATED_KT_OVER_KN)}"
                   if not (np.isfinite(run.kt_over_kn) and CALIBRATED_KT_OVER_KN[0] <= run.kt_over_kn
                           <= CALIBRATED_KT_OVER_KN[1]) else "no soft-mode search")
            reasons.append(f"extrapolation not calibrated here ({why}): only the rigorous interval counts")
    if not run.converged:
        width = "rigorous interval" if run.lowers[-1] is not None else "no rigorous lower bound"
        reasons.append(f"tolerance {tol:g} not met after {run.order} step(s) ({2 * run.order} moments; "
                       f"{width}): returned the best interval")
    if not certified and run.best_low is not None and not run.trivial:
        lam = run.lam if run.lam is not None else run.lam_n
        term = (f"Res^T M^-1 Res / lam with the certified lam = {lam:.3g}" if lam is not None else
                "the dual bound's gap Corr^T K^+ Corr (the CG residual carried by statics)")
        cap = (f"{run.max_order} multilevel + {run.n_factor_steps} factorised step(s)" if run.n_factor_steps
               else f"the cap of {max(run.max_order, run.certify_max_order)} step(s)")
        reasons.append(f"rigorous interval wider than tol after {cap}: the residual term "
                       f"{term} still dominates; raise "
                       "max_order, certify_max_order or factor_steps")
    return certified, jammed, floppy, negative


def _fmt(x):
    return "n/a" if x is None else f"{x:.4g}"


def _finish(run, preconditioner, t_asm, t_solve):
    """Orders, estimates, verdict: the result."""
    Cs = run.Cs
    C_orders = np.array(Cs)
    KG = np.array([_iso(C) for C in Cs])
    KGl = np.array([_iso(L) if L is not None else (np.nan, np.nan) for L in run.lowers])
    ests = _estimates(run, KG, KGl)
    C_up = Cs[-1] + run.margins[-1] * np.eye(Cs[-1].shape[0])
    certified, jammed, floppy, negative = _verdict(run, ests, C_up)
    C_fo = run.C_fo
    Ka_all, Ga_all = _iso(run.C_aff_all)
    asm, network = run.asm, run.network
    return HierarchyResult(
        K=ests[0], G=ests[1], K_orders=KG[:, 0], G_orders=KG[:, 1], K_lower_orders=KGl[:, 0],
        G_lower_orders=KGl[:, 1], C_orders=C_orders, C_upper=C_up, C_lower=run.lowers[-1],
        K_first_order=_iso(C_fo)[0], G_first_order=_iso(C_fo)[1], C_first_order=C_fo,
        K_affine_all=Ka_all, G_affine_all=Ga_all, order=int(run.order), n_moments=2 * int(run.order),
        tol=run.tol, converged=bool(run.converged), spectral_bound=run.lam, spectral_bound_source=run.src,
        reasons=tuple(run.reasons), unstable=bool(run.unstable), empty=bool(run.empty),
        n_floppy_directions=int(run.n_floppy), n_dof=int(asm.ndof), n_rattlers=int(asm.rattlers.sum()),
        n_particles=network.n_particles, n_contacts=asm.net.n_contacts, prestress=bool(run.prestress),
        assembly_time=t_asm, solve_time=t_solve, bound_time=run.t_bound,
        preconditioner=preconditioner if not run.trivial else "none", preconditioner_time=run.t_prec,
        n_soft_modes=int(run.n_soft), n_factor_steps=int(run.n_factor_steps),
        certificate_factorisations=int(run.n_cert_fact), certified=bool(certified), calibrated=bool(run.calibrated),
        kt_over_kn=float(run.kt_over_kn), jammed=bool(jammed), floppy=bool(floppy), negative=bool(negative),
        margin_orders=np.array(run.margins, dtype=float))


def _lower(C, cg, Minv, lam, lam_hi, area):
    """Rigorous lower bound of C from the residual ``Res`` of the iterate (docs/theory.md, sec. 9).

    With ``m0 = Res^T M^-1 Res``, ``m1 = Z^T H Z`` (``Z = M^-1 Res``, ``M`` the particle-block
    diagonal whatever preconditioner produced the iterate) and the spectrum of the
    pencil (H, M) on range(H) inside ``[a, b]``: ``Res^T H^+ Res <= ((a + b) m0 - m1)/(a b)``
    (the chord of the convex 1/lambda over the residual's spectral measure); ``b = inf`` gives
    the plain residual bound ``m0 / a``.
    """
    if C is None or cg is None:
        return None
    Z = Minv @ cg.Rt                 # the computed residual fl(B - H X) of the iterate
    m0 = cg.Rt.T @ Z
    m0 = 0.5 * (m0 + m0.T)
    if lam_hi is None or not np.isfinite(lam_hi):
        T = m0 / lam
    else:
        m1 = Z.T @ (cg.H @ Z)
        m1 = 0.5 * (m1 + m1.T)
        T = ((lam + lam_hi) * m0 - m1) / (lam * lam_hi)
    E = getattr(cg, "E", None)
    if E is not None:
        # the exact residual is r_hat + e with |e| <= E entrywise: (r_hat + e)^T H^+ (r_hat + e) <=
        # (1 + t) r_hat^T H^+ r_hat + (1 + 1/t) e^T H^+ e, and e^T H^+ e <= E^T |M^-1| E / lam
        e2 = float(np.einsum("ij,ij->", E, abs(Minv) @ E)) / lam
        tr = max(float(np.trace(T)), 1e-300)
        t = np.sqrt(e2 / tr) if e2 > 0 else 0.0
        T = (1 + t) * T + ((1 + 1 / t) * e2 if t > 0 else 0.0) * np.eye(T.shape[0])
    return C - T / area


def _abs_times(H, X, chunk=1 << 22):
    """``|H| X`` for a CSR ``H`` (n, n) and X (n, s), in slices of about ``chunk`` non-zeros of
    ``H``'s rows: the same numbers as ``abs(H) @ X`` (each row is summed in the same order) without
    a copy of ``H`` (issue 26: ``abs(H)`` was held through the CG, 12 bytes per non-zero)."""
    n = H.shape[0]
    ptr = H.indptr
    out = np.empty((n,) + X.shape[1:], dtype=np.result_type(H.dtype, X.dtype))
    a = 0
    while a < n:
        b = int(np.searchsorted(ptr, ptr[a] + chunk, side="right")) - 1
        b = min(max(b, a + 1), n)
        lo, hi = ptr[a], ptr[b]
        S = sp.csr_matrix((np.abs(H.data[lo:hi]), H.indices[lo:hi], ptr[a:b + 1] - lo), shape=(b - a, H.shape[1]))
        out[a:b] = S @ X
        a = b
    return out


def _roundoff(cg, keep=True):
    """A-priori floating-point margin ``s`` of the energy ``2 B^T X - X^T H X`` evaluated as
    ``B^T X + X^T fl(B - H X)`` [unit of R]: the computed 3 x 3 tensor is within ``s I`` of the exact
    energy of the computed ``X`` in the Loewner order (Gershgorin on the entrywise bounds). Each
    entry errs by at most ``g_n (|B|^T |X| + |X|^T |r|) + g_m |X|^T (|B| + |H| |X|)`` with
    ``g_m = (m + 1) u`` for the residual (``m`` non-zeros per row of ``H``) and ``g_n = sqrt(n) u``
    for the dot products over the ``n`` unknowns (the usual estimate, as for the certificate's
    margin, docs/stiffness.md). Also stores ``cg.E`` (ndof, s), the entrywise bound of the
    residual's error ``g_m (|B| + |H| |X|)``, for the lower bound (``keep``; else None: issue 26,
    only the spectral lower bounds read it).

    With ``H`` read from the multilevel copy ``A = P H P^T + s I`` (``cg.H`` a
    :class:`microhom.shared_h.ShiftedCopy`: each product ``fl(fl(A x) - fl(s x))``) the product's
    error is at most ``(m + 3) u (|A| + 2 s I) |x|`` (``m`` the stored entries of a row of ``A``;
    ``microhom.shared_h``), so ``m + 3`` replaces ``m`` and ``(|A| + 2 s I) |X|`` replaces
    ``|H| |X|``: ``E`` again bounds the computed residual's distance to ``B - H X`` of the exact
    ``H``, and the margin keeps the upper bounds rigorous (they hold for any iterate ``X``; only
    the evaluation of its energy must be bounded, and it is)."""
    u = np.finfo(float).eps
    shared = isinstance(cg.H, ShiftedCopy)
    if not cg.m_row:
        cg.m_row = cg.H.m_row + 3 if shared else int(np.diff(cg.H.indptr).max(initial=0))
    n = cg.H.shape[0]
    aX, aB = np.abs(cg.X), np.abs(cg.B)
    E = (cg.m_row + 1) * u * (aB + (cg.H.abs_bound(aX) if shared else _abs_times(cg.H, aX)))
    D = np.sqrt(n) * u * (aB.T @ aX + aX.T @ np.abs(cg.Rt)) + aX.T @ E
    cg.E = E if keep else None
    D = np.maximum(D, D.T)
    return float(D.sum(axis=1).max(initial=0.0))


def _best_lower(run, C, cg):
    """The rigorous lower tensor of this order: from ``(H, M)`` and, where it exists, the
    companion bound ``(H, N)`` (``_companion_bound``); the one with the larger K + G. None
    without any spectral bound."""
    cands = []
    if run.lam is not None:
        cands.append(_lower(C, cg, run.Minv, run.lam, run.lam_hi, run.area))
    if run.lam_n is not None:
        cands.append(_lower(C, cg, run.Ninv, run.lam_n, None, run.area))
    cands = [L - run.margins[-1] * np.eye(L.shape[0]) for L in cands]   # round-off of the energy
    if run.dual is not None and _dual_due(run, C, cg):   # its own round-off margin is subtracted already
        tb = time.perf_counter()
        W = _dual_trial(run, cg)
        b = dual_lower_bound(run.asm, cg.X, run.area, run.dual, coarse=run.dual_coarse, trial=W)
        release_free_memory()
        run.n_dual += 1
        if b.valid:     # the statics' own gap schedules (_dual_due), or the interval's width (DUAL_SCHEDULE)
            gap = (np.array(_iso(C)) - np.array(_iso(b.C_lower)) if DUAL_SCHEDULE == "width"
                   else np.array(_iso(b.gap)))
            run.dual_last = (b.C_lower, np.abs(gap), float(np.linalg.norm(cg.Rt)))
        run.t_bound += time.perf_counter() - tb
    if run.dual is not None and run.dual_last is not None:   # any order's field bounds the exact C
        cands.append(run.dual_last[0])
    if run.dual is not None and DUAL_TRIAL and not _lean_cg(run):
        run.dual_prev_X = cg.X.copy()
    if not cands:
        return None
    L = max(cands, key=lambda L: sum(_iso(L)))
    kg = np.array(_iso(L))
    run.best_low = kg if run.best_low is None else np.maximum(run.best_low, kg)
    return L


#: Richardson steps of the multilevel V-cycle applied to the CG residual before the dual bound's
#: statics (_dual_correction; docs/theory.md section 12, "A correction before the statics"): 0,
#: off (measured: a smaller gap per evaluation but each V-cycle costs about a CG order, and the
#: best field in the span of the next CG direction, DUAL_TRIAL, gains more for less)
DUAL_VCYCLES = 0
#: the dual bound's field is the best one in the span of the next preconditioned residual ``Z`` and
#: the last step ``X_k - X_{k-1}`` (``dual_lower_bound``'s ``trial``; docs/theory.md section 12,
#: "The best field in a small subspace"); on the 3D lean path the last search block, whose span
#: holds the last step (:func:`_dual_trial`)
DUAL_TRIAL = True
#: particles per cluster of the dual bound's two-level statics in 3D (``build_equilibrator``'s
#: ``clusters``; docs/theory.md section 12, "Two-level statics"), or None: the one-seed statics.
#: Measured (docs/results/spheres.md, "A statics of bounded depth"): 3 orders instead of 6 at
#: 3.2e4 spheres (43 s CPU against 49), 8 instead of 18 at 1.08e5 (201 s against 310). 2D keeps
#: the one-seed statics; networks under 400 spheres get it too (fewer than 8 clusters)
DUAL_CLUSTERS = 400


def _lean_cg(run):
    """The 3D lean path: the CG reads ``H`` from the multilevel copy (:func:`_early_multilevel`);
    it keeps the fewest (ndof, 6) blocks (true residual, :func:`_dual_trial`; issue 26)."""
    return run.H_shared is not None


def _dual_trial(run, cg):
    """The dual bound's trial span (``DUAL_TRIAL``; None without): the next preconditioned
    residual ``Z`` and the last step, as blocks (not stacked: one copy fewer). The last step is
    ``X_k - X_{k-1}`` (a copy of ``X_{k-1}`` kept per order) or, on the lean path
    (:func:`_lean_cg`), the last search block ``P_k`` whose span contains it (``X_k - X_{k-1} =
    P_k alpha_k``): the best field over a span that contains the other is at least as good, and
    no copy of ``X`` is kept (issue 26: two (ndof, 6) blocks, 0.54 GiB at 1e6 spheres)."""
    if not DUAL_TRIAL:
        return None
    if _lean_cg(run):
        last = cg.last_block()
        return [cg.Z] if last is None else [cg.Z, last]
    prev = run.dual_prev_X if run.dual_prev_X is not None else 0.0
    return [cg.Z, cg.X - prev]


def _dual_correction(H, P, steps=None):
    """``r -> y``: ``steps`` (default ``DUAL_VCYCLES``) Richardson steps ``y += P (r - H y)`` of
    the V-cycle ``P`` from ``y = 0`` on ``H y = r`` (``microhom.dual_bound.dual_lower_bound``'s
    ``coarse``). None for 0 steps."""
    steps = DUAL_VCYCLES if steps is None else int(steps)
    if steps <= 0:
        return None

    def apply(r):
        y = np.asarray(P @ r)
        for _ in range(steps - 1):
            y = y + np.asarray(P @ (r - H @ y))
        return y

    return apply


#: the dual bound is evaluated at an order only when its gap, predicted from the last evaluated
#: one, is below this many times the width the tolerance allows (_dual_due)
_DUAL_DUE = 10.0
#: what _dual_due predicts from: "statics", the statics' own gap (the bound without the trial
#: span; the same orders evaluated as before it), or "width", the interval's width with it
#: (predicted against 10 times more: _DUAL_DUE_WIDTH); measured in docs/results/spheres.md
DUAL_SCHEDULE = "statics"
_DUAL_DUE_WIDTH = 100.0


def _dual_due(run, C, cg):
    """Whether this order evaluates the dual bound (its cost is about one CG step's): always the
    first time, at the last order the loop can reach and when CG is done; otherwise only when the
    gap ``Corr^T K^+ Corr`` of the last evaluated bound, scaled by the squared ratio of the CG
    residual norms (the gap is quadratic in the residual), is within ``_DUAL_DUE`` times
    ``tol`` times the upper bound for both K and G. A skipped order keeps the last evaluated
    lower bound (a bound of the exact tensor from any order's field)."""
    if run.dual_last is None or cg.done:
        return True
    order = len(run.Cs) - 1
    cap = max(run.max_order, run.certify_max_order) if run.factor is None else run.max_order + run.factor_steps
    if order >= cap:
        return True
    _, gap, rho = run.dual_last
    r = float(np.linalg.norm(cg.Rt))
    pred = gap * (r / rho) ** 2 if rho > 0 else np.zeros(2)
    due = _DUAL_DUE_WIDTH if DUAL_SCHEDULE == "width" else _DUAL_DUE
    return bool(np.all(pred <= due * run.tol * np.abs(np.array(_iso(C)))))


def _met(C, L, tol, Cs, calibrated=True, prestress=True, floor=(0.0, 0.0)):
    """Stop test: the rigorous interval (``L`` = the best lower bounds (K, G) of all orders so far,
    or None; raised to 0 without pre-stress) has relative width <= tol for both K and G (plus
    ``floor``, the width the round-off margins alone make: a modulus that is exactly 0 has no
    relative width), or, only where the extrapolation is calibrated, its stated interval
    ``value +- error`` has."""
    K, G = _iso(C)
    if L is not None:
        Kl, Gl = L
        if not prestress:
            Kl, Gl = max(Kl, 0.0), max(Gl, 0.0)
        if (K - Kl) <= tol * abs(K) + floor[0] and (G - Gl) <= tol * abs(G) + floor[1]:
            return True
    if not calibrated:
        return False
    KG = np.array([_iso(c) for c in Cs[1:]])
    ok = True
    for m in range(2):
        v, err = _extrapolate(KG[:, m])
        ok &= bool(np.isfinite(err) and 2 * err <= tol * abs(v))
    return bool(ok)
