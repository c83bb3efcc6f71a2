"""Short runs of every contact law of the engine, recorded before the sub-model composition.

``tests/data/law_reference.npz`` holds the positions, velocities, spins, rotations, cell and
tangential history after these runs, computed by the three hand-written kernels of
``dem/engine/contact_laws.py`` (commit 087b653, before the laws were composed from sub-models). The
composed laws must reproduce them bit for bit (``tests/test_contact_laws.py``). Regenerate only
with that old code (``git stash; git checkout 087b653 -- dem``), never with the code under test.
"""
import numpy as np

from dem.engine.cell import PressureServo
from dem.engine.contact_laws import Frictionless, HertzMindlin, LinearFriction
from dem.engine import integrate
from dem.engine.state import State
from microhom import lattices

R = 0.5
RHO = 1.0 / (np.pi * R * R)

CASES = {
    "frictionless": lambda: Frictionless(kn=1e4),
    "frictionless_e": lambda: Frictionless(kn=1e4, restitution=0.6),
    # contact_arms=False: the recorded kernels took the radii as spin arms
    "linear": lambda: LinearFriction(kn=1e4, kt=7e3, mu=0.3, contact_arms=False),
    "linear_e": lambda: LinearFriction(kn=1e4, kt=1e4, mu=0.5, restitution=0.7, contact_arms=False),
    "linear_e_tdamp": lambda: LinearFriction(kn=1e4, kt=1e4, mu=0.5, restitution=0.7,
                                             tangential_damping=True, contact_arms=False),
    "hertz": lambda: HertzMindlin(kh=3e5, mu=0.4, delta_ref=0.02, contact_arms=False),
    "hertz_e": lambda: HertzMindlin(kh=3e5, mu=0.4, delta_ref=0.02, kt_ratio=0.5, restitution=0.5,
                                    contact_arms=False),
}
STEPS = 400
FIELDS = ("x", "v", "omega", "theta", "h", "nl_ft", "ids")


def initial_state(spins, seed=3):
    """Perturbed, squeezed triangular lattice (12 x 12) with random velocities and spins."""
    rng = np.random.default_rng(seed)
    net = lattices.triangular(12, 12, diameter=1.0)
    sq = 0.985
    x = net.positions * sq + rng.uniform(-0.04, 0.04, net.positions.shape)
    r = R * (1 + rng.uniform(-0.08, 0.08, net.n_particles))
    st = State.from_disks(x, r, net.cell * sq, rho=RHO, spins=spins)
    st.v[:] = rng.normal(0, 5e-2, st.v.shape)
    if spins:
        st.omega[:] = rng.normal(0, 1e-1, st.n)
    return st


def simulation(state, law, **kw):
    """``Simulation(state, law, ...)`` with the loop and guard settings given by name: bundled into
    ``Loop`` and ``Guard`` for this engine, flat for the older engines that recorded the runs (so
    that the recording commands above still run)."""
    if hasattr(integrate, "Loop"):
        loop = {k: kw.pop(k) for k in integrate.Loop.names() if k in kw}
        guard = {k: kw.pop(k) for k in integrate.Guard.names() if k in kw}
        kw.update(loop=integrate.Loop(**loop), guard=integrate.Guard(**guard))
    return integrate.Simulation(state, law, **kw)


def run_case(name):
    """Run case ``name`` for STEPS steps (pressure servo, local damping, frequent rebuilds and
    spatial sorts) and return the final state and the last ``out`` vector of the kernel."""
    law = CASES[name]()
    st = initial_state(law.needs_spin)
    sim = simulation(st, law, damping=0.2, skin=0.02, sort_every=3,
                     control=PressureServo(p_target=80.0, max_rate=5e-3))
    sim.run(STEPS)
    return st, sim.out.copy(), sim.n_rebuilds


def record(path, cases=None, run=None, fields=FIELDS):
    """Run every case (default: this module's ``CASES`` with :func:`run_case`) and save the final
    ``fields`` of the state, the last ``out`` and the number of builds to ``path``."""
    cases = CASES if cases is None else cases
    run = run_case if run is None else run
    data = {}
    for name in cases:
        st, out, nreb = run(name)
        for f in fields:
            a = getattr(st, f)
            if a is not None:
                data[f"{name}/{f}"] = a
        data[f"{name}/out"] = out
        data[f"{name}/n_rebuilds"] = np.array(nreb)
    np.savez_compressed(path, **data)


if __name__ == "__main__":
    record("tests/data/law_reference.npz")


def assert_reproduces(reference, name, run, fields=FIELDS):
    """Run case ``name`` with ``run`` and check the final state, ``out`` and the number of builds
    against the recorded ``reference`` (an ``np.load`` of a :func:`record` file), bit for bit."""
    st, out, nreb = run(name)
    assert nreb == int(reference[f"{name}/n_rebuilds"])
    for f in fields:
        key = f"{name}/{f}"
        a = getattr(st, f)
        if key not in reference.files:
            assert a is None, f
            continue
        assert np.array_equal(a, reference[key]), f"{name}: {f} differs from the recorded trajectory"
    assert np.array_equal(out, reference[f"{name}/out"])
