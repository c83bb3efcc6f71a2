"""The ``analyse`` sub-command of ``python -m dem`` (the engine is :mod:`dem.analysis.analyse`).

    python -m dem analyse packing.dump --kn 1e5 --kt-ratio 0.2857   # any file dem.io reads
    python -m dem analyse D0001 --kn 2e8 --kn-convention oval --json

Kept apart from ``dem/__main__.py``'s ``pack`` so that each command's options live beside their
help text; ``dem/__main__.py`` wires it in and owns the exit codes.
"""
from __future__ import annotations

import argparse
import csv
import io as _io
import json

from microhom.cli import whole_number

from . import analyse as dan

__all__ = ["add_parser", "run"]


def add_parser(sub):
    """Add the ``analyse`` sub-parser to ``sub`` (the sub-parsers of ``python -m dem``)."""
    a = sub.add_parser(
        "analyse", help="measure a packing file and compare the theory with its exact stiffness",
        description="Read a packing (LAMMPS dump/data, OVAL/DEMPLA D-file, dem.io npz/CSV, a "
                    "dem.engine.packing npz, or a dem.engine.lammps run folder), build its contact network and "
                    "print coordination with and without rattlers, structural sums (vbar, ebar "
                    "measured vs eq. 37), measured rho, stress (when the file has contact forces), "
                    "the theory's moduli (mean field; corrected with the measured rho and with the "
                    "alignment model) and the exact stiffness tensor (dem.analysis.stiffness). Moduli and "
                    "stresses in 2D are force per length [N/m], vbar and ebar [N m], in the units "
                    "of kn and the file. The notes say every assumption made (kn, kt, frame).",
        epilog="exit codes: 0 analysed (degenerate results are flagged in the report, not by the "
               "exit code), 2 bad input (option out of range, file missing or malformed), "
               "1 the machine's state (a file that cannot be read: permissions; out of memory), "
               "130 interrupted, 141 output pipe closed (e.g. '| head': silent)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    a.add_argument("file", help="packing file or dem.engine.lammps run folder")
    a.add_argument("--format", default=None, choices=dan.FORMATS, metavar="FORMAT",
                   help="one of " + ", ".join(dan.FORMATS) + " (packing = dem.engine.packing npz, "
                        "lammps-run = folder); default from the name/extension")
    a.add_argument("--kn", type=float, default=None,
                   help="normal contact stiffness [N/m] (force per unit overlap), > 0; default 1 "
                        "(moduli in units of kn). Ignored for files that carry their contact law "
                        "(packing npz, LAMMPS run folder)")
    kt = a.add_mutually_exclusive_group()
    kt.add_argument("--kt", type=float, default=None,
                    help="tangential stiffness [N/m], >= 0; default kt = kn (said in the notes)")
    kt.add_argument("--kt-ratio", type=float, default=None, metavar="KT_OVER_KN",
                    help="kt = KT_OVER_KN * kn, >= 0; LAMMPS gran/hooke/history's default is 2/7 "
                         "= 0.2857")
    a.add_argument("--kn-convention", choices=("standard", "oval"), default=None,
                   help="'oval': --kn is OVAL's, which multiplies half the overlap (the network "
                        "gets kn/2)")
    a.add_argument("--branch-length", choices=("distance", "radii"), default="distance",
                   help="branch vectors: centre distance, or direction kept with length r_i + r_j "
                        "(paper's |c| = D)")
    a.add_argument("--alpha", type=float, default=None,
                   help="alignment width of the model-rho prediction (54), in [0, 2]; default "
                        "2(1 - 1/Nbar)")
    a.add_argument("--rho-neighbours", choices=("near", "contacts"), default="near",
                   help="neighbourhood of the measured rho: 'near' (default, the paper's Nbar near "
                        "neighbours of eq. 39, Nbar from phi; 4 below phi = pi/4, said in the output) "
                        "or 'contacts' (contacting neighbours only)")
    a.add_argument("--prestress", action="store_true",
                   help="exact stiffness with the pre-stress terms (normal forces from the file, "
                        "else kn*overlap)")
    a.add_argument("--min-contacts", type=whole_number, default=None,
                   help="rattler threshold; default 2 for frictional, 3 for frictionless particles")
    a.add_argument("--frame", type=whole_number, default=-1,
                   help="frame of a LAMMPS dump: 1 = first, -1 = last (the notes say which was "
                        "read)")
    a.add_argument("--radius", type=float, default=None,
                   help="constant disk radius [m] for LAMMPS dumps without a radius or diameter "
                        "column")
    a.add_argument("--no-exact", action="store_true",
                   help="skip the exact stiffness (one sparse factorisation)")
    a.add_argument("--spin-arm", choices=("contact", "radius"), default=None,
                   help="spin kinematics of the exact stiffness: 'radius' (the radius r_i, as "
                        "LAMMPS gran/* and the disk engine's default law) or 'contact' (the "
                        "distance to the contact point |c| r_i/(r_i + r_j), the theory's); "
                        "default: matched to the file's code (LAMMPS files 'radius', other files "
                        "'contact'); the notes say which")
    a.add_argument("--hierarchy-tol", type=float, default=dan.DEFAULT_TOL, metavar="TOL",
                   help="target relative width of the hierarchy's interval, in (0, 1) (the "
                        "library's default, microhom.hierarchy.DEFAULT_TOL)")
    a.add_argument("--no-hierarchy", action="store_true",
                   help="skip the relaxation hierarchy (moduli with a rigorous upper bound and a "
                        "stated error, microhom.hierarchy)")
    out = a.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="print JSON instead of a table")
    out.add_argument("--csv", action="store_true",
                     help="print one CSV row (flattened section.key columns)")
    return a


