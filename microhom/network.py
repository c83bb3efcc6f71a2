"""The contact network: the one type the DEM (and any reader of other codes' files) hands to the theory.

A :class:`ContactNetwork` is plain arrays and nothing else: particle positions and radii, an
optional periodic cell, and per contact the particle pair, the branch vector, the normal and
tangential stiffnesses, a sliding flag and (optionally) the contact forces.

Conventions (see ``docs/theory.md``):

* 2D, SI units or any consistent set (``docs/theory.md``, "Conventions"): lengths in m, contact
  forces in N, contact stiffnesses in N/m, 2D stresses and moduli in N/m (force per length).
* Contact ``k`` joins particles ``i = pairs[k, 0]`` and ``j = pairs[k, 1]``; its branch vector is
  ``c = x_j - x_i`` taken to the periodic image that touches (paper: ``c^{mu nu} = x^nu - x^mu``).
  The unit normal is ``n = c / |c|``, pointing from ``i`` to ``j``.
* The contact stiffness tensor is ``K = kn n n + kt (I - n n)`` (paper eq. 35); a sliding contact
  is treated as ``kt = 0`` wherever a tangent stiffness is formed (``effective_kt``).
* ``fn`` is the normal force magnitude, compression positive; ``ft`` the tangential force on ``j``
  along ``t = (-n_y, n_x)``. Both optional (needed for stress and for geometric stiffness terms).
* ``cell`` is the 2x2 shape matrix ``h`` whose *columns* are the periodic cell vectors; the cell
  spans ``origin + h @ s`` for fractional ``s`` in [0, 1)^2. ``None`` means no periodicity
  (periodic geometry: :mod:`microhom.periodic`).

Builders: :func:`from_overlaps` (contacts found from positions and radii) and :func:`from_pairs`
(the caller's contact list, in the caller's order). Both take ``kn``, ``kt`` per contact as
scalars, (C,) arrays or functions ``f(i, j, r_i, r_j, overlap)``, or a normal contact ``law`` of
:mod:`microhom.laws` that sets ``kn`` and consistent forces ``fn``; peers' conventions are in
:mod:`microhom.conventions`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from . import periodic
from .limits import as_float_array

__all__ = ["ContactNetwork", "from_overlaps", "from_pairs"]


def _as_float(name, value, shape_tail, allow_none=False):
    if value is None:
        if allow_none:
            return None
        raise ValueError(f"{name} is required")
    arr = np.ascontiguousarray(as_float_array(name, value))
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != tuple(shape_tail):
        raise ValueError(f"{name} must have shape (n, {', '.join(map(str, shape_tail))})"
                         if shape_tail else f"{name} must be a 1-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values (NaN or inf)")
    return arr


def _per_contact(name, value, nc, dtype=np.float64):
    """A scalar or a (nc,) array -> (nc,) array; a wrong length is an error naming ``name``."""
    arr = np.asarray(value, dtype=dtype)
    if arr.ndim == 0:
        return np.full(nc, arr.item(), dtype=dtype)
    if arr.shape != (nc,):
        raise ValueError(
            f"{name} has shape {arr.shape} but the network has {nc} contacts: give a scalar, a "
            f"({nc},) array in the order of `pairs` (from_pairs keeps the caller's order), or a "
            f"function {name}(i, j, r_i, r_j, overlap) evaluated per contact")
    return arr


def _resolve(name, value, i, j, radii, overlap):
    """A per-contact quantity given as a scalar, a (C,) array, or a function of
    ``(i, j, r_i, r_j, overlap)`` -> (C,) float array."""
    if callable(value):
        value = value(i, j, radii[i], radii[j], overlap)
    return _per_contact(name, value, i.shape[0])


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
    fn : (C,) float or None, normal force, compression positive [N].
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
        zero = np.flatnonzero(np.hypot(branch[:, 0], branch[:, 1]) <= 0) if nc else []
        if len(zero):
            k = int(zero[0])
            a, b = (int(v) for v in pairs[k])
            raise ValueError(f"contact {k} between particles {a} and {b}: branch vector of zero "
                             f"length (the centres coincide at ({pos[a, 0]:.6g}, {pos[a, 1]:.6g})"
                             f"{'' if len(zero) == 1 else f'; {len(zero)} such contacts'}): "
                             "coincident particles have no contact direction; remove duplicates")
        kn = _as_float("kn", _per_contact("kn", self.kn, nc), ())
        kt = _as_float("kt", _per_contact("kt", self.kt, nc), ())
        if np.any(kn <= 0):
            raise ValueError("kn must be > 0 for every contact (allowed range: (0, inf) N/m)")
        if np.any(kt < 0):
            raise ValueError("kt must be >= 0 for every contact (allowed range: [0, inf) N/m)")
        sliding = _per_contact("sliding", self.sliding, nc, dtype=bool)
        fn = None if self.fn is None else _as_float("fn", _per_contact("fn", self.fn, nc), ())
        ft = None if self.ft is None else _as_float("ft", _per_contact("ft", self.ft, nc), ())
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
        """Number of particles N."""
        return self.positions.shape[0]

    @property
    def n_contacts(self) -> int:
        """Number of contacts C."""
        return self.pairs.shape[0]

    @property
    def periodic(self) -> bool:
        """True when the network has a periodic cell."""
        return self.cell is not None

    # ---- per-contact geometry ----------------------------------------------------------------
    @property
    def lengths(self) -> np.ndarray:
        """(C,) branch lengths ``|c|`` [m]."""
        return np.hypot(self.branch[:, 0], self.branch[:, 1])

    @property
    def normals(self) -> np.ndarray:
        """(C, 2) unit contact normals ``n = c/|c|``, from particle i to particle j."""
        return self.branch / self.lengths[:, None]

    @property
    def overlaps(self) -> np.ndarray:
        """(C,) overlaps ``r_i + r_j - |c|`` [m], positive when the disks overlap."""
        return self.radii[self.pairs[:, 0]] + self.radii[self.pairs[:, 1]] - self.lengths

    @property
    def effective_kt(self) -> np.ndarray:
        """(C,) tangent stiffness [N/m] used by the theory and the stiffness solver (``kt``, 0 where sliding)."""
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
        direct = self.positions[self.pairs[:, 1]] - self.positions[self.pairs[:, 0]]
        return periodic.image_shifts(self.branch, direct, self.cell)

    # ---- derived networks -------------------------------------------------------------------
    def _resolve(self, name, value):
        return _resolve(name, value, self.pairs[:, 0], self.pairs[:, 1], self.radii, self.overlaps)

    def with_stiffness(self, kn=None, kt=None, sliding=None) -> "ContactNetwork":
        """A copy with new contact stiffnesses and/or sliding flags.

        Each of ``kn``, ``kt`` [N/m] is a scalar, a (C,) array in the order of ``pairs``, or a
        function ``f(i, j, r_i, r_j, overlap)`` of (C,) arrays returning (C,) values (``overlap``
        = :attr:`overlaps`); ``None`` keeps the current values.
        """
        return replace(self,
                       kn=self.kn if kn is None else self._resolve("kn", kn),
                       kt=self.kt if kt is None else self._resolve("kt", kt),
                       sliding=self.sliding if sliding is None
                       else _per_contact("sliding", sliding, self.n_contacts, dtype=bool))

    def with_law(self, law, kt=None) -> "ContactNetwork":
        """A copy whose ``kn`` (tangent stiffness) and ``fn`` come from a normal contact ``law``
        (:mod:`microhom.laws`) at the current overlaps; ``kt`` as in :meth:`with_stiffness`,
        default ``law.kt_ratio * kn``. ``ft`` is kept. Every contact must overlap enough for a
        positive stiffness (``kn > 0``)."""
        ri, rj = self.radii[self.pairs[:, 0]], self.radii[self.pairs[:, 1]]
        kn = law.stiffness(ri, rj, self.overlaps)
        kt = law.kt_ratio * kn if kt is None else self._resolve("kt", kt)
        return replace(self, kn=kn, kt=kt, fn=law.force(ri, rj, self.overlaps))

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
    periodic orthogonal case with ``boxsize``; a sheared cell with the boundary images of
    :func:`microhom.periodic.boundary_images`.
    """
    if cell is None:
        tree = cKDTree(positions)
        pairs = tree.query_pairs(cutoff, output_type="ndarray")
        i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        return i, j, positions[j] - positions[i]

    # heights of the cell perpendicular to each cell vector: every height must exceed 2*cutoff
    heights = periodic.heights(cell)
    if np.any(heights <= 2 * cutoff):
        raise ValueError(
            f"periodic cell too small: its heights {heights} must exceed twice the contact cutoff "
            f"{cutoff:.6g} (a particle would touch two images of the same neighbour)")
    n = positions.shape[0]
    if abs(cell[0, 1]) == 0 and abs(cell[1, 0]) == 0:
        wrapped, _ = periodic.wrap(positions, cell, origin)
        box = np.array([cell[0, 0], cell[1, 1]])
        local = np.mod(wrapped - origin, box)
        local = np.where(local >= box, 0.0, local)  # guard against round-off at the upper edge
        tree = cKDTree(local, boxsize=box)
        pairs = tree.query_pairs(cutoff, output_type="ndarray")
        i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        d = local[j] - local[i]
        d = periodic.minimum_image(d, cell)
    else:
        # sheared cell: the particles plus the images of those within `cutoff` of an edge
        images, owner = periodic.boundary_images(positions, cell, origin, cutoff)
        wrapped = images[:n]
        sdm = cKDTree(wrapped).sparse_distance_matrix(cKDTree(images), cutoff, output_type="ndarray")
        i = sdm["i"].astype(np.int64)
        img = sdm["j"].astype(np.int64)
        j = owner[img]
        keep = i < j
        i, j, img = i[keep], j[keep], img[keep]
        d = images[img] - wrapped[i]
    return i, j, d  # a branch vector is the same whichever image represents a particle


