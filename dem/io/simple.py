"""Plain npz and CSV configuration files (this project's own schema, versioned).

npz schema (``format_version`` 1), one array per key:

==========================  ==========  =========================================================
key                         shape       meaning
==========================  ==========  =========================================================
``format``                  ()          the string ``"microhom-configuration"``
``format_version``          ()          int, 1
``positions``               (N, 2)      float64 centres
``radii``                   (N,)        float64 radii
``cell``                    (2, 2)      float64 shape matrix, columns = cell vectors (absent: open)
``origin``                  (2,)        float64 lower-left corner of the cell
``ids``, ``types``          (N,)        int64
``velocities``              (N, 2)      optional
``forces``                  (N, 2)      optional
``field:<name>``            (N,)        optional further per-particle fields
``meta_json``               ()          JSON text of ``Configuration.meta`` (JSON-able entries only)
``network:pairs``           (C, 2)      optional contact network: int64 particle indices i < j
``network:branch``          (C, 2)      float64 branch vectors x_j - x_i (periodic image resolved)
``network:kn``, ``:kt``     (C,)        float64 contact stiffnesses [N/m]
``network:sliding``         (C,)        bool, contacts at the Coulomb limit
``network:fn``, ``:ft``     (C,)        optional normal (compression positive) and tangential forces
``network:rows``            (N,)        int64, the row of each network particle in ``positions``
==========================  ==========  =========================================================

The ``network:`` keys are written together (:func:`write_npz` with ``network=``) and read by
:func:`read_npz_network`: a file that carries them hands its contacts, stiffnesses and forces to
the analysis without the simulator that made it.

Other keys are ignored by :func:`read_npz`: a packing file of :mod:`dem.engine.packing` keeps its
bit-exact state there (``write_npz(..., extra=...)``), and its ``meta_json`` holds the packing
report and the protocol that made it (``meta["protocol"]``, a
``dem.engine.packing.PackingProtocol.as_dict()``). :func:`write_npz` is the one writer of this schema.

CSV schema (``format_version`` 1): optional ``#`` header lines ``key: value`` (``format_version``,
``cell_a: ax ay``, ``cell_b: bx by`` — both absent for an open packing —, ``origin: ox oy``,
``meta: {json}``), then a comma-separated table with a header row ``id,type,x,y,radius`` followed
by optional ``vx,vy``, ``fx,fy`` and further field columns. Floats are written with 17 significant
digits, so a round trip is exact. A plain table from another code (a header row with at least
``x,y,radius``, no ``#`` lines) is read as version 1 of an open packing.
"""
from __future__ import annotations

import io
import json
import os
import zipfile
import zlib

import numpy as np

from ._core import (Configuration, FormatError, build, check_regular_file, open_bytes,
                    require_particles, show)


def _f(x):
    """Shortest text that reads back as the same float64."""
    return repr(float(x))


__all__ = ["read_npz", "write_npz", "read_npz_network", "read_csv", "write_csv", "FORMAT_VERSION"]

FORMAT_VERSION = 1
_MAGIC = "microhom-configuration"
_SCHEMA_KEYS = frozenset({"format", "format_version", "positions", "radii", "cell", "origin", "ids",
                          "types", "velocities", "forces", "meta_json"})


def _jsonable_meta(meta):
    out = {}
    for k, v in meta.items():
        if isinstance(v, np.ndarray):
            v = v.tolist()
        elif isinstance(v, np.generic):
            v = v.item()
        try:
            json.dumps(v)
        except (TypeError, ValueError):
            continue
        out[str(k)] = v
    return out


_NETWORK_KEYS = ("pairs", "branch", "kn", "kt", "sliding", "fn", "ft")


def _network_arrays(network, n_particles, rows=None):
    """The ``network:`` arrays of a :class:`microhom.network.ContactNetwork` (2D); ``rows`` (N,):
    the configuration row of each of the network's particles (default: the same order)."""
    if network.n_particles != n_particles:
        raise ValueError(f"network has {network.n_particles} particles but the configuration "
                         f"{n_particles}: write the network of this configuration")
    rows = np.arange(n_particles) if rows is None else np.asarray(rows, dtype=np.int64)
    if rows.shape != (n_particles,) or not np.array_equal(np.sort(rows), np.arange(n_particles)):
        raise ValueError(f"network_rows must be a permutation of the {n_particles} configuration rows")
    out = {f"network:{k}": getattr(network, k) for k in _NETWORK_KEYS
           if getattr(network, k) is not None}
    out["network:rows"] = rows
    return out


