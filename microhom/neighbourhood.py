"""The small assembly of the theory: a particle and its N̄ near neighbours (section 6, eq. (39)).

Two things live here, both about the neighbourhood over which the seed paper sums in (38)-(41):

* **The geometry φ(N̄)** (section 6). A particle of diameter D with N̄ neighbours whose centres sit
  at distance D on a regular N̄-gon: the polygon's area is ``(N̄/2) D² sin(2π/N̄)``; the solids
  inside it are the central disk plus, from each neighbour, the sector cut by the polygon's
  interior angle ``π (N̄ - 2)/N̄``, together ``π N̄ D²/8``. Hence

      φ = (π/4) / sin(π (N̄ - 2)/N̄),        N̄ = 2π / arcsin(π/(4φ))  on the branch N̄ ∈ [4, 6].

  :func:`derive_phi_of_nbar` derives this with sympy from the polygon's vertices (no typed-in
  relation); :func:`nbar_from_phi` is the numeric inverse used by :mod:`microhom.moduli`.
* **The measured neighbourhood** (:func:`near_neighbours`): on a real packing, the N̄ near
  neighbours of each particle, touching or not, as the paper's N̄ counts them. It is the set of
  the ``round(N N̄ / 2)`` pairs with the smallest surface gap ``|c| - r_i - r_j`` (contacts first:
  their gap is <= 0), so that the mean number of neighbours per particle is N̄ (from φ by default).

**Defaults.** :func:`microhom.moduli.predict_moduli` takes N̄ from φ with :func:`nbar_from_phi`
unless ``nbar`` is given, and then, unless ``alpha`` or ``rho`` is given, α = 2(1 - 1/N̄) (the
paper's order-of-magnitude estimate, not a fit). At the seed's statistics (Nc = 4.1, r = 0.35,
φ = 0.82, kt = kn): N̄ = 4.9116; with α = 1.76 the drops are 0.186 (bulk) and 0.279 (shear), against
the seed table's 0.189 and 0.284 with ``nbar=5``; with α from N̄ (1.593) they are 0.219 and 0.328.

This module imports numpy only at the top (sympy inside :func:`derive_phi_of_nbar`, scipy through
:mod:`microhom.network` inside :func:`near_neighbours`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .network import ContactNetwork, _candidate_pairs
from .periodic import heights as periodic_heights
from .results import Result

__all__ = ["PHI_MAX", "PHI_MIN_NBAR", "nbar_from_phi", "nbar_or_substitute", "phi_from_nbar",
           "derive_phi_of_nbar", "near_neighbours", "Neighbourhood"]

PHI_MAX = np.pi / (2 * np.sqrt(3))  # triangular close packing: N̄ = 6
PHI_MIN_NBAR = np.pi / 4  # N̄ = 4: below this phi the relation has no solution on the branch [4, 6]


def _phi_in_range(phi):
    """phi as float64, finite and in [pi/4, pi/(2 sqrt 3)] (1e-12 relative slack); else ValueError."""
    p = np.asarray(phi, dtype=np.float64)
    lo, hi = PHI_MIN_NBAR * (1 - 1e-12), PHI_MAX * (1 + 1e-12)
    bad = ~np.isfinite(p) | (p < lo) | (p > hi)
    if np.any(bad):
        val = float(p.ravel()[np.flatnonzero(np.broadcast_to(bad, p.shape).ravel())[0]])
        raise ValueError(f"phi must be finite and in [{lo:.6g}, {hi:.6g}] (pi/4 to pi/(2 sqrt 3)) to give "
                         f"Nbar from phi = (pi/4)/sin(pi (Nbar-2)/Nbar); got {val!r}")
    return p


def nbar_from_phi(phi):
    """Mean number of near neighbours N̄ from the solid fraction φ (section 6).

    Inverts ``phi = (pi/4)/sin(pi (Nbar - 2)/Nbar)`` on the branch N̄ ∈ [4, 6]:
    ``Nbar = 2 pi / arcsin(pi/(4 phi))``. phi (dimensionless, any shape) must lie in
    [pi/4, pi/(2 sqrt 3)]; the seed's phi = 0.82 gives N̄ = 4.9116 (the paper rounds to 5).
    """
    p = _phi_in_range(phi)
    return 2.0 * np.pi / np.arcsin(np.minimum(np.pi / (4.0 * p), 1.0))


def nbar_or_substitute(phi):
    """N̄ from phi where it exists, else the value at the nearer end of the branch, with a note.

    Returns ``(nbar, note)``: ``note`` is ``""`` when ``phi`` is in ``[pi/4, pi/(2 sqrt 3)]`` and
    ``nbar = nbar_from_phi(phi)``. Below pi/4 (loose packings) φ(N̄) has no solution: N̄ = 4, its
    value at phi = pi/4, is used and the note says so; above close packing (overlaps inflate phi)
    N̄ = 6. phi: a finite scalar solid fraction, > 0.
    """
    phi = float(phi)
    if not (np.isfinite(phi) and phi > 0):
        raise ValueError(f"phi must be finite and > 0, got {phi!r}")
    if phi < PHI_MIN_NBAR * (1 - 1e-12):
        return 4.0, (f"phi = {phi:.4f} below pi/4: Nbar(phi) does not exist; Nbar = 4 (its value at "
                     "phi = pi/4) used")
    if phi > PHI_MAX * (1 + 1e-12):
        return 6.0, (f"phi = {phi:.4f} above close packing pi/(2 sqrt 3): Nbar = 6 (its value at close "
                     "packing) used")
    return float(nbar_from_phi(min(max(phi, PHI_MIN_NBAR), PHI_MAX))), ""


def phi_from_nbar(nbar):
    """φ(N̄) = (π/4)/sin(2π/N̄) (= sin(π(N̄-2)/N̄)), for N̄ in [4, 6] (any shape)."""
    n = np.asarray(nbar, dtype=np.float64)
    if np.any(~np.isfinite(n) | (n < 4 - 1e-12) | (n > 6 + 1e-12)):
        raise ValueError(f"nbar must be finite and in [4, 6] for phi(Nbar); got {nbar!r}")
    return 0.25 * np.pi / np.sin(2.0 * np.pi / n)


@lru_cache(maxsize=None)
def derive_phi_of_nbar():
    """Derive φ(N̄) with sympy from the polygon and its sectors (section 6); no relation typed in.

    Construction: vertices ``P_k = D (cos(k t), sin(k t))``, ``t = 2π/N``, around the central disk
    at the origin. Sympy computes

    * the polygon area as N times the triangle (O, P_0, P_1) by the cross product;
    * the interior angle at a vertex from the dot product of the edges to its two neighbours
      (checked to equal ``π - t`` through its cosine), and the solids: the central disk
      ``π D²/4`` plus N sectors of angle ``π - t`` of disks of radius D/2;
    * φ = solids / area, simplified.

    Returns a dict of sympy expressions in the symbols ``N`` (positive) and ``D``:
    ``area``, ``interior_angle``, ``solids``, ``phi``, and ``angle_ok`` (bool).
    """
    import sympy as sp

    N, D = sp.symbols("N D", positive=True)
    t = 2 * sp.pi / N

    def P(k):
        return sp.Matrix([D * sp.cos(k * t), D * sp.sin(k * t)])

    p0, p1, p2 = P(0), P(1), P(2)
    tri = (p0[0] * p1[1] - p0[1] * p1[0]) / 2  # area of (O, P0, P1), counter-clockwise
    area = sp.simplify(N * tri)
    e1, e2 = p0 - p1, p2 - p1  # edges from P1 to its neighbours
    cos_int = sp.simplify(e1.dot(e2) / (e1.norm() * e2.norm()))
    interior = sp.pi - t
    angle_ok = sp.simplify(cos_int - sp.cos(interior)) == 0
    solids = sp.pi * D ** 2 / 4 + N * interior / (2 * sp.pi) * sp.pi * D ** 2 / 4
    phi = sp.simplify(solids / area)
    return {"N": N, "D": D, "area": area, "interior_angle": interior, "solids": sp.simplify(solids),
            "phi": phi, "angle_ok": bool(angle_ok)}


@dataclass(frozen=True)
class Neighbourhood(Result):
    """The N̄ near neighbours of every particle (:func:`near_neighbours`).

    pairs : (E, 2) int, particle indices of each neighbour pair (each pair once).
    branch : (E, 2) float, ``x_j - x_i`` to the nearest periodic image [m].
    gap : (E,) float, surface gap ``|c| - r_i - r_j`` [m] (<= 0 for overlapping disks).
    degree : (N,) int, number of near neighbours of each particle.
    nbar : float, the target mean number of neighbours per particle (from phi unless given).
    mean_degree : float, the realised mean ``2 E / N`` (equals nbar to within 1/N).
    gap_cutoff : float, the largest gap kept [m].
    """

    pairs: np.ndarray = field(metadata={"export": False})
    branch: np.ndarray = field(metadata={"export": False})
    gap: np.ndarray = field(metadata={"export": False})
    degree: np.ndarray = field(metadata={"export": False})
    nbar: float
    mean_degree: float
    gap_cutoff: float


def near_neighbours(network: ContactNetwork, nbar=None, search=None) -> Neighbourhood:
    """The neighbourhood of (39) measured on a packing: the N̄ near neighbours of each particle.

    The paper's N̄ counts the neighbours around a particle, "not necessarily touching" (section 2,
    section 6), whose mean follows from φ. We take the ``round(N nbar / 2)`` pairs of smallest
    surface gap (so the mean number per particle is N̄; contacts, with gap <= 0, come first).

    Parameters
    ----------
    network : microhom.network.ContactNetwork
        The packing (positions (N, 2) [m], radii (N,) [m], optional periodic cell; images handled).
    nbar : float, optional
        Target mean number of near neighbours, > 0; default
        ``nbar_from_phi(network.solid_fraction)`` (needs phi in ``[pi/4, pi/(2 sqrt 3)]``).
    search : float, optional
        Candidate pairs are looked for up to ``search * 2 r_max`` between centres (> 1). Default:
        1.6, doubled while there are fewer candidates than ``N nbar / 2`` (sparse or small
        packings), up to the whole open packing or half the periodic cell's height.

    Returns
    -------
    Neighbourhood
        The near-neighbour pairs and their branch vectors.
    """
    if nbar is None:
        nbar = float(nbar_from_phi(network.solid_fraction))
    nbar = float(nbar)
    if not (np.isfinite(nbar) and nbar > 0):
        raise ValueError(f"nbar must be finite and > 0, got {nbar!r}")
    adaptive = search is None
    search = 1.6 if adaptive else search
    if not (np.isfinite(search) and search > 1):
        raise ValueError(f"search must be finite and > 1, got {search!r}")
    n = network.n_particles
    rad = network.radii
    m = int(round(n * nbar / 2))
    if n < 2 or m > n * (n - 1) // 2 and network.cell is None:
        raise ValueError(f"nbar = {nbar:g} near neighbours need N nbar/2 = {m} pairs; {n} particles have "
                         f"{n * (n - 1) // 2}")
    d2 = 2.0 * rad.max()
    if network.cell is None:
        span = float(np.ptp(network.positions, axis=0).max()) if n else 0.0
        limit = span + d2           # every pair
    else:
        limit = 0.4999 * float(np.min(periodic_heights(network.cell)))
    while True:
        cut = min(search * d2, limit) if adaptive else search * d2
        i, j, d = _candidate_pairs(network.positions, network.cell, network.origin, cut)
        if len(i) >= m or not adaptive or cut >= limit:
            break
        search *= 2.0
    gap = np.hypot(d[:, 0], d[:, 1]) - rad[i] - rad[j]
    if m > len(gap):
        raise ValueError(f"only {len(gap)} candidate pairs within {cut / d2:.3g} diameters for "
                         f"N nbar/2 = {m}" + (": raise search" if not adaptive else
                                              " (the periodic cell is too small for this nbar)"))
    keep = np.argsort(gap, kind="stable")[:m]
    i, j, d, gap = i[keep], j[keep], d[keep], gap[keep]
    degree = np.bincount(np.concatenate([i, j]), minlength=n)
    return Neighbourhood(pairs=np.stack([i, j], 1), branch=d, gap=gap, degree=degree, nbar=nbar,
                         mean_degree=float(degree.mean()) if n else 0.0,
                         gap_cutoff=float(gap.max()) if m else float("nan"))