def _check_geometry(positions, radii):
    positions = _as_float("positions", positions, (2,))
    n = positions.shape[0]
    if n == 0:
        raise ValueError("positions holds no particles (shape (0, 2)): a network needs at least "
                         "one particle")
    radii = as_float_array("radii", radii, unit=" [m]")
    if radii.ndim and radii.shape != (n,):
        raise ValueError(f"radii must be a scalar or have shape ({n},) like positions, got {radii.shape}")
    radii = _as_float("radii", np.broadcast_to(radii, (n,)), ())
    bad = np.flatnonzero(~(radii > 0))
    if bad.size:
        raise ValueError(f"radii must be > 0 [m]; particle {int(bad[0])} has {float(radii[bad[0]])!r}")
    return positions, radii


def _check_cell(cell):
    """The periodic shape matrix as a finite, non-singular (2, 2) float array (None stays None)."""
    if cell is None:
        return None
    cell = as_float_array("cell", cell, unit=" [m]")
    if cell.shape != (2, 2) or not np.all(np.isfinite(cell)):
        raise ValueError(f"cell must be a finite 2x2 matrix whose columns are the periodic vectors "
                         f"[m], or None (open boundaries); got shape {cell.shape}")
    area = abs(float(np.linalg.det(cell)))
    if not area > 1e-12 * float(np.abs(cell).max()) ** 2:
        raise ValueError(f"cell must have a positive area (non-singular shape matrix, columns = "
                         f"periodic vectors); got {cell.tolist()} with area {area:.3g}")
    return cell


