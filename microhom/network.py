"""The contact network: the one type the DEM (and any reader of other codes' files) hands to the theory.

A :class:`ContactNetwork` is plain arrays and nothing else: particle positions and radii, an
optional periodic cell, and per contact the particle pair, the branch vector, the normal and
tangential stiffnesses, a sliding flag and (optionally) the contact forces.

Conventions (see ``docs/theory.md``):

* 2D, SI units or any consistent set. Lengths in m, stiffnesses per unit thickness in N/m,
  forces per unit thickness in N/m (2D) or N if you think of disks of unit thickness.
* Contact ``k`` joins particles ``i = pairs[k, 0]`` and ``j = pairs[k, 1]``; its branch vector is
  ``c = x_j - x_i`` taken to the periodic image that touches (paper: ``c^{mu nu} = x^nu - x^mu``).
  The unit normal is ``n = c / |c|``, pointing from ``i`` to ``j``.
* The contact stiffness tensor is ``K = kn n n + kt (I - n n)`` (paper eq. 35); a sliding contact
  is treated as ``kt = 0`` wherever a tangent stiffness is formed (``effective_kt``).
* ``fn`` is the normal force magnitude, compression positive; ``ft`` the tangential force on ``j``
  along ``t = (-n_y, n_x)``. Both optional (needed for stress and for geometric stiffness terms).
* ``cell`` is the 2x2 shape matrix ``h`` whose *columns* are the periodic cell vectors; the cell
  spans ``origin + h @ s`` for fractional ``s`` in [0, 1)^2. ``None`` means no periodicity.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["ContactNetwork", "from_overlaps"]


def _as_float(name, value, shape_tail, allow_none=False):
    if value is None:
        if allow_none:
            return None
        raise ValueError(f"{name} is required")
    arr = np.ascontiguousarray(value, dtype=np.float64)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != tuple(shape_tail):
        raise ValueError(f"{name} must have shape (n, {', '.join(map(str, shape_tail))})"
                         if shape_tail else f"{name} must be a 1-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values (NaN or inf)")
    return arr


@dataclass(frozen=True, eq=False)
class ContactNetwork:
    """A 2D contact network of disks. All arrays are read-only views after construction.

    Parameters
    ----------
    positions : (N, 2) float, particle centres [m].
    radii : (N,) float, particle radii [m], > 0.
    cell : (2, 2) float or None, periodic shape matrix, columns = cell vectors [m].
    pairs : (C, 2) int, particle indices of each contact.
    branch : (C, 2) float, branch vectors ``x_j - x_i`` (periodic image resolved) [m].
    kn, kt : (C,) float, normal and tangential contact stiffness [N/m], kn > 0, kt >= 0.
    sliding : (C,) bool, contacts at the Coulomb limit (their tangent ``kt`` is taken as 0).
    fn : (C,) float or None, normal force, compression positive [N/m per unit thickness].
    ft : (C,) float or None, tangential force on j along t = (-n_y, n_x).
    origin : (2,) float, lower-left corner of the periodic cell [m].
    """

    positions: np.ndarray
    radii: np.ndarray
    cell: np.ndarray | None
    pairs: np.ndarray
    branch: np.ndarray
    kn: np.ndarray
    kt: np.ndarray
    sliding: np.ndarray
    fn: np.ndarray | None = None
    ft: np.ndarray | None = None
    origin: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def __post_init__(self):
        pos = _as_float("positions", self.positions, (2,))
        rad = _as_float("radii", self.radii, ())
        if rad.shape[0] != pos.shape[0]:
            raise ValueError(f"radii has {rad.shape[0]} entries but positions has {pos.shape[0]}")
        if np.any(rad <= 0):
            raise ValueError("radii must be > 0")
        cell = None
        if self.cell is not None:
            cell = np.array(self.cell, dtype=np.float64)
            if cell.shape != (2, 2) or not np.all(np.isfinite(cell)):
                raise ValueError("cell must be a finite 2x2 matrix (columns = cell vectors) or None")
            if abs(np.linalg.det(cell)) <= 0:
                raise ValueError("cell must have a positive area (non-singular shape matrix)")
        pairs = np.ascontiguousarray(self.pairs, dtype=np.int64).reshape(-1, 2)
        nc = pairs.shape[0]
        if nc and (pairs.min() < 0 or pairs.max() >= pos.shape[0]):
            raise ValueError("pairs contains particle indices outside [0, N)")
        if nc and np.any(pairs[:, 0] == pairs[:, 1]):
            raise ValueError("pairs contains a particle in contact with itself")
        branch = _as_float("branch", np.reshape(self.branch, (-1, 2)), (2,))
        if branch.shape[0] != nc:
            raise ValueError(f"branch has {branch.shape[0]} rows but pairs has {nc}")
        if nc and np.any(np.hypot(branch[:, 0], branch[:, 1]) <= 0):
            raise ValueError("branch vectors must have a positive length")
        kn = _as_float("kn", np.broadcast_to(self.kn, (nc,)), ())
        kt = _as_float("kt", np.broadcast_to(self.kt, (nc,)), ())
        if np.any(kn <= 0):
            raise ValueError("kn must be > 0 for every contact (allowed range: (0, inf) N/m)")
        if np.any(kt < 0):
            raise ValueError("kt must be >= 0 for every contact (allowed range: [0, inf) N/m)")
        sliding = np.ascontiguousarray(np.broadcast_to(self.sliding, (nc,)), dtype=bool)
        fn = None if self.fn is None else _as_float("fn", np.broadcast_to(self.fn, (nc,)), ())
        ft = None if self.ft is None else _as_float("ft", np.broadcast_to(self.ft, (nc,)), ())
        origin = _as_float("origin", np.reshape(self.origin, (1, 2)), (2,))[0]
        for name, arr in (("positions", pos), ("radii", rad), ("cell", cell), ("pairs", pairs),
                          ("branch", branch), ("kn", kn), ("kt", kt), ("sliding", sliding),
                          ("fn", fn), ("ft", ft), ("origin", origin)):
            if arr is not None:
                arr = np.array(arr, copy=True)
                arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    # ---- sizes -------------------------------------------------------------------------------
    @property
    def n_particles(self) -> int:
        return self.positions.shape[0]

    @property
    def n_contacts(self) -> int:
        return self.pairs.shape[0]

    @property
    def periodic(self) -> bool:
        return self.cell is not None

    # ---- per-contact geometry ----------------------------------------------------------------
    @property
    def lengths(self) -> np.ndarray:
        """(C,) branch lengths |c| [m]."""
        return np.hypot(self.branch[:, 0], self.branch[:, 1])

    @property
    def normals(self) -> np.ndarray:
        """(C, 2) unit contact normals n = c/|c|, from particle i to particle j."""
        return self.branch / self.lengths[:, None]

    @property
    def effective_kt(self) -> np.ndarray:
        """(C,) tangent stiffness used by the theory and the stiffness solver: kt, 0 where sliding."""
        return np.where(self.sliding, 0.0, self.kt)

    def stiffness_tensors(self) -> np.ndarray:
        """(C, 2, 2) contact stiffness tensors K = kn n n + kt_eff (I - n n) [N/m] (eq. 35)."""
        n = self.normals
        nn = n[:, :, None] * n[:, None, :]
        kt = self.effective_kt
        return (self.kn - kt)[:, None, None] * nn + kt[:, None, None] * np.eye(2)

    # ---- per-particle counts -----------------------------------------------------------------
    def contact_counts(self) -> np.ndarray:
        """(N,) number of contacts of each particle."""
        return np.bincount(self.pairs.ravel(), minlength=self.n_particles)

    # ---- cell -------------------------------------------------------------------------------
    @property
    def area(self) -> float:
        """Area of the periodic cell [m^2]; for a non-periodic network, of the particles' bounding box."""
        if self.cell is not None:
            return float(abs(np.linalg.det(self.cell)))
        lo = (self.positions - self.radii[:, None]).min(axis=0)
        hi = (self.positions + self.radii[:, None]).max(axis=0)
        return float(np.prod(hi - lo))

    @property
    def solid_fraction(self) -> float:
        """Solid (area) fraction phi = sum(pi r^2) / area."""
        return float(np.pi * np.sum(self.radii ** 2) / self.area)

    def image_shifts(self) -> np.ndarray:
        """(C, 2) integer image shifts s with c = x_j + h s - x_i (zeros if not periodic)."""
        if self.cell is None:
            return np.zeros((self.n_contacts, 2), dtype=np.int64)
        d = self.branch - (self.positions[self.pairs[:, 1]] - self.positions[self.pairs[:, 0]])
        return np.rint(np.linalg.solve(self.cell, d.T).T).astype(np.int64)

    # ---- derived networks -------------------------------------------------------------------
    def with_stiffness(self, kn=None, kt=None, sliding=None) -> "ContactNetwork":
        """A copy with new contact stiffnesses (scalars broadcast) and/or sliding flags."""
        return replace(self,
                       kn=self.kn if kn is None else np.broadcast_to(kn, (self.n_contacts,)),
                       kt=self.kt if kt is None else np.broadcast_to(kt, (self.n_contacts,)),
                       sliding=self.sliding if sliding is None
                       else np.broadcast_to(sliding, (self.n_contacts,)))

    def select_contacts(self, mask) -> "ContactNetwork":
        """A copy keeping only the contacts where ``mask`` is True (particles are kept)."""
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (self.n_contacts,):
            raise ValueError(f"mask must have shape ({self.n_contacts},)")
        return replace(self, pairs=self.pairs[mask], branch=self.branch[mask], kn=self.kn[mask],
                       kt=self.kt[mask], sliding=self.sliding[mask],
                       fn=None if self.fn is None else self.fn[mask],
                       ft=None if self.ft is None else self.ft[mask])

    def translated(self, shift) -> "ContactNetwork":
        """The same network with every position moved by ``shift`` (2,) [m]; branches unchanged."""
        return replace(self, positions=self.positions + np.asarray(shift, dtype=float))

    def __repr__(self):
        cell = "periodic" if self.periodic else "open"
        return (f"ContactNetwork(N={self.n_particles}, contacts={self.n_contacts}, {cell}, "
                f"phi={self.solid_fraction:.4f})")


