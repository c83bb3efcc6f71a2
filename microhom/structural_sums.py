"""Structural sums (10), spin elimination (15)-(16) and the statistics the theory needs.

Everything is computed from a :class:`~microhom.network.ContactNetwork`, vectorised with
``numpy.bincount`` (10^5 particles in a fraction of a second). For particle mu and each of its
contacts nu, ``c = x^nu - x^mu`` is the branch vector *seen from mu* (so the two ends of a contact
see opposite branch vectors) and ``K = kn n n + kt_eff (I - n n)`` (35), ``kt_eff = 0`` if sliding.

Per particle (arrays with the particle index first):

* ``A2[mu, p, q]       = sum K_pq``                    (10)
* ``A3[mu, p, q, r]    = sum K_pq c_r``                (10) odd: one-sidedness of the contacts
* ``A4[mu, p, q, r, s] = sum K_pq c_r c_s``            (10)
* ``B[mu] = eps_3qr eps_ij3 A_rijq``                   (15) (2D: the spin is out of plane)
* ``Z[mu, p, k, s, t]``                                (16) local stiffness after spin elimination
* ``W[mu] = (1/pi) sum_nu n^{mu nu}``                  odd part of mu's contact density, so that
  the model (43) ``A_ijk = pi D W_p [...]`` is exact for a particle with first-harmonic density
* ``V[mu] = (1/pi) sum_nu Nc^nu n^{mu nu}``            odd angular distribution of the contact
  numbers of mu's neighbours (41). ``ParticleSums.V`` sums over the contacting neighbours;
  :func:`neighbour_vector` over any neighbour set, e.g. the paper's N̄ near neighbours of (39)
  (:func:`microhom.neighbourhood.near_neighbours`); ``network_statistics(rho_neighbours=...)``
  chooses (default ``"near"``, the paper's definition; ``"contacts"`` is the option), and
  :func:`rho_definitions` compares both with a shuffled-Nc null model.

The choices for V and W are explained in docs/theory.md §7, the measurements in docs/results/rho.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .neighbourhood import PHI_MAX, PHI_MIN_NBAR, near_neighbours, nbar_from_phi, nbar_or_substitute
from .network import ContactNetwork
from .results import Result

__all__ = ["particle_sums", "ParticleSums", "rattlers", "network_statistics", "NetworkStatistics",
           "sphere_statistics", "SphereStatistics", "fabric_affine_tensor", "NOT_IN_3D",
           "isotropic_fit", "neighbour_vector", "rho_statistic", "rho_definitions", "RhoDefinitions",
           "RHO_NEIGHBOURS", "bond_order", "BondOrder"]

RHO_NEIGHBOURS = ("contacts", "near")  # the neighbourhoods V can be summed over (see neighbour_vector)

_EPS2 = np.array([[0.0, 1.0], [-1.0, 0.0]])  # 2D Levi-Civita eps_ij3


def _scatter(n, pairs, val_i, val_j):
    """Per-particle sums of per-contact values: val_i goes to pairs[:,0], val_j to pairs[:,1].

    val_i, val_j: (C, ...) arrays of the same trailing shape. Returns (n, ...).
    """
    tail = val_i.shape[1:]
    m = int(np.prod(tail)) if tail else 1
    vi = val_i.reshape(len(val_i), m)
    vj = val_j.reshape(len(val_j), m)
    out = np.empty((n, m))
    idx = np.concatenate([pairs[:, 0], pairs[:, 1]])
    both = np.concatenate([vi, vj], axis=0)
    for k in range(m):
        out[:, k] = np.bincount(idx, weights=both[:, k], minlength=n)
    return out.reshape((n,) + tail)


class ParticleSums:
    """Per-particle structural sums of a network (see the module docstring for definitions).

    ``active``: optional (C,) bool mask of the contacts to use (e.g. without rattlers). With N
    particles, the attributes are ``network`` (the network restricted to the active contacts),
    ``counts`` (N,) contact numbers, ``A2`` (N, 2, 2) ``sum K`` [N/m], ``A3`` (N, 2, 2, 2)
    ``sum K c`` [N], ``A4`` (N, 2, 2, 2, 2) ``sum K c c`` [N m] (indices: stiffness, stiffness,
    branch, branch), ``W`` (N, 2) ``(1/pi) sum n`` and ``V`` (N, 2) :func:`neighbour_vector` over
    the contacts (both dimensionless); :attr:`B` and :attr:`Z` are the spin elimination (15)-(16).
    """

    def __init__(self, network: ContactNetwork, active=None):
        """active: optional (C,) bool mask of the contacts to use (e.g. without rattlers)."""
        net = network if active is None else network.select_contacts(active)
        n = net.n_particles
        self.network = net
        K = net.stiffness_tensors()  # (C,2,2)
        c = net.branch  # from i to j: seen from i it is c, seen from j it is -c
        Kc = K[:, :, :, None] * c[:, None, None, :]
        Kcc = Kc[..., None] * c[:, None, None, None, :]
        self.counts = net.contact_counts()
        self.A2 = _scatter(n, net.pairs, K, K)
        self.A3 = _scatter(n, net.pairs, Kc, -Kc)
        self.A4 = _scatter(n, net.pairs, Kcc, Kcc)
        nrm = net.normals
        self.W = _scatter(n, net.pairs, nrm, -nrm) / np.pi
        self.V = neighbour_vector(self.counts, net.pairs, net.branch, n)

    @property
    def B(self) -> np.ndarray:
        """(N,) ``B = eps_3qr eps_ij3 A_rijq`` (15) [N m]; equals ``-sum kt_eff |c|^2``, zero without tangent stiffness."""
        return np.einsum("qr,ij,nrijq->n", _EPS2, _EPS2, self.A4)

    @property
    def Z(self) -> np.ndarray:
        """(N,2,2,2,2) Z_pkst = A_pstk - (eps_ij3 A_pijk) (eps_3qr A_rstq) / B (16).

        Where B = 0 (all contacts of the particle without tangent stiffness) the moment balance
        is void and the spin term vanishes identically: Z = A there.
        """
        A = self.A4
        L = np.einsum("ij,npijk->npk", _EPS2, A)  # eps_ij3 A_pijk
        M = np.einsum("qr,nrstq->nst", _EPS2, A)  # eps_3qr A_rstq
        B = self.B
        scale = np.max(np.abs(A), axis=(1, 2, 3, 4)) + 1e-300
        inv = np.divide(1.0, B, out=np.zeros_like(B), where=np.abs(B) > 1e-13 * scale)
        return np.einsum("npstk->npkst", A) - np.einsum("npk,nst,n->npkst", L, M, inv)


def particle_sums(network: ContactNetwork, active=None) -> ParticleSums:
    """Per-particle structural sums (:class:`ParticleSums`), optionally over a subset of the contacts
    (``active``: (C,) bool mask)."""
    return ParticleSums(network, active)


def rattlers(network: ContactNetwork, min_contacts=None):
    """Iteratively flag rattlers: particles with fewer than ``min_contacts`` load-bearing contacts.

    Removing a rattler removes its contacts, which may make neighbours rattlers; iterate to a fixed
    point. Default ``min_contacts=None`` decides per particle: 2 if any of its remaining contacts
    has tangent stiffness (frictional disks and spheres alike), else d + 1 (3 for frictionless
    disks, 4 for frictionless spheres: the jamming convention).

    The rule keeps every particle that can carry load, not only the ones held rigid
    (docs/spheres.md, "Rattlers in 3D"). A frictional particle with two contacts is a two-force
    body: in equilibrium its two contact forces are equal, opposite and along the chord joining the
    contact points, and it passes that force, and the stiffness along the chord, between its
    neighbours. In 2D two contacts also hold the disk rigid. In 3D a contact at arm ``a_k`` along
    ``n_k`` is undeformed when ``u + a_k omega x n_k = 0``; two such contacts leave one motion,
    ``omega`` parallel to the chord ``a_1 n_1 - a_2 n_2`` with ``u = -a_1 omega x n_1`` (the sphere
    turns about the chord), a floppy mode the solvers count, not a reason to remove the sphere.
    With one contact a particle follows its neighbour and carries nothing. Frictionless, the
    threshold stays the jamming convention d + 1 (d or fewer compressive normal forces balance only
    if their normals lie in a (d - 1)-dimensional subspace, which leaves the particle a free
    translation).

    ``min_contacts="rigid"`` is the former rule, d with friction (3 for spheres) and d + 1 without:
    it keeps only particles held rigid by their own contacts, what the relaxation hierarchy's
    block preconditioner needs (a two-contact sphere's own 6 x 6 block is singular). In 2D it is
    the default rule.

    Returns (is_rattler (N,) bool, active (C,) bool: contacts between non-rattlers).
    """
    rigid = isinstance(min_contacts, str) and min_contacts == "rigid"
    if min_contacts is not None and not rigid and (isinstance(min_contacts, str) or int(min_contacts) != min_contacts
                                                   or min_contacts < 0):
        raise ValueError(f"min_contacts must be a non-negative integer, None or 'rigid', got {min_contacts!r}")
    n = network.n_particles
    i, j = network.pairs[:, 0], network.pairs[:, 1]
    fric = (network.effective_kt > 0).astype(np.float64)
    active = np.ones(network.n_contacts, dtype=bool)
    rattler = np.zeros(n, dtype=bool)
    while True:
        ia, ja = i[active], j[active]
        counts = np.bincount(ia, minlength=n) + np.bincount(ja, minlength=n)
        if min_contacts is None or rigid:
            fa = fric[active]
            n_fric = np.bincount(ia, weights=fa, minlength=n) + np.bincount(ja, weights=fa, minlength=n)
            threshold = np.where(n_fric > 0, network.dim if rigid else 2, network.dim + 1)
        else:
            threshold = int(min_contacts)
        new = (~rattler) & (counts < threshold)
        if not np.any(new):
            return rattler, active
        rattler |= new
        active &= ~(rattler[i] | rattler[j])


def isotropic_fit(A4):
    """Least-squares fit of (..., 2,2,2,2) tensors to vbar d_pq d_rs + ebar (d_pr d_qs + d_ps d_qr).

    Returns (vbar, ebar) arrays of the leading shape. For the isotropic mean (37) of constant
    stiffnesses the fit is exact: vbar = D^2 Nc (kn + 3 kt)/8, ebar = D^2 Nc (kn - kt)/8.
    """
    d = np.eye(2)
    I1 = np.einsum("pq,rs->pqrs", d, d).ravel()
    I2 = (np.einsum("pr,qs->pqrs", d, d) + np.einsum("ps,qr->pqrs", d, d)).ravel()
    basis = np.stack([I1, I2], axis=1)  # (16, 2)
    flat = np.asarray(A4).reshape(-1, 16)
    coef, *_ = np.linalg.lstsq(basis, flat.T, rcond=None)
    lead = np.asarray(A4).shape[:-4]
    return coef[0].reshape(lead), coef[1].reshape(lead)


def neighbour_vector(counts, pairs, branch, n=None):
    """V^mu = (1/pi) sum_nu Nc^nu n^{mu nu} over the given neighbour pairs (41): (N, 2).

    Each pair adds ``Nc^j n`` to ``V^i`` and ``-Nc^i n`` to ``V^j`` (``n = branch/|branch|``).

    Parameters
    ----------
    counts : (N,) array
        Contact numbers ``Nc^nu`` of the particles (the summand is the neighbour's own contact
        number, whether or not the neighbour touches mu).
    pairs : (E, 2) int array
        Neighbour pairs, each once.
    branch : (E, 2) array
        ``x_j - x_i`` [m] (only its direction is used).
    n : int, optional
        Number of particles N (default ``len(counts)``).
    """
    counts = np.asarray(counts, dtype=float)
    n = len(counts) if n is None else n
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    branch = np.asarray(branch, dtype=float).reshape(-1, 2)
    nrm = branch / np.hypot(branch[:, 0], branch[:, 1])[:, None]
    return _scatter(n, pairs, counts[pairs[:, 1], None] * nrm, -counts[pairs[:, 0], None] * nrm) / np.pi


def rho_statistic(V, W, counts, mask=None) -> float:
    """rho = Nc sum V.W / sum V^2 over the particles in ``mask`` (all if None); Nc = mean counts[mask].

    Returns 0 where there is no odd structure (sum V^2 at round-off level, e.g. a perfect lattice):
    nothing for the correction to act on.
    """
    mask = np.ones(len(counts), dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    V, W = np.asarray(V)[mask], np.asarray(W)[mask]
    vv = float(np.sum(V * V))
    nc = float(np.mean(np.asarray(counts)[mask])) if np.any(mask) else 0.0
    if vv <= 1e-24 * max(nc, 1.0) ** 2 * max(len(V), 1):
        return 0.0
    return nc * float(np.sum(V * W)) / vv


def _near_pairs(network, nbar):
    nb = near_neighbours(network, nbar=nbar)
    return nb.pairs, nb.branch


def _nbar_or_raise(network, nbar):
    if nbar is not None:
        return float(nbar)
    phi = network.solid_fraction
    if not (PHI_MIN_NBAR <= phi <= PHI_MAX * (1 + 1e-12)):
        raise ValueError(f"the near neighbourhood needs Nbar: phi = {phi:.4f} is outside [pi/4, pi/(2 sqrt 3)], "
                         "so pass nbar explicitly")
    return float(nbar_from_phi(phi))


@dataclass(frozen=True)
class NetworkStatistics(Result):
    """The statistics of a contact network that the theory takes as input (:func:`network_statistics`).

    Suffix ``_all``: all particles, rattlers included; no suffix: rattlers removed (iteratively,
    see :func:`rattlers`). Lengths in the unit of the positions [m]; ``vbar``, ``ebar`` and their
    ``_theory`` values in N m (stiffness [N/m] times length squared); the rest is dimensionless.
    Fields that need non-rattlers are NaN when every particle is a rattler. ``as_dict()`` gives the same keys, in the same order, as the dict this function
    returned before it was typed (NaN -> None).

    Attributes
    ----------
    n_particles : int
        Number of particles N.
    n_contacts : int
        Number of contacts C.
    n_rattlers : int
        Particles removed as rattlers.
    rattler_fraction : float
        ``n_rattlers / N``.
    nc_all : float
        Mean contacts per particle, all particles.
    r_all : float
        ``var(Nc)/mean(Nc)^2``, all particles (the paper's ``mean(Nc'^2)/Nc^2``).
    rho_all : float
        ``Nc sum V.W / sum V^2``, all particles (V over ``rho_neighbours``).
    nc : float
        Mean contacts per non-rattler, counting only contacts between non-rattlers.
    r : float
        ``var(Nc)/mean(Nc)^2`` over non-rattlers.
    rho : float
        ``Nc sum V.W / sum V^2`` over non-rattlers (V over ``rho_neighbours``).
    phi : float
        Solid (area) fraction.
    nbar_phi : float or None
        N̄ from phi (section 6); None outside ``[pi/4, pi/(2 sqrt 3)]``.
    diameter : float
        Mean particle diameter [m].
    sliding_fraction : float
        Fraction of contacts at the Coulomb limit.
    vbar : float
        ``vbar`` of the isotropic fit (37) of the mean A4 over non-rattlers [N m].
    ebar : float
        The ``(d_pr d_qs + d_ps d_qr)`` coefficient of the same fit [N m].
    vbar_theory : float
        ``vbar`` of (37) with the measured Nc, mean D^2, kn, kt [N m].
    ebar_theory : float
        ``ebar`` of (37) with the measured Nc, mean D^2, kn, kt [N m].
    odd_norm : float
        Mean Frobenius norm of A3 over non-rattlers, over ``kn D`` (dimensionless).
    rho_nbar : float or None
        N̄ of the near neighbourhood V was summed over (``rho_neighbours="near"``); None for
        ``"contacts"``.
    rho_note : str
        ``""`` when N̄ came from phi or was given; otherwise what was used instead and why (phi
        below pi/4, where N̄(phi) does not exist: N̄ = 4; above close packing: N̄ = 6).
    rho_neighbours : str
        The neighbourhood V is summed over (``RHO_NEIGHBOURS``); not exported, so that
        ``as_dict()`` keeps the keys the command-line tools have always written (the two fields
        above come after them).
    """

    n_particles: int
    n_contacts: int
    n_rattlers: int
    rattler_fraction: float
    nc_all: float
    r_all: float
    rho_all: float
    nc: float
    r: float
    rho: float
    phi: float
    nbar_phi: float | None
    diameter: float
    sliding_fraction: float
    vbar: float = float("nan")
    ebar: float = float("nan")
    vbar_theory: float = float("nan")
    ebar_theory: float = float("nan")
    odd_norm: float = float("nan")
    rho_nbar: float | None = None
    rho_note: str = ""
    rho_neighbours: str = field(default="near", metadata={"export": False})


def network_statistics(network: ContactNetwork, min_contacts=None, rho_neighbours="near",
                       nbar=None) -> NetworkStatistics:
    """The statistics the theory takes as input, with and without rattlers (:class:`NetworkStatistics`).

    On a sphere network (3D) it returns :func:`sphere_statistics` (:class:`SphereStatistics`):
    the quantities that have a 3D meaning; ``rho_neighbours`` and ``nbar`` belong to the seed
    paper's 2D rho and N-bar and must be left at their defaults there.

    Parameters
    ----------
    network : ContactNetwork
        The packing (positions [m], radii [m], contacts, stiffnesses [N/m]).
    min_contacts : int, optional
        Rattler threshold of :func:`rattlers` (None: 2 with tangent stiffness, 3 without).
    rho_neighbours : str
        The neighbourhood the vector V of (41) is summed over. ``"near"`` (default since issue
        25): the paper's neighbourhood of (39), the N̄ near neighbours of mu whether or not they
        touch it (:func:`microhom.neighbourhood.near_neighbours`), N̄ from phi unless ``nbar`` is
        given. Where N̄(phi) does not exist (phi below pi/4; or above close packing) N̄ = 4 (6)
        is used and ``rho_note`` says so. ``"contacts"`` (the option; the default before issue 25):
        mu's contacting neighbours only, which makes ``V ~ Nc W`` and rho ~ 1 by definition.
        ``docs/results/rho.md`` compares the two with a null model.
    nbar : float, optional
        Mean number of near neighbours for ``rho_neighbours="near"``, > 0 (default from phi).
    """
    if rho_neighbours not in RHO_NEIGHBOURS:
        raise ValueError(f"rho_neighbours must be one of {RHO_NEIGHBOURS}, got {rho_neighbours!r}")
    if network.dim == 3:
        if nbar is not None or rho_neighbours != "near":
            raise ValueError("nbar and rho_neighbours define the seed paper's 2D rho and N-bar, which "
                             "have no 3D meaning: leave them at their defaults for a sphere network "
                             "(network_statistics then returns SphereStatistics)")
        return sphere_statistics(network, min_contacts)
    rat, active = rattlers(network, min_contacts)
    all_sums = ParticleSums(network)
    sums = ParticleSums(network, active)
    keep = ~rat
    n = network.n_particles
    c_all = all_sums.counts.astype(float)
    c = sums.counts[keep].astype(float)
    rho_nbar, rho_note = None, ""
    if rho_neighbours == "near":
        if nbar is None:
            rho_nbar, rho_note = nbar_or_substitute(network.solid_fraction)
        else:
            rho_nbar = float(nbar)
        try:
            pairs, branch = _near_pairs(network, rho_nbar)
        except ValueError as exc:  # too few particles (or too small a cell) for N nbar/2 pairs
            if nbar is not None:
                raise
            rho_note = ((rho_note + "; ") if rho_note else "") + \
                f"no near neighbourhood ({exc}): V over the contacting neighbours used"
            rho_nbar, rho_neighbours = None, "contacts"
    if rho_neighbours == "near":
        V_all = neighbour_vector(all_sums.counts, pairs, branch)
        V = neighbour_vector(sums.counts, pairs, branch)
    else:
        V_all, V = all_sums.V, sums.V
    phi = network.solid_fraction
    vals = dict(
        n_particles=n, n_contacts=network.n_contacts, n_rattlers=int(rat.sum()),
        rattler_fraction=float(rat.mean()) if len(rat) else 0.0,
        nc_all=float(c_all.mean()),
        r_all=float(c_all.var() / c_all.mean() ** 2) if c_all.mean() > 0 else 0.0,
        rho_all=rho_statistic(V_all, all_sums.W, all_sums.counts),
        nc=float(c.mean()) if len(c) else 0.0,
        r=float(c.var() / c.mean() ** 2) if len(c) and c.mean() > 0 else 0.0,
        rho=rho_statistic(V, sums.W, sums.counts, keep),
        phi=phi,
        nbar_phi=float(nbar_from_phi(phi)) if PHI_MIN_NBAR <= phi <= PHI_MAX * (1 + 1e-12) else None,
        diameter=float(2 * network.radii.mean()),
        sliding_fraction=float(network.sliding.mean()) if network.n_contacts else 0.0,
        rho_nbar=rho_nbar, rho_note=rho_note, rho_neighbours=rho_neighbours)
    if np.any(keep):
        vb, eb = isotropic_fit(sums.A4[keep].mean(axis=0))
        d2 = float(np.mean(network.lengths[active] ** 2)) if np.any(active) else 0.0
        knm = float(network.kn[active].mean()) if np.any(active) else 0.0
        ktm = float(network.effective_kt[active].mean()) if np.any(active) else 0.0
        scale = (network.kn.mean() * vals["diameter"]) if network.n_contacts else 1.0
        vals.update(vbar=float(vb), ebar=float(eb),
                      vbar_theory=d2 * vals["nc"] * (knm + 3 * ktm) / 8,
                      ebar_theory=d2 * vals["nc"] * (knm - ktm) / 8,
                      odd_norm=float(np.mean(np.sqrt(np.sum(sums.A3[keep] ** 2, axis=(1, 2, 3))))) / scale)
    return NetworkStatistics(**vals)


#: Statistics of the 2D theory that :func:`sphere_statistics` does not compute, and why.
NOT_IN_3D = (
    "rho, rho_all: the seed paper's rho of (41) correlates the first angular harmonic of a disk's "
    "contact density with its neighbours' contact numbers on the circle; its 3D counterpart (a "
    "vector harmonic on the sphere, with its own normalisation) is not derived",
    "nbar_phi, rho_nbar: N-bar(phi) of section 6 counts near neighbours of a disk from the 2D "
    "solid fraction (pi/4 .. pi/(2 sqrt 3)); no 3D relation is derived",
    "vbar, ebar and their _theory values: the isotropic fit (37) and the spin elimination (15)-(16) "
    "are the 2D ones (one out-of-plane spin per disk)",
)


def fabric_affine_tensor(network: ContactNetwork, active=None) -> np.ndarray:
    """(6, 6) Mandel affine (Voigt) stiffness of a sphere network from its contact fabric [Pa]:

    ``C_ijkl = (1/V) sum_c l^2 [kn n_i n_j n_k n_l + kt_eff (sym(d_ik n_j n_l) - n_i n_j n_k n_l)]``

    summed over the contacts ``active`` (default all), with ``l`` the branch length, ``n`` the
    normal and ``sym`` the minor symmetrisation over (i, j) and (k, l); ``V`` the cell volume.
    It is the energy density ``1/2 sum_c [kn (n.E c)^2 + kt_eff (|E c|^2 - (n.E c)^2)] / V`` of
    the affine motion without pre-stress (docs/spheres.md, "Mean field in 3D"), computed from the
    fourth- and second-order fabric sums, not from the per-contact matrices of
    ``microhom.kinematics``."""
    if network.dim != 3:
        raise ValueError(f"fabric_affine_tensor takes a sphere network (dim 3), got dim {network.dim}")
    sel = np.ones(network.n_contacts, bool) if active is None else np.asarray(active, bool)
    n = network.normals[sel]
    l2 = network.lengths[sel] ** 2
    kn = (np.asarray(network.kn, float) * np.ones(network.n_contacts))[sel] * l2
    kt = network.effective_kt[sel] * l2
    N4 = np.einsum("c,ci,cj,ck,cl->ijkl", kn - kt, n, n, n, n)
    N2 = np.einsum("c,ci,cj->ij", kt, n, n)
    eye = np.eye(3)
    T = np.einsum("ik,jl->ijkl", eye, N2)                     # d_ik (kt n_j n_l)
    T = 0.25 * (T + T.transpose(1, 0, 2, 3) + T.transpose(0, 1, 3, 2) + T.transpose(1, 0, 3, 2))
    C4 = (N4 + T) / network.volume
    pairs = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
    basis = []
    for p, q in pairs:                                         # Mandel unit strains as tensors
        E = np.zeros((3, 3))
        E[p, q] = E[q, p] = 1.0 if p == q else 1.0 / np.sqrt(2.0)
        basis.append(E)
    C = np.array([[np.einsum("ij,ijkl,kl->", Ea, C4, Eb) for Eb in basis] for Ea in basis])
    return 0.5 * (C + C.T)


@dataclass(frozen=True)
class SphereStatistics(Result):
    """Statistics of a sphere network (3D) with and without rattlers (:func:`sphere_statistics`).

    The 3D subset of :class:`NetworkStatistics`: what has a 3D meaning is measured, the rest is
    listed in ``not_defined`` with the reason (``NOT_IN_3D``), never computed with a 2D formula.
    Suffix ``_all``: every particle and contact; no suffix: rattlers removed (iteratively,
    :func:`rattlers`: fewer than 2 contacts with friction, 4 without). Moduli in Pa (the unit of
    kn [N/m] over a length), lengths in the unit of the positions [m], the rest dimensionless.

    Attributes
    ----------
    n_particles, n_contacts, n_rattlers : int
        Spheres N, contacts C, spheres removed as rattlers.
    rattler_fraction : float
        ``n_rattlers / N``.
    nc_all, nc : float
        Mean contacts per sphere, Z (all; non-rattlers, counting contacts between non-rattlers).
    r_all, r : float
        Contact-number fluctuation ``var(Nc)/mean(Nc)^2`` (all; non-rattlers).
    phi : float
        Solid (volume) fraction ``sum (4/3) pi r^3 / V``.
    diameter : float
        Mean sphere diameter [m].
    sliding_fraction : float
        Fraction of contacts at the Coulomb limit.
    K_affine, G_affine : float
        Affine (Voigt) bulk and shear moduli of the load-bearing contacts from the fabric,
        ``K = sum kn l^2 / (9 V)``, ``G = sum (2 kn + 3 kt_eff) l^2 / (30 V)`` (docs/spheres.md,
        "Mean field in 3D"; the isotropic projection of :func:`fabric_affine_tensor`) [Pa].
    K_affine_all, G_affine_all : float
        The same over every contact, rattlers' included [Pa].
    C_affine : ndarray, shape (6, 6)
        :func:`fabric_affine_tensor` of the load-bearing contacts [Pa].
    not_defined : tuple of str
        The 2D statistics with no 3D meaning here, each with the reason (``NOT_IN_3D``).
    """

    n_particles: int
    n_contacts: int
    n_rattlers: int
    rattler_fraction: float
    nc_all: float
    r_all: float
    nc: float
    r: float
    phi: float
    diameter: float
    sliding_fraction: float
    K_affine: float
    G_affine: float
    K_affine_all: float
    G_affine_all: float
    C_affine: np.ndarray = field(repr=False)
    not_defined: tuple = NOT_IN_3D


def _voigt_moduli(network, active):
    """(K, G) of the affine fabric formula over ``active`` contacts [Pa] (docs/spheres.md)."""
    l2 = network.lengths[active] ** 2
    kn = (np.asarray(network.kn, float) * np.ones(network.n_contacts))[active]
    kt = network.effective_kt[active]
    V = network.volume
    return float(np.sum(kn * l2) / (9 * V)), float(np.sum((2 * kn + 3 * kt) * l2) / (30 * V))


def sphere_statistics(network: ContactNetwork, min_contacts=None) -> SphereStatistics:
    """Coordination statistics and the affine (Voigt) moduli of a sphere network (3D), with and
    without rattlers (:class:`SphereStatistics`).

    Parameters
    ----------
    network : ContactNetwork
        A network of spheres: positions (N, 3) [m], radii [m], contacts, kn, kt [N/m]; periodic
        (the moduli are per cell volume).
    min_contacts : int, optional
        Rattler threshold of :func:`rattlers` (None: 2 with tangent stiffness, 4 without).
    """
    if not isinstance(network, ContactNetwork):
        raise TypeError(f"network must be a microhom.network.ContactNetwork, got {type(network).__name__}")
    if network.dim != 3:
        raise ValueError(f"sphere_statistics takes a sphere network (positions (N, 3)), got dim "
                         f"{network.dim}: use network_statistics for disks")
    if network.cell is None:
        raise ValueError("network must be periodic (cell is None): the affine moduli are per cell volume")
    rat, active = rattlers(network, min_contacts)
    n = network.n_particles
    c_all = np.bincount(network.pairs.ravel(), minlength=n).astype(float)
    pa = network.pairs[active]
    c = np.bincount(pa.ravel(), minlength=n)[~rat].astype(float)
    fluct = lambda x: float(x.var() / x.mean() ** 2) if x.size and x.mean() > 0 else 0.0  # noqa: E731
    Ka, Ga = _voigt_moduli(network, active)
    Kall, Gall = _voigt_moduli(network, np.ones(network.n_contacts, bool))
    return SphereStatistics(
        n_particles=n, n_contacts=network.n_contacts, n_rattlers=int(rat.sum()),
        rattler_fraction=float(rat.mean()) if n else 0.0,
        nc_all=float(c_all.mean()) if n else 0.0, r_all=fluct(c_all),
        nc=float(c.mean()) if c.size else 0.0, r=fluct(c),
        phi=network.solid_fraction, diameter=float(2 * network.radii.mean()),
        sliding_fraction=float(network.sliding.mean()) if network.n_contacts else 0.0,
        K_affine=Ka, G_affine=Ga, K_affine_all=Kall, G_affine_all=Gall,
        C_affine=fabric_affine_tensor(network, active))


@dataclass(frozen=True)
class RhoDefinitions(Result):
    """rho = Nc sum V.W / sum V^2 under each definition of V, with its null model (:func:`rho_definitions`).

    Every value is over non-rattlers (contacts between non-rattlers; Nc^nu = active contact numbers).
    ``rho[name]`` is the measured value for the neighbourhood ``name``; ``null_mean[name]`` and
    ``null_std[name]`` the mean and standard deviation over ``n_null`` random permutations of the
    contact numbers Nc^nu among the non-rattlers (geometry, W and the neighbourhoods unchanged):
    the value the definition gives when the neighbours' contact numbers carry no correlation with
    mu at all. ``mean_degree[name]`` is the mean number of neighbours per particle in that
    neighbourhood. Dimensionless throughout.

    Attributes
    ----------
    rho : dict of str to float
        Measured rho per neighbourhood name.
    null_mean, null_std : dict of str to float
        Mean and standard deviation of rho over the ``n_null`` permutations, per name.
    mean_degree : dict of str to float
        Mean number of neighbours per non-rattler, per name.
    nc : float
        Mean active contacts per non-rattler.
    r : float
        ``var(Nc)/mean(Nc)^2`` over non-rattlers.
    nbar : float
        N̄ used for the ``"near"`` neighbourhood.
    n_null : int
        Number of random permutations of the null model.
    """

    rho: dict
    null_mean: dict
    null_std: dict
    mean_degree: dict
    nc: float
    r: float
    nbar: float
    n_null: int


def rho_definitions(network: ContactNetwork, min_contacts=None, nbar=None, extra=None, n_null=20,
                    seed=0) -> RhoDefinitions:
    """rho measured with V over several neighbourhoods, each beside its shuffled-Nc null model.

    Neighbourhoods: ``"contacts"`` (mu's contacting neighbours), ``"near"`` (the N̄ near
    neighbours of (39), N̄ = ``nbar`` or from phi), plus ``extra``: a dict name -> (pairs (E, 2),
    branch (E, 2)) of other neighbour sets (e.g. Delaunay neighbours measured elsewhere).
    n_null : number of random permutations for the null model (>= 2); seed : their RNG seed.
    """
    if int(n_null) != n_null or n_null < 2:
        raise ValueError(f"n_null must be an integer >= 2, got {n_null!r}")
    rat, active = rattlers(network, min_contacts)
    sums = ParticleSums(network, active)
    keep = ~rat
    nb = _nbar_or_raise(network, nbar)
    hoods = {"contacts": (sums.network.pairs, sums.network.branch), "near": _near_pairs(network, nb)}
    hoods.update(extra or {})
    counts = sums.counts
    idx = np.flatnonzero(keep)
    rng = np.random.default_rng(seed)
    perms = [rng.permutation(idx) for _ in range(int(n_null))]
    out = {k: {} for k in ("rho", "null_mean", "null_std", "mean_degree")}
    for name, (pairs, branch) in hoods.items():
        out["rho"][name] = rho_statistic(neighbour_vector(counts, pairs, branch), sums.W, counts, keep)
        nulls = []
        for p in perms:
            shuffled = counts.copy()
            shuffled[idx] = counts[p]
            nulls.append(rho_statistic(neighbour_vector(shuffled, pairs, branch), sums.W, counts, keep))
        out["null_mean"][name] = float(np.mean(nulls))
        out["null_std"][name] = float(np.std(nulls, ddof=1))
        out["mean_degree"][name] = 2.0 * len(np.asarray(pairs).reshape(-1, 2)) / network.n_particles
    c = counts[keep].astype(float)
    return RhoDefinitions(**out, nc=float(c.mean()) if len(c) else 0.0,
                          r=float(c.var() / c.mean() ** 2) if len(c) and c.mean() > 0 else 0.0,
                          nbar=nb, n_null=int(n_null))


@dataclass(frozen=True)
class BondOrder(Result):
    """Bond-orientational order of the load-bearing contact network (:func:`bond_order`), 2D.

    ``psi_m,i = (1/z_i) sum_j exp(i m theta_ij)`` over the load-bearing contacts of particle i
    (theta_ij: angle of the branch vector; z_i its load-bearing contacts), rattlers removed
    (:func:`rattlers`). Dimensionless.

    Attributes
    ----------
    m : int
        Symmetry order (6: hexatic, 4: square).
    psi : float
        Global order ``|mean_i psi_m,i|`` over the load-bearing particles [-]: 1 for a perfect
        lattice of that symmetry in one orientation, ~N^-1/2 for an amorphous packing, small for a
        polycrystal of randomly oriented grains.
    psi_local : float
        Mean local modulus ``mean_i |psi_m,i|`` [-]: 1 when every particle's contacts have the
        m-fold symmetry (whatever the grain orientation); ~0.3-0.5 for amorphous disks at Z ~ 4.
    n_particles : int
        Load-bearing particles the means run over.
    """

    m: int
    psi: float
    psi_local: float
    n_particles: int


def bond_order(network: ContactNetwork, m: int = 6, min_contacts=None) -> BondOrder:
    """Bond-orientational order ``psi_m`` of the load-bearing contacts of a disk network
    (:class:`BondOrder`): the global ``|<psi_m>|`` and the mean local ``<|psi_m,i|>`` over the
    load-bearing particles (rattlers removed as in :func:`rattlers`; ``min_contacts`` as there).

    m : int, >= 1 (6: hexatic psi6, 4: square psi4). Exact values: a triangular lattice gives
    psi6 = 1, psi4 ~ 0; a square lattice psi6 = 0, psi4 = 1 (``tests/test_closure.py``).
    Delaunay-neighbour psi6 (every near neighbour, contacts or not) is
    ``dem.analysis.measure.hexatic_order``.
    """
    if network.dim != 2:
        raise ValueError(f"bond_order is defined for 2D disk networks; got dim = {network.dim}")
    if int(m) != m or m < 1:
        raise ValueError(f"m must be an integer >= 1, got {m!r}")
    m = int(m)
    rat, active = rattlers(network, min_contacts)
    n = network.n_particles
    i, j = network.pairs[active, 0], network.pairs[active, 1]
    br = np.asarray(network.branch)[active]
    th = np.arctan2(br[:, 1], br[:, 0])
    zi = np.exp(1j * m * th)            # as seen from i (branch i -> j)
    zj = zi * (-1.0) ** m               # from j: theta + pi
    re = np.bincount(i, weights=zi.real, minlength=n) + np.bincount(j, weights=zj.real, minlength=n)
    im = np.bincount(i, weights=zi.imag, minlength=n) + np.bincount(j, weights=zj.imag, minlength=n)
    deg = np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
    keep = (~rat) & (deg > 0)
    if not keep.any():
        return BondOrder(m=m, psi=float("nan"), psi_local=float("nan"), n_particles=0)
    loc = (re[keep] + 1j * im[keep]) / deg[keep]
    return BondOrder(m=m, psi=float(abs(loc.mean())), psi_local=float(np.abs(loc).mean()),
                     n_particles=int(keep.sum()))
