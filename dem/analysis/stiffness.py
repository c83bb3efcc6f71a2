"""Exact linear (incremental) stiffness tensor of a periodic contact network.

Given a periodic :class:`~microhom.network.ContactNetwork`, :func:`stiffness` assembles the sparse
Hessian of the contact energy over the particle translations ``u`` and spins ``omega``, solves the
non-affine relaxation for the three homogeneous strain modes with a single sparse factorisation and
returns the relaxed 2D stiffness tensor beside the affine one (see ``docs/stiffness.md``).

Formulation (2D, tension positive). Contact ``k`` joins ``i`` and ``j``, branch ``c = x_j - x_i``
(periodic image resolved), ``n = c/|c|``, ``t = (-n_y, n_x)``, arms ``a_i = |c| r_i/(r_i+r_j)``,
``a_j = |c| r_j/(r_i+r_j)``. Under a homogeneous strain ``E`` of the cell plus periodic fluctuations
``u``, ``omega`` the relative displacement of the contact point of ``j`` with respect to that of ``i``
is::

    Delta = u_j - u_i + E c - (a_i omega_i + a_j omega_j) t          (omega x r = omega (-r_y, r_x))

the (tension-positive) contact force increment is ``f = K Delta`` with
``K = kn n n + kt_eff (I - n n)`` and the stress increment is ``(1/A) sum sym(f (x) c)``. The energy
``W = 1/2 sum Delta.K.Delta`` is minimised over ``(u, omega)``; with ``Delta = B q + D eps`` (``eps``
the strain in Mandel form ``[E11, E22, sqrt2 E12]``)::

    H q = -F eps,   H = B^T K B,   F = B^T K D,   C = (1/A) Delta^T K Delta  (at the minimiser)
                                                     = C_aff - (1/A) F^T H^+ F,
    C_aff = (1/A) D^T K D.

``C`` is evaluated in the energy form ``Delta^T K Delta`` (symmetric, positive semi-definite, no
cancellation when a modulus vanishes); the stress form ``D^T K Delta`` is kept as a consistency check.

With ``prestress=True`` the normal forces ``fn`` (compression positive) add the geometric stiffness
of the rotating normal force, acting on the centre-to-centre relative displacement
``Delta_c = u_j - u_i + E c`` (spins do not move a force through the centre)::

    K_g = -(fn/|c|) (I - n n),

and the result is the Cauchy stress increment of the pre-stressed packing,
``d sigma = sym(dP) + sym(sigma0 dE) - sigma0 tr(dE)``, whose isotropic part is
``K = B + p/2``, ``G = G_U - p/2`` in terms of the moduli ``B``, ``G_U`` of the energy density
(the jax-md ``athermal_moduli`` convention). Exact for frictionless disks; for frictional disks the
geometric terms of ``ft`` (rotation of the tangential force, rolling) are not included. On spheres
with tangential forces they are, under LAMMPS's history update (``microhom.kinematics``,
``docs/spheres.md``): the tangent is then not symmetric and is solved by SuperLU
(:func:`relax_tangential`), the tensor in the stress form.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from microhom.kinematics import (affine_tensor, assemble, rotational_dofs, skew_stress_correction, sparse_rows,
                                 stress0)
from microhom.network import ContactNetwork
from microhom.results import Result
from microhom.tensors import (isotropic_moduli, mandel_to_tensor, mandel_to_voigt, prestress_correction,
                              strain_to_mandel)

from microhom import factor as _factor
from microhom.factor import (AUTO_PARDISO_DOF, COUNTS, MemoryGuardError, NotPositiveDefinite, have_pardiso,
                             memory_check, predicted_factor_bytes)

_cholmod = _factor._cholmod     # optional CHOLMOD (scikit-sparse); tests set this to None

__all__ = ["StiffnessResult", "RIGIDITY_CHECK_MAX_DOF", "rigidity_factor", "stiffness", "affine_stiffness", "stress_increment", "reduce_system",
           "factorise", "count_modes", "relax", "relax_tangential", "relaxed_tensor", "degeneracy_flags", "have_cholmod",
           "have_pardiso", "particle_ordering", "predicted_memory", "Reduced", "ModeCount",
           "Turns", "two_contact_turns", "deflate_turns", "restore_turns",
           "MemoryGuardError"]
# the tensor-notation helpers (mandel_to_tensor, isotropic_moduli, ...) live in microhom.tensors and
# the assembly in microhom.kinematics; they are imported here for the solver, not re-exported.



# ---- result ----------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class StiffnessResult(Result):
    """Relaxed and affine 2D stiffness of a contact network (Mandel form over [xx, yy, sqrt2 xy]).

    Tensors [N/m, 2D per unit thickness]: ``C_mandel``, ``C_affine_mandel`` (3, 3); moduli ``K``,
    ``G``, ``K_affine``, ``G_affine`` their isotropic projection (``microhom.tensors``).
    Counts: ``n_rattlers`` particles removed (iteratively, fewer than ``min_contacts`` contacts);
    ``n_floppy`` zero-energy modes of the reduced Hessian (after removing rattlers, dropped spins
    and the two global translations); ``n_unstable`` negative modes of the Hessian (pre-stress
    only); ``n_turns`` of the floppy modes, the turns of two-contact spheres removed before the
    factorisation (3D without pre-stress, ``stiffness(deflate=True)``); ``n_dof`` the number of
    unknowns solved for. ``solve_time`` is factorisation + mode
    count + solves [s]; ``assembly_time`` the assembly [s]. ``solver`` the back end that ran
    (``"pardiso"``, ``"cholmod"`` or ``"splu"``; ``"splu"`` for the non-symmetric solve of
    spheres with tangential forces under pre-stress, whose modes are counted on the symmetric
    part). ``flags``: the reasons the result is degenerate, one
    sentence each (not jammed, floppy, unstable, ill-conditioned); empty for a rigid, stable
    network. ``stiffness_scale``: the power of two the contact stiffnesses were divided by
    before the solve (exact; the tensor is scaled back).
    Sizes: ``n_particles`` of the network, ``n_contacts`` kept (between non-rattlers),
    ``n_spins`` spin unknowns kept. ``prestress``: whether the geometric stiffness of the normal
    forces and the pre-stress terms of the Cauchy increment are included; ``stress0_mandel``: the
    pre-stress (3,) Mandel [N/m, tension positive] or None. Accuracy: ``residual`` =
    ``max_j |H q_j + F_j|`` over the norm of the per-contact affine forces, after ``n_refine``
    steps of iterative refinement [-] (above ``INACCURATE`` = 1e-8: flagged, and ``C_mandel``, ``K``,
    ``G`` NaN); ``relax_path`` the factor(s) and shift(s) the refinement ran on (a diverging
    refinement re-solved at the opposite shift, :func:`relax`); ``consistency`` = ``|stress form - energy form| / |C|``
    [-]; ``pivot_gap`` = (largest floppy, smallest kept) relative pivot [-];
    ``count_method`` how the floppy modes were counted (see :func:`count_modes`); ``step_times``
    the wall time of each named step [s]. Not exported: ``u`` (3, N, 2) relaxed fluctuations [m]
    and ``omega`` (3, N) spins [rad] per Mandel unit strain, ``rattler_mask`` (N,) bool.

    3D networks (spheres, ``docs/spheres.md``) give the same fields in 3D shapes: (6, 6) Mandel
    tensors over [xx, yy, zz, sqrt2 yz, sqrt2 xz, sqrt2 xy] [Pa], ``u`` (6, N, 3), ``omega``
    (6, N, 3) rotations, ``stress0_mandel`` (6,), three global translations.
    """

    C_mandel: np.ndarray
    C_affine_mandel: np.ndarray
    K: float
    G: float
    K_affine: float
    G_affine: float
    n_rattlers: int
    n_floppy: int
    n_dof: int
    solve_time: float
    assembly_time: float = 0.0
    n_particles: int = 0
    n_contacts: int = 0            # contacts kept (between non-rattlers)
    n_spins: int = 0               # spin unknowns kept
    n_unstable: int = 0            # negative-stiffness modes of the Hessian (only possible with prestress)
    n_turns: int = 0               # floppy turns of two-contact spheres deflated before the factorisation
    prestress: bool = False
    solver: str = "splu"
    residual: float = 0.0          # max_j |H q_j + F_j| / (norm of the per-contact affine forces) after refinement
    consistency: float = 0.0       # |stress form - energy form| / |C|
    n_refine: int = 0
    relax_path: str = ""           # the factor(s) and shift(s) the refinement ran on (see relax)
    pivot_gap: tuple = (np.nan, np.nan)   # (largest floppy, smallest kept) relative pivot
    stress0_mandel: np.ndarray | None = None
    flags: tuple = ()
    stiffness_scale: float = 1.0
    count_method: str = "pivots"   # how the floppy modes were counted (see count_modes)
    step_times: dict = field(default_factory=dict)   # wall time of each named step [s]
    u: np.ndarray | None = field(default=None, repr=False, metadata={"export": False})      # (3, N, 2)
    omega: np.ndarray | None = field(default=None, repr=False, metadata={"export": False})  # (3, N)
    rattler_mask: np.ndarray | None = field(default=None, repr=False, metadata={"export": False})

    @property
    def C(self) -> np.ndarray:
        """(2, 2, 2, 2) relaxed stiffness tensor."""
        return mandel_to_tensor(self.C_mandel)

    @property
    def C_affine(self) -> np.ndarray:
        return mandel_to_tensor(self.C_affine_mandel)

    @property
    def C_voigt(self) -> np.ndarray:
        return mandel_to_voigt(self.C_mandel)

    @property
    def ok(self) -> bool:
        """True when nothing is flagged (rigid, stable, well conditioned)."""
        return not self.flags

    def summary(self) -> str:
        f = np.array2string
        lines = [
            f"stiffness ({self.solver}{', prestress' if self.prestress else ''}): "
            f"N={self.n_particles}, contacts kept={self.n_contacts}, rattlers={self.n_rattlers}, "
            f"dof={self.n_dof} (spins {self.n_spins}), floppy={self.n_floppy}"
            + (f", UNSTABLE={self.n_unstable}" if self.n_unstable else ""),
            f"  K = {self.K:.10g}   G = {self.G:.10g}   (affine K = {self.K_affine:.10g}, "
            f"G = {self.G_affine:.10g}; ratio K {_ratio(self.K, self.K_affine)}, "
            f"G {_ratio(self.G, self.G_affine)})",
            "  C (Mandel [xx, yy, sqrt2 xy]):\n    "
            + f(self.C_mandel, precision=6, suppress_small=False).replace("\n", "\n    "),
            "  C affine:\n    "
            + f(self.C_affine_mandel, precision=6, suppress_small=False).replace("\n", "\n    "),
            f"  residual {self.residual:.2e} after {self.n_refine} refinement(s), consistency "
            f"{self.consistency:.2e}, pivot gap {self.pivot_gap[0]:.1e} | {self.pivot_gap[1]:.1e}",
            f"  assembly {self.assembly_time:.3f} s, solve {self.solve_time:.3f} s",
        ]
        if "diverged" in self.relax_path:
            lines.append(f"  refinement: {self.relax_path}")
        lines += [f"  FLAG: {s}" for s in self.flags]
        return "\n".join(lines)


def _ratio(a, b):
    return f"{a / b:.6f}" if b != 0 else "n/a"


# ---- affine tensor ---------------------------------------------------------------------------
def affine_stiffness(network, prestress=False, spin_arm="contact") -> np.ndarray:
    """(3, 3) Mandel affine (no relaxation) stiffness of all contacts of ``network`` [N/m]
    ((6, 6) [Pa] in 3D; with ``prestress`` on spheres, the tangential forces' terms included)."""
    _check(network, prestress)
    c = affine_tensor(network, prestress, tangential=True, spin_arm=spin_arm)
    if prestress:
        c = c + prestress_correction(stress0(network))
        if network.dim == 3 and network.ft is not None and np.any(network.ft != 0):
            c = c + skew_stress_correction(network)
    return 0.5 * (c + c.T) if not prestress else c


def _check(network, prestress):
    if network.cell is None:
        raise ValueError("stiffness needs a periodic network (cell is None)")
    if prestress and network.fn is None:
        raise ValueError("prestress=True needs the normal forces fn of the network")


#: contact stiffness ratio max/min above which the result is flagged (floppy count and tensor
#: lose digits: the pencil (H, diag H) then has eigenvalues down to ~ 1/ratio from rigid modes)
RATIO_WARN = 1e6
#: ratio above which the problem is refused: double precision cannot separate floppy from rigid
#: modes (measured: on a diluted network with 3 floppy modes, the count held up to a ratio of
#: 4e8 with both solvers and failed with SuperLU at 4e9: rigid pivots of 1e-11 meet the shift)
RATIO_REFUSE = 1e9


def _normalise(network, prestress):
    """Step 0: check the input and divide kn, kt, fn, ft by a power of two ``s`` near max(kn)
    (exact in floating point; the linear response scales with them). Returns (network, s, flags).

    Refuses (ValueError) a contact stiffness ratio max/min above ``RATIO_REFUSE``; flags one
    above ``RATIO_WARN``."""
    _check(network, prestress)
    flags = []
    if network.n_contacts == 0:
        return network, 1.0, flags
    kn = network.kn
    with np.errstate(over="ignore"):   # an inf scale is refused just below, with the reason
        s = float(2.0 ** np.round(np.log2(kn.max())))
    if not np.isfinite(s) or s == 0:
        raise ValueError(f"kn must be in (0, 2^1023.5 = 1.27e308] N/m so that its power-of-two "
                         f"scale exists; got max kn = {float(kn.max()):.6g} (rescale the "
                         "stiffnesses: the moduli are proportional to kn)")
    kt = network.effective_kt
    ks = np.concatenate([kn, kt[kt > 0]])
    ratio = float(ks.max() / ks.min())
    if ratio > RATIO_REFUSE:
        raise ValueError(f"contact stiffness ratio max/min = {ratio:.3g} (kn, kt) exceeds "
                         f"{RATIO_REFUSE:.0e}: double precision cannot tell floppy from rigid "
                         f"modes; allowed range of kt/kn and of kn spread: ratio <= {RATIO_REFUSE:.0e}")
    if ratio > RATIO_WARN:
        flags.append(f"ill-conditioned: contact stiffness ratio max/min = {ratio:.3g} > "
                     f"{RATIO_WARN:.0e}; floppy modes counted by the shift-rescaling test, the "
                     f"tensor may lose about log10(ratio) digits")
    if s != 1.0:
        network = replace(network, kn=network.kn / s, kt=network.kt / s,
                          fn=None if network.fn is None else network.fn / s,
                          ft=None if network.ft is None else network.ft / s)
    return network, s, flags


# ---- step 2: reduce the system ---------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Reduced:
    """The assembled system without its stiffness-free unknowns.

    H : (m, m) CSC Hessian of the unknowns that carry stiffness; F : (m, 3) their loads;
    d : (m,) positive diagonal scale of H (``|diag H|``, zeros replaced by its max);
    idx : (m,) their index among the assembly's unknowns; n_zero : unknowns dropped (each is a
    floppy mode: a dof with no stiffness at all); particle : (m,) particle of each unknown;
    n_turns : unknowns removed by :func:`deflate_turns` (each one floppy mode: the turn of a
    two-contact sphere), 0 unless deflated."""

    H: sp.csc_matrix
    F: np.ndarray
    d: np.ndarray
    idx: np.ndarray
    n_zero: int
    particle: np.ndarray
    n_turns: int = 0


def reduce_system(asm) -> Reduced:
    """Drop the unknowns whose Hessian row is zero (rattlers are already out of the assembly:
    :func:`microhom.kinematics.assemble` removes them iteratively)."""
    H = asm.H
    d = H.diagonal()
    rown = np.asarray(abs(H).sum(axis=1)).ravel()
    zero = rown <= 1e-300 + 1e-15 * (np.abs(d).max() if d.size else 0.0)
    idx = np.flatnonzero(~zero)
    Hr = H[idx][:, idx].tocsc() if zero.any() else H
    dr = np.abs(Hr.diagonal())
    dr = np.where(dr > 0, dr, dr.max() if dr.size else 1.0)
    N, dim = asm.net.n_particles, asm.net.dim
    rot = rotational_dofs(dim)
    full = np.flatnonzero(asm.dof_map >= 0)                 # full numbering of each unknown
    part = np.empty(asm.ndof, dtype=np.int64)
    part[asm.dof_map[full]] = np.where(full < dim * N, full // dim, (full - dim * N) // rot)
    return Reduced(H=Hr, F=asm.F[idx], d=dr, idx=idx, n_zero=int(zero.sum()), particle=part[idx])


# ---- step 2b: deflate the turns of two-contact spheres ---------------------------------------
#: a two-contact sphere's turn is deflated when the smallest singular value of its (6, 6)
#: compatibility block is below this fraction of the largest (exactly zero but for rounding) and
#: the next one above ``TURN_RANK`` of it (one free motion, no other)
TURN_TOL = 1e-12
TURN_RANK = 1e-8


@dataclass(frozen=True, eq=False)
class Turns:
    """The known floppy modes of the frictional spheres with exactly two contacts (3D, no
    pre-stress; ``docs/spheres.md``, "The exact solver on spheres"): the sphere turns about its
    chord, ``omega`` along ``c_1 - c_2`` and ``u = -omega x c_1``, with ``c_k = a_k n_k`` its
    contact points (arm ``a_k``, normal ``n_k`` towards neighbour ``k``), deforming neither contact.

    particle : (t,) the spheres; dropped : (t,) the reduced unknown removed for each (its rotation
    component along the chord's largest direction); local : (t, 6) the unknowns of each sphere
    (translations, then rotations) in the reduced numbering *before* the removal; vector : (t, 6)
    the unit turn on those unknowns."""

    particle: np.ndarray
    dropped: np.ndarray
    local: np.ndarray
    vector: np.ndarray

    @property
    def n(self) -> int:
        """Number of turns (two-contact spheres deflated)."""
        return int(self.particle.size)


def _no_turns() -> Turns:
    return Turns(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 6), np.int64), np.zeros((0, 6)))


