"""Virgin state and excavation by Eshelby forces.

Units: SI per m of thickness (N/m, m). Tension positive.

* :func:`virgin_state` makes the pre-stressed, un-excavated model exactly static: F(u) = F(0) - K u
  for the intact assembly, so one sparse solve K u = F(0) on the free dofs (the dead loads, element
  prestress, interface preloads and, with ``gas="eigenstrain"``, the eigenstress forces) gives
  residual ~1e-15.
* :func:`excavate` removes the opening cells. Each wall node gets the force F_E0 that the removed
  neighbour's interface carried in the virgin state; the dynamics multiply it by g(t)
  (``dem.hexagons.dynamics.ramp_value``: instant, linear 1 - t/T_r, or 3DEC 0.95^(100 t/T_r)). This
  is Eshelby's cut-and-weld construction (the paper's "successive change of values of Eshelby's
  forces on the face of the side wall"), the same as 3DEC's ``block relax``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from ...hexagons.dynamics import Model, assemble_stiffness, forces_frozen
from ...hexagons.fault import segment_tractions

__all__ = ["virgin_state", "virgin_utilisation", "excavate", "wall_forces", "static_excavation"]


def virgin_state(full: Model, kn, kt):
    """Solve the intact model to static equilibrium in place; returns the relative residual."""
    F0 = forces_frozen(full, full.u)
    K = assemble_stiffness(full)
    free = full.minv.ravel() > 0
    uv = np.zeros(F0.size)
    uv[free] = spla.spsolve(K[free][:, free].tocsc(), F0.ravel()[free])
    uv = uv.reshape(F0.shape)
    n = np.stack([full.nx, full.ny], axis=1)
    dux = uv[full.cj, 2 * full.cb] - uv[full.ci, 2 * full.ca]
    duy = uv[full.cj, 2 * full.cb + 1] - uv[full.ci, 2 * full.ca + 1]
    jn = dux * n[:, 0] + duy * n[:, 1]
    jt = -dux * n[:, 1] + duy * n[:, 0]
    full.sn = full.sn0 + kn * jn
    full.tau = full.tau + kt * jt
    full.jtp = jt.copy()
    full.jnp = jn.copy()
    full.u = uv
    Fv = forces_frozen(full, uv)
    scale = np.abs(F0).max() + np.abs(full.f0).max()
    return float(np.abs(Fv.ravel()[free]).max() / scale)


def _utilisation(sp, tau, ft, coh, tanphi):
    lim = coh - sp * tanphi
    with np.errstate(divide="ignore", invalid="ignore"):
        ut = np.where(ft > 0, sp / np.where(ft > 0, ft, 1.0), np.where(sp >= 0, np.inf, 0.0))
        us = np.where(lim > 0, np.abs(tau) / np.maximum(lim, 1e-300), np.inf)
    return np.maximum(ut, us)


def virgin_utilisation(m: Model, fault_only: bool = False):
    """Largest Mohr-Coulomb utilisation over the interfaces (>= 1: failing) and their count. The
    edges of a planar fault count once per segment, with the segment's tractions on the true plane
    (:func:`dem.hexagons.fault.segment_tractions`); ``fault_only``: only those segments."""
    plane = m.fseg is not None and np.any(m.fseg >= 0)
    edge = np.ones(m.n_ifc, bool) if not plane else (m.fseg < 0)
    u = _utilisation((m.sn + m.pg)[edge], m.tau[edge], m.ft[edge], m.coh[edge], m.tanphi[edge])
    if fault_only:
        u = u[:0]
    if plane:
        st = segment_tractions(m)
        e0 = np.array([np.nonzero(m.fseg == s)[0][0] for s in st["seg"]])
        u = np.concatenate([u, _utilisation(st["sigma"] + st["pg"], st["tau"], m.ft[e0], m.coh[e0],
                                            m.tanphi[e0])])
    if u.size == 0:
        return 0.0, 0
    return float(u.max()), int(np.sum(u >= 1))


def wall_forces(full: Model, in_open, newidx):
    """Eshelby wall loads: (cell in the excavated model, edge, F_E0 (nw,2) [N/m]) for every
    interface between a kept cell and an opening cell, with the virgin interface force."""
    n = np.stack([full.nx, full.ny], axis=1)
    Fx = full.L * (full.sn * n[:, 0] - full.tau * n[:, 1])
    Fy = full.L * (full.sn * n[:, 1] + full.tau * n[:, 0])
    ci, ca, cj, cb = full.ci, full.ca, full.cj, full.cb
    wc, wk, FE = [], [], []
    for mm, cc, kk, sg in ((~in_open[ci] & in_open[cj], ci, ca, 1.0), (in_open[ci] & ~in_open[cj], cj, cb, -1.0)):
        wc.append(newidx[cc[mm]])
        wk.append(kk[mm])
        FE.append(sg * np.stack([Fx[mm], Fy[mm]], axis=1))
    return np.concatenate(wc), np.concatenate(wk), np.concatenate(FE)


def excavate(full: Model, in_open, ramp_kind, ramp_time, alpha=0.0, v_abort=1e3):
    """The excavated model (opening cells removed, interface states and displacements carried over,
    Eshelby wall loads attached) and the kept cell indices of the full lattice."""
    N = full.n_cells
    keep = np.nonzero(~in_open)[0]
    newidx = -np.ones(N, np.int64)
    newidx[keep] = np.arange(len(keep))
    ki = ~in_open[full.ci] & ~in_open[full.cj]
    wc, wk, FE = wall_forces(full, in_open, newidx)
    per_ifc = ("nx", "ny", "kn", "kt", "ft", "coh", "tanphi", "tanphi_r", "vent", "sn0", "is_disl", "sn", "tau",
               "jtp", "jnp", "pg")
    kw = {k: getattr(full, k)[ki].copy() for k in per_ifc}
    for k in ("fseg", "flam"):                      # the planar fault, when there is one
        if getattr(full, k) is not None:
            kw[k] = getattr(full, k)[ki].copy()
    per_cell = ("centres", "mat", "is_coal", "f0", "fext", "mnode", "minv")
    kw.update({k: getattr(full, k)[keep].copy() for k in per_cell})
    m = Model(Kmat=full.Kmat, geo=full.geo, L=full.L, ci=newidx[full.ci[ki]], ca=full.ca[ki].copy(),
              cj=newidx[full.cj[ki]], cb=full.cb[ki].copy(), broken=np.zeros(int(ki.sum()), np.int64),
              wc=wc, wk=wk, FE0=FE, ramp_kind=ramp_kind, ramp_time=ramp_time, alpha=alpha, v_abort=v_abort,
              **kw)
    m.u = full.u[keep].copy()
    return m, keep


def static_excavation(m: Model):
    """Elastic static response of the excavated model to the full removal of the Eshelby forces
    (linear, every interface intact): (du (N,12) [m], released energy 1/2 sum F_E0 . du [J/m]).
    The reference of test T7 for an elastic scene run to rest."""
    K = assemble_stiffness(m)
    free = m.minv.ravel() > 0
    rhs = np.zeros(m.u.size)
    idx = 12 * m.wc + 2 * m.wk
    np.add.at(rhs, idx, -m.FE0[:, 0])
    np.add.at(rhs, idx + 1, -m.FE0[:, 1])
    du = np.zeros(m.u.size)
    du[free] = spla.spsolve(K[free][:, free].tocsc(), rhs[free])
    return du.reshape(m.u.shape), float(abs(0.5 * rhs @ du))
