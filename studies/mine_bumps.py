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

from dem.scenes.mine import MineParams, block_labels, block_indicators, block_names, resolve, run_scene
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


def _params(reading, angle=60.0, n=0, duration=0.1, placement=None):
    r = dict(reading)
    if placement:
        r["placement"] = placement
    return MineParams(**r, disl_angle_deg=angle, n_disl=n, duration=duration)


def _flat_blocks(prefix, blocks):
    return {f"b.{prefix}.{b.name}.{k}": v for b in blocks for k, v in b.as_dict().items() if k != "name"}


def run_case(case: dict) -> dict:
    """One run of the study (Dask task): a 60/120 case or a control evaluated on every partition it
    is compared with. Saves the final-state snapshot and the seam profiles to out/states/<id>.npz."""
    r = case["reading"]
    if case["role"] == "case":
        p = _params(r, case["angle"], case["n_disl"], case["duration"])
    else:
        p = _params(r, duration=case["duration"])
    res = run_scene(p)
    ind = res.indicators
    row = {k: v for k, v in ind.as_dict().items() if k not in ("blocks",)}
    if case["role"] == "case":
        row.update(_flat_blocks(_key(r["placement"], case["angle"], case["n_disl"]), ind.blocks))
    else:
        m = res.scene.model
        for pl, a, n in case["partitions"]:
            g = resolve(_params(r, a, n, placement=pl))
            lab = block_labels(g, m.centres, m.is_coal)
            row.update(_flat_blocks(_key(pl, a, n), block_indicators(res.scene, res.series, lab, block_names(n))))
    sd = os.path.join(case["out"], "states")
    os.makedirs(sd, exist_ok=True)
    pr = ind.profile
    np.savez_compressed(os.path.join(sd, case_id(case) + ".npz"), **snapshot(res.scene), prof_dist=pr.dist_m,
                        prof_g=pr.g, prof_syy=pr.syy_Pa, Ek_t=res.series["t"], Ek=res.series["Ek"])
    return row


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


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m studies.mine_bumps", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="base reading only, 5 ms ramp + 10 ms (3 runs)")
    ap.add_argument("--out", default="out/mine_bumps")
    ap.add_argument("--scheduler", default=None, help="None (serial), 'local' or a Dask address")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--img", default=None, help="also copy the figures here (e.g. docs/img)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    out = a.out + ("_quick" if a.quick and a.out == "out/mine_bumps" else "")
    cli_out_dir(out, cache=False)  # checked before computing (one line and exit 1 otherwise)
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
    head = (f"{len(df)} runs ({len(bad)} failed), wall {wall:.0f} s (sum of run times {run_s:.0f} s), scheduler "
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


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
