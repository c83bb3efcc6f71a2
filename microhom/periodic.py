"""Periodic geometry of a parallelogram (2D) or parallelepiped (3D) cell: fractional coordinates,
wrapping, minimum image, image shifts and boundary images. The one implementation used by ``microhom.network``,
``dem.engine.cell`` and ``dem.analysis.measure`` (it lives on the theory side: ``dem`` may import ``microhom``,
never the reverse).

Conventions (as :class:`microhom.network.ContactNetwork`): the cell is the d x d shape matrix ``h``
[m] (d = 2 or 3, taken from the data) whose *columns* are the cell vectors ``a1 .. ad``; it spans
``origin + h @ s`` for fractional ``s`` in [0, 1)^d. Positions are (N, d) arrays [m]; a branch
vector ``x_j + h k - x_i`` is the same whichever image represents a particle.
"""
from __future__ import annotations

import itertools

import numpy as np

__all__ = ["heights", "fractional", "wrap", "minimum_image", "image_shifts", "boundary_images"]


def heights(h) -> np.ndarray:
    """(d,) perpendicular widths of the cell across its d pairs of faces [m]: in 2D
    ``(A/|a2|, A/|a1|)``, in 3D ``V/|a2 x a3|, V/|a3 x a1|, V/|a1 x a2|``."""
    h = np.asarray(h, dtype=float)
    a = abs(np.linalg.det(h))
    if h.shape == (3, 3):
        return np.array([a / np.linalg.norm(np.cross(h[:, (k + 1) % 3], h[:, (k + 2) % 3]))
                         for k in range(3)])
    return np.array([a / np.hypot(*h[:, 1]), a / np.hypot(*h[:, 0])])


def _cartesian(s, h):
    """(M, d) Cartesian vectors ``h s`` of fractional ones (in 2D elementwise: faster than a matmul)."""
    if h.shape[0] == 2:
        return s[:, :1] * h[:, 0] + s[:, 1:2] * h[:, 1]
    return s @ h.T


def fractional(x, h, origin=None) -> np.ndarray:
    """(N, d) fractional coordinates ``s = h^{-1} (x - origin)`` of positions ``x`` (N, d) [m]."""
    x = np.asarray(x, dtype=float)
    if origin is not None:
        x = x - np.asarray(origin, dtype=float)
    return np.linalg.solve(np.asarray(h, dtype=float), x.T).T


def wrap(x, h, origin=None):
    """Wrap positions into the cell. Returns ``(x_wrapped, k)`` with ``x = x_wrapped + h k``,
    ``k`` (N, d) integer image counts and ``x_wrapped`` in ``origin + h [0, 1)^d``."""
    s = fractional(x, h, origin)
    k = np.floor(s)
    xw = _cartesian(s - k, np.asarray(h, dtype=float))
    if origin is not None:
        xw = xw + np.asarray(origin, dtype=float)
    return xw, k.astype(np.int64)


def minimum_image(d, h) -> np.ndarray:
    """(M, d) separation vectors ``d`` [m] moved to their nearest periodic image
    ``d - h rint(h^{-1} d)`` (the shortest one when the cell is not strongly sheared; callers that
    need it unambiguous check :func:`heights` against twice the largest distance of interest)."""
    d = np.asarray(d, dtype=float)
    return d - _cartesian(np.rint(fractional(d, h)), np.asarray(h, dtype=float))


def image_shifts(branch, direct, h) -> np.ndarray:
    """(M, d) integer shifts ``k`` with ``branch = direct + h k`` (``direct = x_j - x_i`` as stored)."""
    return np.rint(fractional(np.asarray(branch, float) - np.asarray(direct, float), h)).astype(np.int64)


def boundary_images(x, h, origin=None, margin=0.0):
    """The positions wrapped into the cell followed by the images of those within ``margin`` [m]
    of a face (the 3^d - 1 neighbouring copies of the cell: 8 in 2D, 26 in 3D). Returns
    ``(points (M, d), owner (M,))``: ``points[:N]`` are the wrapped positions themselves
    (``owner[:N] = arange(N)``), ``owner`` the original index of every point. A ``margin`` beyond
    the cell heights keeps all copies (never more: a point two cells away is not produced)."""
    h = np.asarray(h, dtype=float)
    dim = h.shape[0]
    o = np.zeros(dim) if origin is None else np.asarray(origin, dtype=float)
    frac = fractional(x, h, o)
    frac -= np.floor(frac)
    fm = margin / heights(h)          # margin in fractional units, per direction
    n = frac.shape[0]
    pts, owner = [o + _cartesian(frac, h)], [np.arange(n)]
    for shift in itertools.product((-1, 0, 1), repeat=dim):
        if not any(shift):
            continue
        f = frac + np.array(shift, dtype=float)
        near = np.all((f > -fm) & (f < 1 + fm), axis=1)
        pts.append(o + _cartesian(f[near], h))
        owner.append(np.flatnonzero(near))
    return np.concatenate(pts), np.concatenate(owner)
