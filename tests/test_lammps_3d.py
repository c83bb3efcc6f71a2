"""A 3D packing made by LAMMPS (dem.engine.lammps.write_inputs(..., dimension=3): isotropic
compression of frictional spheres, gran/hooke/history, fix nve/sphere, a pressure servo on the
periodic box, then relaxation at mu_prep and mu), read back as a 3D network with LAMMPS's own
contact forces, and checked against LAMMPS's computes: the contact count (compute contact/atom),
the stress (compute pressure NULL virial, printed with 17 digits) and the normal forces (compute
pair/local); then the exact stiffness of the network runs.

300 spheres: about 6 s of LAMMPS on one core. Skipped when ``lmp`` is not on PATH."""
import shutil

import numpy as np
import pytest

from dem.analysis.stiffness import stiffness
from dem.engine.lammps import pack_lammps, read_run, write_inputs
from dem.engine.packing import PackingProtocol

pytestmark = pytest.mark.skipif(shutil.which("lmp") is None, reason="LAMMPS binary 'lmp' not on PATH")

N = 300
PROTO = PackingProtocol(n=N, p_over_kn=1e-3, kn=1.0, mu=0.5, mu_prep=0.05, dispersity=0.2, seed=1)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lammps3d")
    return pack_lammps(PROTO, folder, np=1, timeout=300, max_steps=200_000, dimension=3)


def test_packing_is_3d_and_converged(run):
    res = run.lammps
    assert run.config.dim == 3 and run.network.positions.shape == (N, 3)
    assert run.network.cell.shape == (3, 3) and run.network.ft.shape == (len(run.network.pairs), 3)
    assert res["N"] == N and res["converged"] == 1.0
    # target pressure p_over_kn kn / (2 radius) [Pa] within the protocol's tol_p
    assert res["pressure"] == pytest.approx(1e-3 * 1.0 / (2 * 0.5), rel=PROTO.tol_p)
    assert [ph["name"] for ph in run.phases] == ["compact", "prep", "test"]
    # a jammed frictional sphere packing: between the frictional (4) and frictionless (6)
    # isostatic coordination, counting its rattlers in
    assert 4.0 < res["Z"] < 6.5 and 0.55 < res["phi"] < 0.66
    v = np.linalg.det(run.network.cell)
    assert v == pytest.approx(res["lx"] * res["ly"] * res["lz"], rel=1e-14)
    phi = 4 / 3 * np.pi * np.sum(run.config.radii ** 3) / v
    assert phi == pytest.approx(res["phi"], rel=1e-13)


def test_contacts_match_lammps(run):
    net = run.network
    assert 2 * len(net.pairs) == round(run.lammps["Z"] * N)        # compute contact/atom, summed
    deg = np.bincount(net.pairs.ravel(), minlength=N)
    np.testing.assert_array_equal(deg, run.config.fields["c_cn"].astype(int))


def test_read_run_from_the_folder_alone(run):
    """read_run without the writer's parameters: the header comment says dimension=3."""
    back = read_run(run.folder)
    assert back.params["dimension"] == 3 and back.config.dim == 3
    np.testing.assert_array_equal(back.network.pairs, run.network.pairs)
    np.testing.assert_array_equal(back.network.ft, run.network.ft)


def test_forces_match_lammps(run):
    net = run.network
    scale = np.abs(net.fn).max()
    # normal forces kn * overlap from the positions against compute pair/local's (dashpots idle)
    np.testing.assert_allclose(net.fn, run.contacts["force"], rtol=0, atol=1e-12 * scale)
    # LAMMPS's tangential forces are tangential, and Coulomb holds
    assert np.abs(np.einsum("ci,ci->c", net.ft, net.normals)).max() <= 1e-12 * scale
    assert np.all(np.linalg.norm(net.ft, axis=1) <= PROTO.mu * net.fn * (1 + 1e-9))


