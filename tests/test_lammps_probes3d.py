"""LAMMPS's own strain probes on a 3D packing against the exact tensor (studies.lammps_probes3d).

A small packing made by the project's 3D LAMMPS deck (80 spheres, pD/kn = 1e-2: LAMMPS runs
about 5 s on one core) is relaxed by LAMMPS to round-off; the six Mandel modes are probed by
LAMMPS (fix deform remap v, damped dynamics, tangential history kept) at +-1e-6, and the (6, 6)
Cauchy stiffness from LAMMPS's pressure tensor is compared with
``stiffness(network, prestress=True, spin_arm="radius")`` of the network read back from LAMMPS
and with ``probe_tangent`` (the same law under the probes' own gradients and stress reading).
The comparison can fail: without the pre-stress terms the two differ by ``prestress_size``
(checked to be far above the agreement). Skipped when ``lmp`` is not on PATH.
"""
import shutil

import numpy as np
import pytest

from dem.engine.packing import PackingProtocol
from microhom.tensors import mandel_to_strain

pytestmark = pytest.mark.skipif(shutil.which("lmp") is None, reason="LAMMPS binary 'lmp' not on PATH")


def _case(tmp_path_factory, mu, mu_prep):
    from studies.lammps_probes3d import compare, lammps_probes, pack_with_restart, relax_base
    folder = tmp_path_factory.mktemp(f"probes3d_mu{mu}")
    proto = PackingProtocol(n=80, p_over_kn=1e-2, kn=1.0, mu=mu, mu_prep=mu_prep, dispersity=0.2, seed=3)
    run, prm, _ = pack_with_restart(proto, folder, max_steps=400_000, timeout=300)
    base, blog = relax_base(folder, prm)
    pr = lammps_probes(folder, prm, blog, amplitudes=(1e-6,))
    return base, pr, compare(base, pr)


@pytest.fixture(scope="module")
def frictional(tmp_path_factory):
    return _case(tmp_path_factory, 0.5, 0.05)


def test_probes_are_converged_and_tangent(frictional):
    base, pr, cmp = frictional
    assert pr.C_mandel.shape == (6, 6) and np.all(np.isfinite(pr.C_mandel))
    assert pr.unbalanced < 1e-10 and pr.residual < 1e-7       # relaxed to round-off
    assert pr.asymmetry < 1e-5 and pr.contact_events == 0       # second order O(a), no contact change
    assert pr.sliding_by_amplitude == {1e-6: 0}
    # LAMMPS's base stress is the network's P_ab = (1/V) sum c_a f_b (compute pressure NULL
    # virial), of which LAMMPS gives the upper triangle; P is not symmetric where the torques
    # balance (LAMMPS's arm is the radius, |c| = r_i + r_j - overlap): sum overlap n x f_t / V
    net = base.network
    f = net.fn[:, None] * net.normals + net.ft
    P = np.einsum("ca,cb->ab", net.branch, f) / abs(np.linalg.det(net.cell))
    upper = np.triu(P) + np.triu(P, 1).T
    assert np.abs(-upper - pr.stress0).max() < 1e-9 * np.abs(P).max()
    skew = np.einsum("c,ca,cb->ab", -(net.radii[net.pairs].sum(axis=1) - net.lengths), net.normals, net.ft)
    np.testing.assert_allclose(P - P.T, (skew - skew.T) / abs(np.linalg.det(net.cell)),
                               rtol=0, atol=1e-6 * np.abs(P - P.T).max())


def test_probes_agree_with_the_exact_tensor(frictional):
    """The probes against the exact probe tangent (LAMMPS's history law under the probes' strains
    and rotations, P read from its upper triangle): to the probes' own accuracy (their +- asymmetry
    is 1e-7), far below the rotation response and the pre-stress terms, which both can make the
    comparison fail. Against the Cauchy tensor of the pure strain: to the order of the tangential
    forces (the rotation response); moduli to 1e-4."""
    _, pr, cmp = frictional
    assert cmp.n_sliding == 0 and cmp.spin_arm == "radius"
    assert cmp.prestress_size > 1e-3
    assert cmp.difference_lammps < 1e-6
    assert cmp.difference_lammps < 0.01 * cmp.rotation_size
    assert cmp.difference < 0.05 * cmp.prestress_size
    assert cmp.difference < 2 * cmp.tangential_scale + 1e-6
    assert cmp.K_probes == pytest.approx(cmp.K_exact, rel=1e-4)
    assert cmp.G_probes == pytest.approx(cmp.G_exact, rel=1e-4)


def test_shear_probe_is_upper_triangular_with_the_strain_as_symmetric_part():
    """LAMMPS's restricted triclinic box takes upper-triangular displacement gradients: the deck
    applies L with sym(L) = E (the rotation W = L - E is removed from the stress)."""
    from studies.lammps_probes3d import _probe_deck
    prm = dict(kn=1.0, kt=1.0, mu=0.5, m1=1.0, skin=0.1, dt=0.1)
    deck = _probe_deck(prm, 5, 1e-6, 100, "")                  # Mandel sqrt2 xy
    E = mandel_to_strain(1e-6 * np.eye(6)[5])
    assert f"variable        L01 equal {float(2 * E[0, 1])!r}" in deck
    assert "variable        L00 equal 0.0" in deck and "remap v" in deck
    with pytest.raises(ValueError, match="amplitudes"):
        from studies.lammps_probes3d import lammps_probes
        lammps_probes(".", prm, {}, amplitudes=(0.1,))
