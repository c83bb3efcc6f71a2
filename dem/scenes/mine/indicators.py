"""Indicators of a mine-scene run: typed, documented results (``microhom.results.Result``).

Units: SI per m of thickness (J/m, kg/m, m, m/s, Pa). Tension positive. "Toward the opening" is
the horizontal direction from the dislocation rib into the adit (-x for the right rib): a positive
displacement moves toward the opening.

* :class:`BlockIndicators`: one block of coal (the wedge between the rib and the first dislocation,
  a block between two dislocations, or the seam beyond the last one), see
  :func:`~dem.scenes.mine.geometry.block_labels`. ``minus(control)`` subtracts the control run (no
  dislocation) evaluated on the same partition.
* :class:`SeamProfile`: vertical stress along the seam mid-height row at successive excavation stages
  (g = 1 virgin ... 0 excavated, and the end of the run): the paper's Fig. 1.
* :class:`FaultIndicators`: slip along the dislocation line(s), slipped length, energy released by
  the fault's slip and radiated; ``minus(control)`` as for the blocks.
* :class:`MineIndicators`: the whole run.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from microhom.results import Result

from ...hexagons.dynamics import ACC, cell_stress
from ...hexagons.fault import fault_frame, segments_cross
from .geometry import block_names

__all__ = ["BlockIndicators", "FaultIndicators", "fault_indicators", "SeamProfile", "MineIndicators", "cell_flags",
           "seam_row", "block_indicators",
           "seam_profile", "broken_kinematics", "compute", "STAGES"]

STAGES = (1.0, 0.75, 0.5, 0.25, 0.0)
"""Eshelby factors g [-] of the stages recorded in :class:`SeamProfile` (1 virgin, 0 excavated)."""


@dataclass(frozen=True)
class BlockIndicators(Result):
    """One block of coal (SI per m of thickness).

    Attributes
    ----------
    name : str
        Name of the block (:func:`~dem.scenes.mine.geometry.block_names`).
    n_cells : int
        Number of cells in the block.
    mass_kg_per_m : float
        Mass of the block [kg/m].
    disp_mean_m, disp_max_m : float
        Mean / max over its cells of the cell displacement toward the opening at the end [m].
    peak_Ek_J_per_m : float
        Largest kinetic energy of the block over the run [J/m].
    broken_fraction : float
        Broken / all interfaces with both cells in the block [-].
    ejected_mass_kg_per_m : float
        Mass of its detached cells with an open crack [kg/m].
    """
    name: str
    n_cells: int
    mass_kg_per_m: float
    disp_mean_m: float
    disp_max_m: float
    peak_Ek_J_per_m: float
    broken_fraction: float
    ejected_mass_kg_per_m: float

    def minus(self, control: "BlockIndicators") -> "BlockIndicators":
        """This block with the control run's values subtracted (name and size kept)."""
        kw = {f.name: getattr(self, f.name) - getattr(control, f.name) for f in dataclasses.fields(self)
              if f.name not in ("name", "n_cells", "mass_kg_per_m")}
        return dataclasses.replace(self, **kw)


@dataclass(frozen=True)
class FaultIndicators(Result):
    """Indicators on the dislocation line(s) themselves (SI per m of thickness).

    Measured across the *geometric* lines, so a control run (no dislocation) is measured across the
    same lines (through intact coal) and ``minus(control)`` is meaningful. Slip and opening are the
    jumps of the node displacements since the start of the run (excavation included) across every
    interface the line crosses, along the line's tangent t (from its floor end to its roof end) and
    its normal n = (t_y, -t_x), the side of +n moving relative to the other.

    Attributes
    ----------
    slip_mean_m : float
        Mean slip along the line, weighted by the crossed edges' projected lengths [m] (signed:
        positive when the +n side moves toward the roof end).
    slip_max_m : float
        Largest ``|slip|`` of a crossed edge [m].
    slipped_length_m : float
        Projected length of the line over which ``|slip|`` >= ``slip_threshold_m`` [m].
    opening_max_m : float
        Largest opening of a crossed edge [m].
    n_broken : int
        Broken interfaces on the line(s).
    released_J_per_m : float
        Energy released by the fault's slip: the work dissipated on the planar fault's segments
        (friction and break drops, ``acc`` D_fric_fault + D_break_fault) [J/m]; 0 without a planar
        fault (``fault_law="zigzag"`` or a control run).
    radiated_J_per_m : float
        Kinetic energy radiated out of the model: work of the absorbing boundaries' dashpots and of
        mass damping (``D_damp``) at the end [J/m]; 0 without either.
    peak_Ek_rock_J_per_m : float
        Largest kinetic energy of the rock cells over the run (waves radiated into the strata) [J/m].
    slip_threshold_m : float
        The slip that counts as slipped [m].
    """
    slip_mean_m: float
    slip_max_m: float
    slipped_length_m: float
    opening_max_m: float
    n_broken: int
    released_J_per_m: float
    radiated_J_per_m: float
    peak_Ek_rock_J_per_m: float
    slip_threshold_m: float = 1e-4

    def minus(self, control: "FaultIndicators") -> "FaultIndicators":
        """These indicators with the control run's values (same lines) subtracted."""
        kw = {f.name: getattr(self, f.name) - getattr(control, f.name) for f in dataclasses.fields(self)
              if f.name != "slip_threshold_m"}
        return dataclasses.replace(self, **kw)


