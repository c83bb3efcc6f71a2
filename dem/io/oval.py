"""Kuhn's OVAL / DEMPLA StartFiles (the "D-file") of circular disks, as DEMPLA's manual defines them.

Layout (DEMPLA manual, version 0.2.5, section "StartFile: the initial particle arrangement")::

    1                                                        <- kshape (i1): 1 = circular 2D disks
      1002  2.97703143874021730E+01  2.97703143874021730E+01  1.00000000000000000E+00
            0.00000000000000000E+00  0.00000000000000000E+00  0.00000000000000000E+00
      3.13454063710418570E-01  1.71808487138605380E+01  2.16944835798332460E+01
      ...

* line 1: ``kshape`` (format ``i1``); only 1 (circular 2D disks) is supported here;
* line 2: ``np, xcell(1,1), xcell(2,2), xcell(3,3)`` (format ``i6, 3(1pd25.17)``): the particle
  count and the spacings of opposite periodic boundaries; ``xcell(3,3)`` is the third dimension,
  which a 2D run ignores ("any value will work");
* line 3: ``xcell(1,2), xcell(1,3), xcell(2,3)`` (format ``6x, 3(1pd25.17)``): the three shear
  offsets; ``xcell(1,2)`` is the x1-offset of the x2 boundaries, the other two concern the third
  direction and are kept as metadata;
* then one line per disk: ``radius, x1, x2`` (each ``1pd25.17``).

DEMPLA itself reads these lines list-directed (``read(1,*)``), so the reader takes
whitespace-separated numbers (Fortran ``D`` exponents accepted); the writer writes the fixed
columns the manual specifies.

The periodic cell is upper triangular (the manual: ``F_ij = 0`` for ``i > j``), with its corner at
the origin: cell vectors ``a = (xcell(1,1), 0)`` and ``b = (xcell(1,2), xcell(2,2))``, so
``h = [[xcell(1,1), xcell(1,2)], [0, xcell(2,2)]]`` (columns = cell vectors).

Stiffness convention: in OVAL the normal stiffness kn multiplies *half* the overlap (force per unit
overlap = kn / 2). Build networks with ``config.network(kn=kn_oval, kn_convention="oval")``, which
halves kn.
"""
from __future__ import annotations

import os
import re
import warnings

from ._core import (Configuration, FormatError, build, check_positive, open_bytes, parse_number,
                    parse_table, require_particles, show)

__all__ = ["read_oval", "write_oval"]

_FORTRAN_EXP = re.compile(rb"(?<=[0-9.])[dD](?=[+-]?[0-9])")  # 1.5D-03 -> 1.5e-03
_COL = 25  # width of a 1pd25.17 field


