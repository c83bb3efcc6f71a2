"""LAMMPS data files and text dumps (2D disks and 3D spheres, ``atom_style sphere``).

Box conventions (LAMMPS ``Howto_triclinic``): a restricted triclinic box has edge vectors
``a = (lx, 0, 0)``, ``b = (xy, ly, 0)``, ``c = (xz, yz, lz)`` with ``lx = xhi - xlo``,
``ly = yhi - ylo``, ``lz = zhi - zlo``, origin ``(xlo, ylo, zlo)``; so the shape matrix is
``h = [[lx, xy, xz], [0, ly, yz], [0, 0, lz]]`` (columns = cell vectors), and its upper-left
2 x 2 block ``[[lx, xy], [0, ly]]`` in 2D.
Dump files give the *bounding box* of the tilted cell, ``xlo_bound = xlo + min(0, xy, xz, xy+xz)``,
``xhi_bound = xhi + max(0, xy, xz, xy+xz)``, ``ylo_bound = ylo + min(0, yz)``,
``yhi_bound = yhi + max(0, yz)``; the readers/writers here invert/apply exactly that. LAMMPS's
*general* triclinic form (any orientation; data header ``avec/bvec/cvec/abc origin``, dump
``BOX BOUNDS abc origin``, LAMMPS >= 17Apr2024) is read, and written for cells that are not in the
restricted form (or use :meth:`~dem.io.Configuration.to_restricted` first for older LAMMPS versions).

Dimension (neither file format states it): ``dimension=None`` (default) reads a file as 3D when
its z direction is periodic and its z coordinates are not all equal, else as 2D (LAMMPS's
``dimension 2`` keeps z fixed: ``fix enforce2d``); ``dimension=2`` or ``3`` says it. A data file
does not say its boundaries: its z is periodic exactly when ``periodic=True``. A dump says them on
its ``BOX BOUNDS`` line. So a 3D packing with a non-periodic z needs ``dimension=3``.
"""
from __future__ import annotations

import io
import os
import warnings

import numpy as np

from ._core import (Configuration, FormatError, build, check_positive, open_bytes, parse_number,
                    parse_table, require_particles, row_line, show)


def _f(x):
    """Shortest text that reads back as the same float64."""
    return repr(float(x))


__all__ = ["read_lammps_data", "read_lammps_dump", "write_lammps_data", "write_lammps_dump",
           "dump_bounds", "box_from_dump_bounds", "iter_lammps_dump"]

_SECTION_WORDS = {"Atoms", "Velocities", "Masses", "Ellipsoids", "Lines", "Triangles", "Bodies",
                  "Bonds", "Angles", "Dihedrals", "Impropers"}
_SPHERE_COLS = ("id", "type", "diameter", "density", "x", "y", "z")
_IMAGE_COLS = ("ix", "iy", "iz")
_REL_TOL = 1e-9  # relative slack of the "inside a non-periodic box" check


# ---- box helpers ------------------------------------------------------------------------------

def dump_bounds(xlo, xhi, ylo, yhi, xy=0.0, xz=0.0, yz=0.0):
    """LAMMPS dump bounding box of a restricted triclinic box: (xlo_b, xhi_b, ylo_b, yhi_b), all in
    the length unit of the box bounds and tilt factors ``xy``, ``xz``, ``yz``."""
    return (xlo + min(0.0, xy, xz, xy + xz), xhi + max(0.0, xy, xz, xy + xz),
            ylo + min(0.0, yz), yhi + max(0.0, yz))


def box_from_dump_bounds(xlo_b, xhi_b, ylo_b, yhi_b, xy=0.0, xz=0.0, yz=0.0):
    """Inverse of :func:`dump_bounds`: (xlo, xhi, ylo, yhi) of the box itself (same length unit)."""
    return (xlo_b - min(0.0, xy, xz, xy + xz), xhi_b - max(0.0, xy, xz, xy + xz),
            ylo_b - min(0.0, yz), yhi_b - max(0.0, yz))


def _restricted(cell, rtol=1e-12):
    scale = np.abs(cell).max()
    return bool(np.all(np.abs(np.tril(cell, -1)) <= rtol * scale) and np.all(np.diag(cell) > 0))


def _as3(h, origin):
    """(3, 3) cell and (3,) origin of a 2D or 3D box (a 2D box gets c = (0, 0, 1), z0 = -0.5)."""
    if h.shape == (3, 3):
        return h, origin
    h3 = np.eye(3)
    h3[:2, :2] = h
    return h3, np.array([origin[0], origin[1], -0.5])


def _box_of(config: Configuration):
    """(h, origin, periodic) of the box to write: the cell, meta['box'], or the disks' extent."""
    if config.cell is not None:
        return config.cell, config.origin, True
    if "box" in config.meta:
        return np.asarray(config.meta["box"], float), config.origin, False
    lo = (config.positions - config.radii[:, None]).min(axis=0)
    hi = (config.positions + config.radii[:, None]).max(axis=0)
    return np.diag(hi - lo), lo, False


def _dimension(dimension, z, z_periodic, path):
    """The dimension of a file: ``dimension`` if given (2 or 3), else 3 when z is periodic and
    the z coordinates ``z`` (None: no z column) are not all equal, else 2."""
    if dimension is not None:
        if dimension not in (2, 3):
            raise ValueError(f"dimension must be None (from the file), 2 or 3, got {dimension!r}")
        if dimension == 3 and z is None:
            raise FormatError(path, None, "z", "dimension=3 needs z coordinates")
        return int(dimension)
    return 3 if (z_periodic and z is not None and z.size and np.ptp(z) > 0) else 2