def fault_indicators(scene, series, lines=None, slip_threshold=1e-4) -> FaultIndicators:
    """:class:`FaultIndicators` of a run across ``lines`` (tuple of (2,2) arrays: floor end, roof
    end [m]; default the scene's own dislocations) from its final state and ``series["Ek_cells"]``."""
    m = scene.model
    lines = scene.geometry.dislocations if lines is None else lines
    ekc = np.asarray(series["Ek_cells"])
    rock = ~m.is_coal
    pk_rock = float(ekc[:, rock].sum(axis=1).max()) if ekc.size and rock.any() else 0.0
    d_damp = float(np.asarray(series["D_damp"])[-1]) if len(series["D_damp"]) else 0.0
    released = float(m.acc[ACC["D_break_fault"]] + m.acc[ACC["D_fric_fault"]]) if m.fseg is not None else 0.0
    slips, opens, ells, brk = [], [], [], []
    seen = np.zeros(m.n_ifc, bool)
    ne = m.geo["n"][m.ca]                          # geometric edge normal, from cell i to cell j
    du = m.u - m.u0
    for seg in lines:
        cr = segments_cross(m.centres[m.ci], m.centres[m.cj], seg[0], seg[1]) & ~seen
        seen |= cr
        e = np.nonzero(cr)[0]
        if not len(e):
            continue
        t_l, n_l = fault_frame(seg[0], seg[1])
        cosn = ne[e] @ n_l
        s = np.sign(cosn)
        jx = du[m.cj[e], 2 * m.cb[e]] - du[m.ci[e], 2 * m.ca[e]]
        jy = du[m.cj[e], 2 * m.cb[e] + 1] - du[m.ci[e], 2 * m.ca[e] + 1]
        slips.append(s * (jx * t_l[0] + jy * t_l[1]))
        opens.append(s * (jx * n_l[0] + jy * n_l[1]))
        ells.append(m.L * np.abs(cosn))
        brk.append(m.broken[e] > 0)
    if not slips:
        return FaultIndicators(0.0, 0.0, 0.0, 0.0, 0, released, d_damp, pk_rock, slip_threshold)
    sl, op, ell, bk = (np.concatenate(a) for a in (slips, opens, ells, brk))
    return FaultIndicators(
        slip_mean_m=float(np.sum(sl * ell) / np.sum(ell)), slip_max_m=float(np.abs(sl).max()),
        slipped_length_m=float(ell[np.abs(sl) >= slip_threshold].sum()), opening_max_m=float(op.max()),
        n_broken=int(bk.sum()), released_J_per_m=released, radiated_J_per_m=d_damp,
        peak_Ek_rock_J_per_m=pk_rock, slip_threshold_m=slip_threshold)


@dataclass(frozen=True)
class SeamProfile(Result):
    """sigma_yy along the seam mid-height row, ``n`` cells at ``k`` stages.

    Attributes
    ----------
    dist_m : ndarray, shape (n,)
        Distance of each cell centre from the rib [m].
    g : ndarray, shape (k,)
        Eshelby factor of each stage (1 virgin, 0 fully excavated; the last row is the end of the
        run, g = 0) [-].
    t_s : ndarray, shape (k,)
        Time of each stage [s].
    syy_Pa : ndarray, shape (k, n)
        Vertical stress of each cell at each stage [Pa], tension positive.
    """
    dist_m: np.ndarray
    g: np.ndarray
    t_s: np.ndarray
    syy_Pa: np.ndarray

    def peak(self, stage: int = -1):
        """(syy [Pa], distance [m]) of the most compressive cell of a stage."""
        k = int(np.argmin(self.syy_Pa[stage]))
        return float(self.syy_Pa[stage, k]), float(self.dist_m[k])


