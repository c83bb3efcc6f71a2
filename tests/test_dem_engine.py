"""DEM engine checks against closed forms (two-disk collisions, Coulomb, rolling, lattices) and
invariances (momentum, energy, rigid rotation, periodic images, restart, reproducibility)."""
import math

import numpy as np
import pytest

from dem.engine.cell import PressureServo, rotation
from dem.engine.contact_laws import Frictionless, LinearFriction, HertzMindlin, damping_ratio
from dem.engine.integrate import Guard, InstabilityError, Loop, Simulation, critical_dt
from dem.engine.neighbors import rebuild
from dem.engine.state import State
from microhom import lattices
from microhom.network import from_overlaps

R = 0.5
RHO = 1.0 / (np.pi * R * R)  # a disk of radius 0.5 has mass 1


def two_disks(gap=1e-3, v=1.0, spins=False):
    st = State.from_disks([[5.0, 5.0], [5.0 + 2 * R + gap, 5.0]], R, np.diag([20.0, 20.0]), rho=RHO,
                          spins=spins)
    st.v[0] = [v, 0.0]
    st.v[1] = [-v, 0.0]
    return st


def perturbed_lattice(nx=10, ny=10, seed=1, spread=0.05, squeeze=0.98, frictional=True):
    """Triangular lattice squeezed to overlap, positions and radii randomly perturbed."""
    rng = np.random.default_rng(seed)
    net = lattices.triangular(nx, ny, diameter=1.0)
    x = net.positions * squeeze + rng.uniform(-spread, spread, net.positions.shape)
    r = R * (1 + rng.uniform(-spread, spread, net.n_particles))
    st = State.from_disks(x, r, net.cell * squeeze, rho=RHO, spins=frictional)
    return st


# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("law", [Frictionless(kn=1e4), LinearFriction(kn=1e4, kt=1e4, mu=0.5)])
def test_two_disk_impact_duration_elastic(law):
    st = two_disks()
    meff = 0.5
    tc = math.pi * math.sqrt(meff / law.kn)
    dt = tc / 2000
    sim = Simulation(st, law, damping=0.0, dt=dt)
    steps_in_contact = 0
    for _ in range(6000):
        sim.step()
        steps_in_contact += sim.out[4] > 0
    # force first computed at the step after overlap starts: duration resolved to one step
    assert abs(steps_in_contact * dt - tc) <= 1.01 * dt
    assert np.allclose(st.v[:, 0], [-1.0, 1.0], rtol=0, atol=2e-3)


@pytest.mark.parametrize("e", [0.9, 0.5, 0.1])
def test_two_disk_restitution(e):
    kn = 1e4
    st = two_disks(v=0.7)
    zeta = damping_ratio(e)
    assert math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2)) == pytest.approx(e, rel=1e-12)
    td = math.pi * math.sqrt(0.5 / kn) / math.sqrt(1 - zeta ** 2)
    sim = Simulation(st, Frictionless(kn=kn, restitution=e), damping=0.0, dt=td / 4000)
    n_in = 0
    for _ in range(12000):
        sim.step()
        n_in += sim.out[4] > 0
    assert st.v[1, 0] / 0.7 == pytest.approx(e, rel=2e-3)
    assert st.v[0, 0] == pytest.approx(-st.v[1, 0], rel=1e-12)
    assert n_in * sim.dt == pytest.approx(td, abs=1.01 * sim.dt)


def test_tangential_spring_then_coulomb_sliding():
    kn, kt, mu = 1e4, 5e3, 0.3
    overlap = 1e-3
    st = State.from_disks([[5.0, 5.0], [5.0 + 2 * R - overlap, 5.0]], R, np.diag([20.0, 20.0]),
                          rho=RHO, spins=True)
    sim = Simulation(st, LinearFriction(kn=kn, kt=kt, mu=mu), damping=0.0)
    u_dot = 1e-3
    st.v[1] = [0.0, u_dot]  # j slides along +y (~ +t)
    dt = sim.dt
    u = 0.0  # accumulated tangential displacement of j relative to i, along t
    slid = False
    for _ in range(400):
        l = st.x[1] - st.x[0]
        d = np.hypot(*l)
        n = l / d
        t = np.array([-n[1], n[0]])
        u += (st.v[1] @ t) * dt
        fn = kn * (2 * R - d)
        sim.compute_forces()
        ft = st.nl_ft[0]
        if kt * u < mu * fn * (1 - 1e-9):
            assert ft == pytest.approx(-kt * u, rel=1e-9)  # elastic tangential spring
            assert not slid
        else:
            slid = True
            assert ft == pytest.approx(-mu * fn, rel=1e-12)  # Coulomb limit
        assert sim.f[1] @ t == pytest.approx(ft, rel=1e-12, abs=1e-15)  # F_j . t = ft
        assert sim.f[1] @ n == pytest.approx(fn, rel=1e-9)
        st.x[1, 1] += u_dot * dt
    assert slid


