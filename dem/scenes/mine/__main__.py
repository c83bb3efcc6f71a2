"""python -m dem.scenes.mine [--config scene.toml] [--set key=value ...] [--out DIR] [--resume]"""
from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import fields

from .outputs import plot_profile, plot_series, plot_state, write_vtk
from .params import MineParams, load_toml
from .runner import run_scene


def _coerce(name, text):
    typ = {f.name: f.type for f in fields(MineParams)}[name]
    if typ in ("bool", bool):
        return text.lower() in ("1", "true", "yes", "on")
    if typ in ("int", int):
        return int(text)
    if typ in ("float", float):
        return float(text)
    return text


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m dem.scenes.mine", description=__doc__)
    ap.add_argument("--config", help="TOML file with MineParams fields (SI units)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--out", default="out/mine")
    ap.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.npz")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    p = load_toml(a.config) if a.config else MineParams()
    names = {f.name for f in fields(MineParams)}
    kw = {}
    for item in a.set:
        k, _, v = item.partition("=")
        if k not in names:
            ap.error(f"unknown parameter {k!r}")
        kw[k] = _coerce(k, v)
    try:
        p = p.replace(**kw).validate()
    except ValueError as exc:
        ap.error(str(exc))
    res = run_scene(p, out_dir=a.out, progress=not a.no_progress, resume=a.resume)
    os.makedirs(a.out, exist_ok=True)
    plot_state(res.scene, os.path.join(a.out, "state.png"))
    plot_series(res.series, os.path.join(a.out, "series.png"))
    plot_profile(res.scene, os.path.join(a.out, "profile.png"))
    write_vtk(res.scene, os.path.join(a.out, "state.vtk"))
    out = {"indicators": res.indicators.as_dict(), "dt": res.dt, "dt_gershgorin": res.dt_gershgorin,
           "timings": res.timings, "info": res.scene.info, "E_eff": res.scene.E_eff}
    with open(os.path.join(a.out, "summary.json"), "w") as fh:
        json.dump(out, fh, indent=1, default=float)
    print(json.dumps(out, indent=1, default=float))
    print(res.report)
    if res.stopped:
        print("STOPPED:", res.stopped, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
