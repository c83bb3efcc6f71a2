"""The corpus's dem_fixedphi protocol (studies.corpus): LAMMPS's in.prep protocol run by our own
engine: fixed-rate compression with the box side linear in time, to the target solid fraction
exactly, then relaxation at fixed box; read back as the LAMMPS rows are (normal forces from the
overlaps, no tangential forces, no sliding contacts)."""
import numpy as np
import pytest


def test_linear_box_control_is_fix_deform_final():
    """``fix deform ... final``: the box side changes by rate * dt at every step, whatever the side
    (the engine maps h -> (I + dt L) h with L = rate / L_current)."""
    from studies.corpus import _LinearBox
    from types import SimpleNamespace
    c = _LinearBox(-0.01)
    for side in (50.0, 37.5):
        st = SimpleNamespace(h=np.diag([side, side]))
        L = c.update(st, 0.0, 0.0, 0.2)
        h1 = (np.eye(2) + 0.2 * L) @ st.h
        assert h1[0, 0] - side == pytest.approx(-0.01 * 0.2, rel=1e-12) and h1[0, 1] == 0.0
    assert c.to_meta() == {"kind": "linear_box", "rate": -0.01}


def test_fixedphi_packing_reaches_its_solid_fraction_and_rests(tmp_path):
    from studies.corpus import FIXEDPHI, _row, build_network
    row = _row("dem_fixedphi", 200, 1, phi=0.85, dispersity=0.2)
    net, meta = build_network(row, tmp_path)
    phi = np.sum(np.pi * net.radii ** 2) / net.area
    assert phi == pytest.approx(0.85, rel=1e-12)
    assert meta["relaxed"] and meta["ke_per_particle"] < FIXEDPHI["kestop"]
    assert meta["steps_relax"] <= FIXEDPHI["nrelax"]
    # read back as LAMMPS rows: fn = kn * overlap, no tangential force, nothing sliding
    np.testing.assert_allclose(net.fn, net.overlaps, rtol=0, atol=0)
    assert not net.ft.any() and not net.sliding.any() and (net.overlaps > 0).all()
    # at rest in the engine (normal and tangential forces): Yade's unbalanced force ratio; the
    # normal forces alone, as read back, do not balance (the tangential forces are dropped, as
    # LAMMPS's are): their mean resultant is a sizeable fraction of the mean contact force
    assert meta["engine_unbalanced"] < 1e-4
    f = net.fn[:, None] * net.normals
    res = np.zeros((net.n_particles, 2))
    np.add.at(res, net.pairs[:, 0], -f)
    np.add.at(res, net.pairs[:, 1], f)
    assert np.mean(np.hypot(*res.T)) > 0.1 * net.fn.mean()
    # the pressure the engine measured equals the one of the network (same contacts, same law)
    p = np.sum(net.fn * np.hypot(*net.branch.T)) / (2 * net.area)
    assert p == pytest.approx(meta["engine_p_over_kn"], rel=1e-9)
    again, _ = build_network(row, tmp_path)
    np.testing.assert_array_equal(again.positions, net.positions)
