"""The mine scene file: every parameter and every *reading* of the paper, validated.

Units: SI (m, Pa, Pa/m, N/m^3, s, deg for angles). Tension positive. Plane strain, per m thickness.

The paper (Prochazka, "Influence of dislocations on bumps occurrence in deep mines") leaves several
choices open. Each is a named *reading* here, with its allowed values in ``READINGS`` and the reason
for each value in docs/mine_scene.md section 3:

* ``placement``: ``"near"`` (the named end of each dislocation, the 60 deg toe or the 120 deg top,
  is its end nearest to the rib; the line runs away from the opening) or ``"far"`` (the named end is
  the far end; the line runs toward the rib and cuts the face);
* ``floor``: ``"rollers"`` (u_y = 0), ``"no_slip"`` (u = 0), ``"rock"`` (a rock floor layer of
  ``floor_layer`` m under the seam, rollers below it);
* ``loading``: ``"traction"`` (constant overburden traction on the top), ``"rollers"`` (top u_y = 0),
  ``"spring"`` (traction plus a Winkler spring standing for ``overburden_height`` m of rock), ``"tall"``
  (``tall_extra`` m more rock above, traction on its top); ``absorbing`` adds Lysmer-Kuhlemeyer
  dashpots on the far boundaries;
* ``gas``: ``"interface"`` (effective stress on the dislocation interfaces), ``"eigenstrain"`` (the
  paper's eigenstrain in the cells along the dislocation, inside the virgin equilibrium),
  ``"released"`` (the same eigenstrain released with the excavation, (1 - g(t)) of it), ``"none"``;
* ``lattice``: ``"inner"`` (``cell_size`` is the inner radius: 1117 cells after excavation) or
  ``"side"`` (``cell_size`` is the side: 1527 cells, the paper's 1532);
* ``model``: ``"half"`` (the left boundary is the adit's symmetry plane, domain ``width``) or
  ``"full"`` (the whole adit, domain 2 ``width``, no symmetry assumption);
* ``n_disl`` 0..3, ``ramp_time``, ``width``.

A bad scene raises ``ValueError`` naming the field and the allowed range.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, fields

from ...hexagons.dynamics import RAMP_CODES
from .geometry import resolve

__all__ = ["MineParams", "load_toml", "UNITS", "READINGS", "G_ACC"]

G_ACC = 9.81
"""Gravitational acceleration [m/s^2]."""

READINGS = {
    "placement": ("near", "far"),
    "floor": ("rollers", "no_slip", "rock"),
    "loading": ("traction", "rollers", "spring", "tall"),
    "gas": ("interface", "eigenstrain", "released", "none"),
    "lattice": ("inner", "side"),
    "model": ("half", "full"),
    "disl_side": ("right", "left"),
    "element": ("hybrid", "bem"),
    "ramp": tuple(RAMP_CODES),
    "fault_law": ("zigzag", "plane"),
}

UNITS = {
    "width": "m", "height": "m", "seam_bottom": "m", "seam_top": "m", "adit_width": "m",
    "cell_size": "m", "orientation_deg": "deg", "rock_E": "Pa", "rock_nu": "-", "rock_phi_deg": "deg",
    "rock_c": "Pa", "rock_ft": "Pa", "coal_E": "Pa", "coal_nu": "-", "coal_phi_deg": "deg", "coal_c": "Pa",
    "coal_ft": "Pa", "unit_weight": "N/m^3", "friction_residual_deg": "deg", "penalty_factor": "-",
    "kn": "Pa/m", "kt_over_kn": "-", "depth": "m", "K0": "-", "floor_layer": "m",
    "overburden_height": "m", "tall_extra": "m", "ramp_time": "s", "disl_angle_deg": "deg",
    "disl_first": "m", "disl_spacing": "m", "disl_phi_deg": "deg", "disl_c": "Pa", "gas_pressure": "Pa",
    "gas_vent_opening": "m", "elastic_layer": "m", "duration": "s", "dt_safety": "-", "damping": "1/s",
    "contact_damping": "-", "contact_factor": "-", "v_abort": "m/s", "output_every": "s",
}


@dataclass(frozen=True)
class MineParams:
    """Every parameter of the scene, SI units (see ``UNITS``); readings in ``READINGS``.

    Frozen; :meth:`validate` raises ``ValueError`` naming a bad field and its allowed range.

    Attributes
    ----------
    placement, floor, loading, gas, lattice, model : str
        Readings of the paper (allowed values in ``READINGS``; see the module docstring).
    absorbing : bool
        Lysmer-Kuhlemeyer dashpots on the far boundaries.
    width : float
        Half-model width [m]; the full model is 2 ``width`` wide.
    height : float
        Seam + roof rock [m] (a rock floor or a taller model add to it).
    seam_bottom, seam_top : float
        Seam position within ``height`` [m] (above a rock floor if any).
    adit_width : float
        Width of the adit (opening) [m].
    cell_size : float
        Inner radius (``lattice="inner"``) or side (``lattice="side"``) of the hexagons [m].
    orientation_deg : float
        Normal of edge 0 [deg]; 0 = pointy-top (normals 0, +-60 deg).
    element : str
        Cell element, ``"hybrid"`` or ``"bem"``.
    floor_layer : float
        Rock floor thickness for ``floor="rock"`` [m].
    overburden_height : float
        Rock column the top spring stands for (``loading="spring"``) [m].
    tall_extra : float
        Extra rock above for ``loading="tall"`` [m].
    rock_E, coal_E : float
        Young's modulus of rock and coal [Pa].
    rock_nu, coal_nu : float
        Poisson's ratio of rock and coal [-], in (-1, 0.5).
    rock_phi_deg, coal_phi_deg : float
        Interface friction angle in rock and coal [deg], in [0, 90).
    rock_c, coal_c : float
        Interface cohesion in rock and coal [Pa].
    rock_ft, coal_ft : float
        Interface tensile strength in rock and coal [Pa].
    unit_weight : float
        Unit weight of the rock gamma [N/m^3].
    friction_residual_deg : float
        Residual friction angle of broken interfaces [deg]; < 0: the interface's peak angle.
    penalty_factor : float
        kn = factor * max(K + 4G/3) / r_in (Itasca rule) [-].
    kn : float
        Interface normal stiffness [Pa/m]; > 0 overrides the rule.
    kt_over_kn : float
        Shear over normal interface stiffness [-].
    depth : float
        Depth of the seam; sets the overburden traction ``p_top = unit_weight * depth`` [m].
    K0 : float
        Horizontal over vertical virgin stress [-].
    gravity : bool
        Volume weight in the model (the paper neglects it).
    ramp : str
        Release ramp of the excavation forces (``"instant"``, ``"linear"``, ``"nonlinear"``,
        ``"none"``).
    ramp_time : float
        Duration of the ramp [s].
    n_disl : int
        Number of dislocations, 0..3.
    disl_angle_deg : float
        Dislocation angle counter-clockwise from +x (right rib) [deg], in (0, 180).
    disl_first : float
        Distance of the named end of the first dislocation from the rib [m].
    disl_spacing : float
        Spacing of the dislocations [m].
    disl_side : str
        Rib holding the dislocations (``"left"`` only in the full model).
    disl_phi_deg : float
        Friction angle of the dislocations [deg]; < 0: the coal's.
    disl_c : float
        Cohesion of the dislocations [Pa] (their tensile strength is 0).
    fault_law : str
        ``"zigzag"``: every interface the dislocation line crosses is checked on its own edge (the
        lattice's two edge families bias the fault); ``"plane"``: Mohr-Coulomb on the true plane, per
        segment of two crossed edges (:mod:`dem.hexagons.fault`).
    gas_pressure : float
        Gas pressure [Pa].
    gas_vent_opening : float
        Crack opening above which the gas has escaped [m].
    elastic : bool
        Infinite strengths (verification runs).
    elastic_layer : float
        Top rock layer with unbreakable interfaces [m].
    duration : float
        Dynamics after the end of the ramp [s].
    dt_safety : float
        Time step as a fraction of the Gershgorin bound [-], in (0, 1].
    damping : float
        Mass-proportional damping alpha [1/s].
    contact_damping : float
        Dashpot of contacts and cracked closed interfaces as a fraction of critical damping [-].
    contact : bool
        Proximity contact between cells that were not neighbours.
    contact_factor : float
        Contact penalty kc = factor * kn * L [-].
    v_abort : float
        Runaway guard [m/s].
    output_every : float
        Interval of the recorded series [s].
    """
    # readings of the paper
    placement: str = "near"
    floor: str = "rollers"
    loading: str = "traction"
    absorbing: bool = False
    gas: str = "interface"
    lattice: str = "inner"
    model: str = "half"
    # geometry
    width: float = 26.0              # half-model width; the full model is 2 * width wide
    height: float = 9.5              # seam + roof rock (a rock floor or a taller model add to it)
    seam_bottom: float = 0.0         # seam position within `height` (above a rock floor if any)
    seam_top: float = 4.75
    adit_width: float = 3.0
    cell_size: float = 0.25          # inner radius (lattice="inner") or side (lattice="side")
    orientation_deg: float = 0.0     # normal of edge 0; 0 = pointy-top (normals 0, +-60)
    element: str = "hybrid"          # 'hybrid' | 'bem'
    floor_layer: float = 2.375       # rock floor thickness for floor="rock"
    overburden_height: float = 50.0  # rock column the top spring stands for (loading="spring")
    tall_extra: float = 9.5          # extra rock above for loading="tall"
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
    gravity: bool = False            # paper: volume weight neglected in the model
    # excavation
    ramp: str = "linear"             # 'instant' | 'linear' | 'nonlinear' | 'none'
    ramp_time: float = 0.01
    # dislocations
    n_disl: int = 1
    disl_angle_deg: float = 60.0     # counter-clockwise from +x (right rib)
    disl_first: float = 2.5          # distance of the named end of the first one from the rib
    disl_spacing: float = 5.0
    disl_side: str = "right"         # rib holding the dislocations ('left' only in the full model)
    disl_phi_deg: float = -1.0       # <0: coal friction angle
    disl_c: float = 0.0              # cohesion of the dislocation [Pa]
    fault_law: str = "zigzag"        # 'zigzag' (edge by edge) | 'plane' (Mohr-Coulomb on the true plane)
    gas_pressure: float = 1e6
    gas_vent_opening: float = 0.01   # crack opening above which the gas has escaped
    # run
    elastic: bool = False            # infinite strengths (verification)
    elastic_layer: float = 2.375     # top rock layer with unbreakable interfaces (D6)
    duration: float = 0.1            # dynamics after the end of the ramp
    dt_safety: float = 0.7
    damping: float = 0.0             # mass-proportional damping alpha [1/s]
    contact_damping: float = 0.0
    contact: bool = True
    contact_factor: float = 1.0
    v_abort: float = 1e3             # runaway guard [m/s]
    output_every: float = 5e-4

    # ------------------------------------------------------------------ validation
    def validate(self) -> "MineParams":
        """Return ``self`` if every field is in range, else raise ``ValueError`` naming the field."""
        def bad(name, msg):
            raise ValueError(f"{name}={getattr(self, name)!r}: {msg}")

        for name, allowed in READINGS.items():
            if getattr(self, name) not in allowed:
                bad(name, f"unknown reading; allowed: {', '.join(map(repr, allowed))}")
        for name in ("absorbing", "gravity", "elastic", "contact"):
            if not isinstance(getattr(self, name), bool):
                bad(name, "must be true or false")
        for name in ("width", "height", "cell_size", "adit_width", "rock_E", "coal_E", "unit_weight",
                     "penalty_factor", "kt_over_kn", "dt_safety", "output_every", "contact_factor",
                     "floor_layer", "overburden_height", "tall_extra", "v_abort"):
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
            if getattr(self, name) >= 90.0:
                bad(name, "friction angle must be < 90 deg (negative = default)")
        for name in ("rock_c", "rock_ft", "coal_c", "coal_ft"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                bad(name, "strength must be a finite number >= 0 Pa")
        for name in ("gas_pressure", "depth", "ramp_time", "duration", "damping", "contact_damping", "kn", "disl_c",
                     "disl_first", "gas_vent_opening", "elastic_layer"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                bad(name, "must be a finite number >= 0")
        if not (self.K0 > 0):
            bad("K0", "must be > 0")
        if self.elastic_layer > self.height - self.seam_top:
            bad("elastic_layer", "must not reach into the seam (<= height - seam_top)")
        if not (0 <= self.seam_bottom < self.seam_top <= self.height):
            bad("seam_top", f"need 0 <= seam_bottom < seam_top <= height ({self.height})")
        half_open = self.adit_width / 2 if self.model == "half" else self.adit_width
        if half_open >= self.width - self.r_in:
            bad("adit_width", f"the adit must leave coal beside it in a {self.width} m domain")
        if self.dt_safety > 1.0:
            bad("dt_safety", "must be <= 1 (fraction of the Gershgorin bound)")
        if self.ramp in ("linear", "nonlinear") and self.ramp_time <= 0:
            bad("ramp_time", "must be > 0 for a linear/nonlinear ramp (use ramp='instant')")
        if not (isinstance(self.n_disl, int) and 0 <= self.n_disl <= 3):
            bad("n_disl", "must be an integer 0..3")
        if self.disl_side == "left" and self.model != "full":
            bad("disl_side", "a left-rib dislocation needs model='full' (the half-model has no left rib)")
        if self.n_disl > 0:
            if not (0.0 < self.disl_angle_deg < 180.0):
                bad("disl_angle_deg", "must be in (0, 180) deg, counter-clockwise from +x")
            if self.n_disl > 1 and not (self.disl_spacing > 0):
                bad("disl_spacing", "must be > 0 with more than one dislocation")
            g = resolve(self)
            lo, hi = (g.rib_x, g.W) if self.disl_side == "right" else (0.0, g.rib_x)
            for k, seg in enumerate(g.dislocations):
                named = seg[g.named_end, 0]
                xs = seg[:, 0]
                if not (lo + 0.5 * g.r_in < named < hi - 0.5 * g.r_in) or xs.min() < 0 or xs.max() > g.W:
                    raise ValueError(
                        f"disl_first={self.disl_first!r}: dislocation {k + 1} (named end at x = {named:.3f} m, "
                        f"spanning x in [{xs.min():.3f}, {xs.max():.3f}] m) lies outside the seam of the "
                        f"{self.disl_side} rib [{lo:.3f}, {hi:.3f}] m; check disl_first, disl_spacing, "
                        "disl_angle_deg, n_disl")
        return self

    # ------------------------------------------------------------------ derived
    @property
    def r_in(self) -> float:
        """Inner radius of the hexagons [m]."""
        return self.cell_size if self.lattice == "inner" else self.cell_size * math.sqrt(3.0) / 2.0

    @property
    def theta0(self) -> float:
        """Orientation of edge 0's normal [rad]."""
        return math.radians(self.orientation_deg)

    @property
    def rho(self) -> float:
        """Density of the rock, ``unit_weight / G_ACC`` [kg/m^3]."""
        return self.unit_weight / G_ACC

    @property
    def p_top(self) -> float:
        """Overburden pressure at the top of the model, ``unit_weight * depth`` [Pa]."""
        return self.unit_weight * self.depth

    def replace(self, **kw) -> "MineParams":
        """A copy with the given fields changed (not validated: call :meth:`validate`)."""
        return dataclasses.replace(self, **kw)

    def to_dict(self):
        """The fields as a plain dict (the scene file's keys)."""
        return dataclasses.asdict(self)


def load_toml(path) -> MineParams:
    """Read a scene file: top-level keys (or a [scene] table) named like the MineParams fields.
    Unknown keys and unknown readings are refused with the field named."""
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    if "scene" in data and isinstance(data["scene"], dict):
        data = data["scene"]
    names = {f.name for f in fields(MineParams)}
    unknown = set(data) - names
    if unknown:
        raise ValueError(f"unknown scene parameter(s) {sorted(unknown)} in {path}; known: {sorted(names)}")
    return MineParams(**data).validate()
