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
  numbers of mu's contacting neighbours (41); ``V = Nc W`` when all neighbours have Nc contacts,
  so that ``rho = Nc sum V.W / sum V^2`` is 1 for perfect correlation, the paper's alpha -> 0 limit.

The choices for V and W (contacting neighbours, full ``Nc^nu``) are explained in docs/theory.md.
"""
from __future__ import annotations

import numpy as np

from .network import ContactNetwork

__all__ = ["particle_sums", "ParticleSums", "rattlers", "network_statistics", "isotropic_fit"]

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
    """Per-particle structural sums of a network (see the module docstring for definitions)."""

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
        cnt = self.counts.astype(float)
        self.V = _scatter(n, net.pairs, cnt[net.pairs[:, 1], None] * nrm, -cnt[net.pairs[:, 0], None] * nrm) / np.pi

    @property
    def B(self) -> np.ndarray:
        """(N,) B = eps_3qr eps_ij3 A_rijq (15); equals -sum kt_eff |c|^2, zero without tangent stiffness."""
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
    """Per-particle structural sums, optionally over a subset of the contacts."""
    return ParticleSums(network, active)


def rattlers(network: ContactNetwork, min_contacts=None):
    """Iteratively flag rattlers: particles with fewer than ``min_contacts`` load-bearing contacts.

    Removing a rattler removes its contacts, which may make neighbours rattlers; iterate to a fixed
    point. Default ``min_contacts=None`` decides per particle: 2 if any of its remaining contacts
    has tangent stiffness (a frictional disk is held by 2 contacts), else 3 (frictionless disks
    need d + 1 contacts, the jamming convention).

    Returns (is_rattler (N,) bool, active (C,) bool: contacts between non-rattlers).
    """
    if min_contacts is not None and (int(min_contacts) != min_contacts or min_contacts < 0):
        raise ValueError(f"min_contacts must be a non-negative integer, got {min_contacts}")
    n = network.n_particles
    i, j = network.pairs[:, 0], network.pairs[:, 1]
    fric = (network.effective_kt > 0).astype(np.float64)
    active = np.ones(network.n_contacts, dtype=bool)
    rattler = np.zeros(n, dtype=bool)
    while True:
        ia, ja = i[active], j[active]
        counts = np.bincount(ia, minlength=n) + np.bincount(ja, minlength=n)
        if min_contacts is None:
            fa = fric[active]
            n_fric = np.bincount(ia, weights=fa, minlength=n) + np.bincount(ja, weights=fa, minlength=n)
            threshold = np.where(n_fric > 0, 2, 3)
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


def _rho(sums: ParticleSums, mask):
    V, W = sums.V[mask], sums.W[mask]
    vv = float(np.sum(V * V))
    nc = float(np.mean(sums.counts[mask])) if np.any(mask) else 0.0
    if vv <= 1e-24 * max(nc, 1.0) ** 2 * max(len(V), 1):
        return 0.0  # no odd structure (perfect lattice; V is round-off): nothing for the correction to act on
    return nc * float(np.sum(V * W)) / vv


def network_statistics(network: ContactNetwork, min_contacts=None) -> dict:
    """The statistics the theory takes as input, with and without rattlers.

    Keys (``*_all`` = all particles, rattlers included; without suffix = rattlers removed):
    ``nc``, ``r`` (= var(Nc)/Nc^2), ``rho`` (= Nc sum V.W / sum V^2), ``n_particles``,
    ``n_rattlers``, ``rattler_fraction``, ``phi``, ``nbar_phi`` (Nbar from phi; None below pi/4),
    ``diameter`` (mean), ``sliding_fraction``, ``vbar``, ``ebar`` (isotropic fit of the mean A4
    over non-rattlers), ``vbar_theory``, ``ebar_theory`` (37) with the measured Nc and mean kn, kt,
    ``odd_norm`` (mean Frobenius norm of A3 over non-rattlers, in units of kn D).
    """
    from .moduli import PHI_MAX, PHI_MIN_NBAR, nbar_from_phi

    rat, active = rattlers(network, min_contacts)
    all_sums = ParticleSums(network)
    sums = ParticleSums(network, active)
    keep = ~rat
    out = {"n_particles": network.n_particles, "n_contacts": network.n_contacts,
           "n_rattlers": int(rat.sum()), "rattler_fraction": float(rat.mean()) if len(rat) else 0.0}
    c_all = all_sums.counts.astype(float)
    out["nc_all"] = float(c_all.mean())
    out["r_all"] = float(c_all.var() / c_all.mean() ** 2) if c_all.mean() > 0 else 0.0
    out["rho_all"] = _rho(all_sums, np.ones(network.n_particles, dtype=bool))
    c = sums.counts[keep].astype(float)
    out["nc"] = float(c.mean()) if len(c) else 0.0
    out["r"] = float(c.var() / c.mean() ** 2) if len(c) and c.mean() > 0 else 0.0
    out["rho"] = _rho(sums, keep)
    phi = network.solid_fraction
    out["phi"] = phi
    out["nbar_phi"] = float(nbar_from_phi(phi)) if PHI_MIN_NBAR <= phi <= PHI_MAX * (1 + 1e-12) else None
    out["diameter"] = float(2 * network.radii.mean())
    out["sliding_fraction"] = float(network.sliding.mean()) if network.n_contacts else 0.0
    if np.any(keep):
        vb, eb = isotropic_fit(sums.A4[keep].mean(axis=0))
        out["vbar"], out["ebar"] = float(vb), float(eb)
        d2 = float(np.mean(network.lengths[active] ** 2)) if np.any(active) else 0.0
        knm = float(network.kn[active].mean()) if np.any(active) else 0.0
        ktm = float(network.effective_kt[active].mean()) if np.any(active) else 0.0
        out["vbar_theory"] = d2 * out["nc"] * (knm + 3 * ktm) / 8
        out["ebar_theory"] = d2 * out["nc"] * (knm - ktm) / 8
        scale = (network.kn.mean() * out["diameter"]) if network.n_contacts else 1.0
        out["odd_norm"] = float(np.mean(np.sqrt(np.sum(sums.A3[keep] ** 2, axis=(1, 2, 3))))) / scale
    return out
