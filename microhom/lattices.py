"""Perfect periodic lattices of identical disks and spheres: the exact cases every measurement is
checked on.

Each function returns a periodic :class:`~microhom.network.ContactNetwork` of touching particles
of diameter ``diameter`` [m] with contact stiffnesses ``kn``, ``kt`` [N/m].

Disks (2D):

* triangular (hexagonal close packing): 6 contacts each, phi = pi / (2 sqrt 3);
* square: 4 contacts each, phi = pi / 4;
* honeycomb: 3 contacts each, phi = pi / (3 sqrt 3).

Spheres (3D):

* simple_cubic: 6 contacts each, phi = pi / 6;
* fcc (face-centred cubic): 12 contacts each, phi = pi / (3 sqrt 2).
"""
from __future__ import annotations

import numpy as np

from .network import ContactNetwork, from_overlaps

__all__ = ["triangular", "square", "honeycomb", "simple_cubic", "fcc"]


def _check(nx, ny, diameter, even_ny=False):
    for name, v in (("nx", nx), ("ny", ny)):
        if int(v) != v or v < 3:
            raise ValueError(f"{name} must be an integer >= 3, got {v}")
    if even_ny and ny % 2:
        raise ValueError(f"ny must be even for a rectangular periodic cell, got {ny}")
    if not (np.isfinite(diameter) and diameter > 0):
        raise ValueError(f"diameter must be > 0, got {diameter}")


def triangular(nx=6, ny=6, *, diameter=1.0, kn=1.0, kt=None, sliding=False,
               angle=0.0) -> ContactNetwork:
    """Triangular lattice, ``nx`` x ``ny`` disks (ny even), optionally rotated by ``angle`` [rad]."""
    _check(nx, ny, diameter, even_ny=True)
    d = float(diameter)
    k, i = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    pos = np.stack([(i + 0.5 * (k % 2)) * d, k * d * np.sqrt(3) / 2], axis=-1).reshape(-1, 2)
    cell = np.diag([nx * d, ny * d * np.sqrt(3) / 2])
    return _rotated(pos, d, cell, kn, kt, sliding, angle)


def square(nx=5, ny=5, *, diameter=1.0, kn=1.0, kt=None, sliding=False, angle=0.0) -> ContactNetwork:
    """Square lattice, ``nx`` x ``ny`` disks, optionally rotated by ``angle`` [rad]."""
    _check(nx, ny, diameter)
    d = float(diameter)
    k, i = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    pos = np.stack([i * d, k * d], axis=-1).reshape(-1, 2).astype(float)
    cell = np.diag([nx * d, ny * d])
    return _rotated(pos, d, cell, kn, kt, sliding, angle)


def honeycomb(nx=4, ny=3, *, diameter=1.0, kn=1.0, kt=None, sliding=False,
              angle=0.0) -> ContactNetwork:
    """Honeycomb lattice of ``nx`` x ``ny`` rectangular 4-disk unit cells (``sqrt3 D`` by ``3 D``,
    D = ``diameter`` [m]), optionally rotated by ``angle`` [rad]."""
    _check(nx, ny, diameter)
    d = float(diameter)
    s3 = np.sqrt(3.0)
    basis = np.array([[0.0, 0.0], [s3 / 2, 0.5], [s3 / 2, 1.5], [0.0, 2.0]]) * d
    cells = np.array([(a * s3 * d, b * 3 * d) for b in range(ny) for a in range(nx)])
    pos = (cells[:, None, :] + basis[None, :, :]).reshape(-1, 2)
    cell = np.diag([nx * s3 * d, ny * 3 * d])
    return _rotated(pos, d, cell, kn, kt, sliding, angle)


def _rotated(pos, d, cell, kn, kt, sliding, angle):
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    pos = pos @ rot.T
    cell = rot @ cell
    return from_overlaps(pos, 0.5 * d, cell, kn=kn, kt=kt, sliding=sliding, tolerance=1e-9)


def _check3(n, diameter):
    if int(n) != n or n < 3:
        raise ValueError(f"n must be an integer >= 3 (cells per side), got {n}")
    if not (np.isfinite(diameter) and diameter > 0):
        raise ValueError(f"diameter must be > 0, got {diameter}")


def simple_cubic(n=3, *, diameter=1.0, kn=1.0, kt=None, sliding=False) -> ContactNetwork:
    """Simple cubic lattice of ``n``^3 spheres in a cubic periodic cell of side ``n D``."""
    _check3(n, diameter)
    d = float(diameter)
    g = np.arange(n) * d
    pos = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    return from_overlaps(pos, 0.5 * d, np.eye(3) * n * d, kn=kn, kt=kt, sliding=sliding,
                         tolerance=1e-9)


def fcc(n=2, *, diameter=1.0, kn=1.0, kt=None, sliding=False) -> ContactNetwork:
    """Face-centred cubic lattice: ``n``^3 cubic cells of side ``a = sqrt2 D`` with 4 spheres each
    (``n`` >= 2: the cell must be wider than two diameters)."""
    if int(n) != n or n < 2:
        raise ValueError(f"n must be an integer >= 2 (cubic cells per side), got {n}")
    _check3(3, diameter)
    d = float(diameter)
    a = np.sqrt(2.0) * d
    basis = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]]) * a
    g = np.arange(n) * a
    corners = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    pos = (corners[:, None, :] + basis[None, :, :]).reshape(-1, 3)
    return from_overlaps(pos, 0.5 * d, np.eye(3) * n * a, kn=kn, kt=kt, sliding=sliding,
                         tolerance=1e-9)
