"""Fit the statistics-only closure (``microhom.closure``) on the corpus of ``studies.corpus`` and
measure it honestly: leave one protocol out, leave one preparation family out, the candidate
statistics, the collapse plots.

    python -m studies.closure_fit [--cache DIR] [--out DIR] [--quick] [--no-build] [--bench] [--trials]

1. The corpus (``studies.corpus.load_corpus``: built where the cache lacks it, unless
   ``--no-build``); ``--quick`` reads the committed corpus summary ``studies/closure_corpus.csv``
   instead and builds one small packing end to end (CI).
2. Rows used: exact response jammed (no flag from ``dem.analysis.stiffness``), ``Z - Z_iso >= DZ_MIN``.
3. Fit: nonlinear least squares of ``log K`` and ``log G`` of the closure's form (module docstring
   of ``microhom.closure``) on its features; the printed coefficients are the ones stored.
4. Leave one protocol out (LOPO): for each protocol, fit on the others, predict it; relative
   errors, leverages; the error scale ``Q`` is the 90th percentile of
   ``|err| / sqrt(1 + h / h_mean)`` over all held-out cases, and the table gives per protocol the
   rms and max error and the fraction inside the stated error.
4b. Leave one preparation family out (:data:`FAMILIES`: protocols that share a preparation, so
   that no twin of the held-out packings is in the fit): per family, fit on the other families,
   Q calibrated on *their* LOPO residuals (the error the closure would state), predict the family;
   valid cases (not flagged: leverage and the training rows' box), rms and max error, coverage of
   the stated error and overclaims (valid, outside it). ``--trials`` (always without ``--quick``):
   the same two tables with the normal-force coefficient of variation added (:data:`FN_CV_TRIALS`).
4c. The default stated error, across families (:func:`calibrate_family`): ``Q(kt) = max(Q, a + b
   ln(kn/kt))`` with ``(a, b)`` the smallest on average such that at least 90 % of the valid
   family-out cases of every family at every kt/kn lie within ``Q(kt) sqrt(1 + h/h_mean)``; the
   printed ``Q_FAMILY`` is the one stored. Table ``family_error``: per family and protocol the
   coverage and overclaims of the in-family error (before), of ``Q_FAMILY`` (after) and of it
   calibrated without the family (nested). The search for statistics that carry K across
   families is ``studies.closure_transfer``.
5. Candidate statistics: LOPO rms of ``log(K/K_mf)`` and ``log(G/G_mf)`` when each candidate is
   added to the base features (how much of the spread across protocols it removes).
6. Plots under ``--out`` (collapse of G/G_mf and K/K_mf against Z - Z_iso by protocol; predicted
   against exact).
"""
from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from microhom.closure import DZ_MIN, FEATURES_G, FEATURES_K, L_MAX, family_error_scale, features, predict_closure
from studies.closure_rigidity import RIGIDITY_COLUMNS, rigidity_columns
from studies.common import cli_out_dir, write_table

SUMMARY = Path(__file__).resolve().parent / "closure_corpus.csv"
COLUMNS = ["protocol", "key", "seed", "n", "kt_over_kn", "knob_p_over_kn", "knob_mu_prep", "knob_dispersity",
           "knob_phi", "knob_radii", "Z", "Z_all", "Z_iso", "dZ", "r", "phi", "rattler_fraction",
           "sliding_fraction", "dispersity", "z_size_corr", "Z_size", "f_min", "psi6", "psi6_local", "fabric_anisotropy",
           "force_anisotropy", "p_over_kn", "fn_cv", "K", "G", "K_ps", "G_ps", "K_aff", "G_aff", "n_floppy",
           "flags", "weak_fraction", "fn_small", "near_contacts", "Z_stick", "f_z3"]   # the last five:
#: studies.closure_transfer.CONTACT_COLUMNS (measured on the cached packings)
#: candidate statistics tried on top of the base features (item 2 of issue 25)
CANDIDATES = ("phi", "z_size_corr", "f_min", "fabric_anisotropy", "force_anisotropy", "fn_cv",
              "sliding_fraction", "psi6") + RIGIDITY_COLUMNS
#: the closure before the corpus held identical disks at low pressure and psi6 (for the table)
PREVIOUS_K = ("1", "frictionless", "log kt/kn", "(log kt/kn)^2", "log dZ", "frictionless * log dZ",
              "rattler fraction", "log10 p/kn")
PREVIOUS_G = ("1", "frictionless", "log kt/kn", "(log kt/kn)^2", "log kt/kn * tanh(Z - 4)", "log dZ",
              "frictionless * log dZ", "dispersity", "r", "size-coordination")


#: protocols whose packings are in force balance without tangential forces (kt = 0 is physical)
FRICTIONLESS_PREP = ("pack_frictionless", "minimise")


def usable(df: pd.DataFrame) -> pd.DataFrame:
    """Rows with a jammed exact response and Z - Z_iso >= DZ_MIN (the closure's domain). kt = 0
    rows only for packings prepared without friction: a packing prepared with friction carries
    tangential forces and is not an equilibrium of frictionless contacts."""
    f = df["flags"].fillna("").astype(str)
    ok = (f == "") & (df.K > 0) & (df.G > 0) & (df.dZ >= DZ_MIN)
    ok &= (df.kt_over_kn > 0) | df.protocol.isin(FRICTIONLESS_PREP)
    out = df[ok].copy()
    out["Z_size_minus_Z"] = out.Z_size - out.Z
    out["log_p_over_kn"] = np.log10(out.p_over_kn)
    return out.reset_index(drop=True)


def _extra(extra, m):
    """The corpus columns added to modulus ``m``'s design: ``extra`` itself (both moduli) or
    ``extra[m]`` when it is a mapping ``{"K": (...), "G": (...)}``."""
    return tuple(extra.get(m, ())) if isinstance(extra, dict) else tuple(extra)