def _finish(positions, radii, cell, origin, i, j, d, *, kn, kt, sliding, law, fn=None, ft=None):
    """The network of contacts (i, j, branch d), stiffness and forces resolved per contact."""
    dist = np.hypot(d[:, 0], d[:, 1])
    overlap = radii[i] + radii[j] - dist
    if law is not None:
        if kn is not None:
            raise ValueError("give either kn or law (the law sets kn = d fn / d overlap), not both")
        if fn is not None:
            raise ValueError("give either fn or law (the law sets fn from the overlap), not both")
        kn = law.stiffness(radii[i], radii[j], overlap)
        fn = law.force(radii[i], radii[j], overlap)
        kt = law.kt_ratio * kn if kt is None else _resolve("kt", kt, i, j, radii, overlap)
    else:
        kn = _resolve("kn", 1.0 if kn is None else kn, i, j, radii, overlap)
        kt = kn if kt is None else _resolve("kt", kt, i, j, radii, overlap)
        if fn is not None:
            fn = _resolve("fn", fn, i, j, radii, overlap)
    return ContactNetwork(positions=positions, radii=radii, cell=cell,
                          pairs=np.stack([i, j], axis=1).reshape(-1, 2), branch=d.reshape(-1, 2),
                          kn=kn, kt=kt, sliding=_per_contact("sliding", sliding, i.shape[0], bool),
                          fn=fn, ft=None if ft is None else _per_contact("ft", ft, i.shape[0]),
                          origin=origin)


