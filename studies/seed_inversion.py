"""What would the seed's correction need to agree with the DEM? (issue 25, docs/theory.md section 10)

    python -m studies.seed_inversion [--quick] [--n N] [--seeds 1 2 3 4 5] [--sweep out/sweep/sweep.csv]
                                     [--out DIR]

The seed's first-order correction (50)-(51) depends on the statistics only through
``x = r (N̄/Nc) rho``. For each packing of the main study (``studies.kuhn``: N = 1000, seeds 1-5,
crystalline ones excluded) this study

1. **inverts** the correction in closed form (:func:`microhom.seed_inversion.invert_seed_correction`):
   the r, rho or N̄ (the other two at their measured values) that reproduces the exact DEM drop of
   K, and separately of G, and the mismatch ``x_G / x_K`` (1 where one parameter fits both);
2. **re-measures rho with a larger neighbourhood** (``network_statistics(nbar=N̄)`` for N̄ from 3
   to 30): an effective N̄ read as "the particles of a correlated cluster" changes the neighbourhood
   rho is summed over too, so the self-consistent ``x(N̄) = r N̄ rho(N̄)/Nc`` is what such a reading
   would give;
3. measures the **size of the correlated clusters** of the exact non-affine displacement field
   (``dem.analysis.stiffness``'s relaxed fluctuations, rattlers removed): the first zero of the
   displacement correlation ``C(d) = <u_i . u_j>_{|x_i - x_j| = d} / <u^2>``, and the number of
   particles within it, ``N_cl = n pi d0^2``, to compare with the N̄ the inversion needs.

With ``--sweep CSV`` (the sweep's ``sweep.csv``) it also inverts every sweep case (kt/kn from 0
to 2, Nc from near isostatic to dense) and relates the needed x to ``Z - Z_iso``.
Outputs under ``out/seed_inversion/``: ``kuhn.csv``/``kuhn.md`` (per packing), ``nbar_curve.csv``,
``sweep.csv``/``sweep.md`` (if given), ``inversion.png``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from dem.analysis.stiffness import stiffness
from microhom.seed_inversion import invert_seed_correction
from microhom.structural_sums import network_statistics
from studies.cases import DEFAULTS, get_packing
from studies.common import cli_out_dir, write_table

PSI6_MAX = 0.5
NBAR_GRID = (3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0, 20.0, 30.0)


def invert_frame(df: pd.DataFrame, kt_over_kn, ref="exact") -> pd.DataFrame:
    """Inversion columns for a frame with ``nc, r, rho, theory_mf_{K,G}, {ref}_{K,G}`` and N̄
    (``rho_nbar`` where present and finite, else ``nbar_phi``)."""
    nbar = df["nbar_phi"].astype(float)
    if "rho_nbar" in df:
        nbar = df["rho_nbar"].astype(float).where(np.isfinite(df["rho_nbar"].astype(float)), nbar)
    dK = 1 - df[f"{ref}_K"] / df["theory_mf_K"]
    dG = 1 - df[f"{ref}_G"] / df["theory_mf_G"]
    inv = invert_seed_correction(dK.to_numpy(), dG.to_numpy(), kt_over_kn=np.asarray(kt_over_kn, float),
                                 nc=df["nc"].to_numpy(), r=df["r"].to_numpy(), nbar=nbar.to_numpy(),
                                 rho=df["rho"].to_numpy())
    out = pd.DataFrame({k: np.ravel(v) for k, v in inv.as_dict().items()}, index=df.index)
    out.insert(0, "drop_G", dG.to_numpy())
    out.insert(0, "drop_K", dK.to_numpy())
    out.insert(0, "nbar", nbar.to_numpy())
    return out


def nbar_curve(net, r, nc, grid=NBAR_GRID) -> pd.DataFrame:
    """rho re-measured over the N̄ near neighbours for each N̄ of ``grid``, and x(N̄) = r N̄ rho/Nc."""
    rows = []
    for nb in grid:
        rho = network_statistics(net, nbar=nb).rho
        rows.append({"nbar": nb, "rho": rho, "x": r * nb * rho / nc})
    return pd.DataFrame(rows)


def displacement_correlation(net, u, keep, bins):
    """C(d) = sum u_i.u_j / (pairs * <u^2>) over the pairs at centre distance d (minimum image).

    u: (N, 2) field, keep: (N,) bool (non-rattlers), bins: distance bin edges [m]. Returns the
    bin centres and C per bin (NaN where a bin has no pair)."""
    x = net.positions[keep]
    v = u[keep] - u[keep].mean(axis=0)
    inv = np.linalg.inv(net.cell)
    d = x[None, :, :] - x[:, None, :]
    s = d @ inv.T
    d = (s - np.round(s)) @ net.cell.T
    dist = np.hypot(d[..., 0], d[..., 1])
    dot = v @ v.T
    iu = np.triu_indices(len(x), 1)
    dist, dot = dist[iu], dot[iu]
    idx = np.digitize(dist, bins) - 1
    ok = (idx >= 0) & (idx < len(bins) - 1)
    num = np.bincount(idx[ok], weights=dot[ok], minlength=len(bins) - 1)
    cnt = np.bincount(idx[ok], minlength=len(bins) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = num / cnt / np.mean(np.sum(v * v, axis=1))
    return 0.5 * (bins[1:] + bins[:-1]), c


def cluster_size(net, ex, mode):
    """First zero d0 of the non-affine displacement correlation of ``mode`` ("bulk" or "shear"),
    in diameters, and the number of particles within it, N_cl = (N/A) pi d0^2."""
    u = ex.u
    fields = [u[0] + u[1]] if mode == "bulk" else [u[0] - u[1], u[2]]
    keep = ~np.asarray(ex.rattler_mask, bool) if ex.rattler_mask is not None else np.ones(net.n_particles, bool)
    D = 2 * float(net.radii.mean())
    L = float(min(np.abs(np.linalg.det(net.cell)) / np.hypot(*net.cell[:, k]) for k in (0, 1)))
    bins = np.arange(0.0, 0.5 * L, 0.25 * D)
    cs = []
    for f in fields:
        centres, c = displacement_correlation(net, f, keep, bins)
        cs.append(c)
    with np.errstate(invalid="ignore"):
        c = np.mean(cs, axis=0)   # NaN in the empty bins (distances no pair has)
    below = np.flatnonzero((c < 0) & (centres > 0.5 * D))   # NaN compares False
    if not len(below):
        return float("nan"), float("nan"), centres / D, c
    k = below[0]  # linear interpolation of the zero between bins k-1 and k
    d0 = centres[k - 1] + (centres[k] - centres[k - 1]) * c[k - 1] / (c[k - 1] - c[k])
    density = net.n_particles / abs(np.linalg.det(net.cell))
    return d0 / D, density * np.pi * d0 ** 2, centres / D, c


def kuhn_packings(n, seeds, mu_prep):
    """Per packing of the main study: statistics, exact drops, inversion, rho(N̄), cluster sizes."""
    rows, curves = [], []
    for seed in seeds:
        res, _, _ = get_packing({**DEFAULTS, "n": n, "seed": seed, "mu_prep": mu_prep})
        net = res.to_network()
        psi6 = float(res.report.get("psi6", np.nan))
        st = network_statistics(net)
        t0 = time.perf_counter()
        ex = stiffness(net, prestress=True)
        mf_K, mf_G = st.nc * st.phi / (2 * np.pi), st.nc * st.phi * 2 / (4 * np.pi)  # (37), kt = kn = 1
        row = {"seed": seed, "psi6": psi6, "nc": st.nc, "r": st.r, "r_all": st.r_all, "rho": st.rho,
               "rho_contacts": network_statistics(net, rho_neighbours="contacts").rho,
               "phi": st.phi, "nbar_phi": st.nbar_phi, "theory_mf_K": mf_K, "theory_mf_G": mf_G,
               "exact_K": ex.K, "exact_G": ex.G, "affine_K": ex.K_affine, "affine_G": ex.G_affine}
        for mode in ("bulk", "shear"):
            d0, ncl, _, _ = cluster_size(net, ex, mode)
            row[f"d0_{mode}"], row[f"ncl_{mode}"] = d0, ncl
        row["time_s"] = time.perf_counter() - t0
        cur = nbar_curve(net, st.r, st.nc)
        cur["seed"] = seed
        curves.append(cur)
        rows.append(row)
        print(f"seed {seed}: psi6 = {psi6:.2f}, Nc = {st.nc:.3f}, r = {st.r:.3f}, rho = {st.rho:.3f} "
              f"(contacts {row['rho_contacts']:.3f}), drops K {1 - ex.K / mf_K:.3f} G {1 - ex.G / mf_G:.3f}, "
              f"cluster d0 = {row['d0_bulk']:.2f} / {row['d0_shear']:.2f} D", flush=True)
    df = pd.DataFrame(rows)
    inv = invert_frame(df, 1.0)
    return pd.concat([df, inv], axis=1), pd.concat(curves, ignore_index=True)


def self_consistent_nbar(curve: pd.DataFrame, x_needed: float) -> float:
    """The smallest N̄ of the curve where x(N̄) reaches ``x_needed`` (linear interpolation), or NaN."""
    nb, x = curve["nbar"].to_numpy(), curve["x"].to_numpy()
    hit = np.flatnonzero(x >= x_needed)
    if not len(hit):
        return float("nan")
    k = hit[0]
    if k == 0:
        return float(nb[0])
    return float(nb[k - 1] + (nb[k] - nb[k - 1]) * (x_needed - x[k - 1]) / (x[k] - x[k - 1]))


def sweep_inversion(path) -> pd.DataFrame:
    """Invert every successful case of the sweep's ``sweep.csv`` (its reference: no pre-stress)."""
    df = pd.read_csv(path)
    # kt = 0 re-analyses of frictional packings are mechanisms (exact K = G = 0, drop 1): no finite x
    df = df[(df.status == "ok") & (df.rho.abs() > 0) & (df.kt_ratio > 0)
            & (df.exact_K / df.theory_mf_K > 1e-9) & (df.exact_G / df.theory_mf_G > 1e-9)].copy()
    inv = invert_frame(df, df["kt_ratio"].to_numpy())
    keys = ["mu_prep", "p_over_kn", "kt_ratio", "seed", "nc", "r", "rho", "phi"]
    out = pd.concat([df[keys], inv], axis=1)
    out["z_iso"] = np.where(out.kt_ratio > 0, 3.0, 4.0)
    out["z_minus_ziso"] = out.nc - out.z_iso
    return out


