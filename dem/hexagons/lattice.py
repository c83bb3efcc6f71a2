"""Regular hexagon lattice clipped to a rectangle: cells, interfaces, free (boundary) edges.

Units: m. Edge ``k`` of every cell has outward normal at ``theta0 + k*60 deg``; the neighbour across
edge ``k`` sits at ``c + d n_k`` (d = 2 r_in) and faces it with its edge ``(k+3) % 6``.

``theta0 = 0`` (default): vertical edges, "pointy-top" cells, horizontal rows of centres, interface
normals at 0, +-60 deg -> the virgin state (K0 = 1/3) stays inside Mohr-Coulomb (docs/mine_scene.md D4).
``theta0 = pi/6``: flat-top cells, normals at 30, 90, 150 deg (fails at the virgin state with the
paper's strengths; kept as an option and refused by the scene's virgin check).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .element import hex_geometry

__all__ = ["Lattice", "make_lattice"]


@dataclass
class Lattice:
    r_in: float
    theta0: float
    centres: np.ndarray          # (N,2)
    ij: np.ndarray               # (N,2) integer lattice coordinates
    neigh: np.ndarray            # (N,6) neighbour index across edge k, -1 if none
    ifc: np.ndarray              # (M,4) interfaces: cell i, edge a, cell j, edge b (a < 3 always)
    geo: dict                    # hexagon geometry (normals, tangents, midpoints, L, A)

    @property
    def d(self) -> float:
        return 2.0 * self.r_in

    @property
    def n_cells(self) -> int:
        return len(self.centres)

    def node_positions(self) -> np.ndarray:
        """(N,6,2) reference positions of the edge-midpoint nodes."""
        return self.centres[:, None, :] + self.geo["x"][None, :, :]

    def free_edges(self):
        """(cell, edge) pairs with no neighbour."""
        c, e = np.nonzero(self.neigh < 0)
        return c, e


_OFF = [(1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1)]


def make_lattice(W: float, H: float, r_in: float, theta0: float = 0.0,
                 anchor=(0.0, 0.0), tol: float = 1e-9) -> Lattice:
    """Hexagons whose centres lie in [0,W] x [0,H] (closed, tolerance ``tol``), one centre at
    ``anchor``. Lattice vectors a1 = d n_0, a2 = d n_1."""
    if W <= 0 or H <= 0:
        raise ValueError(f"domain must have W, H > 0, got W={W}, H={H}")
    geo = hex_geometry(r_in, theta0)
    d = 2 * r_in
    a1 = d * geo["n"][0]
    a2 = d * geo["n"][1]
    Amat = np.column_stack([a1, a2])
    corners = np.array([[0, 0], [W, 0], [0, H], [W, H]], float) - np.asarray(anchor, float)
    ijc = np.linalg.solve(Amat, corners.T).T
    lo = np.floor(ijc.min(axis=0)).astype(int) - 2
    hi = np.ceil(ijc.max(axis=0)).astype(int) + 2
    I, J = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    I = I.ravel()
    J = J.ravel()
    C = np.asarray(anchor, float)[None, :] + I[:, None] * a1[None, :] + J[:, None] * a2[None, :]
    keep = (C[:, 0] >= -tol) & (C[:, 0] <= W + tol) & (C[:, 1] >= -tol) & (C[:, 1] <= H + tol)
    C, I, J = C[keep], I[keep], J[keep]
    # order: rows bottom->top then left->right (locality, reproducibility)
    order = np.lexsort((np.round(C[:, 0], 9), np.round(C[:, 1], 9)))
    C, I, J = C[order], I[order], J[order]
    index = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(I, J))}
    N = len(C)
    neigh = -np.ones((N, 6), dtype=np.int64)
    for k in range(N):
        for e, (di, dj) in enumerate(_OFF):
            neigh[k, e] = index.get((int(I[k]) + di, int(J[k]) + dj), -1)
    ifc = [(i, a, int(neigh[i, a]), (a + 3) % 6) for i in range(N) for a in range(3) if neigh[i, a] >= 0]
    ifc = np.array(ifc, dtype=np.int64).reshape(-1, 4)
    return Lattice(r_in=r_in, theta0=theta0, centres=C, ij=np.column_stack([I, J]), neigh=neigh,
                   ifc=ifc, geo=geo)


def classify_free_edges(lat: Lattice, W: float, H: float, cells_mask=None):
    """Label every free edge of the full lattice with the nearest domain side it faces.

    Returns (cell, edge, side) with side 0 = left, 1 = right, 2 = bottom, 3 = top.
    """
    c, e = lat.free_edges()
    n = lat.geo["n"][e]
    mid = lat.centres[c] + lat.geo["x"][e]
    big = 1e30
    dist = np.full((len(c), 4), big)
    dist[:, 0] = np.where(n[:, 0] < -1e-9, mid[:, 0], big)
    dist[:, 1] = np.where(n[:, 0] > 1e-9, W - mid[:, 0], big)
    dist[:, 2] = np.where(n[:, 1] < -1e-9, mid[:, 1], big)
    dist[:, 3] = np.where(n[:, 1] > 1e-9, H - mid[:, 1], big)
    side = np.argmin(dist, axis=1)
    return c, e, side