def two_contact_turns(asm, red) -> Turns:
    """The turns of the two-contact spheres of a 3D assembly whose six unknowns are all in
    ``red``: the null vector of the sphere's (6, 6) block of its two contacts' compatibility
    ``B`` (its neighbours held), which :class:`Turns` states in closed form; kept when that block
    has rank 5 to rounding (``TURN_TOL``, ``TURN_RANK``). Empty in 2D (a two-contact disk has no
    zero mode) and without candidates."""
    empty = _no_turns()
    net = asm.net
    if net.dim != 3 or net.n_contacts == 0:
        return empty
    N = net.n_particles
    ends = net.pairs.ravel()                                  # contact k: ends 2k (side i), 2k + 1 (j)
    cand = np.flatnonzero(np.bincount(ends, minlength=N) == 2)
    if cand.size == 0:
        return empty
    pos = np.full(asm.ndof + 1, -1, dtype=np.int64)           # asm unknown -> reduced position
    pos[red.idx] = np.arange(red.idx.size)
    full = np.concatenate([3 * cand[:, None] + np.arange(3), 3 * N + 3 * cand[:, None] + np.arange(3)], axis=1)
    local = pos[asm.dof_map[full]]                            # (t, 6); -1 where not an unknown
    ok = np.all(local >= 0, axis=1)
    cand, local = cand[ok], local[ok]
    order = np.argsort(ends, kind="stable")
    first = np.searchsorted(ends[order], cand)
    end2 = order[np.stack([first, first + 1], axis=1)]       # (t, 2) contact ends of each sphere
    k, side = end2 // 2, end2 % 2
    B = asm.matrices.B
    blk = np.stack([B[k[:, 0]], B[k[:, 1]]], axis=1)          # (t, 2, 3, 12)
    cols = 6 * side[:, :, None] + np.arange(6)                # the sphere's six columns per contact
    M = np.take_along_axis(blk, cols[:, :, None, :], axis=3).reshape(-1, 6, 6)
    _, sv, Vt = np.linalg.svd(M) if M.size else (None, np.zeros((0, 6)), np.zeros((0, 6, 6)))
    good = (sv[:, 5] <= TURN_TOL * sv[:, 0]) & (sv[:, 4] >= TURN_RANK * sv[:, 0])
    v = Vt[good, 5]
    drop = 3 + np.argmax(np.abs(v[:, 3:]), axis=1)            # the rotation most along the chord
    return Turns(cand[good], local[good][np.arange(v.shape[0]), drop], local[good], v)


