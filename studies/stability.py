"""Stiff and extreme cases: each gives a finite, checked answer or a clear error, in one table.

    python -m studies.stability [--quick] [--out DIR]

Cases: kt/kn from 0 to 10, kn over fifteen decades, alpha at and around 1, r -> 0, corrections
larger than the mean field, phi at close packing and below pi/4, singular B (kt = 0), floppy
lattices (square and honeycomb with kt = 0), a near-singular stiffness matrix (kt/kn = 1e-12),
stiffness scale invariance over ten decades of kn, and (with DEM packings) near-jamming pressure
and many rattlers. For each: the outcome (``ok``, ``flagged`` or ``error``), the value, the
reference it is checked against, the relative error and the run time.
"""
from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np
import pandas as pd

from dem.analysis.stiffness import stiffness
from microhom import lattices
from microhom.moduli import predict_from_network, predict_moduli, rho_from_alpha
from microhom.structural_sums import particle_sums
from studies.cases import DEFAULTS, get_packing
from studies.common import EXIT_NO_OUTPUT, cli_out_dir, write_table

ROWS = []


def case(category, name, fn, reference=None, tol=1e-10):
    """Run ``fn() -> value`` (float); record value, reference, relative error, outcome, time."""
    t0 = time.perf_counter()
    outcome, value, msg = "ok", np.nan, ""
    try:
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            value = fn()
        if w:
            outcome, msg = "flagged", str(w[0].message)
    except ValueError as exc:
        outcome, msg = "error", str(exc)
    dt = time.perf_counter() - t0
    rel = np.nan
    if reference is not None and outcome != "error":
        rel = abs(value - reference) / max(abs(reference), 1e-300)
        if not np.isfinite(value) or rel > tol:
            outcome = "WRONG"
    elif outcome != "error" and not np.isfinite(value):
        outcome = "WRONG"
    ROWS.append({"category": category, "case": name, "outcome": outcome, "value": value,
                 "reference": np.nan if reference is None else reference, "rel_error": rel,
                 "message": msg[:160], "run_time_s": dt})


def theory_cases():
    nc, phi, r = 4.1, 0.82, 0.2
    for ratio in (0.0, 1e-12, 1e-3, 0.25, 1.0, 2.0, 10.0):
        x = r * float(predict_moduli(1, ratio, nc, phi, r, alpha=1.5).nbar) / nc * float(rho_from_alpha(1.5))
        case("kt/kn", f"K, G at kt/kn = {ratio:g}",
             lambda ratio=ratio: float(predict_moduli(1.0, ratio, nc, phi, r, alpha=1.5).G),
             reference=nc * phi * (1 + ratio) / (4 * math.pi) * (1 - 2 * (2 + ratio) / (3 + ratio) * x))
    for kn in (1e-3, 1.0, 1e6, 1e9, 1e12, 1e15):
        case("kn decades", f"K/kn at kn = {kn:g} N/m",
             lambda kn=kn: float(predict_moduli(kn, kn, nc, phi, r, alpha=1.5).K) / kn,
             reference=float(predict_moduli(1.0, 1.0, nc, phi, r, alpha=1.5).K), tol=1e-14)
    for a in (1.0 - 1e-12, 1.0, 1.0 + 1e-12, 1.0 + 1e-6, 2.0):
        ref = math.pi / 4 if abs(a - 1) < 1e-9 else math.cos(math.pi * a / 2) / (1 - a * a)
        case("alpha", f"rho(alpha = {a!r})", lambda a=a: float(rho_from_alpha(a)), reference=ref,
             tol=1e-3 if abs(a - 1) < 1e-9 else 1e-9)
    case("alpha", "alpha = 2.5 (outside [0, 2])", lambda: float(rho_from_alpha(2.5)))
    case("r", "r = 0 gives exactly the mean field", lambda: float(predict_moduli(1, 1, nc, phi, 0.0).K),
         reference=nc * phi / (2 * math.pi), tol=0.0)
    case("r", "r = 1.5: correction larger than the mean field",
         lambda: float(predict_moduli(1, 1, nc, phi, 1.5, alpha=1.0).K))
    case("phi", "phi = pi/(2 sqrt 3) (close packing)",
         lambda: float(predict_moduli(1, 0, 6, math.pi / (2 * math.sqrt(3)), 0.0).K),
         reference=math.sqrt(3) / 2)
    case("phi", "phi = 0.7 without nbar (Nbar(phi) undefined)", lambda: float(predict_moduli(1, 1, 4, 0.7, 0.1).K))
    case("phi", "phi = 0.7 with nbar = 4.5", lambda: float(predict_moduli(1, 1, 4, 0.7, 0.1, nbar=4.5).K))
    case("input", "negative kt", lambda: float(predict_moduli(1, -1, 4, 0.82, 0.1).K))
    case("input", "NaN in Nc", lambda: float(predict_moduli(1, 1, float("nan"), 0.82, 0.1).K))
    net = lattices.triangular(6, 6, kn=1.0, kt=0.0)
    case("singular B", "particle B with kt = 0 (moment balance void)", lambda: float(np.max(np.abs(particle_sums(net).B))),
         reference=0.0, tol=np.inf)
    case("singular B", "Z = A where B = 0 (no NaN)",
         lambda: float(np.max(np.abs(particle_sums(net).Z - np.einsum("npstk->npkst", particle_sums(net).A4)))),
         reference=0.0, tol=np.inf)


