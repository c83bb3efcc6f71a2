"""The mine study's advancing face: quasi-static stages of mining, the energy partition of each stage,
the abutment stress at each stage (the paper's Fig. 1 redrawn) and Salamon's stability check of the
wedge, for the 60 and 120 deg dislocations and the control (docs/results/mine.md).

    python -m studies.mine_face --quick                 # a 150-cell scene, one slice (tests)
    python -m studies.mine_face [--workers 1] [--img docs/img]

Each case is ``dem.scenes.mine.face.advance_face`` on a map reading (``studies.mine_bumps``): the
adit (stage 0) and ``N_STEPS`` slices of one cell column (0.5 m), each ramped over 10 ms and relaxed
with mass damping to Ek <= ``EK_TOL`` of the stage's released work. The control (no dislocation) is
run once per angle, its wedge bounded by that angle's line. Resumable (``studies.runner``).
Writes out/mine_face/{cases.csv, stages.csv, salamon.md, fig_*.png}. SI units per m of thickness.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import time

import numpy as np
import pandas as pd

from dem.scenes.mine import MineParams
from dem.scenes.mine.face import advance_face
from studies.common import cli_out_dir
from studies.mine_bumps import ANGLES, MAP_BASE, _map_control, _md
from studies.runner import case_id, run_cases

READINGS = tuple(dict(MAP_BASE, disl_phi_deg=phi, gas_pressure=1e6, coal_c=150e3) for phi in (16.0, 22.0, 30.0))
"""The face is advanced at the paper's coal and gas (150 kPa, 1 MPa) for the three fault frictions of
the map (22 deg the paper-closest reading)."""
N_STEPS = 4
"""Slices after the adit: the face advances 2 m, leaving 0.5 m of coal at the dislocation's near end."""
EK_TOL = 1e-5
"""Quasi-static criterion: the kinetic energy over the last 5 ms at most 1e-5 of the stage's released
work (on the elastic test scene the staged face then ends within 0.3 % of one static solve)."""
QUICK = dict(width=6.0, height=5.0, seam_top=2.5, elastic_layer=1.0, floor_layer=1.0, disl_first=1.5,
             ramp_time=0.005)


def face_cases(quick: bool, out_dir: str, phis=None):
    """The runs: each reading (those with a fault friction in ``phis`` [deg], default all) at 60 and
    120 deg, and one control per angle."""
    rs = [dict(READINGS[1], **QUICK)] if quick else [r for r in READINGS if phis is None or r["disl_phi_deg"] in phis]
    n = 1 if quick else N_STEPS
    geo = dict(READINGS[0], **QUICK) if quick else READINGS[0]     # the partition uses the line's geometry only
    out = [{"role": "control", "reading": _map_control(rs[0]), "partition": dict(geo, disl_angle_deg=a),
            "n_steps": n, "out": out_dir} for a in ANGLES]
    out += [{"role": "case", "reading": dict(r, disl_angle_deg=a), "n_steps": n, "out": out_dir}
            for r in rs for a in ANGLES]
    return out


def run_face_case(case: dict) -> dict:
    """One advancing face (Dask task): the stages go to out/face/<id>.json, the summary to the row."""
    c0 = time.process_time()
    p = MineParams(**case["reading"], n_disl=1 if case["role"] == "case" else 0)
    part = MineParams(**case["partition"], n_disl=1) if case["role"] == "control" else None
    fa = advance_face(p, n_steps=case["n_steps"], ek_tol=EK_TOL, partition=part)
    d = os.path.join(case["out"], "face")
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, case_id(case) + ".json"), "w") as fh:
        json.dump({"stages": [s.as_dict() for s in fa.stages], "k_overburden": fa.k_overburden_Pa_per_m}, fh)
    st = fa.stages
    row = {f"salamon.{k}": v for k, v in fa.salamon.as_dict().items()}
    row.update({"all_converged": all(s.converged for s in st),
                "residual_max_J_per_m": max(abs(s.residual_J_per_m) for s in st),
                "k_overburden_Pa_per_m": fa.k_overburden_Pa_per_m, "cpu_time_s": time.process_time() - c0})
    return row


def stages_table(cases, out) -> pd.DataFrame:
    """All stages of all finished cases, one row each, with the case's role, angle and friction."""
    rows = []
    for c in cases:
        f = os.path.join(out, "face", case_id(c) + ".json")
        if not os.path.exists(f):
            continue
        angle = c["reading"].get("disl_angle_deg") if c["role"] == "case" else c["partition"]["disl_angle_deg"]
        phi = c["reading"].get("disl_phi_deg", float("nan"))
        with open(f) as fh:
            for s in json.load(fh)["stages"]:
                rows.append({"role": c["role"], "angle": angle, "phi": phi,
                             **{k: v for k, v in s.items() if k not in ("x_m", "syy_Pa")}})
    return pd.DataFrame(rows)


def _profiles(cases, out, role, angle, phi=None):
    for c in cases:
        a = c["reading"].get("disl_angle_deg") if c["role"] == "case" else c["partition"]["disl_angle_deg"]
        if c["role"] != role or a != angle or (phi is not None and c["reading"].get("disl_phi_deg") != phi):
            continue
        f = os.path.join(out, "face", case_id(c) + ".json")
        if os.path.exists(f):
            with open(f) as fh:
                return json.load(fh)["stages"]
    return None