def deflate_turns(red, turns) -> Reduced:
    """``red`` without the unknown ``turns.dropped`` of each turn: the reduced Hessian then has
    none of these null vectors (each had a non-zero component on its dropped unknown, and the
    turns have disjoint supports), the system stays consistent (the load is orthogonal to them),
    and each removal is one floppy mode, counted in ``Reduced.n_turns``."""
    if turns.n == 0:
        return red
    keep = np.ones(red.idx.size, dtype=bool)
    keep[turns.dropped] = False
    k = np.flatnonzero(keep)
    return replace(red, H=red.H[k][:, k].tocsc(), F=red.F[k], d=red.d[k], idx=red.idx[k],
                   particle=red.particle[k], n_turns=turns.n)


def restore_turns(X, red_full, turns):
    """The solution ``X`` (m', k) of the deflated system on the unknowns of ``red_full`` (m, k),
    the dropped unknowns zero, then each turn removed in the ``diag(red_full.d)`` inner product:
    the solution the shifted solve of the undeflated system returns (orthogonal to the null
    vectors in that metric), up to the other floppy modes."""
    full = np.zeros((red_full.idx.size, X.shape[1]))
    keep = np.ones(red_full.idx.size, dtype=bool)
    keep[turns.dropped] = False
    full[keep] = X
    if turns.n:
        dv = red_full.d[turns.local] * turns.vector                       # (t, 6)
        coef = np.einsum("tl,tlk->tk", dv, full[turns.local]) / np.einsum("tl,tl->t", dv, turns.vector)[:, None]
        np.subtract.at(full, turns.local, turns.vector[:, :, None] * coef[:, None, :])
    return full


