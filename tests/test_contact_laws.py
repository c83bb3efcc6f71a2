"""Contact laws composed from sub-models (dem.engine.contact_models): bit-identity with the hand-written
kernels they replaced, fused against separate integration, history layout, the rolling-resistance
law added as one sub-model, and bad coefficients named."""
import contextlib
import math
from dataclasses import replace

import numpy as np
import pytest

from dem.engine import contact_models as cm
from dem.engine.contact_laws import (ContactLaw, Frictionless, HertzMindlin, HertzRolling, LammpsHookeHistory,
                              LinearFriction, law_from_meta)
from dem.engine.cell import PressureServo
from dem.engine.integrate import Guard, Loop, Simulation, critical_dt
from dem.engine.state import State
import arms_reference_cases as aref
import engine_reference_cases as eref
import law_reference_cases as ref

REF = np.load(__import__("pathlib").Path(__file__).parent / "data" / "law_reference.npz")


def _damping_warned(law):
    """The kernel tests run every law with local damping 0.2 (the damping path is part of what
    they pin bit for bit, and the recorded references were made so). For a LAMMPS-equivalent law
    that leaves LAMMPS's equations, and the engine says so: asserted here, not left to escape."""
    if getattr(law, "LAMMPS_EQUIVALENT", False):
        return pytest.warns(RuntimeWarning, match="LAMMPS has no Cundall local damping")
    return contextlib.nullcontext()


@pytest.mark.parametrize("name", list(ref.CASES))
def test_composed_laws_reproduce_the_old_kernels_bit_for_bit(name):
    ref.assert_reproduces(REF, name, ref.run_case)


@pytest.mark.parametrize("name", ["frictionless_e", "linear_e_tdamp", "hertz_e"])
def test_fused_kick_is_bit_identical_to_the_separate_pass(name):
    """Without a cell control the kick can run inside the force loop: same trajectory, same
    kinetic energy and damping work, bit for bit (local damping on, rebuilds and sorts frequent)."""
    runs = []
    for fuse in (False, True):
        law = ref.CASES[name]()
        st = ref.initial_state(law.needs_spin)
        sim = Simulation(st, law, damping=0.2, loop=Loop(skin=0.02, sort_every=3, fuse=fuse))
        for _ in range(150):
            sim.step()
        runs.append((st, sim.ke_n, sim.damping_work, sim.n_rebuilds))
    (a, kea, wa, na), (b, keb, wb, nb) = runs
    assert na == nb and na > 5
    for f in ("x", "v", "omega", "theta", "nl_ft"):
        assert np.array_equal(getattr(a, f), getattr(b, f)) if getattr(a, f) is not None else getattr(b, f) is None
    assert kea == keb and wa == wb


STRATEGY_LAWS = {
    **{name: make for name, make in ref.CASES.items()},
    "lammps": lambda: LammpsHookeHistory(kn=1e4, kt=8e3, gamma_n=30.0, gamma_t=15.0, mu=0.4),
    "rolling": lambda: HertzRolling(kh=3e5, mu=0.4, delta_ref=0.02, mu_r=0.05, restitution=0.5),
    "massgamma_linear": lambda: ContactLaw(cm.Hooke(1e4), cm.MassGamma(30.0, 15.0), cm.LinearHistory(8e3, 0.4)),
    "linear_arms": lambda: LinearFriction(kn=1e4, kt=7e3, mu=0.3, restitution=0.7, contact_arms=True),
}