def from_overlaps(positions, radii, cell=None, *, kn=None, kt=None, sliding=False, law=None,
                  branch_length="distance", tolerance=None, origin=(0.0, 0.0)) -> ContactNetwork:
    """Build a :class:`ContactNetwork` from particle positions, radii and an optional periodic cell.

    Contacts are the pairs whose centre distance ``d`` satisfies ``d <= (r_i + r_j)(1 + tolerance)``
    (overlapping or touching disks; the small default tolerance keeps exactly touching lattice
    neighbours). Polydisperse radii are allowed. Contacts are sorted by ``(i, j)``, ``i < j``.

    Parameters
    ----------
    positions : (N, 2) particle centres [m].
    radii : (N,) radii [m], or a scalar for identical disks.
    cell : (2, 2) periodic shape matrix (columns = cell vectors) [m], or None (open boundaries).
    kn, kt : contact stiffnesses [N/m]: scalars, (C,) arrays in the order of the result, or
        functions ``f(i, j, r_i, r_j, overlap)`` of (C,) arrays returning (C,) values (overlap
        ``r_i + r_j - d`` [m]), e.g. ``kn=lambda i, j, ri, rj, ov: 1 / (ri + rj)**2``.
        ``kn=None`` means 1 (or the law's); ``kt=None`` means ``kt = kn`` (``law.kt_ratio * kn``
        with a law).
    sliding : bool or (C,) flags.
    law : a normal contact law of :mod:`microhom.laws` (e.g. ``laws.harmonic()`` for jax-md's
        harmonic soft disks): sets ``kn`` to its tangent stiffness and ``fn`` to its force at each
        overlap. Only pairs that overlap (``d < r_i + r_j``) are contacts then, and the default
        ``tolerance`` is 0.
    branch_length : ``"distance"`` (default) keeps the centre-to-centre vector as the branch
        vector; ``"radii"`` keeps its direction but sets its length to ``r_i + r_j`` (the
        undeformed-contact convention of the paper, where ``|c| = D``).
    tolerance : relative gap still counted as contact, in [0, 0.5); default 1e-9 (0 with a law).
    origin : (2,) lower-left corner of the periodic cell [m].
    """
    positions, radii = _check_geometry(positions, radii)
    if tolerance is None:
        tolerance = 0.0 if law is not None else 1e-9
    if not (0 <= tolerance < 0.5):
        raise ValueError(f"tolerance must be in [0, 0.5), got {tolerance}")
    if branch_length not in ("distance", "radii"):
        raise ValueError(f"branch_length must be 'distance' or 'radii', got {branch_length!r}")
    if law is not None and branch_length != "distance":
        raise ValueError("a law needs the actual overlaps: use branch_length='distance'")
    cell_arr = _check_cell(cell)
    origin = as_float_array("origin", origin, unit=" [m]")
    if origin.shape != (2,) or not np.all(np.isfinite(origin)):
        raise ValueError(f"origin must be a finite (2,) point [m], got shape {origin.shape}")
    cutoff = 2.0 * radii.max() * (1.0 + tolerance)
    i, j, d = _candidate_pairs(positions, cell_arr, origin, cutoff)
    dist = np.hypot(d[:, 0], d[:, 1])
    rs = radii[i] + radii[j]
    touch = dist < rs if law is not None else dist <= rs * (1.0 + tolerance)
    i, j, d, dist = i[touch], j[touch], d[touch], dist[touch]
    order = np.lexsort((j, i))
    i, j, d, dist = i[order], j[order], d[order], dist[order]
    if branch_length == "radii":
        d = d * ((radii[i] + radii[j]) / dist)[:, None]
    return _finish(positions, radii, cell_arr, origin, i, j, d, kn=kn, kt=kt, sliding=sliding, law=law)