# ---- step 3: factorise -----------------------------------------------------------------------
# the back ends, the shift M = H + eta diag(H) and the floppy count live in microhom.factor
_ETA = _factor.ETA   # relative Tikhonov shift of the factorised matrix  M = H + eta diag(H)


def have_cholmod() -> bool:
    """True when CHOLMOD is importable (``scikit-sparse``; see README: needs Debian's
    ``libsuitesparse-dev`` to build)."""
    return _cholmod is not None


ORDERINGS = ("auto", "amd", "metis", "nesdis")


def particle_ordering(red, pairs, n_particles, method="auto"):
    """Fill-reducing ordering of the unknowns computed on the particle contact graph (N nodes,
    3x fewer than the unknowns, 9x fewer non-zeros), each particle's unknowns kept together.

    method: ``"amd"``, ``"metis"`` (nested dissection; less fill on large 2D networks) or
    ``"auto"`` (amd below 2e5 particles, metis above: measured in ``docs/stiffness.md``).
    Returns a permutation ``perm`` of the reduced unknowns (new position -> old index)."""
    if method not in ORDERINGS:
        raise ValueError(f"unknown ordering {method!r}; allowed: {', '.join(ORDERINGS)}")
    if method == "auto":
        method = "amd" if n_particles < 200_000 else "metis"
    i, j = pairs[:, 0], pairs[:, 1]
    ar = np.arange(n_particles)
    G = sp.csc_matrix((np.r_[np.full(2 * i.size, -1.0), np.full(n_particles, 10.0)],
                       (np.r_[i, j, ar], np.r_[j, i, ar])), shape=(n_particles, n_particles))
    fg = _cholmod.analyze(G, mode="simplicial", ordering_method=method)
    rank = np.empty(n_particles, dtype=np.int64)
    rank[fg.P()] = ar
    return np.lexsort((np.arange(red.particle.size), rank[red.particle]))


SOLVERS = ("auto", "pardiso", "cholmod", "splu")
#: smallest system for which ``solver="auto"`` takes CHOLMOD (measured: 3e3 unknowns, SuperLU 0.03 s
#: against 0.09 s; 3e4 unknowns, CHOLMOD 2.5x faster)
AUTO_CHOLMOD_DOF = 10_000


def _auto_solver(n):
    if have_pardiso() and n >= AUTO_PARDISO_DOF:
        return "pardiso"
    if _cholmod is not None and n >= AUTO_CHOLMOD_DOF:
        return "cholmod"
    return "splu"


def factorise(red, solver="auto", *, pairs=None, n_particles=None, ordering="auto", eta=_ETA,
              max_memory=None, psd=True, dim=2):
    """Factorise a :class:`Reduced` system.

    solver: ``"pardiso"`` (MKL PARDISO Bunch-Kaufman ``LDL^T`` of ``H - eta diag(H)``: its
    inertia counts the zero and negative modes, see :func:`count_modes`; needs the ``mkl``
    wheel, a default dependency on x86-64), ``"cholmod"`` (CHOLMOD supernodal Cholesky of
    ``H + eta diag(H)``, needs scikit-sparse), ``"splu"`` (scipy SuperLU of ``H + eta diag(H)``,
    always available) or ``"auto"``: pardiso if loadable and the system has at least
    ``AUTO_PARDISO_DOF`` unknowns, else cholmod if importable and at least ``AUTO_CHOLMOD_DOF``
    unknowns, else splu (measured in ``docs/stiffness.md``). For CHOLMOD, a matrix that is not
    positive definite (pre-stress with negative modes) goes to SuperLU, whose symmetric pivots
    count the negative modes. ``pairs``/``n_particles`` give the particle graph for the CHOLMOD
    ordering (``ordering``: see :func:`particle_ordering`). ``max_memory`` [bytes]: refuse a
    factorisation predicted above it (:class:`MemoryGuardError`; default: the available memory).
    ``dim``: the network's dimension (2 disks, 3 spheres), for SuperLU's memory guard."""
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; allowed: {', '.join(SOLVERS)}")
    if solver == "cholmod" and _cholmod is None:
        raise RuntimeError("solver='cholmod' needs scikit-sparse (CHOLMOD): apt-get install "
                           "libsuitesparse-dev, then pip install 'scikit-sparse==0.4.16'")
    if solver == "pardiso" and not have_pardiso():
        raise RuntimeError("solver='pardiso' needs MKL PARDISO: pip install mkl (x86-64 Linux or "
                           "Windows)")
    if solver == "auto":
        solver = _auto_solver(red.H.shape[0])
    shifted = dict(scale=red.d, max_memory=max_memory, dim=dim)
    if solver == "pardiso":
        if psd:     # H - eta diag(H): its inertia counts the zero modes, and it solves
            return _factor.factor(red.H, backend="pardiso", shift=-eta, matching=False, **shifted)
        # not psd: H + eta diag(H) counted first (negative modes), then H - eta diag(H) on the
        # same analysis (f.inertias keeps the first count for count_modes)
        return _factor.factor(red.H, backend="pardiso", shift=eta, **shifted).reshift(-eta)
    if solver == "cholmod" and pairs is not None:
        perm = particle_ordering(red, pairs, n_particles, ordering)
        try:
            return _factor.factor(red.H, backend="cholmod", shift=eta, perm=perm, **shifted)
        except NotPositiveDefinite:
            pass
    return _factor.factor(red.H, backend="splu", shift=eta, **shifted)


# ---- step 4: count the modes -----------------------------------------------------------------
@dataclass(frozen=True)
class ModeCount:
    """Zero (floppy) and negative modes of the reduced Hessian, from the factor's pivots.

    n_floppy, n_unstable : counts; gap : (largest relative pivot counted floppy, smallest kept);
    method : ``"pivots"``, ``"rescale"``, ``"inertia"`` (PARDISO) or ``"eig"`` (dense/shift-invert
    fallback);
    factor : the factor to solve with (the rescaled one when ``method == "rescale"`` replaced the
    input factor in place, CHOLMOD), or None (keep using the input factor)."""

    n_floppy: int
    n_unstable: int
    gap: tuple
    method: str
    factor: object = field(default=None, repr=False, compare=False)


#: largest reduced system on which :func:`stiffness` runs the rigidity check of the floppy count
#: (no pre-stress). Measured, one thread, CPU time of the whole exact solve on the benchmark network
#: (``studies.bench_stiffness.diluted_triangular``): 1e4 disks (3e4 unknowns) 0.21-0.25 s without
#: the check, 0.39-0.51 s with it; 1e5 disks 13.9-14.9 s without, 29-36 s with (the same 24 floppy
#: modes); the corpus packings where it mattered have 3e3-1.2e4 unknowns (docs/stiffness.md)
RIGIDITY_CHECK_MAX_DOF = 15_000


