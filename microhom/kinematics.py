"""Per-contact kinematics of a periodic contact network and the sparse Hessian they assemble.

This is the linear algebra the exact stiffness solver (``dem.analysis.stiffness``) and the relaxation
hierarchy (``microhom.hierarchy``) share; it lives on the theory side so that ``microhom`` never
imports ``dem``.

Formulation (2D, tension positive). Contact ``k`` joins ``i`` and ``j``, branch ``c = x_j - x_i``
(periodic image resolved), ``n = c/|c|``, ``t = (-n_y, n_x)``, spin arms ``a_i = |c| r_i/(r_i+r_j)``,
``a_j = |c| r_j/(r_i+r_j)`` (``spin_arm="contact"``, the default: spins turn the material point
at the contact point) or ``a_i = r_i``, ``a_j = r_j`` (``spin_arm="radius"``: the surface point of
each disk on the line of centres, as LAMMPS ``gran/*`` and the disk engine's default law). The two
agree for touching disks (``|c| = r_i + r_j``) and differ by the relative overlap otherwise. Under a homogeneous strain ``E`` of the cell plus periodic
fluctuations ``u`` (translations) and ``omega`` (spins) the relative displacement of the contact
point of ``j`` with respect to that of ``i`` is::

    Delta = u_j - u_i + E c - (a_i omega_i + a_j omega_j) t          (omega x r = omega (-r_y, r_x))
          = B q + D eps,

with ``q = (u_i, omega_i, u_j, omega_j)`` the six local unknowns, ``B`` (C, 2, 6) the
compatibility matrix and ``D`` (C, 2, 3) the affine displacement ``E c`` per Mandel unit strain
``eps = [E11, E22, sqrt2 E12]``. The contact force increment is ``f = K Delta`` with
``K = kn n n + kt_eff (I - n n)`` (paper eq. 35; ``kt_eff = 0`` on sliding contacts). The energy
``W = 1/2 sum Delta.K.Delta`` is minimised over ``q``::

    H q = -F eps,   H = sum_c B_c^T K_c B_c,   F = sum_c B_c^T K_c D_c,
    C = C_aff - (1/A) F^T H^+ F,   C_aff = (1/A) sum_c D_c^T K_c D_c.

With pre-stress, the normal forces ``fn`` (compression positive) add the geometric stiffness
``K_g = -(fn/|c|) (I - n n)`` acting on the centre-to-centre displacement (``B`` without its spin
columns), and the Cauchy stress increment gains ``prestress_correction(sigma0)``
(``microhom.tensors``).

Spheres with tangential forces (3D, pre-stress, ``ft`` not zero): the tangential force is a spring
on the history ``s`` (``ft = -kt s`` on ``j``) updated as LAMMPS's ``gran/hooke/history`` does,
``ds/dt = P (dDelta/dt) - (s . dn/dt) n`` (the history increment projected on the turning tangent
plane, no turn about the normal; ``docs/spheres.md``, "Tangential forces under pre-stress"). Its
rate on the centre displacement ``c' = Bc q' + D eps'`` adds the force ``-G_t c'``,
``G_t = n ft^T / |c|``, and the torques of the turning and stretching arms,
``-X_i c'``, ``X_i = -a_i [ft]x (I - n n)/|c| + kappa_i (n x ft) n^T`` (``kappa_i = r_i/(r_i + r_j)``
for the contact arm, 0 for the radius arm). These terms are not symmetric: they are assembled
apart (``Assembly.Hn``, ``Assembly.Fn``), and ``H`` keeps its meaning (the symmetric Hessian of
the normal pre-stress) for the relaxation hierarchy, which leaves them out.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .network import ContactNetwork
from .structural_sums import rattlers

#: Accepted ``spin_arm`` values (see the module docstring).
SPIN_ARMS = ("contact", "radius")

__all__ = ["SPIN_ARMS", "ContactMatrices", "Assembly", "contact_matrices", "contact_forces",
           "rotational_dofs", "assemble", "stress0", "skew_stress_correction",
           "affine_tensor", "sparse_rows", "block_diag"]

_SQ2 = np.sqrt(2.0)
#: Mandel components per dimension (``microhom.tensors``): 2D [11, 22, 12]; 3D [11, 22, 33, 23, 13, 12]
_MANDEL = {2: ((0, 0), (1, 1), (0, 1)), 3: ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))}


def rotational_dofs(dim: int) -> int:
    """Rotational unknowns per particle: 1 spin for a disk (2D), 3 for a sphere (3D)."""
    return 1 if dim == 2 else 3


def _cross_matrix(n):
    """(C, 3, 3) matrices ``[n]x`` with ``[n]x w = n x w``."""
    z = np.zeros(n.shape[0])
    return np.stack([np.stack([z, -n[:, 2], n[:, 1]], axis=1),
                     np.stack([n[:, 2], z, -n[:, 0]], axis=1),
                     np.stack([-n[:, 1], n[:, 0], z], axis=1)], axis=1)


@dataclass(frozen=True, eq=False)
class ContactMatrices:
    """Element matrices of every contact of a network (see the module docstring).

    ``d`` is the dimension, ``r`` the rotational unknowns per particle (1 in 2D, 3 in 3D) and
    ``m`` the Mandel strain components (3 in 2D, 6 in 3D).

    Attributes
    ----------
    B : (C, d, 2(d + r)) array
        Compatibility on the local unknowns ``(u_i, omega_i, u_j, omega_j)`` [m for the rotation
        columns, 1 for translations]: (C, 2, 6) in 2D, (C, 3, 12) in 3D.
    D : (C, d, m) array
        Affine contact displacement per Mandel unit strain [m].
    K : (C, d, d) array
        Contact stiffness tensors ``kn n n + kt_eff (I - n n)`` [N/m].
    Kg : (C, d, d) array or None
        Geometric stiffness ``-(fn/|c|)(I - n n)`` [N/m], or None without pre-stress.
    Gt : (C, 3, 3) array or None
        Geometric force rate of the tangential force on the centre displacement,
        ``n ft^T/|c|`` [N/m] (the force rate on ``j`` gains ``-Gt c'``); 3D with pre-stress and a
        non-zero ``ft`` only, else None.
    Xt : (C, 2, 3, 3) array or None
        The torque rates of the tangential force's turning and stretching arms on the centre
        displacement, for ``i`` and ``j`` [N] (the torque rates gain ``-Xt c'``); with ``Gt``.
    """

    B: np.ndarray
    D: np.ndarray
    K: np.ndarray
    Kg: np.ndarray | None
    Gt: np.ndarray | None = None
    Xt: np.ndarray | None = None


def _check_spin_arm(spin_arm):
    if spin_arm not in SPIN_ARMS:
        raise ValueError(f"spin_arm must be one of {SPIN_ARMS} ('contact': the distance to the "
                         f"contact point, 'radius': the radius, as LAMMPS), got {spin_arm!r}")


def contact_matrices(net: ContactNetwork, prestress: bool = False,
                     spin_arm: str = "contact") -> ContactMatrices:
    """Per-contact ``B`` (C, d, 2(d + r)), ``D`` (C, d, m) [m], ``K`` (C, d, d) [N/m] (and
    ``K_g`` (C, d, d) [N/m] if ``prestress``) of ``net`` (see :class:`ContactMatrices`);
    ``spin_arm`` ``"contact"`` or ``"radius"`` (module docstring)."""
    _check_spin_arm(spin_arm)
    if prestress and net.fn is None:
        raise ValueError("prestress=True needs the normal forces fn of the network "
                         "(ContactNetwork.fn, compression positive, N/m)")
    dim = net.dim
    rot = rotational_dofs(dim)
    c = net.branch
    L = net.lengths
    n = c / L[:, None]
    ri, rj = net.radii[net.pairs[:, 0]], net.radii[net.pairs[:, 1]]
    if spin_arm == "radius":
        ai, aj = ri, rj
    else:
        ai, aj = L * ri / (ri + rj), L * rj / (ri + rj)
    kt = net.effective_kt
    nn = n[:, :, None] * n[:, None, :]
    eye = np.eye(dim)
    K = (net.kn - kt)[:, None, None] * nn + kt[:, None, None] * eye
    nc = c.shape[0]
    B = np.zeros((nc, dim, 2 * (dim + rot)))
    ui, wi, uj, wj = 0, dim, dim + rot, 2 * dim + rot          # first column of each block
    B[:, :, ui:ui + dim] = -eye
    B[:, :, uj:uj + dim] = eye
    if dim == 2:                 # Delta gains -(a_i w_i + a_j w_j) t  (w x n = w t in the plane)
        t = np.stack([-n[:, 1], n[:, 0]], axis=1)
        B[:, :, wi] = -ai[:, None] * t
        B[:, :, wj] = -aj[:, None] * t
    else:                        # Delta gains -(a_i w_i + a_j w_j) x n = a_i n x w_i + a_j n x w_j
        nx = _cross_matrix(n)
        B[:, :, wi:wi + 3] = ai[:, None, None] * nx
        B[:, :, wj:wj + 3] = aj[:, None, None] * nx
    D = np.zeros((nc, dim, len(_MANDEL[dim])))   # E c for Mandel unit strains
    for a, (p, q) in enumerate(_MANDEL[dim]):
        if p == q:
            D[:, p, a] = c[:, p]
        else:                    # E_pq = E_qp = 1/sqrt2
            D[:, p, a] = c[:, q] / _SQ2
            D[:, q, a] = c[:, p] / _SQ2
    Kg = Gt = Xt = None
    if prestress:
        Kg = (-(net.fn / L))[:, None, None] * (eye - nn)
        if dim == 3 and net.ft is not None and np.any(net.ft != 0):
            Gt, Xt = _tangential_geometric(net.ft, n, L, (ai, aj), ri / (ri + rj), spin_arm)
    return ContactMatrices(B=B, D=D, K=K, Kg=Kg, Gt=Gt, Xt=Xt)


def _tangential_geometric(ft, n, L, arms, wi, spin_arm):
    """``(Gt, Xt)`` of :class:`ContactMatrices` for tangential forces ``ft`` (C, 3) on ``j``
    (docs/spheres.md, "Tangential forces under pre-stress"). Force on ``j``
    ``f = fn n + ft``, torques ``T_i = -a_i n x ft``, ``T_j = -a_j n x ft``; under LAMMPS's history
    law ``d ft/dt = -kt P dDelta/dt - (ft . dn/dt) n`` with ``dn/dt = P c'/|c|``, the rates not in
    ``K`` and ``K_g`` are ``-n (ft . c')/|c|`` (force) and, per arm,
    ``-a dn/dt x ft - (da/dt) n x ft`` (torque; ``da/dt = w n . c'`` for the contact arm)."""
    P = np.eye(3) - n[:, :, None] * n[:, None, :]
    Gt = n[:, :, None] * ft[:, None, :] / L[:, None, None]
    fxP = _cross_matrix(ft) @ P / L[:, None, None]                # [ft]x P / |c|
    nxf = np.cross(n, ft)
    Xt = np.empty((n.shape[0], 2, 3, 3))
    for k, (a, w) in enumerate(zip(arms, (wi, 1.0 - wi))):
        Xt[:, k] = -a[:, None, None] * fxP
        if spin_arm == "contact":                                  # the arm a = w |c| stretches
            Xt[:, k] += w[:, None, None] * nxf[:, :, None] * n[:, None, :]
    return Gt, Xt


def contact_forces(net: ContactNetwork) -> np.ndarray:
    """(C, d) force on ``j`` of every contact, ``fn n + ft`` [N] (``ft t`` in 2D): the forces of
    the pre-stress. Needs ``net.fn``."""
    if net.fn is None:
        raise ValueError("the pre-stress needs the normal forces fn of the network")
    n = net.normals
    f = net.fn[:, None] * n
    if net.ft is not None:
        if net.dim == 2:
            f = f + net.ft[:, None] * np.stack([-n[:, 1], n[:, 0]], axis=1)
        else:
            f = f + net.ft
    return f


def stress0(net: ContactNetwork) -> np.ndarray:
    """(d, d) pre-stress ``sigma0 = -(1/V) sum sym((fn n + ft t) (x) c)`` [N/m in 2D, Pa in 3D,
    tension positive] (3D: ``ft`` is the tangential force vector)."""
    f = contact_forces(net)
    s = -(f[:, :, None] * net.branch[:, None, :]).sum(axis=0) / net.volume
    return 0.5 * (s + s.T)


def skew_stress_correction(net: ContactNetwork) -> np.ndarray:
    """(6, 6) Mandel matrix of ``dE -> (dE A - A dE)/2`` with ``A = -(P - P^T)/2``,
    ``P = (1/V) sum c f^T`` [Pa]: what the rate of the Cauchy stress ``-sym(P)`` gains over
    ``tensors.prestress_correction(stress0)`` when ``P`` is not symmetric (spheres whose torques
    balance with arms other than ``|c|/2``-splits of the branch, e.g. LAMMPS's radius arm:
    ``P - P^T = -(1/V) sum overlap (n ft^T - ft n^T)``). Zero when ``P`` is symmetric."""
    f = contact_forces(net)
    P = (net.branch[:, :, None] * f[:, None, :]).sum(axis=0) / net.volume
    A = -0.5 * (P - P.T)
    m = np.empty((6, 6))
    for b in range(6):
        e = np.zeros((3, 3))
        p, q = _MANDEL[3][b]
        e[p, q] = e[q, p] = 1.0 if p == q else 1.0 / _SQ2
        d = 0.5 * (e @ A - A @ e)
        m[:, b] = [d[a, c] * (1.0 if a == c else _SQ2) for a, c in _MANDEL[3]]
    return m


def affine_tensor(net: ContactNetwork, prestress: bool = False, tangential: bool = False,
                  spin_arm: str = "contact") -> np.ndarray:
    """(m, m) Mandel affine stiffness ``(1/V) sum D^T (K + K_g) D`` [N/m in 2D, Pa in 3D], without
    the pre-stress correction of the Cauchy increment (add ``tensors.prestress_correction``).
    ``tangential``: with ``prestress`` on spheres, add the tangential forces' term
    ``D^T G_t D`` (:class:`ContactMatrices`; not symmetric); ``spin_arm`` only matters there."""
    m = contact_matrices(net, prestress, spin_arm)
    KK = m.K if m.Kg is None else m.K + m.Kg
    if tangential and m.Gt is not None:
        KK = KK + m.Gt
    nm = m.D.shape[2]
    return m.D.reshape(-1, nm).T @ (KK @ m.D).reshape(-1, nm) / net.volume


def sparse_rows(B, ldof, ndof):
    """(C, d, l) element rows on local unknowns -> CSR (d C, ndof); unknowns < 0 are dropped."""
    nc, dim, nl = B.shape
    r = np.repeat(np.arange(dim * nc), nl)
    c = np.broadcast_to(ldof[:, None, :], (nc, dim, nl)).ravel()
    m = c >= 0
    return sp.csr_matrix((B.ravel()[m], (r[m], c[m])), shape=(dim * nc, ndof))


def block_diag(K):
    """(C, d, d) -> block-diagonal CSR (d C, d C)."""
    nc, dim = K.shape[0], K.shape[1]
    ind = np.arange(dim * nc).reshape(nc, dim)
    r = np.broadcast_to(ind[:, :, None], (nc, dim, dim)).ravel()
    c = np.broadcast_to(ind[:, None, :], (nc, dim, dim)).ravel()
    return sp.csr_matrix((K.ravel(), (r, c)), shape=(dim * nc, dim * nc))


@dataclass(frozen=True, eq=False)
class Assembly:
    """The reduced linear-response problem ``H q = -F eps`` of a periodic network.

    Unknowns (d = 2 or 3, r = 1 spin per disk or 3 rotations per sphere): translations of
    non-rattlers (``d p .. d p + d - 1`` in the full numbering), rotations ``d N + r p ..`` of
    particles with a contact of ``kt_eff > 0``; the best-connected particle's translation is pinned
    (removes the d global translations). In 2D the numbering is ``2p, 2p+1`` and ``2N + p``.

    H : (ndof, ndof) CSC Hessian [N/m]; F : (ndof, m) load per Mandel unit strain [N/m * m];
    F_scale : norm of the per-contact element loads before they cancel in the assembly;
    Bs : (dC, ndof) CSR compatibility; Ks : (dC, dC) block-diagonal contact stiffness;
    Bcs, Kgs : the same for the geometric (pre-stress) term, or None; Df : (dC, m) affine
    displacements; matrices : per-contact :class:`ContactMatrices`; ldof : (C, 2(d + r))
    local-to-reduced map (-1 = fixed or absent); net : the network without rattlers' contacts;
    rattlers : (N,) bool; n_spins : particles whose rotations are unknowns; pinned : pinned
    particle or -1; ndof : number of unknowns; dof_map : ((d + r) N,) full-to-reduced map
    (-1 = not an unknown). Spheres with tangential forces under pre-stress (else None):
    Hn : (ndof, ndof) CSC, the non-symmetric rate terms of the tangential forces [N/m] (the tangent
    of the equilibrium is ``H + Hn``); Fn : (ndof, m) their load [N/m * m]; Gts : (3C, 3C)
    block-diagonal ``G_t`` [N/m] (the stress rate gains ``D^T G_t c'``); Ns : (ndof, 3C)
    ``Bc^T G_t + X_t`` on the centre displacements (``Hn = Ns Bc``, ``Fn = Ns Df``).
    """

    H: sp.csc_matrix
    F: np.ndarray
    F_scale: float
    Bs: sp.csr_matrix
    Ks: sp.csr_matrix
    Bcs: sp.csr_matrix | None
    Kgs: sp.csr_matrix | None
    Df: np.ndarray
    matrices: ContactMatrices
    ldof: np.ndarray
    net: ContactNetwork
    rattlers: np.ndarray
    n_spins: int
    pinned: int
    ndof: int
    dof_map: np.ndarray
    Hn: sp.csc_matrix | None = None
    Fn: np.ndarray | None = None
    Gts: sp.csr_matrix | None = None
    Ns: sp.csr_matrix | None = None


def assemble(network: ContactNetwork, *, prestress: bool = False, min_contacts=None,
             pin: bool = True, spin_arm: str = "contact") -> Assembly:
    """Assemble the reduced Hessian ``H`` (ndof, ndof) [N/m] and load ``F`` (ndof, 3) of a periodic
    network (rattlers removed iteratively with :func:`microhom.structural_sums.rattlers`); see
    :class:`Assembly`. ``pin=False`` keeps every translation (``H`` then has the d global
    translations as null vectors, orthogonal to ``F``: what an iterative solver wants, since
    pinning one particle breaks the cell's symmetry). ``spin_arm``: ``"contact"`` (default) or
    ``"radius"`` (the module docstring)."""
    _check_spin_arm(spin_arm)
    if network.cell is None:
        raise ValueError("the stiffness problem needs a periodic network (cell is None)")
    N = network.n_particles
    dim = network.dim
    rot = rotational_dofs(dim)
    ratt, keep_c = rattlers(network, min_contacts)
    net = network.select_contacts(keep_c)
    m = contact_matrices(net, prestress, spin_arm)
    i, j = net.pairs[:, 0], net.pairs[:, 1]
    nc = i.shape[0]

    # which unknowns exist: translations of non-rattlers, spins of particles with a kt_eff > 0 contact
    has_t = ~ratt & (np.bincount(net.pairs.ravel(), minlength=N) > 0)
    fric = (net.effective_kt > 0).astype(np.int64)
    has_s = (np.bincount(i, weights=fric, minlength=N) + np.bincount(j, weights=fric, minlength=N)) > 0
    active = np.zeros((dim + rot) * N, dtype=bool)
    for a in range(dim):
        active[a:dim * N:dim] = has_t
    for b in range(rot):
        active[dim * N + b::rot] = has_s & has_t
    pinned = -1
    if pin and has_t.any():    # pin the global translation: the best-connected particle's u
        cnt = np.bincount(net.pairs.ravel(), minlength=N)
        pinned = int(np.argmax(np.where(has_t, cnt, -1)))
        active[dim * pinned:dim * pinned + dim] = False
    dof = np.full((dim + rot) * N, -1, dtype=np.int64)
    dof[active] = np.arange(int(active.sum()))
    ndof = int(active.sum())
    gl = np.stack([dim * i + a for a in range(dim)] + [dim * N + rot * i + b for b in range(rot)]
                  + [dim * j + a for a in range(dim)] + [dim * N + rot * j + b for b in range(rot)],
                  axis=1)
    ldof = dof[gl]                                              # (C, 2(d + r)), -1 = fixed/absent

    Bs = sparse_rows(m.B, ldof, ndof)
    Ks = block_diag(m.K)
    H = (Bs.T @ (Ks @ Bs)).tocsc()
    Df = m.D.reshape(-1, m.D.shape[2])
    KDf = Ks @ Df
    F = np.asarray(Bs.T @ KDf)
    # load scale: norm of the per-contact element loads before they cancel in the assembly
    rown2 = np.asarray(Bs.multiply(Bs).sum(axis=1)).ravel()
    F_scale = float(np.sqrt(rown2 @ (KDf ** 2)).max()) if nc else 0.0
    Bcs = Kgs = None
    if m.Kg is not None:
        Bc = m.B.copy()                     # centre-to-centre displacement: no rotation columns
        Bc[:, :, dim:dim + rot] = 0.0
        Bc[:, :, 2 * dim + rot:] = 0.0
        Bcs = sparse_rows(Bc, ldof, ndof)
        Kgs = block_diag(m.Kg)
        H = (H + Bcs.T @ (Kgs @ Bcs)).tocsc()
        F = F + np.asarray(Bcs.T @ (Kgs @ Df))
    H.sum_duplicates()
    tang = {}
    if m.Gt is not None:                    # spheres: the tangential forces' rate terms
        Gts = block_diag(m.Gt)
        X = np.zeros((nc, 2 * (dim + rot), dim))               # torque rows only
        X[:, dim:dim + rot] = m.Xt[:, 0]
        X[:, 2 * dim + rot:] = m.Xt[:, 1]
        Ns = (Bcs.T @ Gts + sparse_rows(np.swapaxes(X, 1, 2), ldof, ndof).T).tocsr()
        Hn = (Ns @ Bcs).tocsc()
        Hn.sum_duplicates()
        tang = dict(Hn=Hn, Fn=np.asarray(Ns @ Df), Gts=Gts, Ns=Ns)
    return Assembly(H=H, F=F, F_scale=F_scale, Bs=Bs, Ks=Ks, Bcs=Bcs, Kgs=Kgs, Df=Df, matrices=m,
                    ldof=ldof, net=net, rattlers=ratt, n_spins=int((has_s & has_t).sum()),
                    pinned=pinned, ndof=ndof, dof_map=dof, **tang)
