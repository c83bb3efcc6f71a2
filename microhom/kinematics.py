"""Per-contact kinematics of a periodic contact network and the sparse Hessian they assemble.

This is the linear algebra the exact stiffness solver (``dem.stiffness``) and the relaxation
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
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .network import ContactNetwork
from .structural_sums import rattlers

#: Accepted ``spin_arm`` values (see the module docstring).
SPIN_ARMS = ("contact", "radius")

__all__ = ["SPIN_ARMS", "ContactMatrices", "Assembly", "contact_matrices", "assemble", "stress0",
           "affine_tensor", "sparse_rows", "block_diag"]

_SQ2 = np.sqrt(2.0)


@dataclass(frozen=True, eq=False)
class ContactMatrices:
    """Element matrices of every contact of a network (see the module docstring).

    Attributes
    ----------
    B : (C, 2, 6) array
        Compatibility on the local unknowns ``(u_i[2], omega_i, u_j[2], omega_j)`` [m for the spin
        columns, 1 for translations].
    D : (C, 2, 3) array
        Affine contact displacement per Mandel unit strain [m].
    K : (C, 2, 2) array
        Contact stiffness tensors ``kn n n + kt_eff (I - n n)`` [N/m].
    Kg : (C, 2, 2) array or None
        Geometric stiffness ``-(fn/|c|)(I - n n)`` [N/m], or None without pre-stress.
    """

    B: np.ndarray
    D: np.ndarray
    K: np.ndarray
    Kg: np.ndarray | None


def _check_spin_arm(spin_arm):
    if spin_arm not in SPIN_ARMS:
        raise ValueError(f"spin_arm must be one of {SPIN_ARMS} ('contact': the distance to the "
                         f"contact point, 'radius': the radius, as LAMMPS), got {spin_arm!r}")


def contact_matrices(net: ContactNetwork, prestress: bool = False,
                     spin_arm: str = "contact") -> ContactMatrices:
    """Per-contact ``B`` (C, 2, 6), ``D`` (C, 2, 3) [m], ``K`` (C, 2, 2) [N/m] (and ``K_g``
    (C, 2, 2) [N/m] if ``prestress``) of ``net`` (see :class:`ContactMatrices`); ``spin_arm``
    ``"contact"`` or ``"radius"`` (module docstring)."""
    _check_spin_arm(spin_arm)
    if prestress and net.fn is None:
        raise ValueError("prestress=True needs the normal forces fn of the network "
                         "(ContactNetwork.fn, compression positive, N/m)")
    c = net.branch
    L = net.lengths
    n = c / L[:, None]
    t = np.stack([-n[:, 1], n[:, 0]], axis=1)
    ri, rj = net.radii[net.pairs[:, 0]], net.radii[net.pairs[:, 1]]
    if spin_arm == "radius":
        ai, aj = ri, rj
    else:
        ai, aj = L * ri / (ri + rj), L * rj / (ri + rj)
    kt = net.effective_kt
    nn = n[:, :, None] * n[:, None, :]
    eye = np.eye(2)
    K = (net.kn - kt)[:, None, None] * nn + kt[:, None, None] * eye
    nc = c.shape[0]
    B = np.zeros((nc, 2, 6))
    B[:, 0, 0] = B[:, 1, 1] = -1.0
    B[:, 0, 3] = B[:, 1, 4] = 1.0
    B[:, :, 2] = -ai[:, None] * t
    B[:, :, 5] = -aj[:, None] * t
    D = np.zeros((nc, 2, 3))              # E c for Mandel unit strains [E11, E22, sqrt2 E12]
    D[:, 0, 0] = c[:, 0]
    D[:, 1, 1] = c[:, 1]
    D[:, 0, 2] = c[:, 1] / _SQ2
    D[:, 1, 2] = c[:, 0] / _SQ2
    Kg = None
    if prestress:
        Kg = (-(net.fn / L))[:, None, None] * (eye - nn)
    return ContactMatrices(B=B, D=D, K=K, Kg=Kg)


def stress0(net: ContactNetwork) -> np.ndarray:
    """(2, 2) pre-stress ``sigma0 = -(1/A) sum sym((fn n + ft t) (x) c)`` [N/m, tension positive]."""
    if net.fn is None:
        raise ValueError("the pre-stress needs the normal forces fn of the network")
    n = net.normals
    f = net.fn[:, None] * n
    if net.ft is not None:
        f = f + net.ft[:, None] * np.stack([-n[:, 1], n[:, 0]], axis=1)
    s = -(f[:, :, None] * net.branch[:, None, :]).sum(axis=0) / net.area
    return 0.5 * (s + s.T)


def affine_tensor(net: ContactNetwork, prestress: bool = False) -> np.ndarray:
    """(3, 3) Mandel affine stiffness ``(1/A) sum D^T (K + K_g) D`` [N/m], without the
    pre-stress correction of the Cauchy increment (add ``tensors.prestress_correction``)."""
    m = contact_matrices(net, prestress)
    KK = m.K if m.Kg is None else m.K + m.Kg
    return m.D.reshape(-1, 3).T @ (KK @ m.D).reshape(-1, 3) / net.area


def sparse_rows(B, ldof, ndof):
    """(C, 2, 6) element rows on local unknowns -> CSR (2C, ndof); unknowns < 0 are dropped."""
    nc = B.shape[0]
    r = np.repeat(np.arange(2 * nc), 6)
    c = np.broadcast_to(ldof[:, None, :], (nc, 2, 6)).ravel()
    m = c >= 0
    return sp.csr_matrix((B.ravel()[m], (r[m], c[m])), shape=(2 * nc, ndof))


def block_diag(K):
    """(C, 2, 2) -> block-diagonal CSR (2C, 2C)."""
    nc = K.shape[0]
    ind = np.arange(2 * nc).reshape(nc, 2)
    r = np.broadcast_to(ind[:, :, None], (nc, 2, 2)).ravel()
    c = np.broadcast_to(ind[:, None, :], (nc, 2, 2)).ravel()
    return sp.csr_matrix((K.ravel(), (r, c)), shape=(2 * nc, 2 * nc))


@dataclass(frozen=True, eq=False)
class Assembly:
    """The reduced linear-response problem ``H q = -F eps`` of a periodic network.

    Unknowns: translations of non-rattlers (``2p, 2p+1`` in the full numbering), spins ``2N + p``
    of particles with a contact of ``kt_eff > 0``; the best-connected particle's translation is
    pinned (removes the two global translations).

    H : (ndof, ndof) CSC Hessian [N/m]; F : (ndof, 3) load per Mandel unit strain [N/m * m];
    F_scale : norm of the per-contact element loads before they cancel in the assembly;
    Bs : (2C, ndof) CSR compatibility; Ks : (2C, 2C) block-diagonal contact stiffness;
    Bcs, Kgs : the same for the geometric (pre-stress) term, or None; Df : (2C, 3) affine
    displacements; matrices : per-contact :class:`ContactMatrices`; ldof : (C, 6) local-to-reduced
    map (-1 = fixed or absent); net : the network without rattlers' contacts; rattlers : (N,) bool;
    n_spins : spin unknowns kept; pinned : pinned particle or -1; ndof : number of unknowns;
    dof_map : (3N,) full-to-reduced map (-1 = not an unknown).
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


