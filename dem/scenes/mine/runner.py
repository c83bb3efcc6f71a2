"""Run a mine scene: excavation ramp + dynamics, time series, burst indicators, checkpoints.

Units: SI per m of thickness (J/m, kg/m, m/s, Pa). Tension positive.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field

import numpy as np

from microhom.results import Result

from ...runtime import InstabilityError, RunReport, atomic_write, run_report   # shared with the disk engine
from ...hexagons.dynamics import advance, energies, gershgorin_dt, ramp_value
from .build import Scene, build_scene
from .indicators import MineIndicators, cell_flags, compute, seam_profile
from .params import MineParams

__all__ = ["RunResult", "run_scene", "save_checkpoint", "load_checkpoint", "Snapshot"]

SERIES = ["t", "g", "Ek", "Ek_coal", "Ek_free", "U", "W_ext", "W_E", "W_gas", "D_break", "D_fric",
          "D_dash", "D_damp", "residual", "n_tension", "n_shear", "vmax", "Ek_cells", "syy_seam"]
_STATE = ["u", "vh", "vh_prev", "f", "sn", "tau", "jtp", "jnp", "broken", "pg", "acc"]


@dataclass(frozen=True, eq=False)
class RunResult(Result):
    """One run of a mine scene (SI per m of thickness). ``S`` samples, ``N`` cells, ``n`` cells
    on the seam row.

    Attributes
    ----------
    scene : Scene
        The scene in its final state.
    series : dict of ndarray
        Time series, one entry per name of ``SERIES``: scalars (S,) (``t`` [s], ``g`` [-], energies
        and works [J/m], counts, ``vmax`` [m/s]), per-cell kinetic energy ``Ek_cells`` (S, N) [J/m],
        seam-row ``syy_seam`` (S, n) [Pa].
    indicators : MineIndicators
        The typed indicators of the run.
    dt : float
        Time step used [s].
    dt_gershgorin : float
        Safe bound of the time step [s].
    wall_time : float
        Wall time of the run [s].
    timings : dict
        Phase times ``build_s``, ``dynamics_s``, ``sampling_s``, ``checkpoint_s`` [s] and throughput
        ``steps_per_s``, ``cell_steps_per_s`` [1/s].
    stopped : str
        Why the run stopped early ("" if it ran to the end).
    report : RunReport
        LAMMPS-like timing table (``dem.runtime.RunReport``).
    error : InstabilityError or None
        Set when the runaway guard stopped the run (``dem.runtime.InstabilityError``).
    """
    scene: Scene = field(metadata={"export": False})
    series: dict = field(metadata={"export": False})
    indicators: MineIndicators
    dt: float
    dt_gershgorin: float
    wall_time: float
    timings: dict = field(default_factory=dict)
    stopped: str = ""
    report: RunReport = None          # LAMMPS-like timing table (dem.runtime.RunReport)
    error: InstabilityError = field(default=None, metadata={"export": False})   # set when the runaway guard stopped the run


def _sample(scene, g):
    model = scene.model
    e = energies(model)
    _, _, _, free = cell_flags(model)
    m = model.mnode[:, None]
    vs = 0.5 * (model.vh + model.vh_prev)
    ek_cell = 0.5 * np.sum(m * vs * vs, axis=1)
    return {"t": model.t, "g": g, "Ek": e["Ek"], "Ek_coal": float(ek_cell[model.is_coal].sum()),
            "Ek_free": float(ek_cell[free].sum()), "U": e["U"], "W_ext": e["W_ext"], "W_E": e["W_E"],
            "W_gas": e["W_gas"], "D_break": e["D_break"], "D_fric": e["D_fric"], "D_dash": e["D_dash"],
            "D_damp": e["D_damp"], "residual": e["residual"], "n_tension": int((model.broken == 1).sum()),
            "n_shear": int((model.broken == 2).sum()), "vmax": float(np.abs(vs).max()),
            "Ek_cells": ek_cell, "syy_seam": seam_profile(scene)[1]}


class Snapshot(dict):
    """Copy of the model state arrays (the checkpoint content) at a step, a dict of ndarray keyed
    by the names of the ``Model`` state (``u`` [m], ``vh`` [m/s], ``sn`` [Pa], ...) plus ``t`` [s]
    and ``nstep``; ``.step`` (int) for ``dem.runtime.InstabilityError``."""

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
    """Restore the state of ``model`` in place from an npz checkpoint of :func:`save_checkpoint`.

    Returns (series, meta): the time series so far (dict of lists) and the stored metadata (dict).
    """
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
        s0 = _sample(scene, 1.0)
        for k in SERIES:
            series[k].append(s0[k])
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_total, initial=m.nstep, unit="step", desc="mine scene", mininterval=0.5)
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
        s = _sample(scene, ramp_value(m.ramp_kind, m.ramp_time, m.t))
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
    t_int = t_dyn - t_sample - t_ck
    nrun = m.nstep - nstep0
    timings = {"build_s": t_build, "dynamics_s": t_int, "sampling_s": t_sample, "checkpoint_s": t_ck,
               "steps_per_s": nrun / max(t_int, 1e-12),
               "cell_steps_per_s": nrun * m.n_cells / max(t_int, 1e-12)}
    ind = compute(scene, series, wall, m.nstep, dt, stopped)
    report = _report(m, nrun, wall, {"build": t_build, "integration": t_int, "sampling": t_sample,
                                      "checkpoint": t_ck}, dt, dtg, bool(stopped))
    return RunResult(scene=scene, series=series, indicators=ind, dt=dt, dt_gershgorin=dtg, wall_time=wall,
                     timings=timings, stopped=stopped, report=report, error=error)


def _report(m, steps, wall, phases, dt, dtg, stopped):
    """Per-phase timing table in the format of the engine's ``Simulation.run`` (LAMMPS-like)."""
    return run_report(m.n_cells, steps, wall, phases, f"(dt = {dt:.4g}, dt/dt_bound = {dt / dtg:.3f})",
                      unit="cell", what="hexagons", stopped=stopped)
