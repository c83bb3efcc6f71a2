"""dem.io: every format round-trips, the hand-written example files read as documented, and each
malformed case raises a FormatError naming the file, the line and the field."""
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from dem import io
from dem.io import Configuration, FormatError
from microhom import lattices

DATA = Path(__file__).parent / "data"
S3 = math.sqrt(3.0)
EXTS = ["data", "dump", "csv", "npz", "dfile", "vtu", "vtk"]


def needs(ext):
    if ext in ("vtu", "vtk"):
        pytest.importorskip("meshio")


def random_packing(n=60, sheared=True, seed=1):
    rng = np.random.default_rng(seed)
    h = np.array([[10.0, 2.5 if sheared else 0.0], [0.0, 8.0]])
    origin = np.array([-3.0, 1.5])
    s = rng.random((n, 2))
    return Configuration(positions=origin + s @ h.T, radii=rng.uniform(0.5, 0.9, n), cell=h,
                         origin=origin, ids=rng.permutation(n) + 1,
                         types=rng.integers(1, 3, n),
                         velocities=rng.normal(size=(n, 2)), forces=rng.normal(size=(n, 2)))


def same_network(a, b):
    assert a.n_contacts == b.n_contacts
    np.testing.assert_array_equal(a.pairs, b.pairs)
    np.testing.assert_allclose(a.branch, b.branch, rtol=0, atol=1e-12)


def roundtrip(cfg, tmp_path, ext):
    p = tmp_path / f"cfg.{ext}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        io.write(p, cfg)
        return io.read(p)


# ---- round trips ------------------------------------------------------------------------------

@pytest.mark.parametrize("ext", EXTS)
def test_roundtrip_random_sheared_packing(tmp_path, ext):
    needs(ext)
    cfg = random_packing()
    back = roundtrip(cfg, tmp_path, ext)
    if ext == "dfile":  # OVAL's cell starts at (0, 0): positions are written relative to origin
        np.testing.assert_array_equal(back.origin, 0.0)
        back.positions += cfg.origin
        back.origin = cfg.origin
    np.testing.assert_allclose(back.positions, cfg.positions, rtol=0,
                               atol=1e-14 if ext == "dfile" else 0.0)
    np.testing.assert_array_equal(back.radii, cfg.radii)
    np.testing.assert_allclose(back.cell, cfg.cell, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back.origin, cfg.origin, rtol=0, atol=1e-14)
    if ext != "dfile":  # OVAL has no ids, types, velocities
        np.testing.assert_array_equal(back.ids, cfg.ids)
        np.testing.assert_array_equal(back.types, cfg.types)
    if ext in ("dump", "csv", "npz", "vtu", "vtk", "data"):
        np.testing.assert_array_equal(back.velocities, cfg.velocities)
    if ext in ("dump", "csv", "npz", "vtu", "vtk"):
        np.testing.assert_array_equal(back.forces, cfg.forces)
    same_network(back.network(kn_convention="standard"), cfg.network())


@pytest.mark.parametrize("ext", EXTS)
@pytest.mark.parametrize("angle", [0.0, 0.3])
def test_triangular_lattice_six_contacts(tmp_path, ext, angle):
    """A (rotated) triangular lattice keeps 6 contacts per particle through every format."""
    needs(ext)
    cfg = Configuration.from_network(lattices.triangular(6, 6, angle=angle))
    if ext == "dfile" and angle:
        cfg = cfg.to_restricted()  # OVAL's cell has a along x
    back = roundtrip(cfg, tmp_path, ext)
    np.testing.assert_allclose(back.positions, cfg.positions, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back.cell, cfg.cell, rtol=0, atol=1e-14)
    net = back.network(kn_convention="standard")
    assert np.all(net.contact_counts() == 6)
    same_network(net, cfg.network())