def _candidate_pairs(positions, cell, origin, cutoff):
    """All pairs (i, j, shift) with centre distance <= cutoff, i < j or (i == j never).

    Returns arrays i, j (int64) and branch vectors (x_j + h s - x_i). Uses scipy's cKDTree: the
    periodic orthogonal case with ``boxsize``; a sheared cell by tiling the 3x3 images.
    """
    from scipy.spatial import cKDTree

    n = positions.shape[0]
    if cell is None:
        tree = cKDTree(positions)
        pairs = tree.query_pairs(cutoff, output_type="ndarray")
        i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        return i, j, positions[j] - positions[i]

    # heights of the cell perpendicular to each cell vector: every height must exceed 2*cutoff
    a1, a2 = cell[:, 0], cell[:, 1]
    area = abs(np.linalg.det(cell))
    heights = np.array([area / np.linalg.norm(a2), area / np.linalg.norm(a1)])
    if np.any(heights <= 2 * cutoff):
        raise ValueError(
            f"periodic cell too small: its heights {heights} must exceed twice the contact cutoff "
            f"{cutoff:.6g} (a particle would touch two images of the same neighbour)")
    frac = np.linalg.solve(cell, (positions - origin).T).T
    frac -= np.floor(frac)
    wrapped = origin + frac @ cell.T
    if abs(cell[0, 1]) == 0 and abs(cell[1, 0]) == 0:
        box = np.array([cell[0, 0], cell[1, 1]])
        local = np.mod(wrapped - origin, box)
        local = np.where(local >= box, 0.0, local)  # guard against round-off at the upper edge
        tree = cKDTree(local, boxsize=box)
        pairs = tree.query_pairs(cutoff, output_type="ndarray")
        i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        d = local[j] - local[i]
        d -= box * np.rint(d / box)
    else:
        # sheared cell: the particles plus the images of those within `cutoff` of an edge
        fm = cutoff / heights  # margin in fractional units per cell direction
        pts, own = [wrapped], [np.arange(n)]
        for a in (-1, 0, 1):
            for b in (-1, 0, 1):
                if a == 0 and b == 0:
                    continue
                f = frac + np.array([a, b], dtype=float)
                near = np.all((f > -fm) & (f < 1 + fm), axis=1)
                pts.append(origin + f[near] @ cell.T)
                own.append(np.flatnonzero(near))
        images = np.concatenate(pts)
        owner = np.concatenate(own)
        sdm = cKDTree(wrapped).sparse_distance_matrix(cKDTree(images), cutoff, output_type="ndarray")
        i = sdm["i"].astype(np.int64)
        img = sdm["j"].astype(np.int64)
        j = owner[img]
        keep = i < j
        i, j, img = i[keep], j[keep], img[keep]
        d = images[img] - wrapped[i]
    return i, j, d  # a branch vector is the same whichever image represents a particle


