"""Command line of the disk DEM (also installed as the ``dem`` console script).

    python -m dem pack --n 4000 --p-over-kn 1e-4 --mu-prep 0.1 --mu 0.49 --seed 1 --out packing.npz
    python -m dem analyse packing.npz                 # or any file dem.io reads (see dem.analysis.analyse_cli)

``pack`` builds a dense random packing with :func:`dem.engine.packing.pack` (random gas -> compaction
under the pressure servo -> equilibrium at the preparation friction -> equilibrium at the test
friction). Its protocol options are the fields of :class:`dem.engine.packing.PackingProtocol`, generated
from the protocol's own table (``--p-over-kn``, ``--kn``, ``--mu-prep``, ...: the same names,
units, ranges and defaults; ``--p-target`` [N/m] with ``--kn`` instead of ``--p-over-kn``). It
writes, next to ``--out`` (``packing.npz`` below):

* ``packing.npz`` — the packing: a bit-exact state (``dem.engine.packing.PackingResult.load``) that is
  also a ``dem.io`` configuration (``dem.io.read``);
* ``packing_summary.csv`` — every quantity of ``dem.analysis.measure.summary`` plus the packing report
  (steps, wall time, psi6, the stop criteria), also printed as a table;
* ``packing.png`` — the disks with force chains (``dem.analysis.plot.plot_packing``);
* ``packing.lammpstrj`` — LAMMPS text dump (OVITO);
* ``packing.vtu`` — VTK unstructured grid with the contacts (ParaView; skipped if meshio is
  missing);
* ``packing.checkpoint.npz`` — the checkpoint while running (atomic, every
  ``--checkpoint-seconds`` seconds of wall time and/or every ``--checkpoint-every`` steps, as
  ``checkpoint_seconds`` and ``checkpoint_every`` of :func:`dem.engine.packing.pack`); removed after a
  converged run, kept otherwise for ``--resume``.

Exit codes of ``pack``: 0 converged (also: ``--resume`` of a run that had already converged,
whose stored report and outputs are written again); 2 bad input (the message names the option and
its allowed range; this includes a packing too large for the available memory, about 247 B per
particle, ``dem.engine.packing.BYTES_PER_PARTICLE``); 3 not converged within ``--max-steps`` (outputs written, flagged ``converged =
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
import os
import sys
import tempfile
import time

from tqdm import tqdm

from microhom import cli

from .analysis import analyse_cli
from . import io as dio
from .analysis import measure
from .engine.integrate import InstabilityError
from .io import Configuration, FormatError
from .engine.packing import (BYTES_PER_PARTICLE, PackingProtocol, ProtocolError, check_memory,
                      check_run_options, pack)
from .runtime import remove_stale_temporaries
from .engine.state import State

# the codes shared by every command line (microhom.cli): "not converged" is the "flagged" code
EXIT_OK, EXIT_BAD_INPUT, EXIT_NOT_CONVERGED, EXIT_UNSTABLE, EXIT_INTERRUPTED = (
    cli.EXIT_OK, cli.EXIT_BAD_INPUT, cli.EXIT_FLAGGED, cli.EXIT_UNSTABLE, cli.EXIT_INTERRUPTED)
EXIT_MACHINE, EXIT_BROKEN_PIPE = cli.EXIT_MACHINE, cli.EXIT_BROKEN_PIPE

class BadInput(ValueError):
    """A command-line value outside its allowed range (exit code 2)."""


def _opt(name):
    return "--" + name.replace("_", "-")


#: the run options of ``pack`` (how long and where, not how the packing is made; checked by
#: dem.engine.packing.check_run_options): name -> (default, metavar, help)
_RUN_OPTIONS = {
    "max_steps": (2_000_000, "STEPS", "cap on the total number of time steps, an integer >= 1 "
                  "(default 2e6); a run that reaches it without converging exits with code 3"),
    "checkpoint_seconds": (5.0, "SECONDS", "wall-clock seconds between atomic checkpoints, >= 0 "
                           "(default 5); the API's checkpoint_seconds"),
    "checkpoint_every": (None, "STEPS", "also write a checkpoint every STEPS time steps, an "
                         "integer >= 1 (default: by time only); the API's checkpoint_every"),
    "threads": (1, "N", "threads of the contact-force loop, an integer in [1, 1024] (default 1; "
                "with more, the run is reproducible for that number of threads, forces agree with "
                "one thread's to round-off; docs/dem.md, multi-core mode)"),
}


def _protocol_help(name, default, prm):
    """The --help text of a protocol field: its help, range with unit, default."""
    if prm.kind == "bool":
        return f"{prm.help} (default {'on' if default else 'off'})"
    if default is None and not prm.optional:
        return f"{prm.help}, {prm.allowed_text()} (required unless --resume)"
    unit = " (dimensionless)" if prm.unit == "-" else ""
    shown = "None" if default is None else f"{default:g}"
    return f"{prm.help}; {prm.allowed_text()}{unit} (default {shown})"


def _add_protocol_options(group):
    """One option per field of dem.engine.packing.PackingProtocol: its name, unit, range, default and
    help come from the protocol's own table (nothing is repeated here)."""
    for name, (default, prm) in PackingProtocol.params().items():
        text = _protocol_help(name, default, prm).replace("%", "%%")
        if prm.kind == "bool":
            group.add_argument(_opt(name), dest=name, action=argparse.BooleanOptionalAction,
                               default=None, help=text)
        else:
            group.add_argument(_opt(name), dest=name, default=None, metavar=name.upper(),
                               help=text + ("; 'none' for None" if prm.optional else ""))
    group.add_argument("--p-target", dest="p_target", default=None, metavar="P",
                       help="target pressure in absolute units [N/m] (2D: force per unit length, a "
                            "'Pa m'), instead of --p-over-kn: needs --kn [N/m]; p/kn must lie in "
                            "(0, 0.1]")