def _options(args) -> "dan.AnalysisOptions":
    """The :class:`dem.analysis.analyse.AnalysisOptions` of parsed ``args`` (checked there: a bad
    value raises a ValueError naming the command-line option and its range)."""
    frame = args.frame - 1 if args.frame > 0 else args.frame
    try:
        options = dan.AnalysisOptions(
            format=args.format, kn=args.kn, kt=args.kt, kt_ratio=args.kt_ratio,
            kn_convention=args.kn_convention, branch_length=args.branch_length, alpha=args.alpha,
            prestress=args.prestress, min_contacts=args.min_contacts, frame=frame,
            radius=args.radius, exact=not args.no_exact, hierarchy=not args.no_hierarchy,
            spin_arm=args.spin_arm, hierarchy_tol=args.hierarchy_tol,
            rho_neighbours=args.rho_neighbours)
    except dan.OptionError as exc:
        opt = "--" + exc.name.replace("_", "-")
        raise ValueError(f"{opt} must be {exc.allowed}, got {exc.value!r}") from None
    if args.frame == 0:
        raise ValueError("--frame counts from 1 (first) or from -1 (last); 0 is not a frame")
    return options


def run(args, stdout) -> int:
    """Run ``analyse`` for parsed ``args``, printing to ``stdout``; errors propagate (the caller
    turns them into one line and an exit code)."""
    options = _options(args)
    try:
        res = dan.analyse_file(args.file, options)
    except IndexError as exc:
        n = getattr(exc, "n_frames", None)
        if n is None:
            raise
        raise ValueError(f"--frame {args.frame}: {exc.path} holds {n} frame"
                         f"{'s' if n != 1 else ''}: --frame in [1, {n}] (1 = first) or "
                         f"[-{n}, -1] (-1 = last)") from None
    if args.json:
        stdout.write(json.dumps(res.as_dict(), indent=1, allow_nan=False) + "\n")
    elif args.csv:
        flat = dan.flatten(res)
        buf = _io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(flat))
        w.writeheader()
        w.writerow(flat)
        stdout.write(buf.getvalue())
    else:
        stdout.write(dan.format_table(res) + "\n")
    stdout.flush()
    return 0