@dataclass(frozen=True)
class MineIndicators(Result):
    """Indicators of one run (J/m, kg/m, m, m/s, MPa as named), SI per m of thickness.

    Attributes
    ----------
    peak_Ek_J_per_m, final_Ek_J_per_m : float
        Peak and final kinetic energy of all cells [J/m].
    peak_Ek_coal_J_per_m, peak_Ek_free_J_per_m : float
        Peak kinetic energy of the coal cells and of the free cells (detached, crack open) [J/m].
    released_WE_J_per_m : float
        Released Eshelby work ``-W_E`` at the end [J/m].
    kinetic_fraction : float
        Peak kinetic energy over the released Eshelby work [-].
    n_tension, n_shear : int
        Interfaces broken in tension, in shear.
    n_broken_disl : int
        Broken interfaces on a dislocation.
    damage_depth_m : float
        99th percentile of the distance from the rib of broken seam interfaces [m].
    yield_depth_m : float
        Distance from the rib of the abutment peak of sigma_yy at the end (the classical edge of
        the yield zone) [m].
    rib_disp_m : float
        Mean displacement toward the opening of the rib cells (the cells that carried Eshelby forces
        within the seam) [m].
    ejected_mass_kg_per_m : float
        Mass of the cells detached with an open crack [kg/m].
    ejected_cells : int
        Number of those cells.
    ejected_vmax_m_s, ejected_vmean_m_s : float
        Max and mean speed of those cells at the end [m/s].
    detached_cells : int
        Cells with all their interfaces broken.
    syy_peak_MPa : float
        Most compressive sigma_yy on the seam row at the end [MPa], tension positive.
    syy_peak_dist_m : float
        Its distance from the rib [m].
    energy_residual_rel : float
        Largest energy-balance residual relative to max(``|W_ext|``, ``|W_E|``) [-].
    D_dash_over_W_ext : float
        Work of the contact dashpots relative to the same scale [-].
    contacts_end : int
        Proximity contacts at the end.
    contact_max_overlap_rel : float
        Largest contact overlap over the inscribed diameter d, over the run [-].
    max_rot_broken_deg : float
        Largest rotation of a cell with a broken interface [deg] (:func:`dem.scenes.mine.indicators.broken_kinematics`).
    max_slip_over_L : float
        Largest ``|slip|`` of a broken interface over the edge length L [-].
    max_open_over_d : float
        Largest opening of a broken interface over d = 2 r_in [-].
    closed_max_slip_over_L : float
        Largest ``|slip|`` / L over the closed (force-carrying) broken interfaces [-].
    steps : int
        Time steps taken.
    dt_s : float
        Time step [s].
    wall_time_s : float
        Wall time of the run [s].
    stopped : str
        Why the run stopped early ("" if it ran to the end).
    blocks : tuple of BlockIndicators
        The blocks of the scene's own partition.
    fault : FaultIndicators
        Slip, slipped length, released and radiated energy on the scene's own dislocation lines.
    profile : SeamProfile
        sigma_yy along the seam row at the excavation stages (not exported by ``as_dict``).
    """
    peak_Ek_J_per_m: float
    final_Ek_J_per_m: float
    peak_Ek_coal_J_per_m: float
    peak_Ek_free_J_per_m: float
    released_WE_J_per_m: float
    kinetic_fraction: float
    n_tension: int
    n_shear: int
    n_broken_disl: int
    damage_depth_m: float
    yield_depth_m: float
    rib_disp_m: float
    ejected_mass_kg_per_m: float
    ejected_cells: int
    ejected_vmax_m_s: float
    ejected_vmean_m_s: float
    detached_cells: int
    syy_peak_MPa: float
    syy_peak_dist_m: float
    energy_residual_rel: float
    D_dash_over_W_ext: float
    contacts_end: int
    contact_max_overlap_rel: float
    max_rot_broken_deg: float
    max_slip_over_L: float
    max_open_over_d: float
    closed_max_slip_over_L: float
    steps: int
    dt_s: float
    wall_time_s: float
    stopped: str = ""
    blocks: tuple = ()
    fault: FaultIndicators = None
    profile: SeamProfile = field(default=None, metadata={"export": False})

    def block(self, name: str) -> BlockIndicators:
        """The :class:`BlockIndicators` named ``name``; ``KeyError`` listing the names otherwise."""
        for b in self.blocks:
            if b.name == name:
                return b
        raise KeyError(f"no block {name!r}; blocks: {[b.name for b in self.blocks]}")


