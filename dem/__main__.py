"""Command line of the disk DEM (also installed as the ``dem`` console script).

    python -m dem pack --n 4000 --pressure 1e-4 --mu-prep 0.1 --mu 0.49 --seed 1 --out packing.npz
    python -m dem analyse packing.npz                 # or any file dem.io reads (see dem.analyse_cli)

``pack`` builds a dense random packing with :func:`dem.packing.pack` (random gas -> compaction
under the pressure servo -> equilibrium at the preparation friction -> equilibrium at the test
friction) and writes, next to ``--out`` (``packing.npz`` below):

* ``packing.npz`` — the packing: a bit-exact state (``dem.packing.PackingResult.load``) that is
  also a ``dem.io`` configuration (``dem.io.read``);
* ``packing_summary.csv`` — every quantity of ``dem.measure.summary`` plus the packing report
  (steps, wall time, psi6, the stop criteria), also printed as a table;
* ``packing.png`` — the disks with force chains (``dem.plot.plot_packing``);
* ``packing.lammpstrj`` — LAMMPS text dump (OVITO);
* ``packing.vtu`` — VTK unstructured grid with the contacts (ParaView; skipped if meshio is
  missing);
* ``packing.checkpoint.npz`` — the checkpoint while running (atomic, every
  ``--checkpoint-seconds`` seconds of wall time and/or every ``--checkpoint-every`` steps, as
  ``checkpoint_seconds`` and ``checkpoint_every`` of :func:`dem.packing.pack`); removed after a
  converged run, kept otherwise for ``--resume``.

Exit codes of ``pack``: 0 converged (also: ``--resume`` of a run that had already converged,
whose stored report and outputs are written again); 2 bad input (the message names the option and
its allowed range; this includes a packing too large for the available memory, about 211 B per
particle); 3 not converged within ``--max-steps`` (outputs written, flagged ``converged =
False``; continue with ``--resume --max-steps M``); 4 unstable run (reason printed, last good
checkpoint kept); 1 an output or the checkpoint cannot be written (a folder that cannot be
created or written is found before computing; a full disk during the run or the outputs: one
line with the path, the last checkpoint kept); 130 interrupted (Ctrl-C; the last checkpoint is
kept).

Exit codes of ``analyse``: 0 analysed (a degenerate result is flagged in the report, with its
reason); 2 bad input (an option out of range, a missing or malformed file: one line naming the
file, line and field).

Every command: 1 the machine's state (a file that cannot be read or written, a full disk, out of
memory: one line, no traceback); 130 interrupted; 141 the output pipe was closed (``| head``):
silent, as Unix tools are.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import tempfile
import time

from tqdm import tqdm

from microhom import cli

from . import analyse_cli
from . import io as dio
from . import measure
from .integrate import InstabilityError
from .io import Configuration, FormatError
from .packing import check_memory, pack
from .runtime import remove_stale_temporaries
from .state import State

# the codes shared by every command line (microhom.cli): "not converged" is the "flagged" code
EXIT_OK, EXIT_BAD_INPUT, EXIT_NOT_CONVERGED, EXIT_UNSTABLE, EXIT_INTERRUPTED = (
    cli.EXIT_OK, cli.EXIT_BAD_INPUT, cli.EXIT_FLAGGED, cli.EXIT_UNSTABLE, cli.EXIT_INTERRUPTED)
EXIT_MACHINE, EXIT_BROKEN_PIPE = cli.EXIT_MACHINE, cli.EXIT_BROKEN_PIPE

#: physics options of ``pack``: (default, allowed range text, check). A resumed run keeps the
#: values stored in its checkpoint; giving a different one is refused.
_PHYSICS = {
    "n": (None, "an integer >= 2", lambda v: v >= 2),
    "pressure": (1e-4, "(0, 0.1] (p/kn, dimensionless)", lambda v: 0 < v <= 0.1),
    "pressure_pa": (None, "> 0 [N/m] with p/kn in (0, 0.1]", lambda v: v > 0 and math.isfinite(v)),
    "kn": (1.0, "> 0 [N/m]", lambda v: v > 0 and math.isfinite(v)),
    "kt": (None, "[0, 10 kn] [N/m]", None),
    "mu": (0.488, "[0, 10]", lambda v: 0 <= v <= 10),
    "mu_prep": (0.1, "[0, 10]", lambda v: 0 <= v <= 10),
    "dispersity": (0.0, "[0, 0.5)", lambda v: 0 <= v < 0.5),
    "seed": (0, "an integer >= 0", lambda v: v >= 0),
    "tol_unbalanced": (1e-5, "(0, 1)", lambda v: 0 < v < 1),
}


class BadInput(ValueError):
    """A command-line value outside its allowed range (exit code 2)."""


def _parser():
    ap = argparse.ArgumentParser(
        prog="python -m dem", description="Disk DEM command line: pack (build a packing), "
        "analyse (measure a packing file against the theory).",
        epilog="exit codes (every command): 0 done, 2 bad input, 1 the machine's state (file "
               "cannot be read or written, disk full, out of memory), 130 interrupted, 141 output "
               "pipe closed; pack also 3 not converged, 4 unstable (see python -m dem pack -h)")
    sub = ap.add_subparsers(dest="command", required=True)
    analyse_cli.add_parser(sub)
    p = sub.add_parser(
        "pack", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="build a dense random disk packing at a target pressure",
        description=(
            "Build a dense random packing of N disks in a periodic square cell at a target\n"
            "pressure: random gas -> compaction under the pressure servo -> equilibrium at\n"
            "--mu-prep -> equilibrium at --mu.\n\n"
            "Units: consistent, 2D per unit thickness. Disks have mean diameter 1 [m] and unit\n"
            "mass [kg/m]; kn and kt are forces per overlap [N/m]; the pressure p = -tr(sigma)/2\n"
            "is a force per length [N/m]. The geometry depends on p/kn only, so the default is\n"
            "--pressure as p/kn with kn = 1; --pressure-pa with --kn gives absolute values."),
        epilog=(
            "stop criteria (all three, checked every 100 steps):\n"
            "  |p - p_target| / p_target < 1e-3\n"
            "  unbalanced force ratio (mean |resultant force| over mean |contact force|, Yade)\n"
            "    < --tol-unbalanced\n"
            "  kinetic energy of the particles in contact < 1e-8 x elastic contact energy\n"
            "outputs next to --out STEM.npz:\n"
            "  STEM.npz (packing: PackingResult.load, dem.io.read), STEM_summary.csv (also\n"
            "  printed), STEM.png (force chains), STEM.lammpstrj (OVITO), STEM.vtu (ParaView),\n"
            "  STEM.checkpoint.npz while running (kept unless converged)\n"
            "exit codes:\n"
            "  0 converged (or already converged on --resume), 2 bad input (incl. too many disks\n"
            "  for the available memory), 3 not converged within --max-steps (outputs written,\n"
            "  flagged converged=False), 4 unstable (last good checkpoint kept), 1 an output or\n"
            "  the checkpoint cannot be written (read-only folder, full disk; checkpoint kept),\n"
            "  130 interrupted\n"
            "example:\n"
            "  python -m dem pack --n 4000 --pressure 1e-4 --mu-prep 0.1 --mu 0.49 --seed 1 \\\n"
            "      --out packing.npz"))
    a = p.add_argument
    a("--n", type=cli.whole_number, default=None, metavar="N",
      help="number of disks, an integer >= 2 (required unless --resume)")
    a("--pressure", type=float, default=None, metavar="P_OVER_KN",
      help="target pressure as p/kn, dimensionless, in (0, 0.1] (default 1e-4); p = -tr(sigma)/2 "
           "is a force per length [N/m], kn a force per overlap [N/m]")
    a("--pressure-pa", type=float, default=None, metavar="P",
      help="target pressure in absolute units [N/m] (2D: force per unit length, a 'Pa m'); "
           "needs --kn [N/m]; p/kn must lie in (0, 0.1]")
    a("--kn", type=float, default=None, metavar="KN",
      help="normal contact stiffness [N/m], > 0 (default 1, scaled units)")
    a("--kt", type=float, default=None, metavar="KT",
      help="tangential contact stiffness [N/m], in [0, 10 kn] (default kt = kn)")
    a("--mu", type=float, default=None,
      help="test friction coefficient (dimensionless), in [0, 10] (default 0.488 = tan 26 deg)")
    a("--mu-prep", type=float, default=None,
      help="preparation friction (dimensionless), in [0, 10]: the knob for the coordination "
           "number (default 0.1, amorphous identical disks with Nc ~ 3.9; 0.05 gives Nc ~ 4.0 but "
           "some packings order (psi6 up to 0.5); 0 = densest, crystallises)")
    a("--dispersity", type=float, default=None,
      help="radii uniform in r (1 +- dispersity), dimensionless, in [0, 0.5) (default 0: identical "
           "disks of diameter 1)")
    a("--seed", type=cli.whole_number, default=None, help="random seed, an integer >= 0 (default 0)")
    a("--max-steps", type=cli.whole_number, default=2_000_000, metavar="STEPS",
      help="cap on the total number of time steps, an integer >= 1 (default 2e6); a run that "
           "reaches it without converging exits with code 3")
    a("--tol-unbalanced", type=float, default=None, metavar="TOL",
      help="stop when the unbalanced force ratio (dimensionless) is below TOL, in (0, 1) "
           "(default 1e-5)")
    a("--out", default="packing.npz", metavar="PATH.npz",
      help="packing file (.npz); the other outputs go next to it, its folder is created if "
           "missing (default packing.npz)")
    a("--resume", action="store_true",
      help="continue the interrupted or unconverged run from STEM.checkpoint.npz (bit-exact; "
           "the physics options are those of the checkpoint)")
    a("--fresh", action="store_true",
      help="discard an existing checkpoint and start again")
    a("--checkpoint-seconds", type=float, default=5.0, metavar="SECONDS",
      help="wall-clock seconds between atomic checkpoints, > 0 (default 5); the API's "
           "checkpoint_seconds")
    a("--checkpoint-every", type=cli.whole_number, default=None, metavar="STEPS",
      help="also write a checkpoint every STEPS time steps, an integer >= 1 (default: by time "
           "only); the API's checkpoint_every")
    a("--threads", type=cli.whole_number, default=1, metavar="N",
      help="threads of the contact-force loop, an integer in [1, 1024] (default 1; with more, the "
           "run is reproducible for that number of threads, forces agree with one thread's to "
           "round-off; docs/dem.md, multi-core mode)")
    a("--no-progress", action="store_true", help="no progress bar")
    return ap


def _check(name, value, ok):
    opt = "--" + name.replace("_", "-")
    if value is None:
        return
    rng = _PHYSICS[name][1]
    if isinstance(value, float) and not math.isfinite(value) or not ok(value):
        raise BadInput(f"{opt} must be {rng}, got {value!r}")


def _resolve(args, stored):
    """Physics parameters from the command line (defaults filled in) or from the checkpoint."""
    given = {k: getattr(args, k) for k in _PHYSICS}
    for k, v in given.items():
        if _PHYSICS[k][2] is not None:
            _check(k, v, _PHYSICS[k][2])
    if stored is not None:
        for k, v in given.items():
            if v is not None and stored.get(k) != v:
                raise BadInput(f"--{k.replace('_', '-')} {v!r} differs from the checkpoint's "
                               f"{stored.get(k)!r}: a resumed run keeps its parameters (drop the "
                               f"option, or start again with --fresh)")
        return dict(stored)
    prm = {k: (v if v is not None else _PHYSICS[k][0]) for k, v in given.items()}
    if prm["n"] is None:
        raise BadInput("--n (number of disks, an integer >= 2) is required")
    if args.pressure_pa is not None:
        if args.kn is None:
            raise BadInput("--pressure-pa [N/m] needs --kn [N/m] (the normal stiffness that sets "
                           "the scale)")
        if args.pressure is not None:
            raise BadInput("give either --pressure (p/kn) or --pressure-pa (N/m), not both")
        ratio = args.pressure_pa / prm["kn"]
        if not (0 < ratio <= 0.1):
            raise BadInput(f"--pressure-pa / --kn = {ratio:.4g} must be in (0, 0.1] "
                           f"(p/kn, dimensionless)")
        prm["pressure"] = None
    if prm["kt"] is None:
        prm["kt"] = prm["kn"]
    if not (math.isfinite(prm["kt"]) and 0 <= prm["kt"] <= 10 * prm["kn"]):
        raise BadInput(f"--kt must be in [0, 10 kn] = [0, {10 * prm['kn']:.4g}] [N/m], "
                       f"got {prm['kt']!r}")
    return prm


def _paths(out):
    out = os.fspath(out)
    if not out.endswith(".npz"):
        raise BadInput(f"--out must name an .npz file, got {out!r}")
    stem = out[:-4]
    return {"npz": out, "csv": stem + "_summary.csv", "png": stem + ".png",
            "dump": stem + ".lammpstrj", "vtu": stem + ".vtu", "checkpoint": stem + ".checkpoint.npz"}


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _summary_rows(res, net):
    rows = []
    rep = res.report
    keys = ["converged", "steps", "compaction_steps", "wall_s", "particle_steps_per_s", "n", "seed",
            "p_target", "pressure", "p_over_kn", "rel_p_err", "tol_p", "unbalanced",
            "unbalanced_max", "tol_unbalanced", "ke_rel", "tol_ke", "phi", "Z", "n_contacts",
            "psi6", "psi6_local", "sliding_fraction", "mu_prep", "mu", "kn", "kt", "dt",
            "dt_over_dtcrit", "damping_compaction", "damping", "damping_work", "resumed"]
    for k in keys:
        if k in rep:
            v = rep[k]
            rows.append(("packing", k, v.item() if hasattr(v, "item") else v))
    rows.append(("packing", "phase_steps", json.dumps(rep.get("phase_steps", []))))
    for k, v in measure.summary(net).table().items():
        if hasattr(v, "item"):
            v = v.item()
        rows.append(("measure", k, v))
    return rows


def _write_outputs(res, paths, params, log):
    from .plot import plot_packing   # matplotlib: a heavy import, only when writing the picture

    net = res.to_network()
    res.state.meta["cli"] = params
    res.save(paths["npz"])
    log(f"packing        {paths['npz']}")
    rows = _summary_rows(res, net)
    with open(paths["csv"], "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["section", "quantity", "value"])
        for sec, k, v in rows:
            w.writerow([sec, k, repr(v) if isinstance(v, float) else v])
    log(f"summary table  {paths['csv']}")
    r = res.report
    plot_packing(net, paths["png"], title=f"{net.n_particles} disks, p/kn = {r['p_over_kn']:.3g}, "
                                          f"Z = {r['Z']:.3f}, psi6 = {r['psi6']:.3f}; "
                                          f"line width ~ normal force")
    log(f"picture        {paths['png']}")
    cfg = Configuration.from_network(net, meta={"timestep": int(r["steps"])},
                                     fields={"contacts": net.contact_counts()})
    dio.write(paths["dump"], cfg, timestep=int(r["steps"]))
    log(f"LAMMPS dump    {paths['dump']} (OVITO)")
    try:
        import meshio  # noqa: F401
    except ImportError:
        log(f"VTK            skipped: meshio is not installed (pip install meshio)")
    else:
        dio.write(paths["vtu"], cfg, network=net)
        log(f"VTK            {paths['vtu']} (ParaView)")
    return rows


def _print_table(rows, stream):
    width = max(len(k) for _, k, _ in rows)
    sec = None
    for s, k, v in rows:
        if s != sec:
            print(f"-- {s} " + "-" * max(0, width + 14 - len(s)), file=stream)
            sec = s
        print(f"{k:<{width}s}  {_fmt(v)}", file=stream)


class WriteError(OSError):
    """An output folder cannot be created or written (exit code 1, the machine's state)."""


def _writable(folder):
    """Create ``folder`` if missing and prove it writable with a small probe file; raise
    :class:`WriteError` with the path otherwise (before any computing)."""
    try:
        os.makedirs(folder, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".tmp_probe.", dir=folder)
        try:
            os.write(fd, b"\0" * 4096)
            os.fsync(fd)
        finally:
            os.close(fd)
            os.unlink(probe)
    except OSError as exc:
        raise WriteError(f"cannot write to --out folder {folder}: {exc.strerror or exc}") from None


def cmd_pack(args) -> int:
    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    if args.max_steps < 1:
        raise BadInput(f"--max-steps must be an integer >= 1, got {args.max_steps}")
    if not (math.isfinite(args.checkpoint_seconds) and args.checkpoint_seconds > 0):
        raise BadInput(f"--checkpoint-seconds must be > 0 [s], got {args.checkpoint_seconds}")
    if args.checkpoint_every is not None and args.checkpoint_every < 1:
        raise BadInput(f"--checkpoint-every must be an integer >= 1 [steps], got {args.checkpoint_every}")
    if args.resume and args.fresh:
        raise BadInput("--resume and --fresh exclude each other")
    if not 1 <= args.threads <= 1024:
        raise BadInput(f"--threads must be an integer in [1, 1024], got {args.threads}")
    paths = _paths(args.out)
    folder = os.path.dirname(os.path.abspath(paths["npz"]))
    ck = paths["checkpoint"]
    stored = None
    if args.resume:
        if not os.path.exists(ck):
            raise BadInput(f"--resume: no checkpoint {ck} (run without --resume first)")
        try:
            stored = State.load(ck).meta.get("cli")
        except Exception as exc:
            raise BadInput(f"--resume: cannot read the checkpoint {ck}: {exc}") from None
        if stored is None:
            raise BadInput(f"--resume: {ck} was not written by 'python -m dem pack'")
    elif os.path.exists(ck):
        if not args.fresh:
            raise BadInput(f"a checkpoint {ck} exists from an earlier run: pass --resume to "
                           f"continue it or --fresh to discard it")
        os.unlink(ck)
    prm = _resolve(args, stored)
    try:
        check_memory(prm["n"])
    except ValueError as exc:
        raise BadInput(f"--n: {exc}") from None
    _writable(folder)
    remove_stale_temporaries(paths["npz"])    # left by a run killed while writing its packing

    kw = dict(kn=prm["kn"], kt=prm["kt"], mu=prm["mu"], mu_prep=prm["mu_prep"],
              dispersity=prm["dispersity"], seed=prm["seed"], tol_unbalanced=prm["tol_unbalanced"],
              max_steps=args.max_steps, checkpoint=ck, checkpoint_every=args.checkpoint_every,
              checkpoint_seconds=args.checkpoint_seconds, meta={"cli": prm}, threads=args.threads)
    if prm["pressure_pa"] is not None:
        kw["pressure"] = prm["pressure_pa"]
    else:
        kw["p_over_kn"] = prm["pressure"]

    bar = None
    if not args.no_progress:
        bar = tqdm(total=args.max_steps, unit="step", mininterval=1.0, dynamic_ncols=True,
                   desc="pack", file=sys.stderr)
    ke_seen = ["-"]

    def progress(info):
        if info["ke_rel"] is not None:
            ke_seen[0] = f"{info['ke_rel']:.1e}"
        if bar is not None:
            bar.set_postfix_str(f"{info['phase']} dp/p={info['rel_p_err']:.1e} "
                                f"unb={info['unbalanced']:.1e} ke/U={ke_seen[0]} "
                                f"phi={info['phi']:.4f} Z={info['Z']:.3f}", refresh=False)
            bar.update(info["step"] - bar.n)  # redraws at most every mininterval seconds

    t0 = time.perf_counter()
    try:
        res = pack(prm["n"], progress=progress, **kw)
    except InstabilityError as exc:
        if bar is not None:
            bar.close()
        where = (f"last good checkpoint kept: {exc.checkpoint} (step {exc.checkpoint_step})"
                 if getattr(exc, "checkpoint", None) else "no checkpoint had been written yet")
        log(f"error: the run became unstable: {exc.reason} (step {exc.step}); {where}")
        return EXIT_UNSTABLE
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        there = os.path.exists(ck)
        log("interrupted; " + (f"the last checkpoint {ck} is kept: continue with --resume"
                               if there else "no checkpoint had been written yet"))
        return EXIT_INTERRUPTED
    except OSError as exc:
        if bar is not None:
            bar.close()
        return _write_failed(exc, ck, log)
    if bar is not None:
        bar.update(res.report["steps"] - bar.n)
        bar.close()
    try:
        rows = _write_outputs(res, paths, prm, log)
    except OSError as exc:
        return _write_failed(exc, ck, log)
    _print_table(rows, sys.stdout)
    r = res.report
    if r["already_converged"]:
        log(f"already converged: {ck} holds a finished run (step {r['steps']}); its stored report "
            f"and the outputs were written again")
    if not r["converged"]:
        log(f"NOT CONVERGED within --max-steps {args.max_steps} (steps {r['steps']}, "
            f"dp/p {r['rel_p_err']:.2e}, unbalanced {r['unbalanced']:.2e}, ke/U {r['ke_rel']:.2e}); "
            f"outputs written and flagged converged=False; continue with --resume --max-steps M "
            f"(checkpoint {ck} kept)")
        return EXIT_NOT_CONVERGED
    if os.path.exists(ck):
        os.unlink(ck)
    log(f"converged in {r['steps']} steps, {time.perf_counter() - t0:.1f} s; psi6 = {r['psi6']:.3f}")
    return EXIT_OK


def _write_failed(exc, ck, log):
    where = getattr(exc, "filename", None)
    kept = (f"the last checkpoint {ck} is kept: free space or fix the folder, then --resume"
            if os.path.exists(ck) else "no checkpoint had been written")
    log(f"error: cannot write {where or 'an output'}: {exc.strerror or exc}; {kept}")
    return EXIT_MACHINE


def _join_negative_numbers(argv):
    """``--pressure -1e-4`` -> ``--pressure=-1e-4`` (argparse would take ``-1e-4`` for an option,
    and the range check, not a usage error, should answer)."""
    out = []
    k = 0
    while k < len(argv):
        a = argv[k]
        if a.startswith("--") and "=" not in a and k + 1 < len(argv) and argv[k + 1].startswith("-"):
            try:
                float(argv[k + 1])
            except ValueError:
                pass
            else:
                out.append(f"{a}={argv[k + 1]}")
                k += 2
                continue
        out.append(a)
        k += 1
    return out


def _silence_stdout():
    """After a closed pipe: point stdout at /dev/null so the interpreter's final flush is silent."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def main(argv=None) -> int:
    ap = _parser()
    args = ap.parse_args(_join_negative_numbers(sys.argv[1:] if argv is None else list(argv)))
    try:
        if args.command == "pack":
            return cmd_pack(args)
        if args.command == "analyse":
            return analyse_cli.run(args, sys.stdout)
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (BadInput, FormatError, FileNotFoundError, IsADirectoryError, NotADirectoryError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError as exc:   # also dem.io.FileTooLarge, which names the file and the limit
        print(f"error: {exc or 'out of memory (try a smaller input)'}", file=sys.stderr)
        return EXIT_MACHINE
    except OSError as exc:  # permissions, full disk, read-only folder: the machine's state
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_MACHINE
    except (ValueError, IndexError) as exc:
        if args.command != "analyse":  # pack validates its own options (BadInput)
            raise
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    ap.error(f"unknown command {args.command}")
    return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
