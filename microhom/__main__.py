"""Command line: ``python -m microhom predict ...`` (theory) and ``python -m microhom analyse FILE``.

Examples::

    python -m microhom predict                       # the seed paper's case (Kuhn's simulations)
    python -m microhom predict --kn 1e8 --kt 0 --nc 4.1 --phi 0.82 --r 0.35 --alpha 1.76
    python -m microhom predict --nc 3.8 4.1 4.5 --json
    python -m microhom analyse packing.dump --kn 1e5 --kt 5e4     # any file dem.io reads
    python -m microhom analyse D0001 --kn 2e8 --kn-convention oval --json

``analyse`` measures a packing file (contacts, structural sums, rho, stress) and puts the theory
beside the exact stiffness tensor. Its engine is :mod:`dem.analyse`, imported lazily *inside* the
command function only: the library modules of ``microhom`` never import ``dem`` (the arrows point
studies -> dem -> microhom), so ``predict`` works without the DEM and its numba kernels.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from .moduli import predict_moduli

SEED_CASE = dict(kn=1.0e8, kt=1.0e8, nc=4.1, phi=0.82, r=0.35, alpha=1.76, nbar=5.0)


def _floats(name):
    def conv(text):
        try:
            return float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
    return conv


def build_parser():
    ap = argparse.ArgumentParser(prog="python -m microhom",
                                 description="Micromechanical homogenisation of dense random disk packings.")
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser(
        "predict", help="mean-field and fluctuation-corrected 2D bulk and shear moduli",
        description="Predict the incremental 2D bulk modulus K and shear modulus G of an isotropic random "
                    "packing of identical disks (paper eqs. 37, 50, 51, 54). Several values per option "
                    "broadcast (one row per combination). Defaults: the seed paper's case.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--kn", nargs="+", type=_floats("kn"), default=[SEED_CASE["kn"]],
                   help="normal contact stiffness [N/m], > 0 (2D: force per unit thickness per unit overlap)")
    p.add_argument("--kt", nargs="+", type=_floats("kt"), default=None,
                   help="tangential contact stiffness [N/m], >= 0; default kt = kn; 0 = frictionless/sliding")
    p.add_argument("--nc", nargs="+", type=_floats("nc"), default=[SEED_CASE["nc"]],
                   help="mean coordination number Nc (contacts per particle), > 0")
    p.add_argument("--phi", nargs="+", type=_floats("phi"), default=[SEED_CASE["phi"]],
                   help="solid (area) fraction, in (0, pi/(2 sqrt 3)] = (0, 0.9069]")
    p.add_argument("--r", nargs="+", type=_floats("r"), default=[SEED_CASE["r"]],
                   help="contact-number fluctuation r = var(Nc)/Nc^2 [-], >= 0 (0 = mean field)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--alpha", nargs="+", type=_floats("alpha"), default=None,
                   help="alignment width of the V-W correlation model (54), in [0, 2]; "
                        f"default {SEED_CASE['alpha']} (the paper's fit) unless --rho is given")
    g.add_argument("--rho", nargs="+", type=_floats("rho"), default=None,
                   help="measured rho = Nc sum V.W / sum V^2 (replaces the alpha model)")
    p.add_argument("--nbar", nargs="+", type=_floats("nbar"), default=None,
                   help="mean number of near neighbours; default from phi via phi = (pi/4)/sin(pi(Nbar-2)/Nbar) "
                        "(needs phi >= pi/4); with all defaults the paper's Nbar = 5")
    p.add_argument("--max-correction", type=float, default=0.5,
                   help="fraction change above which a result is flagged outside the first-order range")
    p.add_argument("--json", action="store_true", help="print JSON (a list of records) instead of a table")
    p.add_argument("--csv", action="store_true", help="print CSV instead of a table")

    a = sub.add_parser(
        "analyse", help="measure a packing file and compare the theory with its exact stiffness",
        description="Read a packing (LAMMPS dump/data, OVAL D-file, dem.io npz/CSV, a dem.packing npz, or a "
                    "dem.lammps run folder), build its contact network and print coordination with and "
                    "without rattlers, structural sums (vbar, ebar measured vs eq. 37), measured rho, stress "
                    "(when the file has contact forces), the theory's moduli (mean field; corrected with the "
                    "measured rho and with the alignment model) and the exact stiffness tensor (dem.stiffness). "
                    "Moduli and stresses in 2D are force per length, in the units of kn and the file.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    a.add_argument("file", help="packing file or dem.lammps run folder")
    a.add_argument("--format", default=None,
                   help="lammps-data, lammps-dump, oval, npz, csv, vtk, packing (dem.packing npz) or lammps-run "
                        "(folder); default from the name/extension")
    a.add_argument("--kn", type=_floats("kn"), default=None,
                   help="normal contact stiffness [N/m] (force per unit overlap), > 0; default 1 (moduli in units "
                        "of kn). Ignored for files that carry their contact law (packing npz, LAMMPS run folder)")
    a.add_argument("--kt", type=_floats("kt"), default=None, help="tangential stiffness [N/m], >= 0; default kt = kn")
    a.add_argument("--kn-convention", choices=("standard", "oval"), default=None,
                   help="'oval': --kn is OVAL's, which multiplies half the overlap (the network gets kn/2)")
    a.add_argument("--branch-length", choices=("distance", "radii"), default="distance",
                   help="branch vectors: centre distance, or direction kept with length r_i + r_j (paper's |c| = D)")
    a.add_argument("--alpha", type=_floats("alpha"), default=None,
                   help="alignment width of the model-rho prediction (54), in [0, 2]; default 2(1 - 1/Nbar)")
    a.add_argument("--prestress", action="store_true",
                   help="exact stiffness with the pre-stress terms (normal forces from the file, else kn*overlap)")
    a.add_argument("--min-contacts", type=int, default=None,
                   help="rattler threshold; default 2 for frictional, 3 for frictionless particles")
    a.add_argument("--frame", type=int, default=0, help="frame of a LAMMPS dump (negative from the end)")
    a.add_argument("--no-exact", action="store_true", help="skip the exact stiffness (one sparse factorisation)")
    out = a.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="print JSON instead of a table")
    out.add_argument("--csv", action="store_true", help="print one CSV row (flattened section.key columns)")
    return ap


def _grid(args):
    cols = {"kn": args.kn, "kt": args.kt if args.kt is not None else [None], "nc": args.nc, "phi": args.phi,
            "r": args.r}
    if args.rho is not None:
        cols["rho"] = args.rho
    else:
        cols["alpha"] = args.alpha if args.alpha is not None else [SEED_CASE["alpha"]]
    defaults = all(getattr(args, k) == [SEED_CASE[k]] for k in ("nc", "phi")) and args.nbar is None
    cols["nbar"] = args.nbar if args.nbar is not None else ([SEED_CASE["nbar"]] if defaults else [None])
    names = list(cols)
    mesh = np.meshgrid(*[np.arange(len(cols[n])) for n in names], indexing="ij")
    rows = []
    for idx in zip(*(m.ravel() for m in mesh)):
        row = {n: cols[n][i] for n, i in zip(names, idx)}
        if row["kt"] is None:
            row["kt"] = row["kn"]
        rows.append(row)
    return rows


def cmd_predict(args):
    import pandas as pd

    rows = _grid(args)
    frames = []
    for row in rows:
        kw = {k: v for k, v in row.items() if v is not None}
        p = predict_moduli(max_correction=args.max_correction, warn=False, **kw)
        f = p.to_frame()
        for k in ("r", "phi", "nc", "kt", "kn"):
            f.insert(0, k, row[k])
        frames.append(f)
    df = pd.concat(frames, ignore_index=True)
    if args.json:
        print(df.to_json(orient="records", indent=1))
    elif args.csv:
        print(df.to_csv(index=False), end="")
    else:
        for i, r in df.iterrows():
            print(f"case {i}: kn = {r.kn:.4g} N/m, kt = {r.kt:.4g} N/m, Nc = {r.nc:.4g}, phi = {r.phi:.4g}, "
                  f"r = {r.r:.4g}, Nbar = {r.nbar:.4g}, rho = {r.rho:.4g}")
            print(f"  {'modulus':<8}{'mean field':>14}{'corrected':>14}{'fraction change':>18}")
            print(f"  {'bulk K':<8}{r.K_mf:>14.4g}{r.K:>14.4g}{r.drop_K:>18.3f}")
            print(f"  {'shear G':<8}{r.G_mf:>14.4g}{r.G:>14.4g}{r.drop_G:>18.3f}")
            print(f"  Delta = (G-K)/(G+K): mean field {r.delta_mf:.4f}, corrected {r.delta:.4f}; "
                  f"2D Poisson ratio {r.poisson:.4f}")
            print(f"  validity: {'ok' if r.valid else 'FLAGGED: ' + r.reason}")
    return 0 if bool(df["valid"].all()) else 3


def cmd_analyse(args):
    """``analyse``: the only place this package touches dem (lazy import, see the module docstring)."""
    from dem import analyse as dan  # lazy: microhom's library modules never import dem

    res = dan.analyse_file(args.file, args.format, kn=args.kn, kt=args.kt, kn_convention=args.kn_convention,
                           branch_length=args.branch_length, alpha=args.alpha, prestress=args.prestress,
                           min_contacts=args.min_contacts, frame=args.frame, exact=not args.no_exact)
    if args.json:
        print(json.dumps(res, indent=1, default=_jsonable))
    elif args.csv:
        import csv
        import io

        flat = dan.flatten(res)
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(flat))
        w.writeheader()
        w.writerow(flat)
        print(buf.getvalue(), end="")
    else:
        print(dan.format_table(res))
    return 0


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        if args.command == "analyse":
            return cmd_analyse(args)
        return cmd_predict(args)
    except (ValueError, OSError, IndexError) as exc:  # dem.io.FormatError is a ValueError
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