def _number(text, optional=False):
    """Option text as a float (None for 'none' where None is allowed); other text is returned
    as it is, for the protocol's check to refuse with the option's range."""
    if text is None or isinstance(text, bool):
        return text
    if optional and text.strip().lower() == "none":
        return None
    try:
        return float(text)
    except ValueError:
        return text


def _given(args):
    """The protocol fields given on the command line, {name: value}."""
    params = PackingProtocol.params()
    out = {k: _number(getattr(args, k), prm.optional) for k, (_, prm) in params.items()
           if getattr(args, k) is not None}
    if args.p_target is not None:
        if args.p_over_kn is not None:
            raise BadInput("give either --p-over-kn (dimensionless) or --p-target [N/m], not both")
        if args.kn is None:
            raise BadInput("--p-target [N/m] needs --kn [N/m] (the normal stiffness that sets "
                           "the scale)")
        p, kn = _number(args.p_target), out["kn"]
        ratio = p / kn if isinstance(p, float) and isinstance(kn, float) and kn > 0 else None
        if ratio is None or not (0 < ratio <= 0.1):
            raise BadInput(f"--p-target / --kn = {args.p_target} / {args.kn} must be in (0, 0.1] "
                           f"(p/kn, dimensionless)")
        out["p_over_kn"] = ratio
    return out


def _protocol(args, stored):
    """The protocol of the run: from the options (defaults: the protocol's), or the checkpoint's
    (``stored``, a PackingProtocol) on --resume, which the options may not contradict."""
    given = _given(args)
    try:
        if stored is None:
            if "n" not in given:
                raise BadInput("--n (number of disks, an integer in [2, 1e9]) is required")
            return PackingProtocol(**given)
        proto = stored.replace(**given)
    except ProtocolError as exc:
        name = "p_target" if exc.field == "p_over_kn" and args.p_target is not None else exc.field
        raise BadInput(f"{_opt(name)} must be {exc.allowed}, got {exc.value!r}") from None
    diff = [k for k in given if getattr(proto, k) != getattr(stored, k)]
    if diff:
        raise BadInput(", ".join(f"{_opt(k)} {getattr(proto, k)!r} differs from the checkpoint's "
                                 f"{getattr(stored, k)!r}" for k in diff)
                       + ": a resumed run keeps its protocol (drop the option, or start again "
                         "with --fresh)")
    return stored


