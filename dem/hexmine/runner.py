"""Run a mine scene: excavation ramp + dynamics, time series, burst indicators, checkpoints.

Units: SI per m of thickness (J/m, kg/m, m/s, Pa). Tension positive.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field

import numpy as np

from .dynamics import advance, cell_stress, energies, gershgorin_dt
from .scene import MineParams, Scene, build_scene

__all__ = ["RunResult", "run_scene", "indicators", "seam_profile", "cell_flags", "save_checkpoint",
           "load_checkpoint"]

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
        "steps": int(nsteps),
        "wall_time_s": float(wall_time),
    }


def save_checkpoint(path, model, series, meta):
    """Atomic npz checkpoint (write tmp + os.replace)."""
    data = {k: getattr(model, k) for k in _STATE}
    data["t"] = np.array(model.t)
    data["nstep"] = np.array(model.nstep)
    for k, v in series.items():
        data["series_" + k] = np.asarray(v)
    data["meta"] = np.array(json.dumps(meta))
    tmp = str(path) + ".tmp.npz"
    np.savez(tmp, **data)
    os.replace(tmp, path)


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
    t_sample = 0.0
    while m.nstep < n_total:
        k = min(n_out - (m.nstep % n_out), n_total - m.nstep)
        try:
            advance(m, k, dt, dtg)
        except RuntimeError as exc:
            stopped = str(exc)
            break
        ts = time.perf_counter()
        from .dynamics import ramp_value
        s = _sample(m, ramp_value(m.ramp_kind, m.ramp_time, m.t))
        for key in SERIES:
            series[key].append(s[key])
        t_sample += time.perf_counter() - ts
        if bar is not None:
            bar.update(k)
        if ck is not None and (m.nstep % n_ck < k or m.nstep >= n_total):
            save_checkpoint(ck, m, series, meta)
    if bar is not None:
        bar.close()
    t_dyn = time.perf_counter() - t_loop
    wall = time.perf_counter() - t_wall0
    series = {k: np.asarray(v) for k, v in series.items()}
    ind = indicators(scene, series, wall, m.nstep)
    ind["stopped"] = stopped
    timings = {"build_s": t_build, "dynamics_s": t_dyn - t_sample, "sampling_s": t_sample,
               "steps_per_s": m.nstep / max(t_dyn - t_sample, 1e-12),
               "cell_steps_per_s": m.nstep * m.n_cells / max(t_dyn - t_sample, 1e-12)}
    return RunResult(scene=scene, series=series, indicators=ind, dt=dt, dt_gershgorin=dtg, wall_time=wall,
                     timings=timings, stopped=stopped)