def from_overlaps(positions, radii, cell=None, *, kn=1.0, kt=None, sliding=False,
                  branch_length="distance", tolerance=1e-9, origin=(0.0, 0.0)) -> ContactNetwork:
    """Build a :class:`ContactNetwork` from particle positions, radii and an optional periodic cell.

    Contacts are the pairs whose centre distance ``d`` satisfies ``d <= (r_i + r_j)(1 + tolerance)``
    (overlapping or touching disks; the small default tolerance keeps exactly touching lattice
    neighbours). Polydisperse radii are allowed.

    Parameters
    ----------
    positions : (N, 2) particle centres [m].
    radii : (N,) radii [m], or a scalar for identical disks.
    cell : (2, 2) periodic shape matrix (columns = cell vectors) [m], or None (open boundaries).
    kn, kt : contact stiffnesses [N/m], scalars or (C,) arrays in the order of the result;
        ``kt=None`` means ``kt = kn``.
    sliding : bool or (C,) flags.
    branch_length : ``"distance"`` (default) keeps the centre-to-centre vector as the branch
        vector; ``"radii"`` keeps its direction but sets its length to ``r_i + r_j`` (the
        undeformed-contact convention of the paper, where |c| = D).
    tolerance : relative gap still counted as contact, in [0, 0.5).
    origin : (2,) lower-left corner of the periodic cell [m].
    """
    positions = _as_float("positions", positions, (2,))
    n = positions.shape[0]
    radii = _as_float("radii", np.broadcast_to(radii, (n,)), ())
    if np.any(radii <= 0):
        raise ValueError("radii must be > 0")
    if not (0 <= tolerance < 0.5):
        raise ValueError(f"tolerance must be in [0, 0.5), got {tolerance}")
    if branch_length not in ("distance", "radii"):
        raise ValueError(f"branch_length must be 'distance' or 'radii', got {branch_length!r}")
    cell_arr = None if cell is None else np.asarray(cell, dtype=np.float64)
    origin = np.asarray(origin, dtype=np.float64)
    cutoff = 2.0 * radii.max() * (1.0 + tolerance)
    i, j, d = _candidate_pairs(positions, cell_arr, origin, cutoff)
    dist = np.hypot(d[:, 0], d[:, 1])
    touch = dist <= (radii[i] + radii[j]) * (1.0 + tolerance)
    i, j, d, dist = i[touch], j[touch], d[touch], dist[touch]
    order = np.lexsort((j, i))
    i, j, d, dist = i[order], j[order], d[order], dist[order]
    if branch_length == "radii":
        d = d * ((radii[i] + radii[j]) / dist)[:, None]
    kt = kn if kt is None else kt
    return ContactNetwork(positions=positions, radii=radii, cell=cell_arr,
                          pairs=np.stack([i, j], axis=1), branch=d,
                          kn=np.broadcast_to(kn, i.shape), kt=np.broadcast_to(kt, i.shape),
                          sliding=np.broadcast_to(sliding, i.shape), origin=origin)