def cell_flags(model):
    """Per cell: number of interfaces, number broken, detached (all broken), free (detached and at
    least one crack open)."""
    N = model.n_cells
    nif = np.bincount(model.ci, minlength=N) + np.bincount(model.cj, minlength=N)
    br = (model.broken > 0).astype(np.int64)
    nbr = np.bincount(model.ci, br, minlength=N) + np.bincount(model.cj, br, minlength=N)
    opn = ((model.broken > 0) & (model.sn + model.pg >= 0)).astype(np.int64)
    nop = np.bincount(model.ci, opn, minlength=N) + np.bincount(model.cj, opn, minlength=N)
    detached = (nif > 0) & (nbr == nif)
    free = detached & (nop > 0)
    return nif, nbr.astype(int), detached, free


def seam_row(scene):
    """(cell indices of the seam mid-height row on the dislocation rib, ordered from the rib; their
    distance from the rib [m])."""
    g = scene.geometry
    m = scene.model
    ys = m.centres[:, 1]
    yrow = ys[np.argmin(np.abs(ys - g.seam_mid))]
    idx = np.nonzero(np.abs(ys - yrow) < 1e-6)[0]
    dist = g.side * (m.centres[idx, 0] - g.rib_x)
    ok = dist > -g.r_in
    o = np.argsort(dist[ok])
    return idx[ok][o], dist[ok][o]


def seam_profile(scene, u=None):
    """(distance from the rib [m], sigma_yy [Pa]) along the seam mid-height row."""
    idx, dist = seam_row(scene)
    return dist, cell_stress(scene.model, u)[idx, 1]


def broken_kinematics(model):
    """How far the fixed-normal (linear-kinematics) interfaces are stretched at broken interfaces:
    max rotation [deg] of a cell with a broken interface, max ``|slip|`` / L and max opening / d over
    the broken interfaces, max ``|slip|`` / L over the closed (force-carrying) broken ones."""
    x = model.geo["x"]
    r_in = float(np.linalg.norm(x[0]))
    du = (model.u - model.u0).reshape(-1, 6, 2)
    rot = np.sum(x[None, :, 0] * du[:, :, 1] - x[None, :, 1] * du[:, :, 0], axis=1) / (6 * r_in ** 2)
    brk = model.broken > 0
    if not brk.any():
        return {"max_rot_broken_deg": 0.0, "max_slip_over_L": 0.0, "max_open_over_d": 0.0,
                "closed_max_slip_over_L": 0.0}
    cells = np.unique(np.concatenate([model.ci[brk], model.cj[brk]]))
    closed = brk & (model.sn + model.pg < 0)
    return {"max_rot_broken_deg": float(np.degrees(np.abs(rot[cells]).max())),
            "max_slip_over_L": float(np.abs(model.jtp[brk]).max() / model.L),
            "max_open_over_d": float(max(model.jnp[brk].max(), 0.0) / (2 * r_in)),
            "closed_max_slip_over_L": float(np.abs(model.jtp[closed]).max() / model.L) if closed.any() else 0.0}


def _toward(scene):
    """(N,) displacement of each cell centre toward the opening [m]."""
    m = scene.model
    d = (m.u - m.u0).reshape(-1, 6, 2).mean(axis=1)
    return -scene.geometry.side * d[:, 0]


