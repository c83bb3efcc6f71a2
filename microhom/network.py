"""The contact network: the one type the DEM (and any reader of other codes' files) hands to the theory.

A :class:`ContactNetwork` is plain arrays and nothing else: particle positions and radii, an
optional periodic cell, and per contact the particle pair, the branch vector, the normal and
tangential stiffnesses, a sliding flag and (optionally) the contact forces.

Conventions (see ``docs/theory.md``):

* 2D disks or 3D spheres (the dimension d is taken from the data: positions (N, d), d = 2 or 3),
  SI units or any consistent set (``docs/theory.md``, "Conventions"): lengths in m, contact
  forces in N, contact stiffnesses in N/m, 2D stresses and moduli in N/m (force per length), 3D
  ones in Pa.
* Contact ``k`` joins particles ``i = pairs[k, 0]`` and ``j = pairs[k, 1]``; its branch vector is
  ``c = x_j - x_i`` taken to the periodic image that touches (paper: ``c^{mu nu} = x^nu - x^mu``).
  The unit normal is ``n = c / |c|``, pointing from ``i`` to ``j``.
* The contact stiffness tensor is ``K = kn n n + kt (I - n n)`` (paper eq. 35); a sliding contact
  is treated as ``kt = 0`` wherever a tangent stiffness is formed (``effective_kt``).
* ``fn`` is the normal force magnitude, compression positive; ``ft`` the tangential force on ``j``:
  in 2D a scalar along ``t = (-n_y, n_x)``, in 3D a vector (C, 3) normal to ``n``. Both optional
  (needed for stress and for geometric stiffness terms).
* ``cell`` is the d x d shape matrix ``h`` whose *columns* are the periodic cell vectors; the cell
  spans ``origin + h @ s`` for fractional ``s`` in [0, 1)^d. ``None`` means no periodicity
  (periodic geometry: :mod:`microhom.periodic`).

Builders: :func:`from_overlaps` (contacts found from positions and radii) and :func:`from_pairs`
(the caller's contact list, in the caller's order). Both take ``kn``, ``kt`` per contact as
scalars, (C,) arrays or functions ``f(i, j, r_i, r_j, overlap)``, or a normal contact ``law`` of
:mod:`microhom.laws` that sets ``kn`` and consistent forces ``fn``; peers' conventions are in
:mod:`microhom.conventions`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

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
    """A contact network of disks (2D) or spheres (3D). All arrays are read-only after construction.

    The dimension ``d`` (2 or 3) is the number of columns of ``positions``; every other array
    follows it.

    Parameters
    ----------
    positions : (N, d) float, particle centres [m].
    radii : (N,) float, particle radii [m], > 0.
    cell : (d, d) float or None, periodic shape matrix, columns = cell vectors [m].
    pairs : (C, 2) int, particle indices of each contact.
    branch : (C, d) float, branch vectors ``x_j - x_i`` (periodic image resolved) [m].
    kn, kt : (C,) float, normal and tangential contact stiffness [N/m], kn > 0, kt >= 0.
    sliding : (C,) bool, contacts at the Coulomb limit (their tangent ``kt`` is taken as 0).
    fn : (C,) float or None, normal force, compression positive [N].
    ft : tangential force on j [N] or None: (C,) along t = (-n_y, n_x) in 2D, (C, 3) in 3D.
    origin : (d,) float, lower-left corner of the periodic cell [m] (default zeros).
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
    origin: np.ndarray | None = None

    def __post_init__(self):
        shape = np.shape(self.positions)
        if len(shape) != 2 or shape[1] not in (2, 3):
            raise ValueError(f"positions must have shape (N, 2) for disks or (N, 3) for spheres, "
                             f"got {shape}")
        dim = shape[1]
        pos = _as_float("positions", self.positions, (dim,))
        rad = _as_float("radii", self.radii, ())
        if rad.shape[0] != pos.shape[0]:
            raise ValueError(f"radii has {rad.shape[0]} entries but positions has {pos.shape[0]}")
        if np.any(rad <= 0):
            raise ValueError("radii must be > 0")
        cell = None
        if self.cell is not None:
            cell = np.array(self.cell, dtype=np.float64)
            if cell.shape != (dim, dim) or not np.all(np.isfinite(cell)):
                raise ValueError(f"cell must be a finite {dim}x{dim} matrix (columns = cell vectors) "
                                 f"or None, got shape {cell.shape}")
            if abs(np.linalg.det(cell)) <= 0:
                raise ValueError("cell must have a positive area/volume (non-singular shape matrix)")
        pairs = np.ascontiguousarray(self.pairs, dtype=np.int64).reshape(-1, 2)
        nc = pairs.shape[0]
        if nc and (pairs.min() < 0 or pairs.max() >= pos.shape[0]):
            raise ValueError("pairs contains particle indices outside [0, N)")
        if nc and np.any(pairs[:, 0] == pairs[:, 1]):
            raise ValueError("pairs contains a particle in contact with itself")
        branch = _as_float("branch", np.reshape(self.branch, (-1, dim)), (dim,))
        if branch.shape[0] != nc:
            raise ValueError(f"branch has {branch.shape[0]} rows but pairs has {nc}")
        zero = np.flatnonzero(_norms(branch) <= 0) if nc else []
        if len(zero):
            k = int(zero[0])
            a, b = (int(v) for v in pairs[k])
            where = ", ".join(f"{v:.6g}" for v in pos[a])
            raise ValueError(f"contact {k} between particles {a} and {b}: branch vector of zero "
                             f"length (the centres coincide at ({where})"
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
        if self.ft is None:
            ft = None
        elif dim == 2:
            ft = _as_float("ft", _per_contact("ft", self.ft, nc), ())
        else:
            ft = _as_float("ft", np.reshape(self.ft, (-1, 3)), (3,))
            if ft.shape[0] != nc:
                raise ValueError(f"ft has {ft.shape[0]} rows but the network has {nc} contacts "
                                 "(3D: one tangential force vector per contact, shape (C, 3))")
        origin = np.zeros(dim) if self.origin is None else self.origin
        origin = _as_float("origin", np.reshape(origin, (1, -1)), (dim,))[0]
        for name, arr in (("positions", pos), ("radii", rad), ("cell", cell), ("pairs", pairs),
                          ("branch", branch), ("kn", kn), ("kt", kt), ("sliding", sliding),
                          ("fn", fn), ("ft", ft), ("origin", origin)):
            if arr is not None:
                arr = np.array(arr, copy=True)
                arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    # ---- sizes -------------------------------------------------------------------------------
    @property
    def dim(self) -> int:
        """The dimension d, 2 for disks and 3 for spheres."""
        return self.positions.shape[1]

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
        return _norms(self.branch)

    @property
    def normals(self) -> np.ndarray:
        """(C, d) unit contact normals ``n = c/|c|``, from particle i to particle j."""
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
        """(C, d, d) contact stiffness tensors K = kn n n + kt_eff (I - n n) [N/m] (eq. 35)."""
        n = self.normals
        nn = n[:, :, None] * n[:, None, :]
        kt = self.effective_kt
        return (self.kn - kt)[:, None, None] * nn + kt[:, None, None] * np.eye(self.dim)

    # ---- per-particle counts -----------------------------------------------------------------
    def contact_counts(self) -> np.ndarray:
        """(N,) number of contacts of each particle."""
        return np.bincount(self.pairs.ravel(), minlength=self.n_particles)

    # ---- cell -------------------------------------------------------------------------------
    @property
    def volume(self) -> float:
        """The measure of the periodic cell, its area in 2D [m^2] and volume in 3D [m^3] (for a
        non-periodic network, of the particles' bounding box)."""
        if self.cell is not None:
            return float(abs(np.linalg.det(self.cell)))
        lo = (self.positions - self.radii[:, None]).min(axis=0)
        hi = (self.positions + self.radii[:, None]).max(axis=0)
        return float(np.prod(hi - lo))

    @property
    def area(self) -> float:
        """Area of the periodic cell [m^2] of a 2D network (its :attr:`volume`); for a
        non-periodic network, of the particles' bounding box. A 3D network has a volume instead."""
        if self.dim != 2:
            raise AttributeError("a 3D network has no area: use ContactNetwork.volume [m^3]")
        return self.volume

    @property
    def solid_fraction(self) -> float:
        """The solid fraction phi, sum(pi r^2) / area in 2D and sum(4/3 pi r^3) / volume in 3D."""
        if self.dim == 3:
            return float(4.0 / 3.0 * np.pi * np.sum(self.radii ** 3) / self.volume)
        return float(np.pi * np.sum(self.radii ** 2) / self.volume)

    def image_shifts(self) -> np.ndarray:
        """(C, d) integer image shifts s with c = x_j + h s - x_i (zeros if not periodic)."""
        if self.cell is None:
            return np.zeros((self.n_contacts, self.dim), dtype=np.int64)
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
        """The same network with every position moved by ``shift`` (d,) [m]; branches unchanged."""
        return replace(self, positions=self.positions + np.asarray(shift, dtype=float))

    def __repr__(self):
        cell = "periodic" if self.periodic else "open"
        return (f"ContactNetwork(N={self.n_particles}, contacts={self.n_contacts}, {cell}, "
                f"phi={self.solid_fraction:.4f})")


def _norms(v):
    """(M,) Euclidean norms of (M, d) rows (``np.hypot`` in 2D, as every 2D result was computed)."""
    if v.shape[1] == 2:
        return np.hypot(v[:, 0], v[:, 1])
    return np.sqrt(np.einsum("ij,ij->i", v, v))


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
    if not np.any(cell - np.diag(np.diag(cell))):      # orthogonal cell
        wrapped, _ = periodic.wrap(positions, cell, origin)
        box = np.diag(cell).copy()
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
    shape = np.shape(positions)
    if len(shape) != 2 or shape[1] not in (2, 3):
        raise ValueError(f"positions must have shape (N, 2) for disks or (N, 3) for spheres, got {shape}")
    positions = _as_float("positions", positions, (shape[1],))
    n = positions.shape[0]
    if n == 0:
        raise ValueError(f"positions holds no particles (shape {shape}): a network needs at least "
                         "one particle")
    radii = as_float_array("radii", radii, unit=" [m]")
    if radii.ndim and radii.shape != (n,):
        raise ValueError(f"radii must be a scalar or have shape ({n},) like positions, got {radii.shape}")
    radii = _as_float("radii", np.broadcast_to(radii, (n,)), ())
    bad = np.flatnonzero(~(radii > 0))
    if bad.size:
        raise ValueError(f"radii must be > 0 [m]; particle {int(bad[0])} has {float(radii[bad[0]])!r}")
    return positions, radii


def _check_cell(cell, dim=2):
    """The periodic shape matrix as a finite, non-singular (d, d) float array (None stays None)."""
    if cell is None:
        return None
    cell = as_float_array("cell", cell, unit=" [m]")
    if cell.shape != (dim, dim) or not np.all(np.isfinite(cell)):
        raise ValueError(f"cell must be a finite {dim}x{dim} matrix whose columns are the periodic "
                         f"vectors [m] (positions have {dim} columns: "
                         f"{'disks, 2D' if dim == 2 else 'spheres, 3D'}), or None (open "
                         f"boundaries); got shape {cell.shape}")
    size = abs(float(np.linalg.det(cell)))
    if not size > 1e-12 * float(np.abs(cell).max()) ** dim:
        raise ValueError(f"cell must have a positive {'area' if dim == 2 else 'volume'} (non-singular "
                         f"shape matrix, columns = periodic vectors); got {cell.tolist()} with "
                         f"{'area' if dim == 2 else 'volume'} {size:.3g}")
    return cell


def _finish(positions, radii, cell, origin, i, j, d, *, kn, kt, sliding, law, fn=None, ft=None):
    """The network of contacts (i, j, branch d), stiffness and forces resolved per contact."""
    dim = positions.shape[1]
    d = d.reshape(-1, dim)
    dist = _norms(d)
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
                          pairs=np.stack([i, j], axis=1).reshape(-1, 2), branch=d,
                          kn=kn, kt=kt, sliding=_per_contact("sliding", sliding, i.shape[0], bool),
                          fn=fn, ft=None if ft is None else ft if dim == 3 else _per_contact("ft", ft, i.shape[0]),
                          origin=origin)