def design(df, names, extra=()):
    """Feature matrix of the rows of ``df`` (columns ``names`` of ``ALL_FEATURES``, then the
    corpus columns ``extra``) and dZ."""
    X, dz = features(df.Z.to_numpy(), df.kt_over_kn.to_numpy(), df.dispersity.to_numpy(), df.r.to_numpy(),
                     df.sliding_fraction.to_numpy(), (df.Z_size - df.Z).to_numpy(), df.rattler_fraction.to_numpy(),
                     df.p_over_kn.to_numpy(), df.psi6_local.to_numpy(), names=names)
    if extra:
        X = np.concatenate([X, df[list(extra)].to_numpy(float)], axis=1)
    return X, dz


def mean_field(df):
    """Mean field (37) of the load-bearing particles, Z phi (1 - x_r) (kn = 1)."""
    w = df.Z.to_numpy() * df.phi.to_numpy() * (1 - df.rattler_fraction.to_numpy())
    K_mf = w / (2 * np.pi)
    G_mf = w * (1 + df.kt_over_kn.to_numpy()) / (4 * np.pi)
    return K_mf, G_mf


def fit(df, extra=(), names_K=FEATURES_K, names_G=FEATURES_G):
    """Coefficients c_K, c_G of the closure's form on ``df`` (kn = 1), nonlinear least squares on
    log K and log G from a linear start in the transformed targets, and (F^T F)^-1 per modulus."""
    XK, dz = design(df, names_K, _extra(extra, "K"))
    XG, _ = design(df, names_G, _extra(extra, "G"))
    K_mf, G_mf = mean_field(df)
    lK, lG = np.log(df.K.to_numpy()), np.log(df.G.to_numpy())
    tK = np.log(np.clip(K_mf / df.K.to_numpy() - 1, 1e-3, None))
    tG = np.log(dz * np.clip(G_mf / df.G.to_numpy() - 1, 1e-3, None))
    c0K, *_ = np.linalg.lstsq(XK, tK, rcond=None)
    c0G, *_ = np.linalg.lstsq(XG, tG, rcond=None)
    rK = least_squares(lambda c: np.log(K_mf) - np.logaddexp(0.0, XK @ c) - lK, c0K, method="lm")
    rG = least_squares(lambda c: np.log(G_mf) + np.log(dz) - np.logaddexp(np.log(dz), XG @ c) - lG, c0G,
                       method="lm")
    return rK.x, rG.x, np.linalg.pinv(XK.T @ XK), np.linalg.pinv(XG.T @ XG)


def predict_rows(df, cK, cG, extra=(), names_K=FEATURES_K, names_G=FEATURES_G):
    XK, dz = design(df, names_K, _extra(extra, "K"))
    XG, _ = design(df, names_G, _extra(extra, "G"))
    K_mf, G_mf = mean_field(df)
    dz = np.maximum(dz, 1e-12)
    K = K_mf / (1 + np.exp(XK @ cK))
    G = G_mf * dz / (dz + np.exp(XG @ cG))
    return K, G, XK, XG


#: Preparation families (``studies.corpus``): protocols that share a preparation, held out
#: together by :func:`lofo`. Fixed-rate compression to a solid fraction then relaxation at fixed
#: box (LAMMPS's ``in.prep``, by LAMMPS and by our engine); servo compression to a pressure with
#: friction (``dem.engine.packing.pack`` under three damping schedules); frictionless relaxation to
#: an energy minimum (servo + FIRE quench, L-BFGS at fixed solid fraction).
FAMILIES = {"fixed_phi": ("lammps_prep", "dem_fixedphi"),
            "servo_frictional": ("pack_frictional", "pack_slowdamped", "pack_study"),
            "frictionless_minimum": ("pack_frictionless", "minimise")}


def family_of(protocols, families=FAMILIES):
    """The family name of each protocol (a protocol in no family is its own family)."""
    fam = {p: f for f, ps in families.items() for p in ps}
    return np.array([fam.get(p, p) for p in protocols], dtype=object)


def lopo(df, extra=(), names_K=FEATURES_K, names_G=FEATURES_G, families=None):
    """Leave one protocol out: per held-out row, the relative errors and the leverages in the
    designs of the other protocols (with their mean and largest training leverage).
    ``families`` (a mapping family -> protocols, e.g. :data:`FAMILIES`): leave one *family* out
    instead; the column ``held_out`` names the unit left out (the protocol, or its family)."""
    rows = []
    unit = df.protocol.to_numpy() if families is None else family_of(df.protocol, families)
    for prot in sorted(set(unit)):
        tr, te = df[unit != prot], df[unit == prot]
        cK, cG, covK, covG = fit(tr, extra, names_K, names_G)
        Kp, Gp, XK, XG = predict_rows(te, cK, cG, extra, names_K, names_G)
        d = dict(protocol=te.protocol.to_numpy(), held_out=prot, key=te.key.to_numpy(),
                 kt_over_kn=te.kt_over_kn.to_numpy(),
                 err_K=Kp / te.K.to_numpy() - 1, err_G=Gp / te.G.to_numpy() - 1)
        for m, X, cov, names in (("K", XK, covK, names_K), ("G", XG, covG, names_G)):
            Xtr, _ = design(tr, names, _extra(extra, m))
            htr = np.einsum("ij,jk,ik->i", Xtr, cov, Xtr)
            d.update({f"h_{m}": np.einsum("ij,jk,ik->i", X, cov, X), f"hmean_{m}": htr.mean(),
                      f"hmax_{m}": htr.max()})
        rows.append(pd.DataFrame(d))
    return pd.concat(rows, ignore_index=True)


def scale(lo, m):
    return np.sqrt(1 + lo[f"h_{m}"] / lo[f"hmean_{m}"])


