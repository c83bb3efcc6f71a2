"""FIRE velocity mixing (dem.engine.fire): the kernel against the formula written with numpy, the quench
on uphill motion, and the alpha schedule of Bitzek et al. (2006)."""
import numpy as np
import pytest

from dem.engine.fire import Fire, fire_mix


def _random(n, seed, spins=True):
    g = np.random.default_rng(seed)
    v, f = g.normal(size=(n, 2)), g.normal(size=(n, 2))
    mass, radius = g.uniform(0.5, 2.0, n), g.uniform(0.4, 0.6, n)
    inertia = 0.5 * mass * radius ** 2
    om, tq = (g.normal(size=n), g.normal(size=n)) if spins else (np.zeros(0), np.zeros(0))
    return v, f, mass, om, tq, inertia, radius


@pytest.mark.parametrize("spins", [True, False])
def test_mixing_matches_the_formula(spins):
    v, f, mass, om, tq, inertia, radius = _random(50, 1, spins)
    f = f + 0.5 * v                                      # make the power positive
    if spins:
        tq = tq + 0.5 * om
    # generalised velocity u = (v, r w) and acceleration a = (F/m, r T/I), numpy
    u = np.concatenate([v.ravel(), radius * om]) if spins else v.ravel()
    acc = np.concatenate([(f / mass[:, None]).ravel(), radius * tq / inertia]) if spins else \
        (f / mass[:, None]).ravel()
    power = np.sum(f * v) + (np.sum(tq * om) if spins else 0.0)
    assert power > 0
    alpha = 0.1
    u_new = (1 - alpha) * u + alpha * np.linalg.norm(u) * acc / np.linalg.norm(acc)
    p = fire_mix(v, f, mass, om, tq, inertia, radius, alpha)
    assert p == pytest.approx(power, rel=1e-12)
    assert np.allclose(v.ravel(), u_new[:100], rtol=0, atol=1e-12)
    if spins:
        assert np.allclose(radius * om, u_new[100:], rtol=0, atol=1e-12)


def test_uphill_motion_is_quenched_and_alpha_zero_is_identity():
    v, f, mass, om, tq, inertia, radius = _random(20, 2)
    f, tq = v + 0.1 * f, om + 0.1 * tq          # downhill: P > 0
    v0, om0 = v.copy(), om.copy()
    p = fire_mix(v, f, mass, om, tq, inertia, radius, 0.0)
    assert p == pytest.approx(np.sum(f * v0) + np.sum(tq * om0)) and p > 0
    assert np.array_equal(v, v0) and np.array_equal(om, om0)         # alpha = 0: unchanged
    assert fire_mix(v, -f, mass, om, -tq, inertia, radius, 0.1) < 0  # uphill: quench
    assert np.all(v == 0) and np.all(om == 0)


class _Sim:   # the attributes Fire.update reads
    def __init__(self, v, f):
        class L:
            needs_spin = False
        self.law = L()
        self.f = f
        self.torque = np.zeros(0)

        class S:
            pass
        self.state = S()
        self.state.v, self.state.omega = v, None
        self.state.mass = np.ones(len(v))
        self.state.inertia = np.ones(len(v))
        self.state.radius = np.ones(len(v))


def test_alpha_schedule_and_reset():
    fire = Fire()
    sim = _Sim(np.ones((4, 2)), np.ones((4, 2)))
    for k in range(8):                    # downhill: alpha decays after n_min steps
        sim.state.v[:] = 1.0
        fire.update(sim)
    assert fire.n_pos == 8 and fire.alpha == pytest.approx(0.1 * 0.99 ** 3)
    sim.state.v[:] = -1.0                 # uphill: quench and reset
    fire.update(sim)
    assert fire.n_pos == 0 and fire.alpha == 0.1 and fire.n_quench == 1 and np.all(sim.state.v == 0)
    assert Fire.from_meta(fire.to_meta()) == fire
    with pytest.raises(ValueError, match="f_alpha"):
        Fire(f_alpha=1.5)
