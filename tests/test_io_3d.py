"""dem.io on 3D atom_style sphere files written by LAMMPS itself (tests/data/in.make3d, LAMMPS
29 Sep 2021): orthogonal and triclinic (xy xz yz) boxes, radius/diameter columns, scaled and
unscaled coordinates, .gz, the 2D/3D rule, and the network against LAMMPS's own contact count."""
import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

from dem import io

DATA = Path(__file__).parent / "data"

# printed by LAMMPS (in.make3d's BOX line, %.17g): box and compute contact/atom summed
LAMMPS_BOX = dict(lx=5.7999999999999998, ly=5.6000000000000005, lz=5.8000000000000007,
                  xlo=0.29999999999999999, ylo=-0.20000000000000001, zlo=0.10000000000000001)
LAMMPS = {"tri": dict(LAMMPS_BOX, xy=1.3, xz=-0.90000000000000002, yz=0.69999999999999996,
                      contacts=1118),
          "ortho": dict(LAMMPS_BOX, xy=0.0, xz=0.0, yz=0.0, contacts=1090)}
FILES = {"tri": ["sph3d_tri.data", "sph3d_tri.dump", "sph3d_tri_scaled.dump"],
         "ortho": ["sph3d_ortho.data", "sph3d_ortho_scaled.dump"]}


def _cases():
    return [(box, f) for box, fs in FILES.items() for f in fs]


@pytest.mark.parametrize("box,name", _cases())
def test_box_is_lammps_box(box, name):
    cfg = io.read(DATA / name)
    b = LAMMPS[box]
    assert cfg.dim == 3 and cfg.positions.shape == (200, 3) and cfg.meta["dimension"] == 3
    h = np.array([[b["lx"], b["xy"], b["xz"]], [0, b["ly"], b["yz"]], [0, 0, b["lz"]]])
    np.testing.assert_allclose(cfg.cell, h, rtol=0, atol=1e-15)
    np.testing.assert_allclose(cfg.origin, [b["xlo"], b["ylo"], b["zlo"]], rtol=0, atol=1e-15)
    assert cfg.is_restricted_triclinic()


@pytest.mark.parametrize("box,name", _cases())
def test_contacts_match_lammps(box, name):
    """compute contact/atom (d <= r_i + r_j, summed over atoms = 2 C) against the network built
    through the cell: a wrong tilt or z bound changes the contacts across the boundaries."""
    cfg = io.read(DATA / name).sorted_by_id()
    net = cfg.network(kn=1.0, tolerance=0.0)
    assert net.positions.shape[1] == 3 and net.cell.shape == (3, 3)
    assert 2 * len(net.pairs) == LAMMPS[box]["contacts"]


def test_per_sphere_contacts_and_radii_columns():
    tri = io.read(DATA / "sph3d_tri.dump").sorted_by_id()          # radius column
    sc = io.read(DATA / "sph3d_tri_scaled.dump").sorted_by_id()    # diameter column, xs ys zs
    data = io.read(DATA / "sph3d_tri.data").sorted_by_id()         # diameter column
    net = tri.network(kn=1.0, tolerance=0.0)
    deg = np.bincount(net.pairs.ravel(), minlength=tri.n_particles)
    np.testing.assert_array_equal(deg, tri.fields["c_cn"].astype(int))
    for other in (sc, data):
        np.testing.assert_array_equal(other.ids, tri.ids)
        np.testing.assert_array_equal(other.radii, tri.radii)
    assert set(np.unique(tri.radii)) == {0.5, 0.65}
    # write_data prints 16 digits, the dump 17; scaled ones go through h: round-off only
    np.testing.assert_allclose(data.positions, tri.positions, rtol=0, atol=1e-14)
    np.testing.assert_allclose(sc.positions, tri.positions, rtol=0, atol=1e-13)
    np.testing.assert_allclose(data.velocities, tri.velocities, rtol=1e-15, atol=1e-15)
    assert tri.forces.shape == (200, 3) and np.abs(tri.forces[:, 2]).max() > 0
    for c in ("ix", "iy", "iz"):
        assert data.fields[c].dtype == np.int64


def test_gzip(tmp_path):
    for name in ("sph3d_tri.data", "sph3d_tri.dump"):
        gz = tmp_path / (name + ".gz")
        with open(DATA / name, "rb") as f, gzip.open(gz, "wb") as g:
            shutil.copyfileobj(f, g)
        a, b = io.read(DATA / name), io.read(gz)
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_array_equal(a.cell, b.cell)