def calibrate(lo, coverage=0.9, h_factor=3.0, exclude=None):
    """Error scale Q (relative) per modulus: the largest, over the held-out protocols, of the
    ``coverage`` quantile of ``|err| / sqrt(1 + h / h_mean)`` of its cases inside the data
    (leverage at most ``h_factor`` times the largest training leverage, for K and G; the others
    are flagged). So the stated error covers ``coverage`` of the cases of *every* protocol.
    ``exclude``: a protocol left out of the calibration (the nested check)."""
    inside = (lo.h_K <= h_factor * lo.hmax_K) & (lo.h_G <= h_factor * lo.hmax_G)
    q = {}
    for m in ("K", "G"):
        z = np.abs(lo[f"err_{m}"]) / scale(lo, m)
        sel = inside if exclude is None else inside & (lo.protocol != exclude)
        q[m] = float(max(np.quantile(z[sel & (lo.protocol == p)], coverage, method="higher")
                         for p in lo.protocol[sel].unique()))
    return q, inside


def lopo_table(lo, q, inside):
    """Per held-out protocol: cases, valid (inside the data), rms and max relative error of the
    valid ones, the fraction inside the stated error, and the same fraction with Q calibrated
    without that protocol (``nested_*``: the out-of-sample check of the error statement)."""
    rows = []
    for prot, g in lo.groupby("protocol"):
        v = inside[g.index].to_numpy()
        gv = g[v]
        qn, _ = calibrate(lo, exclude=prot)
        d = dict(protocol=prot, cases=len(g), valid=int(v.sum()))
        for m in ("K", "G"):
            e = gv[f"err_{m}"].abs()
            d.update({f"rms_{m}": float(np.sqrt(np.mean(e ** 2))) if len(gv) else np.nan,
                      f"max_{m}": float(e.max()) if len(gv) else np.nan,
                      f"inside_{m}": float(np.mean(e <= q[m] * scale(gv, m) * (1 + 1e-12))) if len(gv) else np.nan,
                      f"nested_{m}": float(np.mean(e <= qn[m] * scale(gv, m))) if len(gv) else np.nan})
        rows.append(d)
    return pd.DataFrame(rows)[["protocol", "cases", "valid", "rms_K", "max_K", "inside_K", "nested_K", "rms_G",
                               "max_G", "inside_G", "nested_G"]]


def _outside_training_box(te, tr, extra=()):
    """True for each row of ``te`` outside the box of ``tr``'s statistics (the ``RANGES`` of a
    closure fitted on ``tr``, and the range of each corpus column in ``extra``; kt/kn only where
    > 0), and every kt = 0 row if ``tr`` has none."""
    box = data_ranges(tr)
    out = np.zeros(len(te), dtype=bool)
    for c in set(_extra(extra, "K")) | set(_extra(extra, "G")):
        out |= ((te[c] < tr[c].min() - 1e-9) | (te[c] > tr[c].max() + 1e-9)).to_numpy()
    cols = dict(Z=te.Z, dispersity=te.dispersity, r=te.r, phi=te.phi, p_over_kn=te.p_over_kn,
                size_coordination=te.Z_size - te.Z, rattler_fraction=te.rattler_fraction, psi6_local=te.psi6_local)
    for name, v in cols.items():
        lo_, hi_ = box[name]
        out |= ((v < lo_ - 1e-9) | (v > hi_ + 1e-9)).to_numpy()
    kr = te.kt_over_kn.to_numpy()
    klo, khi = box["kt_over_kn"]
    if not (tr.kt_over_kn == 0).any():   # no frictionless row in the fit: its frictionless terms are
        out |= kr == 0                   # unfitted (zero), and the leverage (pinv) cannot see that
    return out | ((kr > 0) & ((kr < klo - 1e-12) | (kr > khi + 1e-12)))


def lofo(df, extra=(), names_K=FEATURES_K, names_G=FEATURES_G, families=FAMILIES, h_factor=3.0):
    """Leave one preparation family out, with the error statement a closure fitted without that
    family would make: per family F, the closure is fitted on the other families, its Q is
    calibrated on *their* leave-one-protocol-out residuals (:func:`calibrate` of :func:`lopo` on
    the other families), and F's rows are predicted. Per held-out row (the columns of
    :func:`lopo`, plus): ``Q_K``, ``Q_G`` (that nested Q), ``stated_K``, ``stated_G``
    (``Q sqrt(1 + h/h_mean)``), ``in_box`` (inside the box of the training rows' statistics),
    ``valid`` (leverage at most ``h_factor`` times the training's largest, in K and G, and inside
    the box: what that closure would not flag), ``overclaim`` (valid, yet outside its stated error
    in K or G)."""
    lo = lopo(df, extra, names_K, names_G, families=families)
    fam = family_of(df.protocol, families)
    parts = []
    for f, g in lo.groupby("held_out", sort=True):
        tr = df[fam != f]
        q, _ = calibrate(lopo(tr, extra, names_K, names_G), h_factor=h_factor)
        te = df.set_index(["key", "kt_over_kn"]).loc[list(zip(g.key, g.kt_over_kn))].reset_index()
        g = g.assign(Q_K=q["K"], Q_G=q["G"], stated_K=q["K"] * scale(g, "K").to_numpy(),
                     stated_G=q["G"] * scale(g, "G").to_numpy(), in_box=~_outside_training_box(te, tr, extra))
        parts.append(g)
    lo = pd.concat(parts).sort_index()
    lo["valid"] = (lo.h_K <= h_factor * lo.hmax_K) & (lo.h_G <= h_factor * lo.hmax_G) & lo.in_box
    inside = (lo.err_K.abs() <= lo.stated_K * (1 + 1e-12)) & (lo.err_G.abs() <= lo.stated_G * (1 + 1e-12))
    lo["overclaim"] = lo.valid & ~inside
    return lo


