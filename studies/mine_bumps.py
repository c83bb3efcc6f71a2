"""Decisive test of the mine paper's claim: is a 120 deg gas-filled dislocation much more dangerous
than a 60 deg one? The 60/120 pair and a control without dislocation, over the readings of the
paper that matter, on the Dask runner (resumable).

    python -m studies.mine_bumps --quick                     # 3 short runs, a few s (tests)
    python -m studies.mine_bumps --scheduler local --workers 2 --img docs/img

Indicators are those of the wedge between the rib and the first dislocation, each with the control
run (same readings, no dislocation, evaluated on the same partition) subtracted. Per reading and
indicator the verdict is "120" if the 120 deg excess exceeds the 60 deg excess by more than
``TOL`` of the larger one, 2 % of the control value and the resolution (``RESOLUTION``), "60" for the
reverse, "=" otherwise.
A reading's overall verdict is "120 worse" when at least two wedge indicators say 120 and none says
60 ("much worse" when the kinetic-energy excess ratio is >= 2, or <= 0.5 for "60 much worse"),
"mixed" when they disagree, "no clear difference" otherwise.
Writes out/mine_bumps/{cases.csv, verdict.csv, verdict.md, states/*.npz, fig_*.png}. SI units per m.
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import shutil
import time

import numpy as np
import pandas as pd

from dem.scenes.mine import (MineParams, block_indicators, block_labels, block_names, fault_indicators, resolve,
                             run_scene)
from dem.scenes.mine.outputs import draw_snapshot, snapshot
from studies.common import cli_out_dir
from studies.runner import case_id, run_cases

BASE = dict(placement="near", floor="rollers", loading="traction", absorbing=False, gas="eigenstrain",
            lattice="inner", model="half", ramp="linear", ramp_time=0.01)
"""The reading closest to the paper's text (docs/mine_scene.md): named end nearest to the rib,
rollers on the outer boundary, overburden as a load on the top, gas as eigenstrain, 0.25 m inner
radius, half-model, 10 ms ramp."""
WEDGE = ("peak_Ek_J_per_m", "disp_mean_m", "disp_max_m", "broken_fraction", "ejected_mass_kg_per_m")
TOL = 0.2
RESOLUTION = {"peak_Ek_J_per_m": 0.0, "disp_mean_m": 1e-3, "disp_max_m": 2e-3, "broken_fraction": 0.02,
              "ejected_mass_kg_per_m": 1200.0}
"""Differences below these are below the model's resolution (about two cells of 552 kg/m, one bond
in 50, a mm) and never decide a verdict."""
ANGLES = (60.0, 120.0)


def _key(placement, angle, n):
    return f"{placement}_{int(angle)}_{n}"


def _control_reading(r):
    """Placement and gas do not act without a dislocation: one control per remaining reading."""
    return {**r, "placement": "near", "gas": "none"}


def readings(quick: bool):
    """(reading dict, n_disl list) of the study."""
    if quick:
        return [(dict(BASE, ramp_time=0.005), [1])]
    out = []
    for pl, fl, (ld, ab), gas in itertools.product(("near", "far"), ("rollers", "no_slip", "rock"),
                                                   (("traction", False), ("rollers", False), ("spring", True)),
                                                   ("interface", "eigenstrain")):
        out.append((dict(BASE, placement=pl, floor=fl, loading=ld, absorbing=ab, gas=gas), [1]))
    for pl in ("near", "far"):
        out.append((dict(BASE, placement=pl), [2, 3]))                              # figures, 1/2/3
        out.append((dict(BASE, placement=pl, loading="tall", absorbing=True), [1]))
        out.append((dict(BASE, placement=pl, absorbing=True), [1]))
        out.append((dict(BASE, placement=pl, model="full"), [1]))
        for rk, rt in (("instant", 0.0), ("linear", 0.05)):
            out.append((dict(BASE, placement=pl, ramp=rk, ramp_time=rt), [1]))
        for fl, ld, ab in (("rollers", "traction", False), ("no_slip", "traction", False),
                           ("rollers", "spring", True), ("no_slip", "spring", True)):
            for gas in ("eigenstrain", "interface"):                              # convergence in the lattice
                out.append((dict(BASE, placement=pl, floor=fl, loading=ld, absorbing=ab, gas=gas, lattice="side"), [1]))
    return out


def cases(quick: bool, out_dir: str):
    dur = 0.01 if quick else 0.1
    runs, controls = [], {}
    for r, ns in readings(quick):
        for n in ns:
            for a in ANGLES:
                runs.append({"role": "case", "reading": r, "angle": a, "n_disl": n, "duration": dur, "out": out_dir})
            ck = json.dumps(_control_reading(r), sort_keys=True)
            parts = controls.setdefault(ck, set())
            parts.update((r["placement"], a, n) for a in ANGLES)
    ctl = [{"role": "control", "reading": json.loads(ck), "partitions": sorted(map(list, parts)), "duration": dur,
            "out": out_dir} for ck, parts in controls.items()]
    return ctl + runs


def _params(reading, angle=60.0, n=0, duration=0.1, placement=None, dt_safety=None):
    r = dict(reading)
    if placement:
        r["placement"] = placement
    if dt_safety is not None:
        r["dt_safety"] = dt_safety
    return MineParams(**r, disl_angle_deg=angle, n_disl=n, duration=duration)


def _flat_blocks(prefix, blocks):
    return {f"b.{prefix}.{b.name}.{k}": v for b in blocks for k, v in b.as_dict().items() if k != "name"}


def run_case(case: dict) -> dict:
    """One run of the study (Dask task): a 60/120 case or a control evaluated on every partition it
    is compared with. Saves the final-state snapshot and the seam profiles to out/states/<id>.npz."""
    cpu0 = time.process_time()
    r = case["reading"]
    dts = case.get("dt_safety")
    if case["role"] == "case":
        p = _params(r, case["angle"], case["n_disl"], case["duration"], dt_safety=dts)
    else:
        p = _params(r, duration=case["duration"], dt_safety=dts)
    res = run_scene(p)
    ind = res.indicators
    row = {k: v for k, v in ind.as_dict().items() if k not in ("blocks", "fault")}
    extra = {}
    if case["role"] == "case":
        key = _key(r["placement"], case["angle"], case["n_disl"])
        row.update(_flat_blocks(key, ind.blocks))
        row.update({f"f.{key}.{k}": v for k, v in ind.fault.as_dict().items()})
        wedge = res.scene.labels == 0
        extra["Ek_wedge_" + key] = res.series["Ek_cells"][:, wedge].sum(axis=1)
        extra["slip_" + key] = np.array(_slip_profile(res.scene, res.scene.geometry.dislocations))
    else:
        m = res.scene.model
        for pl, a, n in case["partitions"]:
            g = resolve(_params(r, a, n, placement=pl))
            lab = block_labels(g, m.centres, m.is_coal)
            key = _key(pl, a, n)
            row.update(_flat_blocks(key, block_indicators(res.scene, res.series, lab, block_names(n))))
            fi = fault_indicators(res.scene, res.series, lines=g.dislocations)
            row.update({f"f.{key}.{k}": v for k, v in fi.as_dict().items()})
            extra["Ek_wedge_" + key] = res.series["Ek_cells"][:, lab == 0].sum(axis=1)
            extra["slip_" + key] = np.array(_slip_profile(res.scene, g.dislocations))
    e = res.series
    row["residual_max_J_per_m"] = float(np.abs(e["residual"]).max())
    row["W_top_J_per_m"] = float(e["W_ext"][-1] - e["W_E"][-1] - e["W_gas"][-1])
    row["W_E_released_J_per_m"] = float(-e["W_E"][-1])
    sd = os.path.join(case["out"], "states")
    os.makedirs(sd, exist_ok=True)
    pr = ind.profile
    np.savez_compressed(os.path.join(sd, case_id(case) + ".npz"), **snapshot(res.scene), prof_dist=pr.dist_m,
                        prof_g=pr.g, prof_syy=pr.syy_Pa, Ek_t=res.series["t"], Ek=res.series["Ek"], **extra)
    row["cpu_time_s"] = time.process_time() - cpu0     # this worker's CPU time for the case (wall in the runner)
    return row


def _slip_profile(scene, lines):
    """(distance along the first line from its floor end [m], slip [m]) across the interfaces the
    first of ``lines`` crosses (the run's final state against its start)."""
    from dem.hexagons.fault import fault_frame, segments_cross
    if not len(lines):
        return np.zeros((2, 0))
    m = scene.model
    p0, p1 = lines[0]
    e = np.nonzero(segments_cross(m.centres[m.ci], m.centres[m.cj], p0, p1))[0]
    t_l, n_l = fault_frame(p0, p1)
    ne = m.geo["n"][m.ca[e]]
    du = m.u - m.u0
    jx = du[m.cj[e], 2 * m.cb[e]] - du[m.ci[e], 2 * m.ca[e]]
    jy = du[m.cj[e], 2 * m.cb[e] + 1] - du[m.ci[e], 2 * m.ca[e] + 1]
    slip = np.sign(ne @ n_l) * (jx * t_l[0] + jy * t_l[1])
    mid = m.centres[m.ci[e]] + m.geo["x"][m.ca[e]]
    s = (mid - p0) @ t_l
    o = np.argsort(s)
    return np.stack([s[o], slip[o]])


def _label(r):
    bits = [r["placement"], f"floor={r['floor']}", f"load={r['loading']}" + ("+abs" if r["absorbing"] else ""),
            f"gas={r['gas']}"]
    for k in ("lattice", "model"):
        if r[k] != BASE[k]:
            bits.append(f"{k}={r[k]}")
    if r["ramp"] != "linear" or r["ramp_time"] != BASE["ramp_time"]:
        bits.append(f"ramp={r['ramp']} {r['ramp_time'] * 1e3:g}ms")
    return " ".join(bits)


def verdict_table(all_cases, df) -> pd.DataFrame:
    """One row per (reading, n): the wedge excesses over the control for 60 and 120 and a verdict
    per indicator and overall."""
    df = df.set_index("case_id")
    ctrl = {json.dumps(c["reading"], sort_keys=True): case_id(c) for c in all_cases if c["role"] == "control"}
    rows = []
    groups = {}
    for c in all_cases:
        if c["role"] == "case":
            groups.setdefault((json.dumps(c["reading"], sort_keys=True), c["n_disl"]), {})[c["angle"]] = case_id(c)
    for (rk, n), ids in groups.items():
        r = json.loads(rk)
        cid = ctrl[json.dumps(_control_reading(r), sort_keys=True)]
        if any(i not in df.index or df.loc[i, "status"] != "ok" for i in (*ids.values(), cid)):
            continue
        row = {"reading": _label(r), "n_disl": n, **{k: r[k] for k in BASE}}
        votes = []
        for ind in WEDGE:
            ex = {}
            for a in ANGLES:
                col = f"b.{_key(r['placement'], a, n)}.wedge.{ind}"
                case_v, ctrl_v = float(df.loc[ids[a], col]), float(df.loc[cid, col])
                ex[a] = case_v - ctrl_v
                row[f"{ind}@{int(a)}"] = case_v
                row[f"{ind}@{int(a)}-ctrl"] = ex[a]
            ref = max(abs(ex[60.0]), abs(ex[120.0]))
            cv = abs(float(df.loc[cid, f"b.{_key(r['placement'], 60.0, n)}.wedge.{ind}"]))
            tol = TOL * ref + 0.02 * cv + RESOLUTION[ind] + 1e-12
            d = ex[120.0] - ex[60.0]
            v = "120" if d > tol else ("60" if d < -tol else "=")
            row[f"verdict {ind}"] = v
            votes.append(v)
        e60, e120 = row["peak_Ek_J_per_m@60-ctrl"], row["peak_Ek_J_per_m@120-ctrl"]
        row["Ek excess ratio 120/60"] = e120 / e60 if abs(e60) > 1e-9 else np.nan
        n120, n60 = votes.count("120"), votes.count("60")
        if n120 >= 2 and not n60:
            v = "120 worse"
        elif n60 >= 2 and not n120:
            v = "60 worse"
        elif n120 and n60:
            v = "mixed"
        else:
            v = "no clear difference"
        ratio = row["Ek excess ratio 120/60"]
        if v != "no clear difference" and np.isfinite(ratio) and (ratio >= 2 or 0 < ratio <= 0.5):
            v = v.replace("worse", "much worse")
        row["votes 120/60/="] = f"{n120}/{n60}/{votes.count('=')}"
        row["verdict"] = v
        rows.append(row)
    return pd.DataFrame(rows)


def summary_by_reading(vt: pd.DataFrame) -> pd.DataFrame:
    """For each reading axis and value (n = 1 rows): how many readings give each verdict, and the
    median ratio of the wedge kinetic-energy excesses 120/60."""
    one = vt[vt.n_disl == 1]
    rows = []
    for ax in ("placement", "floor", "loading", "absorbing", "gas", "lattice", "model", "ramp_time"):
        for val, g in one.groupby(ax):
            v = g.verdict
            rows.append({"axis": ax, "value": val, "readings": len(g), "120 worse": int(v.str.startswith("120").sum()),
                         "60 worse": int(v.str.startswith("60").sum()), "mixed": int((v == "mixed").sum()),
                         "no clear difference": int((v == "no clear difference").sum()),
                         "median Ek excess ratio 120/60": float(np.nanmedian(g["Ek excess ratio 120/60"]))})
    return pd.DataFrame(rows)


def figures(all_cases, df, out, quick):
    """The paper's figure set from the saved snapshots (base reading)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def snap(**want):
        for c in all_cases:
            if c["role"] == "case" and c["reading"] == want["reading"] and c["angle"] == want["angle"] \
                    and c["n_disl"] == want["n"]:
                f = os.path.join(out, "states", case_id(c) + ".npz")
                return dict(np.load(f)) if os.path.exists(f) else None
        return None

    made = []
    for pl in (("near",) if quick else ("near", "far")):
        base = dict(BASE, placement=pl, **({"ramp_time": 0.005} if quick else {}))
        ns = [1] if quick else [1, 2, 3]
        s = snap(reading=base, angle=60.0, n=1)
        if s is not None:                                # Fig. 1: sigma_yy along the seam, stages
            fig, ax = plt.subplots(figsize=(7, 4))
            for k in range(len(s["prof_g"])):
                lab = f"g = {s['prof_g'][k]:.2f}" + (" (end of run)" if k == len(s["prof_g"]) - 1 else "")
                ax.plot(s["prof_dist"], s["prof_syy"][k] / 1e6, ".-", ms=3, label=lab)
            ax.set_xlabel("distance from the rib [m]")
            ax.set_ylabel("sigma_yy at seam mid-height [MPa]")
            ax.set_title(f"Vertical stress along the seam, excavation stages (60 deg, {pl})", fontsize=9)
            ax.legend(fontsize=7)
            fig.tight_layout()
            fn = os.path.join(out, f"fig_profile_{pl}.png")
            fig.savefig(fn, dpi=80)
            plt.close(fig)
            made.append(fn)
        fig, axs = plt.subplots(len(ns), 2, figsize=(13, 4.0 * len(ns)), squeeze=False)
        for i, n in enumerate(ns):
            for j, a in enumerate(ANGLES):
                s = snap(reading=base, angle=a, n=n)
                if s is not None:
                    draw_snapshot(axs[i, j], s, f"{int(a)} deg, {n} dislocation(s), {pl}", xlim=(-0.3, 16))
        fig.tight_layout()
        fn = os.path.join(out, f"fig_cracks_{pl}.png")
        fig.savefig(fn, dpi=80)
        plt.close(fig)
        made.append(fn)
        n = ns[-1]
        fig, axs = plt.subplots(1, 2, figsize=(13, 4.0), squeeze=False)
        for j, a in enumerate(ANGLES):
            s = snap(reading=base, angle=a, n=n)
            if s is not None:
                draw_snapshot(axs[0, j], s, f"displacement vectors, {int(a)} deg, {n} dislocation(s), {pl}",
                              vectors=True, xlim=(-0.3, 16))
        fig.tight_layout()
        fn = os.path.join(out, f"fig_vectors_{pl}.png")
        fig.savefig(fn, dpi=80)
        plt.close(fig)
        made.append(fn)
    return made


def _md(df):
    try:
        return df.to_markdown(index=False, floatfmt=".3g")
    except ImportError:
        return df.to_string(index=False)


def main_legacy(a):
    """The first pass: 66 readings of the paper with the edge-by-edge (zigzag) fault, kept for the
    record (``--legacy``; docs/results/mine.md, "The first pass")."""
    out = a.out + ("_legacy" if a.out == "out/mine_bumps" else "") + ("_quick" if a.quick else "")
    os.makedirs(out, exist_ok=True)
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    all_cases = cases(a.quick, out)
    df = run_cases(run_case, all_cases, os.path.join(out, "cases.csv"), scheduler=a.scheduler, workers=a.workers,
                   progress=not a.no_progress)
    wall = time.perf_counter() - t0
    bad = df[df.status != "ok"]
    for _, r in bad.iterrows():
        print("FAILED:", r["case_id"], r["error"])
    vt = verdict_table(all_cases, df)
    vt.to_csv(os.path.join(out, "verdict.csv"), index=False)
    show = vt[["reading", "n_disl", "peak_Ek_J_per_m@60-ctrl", "peak_Ek_J_per_m@120-ctrl", "Ek excess ratio 120/60",
               "disp_mean_m@60-ctrl", "disp_mean_m@120-ctrl", "ejected_mass_kg_per_m@60-ctrl",
               "ejected_mass_kg_per_m@120-ctrl", "broken_fraction@60-ctrl", "broken_fraction@120-ctrl",
               "votes 120/60/=", "verdict"]].copy()
    for c in ("peak_Ek_J_per_m@60-ctrl", "peak_Ek_J_per_m@120-ctrl"):
        show[c] = show[c] / 1e3
    show.columns = ["reading", "n", "wedge dEk 60 kJ/m", "wedge dEk 120 kJ/m", "ratio", "wedge du 60 m",
                    "wedge du 120 m", "wedge dm 60 kg/m", "wedge dm 120 kg/m", "wedge dbroken 60",
                    "wedge dbroken 120", "votes 120/60/=", "verdict"]
    counts = vt["verdict"].value_counts().to_dict()
    run_s = float(df["wall_time_s"].sum())
    cpu_s = float(df["cpu_time_s"].sum()) if "cpu_time_s" in df else float("nan")
    head = (f"{len(df)} runs ({len(bad)} failed), wall {wall:.0f} s (sum of run times {run_s:.0f} s, of their CPU "
            f"times {cpu_s:.0f} s), scheduler "
            f"{a.scheduler or 'serial'} workers {a.workers or '-'}, load average at start {load0[0]:.2f} / end "
            f"{os.getloadavg()[0]:.2f}. Verdicts: {counts}")
    summ = summary_by_reading(vt) if len(vt) else pd.DataFrame()
    with open(os.path.join(out, "verdict.md"), "w") as fh:
        fh.write(head + "\n\n" + _md(show) + "\n\n" + (_md(summ) if len(summ) else "") + "\n")
    print(_md(show))
    print(head)
    made = figures(all_cases, df, out, a.quick)
    if a.img:
        os.makedirs(a.img, exist_ok=True)
        for f in made:
            shutil.copy(f, os.path.join(a.img, "mine_" + os.path.basename(f)))
    print(f"wrote {out}/cases.csv, verdict.csv, verdict.md, {len(made)} figures ({time.perf_counter() - t0:.0f} s)")
    return 0




# ----------------------------------------------------------------------------- the map (decisive pass)
MAP_BASE = dict(placement="near", floor="rock", loading="spring", absorbing=True, gas="interface", lattice="inner",
                model="half", ramp="linear", ramp_time=0.01, fault_law="plane", K0=0.6)
"""The decisive pass: the planar fault (Mohr-Coulomb on the true plane), a rock floor, the calibrated
overburden spring with absorbing boundaries, gas as pressure on the opened fault faces, and
K0 = 0.6 (with the paper's K0 = 1/3 the true 60 and 120 deg planes fail before excavation, which the
scene refuses: docs/results/mine.md)."""
MAP_AXES = {"disl_phi_deg": (16.0, 22.0, 30.0), "gas_pressure": (0.0, 1e6), "coal_c": (150e3, 1e6)}
"""The swept variables: fault friction [deg] (16 is the weakest that carries the virgin stress with
1 MPa of gas at K0 = 0.6; 22 is the coal's, the paper's fault), gas pressure [Pa] (1 MPa the paper's)
and coal cohesion [Pa] (150 kPa the paper's)."""
PAPER_CLOSEST = {"disl_phi_deg": 22.0, "gas_pressure": 1e6, "coal_c": 150e3}
REPS = (0.64, 0.67, 0.70, 0.73, 0.76)
"""dt_safety of the perturbed repetitions (time step 0.64-0.76 of the Gershgorin bound)."""
JITTER = (2.25, 2.375, 2.50, 2.625, 2.75)
"""``--noise lattice``: the named end of the dislocation at these distances from the rib [m] (the
line moves by up to half a cell, d/2, across the lattice, so the set of crossed edges changes; a
shift of 0.1 m crosses the same edges and changes nothing but round-off), time step 0.7 of the
bound."""
MAP_IND = {"wedge peak Ek [J/m]": ("b", "wedge.peak_Ek_J_per_m", 1e3),
           "wedge disp [m]": ("b", "wedge.disp_mean_m", 1e-3),
           "fault |slip| [m]": ("f", "slip_mean_m", 1e-4),
           "fault released [J/m]": ("f", "released_J_per_m", 1e3)}
"""Indicator -> (table, column, resolution): differences below the resolution (1 kJ/m, 1 mm, 0.1 mm)
never decide a verdict."""
EQUAL_FRACTION = 0.1
"""'equal' needs the whole confidence interval of the 120 - 60 difference within +-10 % of the larger
excess over the control (or the resolution)."""


def map_readings(quick: bool, placement: str = "near", subset: dict | None = None):
    """The readings of the map (one dict of MineParams fields each), with the dislocation's
    ``placement`` ("near": the map; "far": the line runs toward the rib and cuts the face);
    ``subset``: {axis of ``MAP_AXES``: allowed values} keeps only those readings."""
    base = dict(MAP_BASE, placement=placement)
    if quick:
        return [dict(base, ramp_time=0.005, disl_phi_deg=16.0, gas_pressure=1e6, coal_c=150e3)]
    keys = list(MAP_AXES)[::-1]                     # coal cohesion outermost: the paper's coal first
    out = [dict(base, **dict(zip(keys, vals))) for vals in itertools.product(*list(MAP_AXES.values())[::-1])]
    for k, vals in (subset or {}).items():
        if k not in MAP_AXES:
            raise ValueError(f"subset axis {k!r}: allowed {', '.join(MAP_AXES)}")
        out = [r for r in out if any(abs(r[k] - v) <= 1e-9 * max(1.0, abs(v)) for v in vals)]
    return out


def _map_control(r):
    """The control of a map reading: no dislocation, so the fault's friction and the gas do not act."""
    return {k: v for k, v in r.items() if k not in ("disl_phi_deg", "gas_pressure")} | {"gas": "none"}


def map_cases(quick: bool, out_dir: str, noise: str = "dt", placement: str = "near", subset: dict | None = None):
    """The runs of the map. ``noise="dt"``: each case repeated at the time steps ``REPS``;
    ``noise="lattice"``: every map reading with the dislocation moved across the lattice
    (``JITTER``) at one time step (0.7 of the bound). One control per distinct control reading and
    repetition, listed just before the first runs that need it."""
    dur = 0.01 if quick else 0.05
    out, seen = [], set()
    if noise == "lattice":
        reps = [("disl_first", x, 0.7) for x in ((2.45, 2.55) if quick else JITTER)]
    else:
        reps = [(None, None, d) for d in ((0.67, 0.73) if quick else REPS)]
    for r0 in map_readings(quick, placement, subset):
        for jit, x, dts in reps:
            r = dict(r0, **({jit: x} if jit else {}))
            c = _map_control(r)
            extra = {"jitter": jit} if jit else {}
            ck = json.dumps(c, sort_keys=True) + str(dts)
            if ck not in seen:
                seen.add(ck)
                out.append({"role": "control", "reading": c, "partitions": [[r["placement"], a, 1] for a in ANGLES],
                            "duration": dur, "out": out_dir, "dt_safety": dts, **extra})
        for jit, x, dts in reps:
            r = dict(r0, **({jit: x} if jit else {}))
            for a in ANGLES:
                out.append({"role": "case", "reading": r, "angle": a, "n_disl": 1, "duration": dur, "out": out_dir,
                            "dt_safety": dts, **({"jitter": jit} if jit else {})})
    return out


def _rep_key(c):
    """(reading without the repeated variable, the repetition's value) of a case or control."""
    r = dict(c["reading"])
    if c.get("jitter"):
        return json.dumps({k: v for k, v in r.items() if k != c["jitter"]}, sort_keys=True), r[c["jitter"]]
    return json.dumps(r, sort_keys=True), c["dt_safety"]


def _value(df, cid, kind, col, key):
    v = float(df.loc[cid, f"{kind}.{key}.{col}"])
    return abs(v) if col == "slip_mean_m" else v


def map_table(all_cases, df) -> pd.DataFrame:
    """One row per map reading: per indicator the excesses of 60 and 120 over the control (mean and
    2 sigma over the repetitions), the paired difference 120 - 60 with its 95 % half-width (the
    minimum detectable effect, Student t over the repetitions), a verdict per indicator ('120',
    '60', '=' or '?' not resolvable) and overall, and the energy residual beside it."""
    from scipy import stats
    df = df.set_index("case_id")
    ok = lambda i: i in df.index and df.loc[i, "status"] == "ok"       # noqa: E731
    ctrl = {_rep_key(c): case_id(c) for c in all_cases if c["role"] == "control"}
    groups = {}
    for c in all_cases:
        if c["role"] == "case":
            rk, rv = _rep_key(c)
            groups.setdefault(rk, {}).setdefault(rv, {})[c["angle"]] = case_id(c)
    rows = []
    for rk, reps in groups.items():
        r = json.loads(rk)
        key = {a: _key(r["placement"], a, 1) for a in ANGLES}
        trip = []
        for dts, ids in sorted(reps.items()):
            cid = ctrl[(json.dumps(_map_control(r), sort_keys=True), dts)]
            if all(ok(i) for i in (*ids.values(), cid)):
                trip.append((ids, cid))
        n = len(trip)
        if n < 2:
            continue
        row = {**{k: r[k] for k in MAP_AXES}, "reps": n}
        votes, deciding = {}, []
        for name, (kind, col, res) in MAP_IND.items():
            v = {a: np.array([_value(df, ids[a], kind, col, key[a]) for ids, _ in trip]) for a in ANGLES}
            c = {a: np.array([_value(df, cid, kind, col, key[a]) for _, cid in trip]) for a in ANGLES}
            ex = {a: v[a] - c[a] for a in ANGLES}
            d = ex[120.0] - ex[60.0]             # paired by repetition (same time step)
            h = float(stats.t.ppf(0.975, n - 1) * d.std(ddof=1) / np.sqrt(n))
            for a in ANGLES:
                row[f"{name} excess {int(a)}"] = float(ex[a].mean())
                row[f"{name} excess {int(a)} 2sigma"] = float(2 * ex[a].std(ddof=1))
            row[f"{name} diff 120-60"] = float(d.mean())
            row[f"{name} MDE"] = h
            margin = max(EQUAL_FRACTION * max(abs(ex[60.0].mean()), abs(ex[120.0].mean())), res)
            m_ = float(d.mean())
            if abs(m_) > h and abs(m_) > res:
                vt = "120" if m_ > 0 else "60"
                deciding.append((name, abs(m_)))
            elif abs(m_) + h <= margin:
                vt = "="
            else:
                vt = "?"
            row[f"verdict {name}"] = vt
            votes[name] = vt
        vs = list(votes.values())
        if "120" in vs and "60" in vs:
            verdict = "mixed"
        elif "120" in vs:
            verdict = "120 worse"
        elif "60" in vs:
            verdict = "60 worse"
        elif all(x == "=" for x in vs):
            verdict = "equal"
        else:
            verdict = "not resolvable"
        ids_all = [i for ids, cid in trip for i in (*ids.values(), cid)]
        row["residual max [J/m]"] = float(max(df.loc[i, "residual_max_J_per_m"] for i in ids_all))
        en = [x for nm, x in deciding if "J/m" in nm]
        row["smallest deciding energy effect [J/m]"] = min(en) if en else np.nan
        row["W_top / W_E"] = float(np.mean([df.loc[i, "W_top_J_per_m"] / max(df.loc[i, "W_E_released_J_per_m"], 1e-30)
                                            for i in ids_all]))
        row["votes"] = "/".join(f"{votes[k]}" for k in MAP_IND)
        row["verdict"] = verdict
        rows.append(row)
    return pd.DataFrame(rows)


def _closest(all_cases, out, quick, role, angle=None, dts=None, placement="near"):
    want = map_readings(quick, placement)[0] if quick else dict(MAP_BASE, **PAPER_CLOSEST, placement=placement)
    for c in all_cases:
        if c["role"] != role or (dts is not None and c["dt_safety"] != dts):
            continue
        if role == "case" and (c["reading"] != want or c["angle"] != angle):
            continue
        if role == "control" and c["reading"] != _map_control(want):
            continue
        f = os.path.join(out, "states", case_id(c) + ".npz")
        if os.path.exists(f):
            return dict(np.load(f))
    return None


def map_figures(all_cases, mt, out, quick, placement="near"):
    """The pictures of the decisive pass (docs/results/mine.md)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    made = []
    reps = sorted({c["dt_safety"] for c in all_cases})
    mid = reps[len(reps) // 2]
    k60, k120 = _key(placement, 60.0, 1), _key(placement, 120.0, 1)

    def save(fig, name):
        fig.tight_layout()
        fn = os.path.join(out, name)
        fig.savefig(fn, dpi=80)
        plt.close(fig)
        made.append(fn)

    # the reading closest to the paper: cracks of 60, 120 and the control, and the seam stress profile
    s = {a: _closest(all_cases, out, quick, "case", a, mid, placement) for a in ANGLES}
    sc = _closest(all_cases, out, quick, "control", dts=mid, placement=placement)
    if s[60.0] is not None:
        fig, ax = plt.subplots(figsize=(7, 4))
        for k in range(len(s[60.0]["prof_g"])):
            lab = f"g = {s[60.0]['prof_g'][k]:.2f}" + (" (end of run)" if k == len(s[60.0]["prof_g"]) - 1 else "")
            ax.plot(s[60.0]["prof_dist"], s[60.0]["prof_syy"][k] / 1e6, ".-", ms=3, label=lab)
        ax.set_xlabel("distance from the rib [m]")
        ax.set_ylabel("sigma_yy at seam mid-height [MPa]")
        ax.set_title("Vertical stress along the seam during the excavation ramp (60 deg, paper-closest map "
                     "reading; dynamic, not quasi-static stages)", fontsize=8)
        ax.legend(fontsize=7)
        save(fig, f"fig_profile_{placement}.png")
    if s[60.0] is not None and s[120.0] is not None:
        fig, axs = plt.subplots(1, 3, figsize=(16, 3.6))
        for ax, (lab, sn) in zip(axs, (("60 deg", s[60.0]), ("120 deg", s[120.0]), ("control", sc))):
            if sn is not None:
                draw_snapshot(ax, sn, f"{lab}: cells at their displaced positions, cracks", xlim=(-0.3, 12))
                if lab == "control":
                    for seg in s[60.0]["disl"]:
                        ax.plot(seg[:, 0], seg[:, 1], color="0.5", ls=":", lw=0.8)
        save(fig, f"fig_cracks_{placement}.png")
    if sc is not None and s[60.0] is not None and s[120.0] is not None:      # difference maps
        fig, axs = plt.subplots(1, 2, figsize=(13, 3.6))
        for ax, a in zip(axs, ANGLES):
            dd = np.linalg.norm(s[a]["disp"] - sc["disp"], axis=1) * 1e3
            C = s[a]["centres"]
            sel = C[:, 0] < 12
            im = ax.scatter(C[sel, 0], C[sel, 1], c=dd[sel], s=18, marker="h", cmap="magma_r",
                            vmin=0, vmax=max(np.percentile(dd[sel], 99), 1e-6))
            for seg in s[a]["disl"]:
                ax.plot(seg[:, 0], seg[:, 1], "g-", lw=1.5)
            ax.set_aspect("equal")
            ax.set_title(f"|u({int(a)} deg) - u(control)| [mm] at the end", fontsize=9)
            fig.colorbar(im, ax=ax, shrink=0.8)
        save(fig, f"fig_difference_{placement}.png")
    if s[60.0] is not None and s[120.0] is not None:                          # fault-slip profiles
        fig, ax = plt.subplots(figsize=(7, 4))
        for a, k in ((60.0, k60), (120.0, k120)):
            pr = s[a]["slip_" + k]
            if pr.size:
                ax.plot(pr[0], np.abs(pr[1]) * 1e3, ".-", label=f"{int(a)} deg fault")
            if sc is not None and ("slip_" + k) in sc and sc["slip_" + k].size:
                pc = sc["slip_" + k]
                ax.plot(pc[0], np.abs(pc[1]) * 1e3, ":", label=f"control across the {int(a)} deg line")
        ax.set_xlabel("distance along the dislocation from its floor end [m]")
        ax.set_ylabel("|slip| at the end [mm]")
        ax.set_title("Slip along the dislocation (paper-closest map reading)", fontsize=9)
        ax.legend(fontsize=7)
        save(fig, "fig_slip_profile.png")
    # wedge kinetic energy over time with the band over the repetitions
    fig, ax = plt.subplots(figsize=(7, 4))
    for lab, role, a, k, col in (("60 deg", "case", 60.0, k60, "tab:blue"), ("120 deg", "case", 120.0, k120, "tab:red"),
                                 ("control", "control", None, k60, "k")):
        curves = [_closest(all_cases, out, quick, role, a, d, placement) for d in reps]
        curves = [c for c in curves if c is not None and ("Ek_wedge_" + k) in c]
        if not curves:
            continue
        n_ = min(len(c["Ek_t"]) for c in curves)
        t = curves[0]["Ek_t"][:n_] * 1e3
        Y = np.array([np.interp(t, c["Ek_t"] * 1e3, c["Ek_wedge_" + k]) for c in curves]) / 1e3
        ax.fill_between(t, Y.min(axis=0), Y.max(axis=0), color=col, alpha=0.25, lw=0)
        ax.plot(t, np.median(Y, axis=0), color=col, lw=1, label=f"{lab} (band: {len(curves)} time steps)")
    ax.set_xlabel("t [ms]")
    ax.set_ylabel("kinetic energy of the wedge [kJ/m]")
    ax.set_title("Wedge kinetic energy, paper-closest map reading", fontsize=9)
    ax.legend(fontsize=7)
    save(fig, "fig_wedge_Ek.png")
    if len(mt):
        col = {"120 worse": "tab:red", "60 worse": "tab:blue", "mixed": "tab:purple", "equal": "tab:green",
               "not resolvable": "0.6"}
        # one-glance verdict plot: 60 excess against 120 excess, one point per reading, noise boxes
        fig, axs = plt.subplots(1, 2, figsize=(12, 5))
        for ax, name, sc_ in ((axs[0], "wedge peak Ek [J/m]", 1e-3), (axs[1], "fault |slip| [m]", 1e3)):
            x = mt[f"{name} excess 60"] * sc_
            y = mt[f"{name} excess 120"] * sc_
            ax.errorbar(x, y, xerr=mt[f"{name} excess 60 2sigma"] * sc_, yerr=mt[f"{name} excess 120 2sigma"] * sc_,
                        fmt="none", ecolor="0.6", lw=0.8)
            ax.scatter(x, y, c=[col[v] for v in mt.verdict], s=30, zorder=3)
            lo, hi = float(min(x.min(), y.min())), float(max(x.max(), y.max()))
            ax.plot([lo, hi], [lo, hi], "k--", lw=0.7)
            unit = "kJ/m" if "J/m" in name else "mm"
            ax.set_xlabel(f"60 deg excess over the control [{unit}]")
            ax.set_ylabel(f"120 deg excess over the control [{unit}]")
            ax.set_title(name.split(" [")[0] + " (bars: 2 sigma over the repetitions)", fontsize=9)
        for v, cc in col.items():
            axs[0].scatter([], [], c=cc, label=v)
        axs[0].legend(fontsize=7)
        save(fig, "fig_verdict.png")
        # the map: verdict per (fault friction, gas pressure), one panel per coal cohesion
        cs = sorted(mt["coal_c"].unique())
        fig, axs = plt.subplots(1, len(cs), figsize=(5.5 * len(cs), 4), squeeze=False)
        for ax, cval in zip(axs[0], cs):
            sub = mt[mt.coal_c == cval]
            for _, r in sub.iterrows():
                ax.scatter(r.gas_pressure / 1e6, r.disl_phi_deg, s=900, marker="s", c=col[r.verdict])
                ax.text(r.gas_pressure / 1e6, r.disl_phi_deg,
                        f"{r['fault |slip| [m] diff 120-60'] * 1e3:+.2f}\n+-{r['fault |slip| [m] MDE'] * 1e3:.2f} mm",
                        ha="center", va="center", fontsize=6)
            ax.set_xlabel("gas pressure [MPa]")
            ax.set_ylabel("fault friction angle [deg]")
            ax.set_title(f"coal cohesion {cval / 1e3:g} kPa: slip 120 - 60 (95 % half-width)", fontsize=8)
            ax.margins(0.3)
        for v, cc in col.items():
            axs[0, 0].scatter([], [], c=cc, marker="s", label=v)
        axs[0, 0].legend(fontsize=6, loc="lower right")
        save(fig, "fig_map.png")
    return made


def static_coulomb(reading=None, floors=("rock", "rollers")) -> pd.DataFrame:
    """The independent static check: the elastic stress field of the excavated scene (one sparse solve
    of the linear response to the full removal of the Eshelby forces, every interface intact,
    :func:`dem.scenes.mine.excavation.static_excavation`) resolved on the *true* 60 and 120 deg planes in
    the coal cells the dislocation crosses; Coulomb failure function CFF = |tau| + (sigma_n + p_g) tan phi
    [Pa], before and after the excavation. One row per (floor, angle)."""
    from dem.hexagons.dynamics import cell_stress
    from dem.hexagons.fault import fault_frame, segments_cross
    from dem.scenes.mine import build_scene
    from dem.scenes.mine.excavation import static_excavation
    r0 = dict(MAP_BASE, **PAPER_CLOSEST) if reading is None else dict(reading)
    rows = []
    for floor in floors:
        for a in ANGLES:
            p = MineParams(**dict(r0, floor=floor), disl_angle_deg=a, n_disl=1, elastic=True)
            sc = build_scene(p)
            m = sc.model
            du, _ = static_excavation(m)
            seg = sc.geometry.dislocations[0]
            t, n = fault_frame(*seg)
            e = segments_cross(m.centres[m.ci], m.centres[m.cj], seg[0], seg[1])
            cells = np.unique(np.concatenate([m.ci[e], m.cj[e]]))
            cells = cells[m.is_coal[cells]]
            tp = np.tan(np.radians(p.disl_phi_deg if p.disl_phi_deg >= 0 else p.coal_phi_deg))
            row = {"floor": floor, "angle": a}
            for lab, u in (("virgin", m.u), ("excavated", m.u + du)):
                S = cell_stress(m, u)[cells]
                tx = S[:, 0] * n[0] + S[:, 2] * n[1]
                ty = S[:, 2] * n[0] + S[:, 1] * n[1]
                sn, tau = tx * n[0] + ty * n[1], tx * t[0] + ty * t[1]
                cff = np.abs(tau) + (sn + p.gas_pressure) * tp
                row.update({f"sigma_n {lab} MPa": sn.mean() / 1e6, f"|tau| {lab} MPa": np.abs(tau).mean() / 1e6,
                            f"CFF mean {lab} MPa": cff.mean() / 1e6, f"CFF max {lab} MPa": cff.max() / 1e6,
                            f"fraction CFF>0 {lab}": float((cff > 0).mean())})
            rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m studies.mine_bumps", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="one map reading, 2 repetitions, 5 ms ramp + 10 ms (6 runs)")
    ap.add_argument("--legacy", action="store_true", help="the first pass (66 readings, edge-by-edge fault)")
    ap.add_argument("--noise", choices=("dt", "lattice"), default="dt",
                    help="repetitions at 5 time steps over the whole map (dt), or the paper-closest reading with "
                         "the dislocation moved across the lattice (lattice)")
    ap.add_argument("--placement", choices=("near", "far"), default="near",
                    help="the dislocation's placement (far: the line runs toward the rib and cuts the face)")
    for ax_, unit in (("disl_phi_deg", "deg"), ("gas_pressure", "Pa"), ("coal_c", "Pa")):
        ap.add_argument("--" + ax_.replace("_", "-"), type=float, nargs="+", default=None,
                        help=f"only these values of {ax_} [{unit}] (default: the whole map {MAP_AXES[ax_]})")
    ap.add_argument("--out", default="out/mine_bumps")
    ap.add_argument("--scheduler", default=None, help="None (serial), 'local' or a Dask address")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--img", default=None, help="also copy the figures here (e.g. docs/img)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    if a.legacy:
        return main_legacy(a)
    dflt = a.out == "out/mine_bumps"
    out = a.out + ("_lattice" if a.noise == "lattice" and dflt else "") + ("_far" if a.placement == "far" and dflt else "") \
        + ("_quick" if a.quick and dflt else "")
    cli_out_dir(out, cache=False)  # checked before computing (one line and exit 1 otherwise)
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    subset = {k: getattr(a, k) for k in MAP_AXES if getattr(a, k) is not None}
    all_cases = map_cases(a.quick, out, a.noise, a.placement, subset)
    df = run_cases(run_case, all_cases, os.path.join(out, "cases.csv"), scheduler=a.scheduler, workers=a.workers,
                   progress=not a.no_progress)
    wall = time.perf_counter() - t0
    bad = df[df.status != "ok"]
    for _, r in bad.iterrows():
        print("FAILED:", r["case_id"], r["error"])
    mt = map_table(all_cases, df)
    mt.to_csv(os.path.join(out, "verdict.csv"), index=False)
    cols = ["disl_phi_deg", "gas_pressure", "coal_c", "reps"]
    for name in MAP_IND:
        cols += [f"{name} excess 60", f"{name} excess 120", f"{name} diff 120-60", f"{name} MDE"]
    cols += ["residual max [J/m]", "W_top / W_E", "votes", "verdict"]
    show = mt[cols] if len(mt) else mt
    run_s = float(df["wall_time_s"].sum())
    cpu_s = float(df["cpu_time_s"].sum()) if "cpu_time_s" in df else float("nan")
    counts = mt["verdict"].value_counts().to_dict() if len(mt) else {}
    head = (f"{len(df)} runs ({len(bad)} failed), wall {wall:.0f} s (sum of run times {run_s:.0f} s, of their CPU "
            f"times {cpu_s:.0f} s), scheduler "
            f"{a.scheduler or 'serial'} workers {a.workers or '-'}, load average at start {load0[0]:.2f} / end "
            f"{os.getloadavg()[0]:.2f}. Verdicts: {counts}. Votes in the order: {', '.join(MAP_IND)}")
    stat = static_coulomb(map_readings(True)[0] if a.quick else None, ("rock",) if a.quick else ("rock", "rollers"))
    stat.to_csv(os.path.join(out, "static_coulomb.csv"), index=False)
    with open(os.path.join(out, "verdict.md"), "w") as fh:
        fh.write(head + "\n\n" + _md(show) + "\n\nStatic Coulomb check on the true planes (elastic):\n\n"
                 + _md(stat) + "\n")
    print("static Coulomb check on the true planes (elastic, paper-closest map reading):")
    print(_md(stat[["floor", "angle", "CFF mean virgin MPa", "CFF mean excavated MPa", "CFF max excavated MPa",
                    "fraction CFF>0 excavated"]]))
    if len(mt):
        r0 = mt.iloc[0]
        print("fault indicators, first reading (excess over the control, mean +- 2 sigma over the repetitions):")
        for name in MAP_IND:
            print(f"  {name:22s} 60: {r0[f'{name} excess 60']:+.4g} +- {r0[f'{name} excess 60 2sigma']:.2g}   "
                  f"120: {r0[f'{name} excess 120']:+.4g} +- {r0[f'{name} excess 120 2sigma']:.2g}   "
                  f"120-60: {r0[f'{name} diff 120-60']:+.4g} (MDE {r0[f'{name} MDE']:.2g}) -> {r0[f'verdict {name}']}")
    print(head)
    made = map_figures(all_cases, mt, out, a.quick, a.placement)
    if a.img:
        os.makedirs(a.img, exist_ok=True)
        for f in made:
            pre = "mine_map_" + ("far_" if a.placement == "far" else "") + ("lattice_" if a.noise == "lattice" else "")
            shutil.copy(f, os.path.join(a.img, pre + os.path.basename(f)))
    print(f"wrote {out}/cases.csv, verdict.csv, verdict.md, {len(made)} figures ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