def _check_inside(positions, cell, origin, dims, path, line_of_row, names=("x", "y", "z")):
    """FormatError for the first particle outside the box along a non-periodic dimension."""
    s = np.linalg.solve(cell, (positions - origin).T).T
    for d in dims:
        bad = np.flatnonzero((s[:, d] < -_REL_TOL) | (s[:, d] > 1 + _REL_TOL))
        if bad.size:
            k = int(bad[0])
            raise FormatError(path, line_of_row(k), names[d],
                              f"particle {k} at {names[d]} = {float(positions[k, d])!r} lies outside "
                              f"the non-periodic box")




# ---- data files -------------------------------------------------------------------------------

def _section_name(text):
    words = text.split()
    if not words:
        return None
    if words[0] in _SECTION_WORDS and len(words) == 1:
        return words[0]
    if text.endswith("Coeffs") or text.endswith("Labels"):
        return text
    return None


def read_lammps_data(path, *, periodic=True, unwrap=False, dimension=None) -> Configuration:
    """Read a 2D or 3D LAMMPS data file with ``atom_style sphere``.

    Atoms lines: ``id type diameter density x y z [ix iy iz]``; radii = diameter / 2. Optional
    ``Velocities`` section (``id vx vy vz wx wy wz``) fills ``velocities`` and ``fields['omegaz']``;
    ``density`` (and image flags ``ix``, ``iy`` when given) go to ``fields``. The box comes from the
    ``xlo xhi`` / ``ylo yhi`` lines and the optional ``xy xz yz`` tilt line (cell a = (lx, 0),
    b = (xy, ly), origin (xlo, ylo)), or from the general triclinic ``avec``/``bvec``/``abc origin``
    lines. Other sections (Masses, Bonds, ...) are skipped.

    A data file does not say which boundaries are periodic (that is the input script's
    ``boundary`` command): ``periodic=True`` (default) takes x and y as periodic (``cell`` set);
    ``periodic=False`` gives ``cell=None``, keeps the box in ``meta['box']`` and checks that every
    particle lies inside it. ``unwrap=True`` adds the image flags to the positions
    (x + ix a + iy b [+ iz c]); by default positions are kept as written. Raises
    :class:`~dem.io.FormatError`.

    3D (``dimension=3``, or ``None`` and a periodic file whose z coordinates vary: see the module
    docstring): positions (N, 3), cell (3, 3) from the ``zlo zhi`` line and the tilts ``xz yz``
    (``cvec`` in the general form), velocities (N, 3) and ``fields['omegax'|'omegay'|'omegaz']``.
    """
    path = os.fspath(path)
    data = open_bytes(path)
    lines = data.split(b"\n")
    meta = {"title": lines[0].decode("utf-8", "replace").strip()} if lines else {}
    k, natoms, lo_hi, tilt, gen = _data_header(lines, path, meta)
    if natoms is None:
        raise FormatError(path, None, "atoms", "header has no 'N atoms' line (not a LAMMPS data "
                          "file?)")
    if natoms < 0:
        raise FormatError(path, None, "atoms", f"negative atom count {natoms}")
    require_particles(natoms, path)
    cell, origin = _data_box(lo_hi, tilt, gen, path, meta)
    sections = _data_sections(lines, k)
    arr, block, first, ncol = _data_atoms(lines, sections, natoms, path)

    def line_of_row(r):
        return row_line(block, first, r, comment="#")

    ids = arr[:, 0].astype(np.int64)
    _check_unique(ids, path, line_of_row)
    dim = _dimension(dimension, arr[:, 6], periodic, path)
    meta["dimension"] = dim
    if dim == 2:
        cell, origin = cell[:2, :2].copy(), origin[:2].copy()
    pos = arr[:, 4:4 + dim].copy()
    fields = {"density": arr[:, 3].copy()}
    if ncol == 10:
        for m, c in enumerate(_IMAGE_COLS[:dim]):
            fields[c] = arr[:, 7 + m].astype(np.int64)
            if unwrap:
                pos += fields[c][:, None] * cell[:, m]
    velocities = None
    if "Velocities" in sections:
        velocities = _data_velocities(lines, sections["Velocities"], ids, dim, fields, path)
    if not periodic:
        _check_inside(pos, cell, origin, tuple(range(dim)), path, line_of_row)
        meta["box"] = cell.tolist()
    meta["sections"] = sorted(sections)
    return build(path, positions=pos, radii=0.5 * arr[:, 2], cell=cell if periodic else None,
                         origin=origin, ids=ids, types=arr[:, 1].astype(np.int64),
                         velocities=velocities, fields=fields, meta=meta, source=path,
                         source_format="lammps-data")


