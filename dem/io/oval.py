"""Kuhn's OVAL / DEMPLA disk assemblies (the "D-file").

Layout, as read here (whitespace-separated, Fortran-style free format; ``D``/``E`` exponents
accepted)::

    1                         <- shape code: 1 = circular disks (anything else: FormatError)
    N  Lx  Ly  extra          <- number of particles, cell lengths, a third number (kept as metadata)
    sx  s2                    <- shear offsets of the periodic cell
    r  x  y                   <- one line per particle: radius, centre
    ...

Interpretation of the cell (no OVAL manual or source was available to confirm it): the periodic
cell is the parallelogram with vectors ``a = (Lx, 0)`` and ``b = (sx, Ly)`` — ``sx`` is the
x-offset of the top boundary relative to the bottom one — with its lower-left corner at the
origin, so ``h = [[Lx, sx], [0, Ly]]``. The second offset ``s2`` is kept as
``meta['oval_offset2']``; with ``shear="xy"`` it is instead taken as the y-offset of the right
boundary, ``h = [[Lx, sx], [s2, Ly]]``. A non-zero ``s2`` read with the default gives a warning.

Stiffness convention: in OVAL the normal stiffness kn multiplies *half* the overlap (force per unit
overlap = kn / 2). Build networks with ``config.network(kn=kn_oval, kn_convention="oval")``, which
halves kn.
"""
from __future__ import annotations

import os
import re
import warnings

import numpy as np

from ._core import Configuration, FormatError, check_positive, open_bytes, parse_number, parse_table


def _f(x):
    """Shortest text that reads back as the same float64."""
    return repr(float(x))


__all__ = ["read_oval", "write_oval"]

_FORTRAN_EXP = re.compile(rb"(?<=[0-9.])[dD](?=[+-]?[0-9])")  # 1.5D-03 -> 1.5e-03




def read_oval(path, *, shear="x") -> Configuration:
    """Read an OVAL/DEMPLA D-file of circular disks (layout and cell convention: module docstring).

    Returns a periodic :class:`Configuration` (``origin = (0, 0)``, ids 1..N in file order,
    ``source_format = "oval"``) with ``meta`` keys ``oval_shape_code``, ``oval_extra`` (third
    number of line 2), ``oval_offsets`` (both numbers of line 3) and ``oval_offset2``.
    ``shear``: ``"x"`` (default, cell vectors (Lx, 0), (sx, Ly)) or ``"xy"`` (cell vectors
    (Lx, s2), (sx, Ly)).

    OVAL's kn multiplies half the overlap: use ``config.network(kn=..., kn_convention="oval")``.
    Raises :class:`FormatError` (file, line, field) for a shape code other than 1, a bad header,
    truncated particle list, wrong column count, non-numeric values or a radius <= 0.
    """
    if shear not in ("x", "xy"):
        raise ValueError(f"shear must be 'x' or 'xy', got {shear!r}")
    path = os.fspath(path)
    data = _FORTRAN_EXP.sub(b"e", open_bytes(path))
    raw = data.split(b"\n")
    header = []
    k = 0
    while len(header) < 3 and k < len(raw):
        text = raw[k].decode("utf-8", "replace").strip()
        if text:
            header.append((text.split(), k + 1))
        k += 1
    if len(header) < 3:
        raise FormatError(path, k, None, "truncated: need shape-code, size and offset lines")
    (t1, l1), (t2, l2), (t3, l3) = header
    if len(t1) < 1:
        raise FormatError(path, l1, "shape code", "missing")
    code_f = parse_number(t1[0], path, l1, "shape code")
    if code_f != 1:
        raise FormatError(path, l1, "shape code",
                          f"unknown shape code {t1[0]!r}: only 1 (circular disks) is supported "
                          "(ovals and other shapes are not)")
    if len(t2) != 4:
        raise FormatError(path, l2, None,
                          f"expected 4 numbers (N Lx Ly extra), found {len(t2)}")
    n_f = parse_number(t2[0], path, l2, "N")
    if n_f != int(n_f) or n_f < 0:
        raise FormatError(path, l2, "N",
                          f"particle count must be a non-negative integer: {t2[0]!r}")
    n = int(n_f)
    lx = parse_number(t2[1], path, l2, "Lx")
    ly = parse_number(t2[2], path, l2, "Ly")
    extra = parse_number(t2[3], path, l2, "extra")
    if lx <= 0:
        raise FormatError(path, l2, "Lx", f"cell length must be > 0, got {lx!r}")
    if ly <= 0:
        raise FormatError(path, l2, "Ly", f"cell length must be > 0, got {ly!r}")
    if len(t3) != 2:
        raise FormatError(path, l3, None, f"expected 2 shear offsets, found {len(t3)}")
    sx = parse_number(t3[0], path, l3, "shear offset 1")
    s2 = parse_number(t3[1], path, l3, "shear offset 2")
    first = k + 1
    block = b"\n".join(raw[k:])
    arr = parse_table(block, ("radius", "x", "y"), path, first, nrows=n)
    check_positive(arr[:, 0], "radius", path, block, first)
    if shear == "xy":
        cell = np.array([[lx, sx], [s2, ly]])
    else:
        cell = np.array([[lx, sx], [0.0, ly]])
        if s2 != 0.0:
            warnings.warn(f"{path}: second offset on line {l3} is {s2!r}; it is kept as "
                          "meta['oval_offset2'] and NOT used as a shear (pass shear='xy' to use "
                          "it as the y-offset of the right boundary)", stacklevel=2)
    meta = {"oval_shape_code": int(code_f), "oval_extra": extra, "oval_offsets": [sx, s2],
            "oval_offset2": s2, "oval_shear": shear, "kn_convention_hint": "oval"}
    return Configuration(positions=arr[:, 1:3], radii=arr[:, 0], cell=cell, origin=(0.0, 0.0),
                         meta=meta, source=path, source_format="oval")


def write_oval(path, config, *, extra=None):
    """Write a periodic ``config`` as an OVAL D-file (shape code 1, layout of :func:`read_oval`).

    The cell must be ``[[Lx, sx], [s2, Ly]]`` with ``s2 = 0`` unless it was read with
    ``shear="xy"`` (``meta['oval_shear']``); positions are written relative to ``config.origin``.
    ``extra`` (third number of line 2) defaults to ``meta['oval_extra']`` or 0.
    """
    if config.cell is None:
        raise ValueError("an OVAL D-file needs a periodic cell")
    h = config.cell
    shear = config.meta.get("oval_shear", "x")
    if shear == "x" and h[1, 0] != 0.0:
        raise ValueError("cell vector a is not along x: OVAL's cell is (Lx, 0), (sx, Ly); "
                         "rotate with config.to_restricted() first")
    s2 = h[1, 0] if shear == "xy" else float(config.meta.get("oval_offset2", 0.0))
    if extra is None:
        extra = config.meta.get("oval_extra", 0.0)
    x = config.positions - config.origin
    with open(path, "w") as f:
        f.write("1\n")
        f.write(f"{config.n_particles} {_f(h[0, 0])} {_f(h[1, 1])} {_f(float(extra))}\n")
        f.write(f"{_f(h[0, 1])} {_f(float(s2))}\n")
        buf = np.column_stack([config.radii, x])
        np.savetxt(f, buf, fmt="%.17g")