def lofo_table(lo, by="held_out"):
    """Per held-out family (``by="held_out"``) or per protocol within it (``by="protocol"``):
    cases, valid (not flagged by the closure fitted without the family), rms and max relative error
    of the valid ones, the fraction of them inside the stated error (``inside_*``, with the nested Q
    of :func:`lofo`), overclaims (valid, outside the stated error in K or G), and that Q."""
    rows = []
    for u, g in lo.groupby(by, sort=True):
        gv = g[g.valid]
        d = dict(held_out=g.held_out.iloc[0], protocol=u if by == "protocol" else "+".join(sorted(g.protocol.unique())),
                 cases=len(g), valid=int(g.valid.sum()), in_box=int(g.in_box.sum()))
        for m in ("K", "G"):
            e = gv[f"err_{m}"].abs()
            d.update({f"rms_{m}": float(np.sqrt(np.mean(e ** 2))) if len(gv) else np.nan,
                      f"max_{m}": float(e.max()) if len(gv) else np.nan,
                      f"inside_{m}": float(np.mean(e <= gv[f"stated_{m}"] * (1 + 1e-12))) if len(gv) else np.nan})
        d.update(overclaims=int(g.overclaim.sum()), Q_K=float(g.Q_K.iloc[0]), Q_G=float(g.Q_G.iloc[0]),
                 rms_K_all=float(np.sqrt(np.mean(g.err_K ** 2))), rms_G_all=float(np.sqrt(np.mean(g.err_G ** 2))))
        rows.append(d)
    return pd.DataFrame(rows)[["held_out", "protocol", "cases", "in_box", "valid", "rms_K", "max_K", "inside_K",
                               "rms_G", "max_G", "inside_G", "overclaims", "Q_K", "Q_G", "rms_K_all", "rms_G_all"]]


def _family_L(kt):
    """L = ln(kn / kt) of the across-family error scale, clipped to [0, L_MAX] (kt = 0: L_MAX)."""
    kt = np.asarray(kt, dtype=float)
    return np.where(kt > 0, np.clip(-np.log(np.where(kt > 0, kt, 1.0)), 0.0, L_MAX), L_MAX)


def calibrate_family(lf, q_in, coverage=0.9, exclude=None, slopes=np.linspace(0.0, 0.1, 401),
                     by=("held_out", "kt_over_kn")):
    """The across-family error scale ``Q(kt) = max(q_in, a + b L)`` per modulus (``L`` of
    :func:`_family_L`), on the leave-one-family-out cases ``lf`` (:func:`lofo`): for each slope
    ``b >= 0`` the smallest ``a >= 0`` with at least ``coverage`` of the valid cases of *every*
    held-out family at *every* kt/kn (the groups ``by``; ``("held_out",)``: per family only)
    inside ``Q(kt) sqrt(1 + h/h_mean)``; of those the pair with the smallest mean Q over the valid
    cases. ``q_in``: the in-family scale (:func:`calibrate`), the floor: a new family is never
    stated better than a new protocol of a known one. ``exclude``: a family left out of the
    calibration (the nested check). Returns ``{"K": (a, b), "G": (a, b)}``."""
    v = lf[lf.valid & (lf.held_out != exclude)]
    L = _family_L(v.kt_over_kn.to_numpy())
    fams = v[list(by)].astype(str).agg("/".join, axis=1).to_numpy()
    out = {}
    for m in ("K", "G"):
        z = (v[f"err_{m}"].abs() / scale(v, m)).to_numpy()
        best = None
        for b in slopes:
            need = np.where(z > q_in[m] * (1 + 1e-12), z - b * L, -np.inf)   # a at which the case is inside
            a = max([0.0] + [float(np.quantile(need[fams == f], coverage, method="higher")) for f in set(fams)])
            obj = float(np.mean(np.maximum(q_in[m], a + b * L)))
            if best is None or obj < best[0] - 1e-12:
                best = (obj, a, float(b))
        out[m] = (float(np.ceil(best[1] * 1e6) / 1e6), best[2])   # rounded up: the quantile case stays inside
    return out


def family_error_table(lf, q_in, q_family):
    """Per held-out family (:func:`lofo`) and per protocol within it: valid cases, the fraction
    inside the in-family error (``Q sqrt(1 + h/h_mean)``, Q of the closure fitted without the family,
    as :func:`lofo_table`: *before*), inside the across-family error ``max(q_in, a + b L) sqrt(1 +
    h/h_mean)`` calibrated on all families (*after*), and inside it calibrated without the family
    (``nested_*``: the out-of-sample check), with the overclaims (valid, outside in K or G) of each."""
    rows = []
    nested = {f: calibrate_family(lf, q_in, exclude=f) for f in sorted(lf.held_out.unique())}
    for by in ("held_out", "protocol"):
        for u, g in lf.groupby(by, sort=True):
            gv = g[g.valid]
            d = dict(held_out=g.held_out.iloc[0], protocol="all" if by == "held_out" else u, valid=len(gv))
            ok = {}
            for tag, qf in (("before", None), ("after", q_family), ("nested", nested[g.held_out.iloc[0]])):
                for m in ("K", "G"):
                    sc = scale(gv, m).to_numpy()
                    q = gv[f"Q_{m}"].to_numpy() if qf is None else family_error_scale(gv.kt_over_kn.to_numpy(),
                                                                                      q_in[m], qf[m])
                    ok[tag, m] = gv[f"err_{m}"].abs().to_numpy() <= q * sc * (1 + 1e-12)
                    d[f"{tag}_inside_{m}"] = float(ok[tag, m].mean()) if len(gv) else np.nan
                    d[f"{tag}_stated_{m}"] = float(np.median(q * sc)) if len(gv) else np.nan
                d[f"{tag}_overclaims"] = int((~(ok[tag, "K"] & ok[tag, "G"])).sum())
            d.update(rms_K=float(np.sqrt(np.mean(gv.err_K ** 2))) if len(gv) else np.nan,
                     rms_G=float(np.sqrt(np.mean(gv.err_G ** 2))) if len(gv) else np.nan,
                     nested_a_K=nested[g.held_out.iloc[0]]["K"][0], nested_b_K=nested[g.held_out.iloc[0]]["K"][1])
            rows.append(d)
    return pd.DataFrame(rows)