@pytest.mark.parametrize("name", list(STRATEGY_LAWS))
@pytest.mark.parametrize("fuse", [False, True])
def test_chunked_and_serial_pair_loops_are_bit_identical(name, fuse, monkeypatch):
    """The vectorised pair loop (chunks, branch-free law, ordered scatter) and the serial one
    give the same bits for every law: under a pressure servo (every step tallied) and without a
    control, with the kick fused or not, through frequent rebuilds and spatial sorts. The list
    length is not a multiple of the chunk, and many listed pairs are not in contact."""
    runs = []
    for loop in (cm.pair_forces_serial, cm.pair_forces_chunked):
        monkeypatch.setattr(cm, "vectorises", lambda models, loop=loop: loop is cm.pair_forces_chunked)
        law = STRATEGY_LAWS[name]()
        st = ref.initial_state(law.needs_spin)
        control = None if fuse else PressureServo(p_target=80.0, max_rate=5e-3)
        with _damping_warned(law):
            sim = Simulation(st, law, damping=0.2, control=control,
                             loop=Loop(skin=0.02, sort_every=3, fuse=fuse))
        for k in range(120):
            sim.step(tally=k % 7 == 0)
        touching = sim.out[4]
        runs.append((st, sim.out.copy(), sim.f.copy(), sim.torque.copy(), sim.ke_n, sim.damping_work))
    (a, oa, fa, ta, kea, wa), (b, ob, fb, tb, keb, wb) = runs
    assert st.nl_i.shape[0] % cm.CHUNK != 0 and 0 < touching < st.nl_i.shape[0]
    for f in ("x", "v", "omega", "theta", "h", "nl_ft"):
        if getattr(a, f) is None:
            assert getattr(b, f) is None
        else:
            assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert np.array_equal(oa, ob) and np.array_equal(fa, fb) and np.array_equal(ta, tb)
    assert (kea == keb or (np.isnan(kea) and np.isnan(keb))) and wa == wb


def test_vectorised_loop_is_chosen_for_all_laws_but_rolling_resistance():
    """Which strategy each law runs (the choice only matters for speed, docs/dem.md)."""
    assert cm.vectorises(LinearFriction(kn=1e4, kt=1e4, mu=0.5, restitution=0.7, tangential_damping=True).models)
    assert cm.vectorises(HertzMindlin(kh=3e5, mu=0.4, delta_ref=0.02, restitution=0.5).models)
    assert cm.vectorises(Frictionless(kn=1e4).models)
    assert cm.vectorises(STRATEGY_LAWS["lammps"]().models)
    assert not cm.vectorises(STRATEGY_LAWS["rolling"]().models)


def _chain_pair(law, overlap=2e-3, r=0.5):
    """Two equal disks on a periodic line, each touching the other on both sides (two contacts,
    static: the normal forces balance)."""
    w = 2 * (2 * r - overlap)
    st = State.from_disks([[w / 4, 2.0], [3 * w / 4, 2.0]], r, np.diag([w, 4.0]), rho=ref.RHO, spins=True)
    return st, Simulation(st, law, damping=0.0, guard=Guard(check_every=0),
                          loop=Loop(skin=0.05, sort_every=0))


def test_rolling_resistance_elastic_closed_form():
    """Counter-rotating disks roll on each other without slip (no tangential load); the relative
    rotation psi = theta_1 - theta_0 oscillates with omega^2 = 4 k_r / I (two contacts),
    k_r = kr_ratio k_n R_eff^2, k_n = 1.5 kh sqrt(delta), amplitude psi'(0) / omega, about
    -psi'(0) dt (the leapfrog start-up advances the history with the spin of step -1/2 at step 0)."""
    kh, overlap, r = 1e5, 2e-3, 0.5
    law = HertzRolling(kh=kh, mu=0.5, delta_ref=overlap, mu_r=10.0, kr_ratio=0.5)
    st, sim = _chain_pair(law, overlap, r)
    w0 = 1e-3
    st.omega[:] = [-w0 / 2, w0 / 2]
    kr = 0.5 * 1.5 * kh * math.sqrt(overlap) * (r / 2) ** 2
    om = math.sqrt(4 * kr / st.inertia[0])
    period = 2 * math.pi / om
    sim.dt = period / 2000
    psi = []
    for _ in range(2000):
        sim.step()
        psi.append(st.theta[1] - st.theta[0])
        assert st.omega[0] == -st.omega[1]
    assert np.all(st.nl_ft[:, 0] == 0.0)                      # no tangential slip, no tangential force
    assert np.max(psi) == pytest.approx(w0 / om - w0 * sim.dt, rel=1e-5)
    assert (np.argmax(psi) + 1) * sim.dt == pytest.approx(period / 4, rel=2e-3)
    assert abs(psi[-1]) < 1e-4 * np.max(psi)                   # back to zero after a period
    assert np.allclose(st.x, [[st.h[0, 0] / 4, 2.0], [3 * st.h[0, 0] / 4, 2.0]], rtol=0, atol=1e-12)