def assemble(network: ContactNetwork, *, prestress: bool = False, min_contacts=None,
             pin: bool = True, spin_arm: str = "contact") -> Assembly:
    """Assemble the reduced Hessian ``H`` (ndof, ndof) [N/m] and load ``F`` (ndof, 3) of a periodic
    network (rattlers removed iteratively with :func:`microhom.structural_sums.rattlers`); see
    :class:`Assembly`. ``pin=False`` keeps every translation (``H`` then has the two global
    translations as null vectors, orthogonal to ``F``: what an iterative solver wants, since
    pinning one particle breaks the cell's symmetry). ``spin_arm``: ``"contact"`` (default) or
    ``"radius"`` (the module docstring)."""
    _check_spin_arm(spin_arm)
    if network.cell is None:
        raise ValueError("the stiffness problem needs a periodic network (cell is None)")
    N = network.n_particles
    ratt, keep_c = rattlers(network, min_contacts)
    net = network.select_contacts(keep_c)
    m = contact_matrices(net, prestress, spin_arm)
    i, j = net.pairs[:, 0], net.pairs[:, 1]
    nc = i.shape[0]

    # which unknowns exist: translations of non-rattlers, spins of particles with a kt_eff > 0 contact
    has_t = ~ratt & (np.bincount(net.pairs.ravel(), minlength=N) > 0)
    fric = (net.effective_kt > 0).astype(np.int64)
    has_s = (np.bincount(i, weights=fric, minlength=N) + np.bincount(j, weights=fric, minlength=N)) > 0
    active = np.zeros(3 * N, dtype=bool)
    active[0:2 * N:2] = has_t
    active[1:2 * N:2] = has_t
    active[2 * N:] = has_s & has_t
    pinned = -1
    if pin and has_t.any():    # pin the global translation: the best-connected particle's u
        cnt = np.bincount(net.pairs.ravel(), minlength=N)
        pinned = int(np.argmax(np.where(has_t, cnt, -1)))
        active[2 * pinned] = active[2 * pinned + 1] = False
    dof = np.full(3 * N, -1, dtype=np.int64)
    dof[active] = np.arange(int(active.sum()))
    ndof = int(active.sum())
    gl = np.stack([2 * i, 2 * i + 1, 2 * N + i, 2 * j, 2 * j + 1, 2 * N + j], axis=1)
    ldof = dof[gl]                                              # (C, 6), -1 = fixed/absent

    Bs = sparse_rows(m.B, ldof, ndof)
    Ks = block_diag(m.K)
    H = (Bs.T @ (Ks @ Bs)).tocsc()
    Df = m.D.reshape(-1, 3)
    KDf = Ks @ Df
    F = np.asarray(Bs.T @ KDf)
    # load scale: norm of the per-contact element loads before they cancel in the assembly
    rown2 = np.asarray(Bs.multiply(Bs).sum(axis=1)).ravel()
    F_scale = float(np.sqrt(rown2 @ (KDf ** 2)).max()) if nc else 0.0
    Bcs = Kgs = None
    if m.Kg is not None:
        Bc = m.B.copy()
        Bc[:, :, 2] = Bc[:, :, 5] = 0.0
        Bcs = sparse_rows(Bc, ldof, ndof)
        Kgs = block_diag(m.Kg)
        H = (H + Bcs.T @ (Kgs @ Bcs)).tocsc()
        F = F + np.asarray(Bcs.T @ (Kgs @ Df))
    H.sum_duplicates()
    return Assembly(H=H, F=F, F_scale=F_scale, Bs=Bs, Ks=Ks, Bcs=Bcs, Kgs=Kgs, Df=Df, matrices=m,
                    ldof=ldof, net=net, rattlers=ratt, n_spins=int((has_s & has_t).sum()),
                    pinned=pinned, ndof=ndof, dof_map=dof)
