"""rho = Nc sum V.W / sum V^2 under each definition of V, beside its null model (issue 16).

    python -m studies.rho_definitions [--quick] [--n 3000] [--seeds 1 2 3] [--null 20] [--out DIR]

The seed paper's V^mu (41) sums the neighbours' own contact numbers Nc^nu over the neighbourhood
of (39): the N̄ near neighbours of mu, touching it or not. Three neighbourhoods are measured on
DEM packings in the seed's conditions (``studies.cases.DEFAULTS``: identical disks, kt = kn,
mu = tan 26 deg, p/kn = 1e-4):

* ``contacts``: mu's contacting neighbours only (the definition used before issue 16);
* ``near``: the paper's N̄ near neighbours, N̄ from phi (``microhom.neighbourhood.near_neighbours``);
* ``delaunay``: all Delaunay neighbours (mean 6, periodic images; ``dem.analysis.measure``).

For each, the null model permutes the contact numbers Nc^nu among the non-rattlers at random
(geometry, W and the neighbourhood kept) ``--null`` times: the rho the definition gives when the
neighbours' contact numbers carry no correlation with mu. ``rho - null`` is the correlation part.
"""
from __future__ import annotations

import argparse
import os
import time

import pandas as pd

from dem.analysis.measure import delaunay_neighbours
from microhom.moduli import predict_moduli
from microhom.structural_sums import rho_definitions
from studies.cases import DEFAULTS, get_packing
from studies.common import markdown_table, out_dir, write_table

LABELS = {"contacts": "contacting neighbours (before issue 16)", "near": "N̄ near neighbours (paper, (39))",
          "delaunay": "Delaunay neighbours (mean 6)"}


def measure(net, n_null=20, seed=0) -> dict:
    """One packing: a flat dict rho_<name>, null_<name>, null_std_<name>, degree_<name>, nc, r, nbar."""
    dl = delaunay_neighbours(net)
    res = rho_definitions(net, extra={"delaunay": (dl.pairs, dl.branch)}, n_null=n_null, seed=seed)
    row = {"nc": res.nc, "r": res.r, "nbar": res.nbar}
    for name in res.rho:
        row[f"rho_{name}"] = res.rho[name]
        row[f"null_{name}"] = res.null_mean[name]
        row[f"null_std_{name}"] = res.null_std[name]
        row[f"degree_{name}"] = res.mean_degree[name]
    return row


def side_by_side(df: pd.DataFrame) -> pd.DataFrame:
    """Mean over packings, one row per definition: rho, null baseline, correlation part, share, and
    the fraction changes the theory predicts with that rho at the packings' mean Nc, r, phi, N̄ (kt = kn)."""
    rows = []
    m = df.mean(numeric_only=True)
    for name, label in LABELS.items():
        if f"rho_{name}" not in df:
            continue
        rho, null = df[f"rho_{name}"].mean(), df[f"null_{name}"].mean()
        rows.append({"V summed over": label, "neighbours per particle": df[f"degree_{name}"].mean(),
                     "rho measured": rho, "rho spread (packings)": df[f"rho_{name}"].std(ddof=1) if len(df) > 1 else 0.0,
                     "null model (shuffled Nc)": null, "null spread (shuffles)": df[f"null_std_{name}"].mean(),
                     "correlation part rho - null": rho - null,
                     "share from the definition null/rho": null / rho if rho else float("nan")})
        p = predict_moduli(1.0, 1.0, m["nc"], m["phi"], m["r"], rho=rho, nbar=m["nbar"], warn=False)
        rows[-1].update({"theory drop K": float(p.drop_K), "theory drop G": float(p.drop_G)})
    return pd.DataFrame(rows)


PSI6_MAX = 0.5  # as studies.kuhn: a packing with psi6 above is a polycrystal, excluded from the means


def report(n, seeds, mu_prep=DEFAULTS["mu_prep"], out="out/rho", n_null=20) -> pd.DataFrame:
    """Measure every packing (built or taken from the cache), print and write the side-by-side table.

    Returns the table (one row per definition of V). ``studies.kuhn`` calls this on its packings.
    """
    out = out_dir(out)
    rows = []
    for seed in seeds:
        case = {**DEFAULTS, "n": n, "seed": seed, "mu_prep": mu_prep}
        res, t_pack, built = get_packing(case)
        net = res.to_network()
        t0 = time.perf_counter()
        row = {"seed": seed, "n": n, "phi": net.solid_fraction, "psi6": float(res.report.get("psi6", float("nan"))),
               **measure(net, n_null=n_null, seed=seed)}
        row["measure_s"] = time.perf_counter() - t0
        rows.append(row)
        print(f"seed {seed}: N = {n}, phi = {row['phi']:.4f}, psi6 = {row['psi6']:.3f}, Nbar(phi) = {row['nbar']:.3f}, "
              f"Nc = {row['nc']:.3f}, r = {row['r']:.3f}; rho contacts {row['rho_contacts']:.3f} "
              f"(null {row['null_contacts']:.3f}), near {row['rho_near']:.3f} (null {row['null_near']:.3f}), "
              f"delaunay {row['rho_delaunay']:.3f} (null {row['null_delaunay']:.3f}); packing "
              f"{'built' if built else 'from the cache'} ({t_pack:.1f} s to build), "
              f"measured {row['measure_s']:.1f} s", flush=True)
    df = pd.DataFrame(rows)
    df.to_csv(out / "cases.csv", index=False)
    amorphous = df[~(df.psi6 > PSI6_MAX)]
    excluded = f"{len(df) - len(amorphous)} of {len(df)} packings excluded as crystalline (psi6 > {PSI6_MAX})"
    if amorphous.empty:
        raise SystemExit("every packing crystallised: raise --mu-prep or add seeds")
    table = side_by_side(amorphous)
    pd.set_option("display.width", 220)
    print(f"\nrho = Nc sum V.W / sum V^2 (non-rattlers), mean over packings ({excluded}):")
    print(table.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    notes = (f"Packings: N = {n}, seeds {list(seeds)}, p/kn = {DEFAULTS['p_over_kn']}, kt = kn, mu = {DEFAULTS['mu']}, "
             f"mu_prep = {mu_prep}; {excluded}; {n_null} shuffles per packing; load average "
             f"{os.getloadavg()[0]:.2f} (machine shared).\n\nPer packing:\n\n" + markdown_table(df.drop(columns=["n"])))
    md = write_table(table, out, "table", "rho under each definition of V, with the shuffled-Nc null model", notes)
    print(f"\nwritten: {md}, {out / 'cases.csv'}")
    return table


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="one packing of N = 1000 (for CI)")
    ap.add_argument("--n", type=int, default=None, help="disks per packing (default 3000; quick 1000)")
    ap.add_argument("--seeds", type=int, nargs="+", default=None, help="packing seeds (default 1 2 3)")
    ap.add_argument("--mu-prep", type=float, default=DEFAULTS["mu_prep"], help="preparation friction")
    ap.add_argument("--null", type=int, default=20, help="shuffles of the null model per packing")
    ap.add_argument("--out", default="out/rho", help="output folder (CSV, markdown)")
    args = ap.parse_args(argv)
    n = args.n or (1000 if args.quick else 3000)
    seeds = args.seeds or ([1] if args.quick else [1, 2, 3])
    return report(n, seeds, args.mu_prep, args.out, args.null)


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
