"""The mine scene: parameters (dataclass + TOML), validation, building the hexagon model and the
exact virgin state.

Units: SI (m, Pa, Pa/m, N/m^3, s, deg for angles). Tension positive. Plane strain, per m thickness.

Defaults reproduce the paper's case as read in docs/mine_scene.md: 26 m x 9.5 m, coal seam 4.75 m
on the floor, inner radius 0.25 m, adit 3 m wide modelled as a half-model (left side = symmetry plane
of the adit, opening x in [0, 1.5] m), rollers on the sides and the floor, 25 MPa overburden traction
on the top, K0 = 1/3, one gassy dislocation at 60 deg 2.5 m from the rib.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field, fields

import numpy as np
import scipy.sparse.linalg as spla

from .dynamics import RAMP_CODES, Model, assemble_stiffness, model_forces, stored_energy_abs
from .element import element_stiffness, periodic_moduli, isotropic_from_C
from .interface import spring_stiffness_rule
from .lattice import classify_free_edges, make_lattice

__all__ = ["MineParams", "Scene", "build_scene", "load_toml", "UNITS"]

G_ACC = 9.81

UNITS = {
    "width": "m", "height": "m", "seam_bottom": "m", "seam_top": "m", "opening_x0": "m",
    "opening_width": "m", "r_in": "m", "orientation_deg": "deg", "element": "-",
    "rock_E": "Pa", "rock_nu": "-", "rock_phi_deg": "deg", "rock_c": "Pa", "rock_ft": "Pa",
    "coal_E": "Pa", "coal_nu": "-", "coal_phi_deg": "deg", "coal_c": "Pa", "coal_ft": "Pa",
    "unit_weight": "N/m^3", "penalty_factor": "-", "kn": "Pa/m", "kt_over_kn": "-",
    "depth": "m", "K0": "-", "top_bc": "-", "gravity": "-", "ramp": "-", "ramp_time": "s",
    "disl_angle_deg": "deg", "n_disl": "-", "disl_first": "m", "disl_spacing": "m",
    "disl_side": "-", "disl_phi_deg": "deg", "gas": "-", "gas_pressure": "Pa", "gas_vent_opening": "m",
    "elastic": "-", "elastic_layer": "m", "contact_damping": "-", "v_abort": "m/s", "duration": "s", "dt_safety": "-", "damping": "1/s", "output_every": "s",
    "friction_residual_deg": "deg", "contact": "-", "contact_factor": "-",
}


@dataclass
class MineParams:
    """Every parameter of the scene, SI units (see ``UNITS``)."""
    # geometry
    width: float = 26.0
    height: float = 9.5
    seam_bottom: float = 0.0
    seam_top: float = 4.75
    opening_x0: float = 0.0          # 0 -> half-model, left side is the adit's symmetry plane
    opening_width: float = 1.5       # width modelled (half of the 3 m adit in the half-model)
    r_in: float = 0.25               # inner radius (apothem) of the hexagons
    orientation_deg: float = 0.0     # normal of edge 0; 0 = pointy-top (normals 0, +-60)
    element: str = "hybrid"          # 'hybrid' | 'bem'
    # materials (paper)
    rock_E: float = 50e9
    rock_nu: float = 0.25            # from G = 20 GPa
    rock_phi_deg: float = 25.0
    rock_c: float = 1e6
    rock_ft: float = 100e3
    coal_E: float = 5e9
    coal_nu: float = 0.25            # from G = 2 GPa
    coal_phi_deg: float = 22.0
    coal_c: float = 150e3
    coal_ft: float = 10e3
    unit_weight: float = 25e3
    friction_residual_deg: float = -1.0   # <0: residual friction = peak friction of the interface
    # interfaces
    penalty_factor: float = 10.0     # kn = factor * max(K + 4G/3) / r_in   (Itasca rule)
    kn: float = 0.0                  # >0 overrides the rule
    kt_over_kn: float = 1.0
    # loading
    depth: float = 1000.0
    K0: float = 1.0 / 3.0
    top_bc: str = "traction"         # 'traction' (overburden) | 'roller'
    gravity: bool = False            # paper: volume weight neglected in the model
    # excavation
    ramp: str = "linear"             # 'instant' | 'linear' | 'nonlinear' | 'none'
    ramp_time: float = 0.01
    # dislocations
    n_disl: int = 1
    disl_angle_deg: float = 60.0
    disl_first: float = 2.5          # distance of the end nearest to the opening from the rib
    disl_spacing: float = 5.0
    disl_side: str = "right"         # rib holding the dislocations ('left' only with an inner opening)
    disl_phi_deg: float = -1.0       # <0: coal friction angle
    gas: bool = True
    gas_pressure: float = 1e6
    gas_vent_opening: float = 0.01   # crack opening above which the gas has escaped
    # run
    elastic: bool = False            # infinite strengths (verification)
    elastic_layer: float = 2.375     # top rock layer with unbreakable interfaces (paper: the upper
                                     # rock part 'expresses the depth' and carries the loading)
    duration: float = 0.1            # dynamics after the end of the ramp
    dt_safety: float = 0.7           # fraction of the safe bound (lattice Gershgorin + contact, D8)
    damping: float = 0.0             # mass-proportional damping alpha [1/s]; 0 in the dynamic phase
    contact_damping: float = 0.0     # damping ratio of a dashpot on cracked, closed interfaces and on
                                     # new contacts (D7 variant: 0.1); 0 = no artificial damping
    contact: bool = True             # proximity contact of cells that were not neighbours (cells with
                                     # broken interfaces only)
    contact_factor: float = 1.0      # its penalty stiffness kc = contact_factor * kn * L
    v_abort: float = 1e3             # runaway guard [m/s]
    output_every: float = 5e-4

    # ------------------------------------------------------------------ validation
    def validate(self) -> "MineParams":
        def bad(name, msg):
            raise ValueError(f"{name}={getattr(self, name)!r}: {msg}")

        for name in ("width", "height", "r_in", "opening_width", "rock_E", "coal_E", "unit_weight",
                     "penalty_factor", "kt_over_kn", "dt_safety", "output_every", "contact_factor"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                bad(name, "must be a finite number > 0")
        for name in ("rock_nu", "coal_nu"):
            if not (-1.0 < getattr(self, name) < 0.5):
                bad(name, "Poisson's ratio must be in (-1, 0.5)")
        for name in ("rock_phi_deg", "coal_phi_deg"):
            if not (0.0 <= getattr(self, name) < 90.0):
                bad(name, "friction angle must be in [0, 90) deg")
        for name in ("disl_phi_deg", "friction_residual_deg"):
            v = getattr(self, name)
            if v >= 90.0:
                bad(name, "friction angle must be < 90 deg (negative = default)")
        for name in ("rock_c", "rock_ft", "coal_c", "coal_ft", "gas_pressure", "depth", "ramp_time",
                     "duration", "damping", "contact_damping", "kn", "disl_first", "gas_vent_opening", "elastic_layer"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                bad(name, "must be a finite number >= 0")
        if not (self.K0 > 0):
            bad("K0", "must be > 0")
        if self.elastic_layer > self.height - self.seam_top:
            bad("elastic_layer", "must not reach into the seam (<= height - seam_top)")
        if not (0 <= self.seam_bottom < self.seam_top <= self.height):
            bad("seam_top", f"need 0 <= seam_bottom < seam_top <= height ({self.height})")
        if self.opening_x0 < 0 or self.opening_x0 + self.opening_width > self.width:
            bad("opening_x0", "opening must lie inside [0, width]")
        if self.dt_safety > 1.0:
            bad("dt_safety", "must be <= 1 (fraction of the Gershgorin bound)")
        if self.top_bc not in ("traction", "roller"):
            bad("top_bc", "must be 'traction' or 'roller'")
        if self.element not in ("hybrid", "bem"):
            bad("element", "must be 'hybrid' or 'bem'")
        if self.ramp not in RAMP_CODES:
            bad("ramp", f"must be one of {sorted(RAMP_CODES)}")
        if self.ramp in ("linear", "nonlinear") and self.ramp_time <= 0:
            bad("ramp_time", "must be > 0 for a linear/nonlinear ramp (use ramp='instant')")
        if not (isinstance(self.n_disl, int) and 0 <= self.n_disl <= 3):
            bad("n_disl", "must be an integer 0..3")
        if self.disl_side not in ("right", "left"):
            bad("disl_side", "must be 'right' or 'left'")
        if self.disl_side == "left" and self.opening_x0 <= 0:
            bad("disl_side", "a left-rib dislocation needs an opening away from the left boundary")
        if self.n_disl > 0:
            if not (0.0 < self.disl_angle_deg < 180.0):
                bad("disl_angle_deg", "must be in (0, 180) deg, counter-clockwise from +x")
            if self.n_disl > 1 and not (self.disl_spacing > 0):
                bad("disl_spacing", "must be > 0 with more than one dislocation")
            for k, seg in enumerate(self.dislocation_segments()):
                xs = seg[:, 0]
                lo, hi = (self.opening_x0 + self.opening_width, self.width) if self.disl_side == "right" \
                    else (0.0, self.opening_x0)
                if xs.min() < lo - 1e-9 or xs.max() > hi + 1e-9:
                    raise ValueError(
                        f"dislocation {k + 1} spans x in [{xs.min():.3f}, {xs.max():.3f}] m, outside the "
                        f"seam of the {self.disl_side} rib [{lo:.3f}, {hi:.3f}] m: check disl_first, "
                        f"disl_spacing, disl_angle_deg, n_disl")
        return self

    # ------------------------------------------------------------------ derived
    @property
    def rib_x(self) -> float:
        return self.opening_x0 + self.opening_width if self.disl_side == "right" else self.opening_x0

    def dislocation_segments(self):
        """List of (2,2) arrays: end points of each dislocation, spanning the seam height.

        The end nearest to the opening lies ``disl_first + k*disl_spacing`` from the rib (paper: the
        60 deg toe on the floor, the 120 deg top at the seam roof, both 2.5 m from the face).
        """
        segs = []
        h = self.seam_top - self.seam_bottom
        beta = math.radians(self.disl_angle_deg)
        dx = h / math.tan(beta)          # x(top) - x(bottom)
        sgn = 1.0 if self.disl_side == "right" else -1.0
        for k in range(self.n_disl):
            near = self.rib_x + sgn * (self.disl_first + k * self.disl_spacing)
            # mirror for the left rib: angle 180-beta keeps the same geometry about the opening axis
            ddx = dx if self.disl_side == "right" else -dx
            if sgn * ddx >= 0:           # top end is farther from the opening: near end on the floor
                pb, pt = near, near + ddx
            else:                        # near end at the roof
                pt, pb = near, near - ddx
            segs.append(np.array([[pb, self.seam_bottom], [pt, self.seam_top]]))
        return segs

    @property
    def theta0(self) -> float:
        return math.radians(self.orientation_deg)

    @property
    def rho(self) -> float:
        return self.unit_weight / G_ACC

    @property
    def p_top(self) -> float:
        return self.unit_weight * self.depth

    def replace(self, **kw) -> "MineParams":
        return dataclasses.replace(self, **kw)

    @classmethod
    def note_b0(cls, **kw) -> "MineParams":
        """MINE_SCENE.md §6.1 baseline B0-T: centred 3 m opening at x in [11.5, 14.5] m, right rib,
        dislocation through (16, seam mid-height)."""
        base = dict(opening_x0=11.5, opening_width=3.0)
        base.update(kw)
        return cls(**base)

    def to_dict(self):
        return dataclasses.asdict(self)


def load_toml(path) -> MineParams:
    """Read a TOML file: top-level keys (or a [scene] table) named like the MineParams fields."""
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    if "scene" in data and isinstance(data["scene"], dict):
        data = data["scene"]
    names = {f.name for f in fields(MineParams)}
    unknown = set(data) - names
    if unknown:
        raise ValueError(f"unknown scene parameter(s) {sorted(unknown)} in {path}")
    return MineParams(**data).validate()


def _seg_cross(p1, p2, q1, q2):
    """Vectorised proper intersection of segments p1p2 (m,2) with one segment q1q2."""
    def orient(a, b, c):
        return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
    d1 = orient(q1, q2, p1)
    d2 = orient(q1, q2, p2)
    d3 = orient(p1, p2, q1)
    d4 = orient(p1, p2, q2)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


@dataclass
class Scene:
    params: MineParams
    model: Model                      # the excavated model (opening cells removed)
    full_centres: np.ndarray
    opening_cells: np.ndarray         # indices (full lattice) of removed cells
    keep: np.ndarray                  # full index of every model cell
    kn: float
    kt: float
    E_eff: dict = field(default_factory=dict)
    virgin_residual: float = 0.0
    virgin_utilisation: float = 0.0
    sigma0: np.ndarray = None         # (3,) virgin stress at the top (no gravity: uniform)
    wall_side: np.ndarray = None
    info: dict = field(default_factory=dict)

    def virgin_stress(self, y):
        return _sigma0(self.params, y)


def _sigma0(p: MineParams, y):
    y = np.asarray(y, float)
    gam = p.unit_weight if p.gravity else 0.0
    syy = -(p.p_top + gam * (p.height - y))
    return np.stack([p.K0 * syy, syy, np.zeros_like(syy)], axis=-1)


def build_scene(p: MineParams, virgin_check: bool = True) -> Scene:
    """Lattice -> materials -> interfaces -> boundaries -> exact virgin state (sparse static solve
    on the full, un-excavated model) -> excavated model with Eshelby wall forces F_E0."""
    p.validate()
    theta0 = p.theta0
    axis_x = p.opening_x0 + 0.5 * p.opening_width if p.opening_x0 > 0 else 0.0
    anchor = (axis_x, 0.5 * (p.seam_bottom + p.seam_top))
    lat = make_lattice(p.width, p.height, p.r_in, theta0, anchor=anchor)
    geo = lat.geo
    N = lat.n_cells
    C = lat.centres
    tol = 1e-9
    is_coal = (C[:, 1] >= p.seam_bottom - tol) & (C[:, 1] <= p.seam_top + tol)
    in_open = is_coal & (C[:, 0] >= p.opening_x0 - tol) & (C[:, 0] <= p.opening_x0 + p.opening_width + tol)
    mats = [(p.rock_E, p.rock_nu), (p.coal_E, p.coal_nu)]
    mat = is_coal.astype(np.int64)
    Kmat = np.stack([element_stiffness(E, nu, p.r_in, theta0, kind=p.element) for E, nu in mats])
    kn = p.kn if p.kn > 0 else spring_stiffness_rule(mats, p.r_in, p.penalty_factor)
    kt = p.kt_over_kn * kn
    A = geo["A"]
    L = geo["L"]
    mnode_full = np.full(N, p.rho * A / 6.0)

    # ------------------------------------------------------------------ interfaces (full lattice)
    ifc = lat.ifc
    ci, ca, cj, cb = ifc.T
    n = geo["n"][ca]
    t = geo["t"][ca]
    mid = C[ci] + geo["x"][ca]
    any_coal = is_coal[ci] | is_coal[cj]
    big = 1e300
    ft = np.where(any_coal, p.coal_ft, p.rock_ft).astype(float)
    coh = np.where(any_coal, p.coal_c, p.rock_c).astype(float)
    phi = np.where(any_coal, p.coal_phi_deg, p.rock_phi_deg).astype(float)
    is_disl = np.zeros(len(ci), bool)
    for seg in (p.dislocation_segments() if p.n_disl > 0 else []):
        is_disl |= _seg_cross(C[ci], C[cj], seg[0], seg[1])
    dphi = p.coal_phi_deg if p.disl_phi_deg < 0 else p.disl_phi_deg
    ft[is_disl] = 0.0
    coh[is_disl] = 0.0
    phi[is_disl] = dphi
    phir = phi if p.friction_residual_deg < 0 else np.full_like(phi, p.friction_residual_deg)
    top_layer = (C[ci, 1] >= p.height - p.elastic_layer - tol) & (C[cj, 1] >= p.height - p.elastic_layer - tol)
    top_layer &= ~any_coal
    ft[top_layer] = big
    coh[top_layer] = big
    if p.elastic:
        ft[:] = big
        coh[:] = big
    pg = np.where(is_disl & p.gas, p.gas_pressure, 0.0)
    s0 = _sigma0(p, mid[:, 1])
    sn0 = s0[:, 0] * n[:, 0] ** 2 + s0[:, 1] * n[:, 1] ** 2 + 2 * s0[:, 2] * n[:, 0] * n[:, 1]
    tau0 = (s0[:, 0] * n[:, 0] * t[:, 0] + s0[:, 1] * n[:, 1] * t[:, 1]
            + s0[:, 2] * (n[:, 0] * t[:, 1] + n[:, 1] * t[:, 0]))

    # ------------------------------------------------------------------ element prestress, loads
    sc = _sigma0(p, C[:, 1])
    nn = geo["n"]
    f0 = np.zeros((N, 12))
    f0[:, 0::2] = (sc[:, 0:1] * nn[None, :, 0] + sc[:, 2:3] * nn[None, :, 1]) * L
    f0[:, 1::2] = (sc[:, 2:3] * nn[None, :, 0] + sc[:, 1:2] * nn[None, :, 1]) * L
    fext = np.zeros((N, 12))
    minv = np.full((N, 12), 1.0 / mnode_full[0])
    fc, fe, side = classify_free_edges(lat, p.width, p.height)
    fmid = C[fc] + geo["x"][fe]
    sb = _sigma0(p, fmid[:, 1])
    fn = nn[fe]
    fext[fc, 2 * fe] += (sb[:, 0] * fn[:, 0] + sb[:, 2] * fn[:, 1]) * L
    fext[fc, 2 * fe + 1] += (sb[:, 2] * fn[:, 0] + sb[:, 1] * fn[:, 1]) * L
    # constraints: rollers on sides (u_x) and floor (u_y); top roller optional
    for s_id, comp in ((0, 0), (1, 0), (2, 1)):
        m_ = side == s_id
        minv[fc[m_], 2 * fe[m_] + comp] = 0.0
    if p.top_bc == "roller":
        m_ = side == 3
        minv[fc[m_], 2 * fe[m_] + 1] = 0.0
    if p.gravity:
        fext[:, 1::2] -= (mnode_full * G_ACC)[:, None]

    zeros = np.zeros(len(ci))
    full = Model(centres=C, mat=mat, is_coal=is_coal, Kmat=Kmat, f0=f0, fext=fext, mnode=mnode_full,
                 minv=minv, geo=geo, ci=ci.copy(), ca=ca.copy(), cj=cj.copy(), cb=cb.copy(),
                 nx=n[:, 0].copy(), ny=n[:, 1].copy(), L=L, kn=np.full(len(ci), kn), kt=np.full(len(ci), kt),
                 ft=ft, coh=coh, tanphi=np.tan(np.radians(phi)), tanphi_r=np.tan(np.radians(phir)),
                 vent=np.full(len(ci), p.gas_vent_opening), sn0=sn0, is_disl=is_disl,
                 sn=sn0.copy(), tau=tau0.copy(), jtp=zeros.copy(), jnp=zeros.copy(),
                 broken=np.zeros(len(ci), np.int64), pg=pg.astype(float),
                 wc=np.zeros(0, np.int64), wk=np.zeros(0, np.int64), FE0=np.zeros((0, 2)),
                 ramp_kind=RAMP_CODES["none"], ramp_time=0.0)
    full.u = np.zeros((N, 12))

    # ------------------------------------------------------------------ exact virgin state
    # F(u) = F(0) - K u for the intact elastic assembly: solve K u = F(0) on the free dofs.
    # (interface states are evaluated on a copy so that the solve itself does not advance them)
    F0 = _forces_frozen(full, full.u)
    K = assemble_stiffness(full)
    free = minv.ravel() > 0
    Kf = K[free][:, free].tocsc()
    uf = spla.spsolve(Kf, F0.ravel()[free])
    uv = np.zeros(12 * N)
    uv[free] = uf
    uv = uv.reshape(N, 12)
    # set interface states to the virgin values at uv
    dux = uv[cj, 2 * cb] - uv[ci, 2 * ca]
    duy = uv[cj, 2 * cb + 1] - uv[ci, 2 * ca + 1]
    jn = dux * n[:, 0] + duy * n[:, 1]
    jt = -dux * n[:, 1] + duy * n[:, 0]
    full.sn = sn0 + kn * jn
    full.tau = tau0 + kt * jt
    full.jtp = jt.copy()
    full.jnp = jn.copy()
    full.u = uv
    Fv = _forces_frozen(full, uv)
    fscale = np.abs(F0).max() + np.abs(f0).max()
    virgin_res = float(np.abs(Fv.ravel()[free]).max() / fscale)
    # virgin utilisation (strength check)
    spv = full.sn + full.pg
    lim = full.coh - spv * full.tanphi
    util_t = np.where(full.ft > 0, spv / np.where(full.ft > 0, full.ft, 1.0), np.where(spv >= 0, np.inf, 0.0))
    util_s = np.abs(full.tau) / np.maximum(lim, 1e-300)
    util_s = np.where(lim > 0, util_s, np.inf)
    util = float(max(util_t.max(), util_s.max())) if not p.elastic else 0.0
    if virgin_check and util >= 1.0:
        nfail = int(np.sum((util_t >= 1) | (util_s >= 1)))
        raise ValueError(f"virgin state violates Mohr-Coulomb on {nfail} interfaces (max utilisation "
                         f"{util:.3f}); orientation_deg={p.orientation_deg} with K0={p.K0:.3f} is unstable "
                         "before excavation - use orientation_deg=0 (normals at 0, +-60 deg)")

    # ------------------------------------------------------------------ excavate: remove opening cells
    keep = np.nonzero(~in_open)[0]
    newidx = -np.ones(N, np.int64)
    newidx[keep] = np.arange(len(keep))
    ki = ~in_open[ci] & ~in_open[cj]
    # wall: interfaces between a kept cell and an opening cell -> F_E0 on the kept node
    Fifc_x = L * (full.sn * n[:, 0] - full.tau * n[:, 1])
    Fifc_y = L * (full.sn * n[:, 1] + full.tau * n[:, 0])
    wc, wk, FE = [], [], []
    m1 = ~in_open[ci] & in_open[cj]      # kept i: force on node (i, a) is +F
    m2 = in_open[ci] & ~in_open[cj]      # kept j: force on node (j, b) is -F
    for mm, cc, kk, sg in ((m1, ci, ca, 1.0), (m2, cj, cb, -1.0)):
        wc.append(newidx[cc[mm]])
        wk.append(kk[mm])
        FE.append(sg * np.stack([Fifc_x[mm], Fifc_y[mm]], axis=1))
    wc = np.concatenate(wc)
    wk = np.concatenate(wk)
    FE = np.concatenate(FE)
    # free edges of opening cells vanish; free edges of kept cells stay
    model = Model(centres=C[keep], mat=mat[keep], is_coal=is_coal[keep], Kmat=Kmat, f0=f0[keep],
                  fext=fext[keep], mnode=mnode_full[keep], minv=minv[keep], geo=geo,
                  ci=newidx[ci[ki]], ca=ca[ki].copy(), cj=newidx[cj[ki]], cb=cb[ki].copy(),
                  nx=n[ki, 0].copy(), ny=n[ki, 1].copy(), L=L, kn=full.kn[ki], kt=full.kt[ki],
                  ft=ft[ki], coh=coh[ki], tanphi=full.tanphi[ki], tanphi_r=full.tanphi_r[ki],
                  vent=full.vent[ki], sn0=sn0[ki], is_disl=is_disl[ki], sn=full.sn[ki].copy(),
                  tau=full.tau[ki].copy(), jtp=full.jtp[ki].copy(), jnp=full.jnp[ki].copy(),
                  broken=np.zeros(ki.sum(), np.int64), pg=full.pg[ki].copy(),
                  wc=wc, wk=wk, FE0=FE, ramp_kind=RAMP_CODES[p.ramp], ramp_time=p.ramp_time,
                  alpha=p.damping, v_abort=p.v_abort)
    # dashpot: ratio * critical damping of the node pair (mass m_node/2, stiffness L kn) per edge
    model.cdash = p.contact_damping * 2.0 * np.sqrt(L * kn * mnode_full[0] / 2.0)
    if p.contact:
        # new-neighbour contact: centre-line penalty kc = contact_factor * kn L (one face spring),
        # dashpot of the same ratio on the reduced cell mass m_cell/2
        kc = p.contact_factor * kn * L
        model.enable_contact(kc, p.contact_damping * 2.0 * np.sqrt(kc * 6 * mnode_full[0] / 2.0))
    model.u = uv[keep].copy()
    model.u0 = model.u.copy()
    model.vh = np.zeros_like(model.u)
    model.vh_prev = np.zeros_like(model.u)
    model.t = 0.0
    model.U0 = stored_energy_abs(model)
    model.f = _forces_frozen(model, model.u)
    # effective moduli of the lattice (periodic homogenisation, exact)
    E_eff = {}
    for name, (E, nu) in zip(("rock", "coal"), mats):
        Ke = element_stiffness(E, nu, p.r_in, theta0, kind=p.element)
        Ce = periodic_moduli(Ke, p.r_in, kn, kt, theta0)
        Ee, nue = isotropic_from_C(Ce)
        E_eff[name] = {"E": E, "nu": nu, "E_eff": Ee, "nu_eff": nue, "E_eff_over_E": Ee / E}
    sc_ = Scene(params=p, model=model, full_centres=C, opening_cells=np.nonzero(in_open)[0], keep=keep,
                kn=kn, kt=kt, E_eff=E_eff, virgin_residual=virgin_res, virgin_utilisation=util,
                sigma0=_sigma0(p, np.array(p.height)))
    sc_.info = {"n_cells_full": int(N), "n_cells": int(len(keep)), "n_interfaces": int(ki.sum()),
                "n_wall_nodes": int(len(wc)), "n_disl_interfaces": int(is_disl[ki].sum()),
                "kn": kn, "kt": kt, "rho": p.rho, "p_top": p.p_top}
    return sc_


def _forces_frozen(model: Model, u):
    """F(u, t=0) without changing the model's interface states or energy accounts."""
    saved = [a.copy() for a in (model.sn, model.tau, model.jtp, model.jnp, model.broken, model.pg, model.acc)]
    f = model_forces(model, u, 0.0)
    model.sn, model.tau, model.jtp, model.jnp, model.broken, model.pg, model.acc = saved
    return f