def figures(cases, st: pd.DataFrame, out, phi) -> list:
    """Fig. 1 redrawn (sigma_yy along the seam at each stage), the energy partition per stage and the
    wedge's load-closure path against the local mine stiffness."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    made = []
    runs = [("60 deg", "case", 60.0), ("120 deg", "case", 120.0), ("control (60 deg wedge)", "control", 60.0)]
    fig, axs = plt.subplots(1, 3, figsize=(16, 4), sharey=True)
    for ax, (lab, role, a) in zip(axs, runs):
        ss = _profiles(cases, out, role, a, phi if role == "case" else None)
        for s in ss or []:
            ax.plot(s["x_m"], np.array(s["syy_Pa"]) / 1e6, ".-", ms=3, label=f"face at {s['face_m']:.1f} m")
        ax.set_title(lab, fontsize=9)
        ax.set_xlabel("distance from the adit's rib [m]")
        ax.set_xlim(0, 12)
    axs[0].set_ylabel("sigma_yy at seam mid-height [MPa]")
    axs[0].legend(fontsize=7)
    fig.suptitle("Abutment stress at the quasi-static stages of mining (the paper's Fig. 1)", fontsize=10)
    made.append(_save(fig, plt, out, "fig_face_profile.png"))
    parts = [("W_boundary_J_per_m", "boundary work"), ("released_J_per_m", "released Eshelby work"),
             ("dU_J_per_m", "strain energy change"), ("D_interfaces_J_per_m", "dissipated in interfaces"),
             ("D_radiated_J_per_m", "radiated / damped kinetic")]
    fig, axs = plt.subplots(1, 3, figsize=(16, 4), sharey=True)
    for ax, (lab, role, a) in zip(axs, runs):
        sub = st[(st.role == role) & (st.angle == a) & ((st.phi == phi) | (role == "control"))]
        w = 0.15
        for i, (col, name) in enumerate(parts):
            ax.bar(sub.stage + (i - 2) * w, sub[col] / 1e3, width=w, label=name)
        ax.set_title(lab, fontsize=9)
        ax.set_xlabel("stage (0: the adit)")
    axs[0].set_ylabel("kJ/m per stage")
    axs[0].legend(fontsize=7)
    made.append(_save(fig, plt, out, "fig_face_energy.png"))
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for (lab, role, a), col in zip(runs, ("tab:blue", "tab:red", "k")):
        sub = st[(st.role == role) & (st.angle == a) & ((st.phi == phi) | (role == "control"))]
        ax.plot(sub.wedge_delta_m * 1e3, sub.wedge_F_N_per_m / 1e6, "o-", color=col, label=lab)
    ax.set_xlabel("wedge closure from the virgin state [mm]")
    ax.set_ylabel("wedge load F [MN/m]")
    ax.set_title("Wedge load against closure over the stages (each stage a different, narrower wedge)", fontsize=8)
    ax.legend(fontsize=7)
    made.append(_save(fig, plt, out, "fig_face_wedge.png"))
    return made


def _save(fig, plt, out, name):
    fig.tight_layout()
    fn = os.path.join(out, name)
    fig.savefig(fn, dpi=80)
    plt.close(fig)
    return fn


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m studies.mine_face", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a 150-cell scene, one slice (3 runs)")
    ap.add_argument("--disl-phi-deg", type=float, nargs="+", default=None,
                    help="only these fault frictions [deg] (default: 16, 22 and 30)")
    ap.add_argument("--out", default="out/mine_face")
    ap.add_argument("--scheduler", default=None, help="None (serial), 'local' or a Dask address")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--img", default=None, help="also copy the figures here (e.g. docs/img)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    out = a.out + ("_quick" if a.quick and a.out == "out/mine_face" else "")
    cli_out_dir(out, cache=False)
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    cases = face_cases(a.quick, out, a.disl_phi_deg)
    df = run_cases(run_face_case, cases, os.path.join(out, "cases.csv"), scheduler=a.scheduler, workers=a.workers,
                   progress=not a.no_progress)
    for _, r in df[df.status != "ok"].iterrows():
        print("FAILED:", r["case_id"], r["error"])
    st = stages_table(cases, out)
    st.to_csv(os.path.join(out, "stages.csv"), index=False)
    sal = pd.DataFrame([{"role": c["role"],
                         "angle": c["reading"].get("disl_angle_deg", c.get("partition", {}).get("disl_angle_deg")),
                         "phi": c["reading"].get("disl_phi_deg", float("nan")),
                         **{k.split(".", 1)[1]: v for k, v in r.items() if str(k).startswith("salamon.")},
                         "converged": r.get("all_converged"), "cpu_s": r.get("cpu_time_s")}
                        for c, (_, r) in zip(cases, df.iterrows()) if r["status"] == "ok"])
    head = (f"{len(df)} runs, wall {time.perf_counter() - t0:.0f} s (sum of CPU {df.get('cpu_time_s', pd.Series()).sum():.0f}"
            f" s), load average {load0:.1f} at start, {os.getloadavg()[0]:.1f} at the end")
    with open(os.path.join(out, "salamon.md"), "w") as fh:
        fh.write(head + "\n\n" + _md(sal) + "\n")
    print(_md(sal))
    print(head)
    made = figures(cases, st, out, (cases[-1]["reading"]["disl_phi_deg"] if a.quick else 22.0)) if len(st) else []
    if a.img:
        os.makedirs(a.img, exist_ok=True)
        for f in made:
            shutil.copy(f, os.path.join(a.img, "mine_" + os.path.basename(f)))
    return 0


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
