"""Burst study of the free-hexagon mine scene: 60 vs 120 deg dislocations, one to three of them,
ramp time (excavation speed), gas on/off, plus the mirror-image check.

    python -m studies.mine_bumps --quick        # CI, < 2 min
    python -m studies.mine_bumps                # full matrix (ramp + 100 ms each)

Writes out/mine_bumps/{table.csv, table.md, reading.md, *.png}. Units SI per m of thickness.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np
import pandas as pd

from dem.hexmine import MineParams, run_scene
from dem.hexmine.outputs import plot_series, plot_state

COLS = ["peak_Ek_J_per_m", "peak_Ek_coal_J_per_m", "peak_Ek_free_J_per_m", "released_WE_J_per_m",
        "kinetic_fraction", "ejected_mass_kg_per_m", "ejected_vmax_m_s", "ejected_vmean_m_s",
        "n_tension", "n_shear", "n_broken_disl", "damage_width_m", "syy_peak_MPa", "syy_peak_dist_m",
        "energy_residual_rel", "contact_damping", "D_dash_over_W_ext", "contact_max_overlap_rel",
        "max_rot_broken_deg", "closed_max_slip_over_L", "dt_s", "steps", "wall_time_s"]


def cases(quick: bool):
    dur = 0.03 if quick else 0.1
    out = []
    ramps = [("instant", 0.0), ("linear", 0.01)] if quick else \
        [("instant", 0.0), ("linear", 0.002), ("linear", 0.01), ("linear", 0.05)]
    ndis = [1] if quick else [1, 2, 3]
    gases = [True] if quick else [True, False]
    out.append(("control (no dislocation)", dict(n_disl=0, ramp="linear", ramp_time=0.01, duration=dur)))
    for n in ndis:
        for ang in (60.0, 120.0):
            for rk, rt in ramps:
                for gas in gases:
                    lab = f"{int(ang)}deg n={n} {rk}{'' if rk == 'instant' else f' {rt * 1e3:g}ms'} gas={'on' if gas else 'off'}"
                    out.append((lab, dict(disl_angle_deg=ang, n_disl=n, ramp=rk, ramp_time=rt, gas=gas,
                                          duration=dur)))
    # D7 variant: contact dashpot (ratio 0.1) on cracked closed interfaces and new contacts
    for ang in (60.0, 120.0):
        for rk, rt in (("linear", 0.01), ("instant", 0.0)):
            lab = f"D7 dashpot 0.1: {int(ang)}deg n=1 {rk}{'' if rk == 'instant' else f' {rt * 1e3:g}ms'} gas=on"
            out.append((lab, dict(disl_angle_deg=ang, n_disl=1, ramp=rk, ramp_time=rt, gas=True, duration=dur,
                                  contact_damping=0.1)))
    # mirror-image check: symmetric geometry (seam centred, rollers top and bottom, no loading layer)
    sym = dict(seam_bottom=2.375, seam_top=7.125, top_bc="roller", elastic_layer=0.0, ramp="linear",
               ramp_time=0.01, duration=dur)
    for ang in (60.0, 120.0):
        out.append((f"MIRROR symmetric {int(ang)}deg", dict(sym, disl_angle_deg=ang)))
    # split the asymmetry: seam on the floor but rollers top and bottom (no traction top, no layer)
    half = dict(top_bc="roller", elastic_layer=0.0, ramp="linear", ramp_time=0.01, duration=dur)
    for ang in (60.0, 120.0):
        out.append((f"MIRROR floor-seam rollers {int(ang)}deg", dict(half, disl_angle_deg=ang)))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m studies.mine_bumps")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default="out/mine_bumps")
    ap.add_argument("--img", default=None, help="also copy the key pictures here (e.g. docs/img)")
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    rows = []
    t0 = time.perf_counter()
    keep = {}
    for lab, kw in cases(a.quick):
        r = run_scene(MineParams(**kw))
        row = {"case": lab, **{k: r.indicators[k] for k in COLS}, "stopped": r.indicators["stopped"]}
        rows.append(row)
        keep[lab] = r
        print(f"{lab:45s} peakEk={row['peak_Ek_J_per_m'] / 1e3:8.1f} kJ/m  coalEk={row['peak_Ek_coal_J_per_m'] / 1e3:7.1f}"
              f"  ejected={row['ejected_mass_kg_per_m']:8.0f} kg/m vmax={row['ejected_vmax_m_s']:5.2f}"
              f"  broken t/s={row['n_tension']}/{row['n_shear']}  res={row['energy_residual_rel']:.1e}"
              f"  {row['wall_time_s']:.1f}s", flush=True)
    df = pd.DataFrame(rows)
    df.to_csv(os.path.join(a.out, "table.csv"), index=False)
    show = df[["case", "peak_Ek_J_per_m", "peak_Ek_coal_J_per_m", "peak_Ek_free_J_per_m", "ejected_mass_kg_per_m",
               "ejected_vmax_m_s", "n_tension", "n_shear", "n_broken_disl", "damage_width_m", "syy_peak_MPa",
               "syy_peak_dist_m", "energy_residual_rel", "D_dash_over_W_ext", "max_rot_broken_deg",
               "closed_max_slip_over_L", "wall_time_s"]].copy()
    for c in ("peak_Ek_J_per_m", "peak_Ek_coal_J_per_m", "peak_Ek_free_J_per_m"):
        show[c] = show[c] / 1e3
    show = show.rename(columns={"peak_Ek_J_per_m": "peak Ek kJ/m", "peak_Ek_coal_J_per_m": "peak Ek coal kJ/m",
                                "peak_Ek_free_J_per_m": "peak Ek free kJ/m", "ejected_mass_kg_per_m": "ejected kg/m",
                                "ejected_vmax_m_s": "v max m/s", "n_broken_disl": "disl broken",
                                "damage_width_m": "damage width m", "syy_peak_MPa": "syy peak MPa",
                                "syy_peak_dist_m": "peak dist m", "energy_residual_rel": "energy res",
                                "D_dash_over_W_ext": "D_dash/W", "max_rot_broken_deg": "max rot deg",
                                "closed_max_slip_over_L": "closed slip/L",
                                "wall_time_s": "run s"})
    md = show.to_markdown(index=False, floatfmt=".3g") if _has_tabulate() else show.to_string(index=False)
    with open(os.path.join(a.out, "table.md"), "w") as fh:
        fh.write(md + "\n")
    # reading
    def val(lab, k):
        return float(df.loc[df.case == lab, k].iloc[0])
    lines = ["# Reading of the mine-bump study", ""]
    dur = "30 ms" if a.quick else "100 ms"
    lines.append(f"Runs: {len(df)}, total wall time {time.perf_counter() - t0:.1f} s, dynamics {dur} after the ramp.")
    base = [c for c in df.case if c.startswith("60deg n=1") and "10ms" in c and "gas=on" in c]
    if base:
        b60 = base[0]
        b120 = b60.replace("60deg", "120deg")
        lines.append("")
        lines.append("| indicator | 60 deg | 120 deg | ratio 120/60 |")
        lines.append("|---|---|---|---|")
        for k in ("peak_Ek_coal_J_per_m", "peak_Ek_free_J_per_m", "ejected_mass_kg_per_m", "ejected_vmax_m_s",
                  "n_tension", "n_shear", "n_broken_disl"):
            x, y = val(b60, k), val(b120, k)
            lines.append(f"| {k} | {x:.4g} | {y:.4g} | {y / x if x else float('nan'):.3g} |")
    for pre in ("MIRROR symmetric", "MIRROR floor-seam rollers"):
        l60, l120 = f"{pre} 60deg", f"{pre} 120deg"
        if l60 in set(df.case):
            e60 = keep[l60].series["Ek"]
            e120 = keep[l120].series["Ek"]
            n = min(len(e60), len(e120))
            rel = np.abs(e60[:n] - e120[:n]).max() / max(np.abs(e60[:n]).max(), 1e-30)
            lines.append("")
            lines.append(f"{pre}: max |Ek60 - Ek120| / max Ek = {rel:.2e}; ejected mass 60/120 = "
                         f"{val(l60, 'ejected_mass_kg_per_m'):.4g}/{val(l120, 'ejected_mass_kg_per_m'):.4g} kg/m; "
                         f"broken shear 60/120 = {val(l60, 'n_shear'):.0f}/{val(l120, 'n_shear'):.0f}")
    with open(os.path.join(a.out, "reading.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    # pictures
    pics = [c for c in keep if c.startswith(("control", "MIRROR"))
            or (c.startswith(("60deg n=1", "120deg n=1")) and ("10ms" in c or "instant" in c))]
    for lab in pics:
        slug = lab.replace(" ", "_").replace("(", "").replace(")", "").replace("=", "").replace("/", "")
        plot_state(keep[lab].scene, os.path.join(a.out, f"state_{slug}.png"), title=lab)
        plot_series(keep[lab].series, os.path.join(a.out, f"series_{slug}.png"), title=lab)
    if a.img:
        import shutil
        os.makedirs(a.img, exist_ok=True)
        for f in os.listdir(a.out):
            if f.endswith(".png") and ("n1_linear_10ms_gason" in f or "control" in f or "MIRROR" in f):
                shutil.copy(os.path.join(a.out, f), os.path.join(a.img, "mine_" + f))
    print(f"wrote {a.out}/table.csv, table.md, reading.md ({time.perf_counter() - t0:.1f} s)")
    return 0


def _has_tabulate():
    try:
        import tabulate  # noqa: F401
        return True
    except ImportError:
        return False


if __name__ == "__main__":
    raise SystemExit(main())