def test_dimension_rule(tmp_path):
    """3D when z is periodic and the z coordinates vary; else 2D; dimension= overrides."""
    cfg = io.read(DATA / "sph3d_tri.dump")
    flat = cfg.copy()
    flat.positions[:, 2] = 0.3                 # all z equal: a 2D file
    io.write(tmp_path / "flat.dump", flat)
    assert io.read(tmp_path / "flat.dump").dim == 2
    assert io.read(tmp_path / "flat.dump", dimension=3).dim == 3
    assert io.read(DATA / "sph3d_tri.dump", dimension=2).positions.shape == (200, 2)
    text = (DATA / "sph3d_tri.dump").read_text().replace("xy xz yz pp pp pp", "xy xz yz pp pp ff")
    (tmp_path / "zwall.dump").write_text(text)  # z not periodic: 2D unless said
    assert io.read(tmp_path / "zwall.dump").dim == 2
    with pytest.warns(UserWarning, match="periodic in one direction only"):
        three = io.read(tmp_path / "zwall.dump", dimension=3)
    assert three.dim == 3 and three.cell is None and three.meta["box"]
    # a data file: z periodic exactly when periodic=True
    io.write(tmp_path / "flat.data", flat)
    assert io.read(tmp_path / "flat.data").dim == 2
    assert io.read(DATA / "sph3d_ortho.data", periodic=False).dim == 2
    assert io.read(DATA / "sph3d_ortho.data", periodic=False, dimension=3).dim == 3
    with pytest.raises(ValueError, match="dimension must be None"):
        io.read(DATA / "sph3d_tri.dump", dimension=4)
    # the 2D files stay 2D
    for name in ("ortho.data", "sheared.data", "triclinic.dump", "diameter.dump"):
        assert io.read(DATA / name).dim == 2


@pytest.mark.parametrize("name", ["sph3d_tri.data", "sph3d_ortho.data", "sph3d_tri.dump"])
def test_write_read_round_trip(tmp_path, name):
    cfg = io.read(DATA / name).sorted_by_id()
    for ext in (".data", ".dump"):
        out = tmp_path / ("rt" + ext)
        io.write(out, cfg)
        back = io.read(out).sorted_by_id()
        np.testing.assert_array_equal(back.positions, cfg.positions)
        np.testing.assert_allclose(back.cell, cfg.cell, rtol=0, atol=1e-15)
        np.testing.assert_allclose(back.origin, cfg.origin, rtol=0, atol=1e-15)  # via the bounds
        np.testing.assert_array_equal(back.radii, cfg.radii)


def test_general_triclinic_3d(tmp_path):
    """A rotated 3D cell: written as LAMMPS's general triclinic (abc origin), read back; and
    to_restricted() rotates it to the restricted form with the same contacts."""
    cfg = io.read(DATA / "sph3d_tri.dump").sorted_by_id()
    th = 0.4
    rot = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    rot = rot @ np.array([[1, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]])
    r = cfg.copy()
    r.cell = rot @ cfg.cell
    r.positions = cfg.origin + (cfg.positions - cfg.origin) @ rot.T
    r.velocities = r.forces = None
    assert not r.is_restricted_triclinic()
    for ext in (".data", ".dump"):
        io.write(tmp_path / ("g" + ext), r)
        back = io.read(tmp_path / ("g" + ext)).sorted_by_id()
        np.testing.assert_allclose(back.cell, r.cell, atol=1e-14)
        assert back.meta["triclinic"] == "general"
    res = r.to_restricted()
    assert res.is_restricted_triclinic()
    np.testing.assert_allclose(res.cell, cfg.cell, atol=1e-13)
    np.testing.assert_allclose(res.positions, cfg.positions, atol=1e-13)
    a, b = res.network(tolerance=0.0), cfg.network(tolerance=0.0)
    np.testing.assert_array_equal(a.pairs, b.pairs)


@pytest.mark.parametrize("name", ["x.npz", "x.csv", "x.vtu", "D3d"])
def test_2d_only_formats_refuse_3d(tmp_path, name):
    cfg = io.read(DATA / "sph3d_ortho.data")
    with pytest.raises(ValueError, match="3D configuration can be written as lammps-data or "
                                         "lammps-dump only"):
        io.write(tmp_path / name, cfg)
    assert not (tmp_path / name).exists()