def summary_table(k: pd.DataFrame, curves: pd.DataFrame) -> pd.DataFrame:
    """The docs' table: measured value and the value each modulus needs, mean (min-max) over packings."""
    def span(col):
        v = k[col]
        return f"{v.mean():.3g} ({v.min():.3g}-{v.max():.3g})"
    sc = {m: [self_consistent_nbar(curves[curves.seed == s], x) for s, x in zip(k.seed, k[f"x_{m}"])]
          for m in ("K", "G")}
    xmax = curves.groupby("seed")["x"].max()
    rows = [
        {"parameter": "x = r (Nbar/Nc) rho", "measured": span("x_measured"), "needed for K": span("x_K"),
         "needed for G": span("x_G")},
        {"parameter": "r (Nbar, rho measured)", "measured": span("r"), "needed for K": span("r_K"),
         "needed for G": span("r_G")},
        {"parameter": "rho (r, Nbar measured)", "measured": span("rho"), "needed for K": span("rho_K"),
         "needed for G": span("rho_G")},
        {"parameter": "Nbar, rho held fixed", "measured": span("nbar"), "needed for K": span("nbar_K"),
         "needed for G": span("nbar_G")},
        {"parameter": "Nbar, rho re-measured over Nbar neighbours", "measured": span("nbar"),
         "needed for K": "none reaches it" if np.all(np.isnan(sc["K"])) else f"{np.nanmean(sc['K']):.3g}",
         "needed for G": "none reaches it" if np.all(np.isnan(sc["G"])) else f"{np.nanmean(sc['G']):.3g}"},
        {"parameter": "largest x(Nbar) for Nbar in 3-30", "measured": f"{xmax.mean():.3g}",
         "needed for K": span("x_K"), "needed for G": span("x_G")},
        {"parameter": "particles within the first zero of the non-affine correlation, N_cl = n pi d0^2", "measured": "",
         "needed for K": span("ncl_bulk"), "needed for G": span("ncl_shear")},
        {"parameter": "drop G / drop K (theory: 3/2)", "measured": span("ratio_measured"),
         "needed for K": "", "needed for G": ""},
        {"parameter": "mismatch x_G / x_K (1: one parameter fits both)", "measured": span("mismatch"),
         "needed for K": "", "needed for G": ""},
    ]
    return pd.DataFrame(rows)