def test_rolling_resistance_cap_decelerates_linearly():
    """Above the cap the rolling torque is mu_r R_eff fn per contact: the relative spin decays
    linearly at 4 mu_r R_eff fn / I (two contacts) until it stops."""
    kh, overlap, r, mu_r = 1e5, 2e-3, 0.5, 0.05
    law = HertzRolling(kh=kh, mu=0.5, delta_ref=overlap, mu_r=mu_r, kr_ratio=0.5)
    st, sim = _chain_pair(law, overlap, r)
    w0 = 2.0
    st.omega[:] = [-w0 / 2, w0 / 2]
    fn = kh * overlap ** 1.5
    decel = 4 * mu_r * (r / 2) * fn / st.inertia[0]
    n = 200
    for _ in range(n):
        sim.step()
    rel = st.omega[1] - st.omega[0]
    assert rel == pytest.approx(w0 - decel * n * sim.dt, rel=1e-6)


def test_history_parity_survives_spatial_sorts():
    """Re-ordering particles swaps the i/j roles of some pairs: the LAMMPS shear vector and the
    rolling torque change sign then (parity -1). Runs sorting at every rebuild follow runs that
    never sort to round-off (wrong parities would flip forces by their full size)."""
    gn = 2 * 0.05 * math.sqrt(1e4 / 0.5)
    for law in (LammpsHookeHistory(kn=1e4, kt=1e4, gamma_n=gn, mu=0.3),
                HertzRolling(kh=3e5, mu=0.4, delta_ref=0.02, mu_r=0.1, restitution=0.5)):
        out = []
        for sort_every in (0, 1):
            st = ref.initial_state(True)
            st.v *= 4.0
            sim = Simulation(st, law, damping=0.0, loop=Loop(skin=0.02, sort_every=sort_every))
            sim.run(200)
            inv = np.argsort(st.ids)
            out.append((st.x[inv], st.v[inv], st.omega[inv], st.ids.copy(), sim.n_rebuilds))
        (xa, va, wa, ida, na), (xb, vb, wb, idb, nb) = out
        assert na == nb and na > 10 and not np.array_equal(ida, idb)
        assert np.abs(va - vb).max() < 1e-8 * np.abs(va).max()
        assert np.abs(wa - wb).max() < 1e-8 * np.abs(wa).max()


def test_lammps_law_coefficients_and_null_gamma_t():
    law = LammpsHookeHistory(kn=1e4, kt=2e3, gamma_n=8.0, mu=0.5)
    assert law.models[1] == cm.MassGamma(8.0, 4.0)              # NULL: gamma_n / 2
    assert LammpsHookeHistory(kn=1e4, kt=2e3, gamma_n=8.0, mu=0.5, gamma_t=3.0).models[1].gamma_t == 3.0
    assert LammpsHookeHistory(kn=1e4, kt=2e3, gamma_n=8.0, mu=0.5, dampflag=0).models[1].gamma_t == 0.0
    assert law.history_parity == (-1, -1) and law.needs_spin
    assert law.dt_stiffness() == max(1e4, 2 * 2e3)