def test_stress_matches_lammps_pressure(run):
    """P_ab = (1/V) sum_c c_a f_b (f the force on the contact's second sphere, c = x_j - x_i):
    LAMMPS's virial pressure tensor; the project's tension-positive stress is -P^T and the scalar
    pressure (P_xx + P_yy + P_zz)/3 = -tr(sigma)/3."""
    net, res = run.network, run.lammps
    f = net.fn[:, None] * net.normals + net.ft
    P = np.einsum("ca,cb->ab", net.branch, f) / np.linalg.det(net.cell)
    p = res["pressure"]
    # the virial is summed over pairs in another order: agreement to round-off of p
    for (a, b), name in {(0, 0): "pxx", (1, 1): "pyy", (2, 2): "pzz", (0, 1): "pxy",
                         (0, 2): "pxz", (1, 2): "pyz"}.items():
        assert P[a, b] == pytest.approx(res[name], rel=0, abs=1e-12 * p), name
    assert np.trace(P) / 3 == pytest.approx(p, rel=1e-12)
    # the asymmetric part: the unbalanced torques of a relaxed packing, small but not zero
    assert np.abs(P - P.T).max() < 1e-4 * p


def test_exact_stiffness_runs(run):
    r = stiffness(run.network)
    assert r.C_mandel.shape == (6, 6) and np.all(np.isfinite(r.C_mandel))
    assert r.n_unstable == 0 and "unstable" not in " ".join(r.flags)
    assert 0 < r.K <= r.K_affine and 0 < r.G <= r.G_affine     # relaxation only softens
    assert np.linalg.eigvalsh(0.5 * (r.C_mandel + r.C_mandel.T)).min() > 0
    # the servo's affine stiffness dp/d(linear strain) = kn sum_c |l_c|^2 / (d V) (the input
    # estimates sum |l|^2 by Nc <l^2>) is d times the affine bulk modulus of the exact solver
    net = run.network
    keep = ~r.rattler_mask[net.pairs].any(axis=1)
    servo_K = PROTO.kn * np.sum(net.lengths[keep] ** 2) / (3 * np.linalg.det(net.cell))
    assert 3 * r.K_affine == pytest.approx(servo_K, rel=1e-12)
    pre = stiffness(run.network, prestress=True)
    assert np.isfinite(pre.K) and np.isfinite(pre.G)
    assert abs(pre.K - r.K) < 0.05 * r.K          # pre-stress terms are O(p/kn) corrections


def test_dimension_is_checked(tmp_path):
    with pytest.raises(ValueError, match="dimension must be 2"):
        write_inputs(tmp_path, PROTO, dimension=4)
    with pytest.raises(ValueError, match="jam_z must be in \\[0, 12\\)"):
        write_inputs(tmp_path, PROTO, dimension=3, jam_z=12)
    with pytest.raises(ValueError, match="gas_overlaps must be True"):
        write_inputs(tmp_path, PackingProtocol(n=50, gas_overlaps=False, phi0=0.2), dimension=3)


def test_2d_deck_has_no_3d_lines(tmp_path):
    """The shared deck: the 2D input keeps its 2D lines, the 3D one has none of them."""
    two = write_inputs(tmp_path / "2d", PROTO)
    three = write_inputs(tmp_path / "3d", PROTO, dimension=3)
    t2 = (tmp_path / "2d" / "in.packing").read_text()
    t3 = (tmp_path / "3d" / "in.packing").read_text()
    assert "dimension       2" in t2 and "enforce2d" in t2 and "density/disc" in t2
    assert "dimension       3" in t3 and "enforce2d" not in t3 and "disc" not in t3
    assert "z variable v_dlz v_vlz" in t3 and "lz" not in t2
    assert two["dimension"] == 2 and three["dimension"] == 3
    assert len(t2.splitlines()) + 12 > len(t3.splitlines())   # same deck, a few lines more


def test_time_step_bound_on_contacts():
    """The 3D time step counts at most 2 / (1 - cos theta) touching smallest spheres: 14 for
    identical spheres (kissing number 12, never exceeded), more for a larger sphere; the bound
    holds on the densest arrangement, FCC, where each sphere has 12 touching neighbours."""
    from dem.engine.lammps import _possible_contacts_3d
    from microhom.lattices import fcc
    assert _possible_contacts_3d(np.ones(5)).tolist() == [14.0] * 5
    big = _possible_contacts_3d(np.array([0.5, 0.5, 1.0]))
    assert big[2] > big[0] == 14
    net = fcc(2, diameter=1.0, kn=1.0, kt=1.0)
    assert np.bincount(net.pairs.ravel()).max() == 12 <= 14