def rigidity_factor(asm, red):
    """The stiffness-weighted compatibility ``R`` (rows, m) of the reduced unknowns with
    ``red.H = R^T R`` (no pre-stress): per contact ``Lambda^1/2 Q^T B`` from the eigen-decomposition
    ``K = Q Lambda Q^T`` of its stiffness tensor (``kn`` along the normal, ``kt_eff`` across; a
    zero stiffness, kt = 0 or sliding, gives an exact zero row). For the rigidity check of the
    floppy count (:func:`microhom.factor.count_zero_modes`)."""
    w, Q = np.linalg.eigh(asm.matrices.K)
    # eigenvalues at the rounding level of kn are zero stiffness (kt = 0), not sqrt(1e-16) weights
    w = np.where(w > 64 * np.finfo(float).eps * np.abs(w).max(axis=1, keepdims=True), w, 0.0)
    Rc = np.sqrt(w)[:, :, None] * np.einsum("cji,cjk->cik", Q, asm.matrices.B)
    return sparse_rows(Rc, asm.ldof, asm.ndof)[:, red.idx].tocsr()


def count_modes(factor, red, count="auto", eta=_ETA, *, psd=False, max_memory=None,
                rigidity=None) -> ModeCount:
    """Count zero (floppy) and negative modes of the reduced Hessian from the factor made by
    :func:`factorise`: :func:`microhom.factor.count_zero_modes` on the pencil ``(H, diag H)``
    (Sylvester's law of inertia), plus the ``red.n_zero`` unknowns dropped with no stiffness.

    PARDISO (``method == "inertia"``): the inertia of the Bunch-Kaufman ``LDL^T`` of
    ``H - eta diag(H)`` counts the eigenvalues below ``eta``; unless ``psd`` (``H`` known to be
    positive semi-definite: no pre-stress), those below ``-eta`` (negative modes) come from
    ``H + eta diag(H)``. Exact zero modes sit at ``|lam| < 1e-15`` and the smallest rigid mode of
    the 1e5-disk network at ``7.8e-10`` (``docs/stiffness.md``), so the threshold
    ``eta = 1e-12`` leaves orders of magnitude on both sides; the certified gap
    (:func:`microhom.spectral.certified_bound`) proves it for a given network.

    CHOLMOD and SuperLU, by the rule ``count``: ``"pivots"`` (a relative pivot below 1e-8 is a
    zero mode), ``"rescale"`` (a second factorisation with a 100x smaller shift: a pivot belongs
    to a zero mode iff it scales with the shift; forced on ill-conditioned networks; with CHOLMOD
    it replaces the first in place, so solve with ``ModeCount.factor`` then) or ``"auto"``
    (default: ``"pivots"``, switching to ``"rescale"`` when a relative pivot falls in the
    ambiguous band 1e-10..1e-6; measured: a zero mode spread over a 1e5-disk network had a
    pivot of 1.2e-8, above the 1e-8 threshold).

    ``rigidity`` (:func:`rigidity_factor`, no pre-stress): the floppy count is checked on ``R``
    itself, whose singular values the Hessian squares (``docs/stiffness.md``)."""
    if count not in COUNTS:
        raise ValueError(f"unknown count {count!r}; allowed: {', '.join(COUNTS)}")
    if red.H.shape[0] == 0:
        return ModeCount(red.n_zero + red.n_turns, 0, (np.nan, np.nan), count)
    z = _factor.count_zero_modes(factor, count, eta=eta, psd=psd, max_memory=max_memory,
                                 rigidity=rigidity)
    return ModeCount(red.n_zero + red.n_turns + z.n_zero, z.n_negative, z.gap, z.method, factor=z.factor)


# ---- step 5: solve ---------------------------------------------------------------------------
#: a relative residual above this flags the result "inaccurate", with NaN relaxed tensor and moduli
INACCURATE = 1e-8
#: the refinement diverges once its residual exceeds the best one so far by this factor: a step
#: multiplies the error of a pencil mode ``lam`` by ``-s/(lam + s)`` (shift ``s``), of modulus
#: above 1 for ``lam`` between 0 and ``-2 s`` (a rigid mode within ``eta`` of PARDISO's ``-eta``,
#: or a negative mode within ``eta`` of ``+eta``); rounding moves a stalled residual by less
DIVERGENCE = 10.0


def _refine(factor, red, X, fn_, rtol, steps):
    """At most ``steps`` refinements of ``X`` on ``factor`` against ``H``, stopped at ``rtol`` or
    once the residual exceeds the best by :data:`DIVERGENCE` (or is not finite). Returns
    ``(best X, its residual, refinements run, diverged?, last residual)``."""
    def residual(X):
        return float((np.linalg.norm(-red.F - red.H @ X, axis=0) / fn_).max())
    best, best_r = X, residual(X)
    r, n = best_r, 0
    while best_r > rtol and n < steps:
        X = X + factor.solve(-red.F - red.H @ X)
        n, r = n + 1, residual(X)
        if not (np.isfinite(r) and r <= DIVERGENCE * best_r):
            return best, best_r, n, True, r
        if r < best_r:
            best, best_r = X, r
    return (best, best_r, n, False, r) if r > best_r else (X, r, n, False, r)


def _opposite_shift(factor, max_memory):
    """The factor of ``H - shift diag(d)`` (the other side of the pencil's spectrum): the same
    factor reshifted (PARDISO in place on its analysis, CHOLMOD in place, SuperLU a new factor),
    else a new SuperLU factor under the memory guard. Returns ``(factor, how)``."""
    s = -factor.shift
    new = None
    if factor.scale is not None:
        try:
            new = factor.reshift(s)
        except (NotImplementedError, _factor.FactorisationError):
            new = None
    if new is not None:
        return new, f"{new.name} reshifted to {s:+.0e}"
    new = _factor.factor(factor.A, backend="splu", shift=s, scale=factor.scale, max_memory=max_memory,
                         dim=factor.dim)
    return new, f"splu at {s:+.0e}"


def relax(factor, red, F_scale, rtol=1e-13, max_refine=50, *, max_memory=None, details=False, psd=False):
    """Solve ``H Q = -F`` for the three unit strains by iterated Tikhonov (refinement on the
    shifted factor ``M = H + s diag(d)`` against the unshifted H): exact for every mode whose
    stiffness >> eta diag; zero modes are not excited (F lies in the range of H). Returns
    (Q (m, 3), residual, n_refine) with the residual relative to the norm of the per-contact
    affine forces ``F_scale`` (and the path taken, a string, if ``details``).

    A step multiplies the error of a pencil mode ``lam`` by ``-s/(lam + s)``: a mode between 0
    and ``-2s`` makes the refinement diverge (PARDISO's ``s = -eta`` beside a rigid mode at
    ``1.26 eta``: residual 6e19, K = 1.7e51 on a corpus row, ``docs/stiffness.md``). Once the
    residual grows by ``DIVERGENCE`` (10) over its best, the best iterate is kept and the
    refinement goes on, within the same ``max_refine`` budget, on the factor of
    ``H - s diag(d)`` (``_opposite_shift``: contracting for every mode of that side; a
    positive semi-definite H converges at ``s = +eta``, so with ``psd`` a growth there is rounding
    and only the best iterate is kept). Never more than ``max_refine`` solves; the returned
    iterate is the best seen, its residual the one returned."""
    if red.H.shape[0] == 0:
        return (np.zeros((0, red.F.shape[1])), 0.0, 0) + (("empty",) if details else ())
    fn_ = F_scale if F_scale > 0 else 1.0
    X, resid, n_ref, diverged, last = _refine(factor, red, factor.solve(-red.F), fn_, rtol, max_refine)
    path = f"{factor.name} at {factor.shift:+.0e}"
    if diverged and resid > rtol and n_ref < max_refine and not (psd and factor.shift > 0):
        path += (f": diverged (residual {resid:.1e} grew to {last:.1e} at refinement {n_ref}); "
                 f"kept the best iterate, then ")
        try:
            f2, how = _opposite_shift(factor, max_memory)
        except _factor.MemoryGuardError as exc:
            path += f"no re-solve ({exc})"
        else:
            X, resid, n2, diverged, last = _refine(f2, red, X, fn_, rtol, max_refine - n_ref)
            n_ref += n2
            path += how + (f": diverged too (residual {last:.1e})" if diverged else "")
            if f2 is not factor and hasattr(f2, "release"):
                f2.release()
    elif diverged:
        path += f": diverged (residual {last:.1e}); kept the best iterate"
    return (X, resid, n_ref) + ((path,) if details else ())


