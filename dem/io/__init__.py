"""Configurations in and out: LAMMPS data/dump, Kuhn's OVAL D-files, npz, CSV and VTK.

Every reader returns a :class:`Configuration` (positions, radii, periodic cell, origin, ids, ...)
whose :meth:`Configuration.network` builds the :class:`~microhom.network.ContactNetwork`; every
writer takes a ``Configuration`` (or a ``ContactNetwork``). Malformed files raise
:class:`FormatError` (a ``ValueError``) naming the file, the line and the field.

>>> from dem import io
>>> cfg = io.read("packing.lammpstrj")            # format from the extension
>>> net = cfg.network(kn=1e5, kt=5e4)             # contacts by overlap
>>> io.write("packing.data", cfg)                 # continue in LAMMPS (read_data)
>>> io.write("packing.vtu", cfg, network=net)     # ParaView (needs meshio)

Formats (``format=`` names and extensions) are described in ``docs/formats.md``.

The reading rule (every reader): the path must be a regular file (a FIFO, a device, a socket or a
folder is refused by name: :class:`FormatError`) no larger than the memory available to parse it
(:func:`read_limit`, else :class:`FileTooLarge`); see :func:`check_regular_file`.
"""
from __future__ import annotations

import os

from microhom.network import ContactNetwork

from ._core import (KN_CONVENTIONS, Configuration, FileTooLarge, FormatError, available_memory,
                    check_regular_file, read_limit)
from .lammps import (box_from_dump_bounds, dump_bounds, iter_lammps_dump, read_lammps_data,
                     read_lammps_dump, write_lammps_data, write_lammps_dump)
from .oval import read_oval, write_oval
from .simple import FORMAT_VERSION, read_csv, read_npz, read_npz_network, write_csv, write_npz
from .vtk import read_vtk, write_vtk

__all__ = ["Configuration", "FormatError", "FileTooLarge", "KN_CONVENTIONS", "check_regular_file",
           "available_memory", "read_limit", "FORMAT_VERSION", "FORMATS",
           "read", "write", "detect_format",
           "read_lammps_data", "write_lammps_data", "read_lammps_dump", "write_lammps_dump",
           "iter_lammps_dump", "dump_bounds", "box_from_dump_bounds",
           "read_oval", "write_oval", "read_npz", "read_npz_network", "write_npz", "read_csv", "write_csv",
           "read_vtk", "write_vtk"]

#: format name -> (reader, writer)
FORMATS = {
    "lammps-data": (read_lammps_data, write_lammps_data),
    "lammps-dump": (read_lammps_dump, write_lammps_dump),
    "oval": (read_oval, write_oval),
    "npz": (read_npz, write_npz),
    "csv": (read_csv, write_csv),
    "vtk": (read_vtk, write_vtk),
}

_EXTENSIONS = {".data": "lammps-data", ".lmp": "lammps-data",
               ".dump": "lammps-dump", ".lammpstrj": "lammps-dump",
               ".dfile": "oval", ".d": "oval",
               ".npz": "npz", ".csv": "csv", ".vtu": "vtk", ".vtk": "vtk"}


def detect_format(path) -> str:
    """Format name from the file name: the extension (a trailing ``.gz`` is looked through for
    LAMMPS files), else ``"oval"`` for names starting with ``D`` (Kuhn's ``D0001`` style)."""
    name = os.path.basename(os.fspath(path))
    base = name[:-3] if name.lower().endswith(".gz") else name
    ext = os.path.splitext(base)[1].lower()
    if ext in _EXTENSIONS:
        fmt = _EXTENSIONS[ext]
        if name != base and not fmt.startswith("lammps"):
            raise ValueError(f"{name}: gzip is supported for LAMMPS files only")
        return fmt
    if base.startswith("D"):
        return "oval"
    raise ValueError(f"cannot tell the format of {name!r} from its name; give it (format= in "
                     f"Python, --format on the command line) as one of {sorted(FORMATS)} "
                     f"(extensions: {sorted(_EXTENSIONS)}, or D* for OVAL)")


def _format(path, format):
    if format is None:
        return detect_format(path)
    if format not in FORMATS:
        raise ValueError(f"unknown format {format!r}; known: {sorted(FORMATS)}")
    return format


def read(path, format=None, **kwargs) -> Configuration:
    """Read a configuration; ``format`` from the name (:func:`detect_format`) unless given.
    ``kwargs`` go to the reader (e.g. ``frame=-1`` for dumps, ``periodic=False`` for data files)."""
    return FORMATS[_format(path, format)][0](path, **kwargs)


def write(path, config, format=None, **kwargs):
    """Write a :class:`Configuration` or a :class:`~microhom.network.ContactNetwork`.

    ``format`` from the name unless given; ``kwargs`` go to the writer. For VTK a network given as
    ``config`` (or as ``network=``) also writes its contacts as lines.
    """
    fmt = _format(path, format)
    if not isinstance(config, Configuration):
        if isinstance(config, ContactNetwork):
            if fmt == "vtk":
                kwargs.setdefault("network", config)
            config = Configuration.from_network(config)
        else:
            raise TypeError(f"expected a Configuration or ContactNetwork, got {type(config)!r}")
    if config.dim != 2 and not fmt.startswith("lammps"):
        raise ValueError(f"a {config.dim}D configuration can be written as lammps-data or "
                         f"lammps-dump only; the {fmt} format holds 2D disks")
    if kwargs.get("append"):      # appending to a dump: in place (an existing file is extended)
        return FORMATS[fmt][1](path, config, **kwargs)
    return _write_atomic(path, lambda tmp: FORMATS[fmt][1](tmp, config, **kwargs))


def _write_atomic(path, write):
    """``write(tmp)`` into a temporary file beside ``path`` (same name ending, so that writers
    choosing by extension choose the same), then renamed onto ``path``: a full disk or a killed
    run leaves the old file (or none), never a truncated one. An ``OSError`` is re-raised naming
    ``path`` and the system's reason, with the temporary file removed."""
    path = os.fspath(path)
    folder, name = os.path.split(path)
    tmp = os.path.join(folder, f".tmp-{os.getpid()}-{name}")
    try:
        out = write(tmp)
        os.replace(tmp, path)
        return out
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), path) from None   # names path
    finally:
        if os.path.exists(tmp):
            try:
                os.unlink(tmp)
            except OSError:
                pass
