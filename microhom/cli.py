"""The command-line convention of ``python -m microhom``, ``python -m dem`` and every study.

One table of exit codes, the same code for the same failure in every command:

====  ===========================================================================================
code  meaning
====  ===========================================================================================
0     done
1     the machine's state: an output that cannot be written (read-only or impossible folder,
      full disk), an input that cannot be read (permissions), out of memory; one line naming the
      path and the cause, no traceback; partial results are kept
2     bad input: an option or a file out of its allowed range (the message names the option, or
      the file, line and field, and the allowed range); also argparse's usage errors
3     done, but a result is flagged (outside the theory's range; ``dem pack``: not converged)
4     ``dem pack`` only: the run became unstable (last good checkpoint kept)
130   interrupted (Ctrl-C): one line, no traceback; finished cases, checkpoints and cached
      packings are kept, and a re-run resumes from them
141   the output pipe was closed (``| head``): silent, as Unix tools are
====  ===========================================================================================

:func:`run_cli` applies the rows 1, 130 and 141 around a ``main(argv)``; the commands raise their
own bad-input errors (2) and return 0, 3 or 4. Every study takes ``--out`` (default
``out/NAME``). The table is also in ``docs/index.md`` ("Command lines and exit codes").
"""
from __future__ import annotations

import os
import sys

__all__ = ["EXIT_OK", "EXIT_MACHINE", "EXIT_BAD_INPUT", "EXIT_FLAGGED", "EXIT_UNSTABLE",
           "EXIT_INTERRUPTED", "EXIT_BROKEN_PIPE", "EXIT_CODES", "run_cli", "silence_stdout",
           "os_error_line", "whole_number"]

EXIT_OK, EXIT_MACHINE, EXIT_BAD_INPUT, EXIT_FLAGGED, EXIT_UNSTABLE = 0, 1, 2, 3, 4
EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 130, 141

#: code -> meaning (the table above; the commands' ``--help`` epilogs say the same)
EXIT_CODES = {
    EXIT_OK: "done",
    EXIT_MACHINE: "the machine's state: output cannot be written (read-only, full disk), input "
                  "cannot be read (permissions), out of memory",
    EXIT_BAD_INPUT: "bad input (an option or file out of its allowed range)",
    EXIT_FLAGGED: "done, a result flagged (outside the theory's range; pack: not converged)",
    EXIT_UNSTABLE: "pack: the run became unstable",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C); partial results kept",
    EXIT_BROKEN_PIPE: "output pipe closed (silent)",
}


def silence_stdout():
    """After a closed pipe: point stdout at /dev/null so that the interpreter's final flush is
    silent."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def os_error_line(exc) -> str:
    """One line for an ``OSError``: the path(s) and the system's reason, never a traceback."""
    where = exc.filename if exc.filename is not None else None
    if getattr(exc, "filename2", None):
        where = f"{where} -> {exc.filename2}"
    reason = exc.strerror or str(exc)
    return f"error: {where}: {reason}" if where else f"error: {reason}"


def run_cli(main, argv=None, *, partial=None) -> int:
    """Run ``main(argv)`` under the convention and return its exit code (anything but an int, e.g. ``None``, counts as 0).

    Ctrl-C -> one line and 130 (``partial()``, if given, returns text saying what was kept,
    e.g. the ``--out`` folder); a closed output pipe -> silent 141; an ``OSError`` (an output that
    cannot be written, a full disk, a file that cannot be read) -> one line naming the path and 1;
    ``MemoryError`` -> one line and 1. ``SystemExit`` (argparse's usage errors: 2) passes through;
    any other exception is a bug and keeps its traceback.
    """
    try:
        rc = main(argv)
        sys.stdout.flush()   # a full disk or closed pipe under stdout shows here, not at exit
        return rc if isinstance(rc, int) and not isinstance(rc, bool) else EXIT_OK
    except KeyboardInterrupt:
        kept = partial() if partial is not None else None
        print("interrupted" + (f"; {kept}" if kept else ""), file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        silence_stdout()
        return EXIT_BROKEN_PIPE
    except MemoryError as exc:
        print(f"error: out of memory{': ' + str(exc) if str(exc) else ''}", file=sys.stderr)
        return EXIT_MACHINE
    except OSError as exc:
        if exc.filename is None and sys.stdout is not None:
            silence_stdout()    # stdout itself failed (e.g. /dev/full): do not fail again at exit
        print(os_error_line(exc), file=sys.stderr)
        return EXIT_MACHINE


def whole_number(text) -> int:
    """argparse ``type=`` for integer options that also accepts ``1e9`` or ``4000.0`` (a whole
    number written as a float), so that the option's range check, not "invalid int value",
    answers a large value; ``1.5``, ``inf`` and words are refused as not whole numbers."""
    import argparse

    try:
        return int(text)
    except ValueError:
        pass
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
    if not (v == v and abs(v) != float("inf") and v == int(v)):
        raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}")
    return int(v)
