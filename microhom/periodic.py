"""Periodic geometry of a 2D parallelogram cell: fractional coordinates, wrapping, minimum image,
image shifts and boundary images. The one implementation used by ``microhom.network``,
``dem.cell`` and ``dem.measure`` (it lives on the theory side: ``dem`` may import ``microhom``,
never the reverse).

Conventions (as :class:`microhom.network.ContactNetwork`): the cell is the 2x2 shape matrix ``h``
[m] whose *columns* are the cell vectors ``a1, a2``; it spans ``origin + h @ s`` for fractional
``s`` in [0, 1)^2. Positions are (N, 2) arrays [m]; a branch vector ``x_j + h k - x_i`` is the same
whichever image represents a particle.
"""
from __future__ import annotations

import numpy as np

__all__ = ["heights", "fractional", "wrap", "minimum_image", "image_shifts", "boundary_images"]


def heights(h) -> np.ndarray:
    """(2,) perpendicular widths of the cell across its two pairs of faces [m]: ``(A/|a2|, A/|a1|)``."""
    h = np.asarray(h, dtype=float)
    a = abs(np.linalg.det(h))
    return np.array([a / np.hypot(*h[:, 1]), a / np.hypot(*h[:, 0])])


def _cartesian(s, h):
    """(M, 2) Cartesian vectors ``h s`` of fractional ones (elementwise: faster than a matmul)."""
    return s[:, :1] * h[:, 0] + s[:, 1:2] * h[:, 1]


def fractional(x, h, origin=None) -> np.ndarray:
    """(N, 2) fractional coordinates ``s = h^{-1} (x - origin)`` of positions ``x`` (N, 2) [m]."""
    x = np.asarray(x, dtype=float)
    if origin is not None:
        x = x - np.asarray(origin, dtype=float)
    return np.linalg.solve(np.asarray(h, dtype=float), x.T).T


def wrap(x, h, origin=None):
    """Wrap positions into the cell. Returns ``(x_wrapped, k)`` with ``x = x_wrapped + h k``,
    ``k`` (N, 2) integer image counts and ``x_wrapped`` in ``origin + h [0, 1)^2``."""
    s = fractional(x, h, origin)
    k = np.floor(s)
    xw = _cartesian(s - k, np.asarray(h, dtype=float))
    if origin is not None:
        xw = xw + np.asarray(origin, dtype=float)
    return xw, k.astype(np.int64)


def minimum_image(d, h) -> np.ndarray:
    """(M, 2) separation vectors ``d`` [m] moved to their nearest periodic image
    ``d - h rint(h^{-1} d)`` (the shortest one when the cell is not strongly sheared; callers that
    need it unambiguous check :func:`heights` against twice the largest distance of interest)."""
    d = np.asarray(d, dtype=float)
    return d - _cartesian(np.rint(fractional(d, h)), np.asarray(h, dtype=float))


def image_shifts(branch, direct, h) -> np.ndarray:
    """(M, 2) integer shifts ``k`` with ``branch = direct + h k`` (``direct = x_j - x_i`` as stored)."""
    return np.rint(fractional(np.asarray(branch, float) - np.asarray(direct, float), h)).astype(np.int64)


def boundary_images(x, h, origin=None, margin=0.0):
    """The positions wrapped into the cell followed by the images of those within ``margin`` [m]
    of an edge (the 8 neighbouring copies of the cell). Returns ``(points (M, 2), owner (M,))``:
    ``points[:N]`` are the wrapped positions themselves (``owner[:N] = arange(N)``), ``owner`` the
    original index of every point. A ``margin`` beyond the cell heights keeps all 8 copies (never
    more: a point two cells away is not produced)."""
    h = np.asarray(h, dtype=float)
    o = np.zeros(2) if origin is None else np.asarray(origin, dtype=float)
    frac = fractional(x, h, o)
    frac -= np.floor(frac)
    fm = margin / heights(h)          # margin in fractional units, per direction
    n = frac.shape[0]
    pts, owner = [o + _cartesian(frac, h)], [np.arange(n)]
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            if a == 0 and b == 0:
                continue
            f = frac + np.array([a, b], dtype=float)
            near = np.all((f > -fm) & (f < 1 + fm), axis=1)
            pts.append(o + _cartesian(f[near], h))
            owner.append(np.flatnonzero(near))
    return np.concatenate(pts), np.concatenate(owner)