#: the non-symmetric solve's back ends (:func:`relax_tangential`)
TANGENTIAL_SOLVERS = ("auto", "pardiso", "splu")


def relax_tangential(asm, red, F_scale, rtol=1e-13, max_refine=50, eta=_ETA, *, solver="auto",
                     max_memory=None, details=False):
    """:func:`relax` for spheres with tangential forces under pre-stress: solve the
    non-symmetric ``(H + Hn) Q = -(F + Fn)`` (``microhom.kinematics.Assembly``) on the unknowns of
    ``red``, factorising ``H + Hn + eta diag`` (:func:`microhom.factor.factor_general`) and
    refining against the unshifted matrix. ``solver``: ``"pardiso"`` (MKL PARDISO, real
    non-symmetric), ``"splu"`` (SuperLU) or ``"auto"`` (PARDISO where it loads and the system has
    at least ``AUTO_PARDISO_DOF`` unknowns, else SuperLU). ``max_memory`` [bytes]: a factor
    predicted above it (or above the available memory) is refused with
    :class:`MemoryGuardError` naming the figure, before it allocates. Returns (Q (m, k),
    residual, n_refine) as :func:`relax` (and the back end's name, if ``details``)."""
    if solver not in TANGENTIAL_SOLVERS:
        raise ValueError(f"unknown solver {solver!r} for the non-symmetric solve; allowed: "
                         f"{', '.join(TANGENTIAL_SOLVERS)}")
    if red.H.shape[0] == 0:
        return (np.zeros((0, red.F.shape[1])), 0.0, 0) + (("empty",) if details else ())
    A = (asm.H + asm.Hn).tocsr()[red.idx][:, red.idx].tocsc()
    M = (A + sp.diags(eta * red.d)).tocsc()
    if solver == "auto":
        solver = "pardiso" if have_pardiso() and A.shape[0] >= AUTO_PARDISO_DOF else "splu"
    lu = _factor.factor_general(M, backend=solver, max_memory=max_memory, dim=asm.net.dim)
    try:
        Xr = lu.solve(-red.F)
        fn_ = F_scale if F_scale > 0 else 1.0
        n_ref = 0
        for n_ref in range(1, max_refine + 1):
            R = -red.F - A @ Xr
            resid = float((np.linalg.norm(R, axis=0) / fn_).max())
            if resid <= rtol or not np.isfinite(resid):
                break
            Xr = Xr + lu.solve(R)
        else:
            R = -red.F - A @ Xr
            resid = float((np.linalg.norm(R, axis=0) / fn_).max())
    finally:
        lu.release()
    return (Xr, resid, n_ref) + ((lu.name,) if details else ())


# ---- step 6: the tensor ----------------------------------------------------------------------
def _tangential_tensor(asm, Q, area):
    """The stress form with the tangential forces' rate terms (``Assembly.Gts``, ``Ns``) and the
    relative difference of the work form, which equals it where ``(H + Hn) Q = -(F + Fn)``."""
    Df = asm.Df
    delta = asm.Bs @ Q + Df
    dc = asm.Bcs @ Q + Df
    Kd, Gd = asm.Ks @ delta, (asm.Kgs + asm.Gts) @ dc
    c_str = (Df.T @ (Kd + Gd)) / area
    work = (delta.T @ Kd + dc.T @ (asm.Kgs @ dc) + Df.T @ (asm.Gts @ dc) + Q.T @ (asm.Ns @ dc)) / area
    scale = max(np.abs(c_str).max(), 1e-300)
    return c_str, float(np.abs(work - c_str).max() / scale)


def relaxed_tensor(asm, Q, area):
    """(C, consistency): the relaxed tensor in the energy form ``(1/A) Delta^T K Delta`` at the
    relaxed unknowns ``Q`` (ndof, 3) (without the pre-stress correction) and the relative
    difference of the stress form ``(1/A) D^T K Delta``. Spheres with tangential forces under
    pre-stress (``asm.Gts`` set): the stress form with their rate terms (not symmetric), and the
    difference of the work form."""
    if asm.Gts is not None:
        return _tangential_tensor(asm, Q, area)
    Df = asm.Df
    delta = asm.Bs @ Q + Df                                  # (2C, 3) contact displacements
    Kd = asm.Ks @ delta
    c_rel = delta.T @ Kd
    c_str = Df.T @ Kd
    if asm.Kgs is not None:
        dc = asm.Bcs @ Q + Df
        Kgd = asm.Kgs @ dc
        c_rel = c_rel + dc.T @ Kgd
        c_str = c_str + Df.T @ Kgd
    c_rel = 0.5 * (c_rel + c_rel.T) / area
    c_str = c_str / area
    scale = max(np.abs(c_rel).max(), np.abs(c_str).max(), 1e-300)
    return c_rel, float(np.abs(c_str - c_rel).max() / scale)


def degeneracy_flags(C, C_aff, modes, n_particles, n_rattlers, n_dof):
    """The reasons a result is degenerate: not jammed, floppy, unstable (one sentence each)."""
    flags = []
    scale = np.abs(C_aff).max()
    if n_particles and n_rattlers == n_particles:
        flags.append(f"not jammed: every particle ({n_particles}) is a rattler; C = 0")
    elif n_dof == 0 and n_particles:
        flags.append("not jammed: no unknown carries stiffness")
    w = np.linalg.eigvalsh(0.5 * (C + C.T))
    if scale > 0 and w.max() <= 1e-10 * scale and not flags:
        flags.append(f"not jammed: the relaxed tensor vanishes (largest eigenvalue {w.max():.3g}, "
                     f"affine scale {scale:.3g}) with {modes.n_floppy} floppy mode(s) and "
                     f"{n_rattlers} rattler(s) of {n_particles}")
    elif scale > 0 and not flags and -1e-10 * scale <= w.min() <= 1e-10 * scale:
        flags.append(f"floppy: the relaxed tensor has a zero eigenvalue ({modes.n_floppy} floppy "
                     f"mode(s)); a deformation mode costs no energy")
    if modes.n_unstable:
        flags.append(f"unstable: the Hessian has {modes.n_unstable} negative mode(s) under the "
                     f"pre-stress; the tensor is the stationary response")
    if scale > 0 and w.min() < -1e-10 * scale:
        flags.append(f"unstable: the tensor has a negative eigenvalue ({w.min():.4g}): the "
                     f"homogeneous state is not stable under this (pre-)stress")
    return flags


# ---- main entry ------------------------------------------------------------------------------
#: bytes per particle of everything but the factor (assembly, network, fields), measured peak
#: at 1e5 disks minus the factor (docs/stiffness.md, "Memory guard")
_BYTES_PER_PARTICLE = 4.0e3


