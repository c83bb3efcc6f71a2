"""Kirsch check (test T6): a circular hole in a hexagon lattice under far-field
stress, solved statically (sparse direct solve) and compared with the Kirsch solution.

Units: SI (m, Pa). Tension positive. Plane strain. No prestress: the far-field stress enters only as
the Kirsch tractions on the outer circle r = R_out, the hole r < a is traction-free, and the rigid
modes are removed by three Lagrange multipliers (zero mean displacement and rotation), so the
solution is the full (not incremental) stress field.

    from dem.hexagons.kirsch import kirsch_model, kirsch_solve, kirsch_stress
    km = kirsch_model(a=4.0, R_out=16.0, r_in=0.25)
    s = kirsch_solve(km, Sx=-25e6/3, Sy=-25e6)        # (N,3) cell stresses [sxx, syy, sxy]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .dynamics import RAMP_CODES, Model, assemble_stiffness, cell_stress
from .element import element_stiffness
from .lattice import make_lattice

__all__ = ["kirsch_stress", "hoop", "KirschModel", "kirsch_model", "kirsch_solve"]


def kirsch_stress(x, y, a, Sx, Sy):
    """Kirsch field around a traction-free circular hole of radius ``a`` [m] centred at 0 under the
    far-field stress sxx = Sx, syy = Sy [Pa] (tension positive). Returns (..., 3) [sxx, syy, sxy]."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    r2 = x * x + y * y
    th = np.arctan2(y, x)
    q = a * a / r2
    P = 0.5 * (Sx + Sy)
    Q = 0.5 * (Sx - Sy)
    c2, s2 = np.cos(2 * th), np.sin(2 * th)
    srr = P * (1 - q) + Q * (1 - 4 * q + 3 * q * q) * c2
    stt = P * (1 + q) - Q * (1 + 3 * q * q) * c2
    srt = -Q * (1 + 2 * q - 3 * q * q) * s2
    c, s = np.cos(th), np.sin(th)
    sxx = srr * c * c + stt * s * s - 2 * srt * s * c
    syy = srr * s * s + stt * c * c + 2 * srt * s * c
    sxy = (srr - stt) * s * c + srt * (c * c - s * s)
    return np.stack([sxx, syy, sxy], axis=-1)


def hoop(stress, x, y):
    """Hoop stress sigma_theta_theta [Pa] of Cartesian stresses (..., 3) at points (x, y)."""
    th = np.arctan2(y, x)
    c, s = np.cos(th), np.sin(th)
    return stress[..., 0] * s * s + stress[..., 1] * c * c - 2 * stress[..., 2] * s * c


@dataclass
class KirschModel:
    model: Model
    a: float
    R_out: float
    outer: tuple          # (cell, edge) arrays of the loaded outer free edges
    rim: np.ndarray       # indices of the cells with a free edge facing the hole
    K: sp.csr_matrix

    @property
    def centres(self):
        return self.model.centres


