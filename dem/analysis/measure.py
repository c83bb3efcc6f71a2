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
* :func:`summary` — everything in one :class:`PackingSummary`; its ``table()`` is the flat dict of
  scalars of the packing's summary table (``packing_summary.csv``).

Results are frozen dataclasses (:class:`Fabric`, :class:`ForceStatistics`, :class:`Coordination`,
:class:`DelaunayNeighbours`, :class:`HexaticOrder`, :class:`PackingSummary`) with ``as_dict()``
and ``to_frame()`` (:class:`microhom.results.Result`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import Delaunay

from microhom.network import ContactNetwork
from microhom.periodic import boundary_images
from microhom.results import Result
from microhom.structural_sums import network_statistics, rattlers

__all__ = ["stress", "pressure", "contact_forces", "fabric", "force_statistics", "coordination",
           "delaunay_neighbours", "hexatic_order", "summary", "Fabric", "ForceStatistics",
           "Coordination", "DelaunayNeighbours", "HexaticOrder", "PackingSummary"]


@dataclass(frozen=True, eq=False)
class Fabric(Result):
    """Fabric of the (active) contacts.

    F : (2, 2) fabric tensor ``(1/C) sum n n`` (dimensionless, trace 1; NaN without contacts);
    anisotropy : ``2 (F1 - F2)`` from its principal values (0 isotropic);
    direction : angle of the major principal direction [rad] in (-pi, pi].
    """

    F: np.ndarray
    anisotropy: float
    direction: float


@dataclass(frozen=True)
class ForceStatistics(Result):
    """Contact force statistics (forces per unit thickness [N/m]).

    Attributes
    ----------
    fn_mean, fn_std, fn_max : float
        Normal force mean, standard deviation and maximum [N/m].
    ft_over_fn_mean : float
        Mean mobilised friction ``|ft|/fn`` over the contacts (0 where ``fn <= 0``).
    sliding_fraction : float
        Fraction of contacts flagged sliding.
    tension_contacts : int
        Number of contacts with ``fn < 0``.
    fraction_above_mean : float
        Fraction of contacts with ``fn`` above the mean.
    """

    fn_mean: float
    fn_std: float
    fn_max: float
    ft_over_fn_mean: float
    sliding_fraction: float
    tension_contacts: int
    fraction_above_mean: float


@dataclass(frozen=True, eq=False)
class Coordination(Result):
    """Coordination numbers with and without rattlers (iterative removal).

    z_all : mean contacts per particle, all particles; z : mean over non-rattlers, counting only
    contacts between non-rattlers (0 if all are rattlers);
    hist_all, hist : (zmax + 1,) int histograms of the contact counts (index = count);
    n_rattlers : rattlers removed; rattler_fraction : n_rattlers / N.
    """

    z_all: float
    z: float
    hist_all: np.ndarray
    hist: np.ndarray
    n_rattlers: int
    rattler_fraction: float


@dataclass(frozen=True, eq=False)
class DelaunayNeighbours(Result):
    """Periodic Delaunay neighbours of the particle centres.

    pairs : (E, 2) int unique neighbour pairs (i < j, one per image pair; not exported);
    branch : (E, 2) branch vectors x_j - x_i to the neighbouring image [m] (not exported);
    degree : (N,) int neighbours per particle (not exported);
    mean_degree : mean degree (exactly 6 in a periodic cell, Euler's formula);
    gap : surface gap threshold [m] of the near neighbours, or None;
    near_degree_mean : mean number of Delaunay neighbours with ``|c| - r_i - r_j <= gap``, or None.
    """

    pairs: np.ndarray = field(metadata={"export": False})
    branch: np.ndarray = field(metadata={"export": False})
    degree: np.ndarray = field(metadata={"export": False})
    mean_degree: float = 0.0
    gap: float | None = None
    near_degree_mean: float | None = None


@dataclass(frozen=True)
class HexaticOrder(Result):
    """Hexatic bond-orientational order (dimensionless, in [0, 1]).

    psi6 : global order ``|mean_i psi6_i|`` (1 for a perfect triangular crystal);
    psi6_local : mean local modulus ``mean_i |psi6_i|``.
    """

    psi6: float
    psi6_local: float


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


def fabric(net: ContactNetwork, active=None) -> Fabric:
    """Fabric tensor ``F = (1/C) sum n n`` over the (active) contacts, its principal values and the
    anisotropy ``a = 2 (F1 - F2)`` (0 isotropic) with the major direction [rad]."""
    n = net.normals if active is None else net.normals[active]
    if len(n) == 0:
        return Fabric(F=np.full((2, 2), np.nan), anisotropy=0.0, direction=0.0)
    F = np.einsum("ci,cj->ij", n, n) / len(n)
    w, v = np.linalg.eigh(F)
    return Fabric(F=F, anisotropy=float(2 * (w[1] - w[0])), direction=float(np.arctan2(v[1, 1], v[0, 1])))


def force_statistics(net: ContactNetwork) -> ForceStatistics:
    """Normal and tangential contact force statistics [N/m], and the sliding fraction."""
    fn, ft = _require_forces(net)
    if len(fn) == 0:
        return ForceStatistics(fn_mean=0.0, fn_std=0.0, fn_max=0.0, ft_over_fn_mean=0.0,
                               sliding_fraction=0.0, tension_contacts=0, fraction_above_mean=0.0)
    m = fn.mean()
    with np.errstate(divide="ignore", invalid="ignore"):
        mob = np.where(fn > 0, np.abs(ft) / fn, 0.0)
    return ForceStatistics(fn_mean=float(m), fn_std=float(fn.std()), fn_max=float(fn.max()),
                           ft_over_fn_mean=float(mob.mean()), sliding_fraction=float(net.sliding.mean()),
                           tension_contacts=int(np.sum(fn < 0)), fraction_above_mean=float(np.mean(fn > m)))


def coordination(net: ContactNetwork, min_contacts=None) -> Coordination:
    """Coordination number mean and distribution with and without rattlers (iterative removal)."""
    rat, active = rattlers(net, min_contacts)
    counts_all = net.contact_counts()
    counts = np.bincount(net.pairs[active].ravel(), minlength=net.n_particles)[~rat]
    top = int(counts_all.max(initial=0)) + 1
    return Coordination(z_all=float(counts_all.mean()), z=float(counts.mean()) if len(counts) else 0.0,
                        hist_all=np.bincount(counts_all, minlength=top),
                        hist=np.bincount(counts, minlength=top), n_rattlers=int(rat.sum()),
                        rattler_fraction=float(rat.mean()))


def delaunay_neighbours(net: ContactNetwork, gap=None) -> DelaunayNeighbours:
    """Periodic Delaunay neighbours (scipy.spatial.Delaunay on the cell plus a margin of images).

    ``gap`` [m]: also count, per particle, the Delaunay neighbours whose surface gap
    ``|c| - r_i - r_j`` is at most ``gap`` (touching or nearly touching neighbours).
    """
    if net.cell is None:
        raise ValueError("delaunay_neighbours needs a periodic cell")
    margin = 4.0 * 2 * net.radii.max() * 2
    n = net.n_particles
    pts, owner = boundary_images(net.positions, net.cell, net.origin, margin)
    tri = Delaunay(pts)
    s = tri.simplices
    e = np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [2, 0]]])
    # keep edges with their first end in the primary cell copy (the first n points)
    e = np.concatenate([e, e[:, ::-1]])
    e = e[e[:, 0] < n]
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
    near = None
    if gap is not None:
        g = np.hypot(d[:, 0], d[:, 1]) - net.radii[a] - net.radii[b]
        m = g <= gap
        near = float(np.bincount(np.concatenate([a[m], b[m]]), minlength=n).mean())
    return DelaunayNeighbours(pairs=np.stack([a, b], 1), branch=d, degree=degree,
                              mean_degree=float(degree.mean()), gap=None if gap is None else float(gap),
                              near_degree_mean=near)