def _run_options(args):
    """(max_steps, checkpoint_every, checkpoint_seconds, threads), checked by
    dem.engine.packing.check_run_options (BadInput naming the option)."""
    vals = {k: _number(getattr(args, k)) if getattr(args, k) is not None else _RUN_OPTIONS[k][0]
            for k in _RUN_OPTIONS}
    try:
        return check_run_options(**vals)
    except ProtocolError as exc:
        raise BadInput(f"{_opt(exc.field)} must be {exc.allowed}, got {exc.value!r}") from None


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
            "mass [kg/m]; kn is a force per overlap [N/m]; the pressure p = -tr(sigma)/2 is a\n"
            "force per length [N/m]. The geometry depends on p/kn only, so the target is\n"
            "--p-over-kn (dimensionless) with kn = 1 by default; --p-target [N/m] with --kn\n"
            "gives absolute values.\n\n"
            "The packing protocol options are the fields of dem.engine.packing.PackingProtocol (same\n"
            "names, units, ranges and defaults: the seed paper's conditions); the protocol is\n"
            "stored in STEM.npz."),
        epilog=(
            "stop criteria (all three, checked every --check-every steps):\n"
            "  |p - p_target| / p_target < --tol-p\n"
            "  unbalanced force ratio (mean |resultant force| over mean |contact force|, Yade)\n"
            "    < --tol-unbalanced\n"
            "  kinetic energy of the particles in contact < --tol-ke x elastic contact energy\n"
            "outputs next to --out STEM.npz:\n"
            "  STEM.npz (packing: PackingResult.load, dem.io.read), STEM_summary.csv (also\n"
            "  printed), STEM.png (force chains), STEM.lammpstrj (OVITO), STEM.vtu (ParaView),\n"
            "  STEM.checkpoint.npz while running (kept unless converged)\n"
            "exit codes:\n"
            "  0 converged (or already converged on --resume), 2 bad input (incl. too many disks\n"
            f"  for the available memory, {BYTES_PER_PARTICLE} B per particle), 3 not converged within\n"
            "  --max-steps (outputs written, flagged converged=False), 4 unstable (last good\n"
            "  checkpoint kept), 1 an output or the checkpoint cannot be written (read-only\n"
            "  folder, full disk; checkpoint kept), 130 interrupted\n"
            "example:\n"
            "  python -m dem pack --n 4000 --p-over-kn 1e-4 --mu-prep 0.1 --mu 0.49 --seed 1 \\\n"
            "      --out packing.npz"))
    _add_protocol_options(p.add_argument_group(
        "packing protocol (dem.engine.packing.PackingProtocol; unset options take its defaults)"))
    run = p.add_argument_group("run options (how long and where; not part of the protocol)")
    for name, (default, metavar, text) in _RUN_OPTIONS.items():
        run.add_argument(_opt(name), dest=name, default=None, metavar=metavar, help=text)
    a = run.add_argument
    a("--out", default="packing.npz", metavar="PATH.npz",
      help="packing file (.npz); the other outputs go next to it, its folder is created if "
           "missing (default packing.npz)")
    a("--resume", action="store_true",
      help="continue the interrupted or unconverged run from STEM.checkpoint.npz (bit-exact; "
           "the protocol is the checkpoint's)")
    a("--fresh", action="store_true",
      help="discard an existing checkpoint and start again")
    a("--no-progress", action="store_true", help="no progress bar")
    return ap


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


def _write_outputs(res, paths, log):
    from .analysis.plot import plot_packing   # matplotlib: a heavy import, only when writing the picture

    net = res.to_network()
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
        log("VTK            skipped: meshio is not installed (pip install meshio)")
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

    if args.resume and args.fresh:
        raise BadInput("--resume and --fresh exclude each other")
    max_steps, every, seconds, threads = _run_options(args)
    paths = _paths(args.out)
    folder = os.path.dirname(os.path.abspath(paths["npz"]))
    ck = paths["checkpoint"]
    if args.resume:
        if not os.path.exists(ck):
            raise BadInput(f"--resume: no checkpoint {ck} (run without --resume first)")
        try:
            stored = State.load(ck).meta.get("packing_protocol")
        except Exception as exc:
            raise BadInput(f"--resume: cannot read the checkpoint {ck}: {exc}") from None
        if stored is None:
            raise BadInput(f"--resume: {ck} holds no packing protocol (written by another "
                           f"program or an earlier version): start again with --fresh")
        proto = _protocol(args, PackingProtocol.from_dict(stored))
    else:
        proto = _protocol(args, None)
        if os.path.exists(ck):
            if not args.fresh:
                raise BadInput(f"a checkpoint {ck} exists from an earlier run: pass --resume to "
                               f"continue it or --fresh to discard it")
            os.unlink(ck)
    try:
        check_memory(proto.n)
    except ValueError as exc:
        raise BadInput(f"--n: {exc}") from None
    _writable(folder)
    remove_stale_temporaries(paths["npz"])    # left by a run killed while writing its packing

    bar = None
    if not args.no_progress:
        bar = tqdm(total=max_steps, unit="step", mininterval=1.0, dynamic_ncols=True,
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
        res = pack(proto, max_steps=max_steps, checkpoint=ck, checkpoint_every=every,
                   checkpoint_seconds=seconds, progress=progress, threads=threads)
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
        rows = _write_outputs(res, paths, log)
    except OSError as exc:
        return _write_failed(exc, ck, log)
    _print_table(rows, sys.stdout)
    r = res.report
    if r["already_converged"]:
        log(f"already converged: {ck} holds a finished run (step {r['steps']}); its stored report "
            f"and the outputs were written again")
    if not r["converged"]:
        log(f"NOT CONVERGED within --max-steps {max_steps} (steps {r['steps']}, "
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
    """``--p-over-kn -1e-4`` -> ``--p-over-kn=-1e-4`` (argparse would take ``-1e-4`` for an option,
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
