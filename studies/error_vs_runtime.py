"""Error against wall time for every way of getting the moduli: the figure to choose a method by.

    python -m studies.error_vs_runtime [--quick] [--out DIR]
    python -m studies.error_vs_runtime --replot docs/results/error_vs_runtime.md docs/img/error_vs_runtime.png

Reference: the exact linear response (pre-stress included) of a packing of ``N_ref`` disks in
the seed's conditions. On that same packing, the whole ladder of estimates:

* theory, mean field and corrected (measured rho), from the measured statistics;
* the statistics-only closure (``microhom.closure``), with its stated error;
* the DEM affine tensor (structural sum of the network);
* the relaxation hierarchy (``microhom.hierarchy``): first order (single-particle relaxation) and
  orders 1, 2, 4, 8, 16, 32 CG steps with both preconditioners (multilevel, the default, and the
  particle-block "k shells" ladder), each with its upper bound and its extrapolated value with
  the stated error (open markers in the plot);
* strain probes with amplitudes 1e-8 .. 1e-5 and relaxation tolerances 1e-4 .. 1e-8 (longer
  probes relax further);

and, on separate packings of increasing N, the exact solve (finite-size and sample error). The
column ``measured_against`` says what each row's error is measured against: ``"same packing"``
(a method's own error on the reference packing) or ``"other packing"`` (the exact solve of a
different, smaller packing: its "error" is the finite-size and sample difference between two
packings, not an error of the method; the plot draws these apart, grey, outside the ladder). Each
row has the method's own wall time and the time including the packing it needs (the theory needs
the measured statistics of a packing too, unless they are known). Writes a table (CSV, markdown)
and a log-log plot. ``--replot MD PNG`` redraws the plot from the table recorded on the results
page ``MD`` (:func:`read_table`), without running anything.
"""
from __future__ import annotations

import argparse
import re
import time

import numpy as np
import pandas as pd

from dem.engine.probes import strain_probes
from dem.analysis.stiffness import stiffness
from microhom.closure import closure_inputs, predict_closure
from microhom.hierarchy import relaxation_hierarchy
from microhom.moduli import predict_moduli
from microhom.structural_sums import network_statistics
from studies.cases import DEFAULTS, get_packing
from studies.common import cli_out_dir, write_table