def hexatic_order(net: ContactNetwork, neighbours: DelaunayNeighbours | None = None) -> HexaticOrder:
    """Hexatic bond-orientational order psi6.

    ``psi6_i = (1/n_i) sum_j exp(6 i theta_ij)`` over Delaunay neighbours (default); returns the
    global order ``|mean_i psi6_i|`` (1 for a perfect triangular crystal, ~0 for an amorphous or
    polycrystalline packing) and the mean local modulus ``mean_i |psi6_i|``.
    """
    nb = delaunay_neighbours(net) if neighbours is None else neighbours
    a, b = nb.pairs[:, 0], nb.pairs[:, 1]
    th = np.arctan2(nb.branch[:, 1], nb.branch[:, 0])
    z = np.exp(6j * th)  # the same from both ends (theta + pi)
    n = net.n_particles
    s = np.bincount(a, weights=z.real, minlength=n) + np.bincount(b, weights=z.real, minlength=n) \
        + 1j * (np.bincount(a, weights=z.imag, minlength=n) + np.bincount(b, weights=z.imag, minlength=n))
    deg = np.maximum(np.bincount(np.concatenate([a, b]), minlength=n), 1)
    loc = s / deg
    return HexaticOrder(psi6=float(abs(loc.mean())), psi6_local=float(np.abs(loc).mean()))