#: Refit trials of issue 25 (item 2): the normal-force coefficient of variation ``fn_cv`` (std/mean
#: of the contact normal forces) as one more input, in both moduli or in G only.
FN_CV_TRIALS = (("the closure", ()), ("+ fn_cv (K and G)", ("fn_cv",)), ("+ fn_cv (G only)", {"G": ("fn_cv",)}),
                ("+ fn_cv (K only)", {"K": ("fn_cv",)}))


def family_trials(df, trials=FN_CV_TRIALS) -> pd.DataFrame:
    """Each trial (name, ``extra`` of :func:`fit`) measured both ways: leave one protocol out
    (``lopo_log_K``, ``lopo_log_G``: rms of the log error over every held-out case; ``lopo_worst_K``,
    ``lopo_worst_G``: the largest per-protocol rms of the valid cases, the LOPO target's figure)
    and leave one family out (per family: valid cases, rms of their relative errors, the fraction
    inside the nested stated error, overclaims). One row per trial and held-out family."""
    out = []
    for name, extra in trials:
        lo = lopo(df, extra)
        q, inside = calibrate(lo)
        tab = lopo_table(lo, q, inside)
        base = dict(trial=name, lopo_log_K=float(np.sqrt(np.mean(np.log1p(lo.err_K) ** 2))),
                    lopo_log_G=float(np.sqrt(np.mean(np.log1p(lo.err_G) ** 2))),
                    lopo_worst_K=float(tab.rms_K.max()), lopo_worst_G=float(tab.rms_G.max()))
        for _, r in lofo_table(lofo(df, extra)).iterrows():
            out.append(dict(base, held_out=r.held_out, valid=r.valid, rms_K=r.rms_K, rms_G=r.rms_G,
                            inside_K=r.inside_K, inside_G=r.inside_G, overclaims=r.overclaims,
                            rms_K_all=r.rms_K_all, rms_G_all=r.rms_G_all))
    return pd.DataFrame(out)


def candidates(df):
    """LOPO rms of log K and log G, the chosen features alone and with each candidate added to
    both moduli; plus the spread of log(K/K_mf), log(G/G_mf) with no model (the mean field alone)
    and the base without the statistics beyond Z, kt/kn."""
    K_mf, G_mf = mean_field(df)
    out = [dict(features="mean field only (no fit)", rms_logK=float(np.std(np.log(df.K / K_mf))),
                rms_logG=float(np.std(np.log(df.G / G_mf))))]
    core = ("1", "frictionless", "log kt/kn", "(log kt/kn)^2", "log dZ", "frictionless * log dZ")
    trials = [("Z - Z_iso and kt/kn only", (), core, core + ("log kt/kn * tanh(Z - 4)",)),
              ("previous closure (K: + rattler fraction, log p; G: + dispersity, r, size-coordination)", (),
               PREVIOUS_K, PREVIOUS_G),
              ("the closure", (), FEATURES_K, FEATURES_G),
              ("closure without psi6_local (K)", (), tuple(f for f in FEATURES_K if f != "psi6_local"), FEATURES_G),
              ("closure without log kt/kn * log dZ (G)", (), FEATURES_K,
               tuple(f for f in FEATURES_G if f != "log kt/kn * log dZ"))]
    for name in ("dispersity", "r", "size-coordination", "rattler fraction", "log10 p/kn", "psi6_local",
                 "log kt/kn * log dZ"):
        trials.append((f"core + {name}", (), core + (name,), core + ("log kt/kn * tanh(Z - 4)", name)))
    for c in CANDIDATES:
        if c not in df or df[c].isna().any():   # the pebble-game columns need the cached packings
            continue
        trials.append((f"closure + {c}", (c,), FEATURES_K, FEATURES_G))
    # the Maxwell term without the game: redundant constraints per particle, up to the factor
    # (2 - s)/2 (kt > 0) or 1/2 (kt = 0) and 2/N, linear in Z - Z_iso (the closure has log dZ)
    df = df.assign(maxwell_linear=(1.0 - df.rattler_fraction) * df.dZ)
    trials.append(("closure + (Z - Z_iso)(1 - x_r)", ("maxwell_linear",), FEATURES_K, FEATURES_G))
    for name, extra, nK, nG in trials:
        lo = lopo(df, extra, nK, nG)
        out.append(dict(features=name, rms_logK=float(np.sqrt(np.mean(np.log1p(lo.err_K) ** 2))),
                        rms_logG=float(np.sqrt(np.mean(np.log1p(lo.err_G) ** 2)))))
    return pd.DataFrame(out)


