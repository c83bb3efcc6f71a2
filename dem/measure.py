"""Micromechanical measurements of a packing, from its ContactNetwork (read-only, never mutates).

All functions take a :class:`microhom.network.ContactNetwork` whose ``fn`` (normal force,
compression positive) and ``ft`` (tangential force on j along t = (-n_y, n_x)) are set where
forces are needed. 2D: stresses are force per length (N/m per unit thickness), tension positive;
``pressure = -tr(sigma)/2`` is positive in compression.

* :func:`stress` — Love-Weber stress ``sigma = (1/A) sum_c F^{i} (x) c`` where ``F^{i}`` is the
  force on particle i from j and ``c = x_j - x_i`` (negative in compression).
* :func:`fabric` — ``F = (1/C) sum_c n (x) n`` (trace 1) and its deviator.
* :func:`force_statistics`, :func:`coordination` — distributions with and without rattlers.
* :func:`delaunay_neighbours` — periodic Delaunay neighbours (mean degree exactly 6 in a periodic
  cell, by Euler's formula) and near neighbours within a gap, to set beside ``Nbar`` from phi.
* :func:`hexatic_order` — psi6 over Delaunay neighbours (global and mean local modulus).
* :func:`summary` — everything in one flat dict (the packing's summary table).
"""
from __future__ import annotations

import numpy as np

from microhom.network import ContactNetwork
from microhom.structural_sums import network_statistics, rattlers

__all__ = ["stress", "pressure", "fabric", "force_statistics", "coordination", "delaunay_neighbours",
           "hexatic_order", "summary"]


def _require_forces(net: ContactNetwork):
    if net.fn is None:
        raise ValueError("this measurement needs contact forces: the ContactNetwork has fn=None")
    ft = np.zeros(net.n_contacts) if net.ft is None else net.ft
    return net.fn, ft


def contact_forces(net: ContactNetwork) -> np.ndarray:
    """(C, 2) force on particle j from particle i: ``fn n + ft t`` (fn > 0 pushes j away)."""
    fn, ft = _require_forces(net)
    n = net.normals
    t = np.stack([-n[:, 1], n[:, 0]], axis=1)
    return fn[:, None] * n + ft[:, None] * t


def stress(net: ContactNetwork, symmetric=True) -> np.ndarray:
    """(2, 2) Love-Weber stress [N/m], tension positive, over the cell area.

    ``sigma = (1/A) sum_c F^{i} (x) c = -(1/A) sum_c F^{j} (x) c``. With ``symmetric=False`` the raw
    tensor is returned (its antisymmetric part measures the unbalanced moments).
    """
    if net.cell is None:
        raise ValueError("stress needs a periodic cell (its area is the averaging volume)")
    F = contact_forces(net)
    s = -np.einsum("ci,cj->ij", F, net.branch) / net.area
    return 0.5 * (s + s.T) if symmetric else s


def pressure(net: ContactNetwork) -> float:
    """2D pressure -tr(sigma)/2 [N/m], positive in compression."""
    return float(-np.trace(stress(net)) / 2)


def fabric(net: ContactNetwork, active=None) -> dict:
    """Fabric tensor ``F = (1/C) sum n n`` over the (active) contacts, its principal values and the
    anisotropy ``a = 2 (F1 - F2)`` (0 isotropic) with the major direction [rad]."""
    n = net.normals if active is None else net.normals[active]
    if len(n) == 0:
        return {"F": np.full((2, 2), np.nan), "anisotropy": 0.0, "direction": 0.0}
    F = np.einsum("ci,cj->ij", n, n) / len(n)
    w, v = np.linalg.eigh(F)
    return {"F": F, "anisotropy": float(2 * (w[1] - w[0])), "direction": float(np.arctan2(v[1, 1], v[0, 1]))}


def force_statistics(net: ContactNetwork) -> dict:
    """Normal and tangential contact force statistics [N/m], and the sliding fraction."""
    fn, ft = _require_forces(net)
    if len(fn) == 0:
        return {"fn_mean": 0.0, "fn_std": 0.0, "fn_max": 0.0, "ft_over_fn_mean": 0.0, "sliding_fraction": 0.0,
                "tension_contacts": 0, "fraction_above_mean": 0.0}
    m = fn.mean()
    with np.errstate(divide="ignore", invalid="ignore"):
        mob = np.where(fn > 0, np.abs(ft) / fn, 0.0)
    return {"fn_mean": float(m), "fn_std": float(fn.std()), "fn_max": float(fn.max()),
            "ft_over_fn_mean": float(mob.mean()), "sliding_fraction": float(net.sliding.mean()),
            "tension_contacts": int(np.sum(fn < 0)), "fraction_above_mean": float(np.mean(fn > m))}


def coordination(net: ContactNetwork, min_contacts=None) -> dict:
    """Coordination number mean and distribution with and without rattlers (iterative removal)."""
    rat, active = rattlers(net, min_contacts)
    counts_all = net.contact_counts()
    counts = np.bincount(net.pairs[active].ravel(), minlength=net.n_particles)[~rat]
    top = int(counts_all.max(initial=0)) + 1
    return {"z_all": float(counts_all.mean()), "z": float(counts.mean()) if len(counts) else 0.0,
            "hist_all": np.bincount(counts_all, minlength=top), "hist": np.bincount(counts, minlength=top),
            "n_rattlers": int(rat.sum()), "rattler_fraction": float(rat.mean())}