def from_overlaps(positions, radii, cell=None, *, kn=None, kt=None, sliding=False, law=None,
                  branch_length="distance", tolerance=None, origin=None) -> ContactNetwork:
    """Build a :class:`ContactNetwork` from particle positions, radii and an optional periodic cell.

    Contacts are the pairs whose centre distance ``d`` satisfies ``d <= (r_i + r_j)(1 + tolerance)``
    (overlapping or touching disks; the small default tolerance keeps exactly touching lattice
    neighbours). Polydisperse radii are allowed. Contacts are sorted by ``(i, j)``, ``i < j``.

    Parameters
    ----------
    positions : (N, d) particle centres [m] (d = 2 disks, d = 3 spheres).
    radii : (N,) radii [m], or a scalar for identical particles.
    cell : (d, d) periodic shape matrix (columns = cell vectors) [m], or None (open boundaries).
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
    origin : (d,) lower-left corner of the periodic cell [m] (default zeros).
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
    dim = positions.shape[1]
    cell_arr = _check_cell(cell, dim)
    origin = np.zeros(dim) if origin is None else as_float_array("origin", origin, unit=" [m]")
    if origin.shape != (dim,) or not np.all(np.isfinite(origin)):
        raise ValueError(f"origin must be a finite ({dim},) point [m], got shape {origin.shape}")
    cutoff = 2.0 * radii.max() * (1.0 + tolerance)
    i, j, d = _candidate_pairs(positions, cell_arr, origin, cutoff)
    dist = _norms(d)
    rs = radii[i] + radii[j]
    touch = dist < rs if law is not None else dist <= rs * (1.0 + tolerance)
    i, j, d, dist = i[touch], j[touch], d[touch], dist[touch]
    order = np.lexsort((j, i))
    i, j, d, dist = i[order], j[order], d[order], dist[order]
    if branch_length == "radii":
        d = d * ((radii[i] + radii[j]) / dist)[:, None]
    return _finish(positions, radii, cell_arr, origin, i, j, d, kn=kn, kt=kt, sliding=sliding, law=law)


def from_pairs(positions, radii, cell, pairs, *, shifts=None, kn=None, kt=None, sliding=False,
               fn=None, ft=None, law=None, origin=None) -> ContactNetwork:
    """Build a :class:`ContactNetwork` on the caller's contact list, in the caller's order.

    Use it when per-contact data (stiffness, forces) come from another code aligned with its own
    pair list: row ``k`` of every array is contact ``pairs[k]``.

    Parameters
    ----------
    positions, radii, cell, origin : as :func:`from_overlaps`.
    pairs : (C, 2) int particle indices ``(i, j)``, ``i != j``; the branch vector is
        ``x_j - x_i``.
    shifts : (C, d) int image counts ``k`` with branch ``x_j + h k - x_i``; default: the minimum
        image (requires both cell heights to exceed twice the largest ``r_i + r_j``).
    kn, kt, sliding, law : as :func:`from_overlaps` (arrays of length C in the order of ``pairs``,
        or functions of ``(i, j, r_i, r_j, overlap)``).
    fn, ft : normal (compression positive) and tangential forces [N], scalars, (C,) arrays or
        functions (3D: ``ft`` a (C, 3) array); ``fn`` is set by ``law`` if one is given.
    """
    positions, radii = _check_geometry(positions, radii)
    pairs = np.asarray(pairs)
    if pairs.ndim != 2 or pairs.shape[1] != 2 or (pairs.size and not np.issubdtype(pairs.dtype, np.integer)):
        raise ValueError(f"pairs must be a (C, 2) integer array, got shape {pairs.shape}, dtype {pairs.dtype}")
    i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
    n = positions.shape[0]
    if i.size and (min(i.min(), j.min()) < 0 or max(i.max(), j.max()) >= n):
        raise ValueError(f"pairs contains particle indices outside [0, {n})")
    dim = positions.shape[1]
    cell_arr = _check_cell(cell, dim)
    origin = np.zeros(dim) if origin is None else as_float_array("origin", origin, unit=" [m]")
    d = positions[j] - positions[i]
    if shifts is not None:
        if cell_arr is None:
            raise ValueError("shifts need a periodic cell")
        shifts = np.asarray(shifts)
        if shifts.shape != (pairs.shape[0], positions.shape[1]):
            raise ValueError(f"shifts must have shape {(pairs.shape[0], positions.shape[1])} (one "
                             f"image count per contact and cell vector), got {shifts.shape}")
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