def write_npz(path, config, *, compressed=False, extra=None, network=None, network_rows=None):
    """Write ``config`` as an npz file (schema in the module docstring): the one writer of the
    schema.

    ``path``: a path, or a binary file object (e.g. the temporary file of
    :func:`dem.runtime.atomic_write`). ``extra``: further arrays {key: array} stored beside the
    schema's keys (a ``dem.engine.packing`` file stores its bit-exact state there); a key that is one of
    the schema's, or starts with ``field:`` or ``network:``, raises ``ValueError``;
    :func:`read_npz` ignores them. ``network``: the configuration's
    :class:`~microhom.network.ContactNetwork` (same particles, same order), stored under the
    ``network:`` keys for :func:`read_npz_network`; ``network_rows`` (N,): the configuration row
    of each network particle when the network numbers them in another order.
    """
    arrays = {"format": np.array(_MAGIC), "format_version": np.array(FORMAT_VERSION),
              "positions": config.positions, "radii": config.radii, "origin": config.origin,
              "ids": config.ids, "types": config.types,
              "meta_json": np.array(json.dumps(_jsonable_meta(config.meta)))}
    if config.cell is not None:
        arrays["cell"] = config.cell
    if config.velocities is not None:
        arrays["velocities"] = config.velocities
    if config.forces is not None:
        arrays["forces"] = config.forces
    for name, v in config.fields.items():
        arrays[f"field:{name}"] = v
    clash = sorted(k for k in (extra or {})
                   if k in _SCHEMA_KEYS or k.startswith("field:") or k.startswith("network:"))
    if clash:
        raise ValueError(f"extra arrays {clash} clash with the npz schema's keys {sorted(_SCHEMA_KEYS)}")
    if network is not None:
        arrays.update(_network_arrays(network, len(config.radii), network_rows))
    arrays = {**(extra or {}), **arrays}
    save = np.savez_compressed if compressed else np.savez
    if hasattr(path, "write"):
        save(path, **arrays)
        return
    with open(path, "wb") as f:  # a file object: numpy would otherwise append ".npz"
        save(f, **arrays)


