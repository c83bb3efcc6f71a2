"""Command line of the theory: ``python -m microhom predict ...`` (also the ``microhom`` console script).

Examples::

    python -m microhom predict                       # the seed paper's case (Kuhn's simulations)
    python -m microhom predict --kn 1e8 --kt 0 --nc 4.1 --phi 0.82 --r 0.35 --alpha 1.76
    python -m microhom predict --nc 3.8 4.1 4.5 --json

Measuring a packing file moved to the DEM package, where its engine lives:
``python -m dem analyse FILE`` (this package never imports ``dem``, lazily included).

Exit codes (the convention of :mod:`microhom.cli`, shared with ``python -m dem`` and the
studies): 0 every result valid; 3 at least one result flagged outside the theory's range (the
table, JSON and CSV say which and why); 2 bad input (the message names the option and its
range, including more combinations than the memory holds); 1 the machine's state (the output
cannot be written, e.g. a full disk); 130 interrupted; 141 the output pipe was closed
(``| head``): silent, as Unix tools are.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from .cli import EXIT_BAD_INPUT, EXIT_FLAGGED, EXIT_OK, run_cli  # the codes shared by every CLI
from .limits import MEMORY_FRACTION, available_memory
from .moduli import predict_moduli

#: library wording -> the command line's own flags (the messages are shared with the Python API)
_CLI_WORDS = (("Pass nbar explicitly", "Give --nbar"), ("pass nbar", "give --nbar"),
              ("max_correction", "--max-correction"))

SEED_CASE = dict(kn=1.0e8, kt=1.0e8, nc=4.1, phi=0.82, r=0.35, alpha=1.76, nbar=5.0)


def _floats(name):
    def conv(text):
        try:
            return float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
    return conv


def build_parser():
    ap = argparse.ArgumentParser(
        prog="python -m microhom",
        description="Micromechanical homogenisation of dense random disk packings. (To measure a "
                    "packing file: python -m dem analyse FILE.)",
        epilog="exit codes: 0 valid, 3 a result flagged outside the theory's range, 2 bad input, "
               "1 output cannot be written (full disk), 130 interrupted, 141 output pipe closed")
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser(
        "predict", help="mean-field and fluctuation-corrected 2D bulk and shear moduli",
        description="Predict the incremental 2D bulk modulus K and shear modulus G of an isotropic random "
                    "packing of identical disks (paper eqs. 37, 50, 51, 54). Several values per option "
                    "broadcast (one row per combination). Defaults: the seed paper's case.",
        epilog="exit codes: 0 every result valid, 3 at least one flagged outside the theory's range "
               "(in either direction: a correction that softens or stiffens by more than "
               "--max-correction; overflow, underflow, kt/kn > 10), 2 bad input, 1 output cannot "
               "be written (full disk), 130 interrupted, 141 output pipe closed (silent)",
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
                   help="measured rho = Nc sum V.W / sum V^2, V over the Nbar near neighbours (the "
                        "paper's definition, as python -m dem analyse measures it; replaces the alpha model)")
    p.add_argument("--nbar", nargs="+", type=_floats("nbar"), default=None,
                   help="mean number of near neighbours; default from phi via phi = (pi/4)/sin(pi(Nbar-2)/Nbar) "
                        "(needs phi >= pi/4); with all defaults the paper's Nbar = 5")
    p.add_argument("--max-correction", type=float, default=0.5,
                   help="fraction change above which a result is flagged outside the first-order range")
    p.add_argument("--json", action="store_true", help="print JSON (a list of records) instead of a table")
    p.add_argument("--csv", action="store_true", help="print CSV instead of a table")

    return ap


#: Bytes one output row of ``predict`` takes at its peak (the broadcast inputs, the prediction's
#: arrays, the pandas table, the records and the JSON text), measured as the peak resident size
#: of ``predict --json`` with 1e5 rows less that with one row: 5.1 kB (see
#: ``tests/test_messages.py::test_predict_row_memory_estimate``); the guard keeps a margin of 1.6.
BYTES_PER_ROW = 8000


def _grid(args):
    """The option values broadcast over every combination: dict name -> flat array (or None),
    checked against the memory *before* anything of that size is allocated."""
    cols = {"kn": args.kn, "kt": args.kt, "nc": args.nc, "phi": args.phi, "r": args.r}
    if args.rho is not None:
        cols["rho"] = args.rho
    else:
        cols["alpha"] = args.alpha if args.alpha is not None else [SEED_CASE["alpha"]]
    defaults = all(getattr(args, k) == [SEED_CASE[k]] for k in ("nc", "phi")) and args.nbar is None
    cols["nbar"] = args.nbar if args.nbar is not None else ([SEED_CASE["nbar"]] if defaults else None)
    given = {k: v for k, v in cols.items() if v is not None}
    count = math.prod(len(v) for v in given.values())
    need, allowed = count * BYTES_PER_ROW, int(MEMORY_FRACTION * available_memory())
    if need > allowed:
        sizes = " x ".join(f"{len(v)} (--{k})" for k, v in given.items() if len(v) > 1)
        raise ValueError(f"{sizes} = {count:,} combinations would take about {need / 1e9:.3g} GB, "
                         f"more than the {allowed / 1e9:.3g} GB allowed ({MEMORY_FRACTION:g} of the "
                         f"memory available): give fewer values per option")
    names = list(given)
    mesh = np.meshgrid(*[np.asarray(given[n], dtype=np.float64) for n in names], indexing="ij")
    out = {n: m.ravel() for n, m in zip(names, mesh)}
    if "kt" not in out:
        out["kt"] = out["kn"]
    return out


def cmd_predict(args):
    from .results import to_plain

    grid = _grid(args)
    p = predict_moduli(max_correction=args.max_correction, warn=False, **grid)
    df = p.to_frame()
    for k in ("r", "phi", "nc", "kt", "kn"):
        df.insert(0, k, grid[k])
    if args.json:   # every float at full precision (repr: round-trips), NaN and inf as null
        print(json.dumps(to_plain(df.to_dict("records")), indent=1, allow_nan=False))
    elif args.csv:
        print(df.to_csv(index=False, float_format=None), end="")
    else:
        for i, r in df.iterrows():
            print(f"case {i}: kn = {r.kn:.4g} N/m, kt = {r.kt:.4g} N/m, Nc = {r.nc:.4g}, phi = {r.phi:.4g}, "
                  f"r = {r.r:.4g}, Nbar = {r.nbar:.4g}, rho = {r.rho:.4g}")
            print(f"  {'modulus [N/m]':<14}{'mean field':>14}{'corrected':>14}{'fraction change':>18}")
            print(f"  {'bulk K':<14}{r.K_mf:>14.4g}{r.K:>14.4g}{r.drop_K:>18.3f}")
            print(f"  {'shear G':<14}{r.G_mf:>14.4g}{r.G:>14.4g}{r.drop_G:>18.3f}")
            print(f"  Delta = (G-K)/(G+K): mean field {r.delta_mf:.4f}, corrected {r.delta:.4f}; "
                  f"2D Poisson ratio {r.poisson:.4f}")
            print(f"  validity: {'ok' if r.valid else 'FLAGGED: ' + r.reason}")
    sys.stdout.flush()
    return EXIT_OK if bool(df["valid"].all()) else EXIT_FLAGGED


def _cli_words(text):
    for lib, cli in _CLI_WORDS:
        text = text.replace(lib, cli)
    return text


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["analyse"]:
        print("error: 'analyse' moved to the DEM package: python -m dem analyse "
              + " ".join(argv[1:]), file=sys.stderr)
        return EXIT_BAD_INPUT
    args = build_parser().parse_args(argv)

    def run(_):
        try:
            return cmd_predict(args)
        except ValueError as exc:
            print(f"error: {_cli_words(str(exc))}", file=sys.stderr)
            return EXIT_BAD_INPUT
    # closed pipe 141, full disk or unwritable output 1, Ctrl-C 130 (microhom.cli)
    return run_cli(run)


if __name__ == "__main__":
    sys.exit(main())