def read_oval(path) -> Configuration:
    """Read a DEMPLA/OVAL D-file of circular disks (layout and cell: module docstring).

    Returns a periodic :class:`~dem.io.Configuration` (``origin = (0, 0)``, ids 1..N in file order,
    ``source_format = "oval"``) with ``meta`` keys ``oval_shape_code``, ``oval_xcell33`` (third
    dimension of line 2), ``oval_xcell13``, ``oval_xcell23`` (the offsets of the third direction on
    line 3; a non-zero value is kept and warned about: a 2D cell has no third direction).

    OVAL's kn multiplies half the overlap: use ``config.network(kn=..., kn_convention="oval")``
    (``--kn-convention oval`` on the command line).
    Raises :class:`~dem.io.FormatError` (file, line, field) for a shape code other than 1, a bad header,
    a line 3 without three offsets, a truncated particle list, a wrong column count, non-numeric
    values, a radius <= 0 or no particles.
    """
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
        raise FormatError(path, k, None, "truncated: a D-file starts with the kshape line, the "
                          "'np xcell(1,1) xcell(2,2) xcell(3,3)' line and the offsets line")
    (t1, l1), (t2, l2), (t3, l3) = header
    code_f = parse_number(t1[0], path, l1, "kshape")
    if code_f != 1 or len(t1) != 1:
        raise FormatError(path, l1, "kshape",
                          f"unknown shape code {show(' '.join(t1))}: only 1 (circular disks) is "
                          "supported (ovals, ellipses, nobbies and 3D shapes are not)")
    if len(t2) != 4:
        raise FormatError(path, l2, None, f"expected 4 numbers (np xcell(1,1) xcell(2,2) "
                          f"xcell(3,3)), found {len(t2)}")
    n_f = parse_number(t2[0], path, l2, "np")
    if n_f != int(n_f) or n_f < 0:
        raise FormatError(path, l2, "np", f"particle count must be a non-negative integer: "
                          f"{show(t2[0])}")
    n = int(n_f)
    lx = parse_number(t2[1], path, l2, "xcell(1,1)")
    ly = parse_number(t2[2], path, l2, "xcell(2,2)")
    l3d = parse_number(t2[3], path, l2, "xcell(3,3)")
    for name, v in (("xcell(1,1)", lx), ("xcell(2,2)", ly)):
        if v <= 0:
            raise FormatError(path, l2, name, f"cell dimension must be > 0, got {v!r}")
    if len(t3) != 3:
        hint = (" (a two-offset line is the layout dem.io wrote before it followed DEMPLA's "
                "manual: append xcell(2,3) = 0)" if len(t3) == 2 else "")
        raise FormatError(path, l3, None, f"expected 3 shear offsets (xcell(1,2) xcell(1,3) "
                          f"xcell(2,3)), found {len(t3)}{hint}")
    sx, s13, s23 = (parse_number(t, path, l3, f) for t, f in
                    zip(t3, ("xcell(1,2)", "xcell(1,3)", "xcell(2,3)")))
    first = k + 1
    block = b"\n".join(raw[k:])
    arr = parse_table(block, ("radius", "x1", "x2"), path, first, nrows=n)
    require_particles(arr.shape[0], path)
    check_positive(arr[:, 0], "radius", path, block, first)
    if s13 != 0.0 or s23 != 0.0:
        warnings.warn(f"{path}: line {l3} has offsets of the third direction xcell(1,3) = {s13!r}, "
                      f"xcell(2,3) = {s23!r}; a 2D cell has no third direction, so they are kept "
                      "as meta['oval_xcell13'], meta['oval_xcell23'] and not used", stacklevel=2)
    meta = {"oval_shape_code": 1, "oval_xcell33": l3d, "oval_xcell13": s13, "oval_xcell23": s23,
            "kn_convention_hint": "oval"}
    return build(path, positions=arr[:, 1:3], radii=arr[:, 0], cell=[[lx, sx], [0.0, ly]],
                 origin=(0.0, 0.0), meta=meta, source=path, source_format="oval")


def _d(x) -> str:
    """One ``1pd25.17`` field as DEMPLA's own files have it: 17 significant digits (enough for the
    float64 to read back exactly), an 18th digit 0 (gfortran's padding) and an ``E`` exponent."""
    mant, exp = f"{float(x):.16E}".split("E")
    text = f"{mant}0E{exp}"
    if len(text) >= _COL:  # a negative value with a 3-digit exponent would touch its neighbour
        raise ValueError(f"{float(x)!r} does not fit a 1pd25.17 field with a blank before it")
    return text.rjust(_COL)


def write_oval(path, config, *, xcell33=None):
    """Write a periodic ``config`` as a DEMPLA D-file of circular disks, in the manual's fixed
    columns: ``i1`` / ``i6, 3(1pd25.17)`` / ``6x, 3(1pd25.17)`` / ``3(1pd25.17)`` per disk.

    The cell must be upper triangular, ``[[xcell(1,1), xcell(1,2)], [0, xcell(2,2)]]`` (use
    ``config.to_restricted()`` first for a rotated cell); positions are written relative to
    ``config.origin``, as stored (not wrapped). ``xcell33`` (the third dimension, ignored in 2D)
    defaults to ``meta['oval_xcell33']`` or 1; the offsets of the third direction to
    ``meta['oval_xcell13']``, ``meta['oval_xcell23']`` or 0.
    """
    if config.cell is None:
        raise ValueError("a D-file needs a periodic cell")
    h = config.cell
    if h[1, 0] != 0.0 or not (h[0, 0] > 0 and h[1, 1] > 0):
        raise ValueError("a D-file's cell is [[xcell(1,1), xcell(1,2)], [0, xcell(2,2)]] with "
                         "positive diagonal: write config.to_restricted() instead")
    n = config.n_particles
    if n > 999_999:
        raise ValueError(f"a D-file holds at most 999999 particles (np is an i6 field), got {n}")
    if xcell33 is None:
        xcell33 = config.meta.get("oval_xcell33", 1.0)
    s13 = config.meta.get("oval_xcell13", 0.0)
    s23 = config.meta.get("oval_xcell23", 0.0)
    x = config.positions - config.origin
    lines = ["1\n", f"{n:6d}{_d(h[0, 0])}{_d(h[1, 1])}{_d(xcell33)}\n",
             f"{'':6s}{_d(h[0, 1])}{_d(s13)}{_d(s23)}\n"]
    with open(path, "w") as f:
        f.writelines(lines)
        f.writelines(f"{_d(r)}{_d(a)}{_d(b)}\n" for r, (a, b) in zip(config.radii, x))
