"""Core types of :mod:`dem.io`: the :class:`Configuration` and the :class:`FormatError`, plus the
fast-and-checked table parser every text reader uses."""
from __future__ import annotations

import gzip
import io as _io
import os
import stat
import warnings
import zlib
from dataclasses import dataclass, field

import numpy as np

from microhom.limits import available_memory
from microhom.network import from_overlaps

__all__ = ["Configuration", "FormatError", "FileTooLarge", "KN_CONVENTIONS", "available_memory",
           "check_regular_file", "read_limit"]

#: A periodic position more than this many cell lengths from the cell cannot be wrapped back
#: without losing its digits (x = 1e300 would land on x = 0): such files are refused.
MAX_CELLS_AWAY = 1.0e6
#: An open packing spanning more than this many smallest radii has no meaningful overlaps.
MAX_SPAN_OVER_RADIUS = 1.0e12

#: Accepted values of ``kn_convention`` (see :meth:`Configuration.network`).
KN_CONVENTIONS = ("standard", "oval")


class FormatError(ValueError):
    """A malformed configuration file.

    The message names the file, the (1-based) line number and the field, e.g.
    ``packing.data, line 17, field 'diameter': negative value -0.5 (must be > 0)``.
    ``path``, ``line`` and ``field`` are also available as attributes (``line``/``field`` may be
    ``None`` when the problem concerns the whole file).
    """

    def __init__(self, path, line, field, message):
        self.path = None if path is None else str(path)
        self.line = line
        self.field = field
        where = [str(self.path) if self.path is not None else "<data>"]
        if line is not None:
            where.append(f"line {line}")
        if field is not None:
            where.append(f"field '{field}'")
        super().__init__(f"{', '.join(where)}: {message}")


def _float_array(name, value, shape):
    arr = np.array(value, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values")
    return arr


def _per_particle(name, value, n, dtype, scalar=True):
    """``value`` as an (n,) array (a scalar is broadcast when ``scalar``); ValueError naming
    ``name`` and both shapes otherwise (never numpy's broadcast message)."""
    arr = np.asarray(value) if dtype is None else np.asarray(value, dtype=dtype)
    if arr.ndim == 0 and scalar:
        return np.full(n, arr.item(), dtype=arr.dtype)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have one value per particle, shape ({n},), "
                         f"got shape {arr.shape}")
    return np.array(arr)


def _check_extent(pos, rad, cell, origin):
    """Refuse coordinates too far away to be meaningful (see MAX_CELLS_AWAY, MAX_SPAN_OVER_RADIUS)."""
    if pos.shape[0] == 0:
        return
    if cell is not None:
        s = np.linalg.solve(cell, (pos - origin).T).T
        far = np.flatnonzero(np.abs(s).max(axis=1) > MAX_CELLS_AWAY)
        if far.size:
            k = int(far[0])
            at = ", ".join(f"{float(v):.6g}" for v in pos[k])
            raise ValueError(f"particle {k} at ({at}) is "
                             f"more than {MAX_CELLS_AWAY:.0e} cell lengths from the cell: wrapping "
                             f"it back would lose all its digits")
    else:
        span = float(np.max(pos.max(axis=0) - pos.min(axis=0)))
        if not span <= MAX_SPAN_OVER_RADIUS * float(rad.min()):
            raise ValueError(f"the particles span {span:.6g}, more than {MAX_SPAN_OVER_RADIUS:.0e} "
                             f"times the smallest radius {float(rad.min()):.6g}: coordinates absurd")