def _data_header(lines, path, meta):
    """Parse the header of a data file (the lines before the first section keyword).

    Returns ``(k, natoms, lo_hi, tilt, gen)``: the index of the first section line, the ``N atoms``
    count (None if absent), ``{"x": (lo, hi), ...}`` from the ``xlo xhi`` / ``ylo yhi`` /
    ``zlo zhi`` lines, the ``xy xz yz`` tilts, and the general triclinic ``avec bvec cvec`` /
    ``abc origin`` vectors by name. Other count lines (``N atom types``, ...) go to
    ``meta['header']``; a line that is neither raises :class:`~dem.io.FormatError`."""
    natoms = None
    lo_hi = {}
    tilt = (0.0, 0.0, 0.0)
    gen = {}
    k = 1
    while k < len(lines):
        text = lines[k].decode("utf-8", "replace").split("#", 1)[0].strip()
        if not text:
            k += 1
            continue
        if _section_name(text):
            break
        toks = text.split()
        lineno = k + 1
        if toks[-1] == "atoms" and len(toks) == 2:
            natoms = parse_number(toks[0], path, lineno, "atoms", int)
        elif toks[-2:] in (["xlo", "xhi"], ["ylo", "yhi"], ["zlo", "zhi"]) and len(toks) == 4:
            lo_hi[toks[-2][0]] = (parse_number(toks[0], path, lineno, toks[2]),
                                  parse_number(toks[1], path, lineno, toks[3]))
        elif toks[-3:] == ["xy", "xz", "yz"] and len(toks) == 6:
            tilt = tuple(parse_number(t, path, lineno, n) for t, n in zip(toks[:3], toks[3:]))
        elif toks[-1] in ("avec", "bvec", "cvec") and len(toks) == 4:
            gen[toks[-1]] = [parse_number(t, path, lineno, toks[-1]) for t in toks[:3]]
        elif toks[-2:] == ["abc", "origin"] and len(toks) == 5:
            gen["origin"] = [parse_number(t, path, lineno, "abc origin") for t in toks[:3]]
        else:
            meta.setdefault("header", []).append(text)
            try:
                float(toks[0])
            except ValueError:
                raise FormatError(path, lineno, None,
                                  f"unknown header line or section {show(text, 60)}") from None
        k += 1
    return k, natoms, lo_hi, tilt, gen


def _data_box(lo_hi, tilt, gen, path, meta):
    """(3, 3) cell (columns = cell vectors) and (3,) origin of a data file's header: the general
    triclinic vectors when given, else the restricted box ``[[lx, xy, xz], [0, ly, yz],
    [0, 0, lz]]`` (a 2D file without ``zlo zhi`` gets z in [-0.5, 0.5])."""
    if gen:
        missing = {"avec", "bvec", "origin"} - set(gen)
        if missing:
            raise FormatError(path, None, sorted(missing)[0], "incomplete general triclinic box")
        cell = np.array([gen["avec"], gen["bvec"], gen.get("cvec", [0.0, 0.0, 1.0])]).T
        origin = np.array(gen["origin"])
        meta["triclinic"] = "general"
    else:
        for d in "xy":
            if d not in lo_hi:
                raise FormatError(path, None, f"{d}lo {d}hi", "header has no box line")
        (xlo, xhi), (ylo, yhi) = lo_hi["x"], lo_hi["y"]
        if not (xhi > xlo and yhi > ylo):
            raise FormatError(path, None, "xlo xhi" if xhi <= xlo else "ylo yhi",
                              "box bounds must have lo < hi")
        zlo, zhi = lo_hi.get("z", (-0.5, 0.5))
        if not zhi > zlo:
            raise FormatError(path, None, "zlo zhi", "box bounds must have lo < hi")
        cell = np.array([[xhi - xlo, tilt[0], tilt[1]], [0.0, yhi - ylo, tilt[2]],
                         [0.0, 0.0, zhi - zlo]])
        origin = np.array([xlo, ylo, zlo])
        meta["tilt"] = list(tilt)
    meta["zlo_zhi"] = list(lo_hi.get("z", (-0.5, 0.5)))
    return cell, origin


def _data_sections(lines, k):
    """The sections from line index ``k`` on: {name: (first line index, end index, style)},
    ``style`` the comment after the keyword (``Atoms # sphere``) or None."""
    sections = {}
    current, start, style = None, None, None
    for j in range(k, len(lines) + 1):
        text = (lines[j].decode("utf-8", "replace") if j < len(lines) else "")
        name = _section_name(text.split("#", 1)[0].strip()) if j < len(lines) else "__end__"
        if name:
            if current is not None:
                sections[current] = (start, j, style)
            current, start = name, j + 1
            style = text.split("#", 1)[1].strip() if "#" in text else None
    return sections


def _data_atoms(lines, sections, natoms, path):
    """The ``Atoms`` section (``atom_style sphere``: ``id type diameter density x y z [ix iy iz]``).

    Returns ``(arr, block, first, ncol)``: the (natoms, ncol) table, the section's bytes, the
    1-based line number of its first line and the column count (7, or 10 with image flags)."""
    if "Atoms" not in sections:
        raise FormatError(path, None, "Atoms", "no Atoms section")
    a0, a1, style = sections["Atoms"]
    if style and style.split()[0] != "sphere":
        raise FormatError(path, a0, "Atoms",
                          f"atom_style {style.split()[0]!r} is not supported: need 'sphere' "
                          f"(id type diameter density x y z)")
    block = b"\n".join(lines[a0:a1])
    first = a0 + 1
    ncol = 7
    for j in range(a0, a1):
        toks = lines[j].split(b"#", 1)[0].split()
        if toks:
            ncol = len(toks)
            if ncol not in (7, 10):
                raise FormatError(path, j + 1, None,
                                  f"expected 7 or 10 columns (atom_style sphere: "
                                  f"{' '.join(_SPHERE_COLS)} [ix iy iz]), found {ncol}")
            break
    cols = _SPHERE_COLS + (_IMAGE_COLS if ncol == 10 else ())
    arr = parse_table(block, cols, path, first, nrows=natoms, comment="#")
    check_positive(arr[:, 2], "diameter", path, block, first, comment="#")
    return arr, block, first, ncol


