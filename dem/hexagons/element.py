"""Stiffness of one regular hexagon with 6 edge-average displacement nodes (12 dofs).

Units: SI (Pa, m, N per m of thickness). Plane strain. Tension positive.

Node ``k`` (k = 0..5) is the midpoint of edge ``k``; its outward normal is at angle
``theta0 + k*60 deg``; the dof order is ``[u0x, u0y, u1x, u1y, ...]``. The 12-vector of edge forces
``f = K u`` is the resultant traction force (traction times edge length L) that the surroundings must
apply on each edge to hold the edge-average displacements ``u``.

Two versions (docs/mine_scene.md §2):

* ``"bem"`` — the paper's boundary-element version: Kelvin plane-strain kernels, one constant
  element per edge, collocation at the midpoints, ``H u = G t`` and ``K = diag(L) G^-1 H``,
  symmetrised and with the three rigid modes projected out (so that it is symmetric PSD with exact
  rigid-body modes). It fails the patch test by 8-12 % (documented, tested).
* ``"hybrid"`` (default) — consistency + stabilisation (VEM idea): the exact constant-strain part
  ``A B^T D B`` with ``eps = (1/A) sum_k sym(u_k (x) n_k) L`` (exact for edge averages by the
  divergence theorem) plus the BEM matrix restricted to the 6 higher-order modes. Passes the patch
  test to round-off, rigid modes exact, symmetric PSD.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = [
    "hex_geometry", "plane_strain_D", "bem_raw", "element_stiffness", "strain_operator",
    "rigid_modes", "linear_modes", "periodic_moduli", "lattice_closed_form", "isotropic_from_C",
]


def hex_geometry(r_in: float, theta0: float = 0.0):
    """Geometry of a regular hexagon of inner radius (apothem) ``r_in`` [m] centred at 0.

    ``theta0`` [rad] is the angle of the normal of edge 0. Returns a dict with ``n`` (6,2) outward
    normals, ``t`` (6,2) tangents (counter-clockwise, t = (-n_y, n_x)), ``x`` (6,2) edge midpoints,
    ``L`` edge length (= side = 2 r_in/sqrt3), ``A`` area (= 2 sqrt3 r_in^2) and ``verts`` (6,2)
    (vertex k between edges k and k+1).
    """
    if not (r_in > 0):
        raise ValueError(f"r_in must be > 0, got {r_in}")
    ang = theta0 + np.arange(6) * np.pi / 3.0
    n = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    t = np.stack([-n[:, 1], n[:, 0]], axis=1)
    L = 2.0 * r_in / np.sqrt(3.0)
    x = r_in * n
    verts = x + 0.5 * L * t
    return {"n": n, "t": t, "x": x, "L": L, "A": 2.0 * np.sqrt(3.0) * r_in ** 2, "verts": verts,
            "r_in": r_in, "theta0": theta0}


def plane_strain_D(E: float, nu: float) -> np.ndarray:
    """Plane-strain elasticity matrix in Voigt form [xx, yy, gamma_xy] (Pa)."""
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    return np.array([[lam + 2 * mu, lam, 0.0], [lam, lam + 2 * mu, 0.0], [0.0, 0.0, mu]])


def strain_operator(geo) -> np.ndarray:
    """B (3x12): mean strain [exx, eyy, gxy] = B u from the edge-average displacements (exact)."""
    n, L, A = geo["n"], geo["L"], geo["A"]
    B = np.zeros((3, 12))
    for k in range(6):
        B[0, 2 * k] = n[k, 0] * L / A
        B[1, 2 * k + 1] = n[k, 1] * L / A
        B[2, 2 * k] = n[k, 1] * L / A
        B[2, 2 * k + 1] = n[k, 0] * L / A
    return B


def rigid_modes(geo) -> np.ndarray:
    """(12,3): x-translation, y-translation, rotation about the centre."""
    x = geo["x"]
    R = np.zeros((12, 3))
    R[0::2, 0] = 1.0
    R[1::2, 1] = 1.0
    R[0::2, 2] = -x[:, 1]
    R[1::2, 2] = x[:, 0]
    return R


def linear_modes(geo) -> np.ndarray:
    """(12,6): the 3 rigid modes plus the 3 constant-strain modes u = eps x."""
    x = geo["x"]
    S = np.zeros((12, 3))
    S[0::2, 0] = x[:, 0]               # exx
    S[1::2, 1] = x[:, 1]               # eyy
    S[0::2, 2] = 0.5 * x[:, 1]         # gxy (symmetric shear)
    S[1::2, 2] = 0.5 * x[:, 0]
    return np.hstack([rigid_modes(geo), S])


def _kelvin_U(r, nu, mu):
    """U*(x,y) for r = y - x (m,2) -> (m,2,2)."""
    rr = np.linalg.norm(r, axis=1)
    rd = r / rr[:, None]
    c = -1.0 / (8 * np.pi * mu * (1 - nu))
    U = np.empty((len(r), 2, 2))
    for i in range(2):
        for j in range(2):
            U[:, i, j] = c * ((3 - 4 * nu) * np.log(rr) * (i == j) - rd[:, i] * rd[:, j])
    return U


def _kelvin_T(r, nvec, nu):
    """T*(x,y) for r = y - x (m,2), outward normal at y -> (m,2,2)."""
    rr = np.linalg.norm(r, axis=1)
    rd = r / rr[:, None]
    drdn = rd @ nvec
    c = -1.0 / (4 * np.pi * (1 - nu) * rr)
    T = np.empty((len(r), 2, 2))
    for i in range(2):
        for j in range(2):
            T[:, i, j] = c * (drdn * ((1 - 2 * nu) * (i == j) + 2 * rd[:, i] * rd[:, j])
                              - (1 - 2 * nu) * (rd[:, i] * nvec[j] - rd[:, j] * nvec[i]))
    return T


def bem_raw(E: float, nu: float, r_in: float, theta0: float = 0.0, ngauss: int = 64) -> np.ndarray:
    """The paper's unsymmetrised BEM stiffness ``K = diag(L) G^-1 H`` (12x12, N/m per m)."""
    geo = hex_geometry(r_in, theta0)
    n, t, x, L = geo["n"], geo["t"], geo["x"], geo["L"]
    mu = E / (2 * (1 + nu))
    gp, gw = np.polynomial.legendre.leggauss(ngauss)
    s = 0.5 * L * gp
    w = 0.5 * L * gw
    G = np.zeros((12, 12))
    H = np.zeros((12, 12))
    for i in range(6):
        for j in range(6):
            if i == j:
                c = -1.0 / (8 * np.pi * mu * (1 - nu))
                Gs = c * ((3 - 4 * nu) * L * (np.log(L / 2) - 1) * np.eye(2) - L * np.outer(t[j], t[j]))
                G[2 * i:2 * i + 2, 2 * j:2 * j + 2] = Gs
                H[2 * i:2 * i + 2, 2 * j:2 * j + 2] = 0.5 * np.eye(2)
                continue
            y = x[j][None, :] + s[:, None] * t[j][None, :]
            r = y - x[i][None, :]
            G[2 * i:2 * i + 2, 2 * j:2 * j + 2] = np.einsum("m,mij->ij", w, _kelvin_U(r, nu, mu))
            H[2 * i:2 * i + 2, 2 * j:2 * j + 2] = np.einsum("m,mij->ij", w, _kelvin_T(r, n[j], nu))
    cond = np.linalg.cond(G)
    if cond > 1e12:
        raise ValueError(f"BEM matrix G is near-singular (cond {cond:.2e}) for r_in={r_in}: "
                         "degenerate scale of the log kernel; change r_in slightly")
    return L * np.linalg.solve(G, H)