@dataclass(eq=False)
class Configuration:
    """A disk (2D) or sphere (3D) packing as read from (or written to) a file.

    The dimension ``d`` is the number of columns of ``positions`` (:attr:`dim`): 2 for disks, 3
    for spheres; every other array follows it.

    Parameters
    ----------
    positions : (N, d) float, particle centres [m]. Kept exactly as in the file (not wrapped).
    radii : (N,) float, radii [m], > 0.
    cell : (d, d) float or None, periodic shape matrix h whose *columns* are the periodic cell
        vectors (same convention as :class:`microhom.network.ContactNetwork`); None = not periodic.
    origin : (d,) float, lower-left corner of the cell/box [m] (default zeros).
    ids : (N,) int64, particle ids (LAMMPS ids; 1..N when the format has none).
    types : (N,) int64, particle types (1 when the format has none).
    velocities, forces : (N, d) float or None.
    fields : dict name -> (N,) array of further per-particle columns (e.g. ``omegaz``, ``ix``).
    meta : dict of file-level metadata (timestep, box for non-periodic files, OVAL extras, ...).
    source : path of the file read, or None.
    source_format : name of the format read (``"lammps-data"``, ``"lammps-dump"``, ``"oval"``,
        ``"npz"``, ``"csv"``), or None.
    """

    positions: np.ndarray
    radii: np.ndarray
    cell: np.ndarray | None = None
    origin: np.ndarray | None = None
    ids: np.ndarray | None = None
    types: np.ndarray | None = None
    velocities: np.ndarray | None = None
    forces: np.ndarray | None = None
    fields: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    source: str | None = None
    source_format: str | None = None

    def __post_init__(self):
        pos = np.array(self.positions, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] not in (2, 3):
            raise ValueError(f"positions must have shape (N, 2) (disks) or (N, 3) (spheres), "
                             f"got {pos.shape}")
        n, d = pos.shape
        if not np.all(np.isfinite(pos)):
            raise ValueError("positions contains non-finite values")
        rad = _per_particle("radii", self.radii, n, np.float64)
        if not np.all(np.isfinite(rad)) or np.any(rad <= 0):
            raise ValueError("radii must be finite and > 0")
        self.positions, self.radii = pos, rad
        if self.cell is not None:
            self.cell = _float_array("cell", self.cell, (d, d))
            if not abs(np.linalg.det(self.cell)) > 0:
                raise ValueError("cell must be non-singular")
        self.origin = _float_array("origin", np.zeros(d) if self.origin is None else self.origin,
                                   (d,))
        _check_extent(pos, rad, self.cell, self.origin)
        self.ids = (np.arange(1, n + 1, dtype=np.int64) if self.ids is None
                    else _per_particle("ids", self.ids, n, np.int64, scalar=False))
        self.types = (np.ones(n, dtype=np.int64) if self.types is None
                      else _per_particle("types", self.types, n, np.int64))
        for name in ("velocities", "forces"):
            v = getattr(self, name)
            if v is not None:
                setattr(self, name, _float_array(name, v, (n, d)))
        self.fields = {str(k): _per_particle(f"field {k!r}", v, n, None, scalar=False)
                       for k, v in dict(self.fields).items()}
        self.meta = dict(self.meta)
        if self.source is not None:
            self.source = os.fspath(self.source)

    # ---- sizes and geometry -----------------------------------------------------------------
    @property
    def n_particles(self) -> int:
        """Number of particles N."""
        return self.positions.shape[0]

    @property
    def dim(self) -> int:
        """Number of columns of ``positions``, 2 for disks and 3 for spheres."""
        return self.positions.shape[1]

    @property
    def periodic(self) -> bool:
        """True when the configuration has a periodic cell."""
        return self.cell is not None

    def fractional(self) -> np.ndarray:
        """(N, d) fractional coordinates ``s = h^-1 (x - origin)`` (needs a cell)."""
        if self.cell is None:
            raise ValueError("fractional coordinates need a periodic cell")
        return np.linalg.solve(self.cell, (self.positions - self.origin).T).T

    def wrapped(self) -> "Configuration":
        """A copy with every position mapped into the periodic cell (``s`` in [0, 1)^d)."""
        if self.cell is None:
            return self.copy()
        s = self.fractional()
        s -= np.floor(s)
        s[s >= 1.0] = 0.0
        out = self.copy()
        out.positions = self.origin + s @ self.cell.T
        return out

    def is_restricted_triclinic(self, rtol=1e-12) -> bool:
        """True if the cell is in LAMMPS's restricted form: a = (lx, 0), b = (xy, ly), lx, ly > 0
        (3D: a = (lx, 0, 0), b = (xy, ly, 0), c = (xz, yz, lz), lx, ly, lz > 0: h upper triangular
        with a positive diagonal).
        """
        if self.cell is None:
            return True
        h = self.cell
        scale = np.abs(h).max()
        return bool(np.all(np.abs(np.tril(h, -1)) <= rtol * scale) and np.all(np.diag(h) > 0))

    def to_restricted(self) -> "Configuration":
        """A copy rotated about ``origin`` so the cell is in LAMMPS's restricted triclinic form.

        Positions, velocities and forces are rotated with it (``meta["rotation"]`` holds the d x d
        rotation R applied: ``x_new = origin + R (x - origin)``). The contact network is unchanged
        up to that rotation. Left-handed cells (det h < 0) cannot be rotated to this form.
        """
        out = self.copy()
        if self.cell is None or self.is_restricted_triclinic():
            return out
        h = self.cell
        if np.linalg.det(h) <= 0:
            raise ValueError("cell is left-handed (det h < 0): no rotation gives LAMMPS's form")
        if self.dim == 3:
            q, r = np.linalg.qr(h)          # h = Q R; R upper triangular: LAMMPS's form
            sgn = np.where(np.diag(r) < 0, -1.0, 1.0)
            q, r = q * sgn, sgn[:, None] * r   # positive diagonal; det Q = det h / det R > 0
            rot, new_h = q.T, np.triu(r)
        else:
            rot = new_h = None
        a = h[:, 0]
        if rot is None:
            c, s = a / np.hypot(*a)
            rot = np.array([[c, s], [-s, c]])  # rotates a onto +x
            new_h = rot @ h
            new_h[1, 0] = 0.0
        out.cell = new_h
        out.positions = self.origin + (self.positions - self.origin) @ rot.T
        if self.velocities is not None:
            out.velocities = self.velocities @ rot.T
        if self.forces is not None:
            out.forces = self.forces @ rot.T
        prev = np.asarray(self.meta.get("rotation", np.eye(self.dim)))
        out.meta["rotation"] = (rot @ prev).tolist()
        return out

    def copy(self) -> "Configuration":
        """A deep copy (every array copied)."""
        return Configuration(
            positions=self.positions.copy(), radii=self.radii.copy(),
            cell=None if self.cell is None else self.cell.copy(), origin=self.origin.copy(),
            ids=self.ids.copy(), types=self.types.copy(),
            velocities=None if self.velocities is None else self.velocities.copy(),
            forces=None if self.forces is None else self.forces.copy(),
            fields={k: v.copy() for k, v in self.fields.items()}, meta=dict(self.meta),
            source=self.source, source_format=self.source_format)

    def sorted_by_id(self) -> "Configuration":
        """A copy with particles in increasing id order (LAMMPS dumps are unsorted by default)."""
        order = np.argsort(self.ids, kind="stable")
        out = self.copy()
        out.positions, out.radii = self.positions[order], self.radii[order]
        out.ids, out.types = self.ids[order], self.types[order]
        if self.velocities is not None:
            out.velocities = self.velocities[order]
        if self.forces is not None:
            out.forces = self.forces[order]
        out.fields = {k: v[order] for k, v in self.fields.items()}
        return out

    # ---- conversions ------------------------------------------------------------------------
    @classmethod
    def from_network(cls, net, **kwargs) -> "Configuration":
        """The packing of a :class:`~microhom.network.ContactNetwork` (contacts are not kept)."""
        return cls(positions=net.positions, radii=net.radii, cell=net.cell, origin=net.origin,
                   **kwargs)

    def network(self, kn=1.0, kt=None, *, kn_convention=None, **kwargs):
        """The contact network by :func:`microhom.network.from_overlaps`.

        Parameters
        ----------
        kn, kt : contact stiffnesses [N/m] (scalars or (C,) arrays); ``kt=None`` means ``kt`` equal
            to the (converted) normal stiffness, i.e. the ratio kt/kn = 1 is kept.
        kn_convention : ``"standard"`` — ``kn`` is the force per unit overlap (this project, LAMMPS
            ``hooke``); ``"oval"`` — ``kn`` is given in Kuhn's OVAL convention, where kn multiplies
            *half* the overlap, so the network gets ``kn / 2``. ``kt`` is never converted.
            ``None`` (default) means ``"standard"``, with a warning if the configuration was read
            from an OVAL D-file (say which convention your kn is in).
        **kwargs : passed to ``from_overlaps`` (``sliding``, ``branch_length``, ``tolerance``).
        """
        if kn_convention is None:
            if self.source_format == "oval":
                warnings.warn("configuration read from an OVAL D-file: kn is taken as force per "
                              "unit overlap; say kn_convention='oval' (command line: "
                              "--kn-convention oval) if kn is OVAL's, which multiplies half the "
                              "overlap, or 'standard' to silence this",
                              stacklevel=2)
            kn_convention = "standard"
        if kn_convention not in KN_CONVENTIONS:
            raise ValueError(f"kn_convention must be one of {KN_CONVENTIONS}, "
                             f"got {kn_convention!r}")
        kn_eff = np.asarray(kn, dtype=np.float64)
        if kn_convention == "oval":
            kn_eff = 0.5 * kn_eff
        kt_eff = kn_eff if kt is None else kt
        return from_overlaps(self.positions, self.radii, self.cell, kn=kn_eff, kt=kt_eff,
                             origin=self.origin, **kwargs)

    def __repr__(self):
        cell = "periodic" if self.periodic else "open"
        src = f", from {self.source_format}" if self.source_format else ""
        return f"Configuration(N={self.n_particles}, {cell}{src})"