def _data_velocities(lines, section, ids, dim, fields, path):
    """The ``Velocities`` section (``id vx vy vz wx wy wz``) in the order of the atoms ``ids``:
    returns the (N, dim) velocities and puts the angular velocities in ``fields`` (``omegaz``;
    3D: ``omegax``, ``omegay``, ``omegaz``)."""
    natoms = len(ids)
    v0, v1, _ = section
    vblock = b"\n".join(lines[v0:v1])
    vcols = ("id", "vx", "vy", "vz", "wx", "wy", "wz")
    varr = parse_table(vblock, vcols, path, v0 + 1, nrows=natoms, comment="#")
    order = np.argsort(ids)
    where = np.searchsorted(ids, varr[:, 0].astype(np.int64), sorter=order)
    where = np.clip(where, 0, natoms - 1)
    idx = order[where]
    badv = np.flatnonzero(ids[idx] != varr[:, 0].astype(np.int64))
    if badv.size:
        raise FormatError(path, row_line(vblock, v0 + 1, int(badv[0]), "#"), "id",
                          "velocity for an atom id not in the Atoms section")
    velocities = np.empty((natoms, dim))
    velocities[idx] = varr[:, 1:1 + dim]
    for m, c in enumerate(("omegax", "omegay", "omegaz")):
        if dim == 3 or c == "omegaz":
            w = np.empty(natoms)
            w[idx] = varr[:, 4 + m]
            fields[c] = w
    return velocities


def _check_unique(ids, path, line_of_row):
    order = np.argsort(ids, kind="stable")
    dup = np.flatnonzero(np.diff(ids[order]) == 0)
    if dup.size:
        r = int(order[dup[0] + 1])
        raise FormatError(path, line_of_row(r), "id", f"duplicate atom id {ids[r]}")


def _fmt_table(arr, fmts):
    """Rows of ``arr`` formatted with per-column printf formats, joined by newlines."""
    buf = io.StringIO()
    np.savetxt(buf, arr, fmt=fmts, delimiter=" ")
    return buf.getvalue()


def write_lammps_data(path, config, *, density=1.0, title=None, general_triclinic="auto",
                      velocities=True):
    """Write ``config`` as a LAMMPS data file (``atom_style sphere``) for ``read_data``.

    3D configurations (``config.dim == 3``) are written with their z coordinates, the box's
    ``zlo zhi`` and tilts ``xz yz``, and ``wx wy wz`` from ``fields['omegax'|'omegay'|'omegaz']``;
    use them with ``dimension 3``, ``set ... density`` and ``fix nve/sphere``. The rest of this
    docstring is about 2D files.

    Columns ``id type diameter density x y z`` with z = 0 and ``zlo zhi = -0.5 0.5``; a tilt line
    ``xy 0 0 xy xz yz`` when the cell is sheared; positions are written exactly as stored
    (``read_data`` maps periodic coordinates back into the box). Density is
    ``config.fields['density']`` if present, else ``density``. A ``Velocities`` section is written
    when ``config.velocities`` is set (and ``velocities=True``), with ``wz = fields['omegaz']``.
    Image flags ``fields['ix']``/``['iy']`` are written when present.

    A cell not in LAMMPS's restricted form (a along +x) is written with the general-triclinic header
    (``avec``/``bvec``/``cvec``/``abc origin``, LAMMPS >= 17Apr2024) if
    ``general_triclinic="auto"``; ``"never"`` raises instead (use ``config.to_restricted()``).
    Without a cell the box is ``meta['box']`` or the disks' extent; use ``boundary f f p``.
    In the LAMMPS input: ``dimension 2``, ``atom_style sphere``, ``boundary p p p``, ``read_data``,
    then ``set group all density/disc ...`` and ``fix nve/sphere disc`` for true disks.
    """
    h, origin, periodic = _box_of(config)
    n, dim = config.n_particles, config.dim
    h, origin = _as3(h, origin)
    out = [(title or f"LAMMPS data file ({dim}d, atom_style sphere) written by dem.io") + "\n",
           "\n", f"{n} atoms\n", f"{int(config.types.max()) if n else 1} atom types\n", "\n"]
    if _restricted(h):
        out += [f"{_f(origin[0])} {_f(origin[0] + h[0, 0])} xlo xhi\n",
                f"{_f(origin[1])} {_f(origin[1] + h[1, 1])} ylo yhi\n",
                (f"{_f(origin[2])} {_f(origin[2] + h[2, 2])} zlo zhi\n" if dim == 3
                 else "-0.5 0.5 zlo zhi\n")]
        if h[0, 1] != 0.0 or h[0, 2] != 0.0 or h[1, 2] != 0.0:
            if (abs(h[0, 1]) > 0.5 * h[0, 0] or abs(h[0, 2]) > 0.5 * h[0, 0]
                    or abs(h[1, 2]) > 0.5 * h[1, 1]):
                warnings.warn("a tilt exceeds half the box length: LAMMPS versions before "
                              "2022 need 'box tilt large'", stacklevel=2)
            out.append(f"{_f(h[0, 1])} {_f(h[0, 2])} {_f(h[1, 2])} xy xz yz\n")
    else:
        if general_triclinic != "auto":
            raise ValueError("cell is not in LAMMPS's restricted triclinic form (a along +x): "
                             "write config.to_restricted() or allow general_triclinic='auto'")
        if np.linalg.det(h) <= 0:
            raise ValueError("cell is left-handed (det h < 0): LAMMPS needs a right-handed box")
        out += [f"{_f(h[0, 0])} {_f(h[1, 0])} {_f(h[2, 0])} avec\n",
                f"{_f(h[0, 1])} {_f(h[1, 1])} {_f(h[2, 1])} bvec\n",
                f"{_f(h[0, 2])} {_f(h[1, 2])} {_f(h[2, 2])} cvec\n",
                f"{_f(origin[0])} {_f(origin[1])} {_f(origin[2])} abc origin\n"]
    out += ["\n", "Atoms # sphere\n", "\n"]
    dens = config.fields.get("density", np.full(n, float(density)))
    z = config.positions[:, 2] if dim == 3 else np.zeros(n)
    cols = [config.ids, config.types, 2.0 * config.radii, dens, config.positions[:, 0],
            config.positions[:, 1], z]
    fmts = ["%d", "%d", "%.17g", "%.17g", "%.17g", "%.17g", "%.17g"]
    if "ix" in config.fields and "iy" in config.fields:
        cols += [config.fields["ix"], config.fields["iy"], config.fields.get("iz", np.zeros(n))]
        fmts += ["%d", "%d", "%d"]
    with open(path, "w") as f:
        f.writelines(out)
        f.write(_fmt_table(np.column_stack(cols), fmts))
        if velocities and config.velocities is not None:
            f.write("\nVelocities\n\n")
            z = np.zeros(n)
            w = [config.fields.get(c, z) for c in ("omegax", "omegay", "omegaz")]
            v = config.velocities if dim == 3 else np.column_stack([config.velocities, z])
            f.write(_fmt_table(np.column_stack([config.ids, v, *w]), ["%d"] + ["%.17g"] * 6))
    if not periodic:
        warnings.warn("configuration has no periodic cell: use 'boundary f f p' in LAMMPS",
                      stacklevel=2)


