"""Strain probes (DEM) against the exact linear response: two independent routes to one tensor."""
import math

import numpy as np
import pytest

from dem.contact_laws import LinearFriction
from dem.integrate import Simulation
from dem.packing import network_from_state, pack
from dem.probes import strain_probes
from dem.state import State
from dem.stiffness import stiffness
from microhom import lattices


def compressed_lattice(overlap=1e-3, n=10):
    lat = lattices.triangular(n, n)
    s = 1.0 - overlap
    return State.from_disks(lat.positions * s, np.full(lat.n_particles, 0.5), lat.cell * s,
                            rho=1 / (np.pi * 0.25), spins=True)


def test_triangular_lattice_probe_matches_exact_with_prestress():
    st = compressed_lattice()
    law = LinearFriction(kn=1.0, kt=0.5, mu=10.0)
    probe = strain_probes(st, law, amplitude=1e-7)
    assert probe.converged
    sim = Simulation(st.copy(), law)
    sim.run(1)
    exact = stiffness(network_from_state(sim.state, law), prestress=True)
    assert np.allclose(probe.C_mandel, exact.C_mandel, rtol=0, atol=1e-5)
    # and the unstressed closed form to O(p/kn)
    assert probe.K == pytest.approx(math.sqrt(3) / 2, rel=5e-3)  # pre-stress shifts of order p/kn = 1.7e-3
    assert probe.G == pytest.approx(math.sqrt(3) / 4 * 1.5, rel=5e-3)  # pre-stress shifts of order p/kn = 1.7e-3


def test_zero_amplitude_refused():
    with pytest.raises(ValueError, match="amplitude"):
        strain_probes(compressed_lattice(), LinearFriction(kn=1.0, kt=1.0, mu=0.5), amplitude=0.0)


def _packing_agreement(n, seed, rel):
    res = pack(n, p_over_kn=1e-4, kn=1.0, kt=1.0, mu=0.488, mu_prep=0.02, seed=seed)
    exact = stiffness(res.to_network(), prestress=True)
    probe = strain_probes(res.state, res.law)
    assert probe.converged
    assert probe.K == pytest.approx(exact.K, rel=rel)
    assert probe.G == pytest.approx(exact.G, rel=rel)
    assert np.allclose(probe.C_mandel, exact.C_mandel, atol=rel * exact.K)
    return probe, exact


def test_probe_agrees_with_exact_on_a_frictional_packing():
    probe, _ = _packing_agreement(300, seed=3, rel=1e-4)
    assert probe.contact_events == 0


def test_probe_agrees_with_exact_on_4000_disks():  # ~30 s: the criterion, run in CI
    probe, exact = _packing_agreement(4000, seed=1, rel=1e-2)  # the criterion: within 1 %
    assert abs(probe.G / exact.G - 1) < 1e-2 and abs(probe.K / exact.K - 1) < 1e-2
    print(probe.summary(), exact.summary())


def test_large_probe_reports_contact_events():
    res = pack(300, p_over_kn=1e-4, kn=1.0, kt=1.0, mu=0.488, mu_prep=0.02, seed=3)
    big = strain_probes(res.state, res.law, amplitude=1e-5, tol_unbalanced=1e-8)
    assert big.contact_events > 0  # contacts open/close: the response is no longer the tangent