# ---- checked table parsing ------------------------------------------------------------------

def show(tok, limit=30) -> str:
    """A token as it may appear in a message: quoted, cut at ``limit`` characters, and never raw
    binary (a token with control or replacement characters is described, not echoed)."""
    if any((not ch.isprintable()) or ch == "\ufffd" for ch in tok):
        return f"a non-text token of {len(tok)} characters"
    return repr(tok if len(tok) <= limit else tok[:limit] + "...")


def require_particles(n, path):
    """FormatError "no particles in the file" for an empty table (a reader never returns N = 0)."""
    if n == 0:
        raise FormatError(path, None, None, "no particles in the file")


def build(path, **kwargs) -> Configuration:
    """``Configuration(**kwargs)``, its ValueError turned into a FormatError naming ``path``."""
    try:
        return Configuration(**kwargs)
    except ValueError as exc:
        raise FormatError(path, None, None, str(exc)) from None


def _check_line_fields(line_text, columns, path, lineno):
    """Validate one data line; raise FormatError naming the first bad field."""
    toks = line_text.split()
    if len(toks) != len(columns):
        raise FormatError(path, lineno, None,
                          f"expected {len(columns)} columns ({' '.join(columns)}), "
                          f"found {len(toks)}")
    for tok, col in zip(toks, columns):
        try:
            v = float(tok)
        except ValueError:
            raise FormatError(path, lineno, col, f"non-numeric value {show(tok)}") from None
        if not np.isfinite(v):
            raise FormatError(path, lineno, col, f"non-finite value {show(tok)}")