def plots(df, lo, folder):
    """closure_collapse.png: G/G_mf and K/K_mf against Z - Z_iso (marker: protocol; colour: kt/kn,
    black: kt = 0), and the leave-one-protocol-out predictions of G and K against the exact ones."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    K_mf, G_mf = mean_field(df)
    prots = sorted(df.protocol.unique())
    marks = dict(zip(prots, "osD^v<>"))
    fig, ax = plt.subplots(1, 4, figsize=(19, 4.6))
    fr = (df.kt_over_kn > 0).to_numpy()
    for p in prots:
        m = (df.protocol == p).to_numpy()
        for a_, y in ((ax[0], df.G / G_mf), (ax[1], df.K / K_mf)):
            sc = a_.scatter(df.dZ[m & fr], y[m & fr], marker=marks[p], s=16, c=np.log10(df.kt_over_kn[m & fr]),
                            cmap="viridis", vmin=np.log10(0.05), vmax=0, label=p)
            if (m & ~fr).any():
                a_.scatter(df.dZ[m & ~fr], y[m & ~fr], marker=marks[p], s=22, facecolors="none", edgecolors="k")
    x = np.logspace(-1.5, 0.5)
    ax[0].plot(x, x / (x + 1), "r:", lw=1, label="dZ / (dZ + 1)")
    for a_, yl in ((ax[0], "G / G_mf"), (ax[1], "K / K_mf")):
        a_.set_xscale("log")
        a_.set_xlabel("Z - Z_iso   (Z_iso = 4 if kt = 0, else 6/(2 - s))")
        a_.set_ylabel(yl + "   (mean field of the load-bearing particles)")
    ax[0].set_yscale("log")
    ax[0].legend(fontsize=7, loc="lower right")
    ax[0].set_title("G: colour log10 kt/kn, open black: kt = 0")
    ax[1].set_title("K")
    fig.colorbar(sc, ax=ax[1], label="log10 kt/kn")
    e = lo.merge(df[["key", "kt_over_kn", "G", "K"]], on=["key", "kt_over_kn"])
    for a_, m in ((ax[2], "G"), (ax[3], "K")):
        for p in prots:
            sel = e.protocol == p
            a_.scatter(e[m][sel], e[m][sel] * (1 + e[f"err_{m}"][sel]), marker=marks[p], s=14, label=p)
        lim = np.array([e[m].min() * 0.8, e[m].max() * 1.2])
        a_.plot(lim, lim, "k-", lw=0.8)
        a_.plot(lim, lim * 1.1, "k:", lw=0.6)
        a_.plot(lim, lim / 1.1, "k:", lw=0.6)
        a_.set_xscale("log")
        a_.set_yscale("log")
        a_.set_xlabel(f"exact {m} / kn")
        a_.set_ylabel(f"closure {m} / kn, its protocol left out")
        a_.set_title(f"leave one protocol out: {m} (dotted: +-10 %)")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(folder / "closure_collapse.png", dpi=100)
    plt.close(fig)


def bench(n=1_000_000):
    rng = np.random.default_rng(0)
    args = dict(nc=rng.uniform(3.3, 5.3, n), r=rng.uniform(0.02, 0.06, n), phi=rng.uniform(0.82, 0.9, n),
                kt_over_kn=rng.uniform(0.05, 1, n), dispersity=rng.uniform(0, 0.5, n),
                size_coordination=rng.uniform(0, 0.1, n), rattler_fraction=rng.uniform(0, 0.1, n),
                p_over_kn=10 ** rng.uniform(-4, -2, n), psi6_local=rng.uniform(0.5, 0.8, n))
    predict_closure(**{k: v[:10] for k, v in args.items()})
    t0, c0 = time.perf_counter(), time.process_time()
    predict_closure(**args)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    print(f"predict_closure: {n} sets in {dc:.3f} s of CPU = {n / dc:.3g} sets/s per core "
          f"(wall {dt:.3f} s at load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    return n / dc


def data_ranges(df) -> dict:
    """The box of the corpus's usable rows (the closure flags inputs outside it)."""
    fr = df[df.kt_over_kn > 0]
    zs = df.Z_size - df.Z
    rd = lambda a, b: (float(np.floor(a * 1e4) / 1e4), float(np.ceil(b * 1e4) / 1e4))
    return {"Z": rd(df.Z.min(), df.Z.max()), "kt_over_kn": rd(fr.kt_over_kn.min(), fr.kt_over_kn.max()),
            "dispersity": rd(df.dispersity.min(), df.dispersity.max()), "r": rd(df.r.min(), df.r.max()),
            "phi": rd(df.phi.min(), df.phi.max()), "p_over_kn": (float(df.p_over_kn.min()), float(df.p_over_kn.max())),
            "size_coordination": rd(zs.min(), zs.max()),
            "rattler_fraction": rd(df.rattler_fraction.min(), df.rattler_fraction.max()),
            "psi6_local": rd(df.psi6_local.min(), df.psi6_local.max())}


def stored_model_text(cK, cG, covK, covG, q, h_mean, h_max, q_family=None):
    f = lambda a: np.array2string(np.asarray(a), precision=8, separator=", ", max_line_width=100,
                                  floatmode="maxprec")
    return (f"COEF_K = np.array({f(cK)})\nCOEF_G = np.array({f(cG)})\nCOV_K = np.array({f(covK)})\n"
            f"COV_G = np.array({f(covG)})\nQ = {{'K': {q['K']:.6g}, 'G': {q['G']:.6g}}}\n"
            f"H_MEAN = {{'K': {h_mean['K']:.6g}, 'G': {h_mean['G']:.6g}}}\n"
            f"H_MAX = {{'K': {h_max['K']:.6g}, 'G': {h_max['G']:.6g}}}\n"
            + ("" if q_family is None else
               f"Q_FAMILY = {{'K': ({q_family['K'][0]:.6g}, {q_family['K'][1]:.6g}), "
               f"'G': ({q_family['G'][0]:.6g}, {q_family['G'][1]:.6g})}}\n"))


def quick_end_to_end():
    """One small frictionless packing, built and measured, against the stored closure (CI)."""
    from studies.corpus import _row, build_network, measure_network
    import tempfile
    row = _row("pack_frictionless", 200, 5, p_over_kn=1e-2, dispersity=0.3)
    with tempfile.TemporaryDirectory() as tmp:
        net, _ = build_network(row, Path(tmp))
        m = pd.DataFrame(measure_network(net, row, (0.0, 1.0)))
    p = predict_closure(nc=m.Z.to_numpy(), r=m.r.to_numpy(), phi=m.phi.to_numpy(), kt_over_kn=m.kt_over_kn.to_numpy(),
                        dispersity=m.dispersity.to_numpy(), sliding_fraction=m.sliding_fraction.to_numpy(),
                        size_coordination=(m.Z_size - m.Z).to_numpy(), rattler_fraction=m.rattler_fraction.to_numpy(),
                        p_over_kn=m.p_over_kn.to_numpy(), psi6_local=m.psi6_local.to_numpy())
    m["closure_G"], m["err_G"], m["stated_G"], m["valid"] = p.G, p.G / m.G - 1, p.rel_error_G, p.valid
    print(m[["kt_over_kn", "Z", "dZ", "r", "K", "G", "closure_G", "err_G", "stated_G", "valid"]].to_string(index=False))
    return m


