"""Build the mine scene from its parameters: lattice -> materials -> interfaces and dislocations ->
gas -> boundaries -> exact virgin state -> excavated model with Eshelby wall forces -> boundary
devices (overburden spring, absorbing dashpots).

Units: SI per m of thickness. Tension positive. Plane strain.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...hexagons.dynamics import RAMP_CODES, Model, forces_frozen, stored_energy_abs
from ...hexagons.element import element_stiffness, isotropic_from_C, periodic_moduli
from ...hexagons.fault import plane_fault
from ...hexagons.interface import spring_stiffness_rule
from ...hexagons.lattice import classify_free_edges, make_lattice
from .excavation import excavate, virgin_state, virgin_utilisation
from .gas import eigenstrain_forces, gassy_cells, interface_pressure, release_gas_with_excavation
from .geometry import Geometry, block_labels, resolve, segments_cross
from .params import G_ACC, MineParams

__all__ = ["Scene", "build_scene", "virgin_stress"]

_BIG = 1e300
_TOL = 1e-9         # [m] slack of the seam, opening and layer tests on cell centres
LEFT, RIGHT, BOTTOM, TOP = 0, 1, 2, 3


@dataclass
class Scene:
    """A built scene: ``N`` cells in the full lattice, ``n`` in the excavated model. SI per m of
    thickness.

    Attributes
    ----------
    params : MineParams
        The scene file it was built from.
    geometry : Geometry
        The domain, dislocation lines and blocks (:func:`~dem.scenes.mine.geometry.resolve`).
    model : Model
        The excavated hexagon model (opening cells removed), ready to run.
    full_centres : ndarray, shape (N, 2)
        Cell centres of the full lattice before excavation [m].
    opening_cells : ndarray of int
        Full-lattice indices of the excavated (opening) cells.
    keep : ndarray of int, shape (n,)
        Full-lattice index of each model cell.
    kn, kt : float
        Interface penalty stiffness, normal and shear [Pa/m].
    labels : ndarray, shape (n,)
        Block of each cell (:func:`~dem.scenes.mine.geometry.block_labels`).
    gassy : ndarray of bool, shape (n,)
        Cells of the eigenstrain (gas) zone.
    E_eff : dict
        Per material (``"rock"``, ``"coal"``): input ``E`` [Pa], ``nu`` [-], the lattice's effective
        ``E_eff`` [Pa], ``nu_eff`` [-] and ``E_eff_over_E`` [-].
    virgin_residual : float
        Relative force residual of the virgin equilibrium [-].
    virgin_utilisation : float
        Largest Mohr-Coulomb utilisation of the interfaces in the virgin state [-] (0 if elastic).
    sigma0 : ndarray, shape (3,)
        Virgin stress [sxx, syy, sxy] at the top of the domain [Pa].
    info : dict
        Sizes and inputs for the record (cell, interface, wall-node counts; kn, kt [Pa/m];
        rho [kg/m^3]; p_top [Pa]).
    """
    params: MineParams
    geometry: Geometry
    model: Model
    full_centres: np.ndarray
    opening_cells: np.ndarray
    keep: np.ndarray
    kn: float
    kt: float
    labels: np.ndarray
    gassy: np.ndarray
    E_eff: dict = field(default_factory=dict)
    virgin_residual: float = 0.0
    virgin_utilisation: float = 0.0
    sigma0: np.ndarray = None         # (3,) virgin stress at the top [Pa]
    info: dict = field(default_factory=dict)

    def virgin_stress(self, y):
        """Virgin stress (..., 3) [sxx, syy, sxy] [Pa] at heights ``y`` [m] (:func:`virgin_stress`)."""
        return virgin_stress(self.params, self.geometry, y)


def virgin_stress(p: MineParams, g: Geometry, y):
    """(..., 3) virgin stress [sxx, syy, sxy] [Pa] at heights y [m]: syy = -(p_top + gamma (H - y))
    with gravity, -p_top without; sxx = K0 syy."""
    y = np.asarray(y, float)
    gam = p.unit_weight if p.gravity else 0.0
    syy = -(p.p_top + gam * (g.H - y))
    return np.stack([p.K0 * syy, syy, np.zeros_like(syy)], axis=-1)


def _traction_forces(s, nrm, L):
    """(m,2) edge forces s.n L of stresses s (m,3) on edges with normals nrm (m,2)."""
    return np.stack([s[:, 0] * nrm[:, 0] + s[:, 2] * nrm[:, 1], s[:, 2] * nrm[:, 0] + s[:, 1] * nrm[:, 1]], 1) * L


@dataclass(frozen=True)
class _Interfaces:
    """The interfaces of the full lattice (m of them, :func:`_interfaces`): cells and edges
    ``ci``, ``ca``, ``cj``, ``cb`` (m,) int; frame normals ``nf`` (m, 2) (the fault's normal on
    planar-fault edges); tensile strength ``ft`` [Pa], cohesion ``coh`` [Pa], friction angles
    ``phi``, ``phir`` (peak, residual) [deg]; ``is_disl`` (m,) bool; virgin normal and shear
    tractions ``sn0``, ``tau0`` [Pa]; fault segment ``fseg`` (m,) int (-1 off the fault) and
    weight ``flam`` (m,), both None without a planar fault."""
    ci: np.ndarray
    ca: np.ndarray
    cj: np.ndarray
    cb: np.ndarray
    nf: np.ndarray
    ft: np.ndarray
    coh: np.ndarray
    phi: np.ndarray
    phir: np.ndarray
    is_disl: np.ndarray
    sn0: np.ndarray
    tau0: np.ndarray
    fseg: np.ndarray | None
    flam: np.ndarray | None


def _interfaces(p: MineParams, g: Geometry, lat, is_coal) -> _Interfaces:
    """The interfaces of the full lattice ``lat`` (m of them): strengths by material, the
    dislocations (no tension, ``disl_c``, ``disl_phi_deg``), the unbreakable loading layer above
    ``g.y_elastic``, the virgin tractions on each edge, and the planar fault's frame and segments
    (``fault_law="plane"``, :func:`~dem.hexagons.fault.plane_fault`)."""
    C = lat.centres
    ci, ca, cj, cb = lat.ifc.T
    n = lat.geo["n"][ca]
    t = lat.geo["t"][ca]
    mid = C[ci] + lat.geo["x"][ca]
    any_coal = is_coal[ci] | is_coal[cj]
    ft = np.where(any_coal, p.coal_ft, p.rock_ft).astype(float)
    coh = np.where(any_coal, p.coal_c, p.rock_c).astype(float)
    phi = np.where(any_coal, p.coal_phi_deg, p.rock_phi_deg).astype(float)
    is_disl = np.zeros(len(ci), bool)
    for seg in g.dislocations:
        is_disl |= segments_cross(C[ci], C[cj], seg[0], seg[1])
    ft[is_disl] = 0.0
    coh[is_disl] = p.disl_c
    phi[is_disl] = p.coal_phi_deg if p.disl_phi_deg < 0 else p.disl_phi_deg
    phir = phi if p.friction_residual_deg < 0 else np.full_like(phi, p.friction_residual_deg)
    layer = (C[ci, 1] >= g.y_elastic - _TOL) & (C[cj, 1] >= g.y_elastic - _TOL) & ~any_coal
    ft[layer] = _BIG
    coh[layer] = _BIG
    if p.elastic:
        ft[:] = _BIG
        coh[:] = _BIG
    s0 = virgin_stress(p, g, mid[:, 1])
    sn0 = s0[:, 0] * n[:, 0] ** 2 + s0[:, 1] * n[:, 1] ** 2 + 2 * s0[:, 2] * n[:, 0] * n[:, 1]
    tau0 = (s0[:, 0] * n[:, 0] * t[:, 0] + s0[:, 1] * n[:, 1] * t[:, 1]
            + s0[:, 2] * (n[:, 0] * t[:, 1] + n[:, 1] * t[:, 0]))
    nf = n.copy()
    fseg = flam = None
    if p.fault_law == "plane" and len(g.dislocations):
        # the planar fault: the crossed edges take the fault's frame and act in segments
        fseg = -np.ones(len(ci), np.int64)
        flam = np.zeros(len(ci))
        nseg = 0
        for seg in g.dislocations:
            cr = segments_cross(C[ci], C[cj], seg[0], seg[1]) & (fseg < 0)
            pf = plane_fault(n, mid, cr, seg[0], seg[1], s0, first_segment=nseg)
            k = pf["idx"]
            nf[k, 0], nf[k, 1] = pf["nx"], pf["ny"]
            sn0[k], tau0[k], flam[k], fseg[k] = pf["sn0"], pf["tau0"], pf["flam"], pf["fseg"]
            nseg = int(fseg.max()) + 1
    return _Interfaces(ci=ci, ca=ca, cj=cj, cb=cb, nf=nf, ft=ft, coh=coh, phi=phi, phir=phir,
                       is_disl=is_disl, sn0=sn0, tau0=tau0, fseg=fseg, flam=flam)


def _loads(p: MineParams, g: Geometry, lat, mnode, is_disl, is_coal, ci, cj):
    """The loads and supports of the full lattice ``lat`` (N cells, 12 dofs each): element
    prestress ``f0`` (N, 12) [N/m] of the virgin stress, dead loads ``fext`` (N, 12) [N/m] (the
    virgin tractions on the free edges, gravity, the eigenstrain gas), the free edges ``fc``,
    ``fe``, ``side`` (:func:`~dem.hexagons.lattice.classify_free_edges`), the gassy cells (N,)
    bool, the gas forces ``f_gas`` (N, 12) [N/m] and the inverse nodal masses ``minv`` (N, 12)
    [m/kg] (nodal masses per m of thickness), zero on the supported dofs."""
    geo, C, N = lat.geo, lat.centres, lat.n_cells
    L = geo["L"]
    nn = geo["n"]
    sc = virgin_stress(p, g, C[:, 1])
    f0 = np.zeros((N, 12))
    f0[:, 0::2] = (sc[:, 0:1] * nn[None, :, 0] + sc[:, 2:3] * nn[None, :, 1]) * L
    f0[:, 1::2] = (sc[:, 2:3] * nn[None, :, 0] + sc[:, 1:2] * nn[None, :, 1]) * L
    fext = np.zeros((N, 12))
    fc, fe, side = classify_free_edges(lat, g.W, g.H)
    fb = _traction_forces(virgin_stress(p, g, (C[fc] + geo["x"][fe])[:, 1]), nn[fe], L)
    fext[fc, 2 * fe] += fb[:, 0]
    fext[fc, 2 * fe + 1] += fb[:, 1]
    if p.gravity:
        fext[:, 1::2] -= (mnode * G_ACC)[:, None]
    gassy = gassy_cells(N, ci, cj, is_disl, is_coal) if p.gas in ("eigenstrain", "released") else np.zeros(N, bool)
    f_gas = eigenstrain_forces(gassy, nn, L, p.gas_pressure)
    if p.gas == "eigenstrain":
        fext += f_gas                     # part of the virgin equilibrium
    minv = np.full((N, 12), 1.0 / mnode[0])
    fixed = [(LEFT, 0), (RIGHT, 0), (BOTTOM, 1)]
    if p.floor == "no_slip":
        fixed.append((BOTTOM, 0))
    if p.loading == "rollers":
        fixed.append((TOP, 1))
    for s_id, comp in fixed:
        m_ = side == s_id
        minv[fc[m_], 2 * fe[m_] + comp] = 0.0
    return f0, fext, fc, fe, side, gassy, f_gas, minv


def _effective_moduli(p: MineParams, mats, kn, kt) -> dict:
    """Per material (``"rock"``, ``"coal"``; ``mats`` their ``(E [Pa], nu)``) the input ``E``, ``nu``
    and the periodic lattice's effective ``E_eff`` [Pa], ``nu_eff`` and ``E_eff_over_E`` with the
    interface stiffnesses ``kn``, ``kt`` [Pa/m] (:func:`~dem.hexagons.element.periodic_moduli`)."""
    r_in, theta0 = p.r_in, p.theta0
    E_eff = {}
    for name, (E, nu) in zip(("rock", "coal"), mats):
        Ee, nue = isotropic_from_C(periodic_moduli(element_stiffness(E, nu, r_in, theta0, kind=p.element),
                                                   r_in, kn, kt, theta0))
        E_eff[name] = {"E": E, "nu": nu, "E_eff": Ee, "nu_eff": nue, "E_eff_over_E": Ee / E}
    return E_eff


def build_scene(p: MineParams, virgin_check: bool = True) -> Scene:
    """The scene of ``p`` ready to run (validated first)."""
    p.validate()
    g = resolve(p)
    theta0 = p.theta0
    r_in = p.r_in
    axis_x = 0.5 * (g.open_x0 + g.open_x1) if p.model == "full" else 0.0
    lat = make_lattice(g.W, g.H, r_in, theta0, anchor=(axis_x, g.seam_mid))
    geo = lat.geo
    N = lat.n_cells
    C = lat.centres
    is_coal = (C[:, 1] >= g.seam_lo - _TOL) & (C[:, 1] <= g.seam_hi + _TOL)
    in_open = is_coal & (C[:, 0] >= g.open_x0 - _TOL) & (C[:, 0] <= g.open_x1 + _TOL)
    mats = [(p.rock_E, p.rock_nu), (p.coal_E, p.coal_nu)]
    mat = is_coal.astype(np.int64)
    Kmat = np.stack([element_stiffness(E, nu, r_in, theta0, kind=p.element) for E, nu in mats])
    kn = p.kn if p.kn > 0 else spring_stiffness_rule(mats, r_in, p.penalty_factor)
    kt = p.kt_over_kn * kn
    L = geo["L"]
    mnode = np.full(N, p.rho * geo["A"] / 6.0)

    fi = _interfaces(p, g, lat, is_coal)
    ci, ca, cj, cb = fi.ci, fi.ca, fi.cj, fi.cb
    ft, coh, phi, phir, is_disl = fi.ft, fi.coh, fi.phi, fi.phir, fi.is_disl
    sn0, tau0, nf, fseg, flam = fi.sn0, fi.tau0, fi.nf, fi.fseg, fi.flam
    f0, fext, fc, fe, side, gassy, f_gas, minv = _loads(p, g, lat, mnode, is_disl, is_coal, ci, cj)

    zeros = np.zeros(len(ci))
    full = Model(centres=C, mat=mat, is_coal=is_coal, Kmat=Kmat, f0=f0, fext=fext, mnode=mnode, minv=minv,
                 geo=geo, ci=ci.copy(), ca=ca.copy(), cj=cj.copy(), cb=cb.copy(), nx=nf[:, 0].copy(),
                 ny=nf[:, 1].copy(), L=L, kn=np.full(len(ci), kn), kt=np.full(len(ci), kt), ft=ft, coh=coh,
                 tanphi=np.tan(np.radians(phi)), tanphi_r=np.tan(np.radians(phir)),
                 vent=np.full(len(ci), p.gas_vent_opening), sn0=sn0, is_disl=is_disl, sn=sn0.copy(),
                 tau=tau0.copy(), jtp=zeros.copy(), jnp=zeros.copy(), broken=np.zeros(len(ci), np.int64),
                 pg=interface_pressure(p, is_disl) * (1.0 if flam is None else np.where(fseg >= 0, flam, 1.0)),
                 wc=np.zeros(0, np.int64), wk=np.zeros(0, np.int64),
                 FE0=np.zeros((0, 2)), ramp_kind=RAMP_CODES["none"], ramp_time=0.0, fseg=fseg, flam=flam)
    full.u = np.zeros((N, 12))
    uf = virgin_utilisation(full, fault_only=True)[0] if fseg is not None else 0.0
    if virgin_check and not p.elastic and uf >= 1.0:     # checked on the preloads, before any solve
        raise ValueError(f"disl_phi_deg={p.disl_phi_deg}, disl_c={p.disl_c}: the planar dislocation fails at the "
                         f"virgin state (K0={p.K0:.3f}, utilisation {uf:.3f} on the true plane); raise "
                         "disl_phi_deg, disl_c or K0 (docs/mine_scene.md, the paper's data are not "
                         "self-consistent)")
    residual = virgin_state(full, kn, kt)
    util, nfail = virgin_utilisation(full)
    util = 0.0 if p.elastic else util
    if virgin_check and util >= 1.0:
        raise ValueError(f"orientation_deg={p.orientation_deg}: the virgin state violates Mohr-Coulomb on {nfail} "
                         f"interfaces (max utilisation {util:.3f}) with K0={p.K0:.3f} before excavation; use "
                         "orientation_deg=0 (normals at 0, +-60 deg)")

    model, keep = excavate(full, in_open, RAMP_CODES[p.ramp], p.ramp_time, p.damping, p.v_abort)
    n_eshelby = len(model.wc)
    if p.gas == "released":
        release_gas_with_excavation(model, f_gas[keep])
    _boundary_devices(p, model, fc, fe, side, keep, N, full.u)
    model.cdash = p.contact_damping * 2.0 * np.sqrt(L * kn * mnode[0] / 2.0)
    if p.contact:
        kc = p.contact_factor * kn * L
        model.enable_contact(kc, p.contact_damping * 2.0 * np.sqrt(kc * 6 * mnode[0] / 2.0))
    model.u0 = model.u.copy()
    model.vh = np.zeros_like(model.u)
    model.vh_prev = np.zeros_like(model.u)
    model.t = 0.0
    model.U0 = stored_energy_abs(model)
    model.f = forces_frozen(model, model.u)
    E_eff = _effective_moduli(p, mats, kn, kt)
    sc_ = Scene(params=p, geometry=g, model=model, full_centres=C, opening_cells=np.nonzero(in_open)[0],
                keep=keep, kn=kn, kt=kt, labels=block_labels(g, model.centres, model.is_coal), gassy=gassy[keep],
                E_eff=E_eff, virgin_residual=residual, virgin_utilisation=util,
                sigma0=virgin_stress(p, g, np.array(g.H)))
    sc_.info = {"n_cells_full": int(N), "n_cells": int(len(keep)), "n_interfaces": int(model.n_ifc),
                "n_wall_nodes": int(n_eshelby), "n_gas_nodes": int(len(model.wc) - n_eshelby),
                "n_disl_interfaces": int(model.is_disl.sum()),
                "kn": kn, "kt": kt, "rho": p.rho, "p_top": p.p_top}
    return sc_


def _boundary_devices(p, model, fc, fe, side, keep, n_full, u_virgin):
    """Overburden spring on the top (loading="spring") and Lysmer-Kuhlemeyer dashpots (absorbing):
    c_n = rho c_p L on the normal, c_t = rho c_s L on the tangential dof of each far-boundary node.
    Far boundaries: the top (unless it is a roller, then only its tangential dof) and the outer side(s)
    (right; both in the full model), whose roller is replaced by the virgin traction (a dead load,
    already applied) and the dashpots. The half-model's symmetry plane and the floor keep their
    supports. Devices act on the excavated model only (the virgin state is unaffected)."""
    newidx = -np.ones(n_full, np.int64)
    newidx[keep] = np.arange(len(keep))
    L = model.L
    N = model.n_cells
    if p.loading == "spring":
        lam = p.rock_E * p.rock_nu / ((1 + p.rock_nu) * (1 - 2 * p.rock_nu))
        Mr = lam + p.rock_E / (1 + p.rock_nu)
        model.kspr = np.zeros((N, 12))
        model.uref = u_virgin[keep].copy()
        m_ = side == TOP
        c = newidx[fc[m_]]
        ok = c >= 0
        model.kspr[c[ok], 2 * fe[m_][ok] + 1] = L * Mr / p.overburden_height
    if not p.absorbing:
        return
    model.cvis = np.zeros((N, 12))
    cp, cs = [], []
    for E, nu in ((p.rock_E, p.rock_nu), (p.coal_E, p.coal_nu)):
        lam = E * nu / ((1 + nu) * (1 - 2 * nu))
        mu = E / (2 * (1 + nu))
        cp.append(np.sqrt((lam + 2 * mu) / p.rho))
        cs.append(np.sqrt(mu / p.rho))
    cp, cs = np.array(cp), np.array(cs)
    far_sides = [RIGHT] if p.model == "half" else [LEFT, RIGHT]
    for s_id, normal in [(s, 0) for s in far_sides] + [(TOP, 1)]:
        m_ = side == s_id
        c = newidx[fc[m_]]
        ok = c >= 0
        c, e = c[ok], fe[m_][ok]
        mt = model.mat[c]
        if not (s_id == TOP and p.loading == "rollers"):
            model.cvis[c, 2 * e + normal] = p.rho * cp[mt] * L
            model.minv[c, 2 * e + normal] = 1.0 / model.mnode[c]
        model.cvis[c, 2 * e + 1 - normal] = p.rho * cs[mt] * L