def parse_table(block: bytes, columns, path, first_line, nrows=None, comment=None):
    """Parse a whitespace-separated numeric table into a (rows, ncol) float64 array.

    Fast path: ``pandas.read_csv(sep=r"\\s+")`` (measured the fastest of pandas, numpy.loadtxt,
    numpy.fromstring on 1e6 x 6 tables: see ``studies/bench_io.py``). If it fails or the result
    has a hole (missing/non-numeric/non-finite value), the block is re-read line by line to raise a
    :class:`FormatError` naming the exact line (``first_line`` is the file line number of the
    block's first line) and column. ``nrows``: the expected number of rows (truncation check).
    """
    import pandas as pd  # heavy (~0.3 s): only when a table is parsed

    ncol = len(columns)
    arr = None
    if block.strip():
        try:
            df = pd.read_csv(_io.BytesIO(block), sep=r"\s+", header=None, names=range(ncol),
                             dtype=np.float64, comment=comment, engine="c",
                             skip_blank_lines=True)
            arr = df.to_numpy(dtype=np.float64)
            if not np.all(np.isfinite(arr)):
                arr = None
        except (ValueError, pd.errors.ParserError, IndexError):
            arr = None
        if arr is None:
            _locate_error(block, columns, path, first_line, comment)
            raise FormatError(path, first_line, None, "unparseable table")  # not reached
    else:
        arr = np.empty((0, ncol))
    if nrows is not None and arr.shape[0] != nrows:
        last = first_line + block.rstrip().count(b"\n")
        if arr.shape[0] < nrows:
            raise FormatError(path, last, None,
                              f"truncated: expected {nrows} rows, found {arr.shape[0]}")
        raise FormatError(path, last, None, f"expected {nrows} rows, found {arr.shape[0]}")
    return arr


def _locate_error(block, columns, path, first_line, comment):
    text = block.decode("utf-8", errors="replace")
    for k, line in enumerate(text.split("\n")):
        if comment:
            line = line.split(comment, 1)[0]
        if not line.strip():
            continue
        _check_line_fields(line, columns, path, first_line + k)


def row_line(block: bytes, first_line: int, k: int, comment=None) -> int:
    """File line number of the k-th data row of ``block`` (blank/comment-only lines skipped)."""
    row = -1
    for n, line in enumerate(block.split(b"\n")):
        if comment:
            line = line.split(comment.encode(), 1)[0]
        if line.strip():
            row += 1
            if row == k:
                return first_line + n
    return first_line + k


def check_positive(values, name, path, block, first_line, comment=None):
    """Raise FormatError for the first value <= 0, naming its line in ``block``."""
    bad = np.flatnonzero(~(values > 0))
    if bad.size:
        k = int(bad[0])
        what = "negative" if values[k] < 0 else "zero"
        raise FormatError(path, row_line(block, first_line, k, comment), name,
                          f"{what} value {float(values[k])!r} (must be > 0)")