@pytest.mark.parametrize("ext", ["data", "dump", "dfile"])
def test_sheared_cell_triangular_lattice(tmp_path, ext):
    """Same lattice, cell vectors (6, 0) and (3, 3 sqrt3): a LAMMPS/OVAL tilt of 3."""
    lat = lattices.triangular(6, 6)
    cell = np.array([[6.0, 3.0], [0.0, 3 * S3]])
    cfg = Configuration(positions=lat.positions, radii=lat.radii, cell=cell)
    back = roundtrip(cfg, tmp_path, ext)
    np.testing.assert_array_equal(back.cell, cell)
    assert np.all(back.network(kn_convention="standard").contact_counts() == 6)


def test_to_restricted_rotates_everything():
    cfg = random_packing()
    c, s = math.cos(0.7), math.sin(0.7)
    rot = np.array([[c, -s], [s, c]])
    turned = Configuration(positions=cfg.origin + (cfg.positions - cfg.origin) @ rot.T,
                           radii=cfg.radii, cell=rot @ cfg.cell, origin=cfg.origin,
                           velocities=cfg.velocities @ rot.T)
    assert not turned.is_restricted_triclinic()
    back = turned.to_restricted()
    assert back.is_restricted_triclinic()
    np.testing.assert_allclose(back.cell, cfg.cell, atol=1e-12)
    np.testing.assert_allclose(back.positions, cfg.positions, atol=1e-12)
    np.testing.assert_allclose(back.velocities, cfg.velocities, atol=1e-12)


def test_general_triclinic_headers_and_never(tmp_path):
    cfg = Configuration.from_network(lattices.triangular(6, 6, angle=0.3))
    io.write(tmp_path / "g.data", cfg)
    io.write(tmp_path / "g.dump", cfg)
    assert "avec" in (tmp_path / "g.data").read_text()
    assert "BOX BOUNDS abc origin pp pp pp" in (tmp_path / "g.dump").read_text()
    with pytest.raises(ValueError, match="restricted"):
        io.write(tmp_path / "h.data", cfg, general_triclinic="never")


def test_open_packing_roundtrip(tmp_path):
    cfg = random_packing(sheared=False)
    cfg.cell = None
    for ext in ("dump", "csv", "npz"):
        back = roundtrip(cfg, tmp_path, ext)
        assert back.cell is None
        np.testing.assert_array_equal(back.positions, cfg.positions)
    with pytest.warns(UserWarning, match="boundary f f p"):
        io.write(tmp_path / "open.data", cfg)
    back = io.read(tmp_path / "open.data", periodic=False)
    assert back.cell is None
    same_network(back.network(), cfg.network())


def test_multiframe_dump_append(tmp_path):
    cfg = random_packing()
    p = tmp_path / "traj.lammpstrj"
    io.write_lammps_dump(p, cfg, timestep=0)
    moved = cfg.copy()
    moved.positions = moved.positions + 0.01
    io.write_lammps_dump(p, moved, timestep=10, append=True)
    frames = list(io.iter_lammps_dump(p))
    assert [f.meta["timestep"] for f in frames] == [0, 10]
    np.testing.assert_array_equal(io.read(p, frame=-1).positions, moved.positions)


def test_gzip_dump(tmp_path):
    import gzip
    src = (DATA / "radius.dump").read_bytes()
    p = tmp_path / "radius.dump.gz"
    p.write_bytes(gzip.compress(src))
    assert io.read(p, frame=0).n_particles == 4


def test_vtk_contents(tmp_path):
    meshio = pytest.importorskip("meshio")
    net = lattices.triangular(6, 6)
    from dataclasses import replace
    net = replace(net, fn=np.arange(net.n_contacts, dtype=float), ft=np.zeros(net.n_contacts))
    io.write(tmp_path / "net.vtu", net)
    m = meshio.read(tmp_path / "net.vtu")
    kinds = m.cell_data["kind"][1]
    contact = m.cell_data["contact"][1].astype(int)
    # every contact appears once as a line or twice as half-lines; 4 outline edges
    assert np.sum(kinds == 3) == 4
    counts = np.bincount(contact[contact >= 0], minlength=net.n_contacts)
    assert set(np.unique(counts[np.isin(np.arange(net.n_contacts), contact[kinds == 1])])) == {1}
    assert np.all(counts >= 1)
    np.testing.assert_array_equal(m.cell_data["fn"][1][kinds != 3], contact[kinds != 3])
    # no drawn segment is longer than a contact
    seg = m.points[m.cells_dict["line"][kinds != 3]]
    assert np.max(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)) <= 1.0 + 1e-12