def _scalars(obj) -> dict:
    """The scalar (or None) entries of a result dataclass or a dict, raw values, in field order."""
    if dataclasses.is_dataclass(obj):
        items = [(f.name, getattr(obj, f.name)) for f in dataclasses.fields(obj)
                 if f.metadata.get("export", True)]
    else:
        items = list(obj.items())
    return {k: v for k, v in items if np.isscalar(v) or v is None}


@dataclass(frozen=True, eq=False)
class PackingSummary(Result):
    """All packing measurements of :func:`summary`.

    statistics : the theory's input statistics (:func:`microhom.structural_sums.network_statistics`);
    stress : (2, 2) Love-Weber stress [N/m], tension positive, or None (no forces or no cell);
    pressure : ``-tr(stress)/2`` [N/m] or None; shear_stress : ``sqrt(((sxx-syy)/2)^2 + sxy^2)``
    [N/m] or None; forces : :class:`ForceStatistics` or None; fabric : :class:`Fabric`;
    near_gap_fraction : gap, in mean diameters, of the near-neighbour count;
    nbar_delaunay : mean Delaunay degree or None; nbar_near : mean number of Delaunay neighbours
    within the gap, or None; hexatic : :class:`HexaticOrder` or None (no cell or N < 3).
    """

    statistics: object
    stress: np.ndarray | None
    pressure: float | None
    shear_stress: float | None
    forces: ForceStatistics | None
    fabric: Fabric
    near_gap_fraction: float
    nbar_delaunay: float | None
    nbar_near: float | None
    hexatic: HexaticOrder | None

    def table(self) -> dict:
        """The flat dict of scalars of the packing's summary table (``packing_summary.csv``):
        the statistics' scalars, ``sxx syy sxy pressure shear_stress``, the force statistics,
        ``fabric_anisotropy``, ``nbar_delaunay``, ``nbar_near_<g>D``, ``psi6``, ``psi6_local``
        (entries that were not measured are absent)."""
        out = _scalars(self.statistics)
        if self.stress is not None:
            s = self.stress
            out.update({"sxx": s[0, 0], "syy": s[1, 1], "sxy": s[0, 1], "pressure": self.pressure,
                        "shear_stress": self.shear_stress})
        if self.forces is not None:
            out.update(_scalars(self.forces))
        out["fabric_anisotropy"] = self.fabric.anisotropy
        if self.hexatic is not None:
            out["nbar_delaunay"] = self.nbar_delaunay
            out[f"nbar_near_{self.near_gap_fraction:g}D"] = self.nbar_near
            out.update(_scalars(self.hexatic))
        return out


def summary(net: ContactNetwork, min_contacts=None, near_gap_fraction=0.1) -> PackingSummary:
    """All packing measurements (see :class:`PackingSummary`; ``table()`` for the flat table)."""
    s = p = tau = forces = nbar = near = hx = None
    if net.fn is not None and net.cell is not None:
        s = stress(net)
        p = float(-np.trace(s) / 2)
        tau = float(np.sqrt(((s[0, 0] - s[1, 1]) / 2) ** 2 + s[0, 1] ** 2))
        forces = force_statistics(net)
    if net.cell is not None and net.n_particles >= 3:
        nb = delaunay_neighbours(net, gap=near_gap_fraction * float(2 * net.radii.mean()))
        nbar, near = nb.mean_degree, nb.near_degree_mean
        hx = hexatic_order(net, nb)
    return PackingSummary(statistics=network_statistics(net, min_contacts), stress=s, pressure=p,
                          shear_stress=tau, forces=forces, fabric=fabric(net),
                          near_gap_fraction=float(near_gap_fraction), nbar_delaunay=nbar,
                          nbar_near=near, hexatic=hx)
