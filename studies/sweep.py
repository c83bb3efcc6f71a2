"""Sweep: coordination from near isostatic to dense, and kt/kn, theory against DEM, with error bars.

    python -m studies.sweep [--quick] [--scheduler local|ADDRESS|serial] [--workers N] [--out DIR]

Packings (seed conditions otherwise: identical disks, mu = 0.488, prepared with kt = kn) span the
coordination number through the preparation friction mu_prep and the pressure p/kn; on each
packing the incremental response is analysed for kt/kn in {0, 0.25, 0.5, 1, 2} (same geometry and
forces, only the contact tangent stiffness changes — the theory's parameter; the DEM reference is
the exact response without pre-stress terms, as in the theory). Each (packing,
kt/kn) is one case, run serially or as a Dask task (``studies.runner``: resumable, failures
recorded). Outputs: ``sweep.csv`` (one row per case), ``summary.csv`` (mean and standard error over
seeds), plots of K, G and their fraction changes against Nc, theory against DEM.
"""
from __future__ import annotations

import argparse
import time

import warnings

import numpy as np
import pandas as pd

from dem.analysis.stiffness import stiffness
from microhom.moduli import PHI_MAX, predict_moduli
from microhom.structural_sums import network_statistics
from studies.cases import DEFAULTS, closure_estimate, get_packing, hierarchy_estimates
from studies.common import cli_out_dir, write_table
from studies.runner import run_cases

KT_RATIOS = (0.0, 0.25, 0.5, 1.0, 2.0)


def sweep_case(case: dict) -> dict:
    """One (packing, kt/kn) case: build/load the packing (kt = kn), analyse with kt = ratio * kn."""
    pack_case = {k: v for k, v in case.items() if k != "kt_ratio"}
    res, t_pack, _ = get_packing(pack_case)
    ratio = float(case["kt_ratio"])
    net = res.to_network().with_stiffness(kt=ratio * 1.0)
    t0 = time.perf_counter()
    st = network_statistics(net).as_dict()   # rho over the N̄ near neighbours (the paper's (39))
    if st["n_rattlers"] == st["n_particles"]:
        raise ValueError(f"no load-bearing backbone at kt/kn = {ratio:g}: every particle is a rattler "
                         f"(Nc with rattlers = {st['nc_all']:.2f}; frictionless disks need Nc > 4)")
    out = {k: st[k] for k in ("nc", "nc_all", "r", "r_all", "rho", "phi", "nbar_phi", "rattler_fraction",
                              "rho_nbar", "rho_note")}
    # N̄ from phi; below pi/4 predict_moduli uses N̄ = 4 and flags it (theory_*_valid), as rho_note says
    base = dict(kn=1.0, kt=ratio, nc=st["nc"], phi=min(st["phi"], PHI_MAX), warn=False)
    for name, kw in (("mf", dict(r=0.0)), ("rho", dict(r=st["r"], rho=st["rho"])),
                     ("alpha", dict(r=st["r"], alpha=1.76))):
        p = predict_moduli(**base, **kw)
        out.update({f"theory_{name}_K": float(p.K), f"theory_{name}_G": float(p.G),
                    f"theory_{name}_valid": bool(p.valid)})
    out["theory_time_s"] = time.perf_counter() - t0
    out.update(closure_estimate(st, ratio, float(case.get("dispersity", DEFAULTS["dispersity"]))))
    out.update(hierarchy_estimates(net, prestress=False))
    t0 = time.perf_counter()
    # The theory has no pre-stress (geometric) terms, so the sweep's DEM reference is the exact
    # response of the contact stiffnesses alone; with pre-stress, a frictional packing re-analysed
    # with kt = 0 can be unstable (negative modes), reported in n_unstable_prestress.
    ex = stiffness(net, prestress=False)
    out.update({"exact_K": ex.K, "exact_G": ex.G, "affine_K": ex.K_affine, "affine_G": ex.G_affine,
                "n_floppy": ex.n_floppy, "exact_time_s": time.perf_counter() - t0, "pack_time_s": t_pack,
                "psi6": float(res.report.get("psi6", np.nan))})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        exp = stiffness(net, prestress=True)
    out.update({"exact_prestress_K": exp.K, "exact_prestress_G": exp.G, "n_unstable_prestress": exp.n_unstable})
    return out


def make_cases(quick: bool, n=None, seeds=None):
    if quick:
        grid = [(0.05, 1e-4), (0.3, 1e-4)]
        n = n or 200
        seeds = seeds or [1, 2]
        ratios = (0.0, 1.0)
    else:
        grid = [(mp, 1e-4) for mp in (0.05, 0.1, 0.2, 0.4, 1.0)] + [(0.05, 1e-3), (0.05, 1e-5)]
        n = n or 1000
        seeds = seeds or [1, 2, 3]
        ratios = KT_RATIOS
    cases = []
    for mp, p in grid:
        for s in seeds:
            for kr in ratios:
                cases.append({**{k: DEFAULTS[k] for k in ("mu", "dispersity", "kt_over_kn")}, "n": n,
                              "p_over_kn": p, "mu_prep": mp, "seed": s, "kt_ratio": kr})
    return cases


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    ok = df[df.status == "ok"]
    keys = ["mu_prep", "p_over_kn", "kt_ratio"]
    cols = ["nc", "r", "rho", "phi", "theory_mf_K", "theory_mf_G", "theory_rho_K", "theory_rho_G",
            "theory_alpha_K", "theory_alpha_G", "exact_K", "exact_G", "affine_K", "affine_G",
            "closure_K", "closure_G", "hier_K", "hier_G", "hier_upper_K", "hier_upper_G"]
    g = ok.groupby(keys)[cols]
    mean = g.mean()
    sem = g.std(ddof=1) / np.sqrt(g.count())
    out = mean.join(sem.add_suffix("_sem")).reset_index()
    out["n_seeds"] = g.count()["nc"].to_numpy()
    for m in ("K", "G"):
        out[f"drop_{m}_dem"] = 1 - out[f"exact_{m}"] / out[f"theory_mf_{m}"]
        out[f"drop_{m}_theory"] = 1 - out[f"theory_rho_{m}"] / out[f"theory_mf_{m}"]
    return out