def _row(method, param, K, G, ref, t_method, t_pack, against="same packing", **extra):
    return {"method": method, "parameter": param, "measured_against": against, "K": K, "G": G,
            "err_K": abs(K / ref.K - 1), "err_G": abs(G / ref.G - 1),
            "time_s": t_method, "time_with_packing_s": t_method + t_pack, **extra}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes, for CI")
    ap.add_argument("--n-ref", type=int, default=None, help="reference packing size (default 2000; quick 300)")
    ap.add_argument("--out", default="out/error_vs_runtime")
    ap.add_argument("--replot", nargs=2, metavar=("MD", "PNG"), default=None,
                    help="redraw the figure PNG from the recorded table of the markdown page MD (no run)")
    args = ap.parse_args(argv)
    if args.replot:
        df = read_table(args.replot[0])
        _plot(df, args.replot[1])
        print(f"redrawn from {args.replot[0]} ({len(df)} rows): {args.replot[1]}")
        return 0
    n_ref = args.n_ref or (300 if args.quick else 2000)
    sizes = [100, 200] if args.quick else [250, 500, 1000]
    out = cli_out_dir(args.out)  # checked before computing (one line and exit 1 otherwise)

    case = {**DEFAULTS, "n": n_ref, "seed": 1}
    res, t_pack, _ = get_packing(case)
    net = res.to_network()
    t0 = time.perf_counter()
    ref = stiffness(net, prestress=True)
    t_ref = time.perf_counter() - t0
    rows = [_row("exact linear response", f"N = {n_ref} (reference)", ref.K, ref.G, ref, t_ref, t_pack)]

    t0 = time.perf_counter()
    st = network_statistics(net).as_dict()
    t_stats = time.perf_counter() - t0
    for label, kw in (("theory: mean field", dict(r=0.0)),
                      ("theory: corrected, measured rho", dict(r=st["r"], rho=st["rho"])),
                      ("theory: corrected, alpha = 1.76", dict(r=st["r"], alpha=1.76))):
        t0 = time.perf_counter()
        p = predict_moduli(1.0, 1.0, st["nc"], st["phi"], nbar=st["nbar_phi"], warn=False, **kw)
        dt = time.perf_counter() - t0 + t_stats
        rows.append(_row(label, "measured Nc, r, phi", float(p.K), float(p.G), ref, dt, t_pack))
    t0 = time.perf_counter()
    cl = predict_closure(**closure_inputs(net, kt_over_kn=case["kt_over_kn"]))
    rows.append(_row("closure (statistics only)", "measured Z, r, phi, kt/kn, rattlers, sizes, p", float(cl.K), float(cl.G), ref,
                     time.perf_counter() - t0 + t_stats, t_pack, stated_err_K=float(cl.error_K) / ref.K,
                     stated_err_G=float(cl.error_G) / ref.G))
    rows.append(_row("DEM affine tensor", f"N = {n_ref}", ref.K_affine, ref.G_affine, ref,
                     ref.assembly_time, t_pack))
    for prec, name in (("amg", "hierarchy (multilevel)"), ("block", "hierarchy (k shells)")):
        for k in ([1, 2, 4, 8, 16] if args.quick else [1, 2, 4, 8, 16, 24, 32]):
            t0 = time.perf_counter()
            h = relaxation_hierarchy(net, prestress=True, tol=1e-12, max_order=k, spectral_bound="none",
                                     preconditioner=prec)
            dt = time.perf_counter() - t0
            if k == 1 and prec == "block":
                rows.append(_row("hierarchy: first order", "single-particle relaxation", h.K_first_order,
                                 h.G_first_order, ref, dt, t_pack))
            rows.append(_row(f"{name}: upper bound", f"{k} CG steps ({2 * k} moments)", h.K.upper, h.G.upper,
                             ref, dt, t_pack))
            if np.isfinite(h.K.error) and np.isfinite(h.G.error):
                rows.append(_row(f"{name}: extrapolated", f"{k} CG steps ({2 * k} moments)", h.K.value,
                                 h.G.value, ref, dt, t_pack, stated_err_K=h.K.error / ref.K,
                                 stated_err_G=h.G.error / ref.G))
            if h.order < k:                                   # converged before k steps: nothing new after
                break

    amps = [1e-8, 1e-6, 1e-5] if args.quick else [1e-8, 1e-7, 1e-6, 1e-5]
    tols = [1e-4, 1e-6, 1e-8] if args.quick else [1e-4, 1e-5, 1e-6, 1e-7, 1e-8]
    for amp in amps:
        for tol in (tols if amp == 1e-8 else [1e-8]):
            pr = strain_probes(res.state, res.law, amplitude=amp, tol_unbalanced=tol)
            rows.append(_row("strain probes", f"amplitude {amp:g}, tol {tol:g}", pr.K, pr.G, ref, pr.wall_time,
                             t_pack, steps=pr.steps, contact_events=pr.contact_events))
            print(f"probe amplitude {amp:g} tol {tol:g}: {pr.steps} steps, {pr.wall_time:.2f} s, "
                  f"err K {abs(pr.K / ref.K - 1):.2e}, G {abs(pr.G / ref.G - 1):.2e}, events {pr.contact_events}",
                  flush=True)

    for n in sizes:
        r2, tp2, _ = get_packing({**DEFAULTS, "n": n, "seed": 1})
        t0 = time.perf_counter()
        e2 = stiffness(r2.to_network(), prestress=True)
        rows.append(_row("exact linear response", f"N = {n}", e2.K, e2.G, ref, time.perf_counter() - t0, tp2,
                         against="other packing"))
        print(f"exact N = {n}: K {e2.K:.4f}, G {e2.G:.4f} (reference {ref.K:.4f}, {ref.G:.4f}); packing {tp2:.1f} s",
              flush=True)

    df = pd.DataFrame(rows)
    pd.set_option("display.width", 200)
    print(df.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    md = write_table(df, out, "error_vs_runtime", "Error against run time",
                     f"Reference: exact linear response of a {n_ref}-disk packing (seed conditions, p/kn = 1e-4, "
                     f"kt = kn, mu = 0.488, mu_prep = {DEFAULTS['mu_prep']}); its packing took {t_pack:.1f} s. "
                     "Errors are relative to the reference. Rows measured against the 'same packing' are "
                     "the methods' own errors on the reference packing; the 'other packing' rows are exact "
                     "solves of smaller packings, whose difference from the reference is finite-size and "
                     "sample (seed) variation, not an error of the exact solve.")
    _plot(df, out / "error_vs_runtime.png")
    print(f"written: {md}, {out / 'error_vs_runtime.png'}")


#: the columns of the recorded table (docs/results/error_vs_runtime.md), in its order
TABLE_COLUMNS = ("method", "parameter", "K", "G", "err_K", "err_G", "time_s", "time_with_packing_s",
                 "stated_err_K", "stated_err_G", "steps", "contact_events")


def read_table(md_path) -> pd.DataFrame:
    """The recorded table of a results page (the first markdown table whose header is
    ``TABLE_COLUMNS``) as the frame :func:`_plot` draws: numbers parsed ("nan" as NaN), and
    ``measured_against`` restored ("other packing" for the exact solves of other packings, the
    rows ``exact linear response`` / ``N = n`` without "(reference)"; else "same packing").
    Raises ``ValueError`` if the page has no such table."""
    lines = open(md_path, encoding="utf-8").read().splitlines()
    head = "| " + " | ".join(TABLE_COLUMNS) + " |"
    try:
        i = next(k for k, ln in enumerate(lines) if ln.strip() == head)
    except StopIteration:
        raise ValueError(f"{md_path}: no table with the columns {', '.join(TABLE_COLUMNS)}") from None
    rows = []
    for ln in lines[i + 2:]:
        if not ln.startswith("|"):
            break
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        if len(cells) != len(TABLE_COLUMNS):
            raise ValueError(f"{md_path}: a row of {len(cells)} cells, expected {len(TABLE_COLUMNS)}: {ln}")
        rows.append(cells)
    df = pd.DataFrame(rows, columns=list(TABLE_COLUMNS))
    for c in TABLE_COLUMNS[2:]:
        df[c] = df[c].astype(float)
    other = (df.method == "exact linear response") & ~df.parameter.str.contains("reference")
    df.insert(2, "measured_against", np.where(other, "other packing", "same packing"))
    return df


def _plot(df, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(15, 5.2))
    markers = {"theory": "o", "closure": "P", "DEM affine": "s", "hierarchy: first": "v",
               "hierarchy (multilevel): upper": "1", "hierarchy (multilevel): extra": "*",
               "hierarchy (k shells): upper": "2", "hierarchy (k shells): extra": "X",
               "strain probes": "^", "exact": "D"}
    df = df[~df["parameter"].astype(str).str.contains("reference")]  # its error is 0 by definition
    other = df[df["measured_against"] == "other packing"]
    df = df[df["measured_against"] == "same packing"]
    for ax, key in zip(axes, ("err_G", "err_K")):
        stated = "stated_" + key
        if len(other):   # not a method error: another packing's finite-size and sample difference
            ax.loglog(other["time_s"], np.maximum(other[key].to_numpy(), 1e-12), "D", color="0.6",
                      mfc="none", ms=8, label="exact solve of other, smaller packings (N = "
                      + ", ".join(str(p).split("= ")[-1] for p in other["parameter"])
                      + "):\nfinite-size + sample difference, not a method error")
        for method, g in df.groupby("method", sort=False):
            mk = next((v for k, v in markers.items() if method.startswith(k)), "x")
            err = np.maximum(g[key].to_numpy(), 1e-12)
            name = re.sub(r";[^)]*\)", ")", method)   # the legend without the row's notes
            line = ax.loglog(g["time_s"], err, mk, label=name, ms=7, alpha=0.8)
            if stated in g and g[stated].notna().any():   # the method's own error claim, open marker
                ax.loglog(g["time_s"], g[stated], mk, mfc="none", color=line[0].get_color(), ms=11,
                          label=f"{name}: stated error")
        # the ladder as one curve: best error reached so far against time (same packing only)
        lad = df.sort_values("time_s")
        ax.loglog(lad["time_s"], np.minimum.accumulate(np.maximum(lad[key].to_numpy(), 1e-12)), "k-",
                  lw=0.8, alpha=0.5, label="ladder (best so far)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time of the method [s] (packing not included)")
        ax.set_ylabel(f"|{'G' if key == 'err_G' else 'K'} / {'G' if key == 'err_G' else 'K'}_exact(N_ref) - 1|")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_title("G" if key == "err_G" else "K", fontsize=10)
    fig.suptitle("Every point is measured against the exact solve of the reference packing (N_ref): "
                 "the methods on that same packing (their own error),\nand in grey the exact solves "
                 "of other, smaller packings (their finite-size and sample difference)", fontsize=9)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center right", fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0, 0.74, 0.9))
    fig.savefig(path, dpi=130)
    plt.close(fig)


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