def read_npz(path) -> Configuration:
    """Read an npz configuration written by :func:`write_npz` (checks format and version)."""
    path = os.fspath(path)
    check_regular_file(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
            if "format" not in keys or z["format"].shape != () or str(z["format"]) != _MAGIC:
                raise FormatError(path, None, "format", f"not a {_MAGIC} npz file (written by "
                                  "dem.io.write_npz)")
            version = z["format_version"] if "format_version" in keys else None
            if version is None or version.shape != () or version.dtype.kind not in "iu" \
                    or not 1 <= int(version) <= FORMAT_VERSION:
                raise FormatError(path, None, "format_version",
                                  f"unsupported version (this reader: {FORMAT_VERSION})")
            for key in ("positions", "radii"):
                if key not in keys:
                    raise FormatError(path, None, key, "missing")
            get = {k: z[k] for k in keys}
    except FormatError:
        raise
    except (ValueError, OSError, EOFError, KeyError, zipfile.BadZipFile, zlib.error):
        # not a zip of .npy arrays, a truncated or corrupt member, or a pickled object array
        raise FormatError(path, None, None, "not a readable npz file (truncated, corrupt, or "
                          "not a zip archive of numpy arrays)") from None
    for key, v in get.items():
        if v.dtype.kind not in "iufbU" and key != "meta_json":
            raise FormatError(path, None, key, f"array of unsupported type {v.dtype.str}")
    kw = {}
    for key in ("cell", "origin", "ids", "types", "velocities", "forces"):
        if key in get:
            kw[key] = get[key]
    fields = {k.split(":", 1)[1]: v for k, v in get.items() if k.startswith("field:")}
    try:
        meta = json.loads(str(get["meta_json"])) if "meta_json" in get else {}
    except ValueError:
        raise FormatError(path, None, "meta_json", "invalid JSON") from None
    if not isinstance(meta, dict):
        raise FormatError(path, None, "meta_json", "not a JSON object")
    pos, rad = get["positions"], get["radii"]
    if pos.ndim != 2 or pos.shape[1:] != (2,):
        raise FormatError(path, None, "positions", f"shape {pos.shape}, expected (N, 2)")
    require_particles(pos.shape[0], path)
    if rad.ndim == 1 and rad.dtype.kind in "iuf":
        bad = np.flatnonzero(~(rad > 0))
        if bad.size:
            raise FormatError(path, None, "radii", f"radius of particle {int(bad[0])} is "
                              f"{float(rad[bad[0]])!r} (must be > 0)")
    return build(path, positions=pos, radii=rad, fields=fields, meta=meta, source=path,
                 source_format="npz", **kw)


def write_csv(path, config):
    """Write ``config`` as CSV (schema in the module docstring)."""
    lines = ["# microhom configuration (dem.io CSV)", f"# format_version: {FORMAT_VERSION}"]
    if config.cell is not None:
        h = config.cell
        lines += [f"# cell_a: {_f(h[0, 0])} {_f(h[1, 0])}",
                  f"# cell_b: {_f(h[0, 1])} {_f(h[1, 1])}"]
    lines += [f"# origin: {_f(config.origin[0])} {_f(config.origin[1])}",
              f"# meta: {json.dumps(_jsonable_meta(config.meta))}"]
    names = ["id", "type", "x", "y", "radius"]
    cols = [config.ids, config.types, config.positions[:, 0], config.positions[:, 1],
            config.radii]
    fmts = ["%d", "%d", "%.17g", "%.17g", "%.17g"]
    for label, v in (("v", config.velocities), ("f", config.forces)):
        if v is not None:
            names += [label + "x", label + "y"]
            cols += [v[:, 0], v[:, 1]]
            fmts += ["%.17g", "%.17g"]
    for name, v in config.fields.items():
        if name in names or "," in name:
            raise ValueError(f"field name {name!r} clashes with a column or contains a comma")
        v = np.asarray(v)
        if v.dtype.kind not in "iufb":
            raise ValueError(f"field {name!r} is not numeric")
        names.append(name)
        cols.append(v)
        fmts.append("%d" if v.dtype.kind in "iub" else "%.17g")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n" + ",".join(names) + "\n")
        np.savetxt(f, np.column_stack(cols), fmt=fmts, delimiter=",")


def _csv_floats(path, lineno, name, text, n):
    toks = text.split()
    if len(toks) != n:
        raise FormatError(path, lineno, name, f"expected {n} numbers, found {len(toks)}")
    try:
        vals = [float(t) for t in toks]
    except ValueError:
        raise FormatError(path, lineno, name, f"non-numeric value in {text!r}") from None
    if not all(np.isfinite(vals)):
        raise FormatError(path, lineno, name, "non-finite value")
    return vals


def read_csv(path) -> Configuration:
    """Read a CSV configuration written by :func:`write_csv`, or a plain table with a header row
    holding at least ``x,y,radius`` (checks the version, when given, and every field)."""
    import pandas as pd  # heavy (~0.3 s): only when a table is parsed

    path = os.fspath(path)
    data = open_bytes(path)
    lines = data.split(b"\n")
    head = {}
    k = 0
    while k < len(lines) and lines[k].startswith(b"#"):
        text = lines[k][1:].decode("utf-8", "replace").strip()
        if ":" in text:
            key, val = text.split(":", 1)
            head[key.strip()] = (val.strip(), k + 1)
        k += 1
    v, ln = head.get("format_version", ("1", None))  # a plain table: read as version 1
    if v not in {str(i) for i in range(1, FORMAT_VERSION + 1)}:
        raise FormatError(path, ln, "format_version",
                          f"unsupported version {show(v)} (this reader: {FORMAT_VERSION})")
    cell = None
    if "cell_a" in head or "cell_b" in head:
        for key in ("cell_a", "cell_b"):
            if key not in head:
                raise FormatError(path, None, key, "missing (cell_a and cell_b go together)")
        a = _csv_floats(path, head["cell_a"][1], "cell_a", head["cell_a"][0], 2)
        b = _csv_floats(path, head["cell_b"][1], "cell_b", head["cell_b"][0], 2)
        cell = np.array([a, b]).T
    origin = (_csv_floats(path, head["origin"][1], "origin", head["origin"][0], 2)
              if "origin" in head else (0.0, 0.0))
    meta = {}
    if "meta" in head:
        try:
            meta = json.loads(head["meta"][0])
        except ValueError:
            raise FormatError(path, head["meta"][1], "meta", "invalid JSON") from None
    if k >= len(lines) or not lines[k].strip():
        raise FormatError(path, k + 1, None, "no column header row (a CSV needs at least "
                          "'x,y,radius')")
    names = [c.strip() for c in lines[k].decode("utf-8", "replace").split(",")]
    for req in ("x", "y", "radius"):
        if req not in names:
            raise FormatError(path, k + 1, req, f"column missing from the header row "
                              f"({show(','.join(names), 60)})")
    if len(set(names)) != len(names):
        raise FormatError(path, k + 1, None, "duplicate column names in the header row")
    first = k + 2
    block = b"\n".join(lines[k + 1:])
    if not block.strip():
        require_particles(0, path)
    arr = None
    try:
        df = pd.read_csv(io.BytesIO(block), header=None, names=names, dtype=np.float64,
                         engine="c")
        arr = df.to_numpy(dtype=np.float64)
        if not np.all(np.isfinite(arr)):
            arr = None
    except (ValueError, pd.errors.ParserError):
        arr = None
    if arr is None:  # locate the problem
        for j, raw in enumerate(lines[k + 1:]):
            text = raw.decode("utf-8", "replace").strip()
            if not text:
                continue
            toks = text.split(",")
            if len(toks) != len(names):
                raise FormatError(path, first + j, None,
                                  f"expected {len(names)} columns, found {len(toks)}")
            for tok, name in zip(toks, names):
                try:
                    val = float(tok)
                except ValueError:
                    raise FormatError(path, first + j, name,
                                      f"non-numeric value {show(tok)}") from None
                if not np.isfinite(val):
                    raise FormatError(path, first + j, name, f"non-finite value {show(tok)}")
        raise FormatError(path, first, None, "unparseable table")
    col = {c: i for i, c in enumerate(names)}
    rad = arr[:, col["radius"]]
    bad = np.flatnonzero(~(rad > 0))
    if bad.size:
        raise FormatError(path, first + int(bad[0]), "radius",
                          f"value {float(rad[bad[0]])!r} (must be > 0)")
    used = {"id", "type", "x", "y", "radius", "vx", "vy", "fx", "fy"}
    fields = {c: arr[:, i] for c, i in col.items() if c not in used}
    for c in ("ix", "iy", "iz"):
        if c in fields:
            fields[c] = fields[c].astype(np.int64)
    return build(
        path, positions=arr[:, [col["x"], col["y"]]], radii=rad, cell=cell, origin=origin,
        ids=arr[:, col["id"]].astype(np.int64) if "id" in col else None,
        types=arr[:, col["type"]].astype(np.int64) if "type" in col else None,
        velocities=arr[:, [col["vx"], col["vy"]]] if "vx" in col and "vy" in col else None,
        forces=arr[:, [col["fx"], col["fy"]]] if "fx" in col and "fy" in col else None,
        fields=fields, meta=meta, source=path, source_format="csv")


def read_npz_network(path):
    """The contact network stored in an npz file by ``write_npz(..., network=)``, or None when the
    file carries none. Its particles are the file's ``positions`` and ``radii`` in the network's own
    order (``network:rows``), with the file's cell and origin; the contacts, branch vectors,
    stiffnesses [N/m], sliding flags and forces are the stored ones.
    """
    from microhom.network import ContactNetwork
    read_npz(path)                       # the schema's own checks (format, version, arrays)
    path = os.fspath(path)
    with np.load(path, allow_pickle=False) as z:
        if "network:pairs" not in z.files:
            return None
        got = {k: z[f"network:{k}"] for k in _NETWORK_KEYS if f"network:{k}" in z.files}
        geometry = {k: z[k] for k in ("positions", "radii", "cell", "origin") if k in z.files}
        rows = z["network:rows"] if "network:rows" in z.files else None
    if rows is not None:
        if rows.shape != geometry["radii"].shape or not np.array_equal(np.sort(rows), np.arange(len(rows))):
            raise FormatError(path, None, "network:rows", "not a permutation of the particle rows")
        geometry["positions"], geometry["radii"] = geometry["positions"][rows], geometry["radii"][rows]
    missing = [k for k in ("branch", "kn", "kt", "sliding") if k not in got]
    if missing:
        raise FormatError(path, None, f"network:{missing[0]}", "missing (the network: keys are "
                          "written together)")
    try:
        return ContactNetwork(**geometry, **({} if "cell" in geometry else {"cell": None}), **got)
    except ValueError as exc:
        raise FormatError(path, None, "network:pairs", f"inconsistent stored network ({exc})") from None