def kirsch_model(a=4.0, R_out=16.0, r_in=0.25, E=50e9, nu=0.25, kn_factor=100.0, kt_over_kn=1.0,
                 theta0=0.0, element="hybrid") -> KirschModel:
    """Hexagon lattice (one cell centred at the origin) clipped to ``a <= |centre| <= R_out``, with
    penalty springs kn = kn_factor * E / d on every interface (test T6 uses 100)."""
    if not (0 < a < R_out):
        raise ValueError(f"need 0 < a < R_out, got a={a}, R_out={R_out}")
    d = 2 * r_in
    W = 2 * (R_out + d)
    lat = make_lattice(W, W, r_in, theta0, anchor=(R_out + d, R_out + d))
    C = lat.centres - (R_out + d)
    r = np.hypot(C[:, 0], C[:, 1])
    keep = (r >= a - 1e-9) & (r <= R_out + 1e-9)
    new = -np.ones(len(C), np.int64)
    new[keep] = np.arange(keep.sum())
    ci, ca, cj, cb = lat.ifc.T
    ki = keep[ci] & keep[cj]
    ci, ca, cj, cb = new[ci[ki]], ca[ki], new[cj[ki]], cb[ki]
    C = C[keep]
    N = len(C)
    geo = lat.geo
    n = geo["n"][ca]
    kn = kn_factor * E / d
    M = len(ci)
    z = np.zeros(M)
    Kmat = element_stiffness(E, nu, r_in, theta0, kind=element)[None]
    model = Model(centres=C, mat=np.zeros(N, np.int64), is_coal=np.zeros(N, bool), Kmat=Kmat,
                  f0=np.zeros((N, 12)), fext=np.zeros((N, 12)), mnode=np.ones(N), minv=np.ones((N, 12)),
                  geo=geo, ci=ci, ca=ca, cj=cj, cb=cb, nx=n[:, 0].copy(), ny=n[:, 1].copy(), L=geo["L"],
                  kn=np.full(M, kn), kt=np.full(M, kt_over_kn * kn), ft=np.full(M, 1e300),
                  coh=np.full(M, 1e300), tanphi=z.copy(), tanphi_r=z.copy(), vent=np.full(M, np.inf),
                  sn0=z.copy(), is_disl=np.zeros(M, bool), sn=z.copy(), tau=z.copy(), jtp=z.copy(),
                  jnp=z.copy(), broken=np.zeros(M, np.int64), pg=z.copy(), wc=np.zeros(0, np.int64),
                  wk=np.zeros(0, np.int64), FE0=np.zeros((0, 2)), ramp_kind=RAMP_CODES["none"])
    model.u = np.zeros((N, 12))
    # free edges: every edge of a kept cell without a kept neighbour across it
    has = np.zeros((N, 6), bool)
    has[ci, ca] = True
    has[cj, cb] = True
    fc, fe = np.nonzero(~has)
    mid = C[fc] + geo["x"][fe]
    outer = np.hypot(mid[:, 0], mid[:, 1]) > 0.5 * (a + R_out)
    rim = np.unique(fc[~outer])
    return KirschModel(model=model, a=a, R_out=R_out, outer=(fc[outer], fe[outer]), rim=rim,
                       K=assemble_stiffness(model))


def kirsch_solve(km: KirschModel, loads):
    """Static solve for one or more far-field stresses ``loads`` = [(Sx, Sy), ...] [Pa]: Kirsch
    tractions (evaluated at the outer edge midpoints, r ~ R_out) on the outer free edges, the hole
    free, rigid modes fixed by Lagrange multipliers. Returns a list of (N,3) cell stresses [Pa] and
    the relative residual of the largest one."""
    m = km.model
    N = m.n_cells
    geo = m.geo
    fc, fe = km.outer
    mid = m.centres[fc] + geo["x"][fe]
    nn = geo["n"][fe]
    X = (m.centres[:, None, :] + geo["x"][None, :, :]).reshape(-1, 2)      # node positions
    ndof = 12 * N
    Cm = np.zeros((3, ndof))
    Cm[0, 0::2] = 1.0
    Cm[1, 1::2] = 1.0
    Cm[2, 0::2] = -X[:, 1]
    Cm[2, 1::2] = X[:, 0]
    Cs = sp.csr_matrix(Cm)
    A = sp.bmat([[km.K, Cs.T], [Cs, None]], format="csc")
    lu = spla.splu(A)
    out = []
    res = 0.0
    for Sx, Sy in loads:
        s = kirsch_stress(mid[:, 0], mid[:, 1], km.a, Sx, Sy)
        f = np.zeros((N, 12))
        L = geo["L"]
        np.add.at(f, (fc, 2 * fe), (s[:, 0] * nn[:, 0] + s[:, 2] * nn[:, 1]) * L)
        np.add.at(f, (fc, 2 * fe + 1), (s[:, 2] * nn[:, 0] + s[:, 1] * nn[:, 1]) * L)
        rhs = np.concatenate([f.ravel(), np.zeros(3)])
        sol = lu.solve(rhs)
        u = sol[:ndof]
        r = km.K @ u + Cs.T @ sol[ndof:] - f.ravel()
        res = max(res, float(np.abs(r).max() / np.abs(f).max()))
        out.append(cell_stress(m, u.reshape(N, 12)))
    return out, res