def block_indicators(scene, series, labels, names):
    """:class:`BlockIndicators` for each label 0..len(names)-1 of ``labels`` (N,), from the final
    state and the per-cell kinetic energy series ``series["Ek_cells"]`` (S, N)."""
    m = scene.model
    ux = _toward(scene)
    mass = 6 * m.mnode
    _, _, _, free = cell_flags(m)
    ekc = np.asarray(series["Ek_cells"])
    brk = m.broken > 0
    out = []
    for k, name in enumerate(names):
        sel = labels == k
        if not sel.any():
            out.append(BlockIndicators(name, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
            continue
        inner = sel[m.ci] & sel[m.cj]
        out.append(BlockIndicators(
            name=name, n_cells=int(sel.sum()), mass_kg_per_m=float(mass[sel].sum()),
            disp_mean_m=float(ux[sel].mean()), disp_max_m=float(ux[sel].max()),
            peak_Ek_J_per_m=float(ekc[:, sel].sum(axis=1).max()),
            broken_fraction=float(brk[inner].mean()) if inner.any() else 0.0,
            ejected_mass_kg_per_m=float(mass[sel & free].sum())))
    return tuple(out)


def _stages(series, idx_row, dist):
    g = np.asarray(series["g"])
    t = np.asarray(series["t"])
    S = np.asarray(series["syy_seam"])
    rows = [int(np.argmin(np.abs(g - s))) if s > 0 else int(np.argmax(g <= 0.0)) for s in STAGES]
    rows.append(len(g) - 1)
    return SeamProfile(dist_m=dist, g=g[rows], t_s=t[rows], syy_Pa=S[rows])


def compute(scene, series, wall_time, nsteps, dt, stopped="", names=None) -> MineIndicators:
    """The :class:`MineIndicators` of a finished (or stopped) run."""
    m = scene.model
    g = scene.geometry
    _, _, detached, free = cell_flags(m)
    vcell = (0.5 * (m.vh + m.vh_prev)).reshape(-1, 6, 2).mean(axis=1)
    speed = np.linalg.norm(vcell, axis=1)
    mass = 6 * m.mnode
    idx, dist = seam_row(scene)
    prof = _stages(series, idx, dist)
    syy_pk, d_pk = prof.peak(-1)
    mid = 0.5 * (m.centres[m.ci] + m.centres[m.cj])
    brk = m.broken > 0
    dr = g.side * (mid[:, 0] - g.rib_x)
    seam_b = brk & (mid[:, 1] <= g.seam_hi + g.r_in) & (mid[:, 1] >= g.seam_lo - g.r_in) & (dr > -g.r_in)
    ux = _toward(scene)
    wc = m.wc[:scene.info.get("n_wall_nodes", len(m.wc))]          # the Eshelby loads (not the released gas)
    rib = np.unique(wc[m.is_coal[wc]])
    rib = rib[g.side * (m.centres[rib, 0] - g.rib_x) > -g.r_in] if len(rib) else rib
    Ek = np.asarray(series["Ek"])
    WE = np.asarray(series["W_E"])
    Wx = np.asarray(series["W_ext"])
    scale = max(np.abs(Wx).max(), np.abs(WE).max(), 1e-30)
    names = names or block_names(scene.params.n_disl)
    return MineIndicators(
        peak_Ek_J_per_m=float(Ek.max()), final_Ek_J_per_m=float(Ek[-1]),
        peak_Ek_coal_J_per_m=float(np.max(series["Ek_coal"])), peak_Ek_free_J_per_m=float(np.max(series["Ek_free"])),
        released_WE_J_per_m=float(-WE[-1]), kinetic_fraction=float(Ek.max() / max(-WE[-1], 1e-30)),
        n_tension=int((m.broken == 1).sum()), n_shear=int((m.broken == 2).sum()),
        n_broken_disl=int((brk & m.is_disl).sum()),
        damage_depth_m=float(np.percentile(dr[seam_b], 99)) if seam_b.any() else 0.0,
        yield_depth_m=d_pk, rib_disp_m=float(ux[rib].mean()) if len(rib) else 0.0,
        ejected_mass_kg_per_m=float(mass[free].sum()), ejected_cells=int(free.sum()),
        ejected_vmax_m_s=float(speed[free].max()) if free.any() else 0.0,
        ejected_vmean_m_s=float(speed[free].mean()) if free.any() else 0.0,
        detached_cells=int(detached.sum()), syy_peak_MPa=syy_pk / 1e6, syy_peak_dist_m=d_pk,
        energy_residual_rel=float(np.abs(np.asarray(series["residual"])).max() / scale),
        D_dash_over_W_ext=float(np.asarray(series["D_dash"])[-1] / scale),
        contacts_end=int(m.acc[ACC["n_contacts"]]), contact_max_overlap_rel=float(m.acc[ACC["max_overlap"]]),
        **broken_kinematics(m), steps=int(nsteps), dt_s=float(dt), wall_time_s=float(wall_time), stopped=stopped,
        blocks=block_indicators(scene, series, scene.labels, names), fault=fault_indicators(scene, series),
        profile=prof)