@pytest.mark.parametrize("arms", [True, False])
@pytest.mark.parametrize("roll", [True, False])
def test_rolling_disk_on_disk_no_slip(roll, arms):
    """Disk j orbits disk i (fixed) at rate W with the spin that makes its contact point still
    relative to i's (radii equal): W rr / a_j with the arm a_j = rr / 2 (contact_arms, spin exactly
    2 W) or a_j = R (radius arms); the tangential spring never loads. Without the spin it does."""
    kn, kt, mu = 1e4, 1e4, 1e3  # mu large: no Coulomb cap
    overlap = 1e-3
    c = np.array([5.0, 5.0])
    rr = 2 * R - overlap
    st = State.from_disks([c, c + [rr, 0.0]], R, np.diag([20.0, 20.0]), rho=RHO, spins=True)
    sim = Simulation(st, LinearFriction(kn=kn, kt=kt, mu=mu, contact_arms=arms), damping=0.0)
    arm = rr / 2 if arms else R
    W = 0.05
    dt = sim.dt
    phi = 0.0
    for _ in range(300):
        st.x[1] = c + rr * np.array([math.cos(phi), math.sin(phi)])
        st.v[1] = rr * W * np.array([-math.sin(phi), math.cos(phi)])
        st.omega[1] = W * rr / arm if roll else 0.0
        sim.compute_forces()
        n = (st.x[1] - st.x[0]) / rr
        t = np.array([-n[1], n[0]])
        vt = (st.v[1] - st.v[0]) @ t - (st.omega[0] * arm + st.omega[1] * arm)
        if roll:
            assert abs(vt) < 1e-14
            assert abs(st.nl_ft[0]) < 1e-12
        phi += W * dt
    if not roll:
        # history = -kt * accumulated slip, slip = rr W per unit time
        assert st.nl_ft[0] == pytest.approx(-kt * rr * W * 300 * dt, rel=1e-9)


def test_momentum_conserved_undamped_frictional():
    st = perturbed_lattice()
    rng = np.random.default_rng(3)
    st.v[:] = rng.normal(0, 1e-2, st.v.shape)
    st.omega[:] = rng.normal(0, 1e-2, st.n)
    sim = Simulation(st, LinearFriction(kn=1e4, kt=1e4, mu=0.3), damping=0.0)
    p0 = (st.mass[:, None] * st.v).sum(0)
    scale = (st.mass[:, None] * np.abs(st.v)).sum()
    sim.run(2000)
    p1 = (st.mass[:, None] * st.v).sum(0)
    assert np.abs(p1 - p0).max() < 1e-13 * scale + 1e-15
    assert sim.measure()["n_contacts"] > 0


def test_energy_drift_frictionless_default_dt():
    """Undamped frictionless dynamics at the default dt: no drift of the (synchronised) total
    energy over 1e4 steps (window means compared; leapfrog fluctuations average out)."""
    net = lattices.triangular(8, 8, diameter=1.0)
    sq = 0.99
    rng = np.random.default_rng(5)
    st = State.from_disks(net.positions * sq, R, net.cell * sq, rho=RHO)
    st.v[:] = rng.normal(0, 1e-3, st.v.shape)  # amplitude ~1e-5 d << overlap 1e-2 d: contacts persist
    sim = Simulation(st, Frictionless(kn=1e4), damping=0.0)
    assert sim.dt == pytest.approx(0.8 * critical_dt(st, sim.law))
    E = np.empty(10000)
    for k in range(10000):
        sim.step()
        E[k] = sim.energy_n
    drift = abs(E[-1000:].mean() - E[:1000].mean()) / E.mean()
    assert drift < 1e-6
    assert E.std() / E.mean() < 1e-3