def errors_table(df: pd.DataFrame, seed: int = 1) -> pd.DataFrame:
    """Errors against the exact response [%] of the seed's formula (measured rho), the closure and
    the hierarchy (upper bound, extrapolated), for one seed's frictional cases (docs/results/sweep.md)."""
    ok = df[(df.status == "ok") & (df.seed == seed) & (df.kt_ratio > 0)].sort_values(["mu_prep", "p_over_kn", "kt_ratio"])
    out = pd.DataFrame({"mu_prep": ok.mu_prep, "p/kn": ok.p_over_kn, "kt/kn": ok.kt_ratio, "Z": ok.nc.round(2)})
    for m in ("K", "G"):
        for label, col in (("seed", "theory_rho"), ("closure", "closure"), ("hier up 8", "hier_upper"),
                           ("hier ext 8", "hier")):
            out[f"{m} {label} [%]"] = (100 * (ok[f"{col}_{m}"] / ok[f"exact_{m}"] - 1)).round(2)
    out["closure valid"] = ok.closure_valid.astype(bool)
    return out.reset_index(drop=True)


def plot(summary: pd.DataFrame, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    for kr, g in summary.groupby("kt_ratio"):
        g = g.sort_values("nc")
        for j, m in enumerate(("K", "G")):
            ax = axes[0, j]
            line = ax.errorbar(g.nc, g[f"exact_{m}"], yerr=g[f"exact_{m}_sem"], fmt="o-", ms=4,
                               label=f"DEM exact, kt/kn = {kr:g}")
            c = line[0].get_color()
            ax.plot(g.nc, g[f"theory_mf_{m}"], "--", color=c, lw=1)
            ax.plot(g.nc, g[f"theory_rho_{m}"], ":", color=c, lw=1.5)
            ax.plot(g.nc, g[f"closure_{m}"], "-.", color=c, lw=1)
            ax.plot(g.nc, g[f"hier_{m}"], "s", color=c, ms=3, mfc="none")
            ax.set_xlabel("Nc (rattlers excluded)")
            ax.set_ylabel(f"{m} / kn")
            ax2 = axes[1, j]
            ax2.plot(g.nc, g[f"drop_{m}_dem"], "o-", color=c, ms=4, label=f"DEM, kt/kn = {kr:g}")
            ax2.plot(g.nc, g[f"drop_{m}_theory"], "x:", color=c)
            ax2.set_xlabel("Nc (rattlers excluded)")
            ax2.set_ylabel(f"fraction change of {m} (1 - value / mean field)")
    axes[0, 0].legend(fontsize=7, title="solid: DEM, dashed: mean field, dotted: seed corrected (measured rho), "
                      "dash-dot: closure, squares: hierarchy 16 steps",
                      title_fontsize=7)
    axes[1, 0].legend(fontsize=7, title="o: DEM, x: theory (measured rho)", title_fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a few small cases, serial (for CI)")
    ap.add_argument("--n", type=int, default=None, help="disks per packing (default 1000; quick 200)")
    ap.add_argument("--seeds", type=int, nargs="+", default=None)
    ap.add_argument("--scheduler", default=None,
                    help="'local' (LocalCluster sized to the machine), a Dask scheduler address, or 'serial'; "
                         "default: local if dask.distributed is installed (serial with --quick)")
    ap.add_argument("--workers", type=int, default=None, help="workers of the local cluster")
    ap.add_argument("--out", default="out/sweep")
    args = ap.parse_args(argv)
    out = cli_out_dir(args.out)  # checked before computing (one line and exit 1 otherwise)
    sched = args.scheduler
    if sched is None:
        try:
            import dask.distributed  # noqa: F401
            sched = "serial" if args.quick else "local"
        except ImportError:
            sched = "serial"
    cases = make_cases(args.quick, args.n, args.seeds)
    t0 = time.perf_counter()
    df = run_cases(sweep_case, cases, out / "sweep.csv", scheduler=None if sched == "serial" else sched,
                   workers=args.workers)
    wall = time.perf_counter() - t0
    n_err = int((df.status != "ok").sum())
    summary = summarise(df)
    show = summary[["mu_prep", "p_over_kn", "kt_ratio", "n_seeds", "nc", "r", "rho", "exact_K", "exact_K_sem",
                    "theory_rho_K", "closure_K", "hier_K", "exact_G", "exact_G_sem", "theory_rho_G", "closure_G",
                    "hier_G", "drop_G_dem", "drop_G_theory"]]
    pd.set_option("display.width", 220)
    print(show.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    md = write_table(show, out, "summary", "Sweep: theory (measured rho) against DEM exact",
                     f"{len(df)} cases ({n_err} failed, see sweep.csv), scheduler {sched}, wall {wall:.0f} s. "
                     "Means over seeds with standard errors (_sem).")
    summary.to_csv(out / "summary.csv", index=False)   # after write_table, which writes the shown columns
    if (df.status == "ok").any() and 1 in set(df.seed):
        write_table(errors_table(df), out, "errors_seed1", "Errors against the exact response [%], seed 1")
    plot(summary, out / "sweep.png")
    print(f"written: {md}, {out / 'sweep.csv'}, {out / 'sweep.png'}; {n_err} failed cases; wall {wall:.0f} s")


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
