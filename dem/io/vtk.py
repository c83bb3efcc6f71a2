"""VTK output for ParaView through ``meshio`` (optional dependency: ``pip install meshio``).

One unstructured grid (``.vtu``, or legacy ``.vtk``):

* points: the disk centres (z = 0), then one extra point per half of each contact that crosses the
  periodic boundary (see below);
* point data: ``radius`` (0 on the extra points, so a Glyph filter scaled by radius hides them),
  ``id``, ``type``, ``particle`` (1 for disks, 0 for contact half-points, 2 for the four corners
  of the periodic cell), ``velocity``/``force`` (3-vectors) when set, and every numeric
  ``fields`` entry;
* cells: a ``vertex`` per disk; ``line`` cells for each contact of a
  :class:`~microhom.network.ContactNetwork`, when given, from centre i to centre j — a contact
  whose branch vector goes to a periodic image is drawn as two half-lines, ``x_i -> x_i + c/2``
  and ``x_j -> x_j - c/2``, so no line spans the cell — and for the outline of the periodic cell
  (corners ``o, o+a, o+a+b, o+b``; meshio's VTU writer drops VTK field data, so the cell is kept
  as geometry and :func:`read_vtk` recovers it from the corners);
* cell data (NaN where not applicable): ``kind`` (0 disk, 1 contact, 2 contact half-line,
  3 cell outline), ``contact`` (index into the network, -1 for the outline), ``fn``, ``ft`` when
  the network has forces, ``kn``, ``kt``, ``sliding``, ``length``, ``periodic_image`` (0/1).

ParaView: open the file, Glyph -> Sphere, Scale Array ``radius``, Scale Factor 2 (glyph radius is
0.5 by default); colour the lines by ``fn``.
"""
from __future__ import annotations

import contextlib
import io as _io
import os

import numpy as np

from ._core import Configuration, FormatError, build, check_regular_file, require_particles

__all__ = ["write_vtk", "read_vtk"]


def _meshio():
    try:
        import meshio
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("VTK output needs meshio: pip install meshio "
                          "(or the project's 'io' extra)") from e
    return meshio


