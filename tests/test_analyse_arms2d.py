"""``dem analyse`` on a 2D LAMMPS file: the hierarchy takes the exact solver's spin arms (issue 26),
so the exact tensor lies in the interval the report prints.

A compressed, jittered, polydisperse triangular packing of 64 disks (overlaps about 4 % of D, so
the radius arms of LAMMPS differ from the contact arms) written as a LAMMPS dump: the file's arms are
the radius arms. With contact arms in the hierarchy (the former 2D report) the interval of G
missed the radius-arm exact G (which differs from the contact-arm G by more than three widths of it); the check below would catch it."""
import warnings

import numpy as np

from dem import io as dio
from dem.analysis.analyse import analyse_file
from microhom import lattices


def _contains(est, value):
    return est.lower <= value <= est.upper


def test_the_2d_hierarchy_uses_the_file_arms(tmp_path):
    rng = np.random.default_rng(1)
    lat = lattices.triangular(8, 8, diameter=1.0)
    x = lat.positions * 0.96 + rng.normal(0, 0.02, lat.positions.shape)
    r = rng.uniform(0.48, 0.52, lat.n_particles)
    f = tmp_path / "tri2d.dump"
    dio.write_lammps_dump(f, dio.Configuration(positions=x, radii=r, cell=lat.cell * 0.96), timestep=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rad = analyse_file(f, kn=1.0, kt=0.5)
        con = analyse_file(f, kn=1.0, kt=0.5, spin_arm="contact")
    assert rad.file.spin_arm == "radius" and con.file.spin_arm == "contact"
    for res in (rad, con):
        h, s = res.hierarchy, res.stiffness
        assert h.certified and _contains(h.K, s.K) and _contains(h.G, s.G)
    assert any("the hierarchy uses the same arms" in n for n in rad.notes)
    # the arms matter here: the contact-arm interval does not hold the radius-arm exact G
    assert not _contains(con.hierarchy.G, rad.stiffness.G)
    assert abs(rad.stiffness.G - con.stiffness.G) > 3 * (con.hierarchy.G.upper - con.hierarchy.G.lower)
