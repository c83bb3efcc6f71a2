"""What the two discrete methods share: the instability error, the run report and the atomic writer.

The disk engine (``dem.engine.integrate``, ``dem.engine.packing``) and the free-hexagon method both use these; this
module depends on nothing else in the project.
"""
from __future__ import annotations

import glob
import os
import tempfile
from dataclasses import dataclass, field

from microhom.results import Result

__all__ = ["InstabilityError", "RunReport", "run_report", "atomic_write", "remove_stale_temporaries"]


class InstabilityError(RuntimeError):
    """The run became unstable; ``state`` is the last good state, ``step`` the failing step."""

    def __init__(self, reason, state, step):
        super().__init__(f"unstable run stopped at step {step}: {reason} "
                         f"(last good state kept at step {state.step if state is not None else '?'})")
        self.reason = reason
        self.state = state
        self.step = step


def run_report(n, steps, wall, phases, detail, *, unit="particle", what="particles", stopped=False):
    """The LAMMPS-like end-of-run report shared by every scene: loop time, throughput and a
    per-phase timing table. ``detail`` is the scene's own parenthesis (time step, rebuilds...)."""
    ps = n * steps / wall if wall > 0 else float("nan")
    lines = [f"Loop time of {wall:.4g} s for {steps} steps with {n} {what} {detail}",
             f"Performance: {ps:.4g} {unit}-steps/s, {steps / wall if wall > 0 else float('nan'):.4g} steps/s",
             "Section     |  time (s) |   %"]
    for k, v in phases.items():
        lines.append(f"{k:<11s} | {v:9.4f} | {100 * v / wall if wall > 0 else 0:5.1f}")
    return RunReport(steps=steps, wall=wall, particle_steps_per_s=ps, phases=dict(phases),
                     stopped=stopped, table="\n".join(lines))


@dataclass(frozen=True)
class RunReport(Result):
    """Summary of one run (``Simulation.run`` or a mine scene's run), read-only.

    Attributes
    ----------
    steps : int
        Time steps taken.
    wall : float
        Wall time of the loop [s].
    particle_steps_per_s : float
        Throughput, particles (or cells) x steps per second [1/s].
    phases : dict
        Wall time per phase of the step [s] (neighbours, forces, integration, ...).
    stopped : bool
        True when a callback stopped the run early.
    table : str
        The LAMMPS-like text (loop time, performance, per-phase table); ``str(report)``.
    """

    steps: int
    wall: float
    particle_steps_per_s: float
    phases: dict = field(default_factory=dict)
    stopped: bool = False
    table: str = ""

    def __str__(self):
        return self.table

    def __getitem__(self, key):
        """``report["steps"]`` as ``report.steps`` (the fields only)."""
        if key not in self.__dataclass_fields__:
            raise KeyError(f"RunReport has no field {key!r}; fields: {sorted(self.__dataclass_fields__)}")
        return getattr(self, key)


def _temp_prefix(path):
    return ".tmp_" + os.path.basename(path) + "."


def _umask_mode():
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write(path, write, binary=True):
    """Write ``path`` atomically: ``write(fh)`` into a temporary file ``.tmp_<name>.*`` in the same
    folder, flush and fsync, then ``os.replace``; the temporary file is removed if writing fails
    (a kill -9 can leave one: :func:`remove_stale_temporaries`). The file gets the permissions of
    an ordinary new file (0666 less the umask), not mkstemp's 0600. Every checkpoint of the
    project (disk states, packings, hexagon models) goes through here."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(path), suffix=os.path.splitext(path)[1], dir=folder)
    try:
        os.fchmod(fd, _umask_mode())
        with os.fdopen(fd, "wb" if binary else "w") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError):   # name the file the caller asked for, not the temporary
            raise OSError(exc.errno, exc.strerror or str(exc), path) from exc
        raise


def remove_stale_temporaries(path) -> list:
    """Remove the temporary files :func:`atomic_write` left for ``path`` when its process was
    killed mid-write (call it before resuming from ``path``). Returns the removed paths."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    gone = []
    for tmp in glob.glob(os.path.join(glob.escape(folder), glob.escape(_temp_prefix(path)) + "*")):
        try:
            os.unlink(tmp)
            gone.append(tmp)
        except OSError:
            pass
    return gone