# ---- dumps ------------------------------------------------------------------------------------

_POSITION_SETS = (("x", "y", "z", False, False), ("xu", "yu", "zu", False, True),
                  ("xs", "ys", "zs", True, False), ("xsu", "ysu", "zsu", True, True))
_Z_COLS = {"z", "zu", "zs", "zsu"}


def _frame_offsets(data: bytes):
    offs = []
    pos = data.find(b"ITEM: TIMESTEP")
    while pos >= 0:
        offs.append(pos)
        pos = data.find(b"ITEM: TIMESTEP", pos + 14)
    return offs


def _parse_dump_frame(data, start, end, path, radius, frame_index, dimension=None):
    """One frame, ``data[start:end]``, of a text dump as a :class:`~dem.io.Configuration` (the
    reading of :func:`read_lammps_dump`; ``frame_index`` is 0-based)."""
    meta = {"frame": frame_index}
    natoms, box, columns, pos, lineno = _dump_header(data, start, end, path, meta)
    if natoms is None:
        raise FormatError(path, lineno, "NUMBER OF ATOMS", "missing before 'ITEM: ATOMS'")
    if natoms < 0:
        raise FormatError(path, lineno, "NUMBER OF ATOMS", f"negative atom count {natoms}")
    require_particles(natoms, path)
    if box is None:
        raise FormatError(path, lineno, "BOX BOUNDS", "missing before 'ITEM: ATOMS'")
    cell, origin, pbc = _dump_box(box, path, meta)
    if len(set(columns)) != len(columns):
        raise FormatError(path, lineno - 1, "ATOMS", "duplicate column names")
    block = data[pos:end]
    first = lineno
    arr = parse_table(block, tuple(columns), path, first, nrows=natoms)
    col = {c: k for k, c in enumerate(columns)}
    rad = _dump_radii(arr, col, natoms, radius, path, block, first)
    xy, cell, origin, (xn, yn, zn), unwrapped = _dump_positions(arr, col, cell, origin, pbc,
                                                                dimension, path, first, meta)
    dim = xy.shape[1]
    names = (xn, yn, zn)[:dim]
    fields = _dump_fields(arr, col, (xn, yn, zn), dim)

    def line_of_row(r):
        return row_line(block, first, r)

    ids = arr[:, col["id"]].astype(np.int64) if "id" in col else None
    if ids is not None:
        _check_unique(ids, path, line_of_row)
    nonper = [d for d in range(dim) if not pbc[d]]
    if nonper and not unwrapped:
        _check_inside(xy, cell, origin, nonper, path, line_of_row, names=names)
    periodic = all(pbc[:dim])
    if not periodic:
        meta["box"] = cell.tolist()
        if any(pbc[:dim]):
            warnings.warn(f"{path}: box periodic in one direction only ({meta['boundary']}); the "
                          "configuration is returned without a periodic cell", stacklevel=3)
    vn, fn = ("vx", "vy", "vz")[:dim], ("fx", "fy", "fz")[:dim]
    vel = arr[:, [col[c] for c in vn]] if all(c in col for c in vn) else None
    frc = arr[:, [col[c] for c in fn]] if all(c in col for c in fn) else None
    return build(path, positions=xy, radii=rad, cell=cell if periodic else None, origin=origin,
                         ids=ids, types=arr[:, col["type"]].astype(np.int64) if "type" in col
                         else None, velocities=vel, forces=frc, fields=fields, meta=meta,
                         source=path, source_format="lammps-dump")