@pytest.mark.parametrize("law", [
    Frictionless(kn=1e4, restitution=0.5),
    LinearFriction(kn=1e4, kt=5e3, mu=0.3, restitution=0.8, tangential_damping=True),
    HertzMindlin(kh=1e5, mu=0.5, delta_ref=0.01),
    HertzRolling(kh=1e5, mu=0.5, delta_ref=0.01, mu_r=0.1),
    HertzRolling(kh=1e5, mu=0.5, delta_ref=0.01, mu_r=0.1, contact_arms=True),
    LinearFriction(kn=1e4, kt=5e3, mu=0.3, contact_arms=True),
    LammpsHookeHistory(kn=1e4, kt=1e4, gamma_n=10.0, mu=0.5),
    ContactLaw(cm.Hertz(1e5, 0.01), cm.MassGamma(5.0, 2.5), cm.LammpsHistory(1e4, 0.5),
               cm.RollingResistance(0.2, 0.05)),
    ContactLaw(cm.Hooke(1e4), cm.NoDamping(), cm.LinearHistory(1e4, 0.5, True)),
])
def test_meta_round_trip(law):
    assert law_from_meta(law.to_meta()) == law


def test_old_checkpoint_meta_still_loads():
    meta = {"law": "LinearFriction", "kn": 1e4, "kt": 1e4, "mu": 0.5, "restitution": 0.85,
            "tangential_damping": True}
    law = law_from_meta(meta)
    assert law.models == (cm.Hooke(1e4), cm.ViscousTangential.from_restitution(0.85),
                          cm.LinearHistory(1e4, 0.5), cm.NoRolling())


@pytest.mark.parametrize("make, name", [
    (lambda: LammpsHookeHistory(kn=1e4, kt=0.0, gamma_n=1.0, mu=0.5), "kt"),
    (lambda: LammpsHookeHistory(kn=1e4, kt=1e4, gamma_n=-1.0, mu=0.5), "gamma_n"),
    (lambda: LammpsHookeHistory(kn=1e4, kt=1e4, gamma_n=1.0, mu=0.5, dampflag=2), "dampflag"),
    (lambda: HertzRolling(kh=1e5, mu=0.5, delta_ref=0.01, mu_r=-0.1), "mu_r"),
    (lambda: HertzMindlin(kh=1e5, mu=0.5, delta_ref=0.0), "delta_ref"),
    (lambda: ContactLaw(cm.Hooke(1.0), tangential=cm.Hooke(1.0)), "tangential"),
    (lambda: ContactLaw(cm.Hooke(1.0), cm.Viscous(1.5)), "zeta"),
    (lambda: LinearFriction(kn=1.0, kt=float("nan"), mu=0.1), "kt"),
    (lambda: LinearFriction(kn=1.0, kt=1.0, mu=0.1, contact_arms=0.5), "contact_arms"),
])
def test_bad_coefficients_named(make, name):
    with pytest.raises(ValueError, match=name):
        make()


def test_rolling_law_time_step_covers_rotation():
    law = HertzRolling(kh=1e5, mu=0.5, delta_ref=0.01, mu_r=0.1, kr_ratio=0.5, kt_ratio=0.5)
    kn = 1.5e5 * math.sqrt(0.01)
    assert law.dt_stiffness() == pytest.approx(max(kn, 2 * 0.5 * kn + 2 * 0.5 * kn))
    st = ref.initial_state(True)
    assert critical_dt(st, law) < critical_dt(st, HertzMindlin(kh=1e5, mu=0.5, delta_ref=0.01, kt_ratio=0.5))


ENGINE_REF = np.load(__import__("pathlib").Path(__file__).parent / "data" / "engine_reference.npz")


@pytest.mark.parametrize("name", list(eref.CASES))
def test_engine_refactors_reproduce_the_recorded_runs_bit_for_bit(name):
    """The LAMMPS law, rolling resistance, a sheared cell and the fused kick against runs recorded
    with the engine before the throughput refactors (tests/engine_reference_cases.py)."""
    with _damping_warned(eref.CASES[name][0]()):
        ref.assert_reproduces(ENGINE_REF, name, eref.run_case, eref.FIELDS)