def predicted_memory(n_particles, n_dof=None, solver="auto", dim=2):
    """Predicted peak memory [bytes] of :func:`stiffness` on a network of ``n_particles`` disks
    with ``n_dof`` unknowns (default ``3 n_particles``): the fitted factor size of the solver
    (:func:`microhom.factor.predicted_factor_bytes`) plus ``_BYTES_PER_PARTICLE`` per particle
    for the assembly. Measured against it in ``docs/stiffness.md``. ``dim`` 3: SuperLU's 3D fill
    (``docs/spheres.md``)."""
    n_dof = 3 * int(n_particles) if n_dof is None else int(n_dof)
    if solver == "auto":
        solver = _auto_solver(n_dof)
    return predicted_factor_bytes(n_dof, solver, dim) + _BYTES_PER_PARTICLE * int(n_particles)


def _check_arguments(network, rtol, max_refine, count, ordering, solver, max_memory, deflate=True):
    """The argument checks of :func:`stiffness`: a ``TypeError`` or ``ValueError`` naming the
    parameter and its allowed values or range."""
    if not isinstance(network, ContactNetwork):
        raise TypeError(f"network must be a microhom.network.ContactNetwork (e.g. from "
                        f"from_overlaps or PackingResult.to_network()), got {type(network).__name__}")
    if not (isinstance(rtol, (int, float, np.floating)) and 0 < rtol < 1):
        raise ValueError(f"rtol must be a relative residual in (0, 1), got {rtol!r}")
    if not (isinstance(max_refine, (int, np.integer)) and max_refine >= 1):
        raise ValueError(f"max_refine must be an integer >= 1, got {max_refine!r}")
    if count not in COUNTS:
        raise ValueError(f"unknown count {count!r}; allowed: {', '.join(COUNTS)}")
    if ordering not in ORDERINGS:
        raise ValueError(f"unknown ordering {ordering!r}; allowed: {', '.join(ORDERINGS)}")
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; allowed: {', '.join(SOLVERS)}")
    if max_memory is not None and not (np.isfinite(max_memory) and max_memory > 0):
        raise ValueError(f"max_memory must be a finite number of bytes > 0, got {max_memory!r}")
    if not isinstance(deflate, (bool, np.bool_)):
        raise ValueError(f"deflate must be True or False, got {deflate!r}")


def _reduce_and_deflate(asm, tangential, deflate):
    """The reduce step of :func:`stiffness`: the system without its stiffness-free unknowns
    (for the non-symmetric tangent, its symmetric part, whose modes are counted), then, with
    ``deflate`` (spheres without pre-stress), without one rotation unknown per two-contact sphere
    (its turn, a known null vector; under pre-stress not a null vector of the tangent). Returns
    ``(reduced, deflated, turns)``."""
    red_all = reduce_system(asm if not tangential else
                            replace(asm, H=(asm.H + 0.5 * (asm.Hn + asm.Hn.T)).tocsc(), F=asm.F + asm.Fn))
    turns = two_contact_turns(asm, red_all) if deflate else _no_turns()
    return red_all, deflate_turns(red_all, turns), turns


def _fluctuation_fields(asm, Q, N, dim):
    """The fluctuations of the relaxed solution ``Q`` (reduced unknowns x load cases) on all
    ``N`` particles (rattlers and dropped unknowns zero): displacements ``u`` of shape
    (n_cases, N, dim) and spins ``omega`` of shape (n_cases, N) in 2D, (n_cases, N, 3) in 3D,
    per unit Mandel strain (units of the network's lengths, and radians)."""
    rot, nm = rotational_dofs(dim), Q.shape[1]
    full = np.zeros(((dim + rot) * N + 1, nm))
    full[np.flatnonzero(asm.dof_map >= 0)] = Q[asm.dof_map[asm.dof_map >= 0]]
    u_f = np.stack([full[0:dim * N, b].reshape(N, dim) for b in range(nm)])
    w_f = np.stack([full[dim * N:(dim + rot) * N, b] if rot == 1 else
                    full[dim * N:(dim + rot) * N, b].reshape(N, rot) for b in range(nm)])
    return u_f, w_f


def _relax_and_release(factor, asm, red, tangential, rtol, max_refine, max_memory=None, solver="auto"):
    """The relaxation step of :func:`stiffness`: the symmetric solve on ``factor`` (or, for spheres
    with pre-stress and tangential forces, the non-symmetric one), then the factor's memory freed.
    Returns ``(Xr, residual, n_refine, solver name, path)`` (``path``: see :func:`relax`)."""
    if tangential:
        Xr, resid, n_ref, used = relax_tangential(asm, red, asm.F_scale, rtol, max_refine, solver=solver,
                                                  max_memory=max_memory, details=True)
        path = f"{used} (non-symmetric)"
    else:
        Xr, resid, n_ref, path = relax(factor, red, asm.F_scale, rtol, max_refine, max_memory=max_memory,
                                       details=True, psd=asm.Kgs is None)
        used = factor.name if factor is not None else "none"
    if factor is not None and hasattr(factor, "release"):
        factor.release()
    return Xr, resid, n_ref, used, path