#: kt/kn at which held-out files are analysed (issue 25: 0, 0.2, 0.5, 1)
HELDOUT_KT = (0.0, 0.2, 0.5, 1.0)


def heldout(paths, kt_ratios=HELDOUT_KT, hierarchy=False) -> pd.DataFrame:
    """Packing files made elsewhere (any ``dem.io`` format: DEMPLA/OVAL D-file, LAMMPS data/dump,
    npz, CSV), never in the fit: contacts from the overlaps (kn = 1, linear: fn = kn * overlap),
    exact response and closure at each kt/kn.

    One row per file and kt/kn: the statistics of ``studies.corpus.network_features``, the exact
    ``K``, ``G`` (no pre-stress, kn = 1), the closure's ``closure_K``, ``closure_G``, relative errors
    ``err_K``, ``err_G``, stated errors ``stated_K``, ``stated_G`` (across families, the default) and
    ``stated_K_in_family``, ``stated_G_in_family``, ``valid``, ``flags`` (bits of
    ``microhom.closure``), ``reason``, ``inside_K``/``inside_G`` (|err| <= stated) and
    ``overclaim`` (valid but outside its stated error in K or G: the defect the held-out test
    looks for). ``hierarchy=True`` adds the relaxation hierarchy's certified bounds
    (``hier_G``, ``hier_G_upper``, ``hier_G_lower``; same for K) at kt/kn > 0.
    """
    from dem.analysis.analyse import load_network
    from studies.corpus import CorpusRow, measure_network
    frames = []
    for path in paths:
        with warnings.catch_warnings():   # D-files warn that OVAL's kn convention is not given: kn = 1 here
            warnings.simplefilter("ignore")
            net, _ = load_network(path, kn=1.0, kt_ratio=1.0)
        net = net.with_stiffness(kn=1.0, kt=1.0, sliding=False)
        if net.fn is None:   # positions only: linear contacts, forces from the overlaps
            from dataclasses import replace
            net = replace(net, fn=np.maximum(net.overlaps, 0.0) * net.kn, ft=np.zeros(net.n_contacts))
        row = CorpusRow("heldout", (("file", str(path)),), 0, net.n_particles)
        m = pd.DataFrame(measure_network(net, row, kt_ratios))
        m["file"] = Path(path).name
        if hierarchy:
            m = m.assign(**_hierarchy_columns(net, kt_ratios))
        frames.append(m)
    df = pd.concat(frames, ignore_index=True)
    ok = df.K.notna() & (df.Z > 0)
    p = predict_closure(nc=np.where(ok, df.Z, 4.0), r=np.where(ok, df.r, 0.0), phi=df.phi.to_numpy(),
                        kt_over_kn=df.kt_over_kn.to_numpy(), dispersity=df.dispersity.to_numpy(),
                        sliding_fraction=np.where(ok, df.sliding_fraction, 0.0),
                        size_coordination=np.where(ok, df.Z_size - df.Z, 0.0),
                        rattler_fraction=np.where(ok, df.rattler_fraction, 0.0),
                        p_over_kn=np.where(ok & (df.p_over_kn > 0), df.p_over_kn, 1e-3),
                        psi6_local=np.where(ok, df.psi6_local, 0.6), n_particles=df.n.to_numpy())
    df["closure_K"], df["closure_G"] = p.K, p.G
    df["err_K"], df["err_G"] = p.K / df.K - 1, p.G / df.G - 1
    df["stated_K"], df["stated_G"] = p.rel_error_K, p.rel_error_G
    df["stated_K_in_family"], df["stated_G_in_family"] = p.rel_error_K_in_family, p.rel_error_G_in_family
    df["valid"], df["flags_closure"] = p.valid & ok.to_numpy(), np.where(ok, p.flags, -1)
    df["reason"] = np.where(ok, p.reason, "no exact response")
    df["inside_K"] = np.abs(df.err_K) <= df.stated_K
    df["inside_G"] = np.abs(df.err_G) <= df.stated_G
    df["overclaim"] = df.valid & ~(df.inside_K & df.inside_G)
    df["overclaim_in_family"] = df.valid & ~((np.abs(df.err_K) <= df.stated_K_in_family)
                                             & (np.abs(df.err_G) <= df.stated_G_in_family))
    return df


