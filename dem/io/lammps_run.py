"""Reading back a LAMMPS packing run: its final dump, its contacts' ``dump local`` and its log.

A run folder written by :func:`dem.engine.lammps.write_inputs` and run by LAMMPS holds
``in.packing`` (whose header comment records kn, kt, mu), ``final.dump``, ``contacts.dump`` and
``log.lammps``. :func:`read_run` turns it into a :class:`LammpsRun` with the contact network and
LAMMPS's own per-contact forces. This is a reader: it needs no simulator (``dem analyse`` reads run
folders through it), and it follows the reading rule of :mod:`dem.io` (regular files of a size that
fits in memory). Units are the run's; 2D per unit thickness, or 3D (a run written with
``dimension=3``: the final dump is read as 3D by :mod:`dem.io`'s rule, z periodic and varying).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from microhom.network import from_overlaps
from microhom.results import Result

from ._core import FormatError, open_bytes
from . import read as _read

__all__ = ["LammpsRun", "read_run", "read_dump_local", "INPUT_NAME"]

#: the input file a run folder holds (its header comment records the contact parameters)
INPUT_NAME = "in.packing"
_RESULT = re.compile(r"^(PACK_[A-Z_]+)\s+(.*)$")


def read_dump_local(path) -> tuple[list, np.ndarray]:
    """Last frame of a LAMMPS ``dump local`` text file: (column names, (M, ncol) array)."""
    text = open_bytes(path).decode("utf-8", "replace")   # the reading rule of dem.io
    k = text.rfind("ITEM: TIMESTEP")
    if k < 0:
        raise FormatError(path, 1, "TIMESTEP", "not a LAMMPS dump local file")
    lines = text[k:].splitlines()
    first = text[:k].count("\n") + 1
    n = cols = None
    for m, line in enumerate(lines):
        if line.startswith("ITEM: NUMBER OF ENTRIES"):
            n = int(lines[m + 1])
        elif line.startswith("ITEM: ENTRIES"):
            cols = line.split()[2:]
            rows = [r for r in lines[m + 1:] if r.strip()]
            if n is None or len(rows) != n:
                raise FormatError(path, first + m, "ENTRIES", f"expected {n} rows, found {len(rows)}")
            arr = (np.array([r.split() for r in rows], dtype=float).reshape(n, len(cols))
                   if n else np.empty((0, len(cols))))
            return cols, arr
    raise FormatError(path, first, "ENTRIES", "no 'ITEM: ENTRIES' line")


@dataclass(frozen=True, eq=False)
class LammpsRun(Result):
    """A packing prepared by LAMMPS and read back (see :func:`read_run`), in the caller's units.

    Attributes
    ----------
    config : dem.io.Configuration
        The final configuration, sorted by id (positions, radii [length]; ``fields['c_cn']`` holds
        LAMMPS's contact counts).
    network : microhom.network.ContactNetwork
        The contact network with ``kn``, ``kt`` [N/m] of the run, ``fn = kn * overlap`` and ``ft``
        from LAMMPS's tangential forces: in 2D both (C,), forces per unit thickness; in 3D ``fn``
        (C,) and ``ft`` (C, 3), the tangential force vector on the contact's second sphere [N].
    lammps : dict
        LAMMPS's own figures from the ``PACK_RESULT`` line: ``pressure``, ``pxx``, ``pyy``, ``pxy``
        (``compute pressure NULL virial``, 2D stress [N/m]; 3D: also ``pzz``, ``pxz``, ``pyz``,
        stress [Pa]), ``Z``, ``phi``, ``converged``, ...
    phases : list of dict
        The ``PACK_PHASE`` lines (steps, pressure, criteria per phase).
    contacts : dict
        Per-contact LAMMPS data aligned with the network's contacts: ``force`` (C,) (normal force
        magnitude of ``compute pair/local``), ``fs`` (C, d) (tangential force on the lower-index
        particle) and ``dist`` (C,) (centre distance).
    params : dict
        The parameters written (:func:`dem.engine.lammps.write_inputs`' return value: kn, kt, mu, ...).
    run : dict
        :func:`dem.engine.lammps.run_lammps`'s dict (``wall_s`` [s], ``np``, ``command``, ``log``, ``returncode``);
        empty when read by :func:`read_run` alone.
    folder : str
        The run's folder.
    timing : dict
        ``loops``: one dict per LAMMPS ``Loop time`` line (``loop_s`` [s], ``procs``, ``steps``,
        ``atoms``); :func:`dem.engine.lammps.pack_lammps` adds ``read_s`` and ``lammps_wall_s`` [s].
    """
    config: object
    network: object
    lammps: dict
    phases: list
    contacts: dict
    params: dict = field(default_factory=dict)
    run: dict = field(default_factory=dict)
    folder: str = ""
    timing: dict = field(default_factory=dict)


def _parse_kv(text):
    out = {}
    for tok in text.split():
        if "=" in tok:
            k, v = tok.split("=", 1)
            try:
                out[k] = float(v)
            except ValueError:
                out[k] = v
    return out


def _parse_log(path):
    result, phases, loops = {}, [], []
    for line in Path(path).read_text(errors="replace").splitlines():
        m = _RESULT.match(line)
        if m and m.group(1) == "PACK_RESULT":
            result = _parse_kv(m.group(2))
        elif m and m.group(1) == "PACK_PHASE":
            phases.append(_parse_kv(m.group(2)))
        mm = re.match(r"Loop time of (\S+) on (\d+) procs for (\d+) steps with (\d+) atoms", line)
        if mm:
            loops.append({"loop_s": float(mm.group(1)), "procs": int(mm.group(2)),
                          "steps": int(mm.group(3)), "atoms": int(mm.group(4))})
    return result, phases, loops


def read_run(folder, params=None) -> LammpsRun:
    """Read a finished run in ``folder`` (``final.dump``, ``contacts.dump``, ``log.lammps``).

    ``params``: the dict :func:`dem.engine.lammps.write_inputs` returned (kn, kt, mu); if None they are read back
    from the header comment of ``in.packing``.
    """
    folder = Path(folder)
    if params is None:
        head = (folder / INPUT_NAME).read_text().splitlines()[3]
        params = _parse_kv(head.lstrip("# "))
    kn, kt, mu = float(params["kn"]), float(params["kt"]), float(params["mu"])
    dimension = params.get("dimension")
    cfg = _read(folder / "final.dump",
                dimension=None if dimension is None else int(dimension)).sorted_by_id()
    d = cfg.dim
    net = from_overlaps(cfg.positions, cfg.radii, cfg.cell, kn=kn, kt=kt, tolerance=0.0, origin=cfg.origin)
    cols, arr = read_dump_local(folder / "contacts.dump")
    ia = np.searchsorted(cfg.ids, arr[:, 0].astype(np.int64))
    ib = np.searchsorted(cfg.ids, arr[:, 1].astype(np.int64))
    dist, force, fs = arr[:, 2], arr[:, 3], arr[:, 4:4 + d]
    touching = dist < cfg.radii[ia] + cfg.radii[ib]
    ia, ib, dist, force, fs = ia[touching], ib[touching], dist[touching], force[touching], fs[touching]
    # key each LAMMPS contact on the (lower, higher) particle index, as the network's pairs
    lo, hi = np.minimum(ia, ib), np.maximum(ia, ib)
    n = cfg.n_particles
    key_l = lo * n + hi
    key_n = net.pairs[:, 0] * n + net.pairs[:, 1]
    if len(np.unique(key_l)) != len(key_l) or len(np.unique(key_n)) != len(key_n):
        raise ValueError("two contacts between the same pair of particles (cell smaller than two "
                         "diameters?)")
    order_l = np.argsort(key_l)
    pos = np.searchsorted(key_l[order_l], key_n)
    pos = np.clip(pos, 0, max(len(key_l) - 1, 0))
    matched = (len(key_l) > 0) & (key_l[order_l][pos] == key_n) if len(key_l) else np.zeros(len(key_n), bool)
    if not np.all(matched) or len(key_l) != len(key_n):
        raise ValueError(f"contact sets differ: network {len(key_n)} contacts, LAMMPS {len(key_l)}, "
                         f"{int((~matched).sum())} of the network's not found in LAMMPS's")
    k = order_l[pos]
    # LAMMPS pair (a, b): force on a = (x_a - x_b)/d * force + fs. Network contact (i < j):
    # n = (x_j - x_i)/|.|, force on j = fn n + ft t, t = (-n_y, n_x).
    # 3D: ft = the tangential force vector on j = -fs when a = i, fs when a = j.
    first_is_i = ia[k] == net.pairs[:, 0]
    nrm = net.normals
    fs_k = fs[k]
    if d == 2:
        t = np.stack([-nrm[:, 1], nrm[:, 0]], axis=1)
        ft = np.where(first_is_i, -1.0, 1.0) * np.einsum("ci,ci->c", fs_k, t)
        ft_size = np.abs(ft)
    else:
        ft = np.where(first_is_i[:, None], -1.0, 1.0) * fs_k
        ft_size = np.linalg.norm(ft, axis=1)
    delta = cfg.radii[net.pairs[:, 0]] + cfg.radii[net.pairs[:, 1]] - net.lengths
    fn = kn * delta
    sliding = ft_size >= mu * fn * (1 - 1e-9) if kt > 0 else np.ones(len(fn), bool)
    net = replace(net, fn=fn, ft=ft, sliding=sliding)
    fs_low = np.where(first_is_i[:, None], fs_k, -fs_k)  # tangential force on particle i
    result, phases, loops = _parse_log(folder / "log.lammps")
    return LammpsRun(config=cfg, network=net, lammps=result, phases=phases,
                     contacts={"force": force[k], "fs": fs_low, "dist": dist[k]}, params=dict(params),
                     folder=str(folder), timing={"loops": loops})