def free_cells_model(centres, velocities, E=50e9, nu=0.25, r_in=0.25, rho=25e3 / G_ACC,
                     contact_factor=1.0, contact_damping=0.0, theta0=0.0) -> Model:
    """Unbonded hexagons (no interfaces, no supports) with the new-neighbour contact switched on:
    the smallest model to check the proximity contact (tests). ``centres`` (n,2) m, ``velocities``
    (n,2) m/s (rigid translation of each cell). Contact stiffness and dashpot as in the scene:
    kc = contact_factor * kn L with kn from the Itasca rule."""
    C = np.asarray(centres, float).reshape(-1, 2)
    N = len(C)
    geo = make_lattice(1.0, 1.0, r_in, theta0).geo
    L = geo["L"]
    kn = spring_stiffness_rule([(E, nu)], r_in)
    mnode = np.full(N, rho * geo["A"] / 6.0)
    e64 = np.zeros(0, np.int64)
    z = np.zeros(0)
    m = Model(centres=C, mat=np.zeros(N, np.int64), is_coal=np.zeros(N, bool),
              Kmat=element_stiffness(E, nu, r_in, theta0)[None], f0=np.zeros((N, 12)), fext=np.zeros((N, 12)),
              mnode=mnode, minv=np.full((N, 12), 1.0 / mnode[0]), geo=geo, ci=e64, ca=e64, cj=e64, cb=e64,
              nx=z, ny=z, L=L, kn=z, kt=z, ft=z, coh=z, tanphi=z, tanphi_r=z, vent=z, sn0=z,
              is_disl=np.zeros(0, bool), sn=z.copy(), tau=z.copy(), jtp=z.copy(), jnp=z.copy(), broken=e64.copy(),
              pg=z.copy(), wc=e64, wk=e64, FE0=np.zeros((0, 2)), ramp_kind=RAMP_CODES["none"])
    kc = contact_factor * kn * L
    m.enable_contact(kc, contact_damping * 2.0 * np.sqrt(kc * 6 * mnode[0] / 2.0), margin=10.0 * r_in)
    m.u = np.zeros((N, 12))
    m.u0 = m.u.copy()
    v = np.repeat(np.asarray(velocities, float).reshape(-1, 2), 6, axis=0).reshape(N, 12)
    m.vh = v.copy()
    m.vh_prev = v.copy()
    m.t = 0.0
    m.U0 = stored_energy_abs(m)
    m.f = None
    return m