def _hierarchy_columns(net, kt_ratios) -> dict:
    """The relaxation hierarchy's estimate and rigorous bounds of K and G at each kt/kn > 0 (NaN at
    kt = 0, where the hierarchy's frictional bounds do not apply)."""
    from microhom.hierarchy import relaxation_hierarchy
    cols = {f"hier_{m}{s}": [] for m in ("K", "G") for s in ("", "_upper", "_lower")}
    for kr in kt_ratios:
        h = relaxation_hierarchy(net.with_stiffness(kt=kr * np.asarray(net.kn)), tol=0.01) if kr > 0 else None
        for m in ("K", "G"):
            e = getattr(h, m) if h is not None else None
            for s, attr in (("", "value"), ("_upper", "upper"), ("_lower", "lower")):
                v = getattr(e, attr) if e is not None else None
                cols[f"hier_{m}{s}"].append(float(v) if v is not None else np.nan)
    return cols


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="out/closure/cache")
    ap.add_argument("--out", default="out/closure")
    ap.add_argument("--quick", action="store_true", help="the committed corpus summary + one small packing")
    ap.add_argument("--no-build", action="store_true", help="use only the cached rows of the corpus")
    ap.add_argument("--bench", action="store_true", help="measure predict_closure's throughput")
    ap.add_argument("--no-candidates", action="store_true")
    ap.add_argument("--trials", action="store_true",
                    help="the fn_cv refit trials, LOPO and leave one family out (with --quick too; always without)")
    ap.add_argument("--heldout", nargs="*", default=[], help="packing files from other codes (held out)")
    ap.add_argument("--hierarchy", action="store_true", help="with --heldout: the relaxation hierarchy's bounds too")
    args = ap.parse_args(argv)
    out = cli_out_dir(args.out)  # checked before computing (one line and exit 1 otherwise)
    t0 = time.perf_counter()
    pd.set_option("display.width", 220)
    if args.quick:
        raw = pd.read_csv(SUMMARY, keep_default_na=False, na_values=[""])
    else:
        from studies.corpus import load_corpus
        raw = load_corpus(args.cache, build=not args.no_build, verbose=False)
        from studies.closure_transfer import contact_columns
        raw = contact_columns(rigidity_columns(raw[[c for c in COLUMNS if c in raw.columns]], args.cache), args.cache)
        raw.to_csv(out / "corpus.csv", index=False)
    df = usable(raw)
    print(f"corpus: {raw.key.nunique()} packings, {len(raw)} rows (x kt/kn); {len(df)} usable "
          f"(jammed, Z - Z_iso >= {DZ_MIN}); per protocol: {df.groupby('protocol').key.nunique().to_dict()}")
    cK, cG, covK, covG = fit(df)
    XK, _ = design(df, FEATURES_K)
    XG, _ = design(df, FEATURES_G)
    hK = np.einsum("ij,jk,ik->i", XK, covK, XK)
    hG = np.einsum("ij,jk,ik->i", XG, covG, XG)
    lo = lopo(df)
    q, inside = calibrate(lo)
    h_mean = {"K": float(hK.mean()), "G": float(hG.mean())}
    h_max = {"K": float(3.0 * hK.max()), "G": float(3.0 * hG.max())}
    tab = lopo_table(lo, q, inside)
    lf = lofo(df)
    q_family = calibrate_family(lf, q)
    print("features K:", FEATURES_K, "\nfeatures G:", FEATURES_G)
    print(stored_model_text(cK, cG, covK, covG, q, h_mean, h_max, q_family))
    print("leave one protocol out (relative errors; stated error Q sqrt(1 + h/h_mean)):")
    print(tab.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    write_table(tab, out, "lopo", "Closure, leave one protocol out",
                f"Q_K = {q['K']:.4f}, Q_G = {q['G']:.4f}; {len(df)} usable rows.")
    ftab, fprot = lofo_table(lf), lofo_table(lf, "protocol")
    print("leave one preparation family out (families:", FAMILIES, ")\n  valid: not flagged by the closure "
          "fitted without the family (its leverage and box); stated error: Q of that closure's own LOPO:")
    for t in (ftab, fprot):
        print(t.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    write_table(pd.concat([ftab, fprot], ignore_index=True), out, "lofo", "Closure, leave one preparation family out",
                "Per family, then per protocol within it; Q of the closure fitted without the family.")
    lf.to_csv(out / "lofo_cases.csv", index=False)
    etab = family_error_table(lf, q, q_family)
    print("the stated error on each held-out family: in-family Q (before), across-family Q(kt) = "
          f"max(Q, a + b ln(kn/kt)) (after; {q_family}), and the latter calibrated without the family (nested):")
    print(etab.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    write_table(etab, out, "family_error", "Closure, stated error on held-out families: in-family and across-family",
                f"Q_FAMILY = {q_family}; before: in-family Q of the closure fitted without the family.")
    if args.trials or not (args.quick or args.no_candidates):
        tri = family_trials(df)
        print("refit trials (normal-force coefficient of variation), LOPO and leave one family out:")
        print(tri.to_string(index=False, float_format=lambda x: f"{x:.4f}"))
        write_table(tri, out, "family_trials", "Refit trials: LOPO and leave one family out")
    ranges = data_ranges(df)
    print("RANGES =", ranges)
    (out / "model.json").write_text(json.dumps(dict(coef_K=list(cK), coef_G=list(cG), cov_K=covK.tolist(),
                                                    cov_G=covG.tolist(), Q=q, h_mean=h_mean, h_max=h_max,
                                                    q_family=q_family,
                                                    ranges=ranges)))
    lo.to_csv(out / "lopo_cases.csv", index=False)
    if not args.quick:
        raw.to_csv(out / "closure_corpus.csv", index=False)
        if not args.no_candidates:
            cand = candidates(df)
            print(cand.to_string(index=False, float_format=lambda x: f"{x:.4f}"))
            write_table(cand, out, "candidates", "Candidate statistics: LOPO rms of log K, log G")
        plots(df, lo, out)
    else:
        quick_end_to_end().to_csv(out / "quick.csv", index=False)
    if args.heldout:
        ho = heldout(args.heldout, hierarchy=args.hierarchy)
        cols = ["file", "n", "kt_over_kn", "Z", "dZ", "r", "phi", "dispersity", "K", "closure_K", "err_K",
                "stated_K", "stated_K_in_family", "G", "closure_G", "err_G", "stated_G", "stated_G_in_family", "valid",
                "flags_closure", "overclaim", "overclaim_in_family"]
        cols += [c for c in ho.columns if c.startswith("hier_")]
        print("held-out packings (not in the fit):")
        print(ho[cols].to_string(index=False, float_format=lambda x: f"{x:.4g}"))
        write_table(ho[cols], out, "heldout", "Closure on held-out packing files")
    if args.bench:
        bench()
    print(f"written {out} ({time.perf_counter() - t0:.0f} s)")
    return tab


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