def plot(k, curves, sw, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    ax = axes[0]
    for s, g in curves.groupby("seed"):
        ax.plot(g.nbar, g.x, "o-", ms=3, lw=1, label=f"seed {s}: x(Nbar), rho over Nbar neighbours")
    ax.axhspan(k.x_K.min(), k.x_K.max(), color="C0", alpha=0.2, label="x needed for K (DEM)")
    ax.axhspan(k.x_G.min(), k.x_G.max(), color="C3", alpha=0.2, label="x needed for G (DEM)")
    ax.set_xlabel("Nbar (near neighbours rho is summed over, and in Nbar/Nc)")
    ax.set_ylabel("x = r (Nbar/Nc) rho")
    ax.set_yscale("log")
    ax.legend(fontsize=6)
    ax = axes[1]
    if sw is not None and len(sw):
        for kr, g in sw.groupby("kt_ratio"):
            g = g[g.z_minus_ziso > 0]
            ax.loglog(g.z_minus_ziso, g.x_G, "o", ms=3, label=f"x needed for G, kt/kn = {kr:g}")
        ax.loglog(sw.z_minus_ziso[sw.z_minus_ziso > 0], sw.x_measured[sw.z_minus_ziso > 0], "k.", ms=2,
                  label="x measured")
        ax.set_xlabel("Z - Z_iso (non-rattlers)")
        ax.set_ylabel("x")
        ax.legend(fontsize=6)
    else:
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="one packing of 300 (for CI)")
    ap.add_argument("--n", type=int, default=None, help="disks per packing (default 1000, quick 300)")
    ap.add_argument("--seeds", type=int, nargs="+", default=None, help="default 1 2 3 4 5 (quick 1)")
    ap.add_argument("--mu-prep", type=float, default=DEFAULTS["mu_prep"])
    ap.add_argument("--sweep", default=None, help="the sweep's sweep.csv, to invert its cases too")
    ap.add_argument("--out", default="out/seed_inversion")
    args = ap.parse_args(argv)
    n = args.n or (300 if args.quick else 1000)
    seeds = args.seeds or ([1] if args.quick else [1, 2, 3, 4, 5])
    out = cli_out_dir(args.out)
    t0 = time.perf_counter()
    k, curves = kuhn_packings(n, seeds, args.mu_prep)
    k.to_csv(out / "kuhn_all.csv", index=False)
    curves.to_csv(out / "nbar_curve.csv", index=False)
    amorphous = k[~(k.psi6 > PSI6_MAX)]
    if amorphous.empty:
        raise SystemExit("every packing crystallised")
    ac = curves[curves.seed.isin(amorphous.seed)]
    table = summary_table(amorphous, ac)
    pd.set_option("display.width", 220)
    print(table.to_string(index=False))
    print("\nrho(Nbar) and x(Nbar), mean over the amorphous packings:")
    print(ac.groupby("nbar")[["rho", "x"]].mean().to_string(float_format=lambda v: f"{v:.4f}"))
    notes = (f"Packings: N = {n}, seeds {list(amorphous.seed)} (psi6 <= {PSI6_MAX}), p/kn = "
             f"{DEFAULTS['p_over_kn']}, kt = kn, mu_prep = {args.mu_prep}; reference: exact response with "
             f"pre-stress; mean (min-max) over packings. rho(Nbar) (mean): " +
             ", ".join(f"{nb:g}: {v:.3f}" for nb, v in ac.groupby("nbar")["rho"].mean().items()) +
             f". Wall time {time.perf_counter() - t0:.0f} s.")
    md = write_table(table, out, "kuhn", "What the seed's correction would need (main study's packings)", notes)
    sw = None
    if args.sweep:
        sw = sweep_inversion(args.sweep)
        sw.to_csv(out / "sweep_cases.csv", index=False)
        g = sw.groupby(["mu_prep", "p_over_kn", "kt_ratio"])
        s = g[["nc", "z_minus_ziso", "r", "rho", "drop_K", "drop_G", "x_measured", "x_K", "x_G",
               "r_K", "r_G", "nbar_K", "nbar_G", "mismatch"]].mean().reset_index()
        fits = []
        for kr, gg in sw[sw.z_minus_ziso > 0].groupby("kt_ratio"):
            for m in ("K", "G"):
                ok = np.isfinite(gg[f"x_{m}"]) & (gg[f"x_{m}"] > 0)
                if ok.sum() >= 3:
                    sl, ic = np.polyfit(np.log(gg.z_minus_ziso[ok]), np.log(gg[f"x_{m}"][ok]), 1)
                    fits.append(f"kt/kn = {kr:g}, {m}: x ~ (Z - Z_iso)^{sl:.2f}")
            okm = gg.x_measured > 0
            if okm.sum() >= 3:
                sl, _ = np.polyfit(np.log(gg.z_minus_ziso[okm]), np.log(gg.x_measured[okm]), 1)
                fits.append(f"kt/kn = {kr:g}, measured: x ~ (Z - Z_iso)^{sl:.2f}")
        print(s.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
        print("\n".join(fits))
        write_table(s, out, "sweep", "What the seed's correction would need (sweep cases, means over seeds)",
                    "Power-law fits over the cases with Z > Z_iso: " + "; ".join(fits) + ".")
    plot(amorphous, ac, sw, out / "inversion.png")
    print(f"\nwritten: {md}, {out / 'inversion.png'} (total {time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