def test_triangular_lattice_pressure_closed_form_and_rotation():
    kn = 1e4
    d = 1.0
    net = lattices.triangular(6, 6, diameter=d)
    sq = 0.995
    a = d * sq
    delta = d - a
    st = State.from_disks(net.positions * sq, d / 2, net.cell * sq, rho=RHO, spins=True)
    sim = Simulation(st, LinearFriction(kn=kn, kt=kn, mu=0.5), damping=0.0)
    m = sim.refresh()
    assert m["n_contacts"] == 3 * st.n
    assert m["unbalanced"] < 1e-12
    p_exact = math.sqrt(3) * kn * delta / a  # sigma = -(sqrt 3 fn / a) I
    assert m["pressure"] == pytest.approx(p_exact, rel=1e-12)
    assert np.allclose(m["stress"], -p_exact * np.eye(2), rtol=0, atol=1e-12 * p_exact)

    # anisotropic squeeze, then a rigid rotation of the whole cell: same contact forces, rotated stress
    x0 = net.positions * [0.995, 0.99]
    h0 = net.cell * np.array([[0.995], [0.99]])
    s1 = State.from_disks(x0, d / 2, h0, rho=RHO, spins=True)
    sim1 = Simulation(s1, LinearFriction(kn=kn, kt=kn, mu=0.5), damping=0.0)
    m1 = sim1.refresh()
    Q = rotation(0.37)
    s2 = State.from_disks(x0 @ Q.T, d / 2, Q @ h0, rho=RHO, spins=True)
    sim2 = Simulation(s2, LinearFriction(kn=kn, kt=kn, mu=0.5), damping=0.0)
    m2 = sim2.refresh()
    assert m2["n_contacts"] == m1["n_contacts"]
    f1 = np.sort(np.hypot(*sim1.f.T))
    f2 = np.sort(np.hypot(*sim2.f.T))
    assert np.allclose(f1, f2, rtol=0, atol=1e-9 * kn * 0.01)
    assert np.allclose(m2["stress"], Q @ m1["stress"] @ Q.T, rtol=1e-10, atol=1e-10 * m1["pressure"])
    assert m2["pressure"] == pytest.approx(m1["pressure"], rel=1e-12)


def test_verlet_list_matches_brute_force_in_sheared_cell():
    st = perturbed_lattice(12, 12, seed=7)
    h = st.h.copy()
    h[0, 1] = 0.3 * h[0, 0]  # sheared cell: shift the second cell vector
    st.h = h
    st.x = st.x + (st.x[:, 1:2] / st.h[1, 1]) * np.array([h[0, 1], 0.0])
    sim = Simulation(st, Frictionless(kn=1.0), damping=0.0)
    sim.refresh()
    net = from_overlaps(st.x, st.radius, st.h, tolerance=0.0)
    gap = net.lengths < (st.radius[net.pairs[:, 0]] + st.radius[net.pairs[:, 1]])
    assert sim.measure()["n_contacts"] == int(gap.sum())
    # the list holds every pair within r_i + r_j + skin
    net_s = from_overlaps(st.x, st.radius + sim.skin / 2, st.h, tolerance=0.0)
    assert st.nl_i.shape[0] == net_s.n_contacts


def test_periodic_images_translation_invariance():
    st = perturbed_lattice(seed=11)
    rng = np.random.default_rng(2)
    st2 = st.copy()
    k = rng.integers(-2, 3, size=(st.n, 2))
    st2.x = st.x + k @ st.h.T  # every particle moved by its own integer combination of cell vectors
    st3 = st.copy()
    st3.x = st.x + st.h[:, 0]  # whole packing translated by a cell vector
    law = LinearFriction(kn=1e4, kt=1e4, mu=0.5)
    ms = []
    for s in (st, st2, st3):
        sim = Simulation(s, law, damping=0.0)
        sim.run(50)
        ms.append(sim.measure())
    for m in ms[1:]:
        assert m["n_contacts"] == ms[0]["n_contacts"]
        assert np.allclose(m["stress"], ms[0]["stress"], rtol=1e-9, atol=1e-9 * abs(ms[0]["pressure"]))


