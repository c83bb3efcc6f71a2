"""The spin-arm convention (issue 27 (e)): ``spin_arm="contact"`` turns spins about the contact
point (arms |c| r_i/(r_i + r_j)), ``"radius"`` about the radius (LAMMPS gran/*). Closed forms:
the relative displacement of the two surface points under equal spins, and the two-disk
stiffness; and ``dem analyse`` matches the convention to the file's code."""
import numpy as np
import pytest

from microhom.kinematics import SPIN_ARMS, contact_matrices
from microhom.network import from_overlaps


def pair(ri=0.5, rj=0.3, overlap=0.04, angle=0.3):
    """Two overlapping disks in a large open box, branch at ``angle``."""
    L = ri + rj - overlap
    n = np.array([np.cos(angle), np.sin(angle)])
    pos = np.array([[1.0, 1.0], [1.0, 1.0] + L * n])
    return from_overlaps(pos, np.array([ri, rj]), None, kn=3.0, kt=2.0), n, L


@pytest.mark.parametrize("spin_arm", SPIN_ARMS)
def test_equal_spins_move_the_surface_points_apart_by_the_arm_sum(spin_arm):
    """Both disks spin by w: the point of i at x_i + a_i n moves by w a_i t, that of j at
    x_j - a_j n by -w a_j t, so Delta = -w (a_i + a_j) t with a the arms of the convention:
    r_i + r_j for "radius", |c| for "contact" (geometry by hand, not the code's formula)."""
    ri, rj = 0.5, 0.3
    net, n, L = pair(ri, rj)
    t = np.array([-n[1], n[0]])
    w = 0.7
    q = np.array([0.0, 0.0, w, 0.0, 0.0, w])       # (u_i, w_i, u_j, w_j)
    delta = contact_matrices(net, spin_arm=spin_arm).B[0] @ q
    arms = ri + rj if spin_arm == "radius" else L
    assert np.allclose(delta, -w * arms * t, rtol=0, atol=1e-15)


def test_one_spin_moves_its_point_by_its_arm():
    """Only i spins, by 1: Delta = -a_i t, with a_i = r_i (radius) or |c| r_i / (r_i + r_j)
    (contact); rolling, w_i a_i = -w_j a_j, slips in neither (the arms are proportional)."""
    ri, rj = 0.5, 0.3
    net, n, L = pair(ri, rj)
    t = np.array([-n[1], n[0]])
    for arm, ai in {"radius": ri, "contact": L * ri / (ri + rj)}.items():
        B = contact_matrices(net, spin_arm=arm).B[0]
        assert np.allclose(B @ [0, 0, 1.0, 0, 0, 0], -ai * t, rtol=0, atol=1e-15)
        assert np.allclose(B @ [0, 0, 1 / ri, 0, 0, -1 / rj], 0.0, atol=1e-14)


def test_touching_disks_agree_and_bad_value_named():
    """|c| = r_i + r_j: both conventions give the same B (to round-off); a bad name is refused."""
    net, _, _ = pair(overlap=0.0)
    a = contact_matrices(net, spin_arm="contact").B
    b = contact_matrices(net, spin_arm="radius").B
    assert np.allclose(a, b, rtol=1e-14, atol=1e-15)
    with pytest.raises(ValueError, match="spin_arm must be one of"):
        contact_matrices(net, spin_arm="centre")


def test_exact_stiffness_differs_by_the_overlap_and_lammps_files_use_radius(tmp_path):
    """On an overlapping triangular lattice the two conventions differ (spins relax the
    tangential springs differently) but by a small amount; 'dem analyse' on a LAMMPS file uses
    the radius by default and says so, and --spin-arm contact reproduces stiffness()'s default."""
    from dem import io
    from dem.analysis.analyse import analyse_file
    from dem.analysis.stiffness import stiffness
    from microhom import lattices

    lat = lattices.triangular(6, 6)
    rng = np.random.default_rng(3)
    pos = lat.positions + rng.normal(scale=0.01, size=lat.positions.shape)
    net = from_overlaps(pos, 0.5 * 1.02, lat.cell, kn=1.0, kt=0.5)
    c = stiffness(net, spin_arm="contact")
    r = stiffness(net, spin_arm="radius")
    assert abs(r.G - c.G) / c.G > 1e-8 and abs(r.G - c.G) / c.G < 0.05
    path = tmp_path / "lat.dump"
    io.write(path, io.Configuration(positions=pos, radii=0.5 * 1.02, cell=lat.cell))
    res = analyse_file(path, kn=1.0, kt=0.5, hierarchy=False)
    assert res.file.spin_arm == "radius"
    assert any("spin arms of the exact stiffness: 'radius'" in s for s in res.notes)
    assert res.stiffness.G == pytest.approx(r.G, rel=1e-9)
    res2 = analyse_file(path, kn=1.0, kt=0.5, hierarchy=False, spin_arm="contact")
    assert res2.stiffness.G == pytest.approx(c.G, rel=1e-9)
