"""What the statistics cannot determine: near twins of the corpus (issue 25, item 3).

    python -m studies.closure_twins [--out DIR] [--radius D] [--quick]

Two packings made by *different* protocols whose closure statistics are nearly equal ("twins")
must get nearly the same prediction from *any* closure that is a smooth function of those
statistics. The difference of their exact moduli is therefore an error no such closure can
remove. With standardised features ``x`` (each statistic divided by its standard deviation over
the closure's usable corpus rows), a pair at the same kt/kn and feature distance ``d = |x1 - x2|``,
and any closure ``f`` whose log is L-Lipschitz in ``x``, the log errors ``e_i = log f(x_i) - log
G_i`` satisfy ``e_1 - e_2 = [log f(x_1) - log f(x_2)] - log(G_1/G_2)``, hence

    max(|e_1|, |e_2|) >= (|log(G_1 / G_2)| - L d) / 2

so at ``d -> 0`` half the log ratio of the twins is a lower bound on the larger of their two errors
(the same for K). The stored closure's own slope is measured per pair as the log ratio of its two
predictions; ``|log(G_1/G_2) - log(Ghat_1/Ghat_2)|`` is the part of the twins' difference the
closure's features do not explain (``unexplained_G``).

Data: the committed corpus summary ``studies/closure_corpus.csv`` (rows of
:func:`studies.closure_fit.usable`), so the study needs no packing. Pairs of the same protocol
(other seeds or knobs) give the baseline: the sample-to-sample scatter at N = 1000.

Outputs under ``--out`` (default ``out/closure_twins``; ``--quick``: the tables only, no figure): ``twins.csv``/``.md`` (every cross-protocol pair
within ``--radius`` and each row's nearest twin), ``twins_summary.csv``/``.md`` (by distance bin),
``closure_twins.png`` (|log G1/G2| and |log K1/K2| against the feature distance, with the stored
closure's stated error).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from microhom.closure import predict_closure
from microhom.results import Result
from studies.closure_fit import SUMMARY, usable
from studies.common import cli_out_dir, write_table

__all__ = ["TWIN_FEATURES", "TwinsResult", "standardised", "pairs", "summary", "twins", "nearest_twins", "main"]

#: the packing statistics the closure sees (besides kt/kn, which twins share exactly): log of
#: Z - Z_iso, phi (in the mean field), dispersity, r, size-coordination, rattler fraction, log10 p/kn,
#: and the mean local bond order psi6_local (a feature of K since the refit)
TWIN_FEATURES = ("log_dZ", "phi", "dispersity", "r", "Z_size_minus_Z", "rattler_fraction", "log_p_over_kn",
                 "psi6_local")
#: distance bins of the summary (standardised feature units)
BINS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, np.inf)


@dataclass(frozen=True)
class TwinsResult(Result):
    """Near twins of the corpus and the lower bound they put on any closure's error.

    pairs : every pair of usable rows at the same kt/kn (one row per pair; columns of
        :func:`pairs`), not exported. summary : per distance bin and pair kind (cross-protocol /
        same protocol) the counts and the median and largest |G1/G2 - 1|, |K1/K2 - 1| (relative),
        not exported. by_kt : the same for the pairs within ``radius``, per kt/kn and kind, with
        ``bound_G``/``bound_K`` = exp(max |log X1/X2| / 2) - 1, not exported. radius : the
        distance below which a pair counts as twins [standardised units].
    n_twins : cross-protocol pairs within ``radius``. max_ratio_G, max_ratio_K : the largest
        ``max(G1/G2, G2/G1) - 1`` among them [relative]. bound_G, bound_K : the lower bound on the
        larger of the two errors of any closure for that pair, ``exp(|log G1/G2| / 2) - 1`` at
        d -> 0 [relative]. stated_G, stated_K : the stored closure's in-family stated error at those rows
        (median) [relative]. worst_pair_G : "protocol A vs protocol B at kt/kn" of the pair with
        ``max_ratio_G``.
    """

    pairs: pd.DataFrame = field(metadata={"export": False})
    summary: pd.DataFrame = field(metadata={"export": False})
    by_kt: pd.DataFrame = field(metadata={"export": False})
    radius: float
    n_twins: int
    max_ratio_G: float
    max_ratio_K: float
    bound_G: float
    bound_K: float
    stated_G: float
    stated_K: float
    worst_pair_G: str


def standardised(df: pd.DataFrame) -> tuple[np.ndarray, pd.Series]:
    """(rows, len(TWIN_FEATURES)) standardised features of the usable rows ``df`` and the standard
    deviations used (over all of ``df``)."""
    d = df.assign(log_dZ=np.log(df.dZ))
    X = d[list(TWIN_FEATURES)].to_numpy(float)
    sd = d[list(TWIN_FEATURES)].std()
    if np.any(sd.to_numpy() <= 0):
        raise ValueError(f"a twin feature does not vary over the corpus: {sd[sd <= 0].index.tolist()}")
    return X / sd.to_numpy(), sd


def _closure(df):
    return predict_closure(nc=df.Z.to_numpy(), r=df.r.to_numpy(), phi=df.phi.to_numpy(),
                           kt_over_kn=df.kt_over_kn.to_numpy(), dispersity=df.dispersity.to_numpy(),
                           sliding_fraction=df.sliding_fraction.to_numpy(),
                           size_coordination=df.Z_size_minus_Z.to_numpy(),
                           rattler_fraction=df.rattler_fraction.to_numpy(), p_over_kn=df.p_over_kn.to_numpy(),
                           psi6_local=df.psi6_local.to_numpy())


def pairs(df: pd.DataFrame) -> pd.DataFrame:
    """Every pair of rows of ``df`` (usable corpus rows) at the same kt/kn: protocols, keys,
    feature distance ``d``, the exact log ratios ``logG``, ``logK`` (|log G1/G2|), the stored
    closure's predicted log ratios and the unexplained parts, and the closure's in-family stated errors
    (these are corpus packings: their preparation families are in the fit)."""
    X, _ = standardised(df)
    p = _closure(df)
    lG, lK = np.log(df.G.to_numpy()), np.log(df.K.to_numpy())
    pG, pK = np.log(p.G), np.log(p.K)
    kt = df.kt_over_kn.to_numpy()
    i, j = np.triu_indices(len(df), 1)
    same = kt[i] == kt[j]
    i, j = i[same], j[same]
    prot, key = df.protocol.to_numpy(), df.key.to_numpy()
    out = pd.DataFrame(dict(kt_over_kn=kt[i], protocol_1=prot[i], protocol_2=prot[j], key_1=key[i], key_2=key[j],
                            cross=prot[i] != prot[j], d=np.linalg.norm(X[i] - X[j], axis=1),
                            G_1=df.G.to_numpy()[i], G_2=df.G.to_numpy()[j], K_1=df.K.to_numpy()[i],
                            K_2=df.K.to_numpy()[j],
                            logG=np.abs(lG[i] - lG[j]), logK=np.abs(lK[i] - lK[j]),
                            closure_logG=np.abs(pG[i] - pG[j]), closure_logK=np.abs(pK[i] - pK[j]),
                            unexplained_G=np.abs((lG[i] - lG[j]) - (pG[i] - pG[j])),
                            unexplained_K=np.abs((lK[i] - lK[j]) - (pK[i] - pK[j])),
                            stated_G=np.maximum(p.rel_error_G_in_family[i], p.rel_error_G_in_family[j]),
                            stated_K=np.maximum(p.rel_error_K_in_family[i], p.rel_error_K_in_family[j]),
                            valid=p.valid[i] & p.valid[j]))
    return out.sort_values("d").reset_index(drop=True)


def summary(pr: pd.DataFrame, bins=BINS, by="distance") -> pd.DataFrame:
    """Per distance bin (``by="distance"``) or per kt/kn (``by="kt"``: give the pairs within the
    twin radius) and kind (cross-protocol or same protocol): pairs, the median and largest relative
    differences ``exp(|log G1/G2|) - 1`` (and K), the largest unexplained by the closure, the
    bound ``exp(max |log G1/G2| / 2) - 1`` and the median stated error of the closure there."""
    if by == "distance":
        lab = pd.cut(pr.d, bins=list(bins), right=False)
        name = lambda b: f"[{b.left:g}, {b.right:g})"
    elif by == "kt":
        lab, name = pr.kt_over_kn, lambda b: f"{b:g}"
    else:
        raise ValueError(f"by must be 'distance' or 'kt', got {by!r}")
    rows = []
    for (b, cross), g in pr.groupby([lab, pr.cross], observed=True):
        rows.append(dict(group=name(b), kind="cross-protocol" if cross else "same protocol",
                         pairs=len(g), d_max=float(g.d.max()), median_dG=float(np.expm1(g.logG.median())), max_dG=float(np.expm1(g.logG.max())),
                         max_dG_unexplained=float(np.expm1(g.unexplained_G.max())),
                         median_dK=float(np.expm1(g.logK.median())), max_dK=float(np.expm1(g.logK.max())),
                         max_dK_unexplained=float(np.expm1(g.unexplained_K.max())),
                         bound_G=float(np.expm1(g.logG.max() / 2)), bound_K=float(np.expm1(g.logK.max() / 2)),
                         stated_G=float(g.stated_G.median()), stated_K=float(g.stated_K.median())))
    return pd.DataFrame(rows).rename(columns={"group": by})


def twins(df: pd.DataFrame | None = None, radius: float = 1.0) -> TwinsResult:
    """Near twins of the usable corpus rows ``df`` (default: the committed summary) within
    ``radius`` standardised feature units; see the module docstring for the bound."""
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be a finite distance > 0 (standardised feature units), got {radius!r}")
    if df is None:
        df = usable(pd.read_csv(SUMMARY, keep_default_na=False, na_values=[""]))
    pr = pairs(df)
    tw = pr[pr.cross & (pr.d < radius)]
    by_kt = summary(pr[pr.d < radius], by="kt")
    if tw.empty:
        nan = float("nan")
        return TwinsResult(pr, summary(pr), by_kt, radius, 0, nan, nan, nan, nan, nan, nan, "")
    w = tw.loc[tw.logG.idxmax()]
    return TwinsResult(pairs=pr, summary=summary(pr), by_kt=by_kt, radius=float(radius), n_twins=len(tw),
                       max_ratio_G=float(np.expm1(tw.logG.max())), max_ratio_K=float(np.expm1(tw.logK.max())),
                       bound_G=float(np.expm1(tw.logG.max() / 2)), bound_K=float(np.expm1(tw.logK.max() / 2)),
                       stated_G=float(tw.stated_G.median()), stated_K=float(tw.stated_K.median()),
                       worst_pair_G=f"{w.protocol_1} vs {w.protocol_2} at kt/kn = {w.kt_over_kn:g} (d = {w.d:.2f})")


def nearest_twins(pr: pd.DataFrame, protocol: str = "lammps_prep", other: str = "dem_fixedphi") -> pd.DataFrame:
    """Each row of ``protocol`` (a packing at one kt/kn) with its nearest row of ``other`` at the
    same kt/kn, from the pairs ``pr`` of :func:`pairs`: the keys, the distance ``d`` and the exact
    moduli of both (``K``, ``G`` of ``protocol``; ``K_twin``, ``G_twin``), ``dK = K_twin / K - 1``,
    ``dG`` likewise (signed, relative), and the unexplained parts of :func:`pairs`. Empty if
    either protocol has no row."""
    a = pr[(pr.protocol_1 == protocol) & (pr.protocol_2 == other)]
    b = pr[(pr.protocol_1 == other) & (pr.protocol_2 == protocol)]
    flip = {"key_1": "key_2", "key_2": "key_1", "G_1": "G_2", "G_2": "G_1", "K_1": "K_2", "K_2": "K_1",
            "protocol_1": "protocol_2", "protocol_2": "protocol_1"}
    both = pd.concat([a, b.rename(columns=flip)], ignore_index=True)
    if both.empty:
        return pd.DataFrame(columns=["kt_over_kn", "key", "key_twin", "d", "K", "K_twin", "dK", "G", "G_twin", "dG"])
    near = both.sort_values("d", kind="stable").groupby(["key_1", "kt_over_kn"], sort=True).head(1)
    out = pd.DataFrame(dict(kt_over_kn=near.kt_over_kn, key=near.key_1, key_twin=near.key_2, d=near.d,
                            K=near.K_1, K_twin=near.K_2, dK=near.K_2 / near.K_1 - 1, G=near.G_1, G_twin=near.G_2,
                            dG=near.G_2 / near.G_1 - 1, unexplained_K=near.unexplained_K,
                            unexplained_G=near.unexplained_G))
    return out.sort_values(["kt_over_kn", "key"]).reset_index(drop=True)


def plot(pr: pd.DataFrame, radius: float, path: Path):
    """closure_twins.png: |G1/G2 - 1| and |K1/K2 - 1| against the feature distance, cross-protocol
    pairs coloured by kt/kn, same-protocol pairs grey; the stored closure's median stated error
    (dashed) and 10 % (dotted)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.6))
    near = pr[pr.d < 2.0]
    for a, m in zip(ax, ("G", "K")):
        s = near[~near.cross]
        a.scatter(s.d, np.expm1(s[f"log{m}"]), s=6, c="0.75", label="same protocol (other seed or knobs)")
        c = near[near.cross]
        sc = a.scatter(c.d, np.expm1(c[f"log{m}"]), s=10, c=np.log10(np.where(c.kt_over_kn > 0, c.kt_over_kn, 0.02)),
                       cmap="viridis", vmin=np.log10(0.02), vmax=0, label="different protocols")
        a.axhline(float(near[f"stated_{m}"].median()), color="r", ls="--", lw=1,
                  label=f"closure's stated error (median {near[f'stated_{m}'].median():.0%})")
        a.axhline(0.10, color="k", ls=":", lw=0.8, label="10 %")
        a.axvline(radius, color="0.4", ls="-.", lw=0.8, label=f"twin radius {radius:g}")
        a.set_yscale("log")
        a.set_ylim(1e-3, 3)
        a.set_xlabel("standardised distance of the closure's statistics (same kt/kn)")
        a.set_ylabel(f"exact {m}1/{m}2 - 1 (larger over smaller)")
        a.set_title(f"{m}: pairs of corpus packings at the same kt/kn")
    ax[0].legend(fontsize=7, loc="lower right")
    fig.colorbar(sc, ax=ax[1], label="log10 kt/kn (kt = 0 at the bottom)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/closure_twins")
    ap.add_argument("--quick", action="store_true", help="the tables only (no figure)")
    ap.add_argument("--radius", type=float, default=1.0, help="twin radius in standardised feature units (> 0)")
    args = ap.parse_args(argv)
    out = cli_out_dir(args.out, cache=False)
    res = twins(radius=args.radius)
    pd.set_option("display.width", 220)
    ff = lambda x: f"{x:.3f}"
    print(res.summary.to_string(index=False, float_format=ff))
    print(f"pairs within the twin radius {args.radius:g}, per kt/kn:")
    print(res.by_kt.to_string(index=False, float_format=ff))
    tw = res.pairs[res.pairs.cross & (res.pairs.d < args.radius)]
    cols = ["kt_over_kn", "protocol_1", "protocol_2", "key_1", "key_2", "d", "G_1", "G_2", "logG", "closure_logG",
            "unexplained_G", "K_1", "K_2", "logK", "unexplained_K", "stated_G", "stated_K", "valid"]
    print(tw[cols].to_string(index=False, float_format=ff))
    print({k: v for k, v in res.as_dict().items()})
    write_table(res.summary, out, "twins_summary", "Pairs of corpus packings at the same kt/kn, by feature distance",
                "Relative differences are exp(|log X1/X2|) - 1; unexplained: after the stored closure's own "
                "predicted ratio is removed.")
    write_table(res.by_kt, out, "twins_by_kt", f"Pairs within feature distance {args.radius:g}, per kt/kn")
    write_table(tw[cols], out, "twins", f"Cross-protocol twins (feature distance < {args.radius:g})")
    nt = nearest_twins(res.pairs)
    if len(nt):
        print("each LAMMPS packing (lammps_prep) and its nearest twin made by our engine with the same protocol "
              "(dem_fixedphi):")
        print(nt.to_string(index=False, float_format=ff))
        byk = nt.groupby("kt_over_kn").agg(d_max=("d", "max"), dK_median=("dK", lambda x: x.abs().median()),
                                           dK_max=("dK", lambda x: x.abs().max()), dK_mean=("dK", "mean"),
                                           dG_median=("dG", lambda x: x.abs().median()),
                                           dG_max=("dG", lambda x: x.abs().max()), dG_mean=("dG", "mean")).reset_index()
        print(byk.to_string(index=False, float_format=ff))
        write_table(nt, out, "twins_lammps", "Each LAMMPS packing and its nearest dem_fixedphi twin (same kt/kn)")
        write_table(byk, out, "twins_lammps_by_kt", "LAMMPS packings and their nearest dem_fixedphi twins, per kt/kn",
                    "dK, dG = twin / LAMMPS - 1; median and max of |dK|, |dG|; mean signed.")
    if not args.quick:
        plot(res.pairs, args.radius, out / "closure_twins.png")
    print(f"written {out}")
    return res


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