def parse_number(tok, path, lineno, fieldname, kind=float):
    """One numeric token of a header line; FormatError naming file, line and field otherwise."""
    try:
        v = kind(tok)
    except ValueError:
        raise FormatError(path, lineno, fieldname, f"non-numeric value {show(tok)}") from None
    if kind is float and not np.isfinite(v):
        raise FormatError(path, lineno, fieldname, f"non-finite value {show(tok)}")
    return v


class FileTooLarge(MemoryError):
    """A file (or its gunzipped content) larger than the memory available to read it.

    Raised *before* reading (regular files: from the size on disk) or as soon as a ``.gz``
    stream passes the limit; the message names the file, its size and the limit. A
    ``MemoryError``: the command lines report it as the machine's state (exit 1).
    """

    def __init__(self, path, size, limit, what="file"):
        self.path, self.size, self.limit = str(path), size, limit
        super().__init__(f"{path}: {what} of {_bytes(size)} is larger than the {_bytes(limit)} "
                         f"it may take (1/{READ_MEMORY_FACTOR} of the {_bytes(limit * READ_MEMORY_FACTOR)} "
                         f"of memory available); not read")


#: A text table of S bytes takes up to about this many times S in memory while it is parsed
#: (the bytes, pandas' buffers and the float64 arrays); a file is read only when
#: READ_MEMORY_FACTOR x its size fits the available memory (:func:`read_limit`).
READ_MEMORY_FACTOR = 4


def _bytes(n) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.3g} {unit}"
        n /= 1000.0
    return f"{n} B"  # not reached


def read_limit() -> int:
    """The largest number of bytes a reader takes in: ``available_memory() // READ_MEMORY_FACTOR``."""
    return available_memory() // READ_MEMORY_FACTOR


_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
          (stat.S_ISDIR, "a folder"))


def check_regular_file(path, *, limit=None) -> int:
    """The reading rule of every reader: ``path`` (symlinks followed) must be a regular file no
    larger than ``limit`` bytes (default :func:`read_limit`). Returns its size in bytes.

    Raises ``FileNotFoundError`` naming the path for a missing file, :class:`FormatError` naming
    the path and what it is for a FIFO, a device, a socket or a folder (reading them would block
    for ever or never end), and :class:`FileTooLarge` for a file that does not fit the memory.
    """
    path = os.fspath(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(2, f"{path}: no such file", path) from None
    if not stat.S_ISREG(st.st_mode):
        kind = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
        via = f" (through the symlink {path})" if os.path.islink(path) else ""
        raise FormatError(path, None, None, f"is {kind}{via}, not a regular file: refused (reading "
                          "it could block for ever or never end)")
    limit = read_limit() if limit is None else int(limit)
    if st.st_size > limit:
        raise FileTooLarge(path, st.st_size, limit)
    return int(st.st_size)


def open_bytes(path) -> bytes:
    """The whole file as bytes (transparently gunzipped for ``.gz``), under the reading rule.

    The reading rule (:func:`check_regular_file`): FIFOs, devices, sockets and folders are refused
    by name (:class:`FormatError`), and a file, or the gunzipped content of a ``.gz``, larger than
    :func:`read_limit` raises :class:`FileTooLarge` (a ``.gz`` is decompressed in blocks and
    stopped at the limit, never fully inflated first).
    Raises :class:`FormatError` naming the file for a truncated or non-gzip ``.gz`` and for binary
    content (NUL bytes: every format read through here is text); a missing or unreadable file
    raises the usual ``OSError``.
    """
    path = os.fspath(path)
    limit = read_limit()
    check_regular_file(path, limit=limit)
    with open(path, "rb") as raw:
        if path.endswith(".gz"):
            try:
                with gzip.GzipFile(fileobj=raw, mode="rb") as f:
                    chunks, total = [], 0
                    while True:
                        block = f.read(1 << 24)
                        if not block:
                            break
                        total += len(block)
                        if total > limit:
                            raise FileTooLarge(path, total, limit, "gunzipped content (so far)")
                        chunks.append(block)
                    data = b"".join(chunks)
            except (OSError, EOFError, zlib.error) as exc:
                why = ("truncated" if isinstance(exc, EOFError) else
                       "not gzip-compressed" if "gzip" in str(exc).lower() else "corrupt")
                raise FormatError(path, None, None,
                                  f"not a readable .gz file ({why})") from None
        else:
            data = raw.read(limit + 1)  # a file that grew since the check cannot run away
            if len(data) > limit:
                raise FileTooLarge(path, len(data), limit)
    if b"\x00" in data[:65536]:
        raise FormatError(path, None, None, "binary data (NUL bytes): not a text file of this "
                          "format")
    return data