def _dump_header(data, start, end, path, meta):
    """The ``ITEM:`` lines of a frame up to ``ITEM: ATOMS``.

    Fills ``meta`` (``timestep``, ``time``, ``units``, unknown items under ``items``) and returns
    ``(natoms, box, columns, pos, lineno)``: the ``NUMBER OF ATOMS`` (None if absent), the
    ``BOX BOUNDS`` words and its three rows as ``(tokens, line number)`` (None if absent), the
    ``ATOMS`` column names, and the byte offset and 1-based line number of the first atom line."""
    lineno = data.count(b"\n", 0, start) + 1
    pos = start
    natoms = None
    box = None
    columns = None

    def next_line():
        nonlocal pos, lineno
        nl = data.find(b"\n", pos, end)
        nl = end if nl < 0 else nl
        text = data[pos:nl].decode("utf-8", "replace").strip()
        cur = lineno
        pos, lineno = nl + 1, lineno + 1
        if cur > 0 and pos > end + 1:
            raise FormatError(path, cur, None, "truncated header")
        return text, cur

    while columns is None:
        if pos >= end:
            raise FormatError(path, lineno, None, "truncated: frame has no 'ITEM: ATOMS' line")
        text, ln = next_line()
        if not text:
            continue
        if not text.startswith("ITEM:"):
            raise FormatError(path, ln, None, f"expected an 'ITEM:' line, found {show(text, 60)}")
        item = text[5:].strip()
        if item == "TIMESTEP":
            t, l2 = next_line()
            meta["timestep"] = parse_number(t.split()[0] if t else "", path, l2, "TIMESTEP", int)
        elif item == "TIME":
            t, l2 = next_line()
            meta["time"] = parse_number(t, path, l2, "TIME")
        elif item == "UNITS":
            meta["units"] = next_line()[0]
        elif item == "NUMBER OF ATOMS":
            t, l2 = next_line()
            natoms = parse_number(t, path, l2, "NUMBER OF ATOMS", int)
        elif item.startswith("BOX BOUNDS"):
            words = item.split()[2:]
            rows = []
            for _ in range(3):
                t, l2 = next_line()
                rows.append((t.split(), l2))
            box = (words, rows)
        elif item.startswith("ATOMS"):
            columns = item.split()[1:]
        else:
            meta.setdefault("items", {})[item] = next_line()[0]
    return natoms, box, columns, pos, lineno


def _dump_radii(arr, col, natoms, radius, path, block, first):
    """(N,) radii from the ``radius`` column, else half the ``diameter`` column, else the constant
    ``radius`` given by the caller."""
    if "radius" in col:
        rad = arr[:, col["radius"]].copy()
        check_positive(rad, "radius", path, block, first)
    elif "diameter" in col:
        rad = 0.5 * arr[:, col["diameter"]]
        check_positive(rad, "diameter", path, block, first)
    elif radius is not None:
        rad = np.full(natoms, float(radius))
    else:
        raise FormatError(path, first - 1, "ATOMS",
                          "no 'radius' or 'diameter' column (give a constant radius: radius= in "
                          "Python, --radius on the command line)")
    return rad


def _dump_positions(arr, col, cell, origin, pbc, dimension, path, first, meta):
    """Positions from the first column set found of ``x y [z]``, ``xu yu [zu]``, ``xs ys [zs]``,
    ``xsu ysu [zsu]`` (scaled ones mapped through the box), and the dimension (``meta``).

    Returns ``(positions (N, d), cell (d, d), origin (d,), (xn, yn, zn), unwrapped)``: the box cut
    to the dimension, the names of the columns used and whether they are unwrapped."""
    for xn, yn, zn, scaled, unwrapped in _POSITION_SETS:
        if xn in col and yn in col:
            xy = arr[:, [col[xn], col[yn]]]
            break
    else:
        raise FormatError(path, first - 1, "ATOMS", "no x y (or xu yu, xs ys, xsu ysu) columns")
    zc = arr[:, col[zn]] if zn in col else None
    dim = _dimension(dimension, zc, pbc[2], path)
    meta["dimension"] = dim
    if dim == 3:
        xy = np.column_stack([xy, zc])
        if scaled:
            xy = origin + xy @ cell.T
    else:
        if scaled:      # x, y of a 2D box: the z column (s_z) of h does not enter
            xy = origin[:2] + xy @ cell[:2, :2].T
        cell, origin = cell[:2, :2].copy(), origin[:2].copy()
    meta["coordinates"] = xn[:-1] if len(xn) > 1 else "x"
    return xy, cell, origin, (xn, yn, zn), unwrapped