def test_dt_above_stable_refused():
    st = two_disks()
    law = LinearFriction(kn=1e4, kt=1e4, mu=0.5)
    dtc = critical_dt(st, law)
    assert dtc == pytest.approx(math.sqrt(1.0 / (6 * 2e4)))  # 6 possible contacts, max(kn, 2 kt)
    with pytest.raises(ValueError, match=r"dt = .* exceeds .*dt_crit"):
        Simulation(st, law, dt=1.01 * dtc)
    Simulation(st, law, dt=dtc)  # at the limit: allowed


def test_instability_guard_keeps_last_good_state(tmp_path):
    st = perturbed_lattice(frictional=False)
    law = Frictionless(kn=1e4)
    dtc = critical_dt(st, law)
    sim = Simulation(st, law, dt=2.5 * dtc, damping=0.0,
                     guard=Guard(unsafe_dt=True, check_every=20, failure_path=tmp_path / "last_good.npz"))
    with pytest.raises(InstabilityError) as ei:
        sim.run(20000)
    err = ei.value
    assert "kinetic energy blow-up" in err.reason or "NaN" in err.reason
    assert err.state is not None and err.state.step < err.step
    assert np.isfinite(err.state.x).all()
    assert (tmp_path / "last_good.npz").exists()


def test_checkpoint_restart_bit_exact(tmp_path):
    def make():
        st = perturbed_lattice(seed=4)
        st.v[:] = np.random.default_rng(9).normal(0, 1e-2, st.v.shape)
        ctl = PressureServo(p_target=50.0, max_rate=1e-2)
        return Simulation(st, LinearFriction(kn=1e4, kt=5e3, mu=0.3, restitution=0.8), damping=0.3,
                          control=ctl, loop=Loop(sort_every=3, skin=0.01))
    a = make()
    a.run(900)
    b = make()
    b.run(400)
    b.save(tmp_path / "ck.npz")
    c = Simulation.load(tmp_path / "ck.npz", control=PressureServo(p_target=50.0, max_rate=1e-2))
    c.run(500)
    for name in ("x", "v", "omega", "theta", "h", "L", "nl_ft", "ids"):
        assert np.array_equal(getattr(a.state, name), getattr(c.state, name)), name
    assert a.n_rebuilds == c.n_rebuilds and a.n_rebuilds > 3


def test_same_input_bit_identical_runs():
    out = []
    for _ in range(2):
        st = perturbed_lattice(seed=8)
        sim = Simulation(st, LinearFriction(kn=1e4, kt=1e4, mu=0.5), damping=0.7, loop=Loop(sort_every=2))
        sim.run(300)
        out.append(st)
    assert np.array_equal(out[0].x, out[1].x) and np.array_equal(out[0].nl_ft, out[1].nl_ft)


def test_hertz_two_disk_duration():
    """Hertz impact: duration 2.94324 delta_max / v, delta_max = (5 m_eff v^2 / (4 kh))^(2/5)."""
    kh, v = 1e5, 0.5
    st = two_disks(v=v / 2)
    meff = 0.5
    tc = 2.94324 * (5 * meff * v * v / (4 * kh)) ** 0.4 / v
    law = HertzMindlin(kh=kh, mu=0.5, delta_ref=0.05)
    sim = Simulation(st, law, damping=0.0, dt=tc / 3000)
    n_in = 0
    for _ in range(8000):
        sim.step()
        n_in += sim.out[4] > 0
    assert n_in * sim.dt == pytest.approx(tc, rel=1e-3)
    assert st.v[1, 0] == pytest.approx(v / 2, rel=1e-3)


def test_bad_parameters_named():
    with pytest.raises(ValueError, match="kn"):
        Frictionless(kn=-1.0)
    with pytest.raises(ValueError, match="restitution"):
        LinearFriction(kn=1.0, kt=1.0, mu=0.1, restitution=1.5)
    with pytest.raises(ValueError, match="damping"):
        Simulation(two_disks(), Frictionless(kn=1.0), damping=1.0)
    st = State.from_disks([[0.1, 0.1], [0.5, 0.5]], R, np.eye(2) * 1.05, rho=RHO)
    with pytest.raises(ValueError, match="cell too small"):
        rebuild(st, 0.1)