def write_vtk(path, config, network=None, *, binary=True):
    """Write ``config`` (and optionally the contacts of ``network``) for ParaView (module doc)."""
    meshio = _meshio()
    n = config.n_particles
    pts = [config.positions]
    role = [np.ones(n, dtype=np.int64)]
    lines = [np.empty((0, 2), dtype=np.int64)]
    contact = [np.empty(0, dtype=np.int64)]
    kind = [np.empty(0)]
    if network is not None:
        if network.n_particles != n:
            raise ValueError("network and configuration have different particle counts")
        pairs = network.pairs
        c = network.branch
        direct = np.all(np.isclose(config.positions[pairs[:, 1]] - config.positions[pairs[:, 0]],
                                   c, rtol=1e-9, atol=1e-12 * np.abs(c).max(initial=1.0)), axis=1)
        k_dir = np.flatnonzero(direct)
        k_img = np.flatnonzero(~direct)
        m = k_img.size
        pts += [config.positions[pairs[k_img, 0]] + 0.5 * c[k_img],
                config.positions[pairs[k_img, 1]] - 0.5 * c[k_img]]
        role += [np.zeros(2 * m, dtype=np.int64)]
        lines += [pairs[k_dir], np.stack([pairs[k_img, 0], n + np.arange(m)], axis=1),
                  np.stack([pairs[k_img, 1], n + m + np.arange(m)], axis=1)]
        contact += [k_dir, k_img, k_img]
        kind += [np.ones(k_dir.size), np.full(2 * m, 2.0)]
    if config.cell is not None:  # the periodic cell's outline: corners o, o+a, o+a+b, o+b
        o, h = config.origin, config.cell
        base = sum(p.shape[0] for p in pts)
        pts.append(np.array([o, o + h[:, 0], o + h[:, 0] + h[:, 1], o + h[:, 1]]))
        role.append(np.full(4, 2, dtype=np.int64))
        lines.append(base + np.array([[0, 1], [1, 2], [2, 3], [3, 0]]))
        contact.append(np.full(4, -1))
        kind.append(np.full(4, 3.0))
    xy = np.concatenate(pts)
    npts = xy.shape[0]
    points = np.column_stack([xy, np.zeros(npts)])

    def pad(v, fill=0.0):
        v = np.asarray(v)
        out = np.full((npts,) + v.shape[1:], fill, dtype=np.result_type(v.dtype, type(fill)))
        out[:n] = v
        return out

    point_data = {"radius": pad(config.radii), "id": pad(config.ids, 0).astype(np.int64),
                  "type": pad(config.types, 0).astype(np.int64),
                  "particle": np.concatenate(role)}
    for name, v in (("velocity", config.velocities), ("force", config.forces)):
        if v is not None:
            point_data[name] = pad(np.column_stack([v, np.zeros(n)]))
    for name, v in config.fields.items():
        v = np.asarray(v)
        if v.dtype.kind in "iufb" and name not in point_data:
            point_data[name] = pad(v.astype(np.float64))
    cells = [("vertex", np.arange(n, dtype=np.int64)[:, None])]
    cell_data = {}
    lines = np.concatenate(lines).astype(np.int64)
    if lines.shape[0]:
        contact = np.concatenate(contact)
        cells.append(("line", lines))
        is_c = contact >= 0
        kc = np.where(is_c, contact, 0)

        def per_line(v):
            return np.where(is_c, np.asarray(v, dtype=np.float64)[kc], np.nan)

        vals = {"kind": np.concatenate(kind), "contact": contact.astype(np.float64)}
        if network is not None:
            vals.update({"kn": per_line(network.kn), "kt": per_line(network.kt),
                         "sliding": per_line(network.sliding), "length": per_line(network.lengths),
                         "periodic_image": (np.concatenate(kind) == 2).astype(np.float64)})
            if network.fn is not None:
                vals["fn"] = per_line(network.fn)
            if network.ft is not None:
                vals["ft"] = per_line(network.ft)
        cell_data = {name: [np.full(n, np.nan), v] for name, v in vals.items()}
        cell_data["kind"][0] = np.zeros(n)
    mesh = meshio.Mesh(points, cells, point_data=point_data, cell_data=cell_data)
    fmt = "vtk" if os.fspath(path).endswith(".vtk") else "vtu"
    mesh.write(os.fspath(path), file_format=fmt, binary=binary)


def read_vtk(path) -> Configuration:
    """Read back a file written by :func:`write_vtk` (disks only; contacts are recomputable)."""
    meshio = _meshio()
    path = os.fspath(path)
    check_regular_file(path)
    try:
        with contextlib.redirect_stdout(_io.StringIO()):  # meshio prints "Error: ..." to stdout
            mesh = meshio.read(path)
    except (Exception, SystemExit):  # meshio calls sys.exit on some malformed files
        raise FormatError(path, None, None, "not a readable VTK file (meshio could not parse "
                          "it)") from None
    pd = mesh.point_data
    for key in ("radius", "particle"):
        if key not in pd:
            raise FormatError(path, None, key, "point data missing (not written by dem.io?)")
    role = np.asarray(pd["particle"]).reshape(-1)
    keep = role == 1
    corners = mesh.points[role == 2, :2]
    cell = None
    origin = (0.0, 0.0)
    if corners.shape[0] == 4:
        origin = corners[0]
        cell = np.column_stack([corners[1] - corners[0], corners[3] - corners[0]])
    elif corners.shape[0]:
        raise FormatError(path, None, "particle", "expected 4 cell-corner points (particle = 2)")
    vel = pd["velocity"][keep, :2] if "velocity" in pd else None
    frc = pd["force"][keep, :2] if "force" in pd else None
    skip = {"radius", "particle", "id", "type", "velocity", "force"}
    fields = {k: np.asarray(v)[keep] for k, v in pd.items()
              if k not in skip and np.asarray(v).ndim == 1}
    require_particles(int(keep.sum()), path)
    return build(path, positions=mesh.points[keep, :2], radii=pd["radius"][keep], cell=cell,
                 origin=origin, ids=pd["id"][keep] if "id" in pd else None,
                 types=pd["type"][keep] if "type" in pd else None, velocities=vel,
                 forces=frc, fields=fields, source=path, source_format="vtk")