def _dump_fields(arr, col, position_cols, dim):
    """The columns that are not id, type, radius, position, velocity or force, by name (image
    flags ``ix iy iz`` as integers; in 2D the z columns are dropped)."""
    xn, yn, zn = position_cols
    used = {"id", "type", "radius", "diameter", xn, yn, "vx", "vy", "fx", "fy"}
    if dim == 3:
        used |= {zn, "vz", "fz"}
    fields = {c: arr[:, k].copy() for c, k in col.items()
              if c not in used and (dim == 3 or c not in _Z_COLS)}
    for c in ("ix", "iy", "iz"):
        if c in fields:
            fields[c] = fields[c].astype(np.int64)
    return fields


def _dump_box(box, path, meta):
    words, rows = box
    vals = []
    general = words[:2] == ["abc", "origin"]
    tilted = words[:3] == ["xy", "xz", "yz"]
    flags = words[2:] if general else words[3:] if tilted else words
    want = 4 if general else 3 if tilted else 2
    names = (["a", "b", "c"] if general else ["x", "y", "z"])
    for (toks, ln), nm in zip(rows, names):
        if len(toks) != want:
            raise FormatError(path, ln, "BOX BOUNDS",
                              f"expected {want} numbers on the {nm} bounds line, found {len(toks)}")
        vals.append([parse_number(t, path, ln, f"BOX BOUNDS {nm}") for t in toks])
    if not flags:
        flags = ["pp", "pp", "pp"]
        meta["boundary_assumed"] = True
    if len(flags) != 3:
        raise FormatError(path, rows[0][1] - 1, "BOX BOUNDS", f"expected 3 boundary flags: {flags}")
    meta["boundary"] = " ".join(flags)
    pbc = [f == "pp" for f in flags]
    if general:
        cell = np.array([v[:3] for v in vals]).T
        origin = np.array([v[3] for v in vals])
        meta["triclinic"] = "general"
    else:
        xy, xz, yz = (vals[0][2], vals[1][2], vals[2][2]) if tilted else (0.0, 0.0, 0.0)
        xlo, xhi, ylo, yhi = box_from_dump_bounds(vals[0][0], vals[0][1], vals[1][0], vals[1][1],
                                                  xy, xz, yz)
        zlo, zhi = vals[2][0], vals[2][1]
        if not (xhi > xlo and yhi > ylo):
            raise FormatError(path, rows[0][1], "BOX BOUNDS", "box bounds must have lo < hi")
        if not zhi > zlo:
            raise FormatError(path, rows[2][1], "BOX BOUNDS", "z bounds must have lo < hi")
        cell = np.array([[xhi - xlo, xy, xz], [0.0, yhi - ylo, yz], [0.0, 0.0, zhi - zlo]])
        origin = np.array([xlo, ylo, zlo])
        meta["tilt"] = [xy, xz, yz]
    if not abs(np.linalg.det(cell[:2, :2])) > 0:
        raise FormatError(path, rows[0][1], "BOX BOUNDS", "degenerate box")
    return cell, origin, pbc


def read_lammps_dump(path, frame=None, *, radius=None, dimension=None) -> Configuration:
    """Read one frame of a LAMMPS text dump (``dump custom``/``atom``; ``.gz`` allowed).

    Needs ``ITEM: ATOMS`` columns for positions (``x y``, else ``xu yu``, ``xs ys`` or
    ``xsu ysu``; scaled ones are mapped through the box) and ``radius`` or ``diameter`` (or pass a
    constant ``radius=`` for dumps without one). ``id``, ``type``, ``vx vy``, ``fx fy`` are
    recognised; every other column except the z ones goes to ``fields``. Particles are returned in
    file order (use ``.sorted_by_id()`` to sort).

    Box: ``ITEM: BOX BOUNDS pp pp pp`` (orthogonal, ``lo hi`` lines), ``xy xz yz pp pp pp``
    (restricted triclinic: the lines hold the *bounding* box and the tilt, converted back with
    :func:`box_from_dump_bounds`) or ``abc origin pp pp pp`` (general triclinic). ``cell`` is set
    when x and y are both periodic (``pp``); otherwise ``cell=None``, ``meta['box']`` holds the
    box and particles outside its non-periodic directions raise :class:`~dem.io.FormatError`.
    ``frame`` indexes the frames (negative from the end); see :func:`iter_lammps_dump`. Not given,
    the first frame is read, with a warning naming the frame count when the file has several (a
    trajectory's first frame is usually its initial gas). ``meta['frame']`` (0-based) and
    ``meta['n_frames']`` say which frame was read.

    3D: ``dimension=3``, or ``None`` and a z boundary ``pp`` with z coordinates that are not all
    equal (module docstring): positions (N, 3) from ``x y z`` (``xu yu zu``, ``xs ys zs``,
    ``xsu ysu zsu``), cell (3, 3) with the tilts ``xz yz`` and the z bounds, ``vx vy vz``,
    ``fx fy fz``; periodic when all three directions are ``pp``.
    """
    path = os.fspath(path)
    data = open_bytes(path)
    offs = _frame_offsets(data)
    if not offs:
        raise FormatError(path, 1, "TIMESTEP", "not a LAMMPS dump: no 'ITEM: TIMESTEP' line")
    unsaid = frame is None
    frame = 0 if unsaid else frame
    try:
        start = offs[frame]
    except IndexError:
        n = len(offs)
        err = IndexError(f"{path}: frame={frame} does not exist: the file holds {n} frame"
                         f"{'s' if n != 1 else ''}, frame in [0, {n - 1}] (0-based) or "
                         f"[-{n}, -1] (from the end)")
        err.path, err.frame, err.n_frames = path, frame, n   # for the command line's numbering
        raise err from None
    k = offs.index(start)
    end = offs[k + 1] if k + 1 < len(offs) else len(data)
    cfg = _parse_dump_frame(data, start, end, path, radius, k, dimension)
    cfg.meta["n_frames"] = len(offs)
    if unsaid and len(offs) > 1:
        warnings.warn(f"{path} holds {len(offs)} frames: read the first (timestep "
                      f"{cfg.meta.get('timestep', '?')}); say frame=-1 for the last (--frame -1 "
                      "on the command line)", stacklevel=2)
    return cfg


