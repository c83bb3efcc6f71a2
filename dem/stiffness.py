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
(the jax-md ``athermal_moduli`` convention). Exact for frictionless disks; for frictional contacts the
geometric terms of ``ft`` (rotation of the tangential force, rolling) are not included.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from microhom.kinematics import affine_tensor, assemble, stress0
from microhom.tensors import (isotropic_moduli, mandel_to_strain, mandel_to_tensor, mandel_to_voigt,
                              prestress_correction, strain_to_mandel, tensor_to_mandel, tensor_to_voigt,
                              voigt_to_mandel, voigt_to_tensor)

__all__ = ["StiffnessResult", "stiffness", "affine_stiffness", "stress_increment"]
# the tensor-notation helpers (mandel_to_tensor, isotropic_moduli, ...) live in microhom.tensors and
# the assembly in microhom.kinematics; they are imported here for the solver, not re-exported.



# ---- result ----------------------------------------------------------------------------------
@dataclass
class StiffnessResult:
    """Relaxed and affine 2D stiffness of a contact network (Mandel form over [xx, yy, sqrt2 xy]).

    Counts: ``n_rattlers`` particles removed (iteratively, fewer than ``min_contacts`` contacts);
    ``n_floppy`` zero-energy modes of the reduced Hessian (after removing rattlers, dropped spins
    and the two global translations); ``n_dof`` the number of unknowns solved for.
    ``solve_time`` is factorisation + solves [s]; ``assembly_time`` the assembly [s].
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
    n_unstable: int = 0            # negative-stiffness modes (only possible with prestress)
    prestress: bool = False
    solver: str = "splu"
    residual: float = 0.0          # max_j |H q_j + F_j| / (norm of the per-contact affine forces) after refinement
    consistency: float = 0.0       # |stress form - energy form| / |C|
    n_refine: int = 0
    pivot_gap: tuple = (np.nan, np.nan)   # (largest floppy, smallest kept) relative pivot
    stress0_mandel: np.ndarray | None = None
    u: np.ndarray | None = field(default=None, repr=False)       # (3, N, 2) relaxed fluctuations
    omega: np.ndarray | None = field(default=None, repr=False)   # (3, N) relaxed spins
    rattler_mask: np.ndarray | None = field(default=None, repr=False)

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
        return "\n".join(lines)


def _ratio(a, b):
    return f"{a / b:.6f}" if b != 0 else "n/a"


# ---- assembly (shared with the relaxation hierarchy: microhom.kinematics) -------------------
def affine_stiffness(network, prestress=False) -> np.ndarray:
    """(3, 3) Mandel affine (no relaxation) stiffness of all contacts of ``network``."""
    _check(network, prestress)
    c = affine_tensor(network, prestress)
    if prestress:
        c = c + prestress_correction(stress0(network))
    return 0.5 * (c + c.T) if not prestress else c


def _check(network, prestress):
    if network.cell is None:
        raise ValueError("stiffness needs a periodic network (cell is None)")
    if prestress and network.fn is None:
        raise ValueError("prestress=True needs the normal forces fn of the network")


# ---- solvers ---------------------------------------------------------------------------------
_ETA = 1e-12         # relative Tikhonov shift of the factorised matrix  M = H + eta diag(H)
_FLOPPY_TOL = 1e-8   # a pivot below this fraction of its diagonal entry marks a floppy mode


class _SuperLU:
    """scipy SuperLU of M = H + eta diag(H) with diagonal (symmetric) pivoting: its pivots give the
    inertia of M (Sylvester), hence the number of (near-)zero and negative modes of H."""

    name = "splu"

    def __init__(self, M):
        from scipy.sparse.linalg import splu
        self.lu = splu(M, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options=dict(SymmetricMode=True))
        self.symmetric = bool(np.array_equal(self.lu.perm_r, self.lu.perm_c))
        self._M = M

    def pivots(self):
        """(relative pivots, reliable?) - pivots divided by the matching diagonal entry of M."""
        lu = self.lu
        u = lu.U.diagonal()
        # diagonal of Pr M Pc: row perm_r^-1, column perm_c^-1 -> entry M[q_r[k], q_c[k]]
        qr = np.empty_like(lu.perm_r)
        qr[lu.perm_r] = np.arange(qr.size)
        qc = np.empty_like(lu.perm_c)
        qc[lu.perm_c] = np.arange(qc.size)
        dm = np.asarray(self._M[qr, qc]).ravel() if qr.size else np.zeros(0)
        ok = self.symmetric and np.all(dm > 0)
        return u / np.where(dm != 0, dm, 1.0), ok

    def solve(self, b):
        return self.lu.solve(b)


class _Pardiso:
    """Intel MKL PARDISO through pypardiso (optional): real symmetric indefinite LDL^T
    (Bunch-Kaufman) of the upper triangle; its inertia (iparm 22/23) gives the mode counts."""

    name = "pardiso"

    def __init__(self, M):
        import pypardiso
        self._pp = pypardiso
        self.A, self.solver = self._factor(M)

    def _factor(self, M):
        s = self._pp.PyPardisoSolver(mtype=-2)
        s.set_iparm(10, 13)          # pivot perturbation 1e-13 (default 1e-8 would hide the count)
        A = sp.triu(M, format="csr")
        A.sort_indices()
        s.factorize(A)
        return A, s

    def inertia(self, solver=None):
        s = self.solver if solver is None else solver
        return int(s.get_iparm(22)), int(s.get_iparm(23))

    def counts(self, H, d):
        """(n_floppy, n_unstable): eigenvalues of the pencil (H, diag d) in [-eta, tol) and below
        -eta, from the inertia of H - tol diag(d) and of the factorised H + eta diag(d)."""
        _, neg_plus = self.inertia()
        A, s = self._factor((H - sp.diags(_FLOPPY_TOL * d)).tocsc())
        _, neg_minus = self.inertia(s)
        s.free_memory(everything=True)
        return neg_minus - neg_plus, neg_plus

    def solve(self, b):
        return self.solver.solve(self.A, np.asfortranarray(b))


def _make_solver(name, M):
    if name in ("auto", "pardiso"):
        try:
            return _Pardiso(M)
        except Exception as exc:      # noqa: BLE001 - optional dependency
            if name == "pardiso":
                raise RuntimeError(f"pypardiso unavailable or failed: {exc}") from exc
    if name in ("auto", "splu"):
        return _SuperLU(M)
    raise ValueError(f"unknown solver {name!r} (use 'splu', 'pardiso' or 'auto')")


# ---- main entry ------------------------------------------------------------------------------
def stiffness(network, *, prestress=False, min_contacts=None, solver="splu", rtol=1e-13,
              max_refine=50, count="pivots") -> StiffnessResult:
    """Exact linear-response stiffness tensor of a periodic contact network.

    Parameters
    ----------
    network : periodic ContactNetwork.
    prestress : include the geometric stiffness of the normal forces ``fn`` and the pre-stress
        terms of the Cauchy stress increment (needs ``network.fn``).
    min_contacts : rattler threshold (particles with fewer contacts are removed, iteratively);
        None = per particle 2 if it has a contact with kt_eff > 0, else 3.
    solver : ``"splu"`` (scipy SuperLU, default, always available), ``"pardiso"`` (pypardiso),
        ``"auto"`` (pardiso if importable, else splu).
    count : how zero (floppy) modes are counted with splu: ``"pivots"`` (relative pivot of the
        shifted factorisation below 1e-8; one factorisation) or ``"rescale"`` (a second
        factorisation with a 100x smaller shift: a pivot is a zero mode iff it scales with the
        shift - unambiguous when soft modes sit near the threshold).
    rtol : target relative residual of the relaxation solve (iterative refinement on the
        regularised factorisation).
    """
    t0 = time.perf_counter()
    _check(network, prestress)
    asm = assemble(network, prestress=prestress, min_contacts=min_contacts)
    H, F = asm.H, asm.F
    area = network.area
    c_aff = affine_stiffness(network, prestress=prestress)
    sigma0 = stress0(network) if prestress else None
    t_asm = time.perf_counter() - t0

    t1 = time.perf_counter()
    n_floppy = n_unstable = n_ref = 0
    resid = 0.0
    gap = (np.nan, np.nan)
    Q = np.zeros((asm.ndof, 3))
    used = solver
    if asm.ndof > 0:
        d = H.diagonal()
        rown = np.asarray(abs(H).sum(axis=1)).ravel()
        zero = rown <= 1e-300 + 1e-15 * (np.abs(d).max() if d.size else 0.0)
        n_floppy += int(zero.sum())            # dofs with no stiffness at all
        idx = np.flatnonzero(~zero)
        Hr = H[idx][:, idx].tocsc()
        Fr = F[idx]
        dr = np.abs(Hr.diagonal())
        dr = np.where(dr > 0, dr, dr.max() if dr.size else 1.0)
        M = (Hr + sp.diags(_ETA * dr)).tocsc()
        if Hr.shape[0]:
            slv = _make_solver(solver, M)
            used = slv.name
            if isinstance(slv, _SuperLU):
                piv, ok = slv.pivots()
                if not ok:
                    warnings.warn("SuperLU did not pivot symmetrically: mode counts from an "
                                  "eigen-solver fallback", RuntimeWarning, stacklevel=2)
                    nf, nu = _count_modes_eig(Hr, dr)
                else:
                    small = np.abs(piv) < _FLOPPY_TOL
                    if count == "rescale":
                        # a pivot of a zero mode scales with the shift eta, any other does not
                        slv2 = _SuperLU((Hr + sp.diags(1e-2 * _ETA * dr)).tocsc())
                        piv2, ok2 = slv2.pivots()
                        if ok2 and np.array_equal(slv2.lu.perm_c, slv.lu.perm_c):
                            small = (np.abs(piv) < 1e-4) & (np.abs(piv2) < 0.1 * np.abs(piv))
                        del slv2
                    nf = int(small.sum())
                    nu = int(((piv < 0) & ~small).sum())
                    gap = (float(np.abs(piv[small]).max()) if small.any() else 0.0,
                           float(np.abs(piv[~small]).min()) if (~small).any() else np.inf)
            else:
                nf, nu = slv.counts(Hr, dr)
            n_floppy += nf
            n_unstable += nu
            # solve H q = -F by iterated Tikhonov (refinement): exact for every mode whose
            # stiffness >> eta diag; zero modes are not excited (F lies in the range of H)
            Xr = slv.solve(-Fr)
            # residual relative to the contact-level load (the norm of the per-contact affine
            # forces before they cancel in the assembly: an affine load has F ~ round-off)
            fn_ = asm.F_scale if asm.F_scale > 0 else 1.0
            for n_ref in range(1, max_refine + 1):
                R = -Fr - Hr @ Xr
                resid = float((np.linalg.norm(R, axis=0) / fn_).max())
                if resid <= rtol:
                    break
                Xr = Xr + slv.solve(R)
            else:
                R = -Fr - Hr @ Xr
                resid = float((np.linalg.norm(R, axis=0) / fn_).max())
            Q[idx] = Xr
    t_solve = time.perf_counter() - t1
    if n_unstable:
        warnings.warn(f"the Hessian has {n_unstable} negative mode(s): the network is mechanically "
                      "unstable under its pre-stress; the tensor is the stationary response",
                      RuntimeWarning, stacklevel=2)
    if resid > 1e-8:
        warnings.warn(f"relaxation solve did not converge: relative residual {resid:.2e}",
                      RuntimeWarning, stacklevel=2)

    # contact displacements for the three unit strains, energy form of the tensor
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
    scale = max(np.abs(c_aff).max(), 1e-300)
    consistency = float(np.abs(c_str - c_rel).max() / scale)
    if prestress:
        c_rel = c_rel + prestress_correction(sigma0)
    N = network.n_particles
    full = np.zeros((3 * N + 1, 3))
    full[np.flatnonzero(asm.dof_map >= 0)] = Q[asm.dof_map[asm.dof_map >= 0]]
    u_f = np.stack([full[0:2 * N, b].reshape(N, 2) for b in range(3)])
    w_f = np.stack([full[2 * N:3 * N, b] for b in range(3)])
    K_, G_ = isotropic_moduli(c_rel)
    Ka, Ga = isotropic_moduli(c_aff)
    return StiffnessResult(
        C_mandel=c_rel, C_affine_mandel=c_aff, K=K_, G=G_, K_affine=Ka, G_affine=Ga,
        n_rattlers=int(asm.rattlers.sum()), n_floppy=int(n_floppy), n_dof=int(asm.ndof),
        solve_time=t_solve, assembly_time=t_asm, n_particles=network.n_particles,
        n_contacts=asm.net.n_contacts, n_spins=asm.n_spins, n_unstable=int(n_unstable),
        prestress=bool(prestress), solver=used, residual=resid, consistency=consistency,
        n_refine=n_ref, pivot_gap=gap,
        stress0_mandel=None if sigma0 is None else strain_to_mandel(sigma0),
        u=u_f, omega=w_f, rattler_mask=asm.rattlers)


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


def _count_modes_eig(H, d):
    """Fallback count of zero / negative modes of the pencil (H, diag d) by a dense or shift-invert
    eigen-solve (small systems only)."""
    s = 1.0 / np.sqrt(d)
    A = sp.diags(s) @ H @ sp.diags(s)
    if A.shape[0] <= 3000:
        w = np.linalg.eigvalsh(A.toarray())
    else:   # pragma: no cover - large fallback
        from scipy.sparse.linalg import eigsh
        w = eigsh(A, k=min(200, A.shape[0] - 1), sigma=-1e-3, return_eigenvectors=False)
    small = np.abs(w) < _FLOPPY_TOL
    return int(small.sum()), int(((w < 0) & ~small).sum())