def stiffness_cases():
    s3 = math.sqrt(3)
    for ratio in (0.0, 1e-12, 1e-3, 1.0, 10.0):
        case("lattice stiffness", f"triangular G/kn, kt/kn = {ratio:g}",
             lambda ratio=ratio: stiffness(lattices.triangular(6, 6, kn=1.0, kt=ratio)).G,
             reference=s3 / 4 * (1 + ratio), tol=1e-9)
    for ratio in (1e-12, 1e-6, 1.0, 10.0):
        case("lattice stiffness", f"honeycomb G/kn (entirely non-affine), kt/kn = {ratio:g}",
             lambda ratio=ratio: stiffness(lattices.honeycomb(4, 3, kn=1.0, kt=ratio)).G,
             reference=ratio / (s3 * (1 + ratio)),
             tol=max(1e-9, 100 * np.finfo(float).eps / ratio))  # G ~ kt << kn: accuracy ~ eps kn/kt
    for kn in (1e-3, 1e3, 1e9, 1e15):
        case("lattice stiffness", f"honeycomb K/kn at kn = {kn:g}",
             lambda kn=kn: stiffness(lattices.honeycomb(4, 3, kn=kn, kt=kn)).K / kn,
             reference=1 / (2 * s3), tol=1e-9)
    case("floppy", "square lattice kt = 0: C1212 (floppy modes reported)",
         lambda: stiffness(lattices.square(5, 5, kn=1.0, kt=0.0)).C[0, 1, 0, 1], reference=0.0, tol=np.inf)
    case("floppy", "square lattice kt = 0: number of floppy modes",
         lambda: float(stiffness(lattices.square(5, 5, kn=1.0, kt=0.0)).n_floppy))
    case("floppy", "honeycomb kt = 0: G (mechanism)",
         lambda: stiffness(lattices.honeycomb(4, 3, kn=1.0, kt=0.0)).G, reference=0.0, tol=np.inf)


def packing_cases(n):
    """Near-jamming pressures and a many-rattler packing: the exact solver and the theory on them."""
    for label, kw in (("p/kn = 1e-5", dict(p_over_kn=1e-5)), ("p/kn = 1e-6 (near jamming)", dict(p_over_kn=1e-6)),
                      ("mu_prep = 1 (many rattlers)", dict(mu_prep=1.0))):
        res, _, _ = get_packing({**DEFAULTS, "n": n, "seed": 1, **kw})
        net = res.to_network()
        holder = {}

        def exact_G(net=net, holder=holder):
            e = stiffness(net, prestress=True)
            holder["e"] = e
            return e.G

        case("packings", f"exact G/kn, {label}", exact_G)
        e = holder.get("e")
        if e is not None:
            ROWS[-1]["message"] = (f"N = {n}, rattlers {e.n_rattlers}, floppy {e.n_floppy}, "
                                   f"unstable {e.n_unstable}, G/G_affine = {e.G / e.G_affine:.3f}")
        case("packings", f"theory G/kn (measured rho), {label}", lambda net=net: float(predict_from_network(net).G))


def main(argv=None):
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"exit codes: 0 every case right (ok, flagged or a clear error), 1 a case WRONG, "
               f"{EXIT_NO_OUTPUT} --out cannot be written (checked before computing), 2 usage")
    ap.add_argument("--quick", action="store_true", help="skip the DEM packing cases (near jamming, rattlers)")
    ap.add_argument("--out", default="out/stability",
                    help="output folder (CSV, markdown); the packing cache follows it")
    args = ap.parse_args(argv)
    cli_out_dir(args.out)
    ROWS.clear()
    theory_cases()
    stiffness_cases()
    if not args.quick:
        packing_cases(1000)
    df = pd.DataFrame(ROWS)
    pd.set_option("display.width", 200)
    pd.set_option("display.max_colwidth", 70)
    print(df.drop(columns=["message"]).to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    bad = df[df.outcome == "WRONG"]
    md = write_table(df, args.out, "stability", "Stiff and extreme cases",
                     f"{len(df)} cases: {sum(df.outcome == 'ok')} ok, {sum(df.outcome == 'flagged')} flagged, "
                     f"{sum(df.outcome == 'error')} clear errors, {len(bad)} wrong.")
    print(f"\n{len(df)} cases, {len(bad)} wrong; table: {md}")
    return 1 if len(bad) else 0


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