def iter_lammps_dump(path, *, radius=None, dimension=None):
    """Yield every frame of a LAMMPS text dump as a :class:`~dem.io.Configuration` (``radius``,
    ``dimension``: as :func:`read_lammps_dump`)."""
    path = os.fspath(path)
    data = open_bytes(path)
    offs = _frame_offsets(data)
    for k, start in enumerate(offs):
        end = offs[k + 1] if k + 1 < len(offs) else len(data)
        yield _parse_dump_frame(data, start, end, path, radius, k, dimension)


def write_lammps_dump(path, config, *, timestep=None, fields=True, append=False,
                      general_triclinic="auto"):
    """Write ``config`` as one frame of a LAMMPS text dump (opens in OVITO).

    Columns ``id type radius x y z`` (z = 0 in 2D), then ``vx vy vz`` and ``fx fy fz`` when set,
    then every per-particle ``config.fields`` entry (``fields=True``), or the names listed in
    ``fields``. Box: ``BOX BOUNDS pp pp pp`` or, for a sheared cell, ``xy xz yz pp pp pp`` with the
    bounding box + tilts; a cell not in the restricted form is written as ``abc origin pp pp pp``
    (LAMMPS general triclinic) unless ``general_triclinic="never"``. Non-periodic: ``ff ff pp``
    (3D: ``ff ff ff``) with ``meta['box']`` or the particles' extent. ``append=True`` adds a frame
    to an existing file.
    """
    h, origin, periodic = _box_of(config)
    n, dim = config.n_particles, config.dim
    h, origin = _as3(h, origin)
    if timestep is None:
        timestep = int(config.meta.get("timestep", 0))
    flags = "pp pp pp" if periodic else ("ff ff pp" if dim == 2 else "ff ff ff")
    head = [f"ITEM: TIMESTEP\n{timestep}\n", f"ITEM: NUMBER OF ATOMS\n{n}\n"]
    zlo, zhi = (origin[2], origin[2] + h[2, 2]) if dim == 3 else (-0.5, 0.5)
    if _restricted(h):
        xlo, ylo = origin[:2]
        xhi, yhi = xlo + h[0, 0], ylo + h[1, 1]
        xy, xz, yz = h[0, 1], h[0, 2], h[1, 2]
        if xy != 0.0 or xz != 0.0 or yz != 0.0:
            b = dump_bounds(xlo, xhi, ylo, yhi, xy, xz, yz)
            head.append(f"ITEM: BOX BOUNDS xy xz yz {flags}\n{_f(b[0])} {_f(b[1])} {_f(xy)}\n"
                        f"{_f(b[2])} {_f(b[3])} {_f(xz)}\n{_f(zlo)} {_f(zhi)} {_f(yz)}\n")
        else:
            head.append(f"ITEM: BOX BOUNDS {flags}\n{_f(xlo)} {_f(xhi)}\n"
                        f"{_f(ylo)} {_f(yhi)}\n{_f(zlo)} {_f(zhi)}\n")
    else:
        if general_triclinic != "auto":
            raise ValueError("cell is not in LAMMPS's restricted triclinic form: write "
                             "config.to_restricted() or allow general_triclinic='auto'")
        head.append(f"ITEM: BOX BOUNDS abc origin {flags}\n" + "".join(
            f"{_f(h[0, k])} {_f(h[1, k])} {_f(h[2, k])} {_f(origin[k])}\n" for k in range(3)))
    names = ["id", "type", "radius", "x", "y", "z"]
    z = np.zeros(n)

    def xyz(v):
        return [v[:, 0], v[:, 1], v[:, 2] if dim == 3 else z]

    cols = [config.ids, config.types, config.radii, *xyz(config.positions)]
    fmts = ["%d", "%d"] + ["%.17g"] * 4
    if config.velocities is not None:
        names += ["vx", "vy", "vz"]
        cols += xyz(config.velocities)
        fmts += ["%.17g"] * 3
    if config.forces is not None:
        names += ["fx", "fy", "fz"]
        cols += xyz(config.forces)
        fmts += ["%.17g"] * 3
    extra = list(config.fields) if fields is True else list(fields or [])
    for name in extra:
        if name in names:
            continue
        v = np.asarray(config.fields[name])
        if v.dtype.kind not in "iufb":
            raise ValueError(f"field {name!r} is not numeric: dumps hold numbers only")
        names.append(name)
        cols.append(v)
        fmts.append("%d" if v.dtype.kind in "iub" else "%.17g")
    head.append("ITEM: ATOMS " + " ".join(names) + "\n")
    with open(path, "a" if append else "w") as f:
        f.writelines(head)
        f.write(_fmt_table(np.column_stack(cols), fmts))