def _periodic_images(net: ContactNetwork, margin: float):
    """Positions wrapped into the cell plus the images within ``margin`` of its boundary.

    Returns (points (M, 2), owner (M,) original particle index)."""
    h = net.cell
    frac = np.linalg.solve(h, (net.positions - net.origin).T).T
    frac -= np.floor(frac)
    heights = abs(np.linalg.det(h)) / np.linalg.norm(h[:, ::-1], axis=0)
    fm = margin / heights  # margin in fractional units, per direction
    pts, owner = [], []
    n = net.n_particles
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            f = frac + np.array([a, b])
            keep = np.all((f > -fm) & (f < 1 + fm), axis=1)
            pts.append(net.origin + f[keep] @ h.T)
            owner.append(np.arange(n)[keep])
    return np.concatenate(pts), np.concatenate(owner)


def delaunay_neighbours(net: ContactNetwork, gap=None):
    """Periodic Delaunay neighbours (scipy.spatial.Delaunay on the cell plus a margin of images).

    Returns a dict with ``pairs`` (E, 2) unique neighbour pairs (i < j, one per image pair),
    ``branch`` (E, 2), ``degree`` (N,), ``mean_degree`` (6 in a periodic cell, Euler's formula) and,
    if ``gap`` is given, ``near_degree_mean``: mean number of Delaunay neighbours whose surface gap
    ``|c| - r_i - r_j`` is at most ``gap`` [m] (touching or nearly touching neighbours).
    """
    from scipy.spatial import Delaunay

    if net.cell is None:
        raise ValueError("delaunay_neighbours needs a periodic cell")
    margin = 4.0 * 2 * net.radii.max() * 2
    pts, owner = _periodic_images(net, margin)
    n = net.n_particles
    tri = Delaunay(pts)
    s = tri.simplices
    e = np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [2, 0]]])
    # keep edges with their first end in the primary cell copy (image index < n, a=b=0 block)
    primary = np.zeros(len(pts), dtype=bool)
    h = net.cell
    f = np.linalg.solve(h, (pts - net.origin).T).T
    primary[np.all((f >= 0) & (f < 1), axis=1)] = True
    e = np.concatenate([e, e[:, ::-1]])
    e = e[primary[e[:, 0]]]
    i, j = owner[e[:, 0]], owner[e[:, 1]]
    d = pts[e[:, 1]] - pts[e[:, 0]]
    # unique undirected pairs with their image: key on (min, max, rounded branch sign-normalised)
    flip = i > j
    a, b = np.where(flip, j, i), np.where(flip, i, j)
    d = np.where(flip[:, None], -d, d)
    key = np.round(d / (net.radii.mean() * 1e-6)).astype(np.int64)
    _, first = np.unique(np.stack([a, b, key[:, 0], key[:, 1]], 1), axis=0, return_index=True)
    a, b, d = a[first], b[first], d[first]
    degree = np.bincount(np.concatenate([a, b]), minlength=n)
    out = {"pairs": np.stack([a, b], 1), "branch": d, "degree": degree, "mean_degree": float(degree.mean())}
    if gap is not None:
        g = np.hypot(d[:, 0], d[:, 1]) - net.radii[a] - net.radii[b]
        near = g <= gap
        out["near_degree_mean"] = float(np.bincount(np.concatenate([a[near], b[near]]), minlength=n).mean())
    return out


def hexatic_order(net: ContactNetwork, neighbours=None) -> dict:
    """Hexatic bond-orientational order psi6.

    ``psi6_i = (1/n_i) sum_j exp(6 i theta_ij)`` over Delaunay neighbours (default); returns the
    global order ``|mean_i psi6_i|`` (1 for a perfect triangular crystal, ~0 for an amorphous or
    polycrystalline packing) and the mean local modulus ``mean_i |psi6_i|``.
    """
    nb = delaunay_neighbours(net) if neighbours is None else neighbours
    a, b = nb["pairs"][:, 0], nb["pairs"][:, 1]
    th = np.arctan2(nb["branch"][:, 1], nb["branch"][:, 0])
    z = np.exp(6j * th)  # the same from both ends (theta + pi)
    n = net.n_particles
    s = np.bincount(a, weights=z.real, minlength=n) + np.bincount(b, weights=z.real, minlength=n) \
        + 1j * (np.bincount(a, weights=z.imag, minlength=n) + np.bincount(b, weights=z.imag, minlength=n))
    deg = np.maximum(np.bincount(np.concatenate([a, b]), minlength=n), 1)
    loc = s / deg
    return {"psi6": float(abs(loc.mean())), "psi6_local": float(np.abs(loc).mean())}


def summary(net: ContactNetwork, min_contacts=None, near_gap_fraction=0.1) -> dict:
    """All packing measurements in one flat dict of scalars (for tables and CSV)."""
    out = {}
    st = network_statistics(net, min_contacts).as_dict()
    out.update({k: v for k, v in st.items() if np.isscalar(v) or v is None})
    if net.fn is not None and net.cell is not None:
        s = stress(net)
        out.update({"sxx": s[0, 0], "syy": s[1, 1], "sxy": s[0, 1], "pressure": float(-np.trace(s) / 2),
                    "shear_stress": float(np.sqrt(((s[0, 0] - s[1, 1]) / 2) ** 2 + s[0, 1] ** 2))})
        out.update(force_statistics(net))
    fab = fabric(net)
    out["fabric_anisotropy"] = fab["anisotropy"]
    if net.cell is not None and net.n_particles >= 3:
        nb = delaunay_neighbours(net, gap=near_gap_fraction * out.get("diameter", 1.0))
        out["nbar_delaunay"] = nb["mean_degree"]
        out[f"nbar_near_{near_gap_fraction:g}D"] = nb["near_degree_mean"]
        out.update(hexatic_order(net, nb))
    return out
