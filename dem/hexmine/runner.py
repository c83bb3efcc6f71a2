"""Run a mine scene: excavation ramp + dynamics, time series, burst indicators, checkpoints.

Units: SI per m of thickness (J/m, kg/m, m/s, Pa). Tension positive.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ..runtime import InstabilityError, RunReport, run_report  # shared with the disk engine
from ..runtime import atomic_write                          # the one atomic checkpoint writer
from .dynamics import ACC, advance, cell_stress, energies, gershgorin_dt, ramp_value
from .scene import MineParams, Scene, build_scene

__all__ = ["RunResult", "run_scene", "indicators", "seam_profile", "cell_flags", "save_checkpoint",
           "load_checkpoint", "Snapshot", "broken_kinematics"]

SERIES = ["t", "g", "Ek", "Ek_coal", "Ek_free", "U", "W_ext", "W_E", "W_gas", "D_break", "D_fric",
          "D_dash", "D_damp", "residual", "n_tension", "n_shear", "vmax"]
_STATE = ["u", "vh", "vh_prev", "f", "sn", "tau", "jtp", "jnp", "broken", "pg", "acc"]


@dataclass
class RunResult:
    scene: Scene
    series: dict
    indicators: dict
    dt: float
    dt_gershgorin: float
    wall_time: float
    timings: dict = field(default_factory=dict)
    stopped: str = ""
    report: RunReport = None          # LAMMPS-like timing table (dem.integrate.RunReport)
    error: InstabilityError = None    # set when the runaway guard stopped the run


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


def _sample(model, g):
    e = energies(model)
    _, _, _, free = cell_flags(model)
    m = model.mnode[:, None]
    vs = 0.5 * (model.vh + model.vh_prev)
    ek_cell = 0.5 * np.sum(m * vs * vs, axis=1)
    return {"t": model.t, "g": g, "Ek": e["Ek"], "Ek_coal": float(ek_cell[model.is_coal].sum()),
            "Ek_free": float(ek_cell[free].sum()), "U": e["U"], "W_ext": e["W_ext"], "W_E": e["W_E"],
            "W_gas": e["W_gas"], "D_break": e["D_break"], "D_fric": e["D_fric"], "D_dash": e["D_dash"],
            "D_damp": e["D_damp"], "residual": e["residual"], "n_tension": int((model.broken == 1).sum()),
            "n_shear": int((model.broken == 2).sum()), "vmax": float(np.abs(vs).max())}


def broken_kinematics(model):
    """How far the fixed-normal (linear-kinematics) interfaces are stretched at broken interfaces:
    max rotation [deg] of a cell with a broken interface (mean tangential node displacement / r_in,
    since excavation), max |tangential slip| / edge length L and max opening / d over the broken
    interfaces. Broken pairs re-close along their original normals over the full edge; this is
    acceptable while the rotation stays at a few degrees and the slip a small fraction of L."""
    x = model.geo["x"]
    r_in = float(np.linalg.norm(x[0]))
    du = (model.u - model.u0).reshape(-1, 6, 2)
    rot = np.sum(x[None, :, 0] * du[:, :, 1] - x[None, :, 1] * du[:, :, 0], axis=1) / (6 * r_in ** 2)
    brk = model.broken > 0
    if not brk.any():
        return {"max_rot_broken_deg": 0.0, "max_slip_over_L": 0.0, "max_open_over_d": 0.0,
                "closed_max_slip_over_L": 0.0}
    cells = np.unique(np.concatenate([model.ci[brk], model.cj[brk]]))
    closed = brk & (model.sn + model.pg < 0)          # broken and carrying contact pressure
    return {"max_rot_broken_deg": float(np.degrees(np.abs(rot[cells]).max())),
            "max_slip_over_L": float(np.abs(model.jtp[brk]).max() / model.L),
            "max_open_over_d": float(max(model.jnp[brk].max(), 0.0) / (2 * r_in)),
            "closed_max_slip_over_L": float(np.abs(model.jtp[closed]).max() / model.L) if closed.any() else 0.0}


def seam_profile(scene: Scene, u=None):
    """sigma_yy [Pa] of the row of cells nearest to seam mid-height, on the dislocation rib side:
    returns (distance from rib [m], syy [Pa])."""
    p = scene.params
    m = scene.model
    ymid = 0.5 * (p.seam_bottom + p.seam_top)
    ys = m.centres[:, 1]
    yrow = ys[np.argmin(np.abs(ys - ymid))]
    row = np.abs(ys - yrow) < 1e-6
    s = cell_stress(m, u)
    x = m.centres[row, 0]
    if p.disl_side == "right":
        dist = x - p.rib_x
    else:
        dist = p.rib_x - x
    keep = dist > -p.r_in
    o = np.argsort(dist[keep])
    return dist[keep][o], s[row, 1][keep][o]


def indicators(scene: Scene, series: dict, wall_time: float, nsteps: int) -> dict:
    m = scene.model
    p = scene.params
    nif, nbr, detached, free = cell_flags(m)
    vc = 0.5 * (m.vh + m.vh_prev)
    vcell = vc.reshape(-1, 6, 2).mean(axis=1)
    speed = np.linalg.norm(vcell, axis=1)
    mass = 6 * m.mnode
    dist, syy = seam_profile(scene)
    k = int(np.argmin(syy))
    mid = 0.5 * (m.centres[m.ci] + m.centres[m.cj])
    brk = m.broken > 0
    dr = (mid[:, 0] - p.rib_x) if p.disl_side == "right" else (p.rib_x - mid[:, 0])
    seam_b = brk & (mid[:, 1] <= p.seam_top + p.r_in)
    dzw = float(np.percentile(dr[seam_b], 99)) if seam_b.any() else 0.0
    kin = broken_kinematics(m)
    Ek = np.asarray(series["Ek"])
    WE = np.asarray(series["W_E"])
    Wx = np.asarray(series["W_ext"])
    res = np.asarray(series["residual"])
    scale = max(np.abs(Wx).max(), np.abs(WE).max(), 1e-30)
    return {
        "peak_Ek_J_per_m": float(Ek.max()),
        "final_Ek_J_per_m": float(Ek[-1]),
        "peak_Ek_coal_J_per_m": float(np.max(series["Ek_coal"])),
        "peak_Ek_free_J_per_m": float(np.max(series["Ek_free"])),
        "released_WE_J_per_m": float(-WE[-1]),
        "kinetic_fraction": float(Ek.max() / max(-WE[-1], 1e-30)),
        "n_tension": int((m.broken == 1).sum()),
        "n_shear": int((m.broken == 2).sum()),
        "n_broken_disl": int((brk & m.is_disl).sum()),
        "damage_width_m": dzw,
        "ejected_mass_kg_per_m": float(mass[free].sum()),
        "ejected_cells": int(free.sum()),
        "ejected_vmax_m_s": float(speed[free].max()) if free.any() else 0.0,
        "ejected_vmean_m_s": float(speed[free].mean()) if free.any() else 0.0,
        "detached_cells": int(detached.sum()),
        "syy_peak_MPa": float(syy[k] / 1e6),
        "syy_peak_dist_m": float(dist[k]),
        "energy_residual_rel": float(np.abs(res).max() / scale),
        "D_dash_J_per_m": float(np.asarray(series["D_dash"])[-1]),
        "D_dash_over_W_ext": float(np.asarray(series["D_dash"])[-1] / scale),
        "contacts_end": int(m.acc[ACC["n_contacts"]]),
        **kin,
        "contact_max_overlap_rel": float(m.acc[ACC["max_overlap"]]),
        "steps": int(nsteps),
        "wall_time_s": float(wall_time),
    }


class Snapshot(dict):
    """Copy of the model state arrays (the checkpoint content) at a step; ``.step`` for
    :class:`dem.integrate.InstabilityError`."""

    def __init__(self, model):
        super().__init__({k: np.array(getattr(model, k), copy=True) for k in _STATE})
        self["t"] = np.array(model.t)
        self["nstep"] = np.array(model.nstep)
        self.step = int(model.nstep)


def save_checkpoint(path, model, series, meta, snapshot=None):
    """Atomic npz checkpoint of the model state (or of ``snapshot``), the series and ``meta``."""
    data = dict(snapshot) if snapshot is not None else dict(Snapshot(model))
    for k, v in series.items():
        data["series_" + k] = np.asarray(v)
    data["meta"] = np.array(json.dumps(meta))
    atomic_write(path, lambda fh: np.savez(fh, **data))


def load_checkpoint(path, model):
    z = np.load(path, allow_pickle=False)
    for k in _STATE:
        arr = z[k]
        getattr(model, k)[...] = arr
    model.t = float(z["t"])
    model.nstep = int(z["nstep"])
    series = {k[7:]: list(z[k]) for k in z.files if k.startswith("series_")}
    meta = json.loads(str(z["meta"]))
    return series, meta


def run_scene(p: MineParams | Scene, out_dir=None, progress: bool = False, resume: bool = False,
              checkpoint_every: float = 0.02, t_end: float | None = None, dt: float | None = None) -> RunResult:
    """Build (or take) the scene and integrate to ``t_end`` (default ramp_time + duration).

    Checkpoints (npz, atomic) go to ``out_dir/checkpoint.npz`` every ``checkpoint_every`` s of
    simulated time; ``resume=True`` continues from it (bit-exact with an uninterrupted run).
    """
    t_wall0 = time.perf_counter()
    scene = p if isinstance(p, Scene) else build_scene(p)
    p = scene.params
    m = scene.model
    t_build = time.perf_counter() - t_wall0
    dtg = gershgorin_dt(m)
    if dt is None:
        dt = p.dt_safety * dtg
    if t_end is None:
        t_end = (p.ramp_time if p.ramp in ("linear", "nonlinear") else 0.0) + p.duration
    n_out = max(1, int(round(p.output_every / dt)))
    n_total = int(np.ceil(t_end / dt))
    series = {k: [] for k in SERIES}
    ck = None
    meta = {"params": p.to_dict(), "dt": dt}
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        ck = os.path.join(out_dir, "checkpoint.npz")
        if resume and os.path.exists(ck):
            series, meta_old = load_checkpoint(ck, m)
            if meta_old.get("params") != p.to_dict():
                raise ValueError(f"checkpoint {ck} belongs to different parameters; remove it or drop --resume")
    if not series["t"]:
        s0 = _sample(m, 1.0)
        for k in SERIES:
            series[k].append(s0[k])
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_total, initial=m.nstep, unit="step", desc="hexmine", mininterval=0.5)
    t_loop = time.perf_counter()
    n_ck = max(1, int(round(checkpoint_every / dt)))
    stopped = ""
    error = None
    t_sample = 0.0
    t_ck = 0.0
    nstep0 = m.nstep
    last_good = Snapshot(m)
    while m.nstep < n_total:
        k = min(n_out - (m.nstep % n_out), n_total - m.nstep)
        try:
            advance(m, k, dt, dtg)
        except InstabilityError as exc:
            # the shared engine's error, carrying the last good state (the previous sample)
            error = InstabilityError(exc.reason, last_good, exc.step)
            stopped = str(error)
            if out_dir is not None:
                save_checkpoint(os.path.join(out_dir, "failure.npz"), m, series, meta, snapshot=last_good)
            break
        ts = time.perf_counter()
        s = _sample(m, ramp_value(m.ramp_kind, m.ramp_time, m.t))
        for key in SERIES:
            series[key].append(s[key])
        last_good = Snapshot(m)
        t_sample += time.perf_counter() - ts
        if bar is not None:
            bar.update(k)
        if ck is not None and (m.nstep % n_ck < k or m.nstep >= n_total):
            tc = time.perf_counter()
            save_checkpoint(ck, m, series, meta, snapshot=last_good)
            t_ck += time.perf_counter() - tc
    if bar is not None:
        bar.close()
    t_dyn = time.perf_counter() - t_loop
    wall = time.perf_counter() - t_wall0
    series = {k: np.asarray(v) for k, v in series.items()}
    ind = indicators(scene, series, wall, m.nstep)
    ind["stopped"] = stopped
    ind["contact_damping"] = float(p.contact_damping)
    ind["damping_alpha"] = float(p.damping)
    ind["dt_s"] = float(dt)
    ind["dt_over_bound"] = float(dt / dtg)
    t_int = t_dyn - t_sample - t_ck
    nrun = m.nstep - nstep0
    timings = {"build_s": t_build, "dynamics_s": t_int, "sampling_s": t_sample, "checkpoint_s": t_ck,
               "steps_per_s": nrun / max(t_int, 1e-12),
               "cell_steps_per_s": nrun * m.n_cells / max(t_int, 1e-12)}
    report = _report(m, nrun, wall, {"build": t_build, "integration": t_int, "sampling": t_sample,
                                      "checkpoint": t_ck}, dt, dtg, bool(stopped))
    return RunResult(scene=scene, series=series, indicators=ind, dt=dt, dt_gershgorin=dtg, wall_time=wall,
                     timings=timings, stopped=stopped, report=report, error=error)


def _report(m, steps, wall, phases, dt, dtg, stopped):
    """Per-phase timing table in the format of the engine's ``Simulation.run`` (LAMMPS-like)."""
    return run_report(m.n_cells, steps, wall, phases, f"(dt = {dt:.4g}, dt/dt_bound = {dt / dtg:.3f})",
                      unit="cell", what="hexagons", stopped=stopped)