# ---- the hand-written example files -----------------------------------------------------------

def test_example_orthogonal_data():
    cfg = io.read(DATA / "ortho.data")
    assert cfg.source_format == "lammps-data"
    np.testing.assert_array_equal(cfg.cell, [[4.0, 0.0], [0.0, 2.5]])
    np.testing.assert_array_equal(cfg.radii, 0.5)
    np.testing.assert_array_equal(cfg.types, [1, 1, 2, 2])
    np.testing.assert_array_equal(cfg.velocities[[0, 2]], [[0.1, 0.2], [0.0, -0.25]])
    assert cfg.fields["omegaz"][2] == 0.5
    net = cfg.network()
    assert net.n_contacts == 4 and np.all(net.contact_counts() == 2)


def test_example_sheared_data():
    cfg = io.read(DATA / "sheared.data")
    np.testing.assert_allclose(cfg.cell, [[4.0, 1.0], [0.0, 2 * S3]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(cfg.origin, [-2.0, 1.0])
    assert np.all(cfg.network().contact_counts() == 6)
    assert list(np.flatnonzero(cfg.fields["ix"])) == [5, 9]
    un = io.read(DATA / "sheared.data", unwrap=True)
    np.testing.assert_array_equal(un.positions[5], cfg.positions[5] + [4.0, 0.0])
    assert np.all(un.network().contact_counts() == 6)


def test_example_dump_radius_frames():
    with pytest.warns(UserWarning, match=r"holds 2 frames: read the first \(timestep 1000\)"):
        cfg = io.read(DATA / "radius.dump")
    assert cfg.meta["timestep"] == 1000
    np.testing.assert_array_equal(cfg.ids, [3, 1, 2, 4])  # file order kept
    s = cfg.sorted_by_id()
    np.testing.assert_array_equal(s.positions[:, 0], [0.5, 1.5, 2.5, 3.5])
    np.testing.assert_array_equal(s.velocities[0], [0.1, 0.2])
    np.testing.assert_array_equal(s.forces[0], [-1.0, 0.0])
    np.testing.assert_array_equal(s.fields["c_contacts"], 2)
    last = io.read(DATA / "radius.dump", frame=1)
    assert last.meta["timestep"] == 2000 and np.all(last.positions[:, 1] == 1.0)


def test_example_dump_diameter_scaled_nonperiodic():
    cfg = io.read(DATA / "diameter.dump")
    assert cfg.cell is None and cfg.meta["boundary"] == "ff ff pp"
    np.testing.assert_array_equal(cfg.radii, 0.5)
    np.testing.assert_array_equal(cfg.positions, [[0.5, 0.5], [1.5, 0.5], [2.5, 0.5], [3.5, 0.5]])
    assert cfg.network().n_contacts == 3  # open chain


def test_example_dump_triclinic_bounds():
    """Bounds line 1 is xlo_bound = xlo + min(0, xy) = -3, xhi_bound = xhi = 2 for xy = -1."""
    cfg = io.read(DATA / "triclinic.dump")
    np.testing.assert_allclose(cfg.cell, [[4.0, -1.0], [0.0, 2 * S3]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(cfg.origin, [-2.0, 1.0])
    assert cfg.meta["tilt"] == [-1.0, 0.0, 0.0]
    assert np.all(cfg.network().contact_counts() == 6)


def test_dump_bounds_formulas():
    for xy in (-1.5, 0.0, 2.0):
        b = io.dump_bounds(-2.0, 2.0, 1.0, 3.0, xy)
        assert b[0] == -2.0 + min(0.0, xy) and b[1] == 2.0 + max(0.0, xy)
        assert io.box_from_dump_bounds(*b, xy) == (-2.0, 2.0, 1.0, 3.0)


def test_example_oval_dfile_and_kn_convention():
    cfg = io.read(DATA / "D0001")
    assert cfg.source_format == "oval" and cfg.meta["oval_xcell33"] == 0.25
    np.testing.assert_allclose(cfg.cell, [[4.0, 1.0], [0.0, 2 * S3]], rtol=0, atol=1e-15)
    net = cfg.network(kn=2.0e5, kt=3.0e4, kn_convention="oval")
    assert np.all(net.contact_counts() == 6)
    np.testing.assert_array_equal(net.kn, 1.0e5)  # OVAL's kn multiplies half the overlap
    np.testing.assert_array_equal(net.kt, 3.0e4)
    with pytest.warns(UserWarning, match="kn_convention"):
        cfg.network(kn=1.0)


def test_oval_two_offsets_refused_with_the_fix(tmp_path):
    """The manual puts three offsets on line 3; the old invented two-offset layout is refused with
    the one-token fix in the message (no file of that layout exists outside this project)."""
    p = tmp_path / "D2"
    p.write_text("1\n2 4.0 4.0 0\n0.5 0.0\n0.5 1 1\n0.5 2 1\n")
    with pytest.raises(FormatError, match=r"line 3: expected 3 shear offsets .*append xcell\(2,3\)"):
        io.read(p)


def test_oval_third_direction_offsets_kept_and_warned(tmp_path):
    """xcell(1,3), xcell(2,3) tilt the third direction: kept in meta, never used as an in-plane
    shear (the old reader took the second number as in-plane, against the manual)."""
    p = tmp_path / "D2"
    p.write_text("1\n2 4.0 4.0 1.0\n0.5 0.25 0.125\n0.5 1 1\n0.5 2 1\n")
    with pytest.warns(UserWarning, match="third direction"):
        cfg = io.read(p)
    np.testing.assert_array_equal(cfg.cell, [[4.0, 0.5], [0.0, 4.0]])
    assert cfg.meta["oval_xcell13"] == 0.25 and cfg.meta["oval_xcell23"] == 0.125


def test_oval_fortran_exponents(tmp_path):
    p = tmp_path / "D3"
    p.write_text("1\n     1  4.0D0  4.0d+00  1.0D+00\n        0.0D+00 0.0D0 0.0\n5.0D-01 1.0 1.0\n")
    assert io.read(p).radii[0] == 0.5


def test_oval_writer_follows_the_manual_columns(tmp_path):
    """Round trip of a file laid out exactly as DEMPLA's manual says: i1 / i6, 3(1pd25.17) /
    6x, 3(1pd25.17) / 3(1pd25.17) per disk. The columns are cut at their fixed positions (not
    split on blanks) and read back with the D exponent a Fortran writer would use."""
    cfg = random_packing(n=40).wrapped()
    cfg = io.Configuration(positions=cfg.positions - cfg.origin, radii=cfg.radii, cell=cfg.cell)
    p = tmp_path / "Dman"
    io.write_oval(p, cfg, xcell33=2.5)
    lines = p.read_text().splitlines()
    assert lines[0] == "1" and len(lines) == 3 + 40
    assert len(lines[1]) == 6 + 3 * 25 and len(lines[2]) == 6 + 3 * 25
    assert lines[2][:6] == " " * 6
    assert int(lines[1][:6]) == 40
    fields = lambda line, skip: [float(line[skip + 25 * i: skip + 25 * (i + 1)]) for i in range(3)]
    assert fields(lines[1], 6) == [10.0, 8.0, 2.5]
    assert fields(lines[2], 6) == [2.5, 0.0, 0.0]                      # xcell(1,2), (1,3), (2,3)
    for i, line in enumerate(lines[3:]):
        assert len(line) == 75 and "E" in line[:25]
        assert fields(line, 0) == [cfg.radii[i], *cfg.positions[i]]   # 18 digits: exact
    # Fortran's 1pd25.17 writes D exponents: the same file with D reads to the same numbers
    pd_ = tmp_path / "Dfortran"
    pd_.write_text(p.read_text().replace("E", "D"))
    for path in (p, pd_):
        back = io.read(path)
        np.testing.assert_array_equal(back.positions, cfg.positions)
        np.testing.assert_array_equal(back.radii, cfg.radii)
        np.testing.assert_array_equal(back.cell, cfg.cell)
        assert back.meta["oval_xcell33"] == 2.5
    with pytest.raises(ValueError, match="to_restricted"):
        io.write_oval(p, io.Configuration(positions=[[0, 0]], radii=1, cell=[[4, 0], [1, 4]]))


@pytest.mark.parametrize("name,fmt", [("a.data", "lammps-data"), ("a.lmp", "lammps-data"),
                                      ("a.dump", "lammps-dump"), ("a.lammpstrj", "lammps-dump"),
                                      ("a.dump.gz", "lammps-dump"), ("a.dfile", "oval"),
                                      ("a.d", "oval"), ("D0001", "oval"), ("a.npz", "npz"),
                                      ("a.csv", "csv"), ("a.vtu", "vtk"), ("Dx.csv", "csv")])
def test_detect_format(name, fmt):
    assert io.detect_format(name) == fmt


def test_unknown_extension():
    with pytest.raises(ValueError, match="format="):
        io.detect_format("packing.xyz")
    with pytest.raises(ValueError, match="unknown format"):
        io.read(DATA / "ortho.data", format="pdb")


# ---- malformed files --------------------------------------------------------------------------

DUMP_HEAD = ("ITEM: TIMESTEP\n0\nITEM: NUMBER OF ATOMS\n{n}\nITEM: BOX BOUNDS {b}\n"
             "0 4\n0 2\n-0.5 0.5\n")


def dump_text(rows, n=None, bounds="pp pp pp", cols="id type radius x y z"):
    return DUMP_HEAD.format(n=len(rows) if n is None else n, b=bounds) + \
        f"ITEM: ATOMS {cols}\n" + "".join(r + "\n" for r in rows)


GOOD = ["1 1 0.5 0.5 0.5 0", "2 1 0.5 1.5 0.5 0", "3 1 0.5 2.5 0.5 0"]


def data_text(rows, style="sphere"):
    return ("title\n\n3 atoms\n1 atom types\n\n0 4 xlo xhi\n0 2 ylo yhi\n-0.5 0.5 zlo zhi\n\n"
            f"Atoms # {style}\n\n" + "".join(r + "\n" for r in rows))


DATA_GOOD = ["1 1 1.0 1.0 0.5 0.5 0", "2 1 1.0 1.0 1.5 0.5 0", "3 1 1.0 1.0 2.5 0.5 0"]


def bad_dump(rows, **kw):
    return ("x.dump", dump_text(rows, **kw))


MALFORMED = {
    "dump truncated": (bad_dump(GOOD[:2], n=3), 11, None, "truncated"),
    "dump wrong column count": (bad_dump([GOOD[0], "2 1 0.5 1.5 0.5", GOOD[2]]), 11, None,
                                "expected 6 columns"),
    "dump negative radius": (bad_dump([GOOD[0], GOOD[1], "3 1 -0.5 2.5 0.5 0"]), 12, "radius",
                             "negative"),
    "dump non-numeric": (bad_dump([GOOD[0], "2 1 0.5 abc 0.5 0", GOOD[2]]), 11, "x",
                         "non-numeric"),
    "dump nan": (bad_dump([GOOD[0], "2 1 0.5 nan 0.5 0", GOOD[2]]), 11, "x", "non-finite"),
    "dump outside non-periodic box": (bad_dump([GOOD[0], "2 1 0.5 4.5 0.5 0", GOOD[2]],
                                               bounds="ff ff pp"), 11, "x", "outside"),
    "dump no radius": (bad_dump(["1 1 0.5 0.5 0"], cols="id type x y z"), 9, "ATOMS",
                       "radius"),
    "dump duplicate id": (bad_dump([GOOD[0], GOOD[0], GOOD[2]]), 11, "id", "duplicate"),
    "dump bad bounds": (("x.dump", DUMP_HEAD.replace("0 2\n", "0 two\n").format(n=1, b="pp pp pp")
                         + "ITEM: ATOMS id radius x y\n1 0.5 1 1\n"), 7, "BOX BOUNDS y",
                        "non-numeric"),
    "data truncated": (("x.data", data_text(DATA_GOOD[:2])), 13, None, "truncated"),
    "data wrong column count": (("x.data", data_text([DATA_GOOD[0], "2 1 1.0 1.0 1.5 0.5",
                                                      DATA_GOOD[2]])), 13, None,
                                "expected 7 columns"),
    "data first line bad count": (("x.data", data_text(["1 1 1.0 0.5 0.5"] + DATA_GOOD[1:])), 12,
                                  None, "expected 7 or 10"),
    "data negative diameter": (("x.data", data_text([DATA_GOOD[0], DATA_GOOD[1],
                                                     "3 1 -1.0 1.0 2.5 0.5 0"])), 14,
                               "diameter", "negative"),
    "data non-numeric": (("x.data", data_text([DATA_GOOD[0], "2 1 1.0 1.0 1.5 y? 0",
                                               DATA_GOOD[2]])), 13, "y", "non-numeric"),
    "data atomic style": (("x.data", data_text(DATA_GOOD, style="atomic")), 10, "Atoms",
                          "sphere"),
    "data bad box": (("x.data", data_text(DATA_GOOD).replace("0 2 ylo", "0 z2 ylo")), 7, "yhi",
                     "non-numeric"),
    "oval unknown shape": (("D1", "2\n1 4 4 0\n0 0 0\n0.5 1 1\n"), 1, "kshape", "unknown"),
    "oval truncated": (("D1", "1\n3 4 4 0\n0 0 0\n0.5 1 1\n0.5 2 1\n"), 5, None, "truncated"),
    "oval wrong columns": (("D1", "1\n2 4 4 0\n0 0 0\n0.5 1 1\n0.5 2\n"), 5, None,
                           "expected 3 columns"),
    "oval negative radius": (("D1", "1\n2 4 4 0\n0 0 0\n0.5 1 1\n-0.5 2 1\n"), 5, "radius",
                             "negative"),
    "oval non-numeric Lx": (("D1", "1\n2 four 4 0\n0 0 0\n0.5 1 1\n0.5 2 1\n"), 2, "xcell(1,1)",
                            "non-numeric"),
    "oval header count": (("D1", "1\n2 4 4\n0 0 0\n0.5 1 1\n0.5 2 1\n"), 2, None, "4 numbers"),
    "csv non-numeric": (("x.csv", "# format_version: 1\nid,type,x,y,radius\n1,1,0,0,0.5\n"
                         "2,1,oops,0,0.5\n"), 4, "x", "non-numeric"),
    "csv negative radius": (("x.csv", "# format_version: 1\nid,type,x,y,radius\n1,1,0,0,-0.5\n"),
                            3, "radius", "must be > 0"),
    "csv missing column": (("x.csv", "# format_version: 1\nid,type,x,y\n1,1,0,0\n"), 2,
                           "radius", "missing"),
    "csv version": (("x.csv", "# format_version: 7\nid,type,x,y,radius\n"), 1, "format_version",
                    "unsupported"),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed(tmp_path, case):
    (name, text), line, field, words = MALFORMED[case]
    p = tmp_path / name
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(FormatError) as err:
            io.read(p)
    e = err.value
    assert isinstance(e, ValueError)
    assert str(p) in str(e) and words in str(e)
    assert e.line == line, str(e)
    assert e.field == field, str(e)
    if line is not None:
        assert f"line {line}" in str(e)
    if field is not None:
        assert f"field '{field}'" in str(e)


def test_data_outside_nonperiodic_box(tmp_path):
    p = tmp_path / "x.data"
    p.write_text(data_text([DATA_GOOD[0], "2 1 1.0 1.0 1.5 2.5 0", DATA_GOOD[2]]))
    io.read(p)  # periodic by default: fine
    with pytest.raises(FormatError, match=r"line 13, field 'y'.*outside"):
        io.read(p, periodic=False)


def test_npz_errors(tmp_path):
    p = tmp_path / "x.npz"
    p.write_bytes(b"not a zip")
    with pytest.raises(FormatError, match="npz"):
        io.read(p)
    cfg = random_packing()
    io.write(p, cfg)
    z = dict(np.load(p))
    z["format_version"] = np.array(99)
    np.savez(tmp_path / "y.npz", **z)
    with pytest.raises(FormatError, match="field 'format_version'"):
        io.read(tmp_path / "y.npz")
    z["format_version"] = np.array(1)
    z["radii"] = -z["radii"]
    np.savez(tmp_path / "z.npz", **z)
    with pytest.raises(FormatError, match="field 'radii'"):
        io.read(tmp_path / "z.npz")


def test_write_accepts_network_and_rejects_others(tmp_path):
    net = lattices.square(4, 4)
    io.write(tmp_path / "sq.npz", net)
    assert io.read(tmp_path / "sq.npz").n_particles == 16
    with pytest.raises(TypeError):
        io.write(tmp_path / "sq.csv", {"positions": 1})


def test_real_dempla_startfile_head(tmp_path):
    """The first 23 lines, verbatim, of DEMPLA's own sample StartFile Dcircls_1002_2 (public GitHub
    repository mrkuhn53/dempla; see tests/data/README.md). The header is read as the manual
    defines it (the old reader refused every real file at line 3); the particle table stops after
    20 of the announced 1002 disks, which must be reported as a truncation at the file's end."""
    src = DATA / "Dcircls_1002_2.head"
    with pytest.raises(FormatError, match="truncated: expected 1002 rows, found 20") as err:
        io.read(src)
    assert err.value.line == 23
    # the same lines with np = 20 (the only edit): every number exactly as written in the file
    text = src.read_text().replace("  1002  ", "    20  ", 1)
    p = tmp_path / "Dcircls_20"
    p.write_text(text)
    cfg = io.read(p)
    L = 2.97703143874021730e+01
    np.testing.assert_array_equal(cfg.cell, [[L, 0.0], [0.0, L]])
    assert cfg.meta["oval_xcell33"] == 1.0
    rows = [line.split() for line in text.splitlines()[3:]]
    np.testing.assert_array_equal(cfg.radii, [float(r[0]) for r in rows])
    np.testing.assert_array_equal(cfg.positions, [[float(r[1]), float(r[2])] for r in rows])
    assert cfg.radii[0] == 3.13454063710418570e-01 and cfg.positions[-1, 1] == 1.72715442442558780e+01
    # written back by the manual's fixed-column writer: DEMPLA's own layout, column for column,
    # and the same numbers (the last printed digit may differ: 17 significant digits suffice)
    out = tmp_path / "Dback"
    io.write_oval(out, cfg)
    back, orig = out.read_text().splitlines(), text.splitlines()
    assert [len(x) for x in back] == [len(x) for x in orig]
    for b, o in zip(back, orig):
        assert [m.start() for m in re.finditer("E", b)] == [m.start() for m in re.finditer("E", o)]
        assert [float(t) for t in b.split()] == [float(t) for t in o.split()]


def test_real_dempla_oval_startfile_refused_by_its_kshape():
    """DEMPLA's sample of ovals (kshape 2, verbatim head; tests/data/README.md): refused on line 1,
    naming the shape code, not misread as disks."""
    with pytest.raises(FormatError, match="line 1, field 'kshape': unknown shape code '2'"):
        io.read(DATA / "Dovals_1002_1d.head")