def _projector(V):
    Q, _ = np.linalg.qr(V)
    return np.eye(V.shape[0]) - Q @ Q.T


@lru_cache(maxsize=64)
def _element_stiffness_cached(E, nu, r_in, theta0, kind):
    geo = hex_geometry(r_in, theta0)
    if kind == "bem_raw":
        return bem_raw(E, nu, r_in, theta0)
    Kb = bem_raw(E, nu, r_in, theta0)
    Ks = 0.5 * (Kb + Kb.T)
    if kind == "bem_sym":
        return Ks
    if kind == "bem":
        P = _projector(rigid_modes(geo))
        K = P @ Ks @ P
        return 0.5 * (K + K.T)
    if kind == "hybrid":
        B = strain_operator(geo)
        Kc = geo["A"] * B.T @ plane_strain_D(E, nu) @ B
        Ph = _projector(linear_modes(geo))
        Kst = Ph @ Ks @ Ph
        K = Kc + Kst
        return 0.5 * (K + K.T)
    raise ValueError(f"element kind must be 'hybrid', 'bem', 'bem_sym' or 'bem_raw', got {kind!r}")


def element_stiffness(E: float, nu: float, r_in: float, theta0: float = 0.0,
                      kind: str = "hybrid") -> np.ndarray:
    """12x12 hexagon stiffness [N/m per m]. ``kind``: 'hybrid' (default), 'bem' (paper's BEM,
    symmetrised, rigid modes projected out), 'bem_sym', 'bem_raw' (diagnostics)."""
    if not (E > 0):
        raise ValueError(f"E must be > 0, got {E}")
    if not (-1.0 < nu < 0.5):
        raise ValueError(f"nu must be in (-1, 0.5), got {nu}")
    return _element_stiffness_cached(float(E), float(nu), float(r_in), float(theta0), kind).copy()