ARMS_REF = np.load(__import__("pathlib").Path(__file__).parent / "data" / "arms_reference.npz")


@pytest.mark.parametrize("name", list(aref.CASES))
def test_contact_arms_reproduce_the_recorded_runs_bit_for_bit(name):
    """Contact-point spin arms, a compile-time choice since, against runs recorded when they were a
    flag read at run time (tests/arms_reference_cases.py): both loops, fused kick, three laws."""
    ref.assert_reproduces(ARMS_REF, name, aref.run_case, aref.FIELDS)


def test_arms_reference_tells_the_arms_apart():
    """The recorded arms runs are not those of radius arms: the test above fails if the arms are dropped."""
    law_f, kw_f = aref.CASES["linear_arms_fused"]
    law = replace(law_f(), contact_arms=False)
    st = ref.initial_state(True)
    ref.simulation(st, law, damping=0.2, skin=0.02, sort_every=3, **kw_f()).run(aref.STEPS)
    assert not np.array_equal(st.x, ARMS_REF["linear_arms_fused/x"])


def test_contact_arms_are_a_compiled_type():
    """A law with contact arms gives the loops its scalar-history model as the arms subclass (equal
    as a tuple, an instance of the public class), so numba's dispatcher, which keys a tuple on its
    class and field types, compiles a loop per choice in one process (the radius arms without the
    arm division); pair_forces converts a Models built by hand the same way."""
    import numba
    for m, arms_cls in ((cm.LinearHistory(1e4, 0.5), cm._LinearHistoryArms), (cm.Mindlin(0.5, 0.5), cm._MindlinArms)):
        on = m._replace(contact_arms=True)
        models = cm.Models(cm.Hooke(1.0), cm.NoDamping(), on, cm.NoRolling())
        typed = cm.with_arm_types(models)
        assert type(typed.tangential) is arms_cls and isinstance(typed.tangential, type(m))
        assert typed == models and typed.tangential.contact_arms is True
        off = cm.Models(cm.Hooke(1.0), cm.NoDamping(), m, cm.NoRolling())
        assert cm.with_arm_types(off) is off and cm.with_arm_types(typed) is typed

        @numba.njit
        def kt_ratio_or_kt(models):
            return models.tangential[0]
        kt_ratio_or_kt(off), kt_ratio_or_kt(typed), kt_ratio_or_kt(off)
        assert len(kt_ratio_or_kt.signatures) == 2
    law = LinearFriction(kn=1e4, kt=5e3, mu=0.3, contact_arms=True)
    assert type(law.models.tangential) is cm._LinearHistoryArms
    assert type(LinearFriction(kn=1e4, kt=5e3, mu=0.3).models.tangential) is cm.LinearHistory
    assert law_from_meta(law.to_meta()) == law and law.to_meta()["contact_arms"] is True


def test_contact_arms_torque_and_slip_closed_form():
    """Two unequal overlapping disks, j spinning at w, i still: with contact arms the tangential
    history after one step is -kt (a_j w) dt with a_j = |l| r_j/(r_i + r_j), and the torques are
    -a ft (they differ from the radius-arm values by the overlap share)."""
    ri, rj, d = 0.4, 0.6, 0.99
    w, kt = 0.3, 2e3
    for arms in (True, False):
        st = State.from_disks([[2.0, 2.0], [2.0 + d, 2.0]], [ri, rj], np.diag([6.0, 6.0]), rho=ref.RHO,
                              spins=True)
        st.omega[1] = w
        sim = Simulation(st, LinearFriction(kn=1e4, kt=kt, mu=10.0, contact_arms=arms), damping=0.0,
                         guard=Guard(check_every=0))
        sim.compute_forces()
        ai, aj = (d * ri / (ri + rj), d * rj / (ri + rj)) if arms else (ri, rj)
        ft = -kt * (-(aj * w)) * sim.dt      # slip velocity vt = -(w_i a_i + w_j a_j)
        assert st.nl_ft[0] == pytest.approx(ft, rel=1e-12)
        assert sim.torque == pytest.approx([-ai * ft, -aj * ft], rel=1e-12)