def from_pairs(positions, radii, cell, pairs, *, shifts=None, kn=None, kt=None, sliding=False,
               fn=None, ft=None, law=None, origin=(0.0, 0.0)) -> ContactNetwork:
    """Build a :class:`ContactNetwork` on the caller's contact list, in the caller's order.

    Use it when per-contact data (stiffness, forces) come from another code aligned with its own
    pair list: row ``k`` of every array is contact ``pairs[k]``.

    Parameters
    ----------
    positions, radii, cell, origin : as :func:`from_overlaps`.
    pairs : (C, 2) int particle indices ``(i, j)``, ``i != j``; the branch vector is
        ``x_j - x_i``.
    shifts : (C, 2) int image counts ``k`` with branch ``x_j + h k - x_i``; default: the minimum
        image (requires both cell heights to exceed twice the largest ``r_i + r_j``).
    kn, kt, sliding, law : as :func:`from_overlaps` (arrays of length C in the order of ``pairs``,
        or functions of ``(i, j, r_i, r_j, overlap)``).
    fn, ft : normal (compression positive) and tangential forces [N], scalars, (C,) arrays or
        functions; ``fn`` is set by ``law`` if one is given.
    """
    positions, radii = _check_geometry(positions, radii)
    pairs = np.asarray(pairs)
    if pairs.ndim != 2 or pairs.shape[1] != 2 or (pairs.size and not np.issubdtype(pairs.dtype, np.integer)):
        raise ValueError(f"pairs must be a (C, 2) integer array, got shape {pairs.shape}, dtype {pairs.dtype}")
    i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
    n = positions.shape[0]
    if i.size and (min(i.min(), j.min()) < 0 or max(i.max(), j.max()) >= n):
        raise ValueError(f"pairs contains particle indices outside [0, {n})")
    cell_arr = _check_cell(cell)
    origin = as_float_array("origin", origin, unit=" [m]")
    d = positions[j] - positions[i]
    if shifts is not None:
        if cell_arr is None:
            raise ValueError("shifts need a periodic cell")
        shifts = np.asarray(shifts)
        if shifts.shape != pairs.shape:
            raise ValueError(f"shifts must have the shape of pairs {pairs.shape}, got {shifts.shape}")
        d = d + shifts @ cell_arr.T
    elif cell_arr is not None:
        reach = float((radii[i] + radii[j]).max(initial=0.0))
        if np.any(periodic.heights(cell_arr) <= 2 * reach):
            raise ValueError(f"the minimum image is ambiguous: the cell heights {periodic.heights(cell_arr)} "
                             f"must exceed twice the largest contact distance r_i + r_j = {reach:.6g} "
                             f"(a particle could touch two images of one neighbour); pass shifts")
        d = periodic.minimum_image(d, cell_arr)
    return _finish(positions, radii, cell_arr, origin, i, j, d, kn=kn, kt=kt, sliding=sliding,
                   law=law, fn=fn, ft=ft)