# ------------------------------------------------------------------ periodic homogenisation
def periodic_moduli(K: np.ndarray, r_in: float, kn: float, kt: float, theta0: float = 0.0) -> np.ndarray:
    """Exact effective plane stiffness C (3x3 Voigt, Pa) of the infinite regular lattice of identical
    hexagons (element stiffness K, 12x12) joined by interface springs kn, kt [Pa/m] on every edge.

    One cell per periodic unit cell; the interface across edge k (k = 0,1,2) joins node k of the cell
    with node k+3 of its neighbour at ``d n_k``: jump = u_{k+3} - u_k + eps (d n_k).
    Energy per cell is minimised over the 12 node displacements; ``w = E / A_cell``.
    """
    geo = hex_geometry(r_in, theta0)
    n, t, L, A = geo["n"], geo["t"], geo["L"], geo["A"]
    d = 2 * r_in
    # jump_k = J_k u + E_k eps,  J_k (2x12), E_k (2x3)
    Htot = K.copy()
    F = np.zeros((12, 3))
    C = np.zeros((3, 3))
    for k in range(3):
        S = L * (kn * np.outer(n[k], n[k]) + kt * np.outer(t[k], t[k]))
        J = np.zeros((2, 12))
        J[:, 2 * (k + 3):2 * (k + 3) + 2] = np.eye(2)
        J[:, 2 * k:2 * k + 2] -= np.eye(2)
        c = d * n[k]
        Ek = np.array([[c[0], 0.0, 0.5 * c[1]], [0.0, c[1], 0.5 * c[0]]])
        Htot += J.T @ S @ J
        F += J.T @ S @ Ek
        C += Ek.T @ S @ Ek
    # Htot has 2 zero modes (translations); use lstsq / pinv
    X = np.linalg.lstsq(Htot, F, rcond=None)[0]
    C = C - F.T @ X
    return C / A


def isotropic_from_C(C: np.ndarray):
    """Plane-strain E, nu from an isotropic Voigt C (C11 = lam + 2mu, C12 = lam, C66 = mu)."""
    lam = C[0, 1]
    mu = C[2, 2]
    nu = lam / (2 * (lam + mu))
    E = mu * (3 * lam + 2 * mu) / (lam + mu)
    return E, nu


def lattice_closed_form(kn_l: float, ks_l: float) -> np.ndarray:
    """Triangular lattice of rigid particles with springs kn_l, ks_l [N/m per m]: C11 = sqrt3 (3kn + ks)/4, C12 = sqrt3 (kn - ks)/4, C66 = sqrt3 (kn + ks)/4."""
    s3 = np.sqrt(3.0)
    return np.array([[s3 * (3 * kn_l + ks_l) / 4, s3 * (kn_l - ks_l) / 4, 0.0],
                     [s3 * (kn_l - ks_l) / 4, s3 * (3 * kn_l + ks_l) / 4, 0.0],
                     [0.0, 0.0, s3 * (kn_l + ks_l) / 4]])