@pytest.mark.parametrize("make", [lambda: LinearFriction(kn=1e4, kt=1e4, mu=0.5),
                                  lambda: LammpsHookeHistory(kn=1e4, kt=1e4, gamma_n=10.0, mu=0.5)])
def test_coincident_disks_stop_with_the_reason(make):
    """Both pair loops use numba's numpy error model: two disks at the same point give a NaN
    force (no ZeroDivisionError), which the instability guard reports."""
    from dem.runtime import InstabilityError
    x = np.array([[1.0, 1.0], [1.0, 1.0], [3.0, 3.0]])
    st = State.from_disks(x, np.full(3, 0.5), np.diag([5.0, 5.0]), rho=1.0, spins=True)
    sim = Simulation(st, make(), guard=Guard(check_every=10))
    with pytest.raises(InstabilityError, match="NaN"):
        sim.run(20)


@pytest.mark.parametrize("name", ["frictionless_e", "lammps", "rolling"])
def test_threaded_forces_agree_to_round_off_and_are_reproducible(name):
    """Multi-core forces: the contact history is that of one thread bit for bit, the forces,
    torques and tallies agree to round-off (the particles' sums are taken in another order), and
    two runs with the same number of threads are bit-identical (three threads on four chunks:
    uneven ranges)."""
    def run(threads, steps):
        law = STRATEGY_LAWS[name]()
        st = ref.initial_state(law.needs_spin)
        with _damping_warned(law):
            sim = Simulation(st, law, damping=0.2, control=PressureServo(p_target=80.0, max_rate=5e-3),
                             loop=Loop(skin=0.02, sort_every=3, threads=threads))
        for _ in range(steps):
            sim.step()
        return st, sim

    (a, sa), (b, sb) = run(1, 1), run(3, 1)
    assert -(-a.nl_i.shape[0] // cm.CHUNK) >= 3
    if a.nl_ft is not None:
        assert np.array_equal(a.nl_ft, b.nl_ft)
    scale = np.abs(sa.f).max()
    assert scale > 0 and np.abs(sa.f - sb.f).max() <= 1e-13 * scale
    if a.omega is not None:
        assert np.abs(sa.torque - sb.torque).max() <= 1e-13 * scale
    assert np.allclose(sa.out, sb.out, rtol=1e-12, atol=0)
    (c, _), (d, _) = run(3, 60), run(3, 60)
    for f in ("x", "v", "omega", "nl_ft"):
        if getattr(c, f) is not None:
            assert np.array_equal(getattr(c, f), getattr(d, f)), f


@pytest.mark.parametrize("bad", [0, -2, 2.0, True, "2"])
def test_threads_refused_with_the_range(bad):
    st = ref.initial_state(True)
    with pytest.raises(ValueError, match=r"threads must be an integer in \[1, 1024\]"):
        Simulation(st, STRATEGY_LAWS["linear"](), loop=Loop(threads=bad))


def _kernel_functions():
    """Every function of dem.engine.contact_models that numba compiles: jitted functions (their Python
    source) and the hooks' implementations (the typers registered with ``_implements``)."""
    import inspect
    from numba.core.registry import CPUDispatcher
    for name, obj in vars(cm).items():
        if isinstance(obj, CPUDispatcher):
            yield name, obj.py_func
        elif inspect.isfunction(obj) and obj.__module__ == cm.__name__ and name.startswith("_") and \
                "impl" in obj.__code__.co_varnames:
            yield name, obj


def test_kernels_take_named_bundles_not_long_argument_lists():
    """Issue 23.2: no kernel of the pair loop or the kick takes more than 10 arguments (the hooks
    read Contact, Load and Slots bundles; the loops Bodies, Pairs, Models and Forces). The check
    sees the hooks (22 positional scalars before) and the loops (up to 27)."""
    import inspect
    seen = dict(_kernel_functions())
    assert {"_law", "_chunked", "_serial", "kick_range", "_scalar_tangential", "_lammps_tangential",
            "_roll"} <= set(seen)
    long = {name: len(inspect.signature(f).parameters) for name, f in seen.items()
            if len(inspect.signature(f).parameters) > 10}
    assert long == {}


def test_kick_range_compiles_without_reference_counting():
    """The kick was 10-16 % slower than c673f7b's (docs/dem.md, throughput): the bundles' arrays,
    read inside the loop over blocks, put NRT_incref/NRT_decref calls (atomic) into every block of
    256 particles (78 calls in kick_range's own code). kick_range takes them out once per call;
    numba's pruning then leaves none in its own function (its wrappers excluded)."""
    from numba import njit
    fresh = njit(error_model="numpy")(cm.kick_range.py_func)   # compiled here: cached code cannot be inspected
    n = 300
    rng = np.random.default_rng(0)
    x, v, xr, f = (rng.random(2 * n) for _ in range(4))
    omega, theta, torque = (rng.random(n) for _ in range(3))
    fb = cm.Bodies(x, v, omega, theta, np.ones(n), rng.random(n) + 1.0, rng.random(n) + 1.0, xr)
    fo = cm.Forces(f, torque, np.zeros(8), np.zeros(5))
    kick = cm.Kick(True, 1e-3, 1e-3, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, False)
    sums = fresh(0, n, fb, fo, kick, (0.0,) * 5, np.empty(cm.KICK_SCRATCH))
    assert sums[0] > 0.0
    own = fresh.inspect_llvm(fresh.signatures[0]).split("\ndefine ")[1].split("\n}\n")[0]
    assert "kick_range" in own.splitlines()[0]
    assert "@NRT_incref" not in own and "@NRT_decref" not in own


def test_law_of_one_pair_through_the_bundles_closed_form():
    """The law evaluated on one pair through its bundles (PairInput in, PairForce out, history
    beside its Slots): Hooke with a tangential spring, sliding velocity below the Coulomb cap.
    fn = kn delta, ft = -kt vt dt with vt = dv.t - (w_i r_i + w_j r_j), torques -r ft."""
    from numba import njit

    @njit
    def one_pair(g, hist, cell, models, dt):
        return cm._law(g, hist, cm.Slots(0, 1), np.zeros(0), 0, cell, models, dt, False)

    kn, kt, ri, rj, d = 1e4, 7e3, 0.4, 0.6, 0.98
    vy, wi, wj, dt = 0.03, 0.2, -0.1, 1e-3
    law = LinearFriction(kn=kn, kt=kt, mu=10.0)
    hist = np.zeros(1)
    cell = cm.Cell(0.0, 0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 5.0)
    r = one_pair(cm.PairInput(d, 0.0, d * d, ri, rj, 0.0, vy, wi, wj), hist, cell, law.models, dt)
    assert isinstance(r, cm.PairForce)
    vt = vy - (wi * ri + wj * rj)               # t = (0, 1) for n = (1, 0)
    ft = -kt * vt * dt
    assert r.fn == pytest.approx(kn * (ri + rj - d), rel=1e-13)
    assert r.fx == pytest.approx(r.fn, rel=1e-13) and r.fy == pytest.approx(ft, rel=1e-13)
    assert hist[0] == pytest.approx(ft, rel=1e-13)          # written through the history beside Slots
    assert (r.mi, r.mj) == pytest.approx((ri * ft, rj * ft), rel=1e-13)
    assert r.Ut == pytest.approx(0.5 * ft * ft / kt, rel=1e-13) and r.ok