def stiffness(network, *, prestress=False, min_contacts=None, solver="auto", rtol=1e-13,
              max_refine=50, count="auto", ordering="auto", spin_arm="contact",
              max_memory=None, deflate=True) -> StiffnessResult:
    """Exact linear-response stiffness tensor of a periodic contact network.

    The named steps, each usable on its own: ``_check_arguments`` (argument checks),
    ``_normalise`` (input check, exact scaling), :func:`microhom.kinematics.assemble` (Hessian
    and load, rattlers removed), :func:`reduce_system` (stiffness-free unknowns dropped),
    :func:`factorise`, :func:`count_modes`, :func:`relax` (solve with refinement),
    :func:`relaxed_tensor`, ``_fluctuation_fields`` (the fields on all particles).

    Parameters
    ----------
    network : periodic ContactNetwork.
    prestress : include the geometric stiffness of the normal forces ``fn`` and the pre-stress
        terms of the Cauchy stress increment (needs ``network.fn``); on spheres with ``ft``, also
        the rate terms of the tangential forces (LAMMPS's history update, ``docs/spheres.md``;
        negative modes are then those of the symmetric part of the non-symmetric tangent).
    min_contacts : rattler threshold (particles with fewer contacts are removed, iteratively);
        None = per particle 2 if it has a contact with kt_eff > 0, else 3.
    solver : ``"auto"`` (default: PARDISO where the ``mkl`` wheel loads, else CHOLMOD if
        scikit-sparse is importable, else SuperLU; small systems use SuperLU, see
        :func:`factorise`), ``"pardiso"``, ``"cholmod"`` or ``"splu"`` (scipy SuperLU, always
        available).
    count : how zero (floppy) modes are counted with CHOLMOD and SuperLU: ``"auto"``,
        ``"pivots"`` or ``"rescale"`` (see :func:`count_modes`; ``"rescale"`` is forced on
        ill-conditioned networks). PARDISO counts by the inertia of its ``LDL^T``.
    max_memory : bytes the solve may use (default: the machine's available memory); a network
        whose predicted peak (:func:`predicted_memory`, then PARDISO's own analysis) exceeds it
        is refused with :class:`MemoryGuardError` before the assembly allocates.
    ordering : CHOLMOD fill-reducing ordering on the particle graph (:func:`particle_ordering`).
    rtol : target relative residual of the relaxation solve, in (0, 1).
    spin_arm : ``"contact"`` (default: spins turn the contact point, arms ``|c| r_i/(r_i+r_j)``)
        or ``"radius"`` (arms ``r_i``, LAMMPS's ``gran/*`` kinematics); see
        :mod:`microhom.kinematics`. They agree on touching disks.
    deflate : spheres without pre-stress: remove each two-contact sphere's turn (a known floppy
        mode, :func:`two_contact_turns`) before the factorisation and count it (``n_turns``, in
        ``n_floppy``); the same tensor, no near-zero pivots (``docs/spheres.md``). No effect in 2D.

    Degenerate results (not jammed, floppy, unstable, ill-conditioned) carry ``flags``; all but
    "floppy" (a zero-energy direction of an otherwise jammed network, e.g. the frictionless square
    lattice in shear) also raise a ``RuntimeWarning`` with the reason.
    """
    t0 = time.perf_counter()
    _check_arguments(network, rtol, max_refine, count, ordering, solver, max_memory, deflate)
    net, s, flags = _normalise(network, prestress)
    if flags:
        count = "rescale"
    memory_check(predicted_memory(net.n_particles, (net.dim + rotational_dofs(net.dim)) * net.n_particles,
                                  solver=solver, dim=net.dim),
                 f"exact stiffness of {net.n_particles} particles ({solver} solver)", max_memory)
    asm = assemble(net, prestress=prestress, min_contacts=min_contacts, spin_arm=spin_arm)
    c_aff = affine_stiffness(net, prestress=prestress, spin_arm=spin_arm)
    sigma0 = stress0(net) if prestress else None
    t_asm = time.perf_counter() - t0

    t1, steps = time.perf_counter(), {"assemble": t_asm}
    tangential = asm.Hn is not None        # spheres, pre-stress, tangential forces: modes of sym(H + Hn)
    red_all, red, turns = _reduce_and_deflate(asm, tangential, deflate and not prestress)
    steps["reduce"] = time.perf_counter() - t1
    factor = None
    tc = time.perf_counter()
    if red.H.shape[0]:
        factor = factorise(red, solver, pairs=asm.net.pairs, n_particles=net.n_particles,
                           ordering=ordering, max_memory=max_memory, psd=not prestress, dim=net.dim)
    steps["factorise"] = time.perf_counter() - tc
    tc = time.perf_counter()
    check = not prestress and red.H.shape[0] <= RIGIDITY_CHECK_MAX_DOF
    modes = count_modes(factor, red, count, psd=not prestress, max_memory=max_memory,
                        rigidity=rigidity_factor(asm, red) if check else None)
    if modes.factor is not None:      # CHOLMOD refactored in place with the smaller shift
        factor = modes.factor
    steps["count"] = time.perf_counter() - tc
    tc = time.perf_counter()
    Xr, resid, n_ref, used, path = _relax_and_release(factor, asm, red, tangential, rtol, max_refine,
                                                      max_memory, "auto" if solver == "cholmod" else solver)
    steps["relax"] = time.perf_counter() - tc
    del factor
    Q = np.zeros((asm.ndof, asm.F.shape[1]))          # 3 Mandel strains in 2D, 6 in 3D
    Q[red_all.idx] = restore_turns(Xr, red_all, turns)
    t_solve = time.perf_counter() - t1
    if resid > INACCURATE:
        flags.append(f"inaccurate: the relaxation solve did not converge (relative residual "
                     f"{resid:.2e}; {path}); the relaxed tensor and moduli are NaN")

    tc = time.perf_counter()
    c_rel, consistency = relaxed_tensor(asm, Q, net.volume)
    steps["tensor"] = time.perf_counter() - tc
    if prestress:
        c_rel = c_rel + prestress_correction(sigma0)
    if tangential:                      # the rate of -sym(P) where P = sum c f^T / V is not symmetric
        c_rel = c_rel + skew_stress_correction(net)
    flags += degeneracy_flags(c_rel, c_aff, modes, net.n_particles, int(asm.rattlers.sum()),
                              red.H.shape[0])
    for msg in flags:   # a floppy direction is a property of the network, flagged but not warned
        if not msg.startswith("floppy"):
            warnings.warn(msg, RuntimeWarning, stacklevel=2)
    # moduli of the scaled tensors, then scaled back: no overflow inside the isotropic sums
    (K_, G_), (Ka, Ga) = isotropic_moduli(c_rel), isotropic_moduli(c_aff)
    with np.errstate(over="ignore", invalid="ignore"):
        c_rel, c_aff = c_rel * s, c_aff * s
        K_, G_, Ka, Ga = K_ * s, G_ * s, Ka * s, Ga * s
    if not all(np.all(np.isfinite(v)) for v in (c_rel, c_aff, K_, G_, Ka, Ga)):   # past 1.8e308
        msg = (f"overflow: the tensor exceeds the float64 range once scaled back by kn's scale "
               f"{s:.3g}; rescale the stiffnesses (the moduli are proportional to kn)")
        flags.append(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
    if resid > INACCURATE:       # a tensor off by an unknown amount is not returned (K was 1.7e51)
        c_rel, K_, G_ = np.full_like(c_rel, np.nan), np.nan, np.nan
    N = net.n_particles
    u_f, w_f = _fluctuation_fields(asm, Q, N, net.dim)
    return StiffnessResult(
        C_mandel=c_rel, C_affine_mandel=c_aff, K=K_, G=G_, K_affine=Ka, G_affine=Ga,
        n_rattlers=int(asm.rattlers.sum()), n_floppy=int(modes.n_floppy), n_dof=int(asm.ndof),
        solve_time=t_solve, assembly_time=t_asm, n_particles=N,
        n_contacts=asm.net.n_contacts, n_spins=asm.n_spins, n_unstable=int(modes.n_unstable), n_turns=turns.n,
        prestress=bool(prestress), solver=used, residual=resid,
        consistency=consistency, n_refine=n_ref, relax_path=path, pivot_gap=modes.gap,
        stress0_mandel=None if sigma0 is None else strain_to_mandel(sigma0) * s,
        flags=tuple(flags), stiffness_scale=s, count_method=modes.method, step_times=steps, u=u_f, omega=w_f, rattler_mask=asm.rattlers)


def stress_increment(network, grad, u=None, omega=None) -> np.ndarray:
    """(2, 2) stress increment (1/A) sum sym(K Delta (x) c) for a displacement gradient ``grad``
    (any 2x2, e.g. a rotation) plus given fluctuations ``u`` (N, 2) and spins ``omega`` (N,).

    Direct contact-level evaluation, no solve, no pre-stress terms (used to check the solver).
    """
    _check(network, False)
    grad = np.asarray(grad, dtype=float)
    i, j = network.pairs[:, 0], network.pairs[:, 1]
    c = network.branch
    L = network.lengths
    n = c / L[:, None]
    t = np.stack([-n[:, 1], n[:, 0]], axis=1)
    ri, rj = network.radii[i], network.radii[j]
    delta = c @ grad.T
    if u is not None:
        delta = delta + u[j] - u[i]
    if omega is not None:
        delta = delta - ((L * ri / (ri + rj)) * omega[i] + (L * rj / (ri + rj)) * omega[j])[:, None] * t
    f = np.einsum("cab,cb->ca", network.stiffness_tensors(), delta)
    s = (f[:, :, None] * c[:, None, :]).sum(axis=0) / network.area
    return 0.5 * (s + s.T)
