"""Packing generator: stop criteria met and reported, bit-identical with the same seed, resumable
from a checkpoint, ContactNetwork hand-over consistent with the engine's own stress."""
import csv
import json
import math

import numpy as np
import pytest

from scipy.spatial import Delaunay

import dem.__main__ as cli
from dem import io as dio
from dem.analysis import measure
from dem.engine.integrate import InstabilityError, Simulation
from dem.engine.packing import (PackingProtocol, PackingResult, PackReport, ProtocolError, hexatic_psi6,
                         network_from_state, pack, random_gas)
from dem.engine.state import State
from dem.engine.cell import PressureServo
from dem.engine.contact_laws import Frictionless
from microhom import lattices

PROTO = PackingProtocol(n=60, p_over_kn=1e-3, kn=1.0, mu=0.3, mu_prep=0.3, seed=3,
                        tol_unbalanced=1e-4, tol_ke=1e-6)


@pytest.fixture(scope="module")
def small_packing():
    return pack(PROTO.replace(n=120), max_steps=200_000)


def test_packing_meets_its_stop_criteria(small_packing):
    r = small_packing.report
    assert r["converged"]
    assert r["rel_p_err"] < 1e-3
    assert r["unbalanced"] < 1e-4 and r["unbalanced_max"] >= r["unbalanced"]
    assert r["ke_rel"] < 1e-6
    assert 0.7 < r["phi"] < 0.91  # between a loose random packing and the triangular crystal
    # psi6 recomputed here from the positions alone (periodic Delaunay written in this test)
    psi6, psi6_local = _psi6_delaunay(small_packing.to_network())
    assert r["psi6"] == pytest.approx(psi6, abs=1e-12)
    assert r["psi6_local"] == pytest.approx(psi6_local, abs=1e-12)
    assert r["psi6"] < 0.5        # frictional preparation of identical disks: not a crystal
    assert r["dt_over_dtcrit"] == pytest.approx(1.0)   # the default time step of pack


def _psi6_delaunay(net):
    """psi6 = |mean_i (1/n_i) sum_j exp(6 i theta_ij)| over the Delaunay neighbours of the 3x3
    periodic tiling (independent of dem.analysis.measure)."""
    x, h = net.positions, net.cell
    n = x.shape[0]
    shifts = [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)]
    tiled = np.concatenate([x + h @ np.array(s, float) for s in shifts])
    tri = Delaunay(tiled)
    nb = [set() for _ in range(n)]
    for simplex in tri.simplices:
        for u in simplex:
            if u // n == shifts.index((0, 0)):
                nb[u % n].update(int(v) for v in simplex if v != u)
    centre = shifts.index((0, 0)) * n
    loc = np.array([np.mean([np.exp(6j * np.arctan2(*(tiled[v] - tiled[centre + i])[::-1]))
                             for v in nb[i]]) for i in range(n)])
    return abs(loc.mean()), np.abs(loc).mean()


def test_random_gas_without_overlaps():
    cold = PackingProtocol(n=400, seed=5, dispersity=0.3, phi0=0.44, gas_overlaps=False)
    a = random_gas(cold)
    b = random_gas(cold)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.radius, b.radius)
    assert a.solid_fraction == pytest.approx(0.44)
    L = a.h[0, 0]
    assert np.all((a.x >= 0) & (a.x < L)) and np.all(a.v == 0)
    d = a.x[:, None, :] - a.x[None, :, :]
    d -= L * np.round(d / L)                                  # nearest image, square cell
    gap = np.hypot(d[..., 0], d[..., 1]) - (a.radius[:, None] + a.radius[None, :])
    np.fill_diagonal(gap, np.inf)
    assert gap.min() >= 0
    assert not np.array_equal(a.x, random_gas(cold.replace(seed=6)).x)
    with pytest.raises(ValueError, match="phi0"):
        cold.replace(phi0=0.5)


def test_old_protocol_options_reproduce_the_earlier_packing():
    """The options of the protocol before issue 12.3 give the packing that code gave, bit for
    bit (values recorded with the code of commit 890360b, before FIRE and dt = dt_crit)."""
    r = pack(PROTO.replace(mu_prep=0.1, damping_compaction=0.1, dt_over_dtcrit=0.8, fire=False))
    assert r.report["phase_steps"] == [{"phase": "compact", "step": 5400},
                                       {"phase": "prep", "step": 5500},
                                       {"phase": "test", "step": 5600}]
    assert float(r.state.x.sum()).hex() == "0x1.c9b1bad295a1dp+8"
    assert float(r.state.v.sum()).hex() == "0x1.dcc8cb6b9e608p-15"
    assert r.report["pressure"].hex() == "0x1.0624db7539d42p-10"


def test_resume_inside_a_fire_phase_is_bit_exact(tmp_path):
    proto = PROTO.replace(mu_prep=0.1, tol_unbalanced=1e-9, tol_ke=1e-14)
    straight = pack(proto, checkpoint_every=100)
    assert [h["phase"] for h in straight.report["phase_steps"]] == ["compact", "prep", "test"]
    stop = straight.report["phase_steps"][0]["step"] + 100          # inside prep (FIRE on)
    ck = tmp_path / "pack.npz"
    pack(proto, checkpoint_every=100, max_steps=stop, checkpoint=ck)
    pk = State.load(ck).meta["packing"]
    assert pk["phase"] == "prep" and pk["fire"]["n_pos"] + pk["fire"]["n_quench"] > 0
    resumed = pack(proto, checkpoint_every=100, checkpoint=ck)
    assert resumed.report["resumed"] and resumed.report["steps"] == straight.report["steps"]
    for name in ("x", "v", "omega", "h", "L", "nl_ft"):
        assert np.array_equal(getattr(resumed.state, name), getattr(straight.state, name)), name


def test_compaction_fire_gate_follows_the_solid_fraction():
    """Compact's gate: FIRE on after ``still_checks`` checks without compaction, off as soon as
    the solid fraction moves again; the stop criterion is untouched."""
    from dem.engine.packing import Compact, _Run

    class St:
        solid_fraction = 0.8

    run = _Run.__new__(_Run)
    run.state, run.p_target, run.fire, run.last_phi, run.n_still = St(), 1.0, None, None, 0
    ph = Compact(0.05, 1e-3, 1e-2, still_tol=1e-6, still_checks=3)
    m = {"pressure": 2.0, "unbalanced": 1.0}              # far from done
    seen = []
    for phi in (0.8, 0.8, 0.8, 0.8, 0.8, 0.81, 0.81):
        St.solid_fraction = phi
        assert not ph.done(run, m)
        seen.append((run.n_still, run.fire is not None))
    assert seen == [(0, False), (1, False), (2, False), (3, True), (4, True), (0, False), (1, False)]
    assert Compact(0.05, 1e-3, 1e-2, still_tol=0.0).done(run, {"pressure": 1.0, "unbalanced": 1e-4})


def test_resume_with_the_compaction_gate_counting_is_bit_exact(tmp_path):
    # N = 400, seed 0: the gate opens at step 11 800 (fifth still check), the checkpoint at
    # 11 500 is inside the count
    proto = PackingProtocol(n=400, p_over_kn=1e-4, mu=0.5, mu_prep=0.5, seed=0)
    straight = pack(proto, checkpoint_every=100)
    ck = tmp_path / "pack.npz"
    pack(proto, checkpoint_every=100, max_steps=11500, checkpoint=ck)
    pk = State.load(ck).meta["packing"]
    assert pk["phase"] == "compact" and pk["n_still"] > 0 and pk["last_phi"] is not None
    resumed = pack(proto, checkpoint_every=100, checkpoint=ck)
    assert resumed.report["steps"] == straight.report["steps"]
    for name in ("x", "v", "omega", "h", "L", "nl_ft"):
        assert np.array_equal(getattr(resumed.state, name), getattr(straight.state, name)), name


def test_psi6_of_a_crystal_is_one():
    net = lattices.triangular(6, 6, angle=0.3)
    hx = hexatic_psi6(net)
    assert hx["psi6"] == pytest.approx(1.0, abs=1e-12)
    assert _psi6_delaunay(net)[0] == pytest.approx(1.0, abs=1e-12)


def test_network_handover_matches_pressure(small_packing):
    net = small_packing.to_network()
    r = small_packing.report
    assert net.n_contacts == r["n_contacts"]
    # Love-Weber stress from the handed-over network (another engineer's measurement code)
    assert measure.pressure(net) == pytest.approx(r["pressure"], rel=1e-3)
    # branch vectors: lengths = r_i + r_j - overlap, overlap = fn / kn
    i, j = net.pairs.T
    assert np.allclose(net.lengths, net.radii[i] + net.radii[j] - net.fn / net.kn, rtol=0, atol=1e-12)
    assert np.all(net.fn > 0)
    assert np.all(np.abs(net.ft) <= 0.3 * net.fn * (1 + 1e-9))
    assert np.array_equal(net.sliding, np.abs(net.ft) >= 0.3 * net.fn * (1 - 1e-9))


def test_same_seed_bit_identical_and_other_seed_differs():
    a = pack(PROTO, max_steps=3000)
    b = pack(PROTO, max_steps=3000)
    c = pack(PROTO.replace(seed=4), max_steps=3000)
    for name in ("x", "v", "omega", "h", "nl_ft"):
        assert np.array_equal(getattr(a.state, name), getattr(b.state, name)), name
    assert not np.array_equal(a.state.x, c.state.x)


def test_checkpoint_resume_is_bit_exact(tmp_path):
    straight = pack(PROTO, max_steps=4000, checkpoint_every=1000)
    ck = tmp_path / "pack.npz"
    pack(PROTO, max_steps=2000, checkpoint_every=1000, checkpoint=ck)
    resumed = pack(PROTO, max_steps=4000, checkpoint_every=1000, checkpoint=ck)
    assert resumed.report["resumed"]
    assert resumed.state.step == straight.state.step == 4000
    for name in ("x", "v", "omega", "h", "L", "nl_ft"):
        assert np.array_equal(getattr(resumed.state, name), getattr(straight.state, name)), name


def test_result_save_load(tmp_path, small_packing):
    small_packing.save(tmp_path / "p.npz")
    back = PackingResult.load(tmp_path / "p.npz")
    assert np.array_equal(back.state.x, small_packing.state.x)
    assert back.report["n_contacts"] == small_packing.report["n_contacts"]
    assert back.to_network().n_contacts == small_packing.to_network().n_contacts


def test_absolute_units():
    proto = PackingProtocol(n=40, p_over_kn=2e3 / 1e6, kn=1e6, mu=0.0, mu_prep=0.0, seed=1,
                            tol_unbalanced=1e-3, tol_ke=1e-4)
    assert proto.p_target == pytest.approx(2e3, rel=1e-15) and proto.kt == 1e6
    r = pack(proto, max_steps=100_000).report
    assert r["converged"] and r["p_over_kn"] == pytest.approx(2e-3, rel=1e-3)
    assert r["pressure"] == pytest.approx(2e3, rel=1e-3) and r["p_target"] == proto.p_target
    assert math.isnan(r["sliding_fraction"]) and r["kt"] == 0.0


def test_random_gas_seeded_and_bad_input():
    a = random_gas(PackingProtocol(n=50, seed=9, dispersity=0.1))
    b = random_gas(PackingProtocol(n=50, seed=9, dispersity=0.1))
    assert np.array_equal(a.x, b.x) and np.array_equal(a.radius, b.radius)
    assert a.solid_fraction == pytest.approx(0.2)
    with pytest.raises(ValueError, match="dispersity"):
        PackingProtocol(n=50, dispersity=0.7)
    with pytest.raises(ValueError, match=r"p_over_kn must be in \(0, 0.1\], got -1.0"):
        PackingProtocol(n=50, p_over_kn=-1.0)
    with pytest.raises(TypeError, match="PackingProtocol"):
        pack(50)


def test_isotropic_servo_wiring():
    """The pressure servo brings a frictionless gas to the target pressure, and the pressure it
    reports is the Love-Weber pressure of the contact network computed independently."""
    st = random_gas(PackingProtocol(n=80, seed=2), spins=False)
    sim = Simulation(st, Frictionless(kn=1.0), damping=0.7)   # frictionless: no spins, no history
    sim.control = PressureServo(p_target=1e-3, max_rate=2e-4 / sim.dt, alpha=0.5)
    for _ in range(100):
        sim.run(500)
        m = sim.measure()
        if abs(m["pressure"] - 1e-3) < 1e-3 * 1e-2 and m["unbalanced"] < 1e-2:
            break
    assert st.omega is None and st.nl_ft is None
    assert m["pressure"] == pytest.approx(1e-3, rel=1e-2)
    net = network_from_state(st, sim.law)
    i, j = net.pairs.T
    f = net.fn[:, None] * net.normals                       # compression positive, along i -> j
    sigma = -(f[:, :, None] * net.branch[:, None, :]).sum(0) / net.area
    # (the engine's stress is from the forces of the last step, one drift before these positions)
    assert -np.trace(sigma) / 2 == pytest.approx(m["pressure"], rel=1e-4)


def test_unstable_run_keeps_last_good_checkpoint(tmp_path, monkeypatch):
    orig = Simulation.run

    def poisoned(self, n, **kw):  # a NaN appears between steps 1000 and 1100
        out = orig(self, n, **kw)
        if self.state.step >= 1050:
            self.state.v[0, 0] = np.nan
        return out

    monkeypatch.setattr(Simulation, "run", poisoned)
    ck = tmp_path / "ck.npz"
    with pytest.raises(InstabilityError, match="NaN") as err:
        pack(PROTO, max_steps=200_000, checkpoint=ck, checkpoint_every=500)
    e = err.value
    assert e.step == 1100 and e.state.step == 1000 and np.isfinite(e.state.v).all()
    assert e.checkpoint == str(ck) and e.checkpoint_step == 1000
    assert State.load(ck).step == 1000 and np.isfinite(State.load(ck).v).all()


def test_checkpoint_by_wall_time_and_progress(tmp_path):
    seen = []
    ck = tmp_path / "ck.npz"
    r = pack(PROTO, max_steps=3000, checkpoint=ck, checkpoint_every=None, checkpoint_seconds=0.0,
             progress=seen.append)
    assert [s["step"] for s in seen] == list(range(100, 3001, 100))
    assert all(s["checkpoint_step"] == s["step"] - 100 for s in seen[1:])  # saved at every check
    assert all(s["ke_rel"] is not None for s in seen[9::10])
    assert not r.report["converged"] and r.report["steps"] == 3000


def test_compaction_phase_then_equilibrium_damping(small_packing):
    r = small_packing.report
    phases = [h["phase"] for h in r["phase_steps"]]
    assert phases == ["compact", "prep"]  # mu == mu_prep: no test phase
    assert r["compaction_steps"] == r["phase_steps"][0]["step"] < r["steps"]
    assert small_packing.state.meta["sim"]["damping"] == 0.7 == r["damping"]
    old = pack(PROTO.replace(damping_compaction=None), max_steps=2000)
    assert old.report["compaction_steps"] is None
    with pytest.raises(ValueError, match="damping_compaction"):
        PROTO.replace(damping_compaction=1.0)


# the npz meta and the summary CSV of `python -m dem pack` as they were before the report became
# a dataclass (keys and order): the output a user's scripts read must not change
META_KEYS = ['source', 'note', 'timestep', 'n', 'seed', 'converged', 'steps', 'compaction_steps',
             'wall_s', 'resumed', 'p_target', 'pressure', 'rel_p_err', 'p_over_kn', 'unbalanced',
             'unbalanced_max', 'ke_rel', 'kinetic_energy', 'kinetic_energy_in_contact',
             'elastic_energy', 'phi', 'n_contacts', 'Z', 'sliding_fraction', 'dt', 'dt_over_dtcrit',
             'mu', 'mu_prep', 'kn', 'kt', 'tol_p', 'tol_unbalanced', 'tol_ke', 'damping',
             'damping_compaction', 'damping_work', 'psi6', 'psi6_local', 'timing',
             'particle_steps_per_s', 'law', 'protocol']
CSV_KEYS = ['converged', 'steps', 'compaction_steps', 'wall_s', 'particle_steps_per_s', 'n', 'seed',
            'p_target', 'pressure', 'p_over_kn', 'rel_p_err', 'tol_p', 'unbalanced',
            'unbalanced_max', 'tol_unbalanced', 'ke_rel', 'tol_ke', 'phi', 'Z', 'n_contacts',
            'psi6', 'psi6_local', 'sliding_fraction', 'mu_prep', 'mu', 'kn', 'kt', 'dt',
            'dt_over_dtcrit', 'damping_compaction', 'damping', 'damping_work', 'resumed',
            'phase_steps']


def test_cli_outputs_keep_their_schema(tmp_path):
    out = tmp_path / "p.npz"
    assert cli.main(["pack", "--n", "40", "--p-over-kn", "1e-3", "--mu", "0.3", "--mu-prep", "0.1",
                     "--seed", "2", "--tol-unbalanced", "1e-3", "--no-progress",
                     "--out", str(out)]) == 0
    with np.load(out) as z:
        meta = json.loads(str(z["meta_json"]))
    assert list(meta) == META_KEYS
    with open(tmp_path / "p_summary.csv") as fh:
        rows = [r for r in csv.reader(fh)][1:]
    assert [k for s, k, _ in rows if s == "packing"] == CSV_KEYS
    rep = PackingResult.load(out).report
    assert isinstance(rep, PackReport)
    for s, k, v in rows:
        if s == "packing" and k != "phase_steps":
            assert v == (repr(rep[k]) if isinstance(rep[k], float) else str(rep[k])), k
            assert meta[k] == rep[k] or (rep[k] != rep[k] and meta[k] != meta[k]), k
    assert json.loads(json.dumps(rep.as_dict()))["steps"] == rep.steps   # JSON-ready
    with pytest.raises(Exception):
        rep.steps = 0                                                    # frozen
    with pytest.raises(TypeError):
        rep["steps"] = 0                                                 # no item assignment
    with pytest.raises(TypeError, match="read-only"):
        rep.annotate(steps=0)
    noted = rep.annotate(wall_time=1.5)      # a caller's annotation travels with the packing
    assert "wall_time" not in rep and noted["wall_time"] == 1.5
    back = PackingResult.load(out)
    PackingResult(back.state, back.law, noted, back.protocol).save(out)
    again = PackingResult.load(out)
    assert again.report["wall_time"] == 1.5  # a caller's annotation, not a timing
    # the file says how it was made: the protocol, equal to the one the options gave
    assert again.protocol == PackingProtocol(n=40, p_over_kn=1e-3, mu=0.3, mu_prep=0.1, seed=2,
                                             tol_unbalanced=1e-3)
    assert meta["protocol"] == again.protocol.as_dict()
    assert dio.read(out).meta["protocol"] == again.protocol.as_dict()


def test_pack_with_two_threads_converges_and_is_reproducible():
    """The multi-core force loop in a whole packing run: converged, the same bits twice with two
    threads, and the same packing as one thread's up to the round-off that grows over the run."""
    proto = PackingProtocol(n=60, p_over_kn=1e-3, mu=0.5, mu_prep=0.5, seed=3)
    runs = [pack(proto, threads=t) for t in (2, 2, 1)]
    a, b, c = runs
    assert a.report["converged"] and b.report["converged"] and c.report["converged"]
    assert np.array_equal(a.state.x, b.state.x) and a.report["steps"] == b.report["steps"]
    assert abs(a.report["phi"] - c.report["phi"]) < 0.02


# ---- the protocol object ----------------------------------------------------------------------
#: one value just outside the allowed range of every field (a new field must be added here)
BAD = {"n": 1, "seed": -1, "p_over_kn": 0.2, "kn": 0.0, "kt_over_kn": 10.5, "mu": -0.1,
       "mu_prep": 11.0, "radius": 0.0, "dispersity": 0.5, "rho": 0.0, "phi0": 0.9,
       "gas_overlaps": 1, "growth_dispersity": 0.5, "restore_increments": 0,
       "damping_compaction": 1.0, "jam_p": 1.0, "jam_unbalanced": 0.0, "damping": -0.01,
       "fire": "yes", "restitution": 0.0, "max_strain_per_step": 0.1, "alpha": 0.0,
       "dt_over_dtcrit": 1.01, "tol_p": 0.0, "tol_unbalanced": 1.0, "tol_ke": 0.0,
       "check_every": 0}


def test_protocol_is_frozen_hashable_serialisable_data():
    p = PackingProtocol(n=100, mu_prep=0.05, seed=3)
    assert p == PackingProtocol(n=100, mu_prep=0.05, seed=3)
    assert hash(p) == hash(PackingProtocol(n=100, mu_prep=0.05, seed=3))
    assert len({p, p.replace(seed=3), p.replace(seed=4)}) == 2
    assert PackingProtocol.from_json(p.to_json()) == p == PackingProtocol.from_dict(p.as_dict())
    assert json.loads(p.to_json())["mu_prep"] == 0.05
    with pytest.raises(Exception):
        p.mu = 0.3                                        # frozen
    corpus = [p.replace(seed=s) for s in range(3)]
    assert [q.seed for q in corpus] == [0, 1, 2] and all(q.mu_prep == 0.05 for q in corpus)
    with pytest.raises(ValueError, match="unknown packing protocol field.*'pressure'"):
        PackingProtocol.from_dict({"n": 10, "pressure": 1.0})
    # derived quantities, in N/m
    q = PackingProtocol(n=10, p_over_kn=2e-3, kn=5e6, kt_over_kn=0.5)
    assert q.p_target == 2e-3 * 5e6 and q.kt == 2.5e6
    assert q.areal_density == pytest.approx(1 / (math.pi * 0.25), rel=1e-15)
    assert PackingProtocol(n=10, kt_over_kn=0).frictionless
    assert PackingProtocol(n=10, mu=0, mu_prep=0).frictionless
    assert not PackingProtocol(n=10, mu=0).frictionless
    # an integer given as a float is an integer; a fractional one is refused
    assert PackingProtocol(n=1e3).n == 1000 and isinstance(PackingProtocol(n=1e3).n, int)


def test_protocol_defaults_are_the_seed_papers_conditions():
    p = PackingProtocol(n=10)
    assert p.mu == round(math.tan(math.radians(26.0)), 3)       # friction angle 26 deg
    assert (p.p_over_kn, p.kt_over_kn, p.kn, p.mu_prep, p.dispersity, p.radius) == \
        (1e-4, 1.0, 1.0, 0.1, 0.0, 0.5)
    assert (p.tol_p, p.tol_unbalanced, p.tol_ke, p.damping, p.damping_compaction, p.fire,
            p.dt_over_dtcrit) == (1e-3, 1e-5, 1e-8, 0.7, 0.05, True, 1.0)


@pytest.mark.parametrize("name", sorted(BAD))
def test_protocol_refuses_each_bad_field_naming_it_and_its_range(name):
    from dem.engine.packing import ProtocolError
    prm = PackingProtocol.params()[name][1]
    with pytest.raises(ProtocolError) as err:
        PackingProtocol(**{"n": 10, name: BAD[name]})
    assert err.value.field == name and str(err.value).startswith(f"{name} must be ")
    assert (prm.allowed_text() in str(err.value)) or prm.kind == "bool"
    if prm.kind != "bool":                                    # NaN and inf never pass
        for v in (float("nan"), float("inf")):
            with pytest.raises(ProtocolError, match=name):
                PackingProtocol(**{"n": 10, name: v})
    assert set(BAD) == set(PackingProtocol.params())


def test_lammps_writer_maps_the_protocol(tmp_path):
    """write_inputs takes the protocol's values (no defaults of its own): the same gas, the
    contact law, the servo target, the criteria, the time step; the dashpot from the restitution
    gives that restitution back (closed form of a linear spring-dashpot collision)."""
    from dem import io as dio
    from dem.engine.contact_laws import LinearFriction
    from dem.engine.integrate import critical_dt
    from dem.engine.lammps import INPUT_NAME, write_inputs
    proto = PackingProtocol(n=50, p_over_kn=2e-3, kn=3.0, kt_over_kn=0.5, mu=0.4, mu_prep=0.05,
                            dispersity=0.1, seed=7, restitution=0.6, tol_p=2e-3, tol_ke=1e-7,
                            check_every=50, dt_over_dtcrit=0.9, jam_p=0.02)
    prm = write_inputs(tmp_path, proto)
    text = (tmp_path / INPUT_NAME).read_text()
    gas = random_gas(proto)
    data = dio.read(tmp_path / "gas.data").sorted_by_id()
    assert np.array_equal(data.positions, gas.x) and np.array_equal(data.radii, gas.radius)
    assert prm["p_target"] == 6e-3 and prm["kt"] == 1.5 and prm["mu_prep"] == 0.05
    assert prm["dt"] == 0.9 * critical_dt(gas, LinearFriction(kn=3.0, kt=1.5, mu=0.05))
    assert f"pair_style      gran/hooke/history 3.0 1.5 {prm['gamma_n']!r} " in text
    assert f"halt 50 v_conv" in text and "(v_perr<0.002)" in text and "(v_kerel<1e-07)" in text
    assert "(v_perr<0.02)" in text                             # jam_p
    assert json.loads(text.splitlines()[4][len("# protocol "):]) == proto.as_dict()
    m_eff = 0.5 * gas.rho * math.pi * 0.5 ** 2
    zeta = prm["gamma_n"] / (2 * math.sqrt(3.0 / m_eff))
    assert math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2)) == pytest.approx(0.6, rel=1e-12)
    with pytest.raises(ValueError, match="growth_dispersity"):
        write_inputs(tmp_path, proto.replace(growth_dispersity=0.1))


def test_npz_schema_has_one_writer(tmp_path, small_packing):
    """The packing file is dem.io.simple.write_npz's schema plus the state as extra arrays: the
    configuration keys equal a plain write_npz of the same configuration, array for array."""
    from dem.io.simple import write_npz
    path = small_packing.save(tmp_path / "p.npz")
    cfg = dio.read(path)
    write_npz(tmp_path / "plain.npz", cfg)
    with np.load(path) as z, np.load(tmp_path / "plain.npz") as plain:
        for k in plain.files:
            if k != "meta_json":
                assert np.array_equal(z[k], plain[k]), k
        network_keys = {k for k in z.files if k.startswith("network:")}
        assert network_keys >= {"network:pairs", "network:branch", "network:kn", "network:kt",
                                "network:sliding", "network:fn", "network:ft", "network:rows"}
        assert set(z.files) - set(plain.files) - network_keys == set(small_packing.state.arrays()) - {"ids"}
    with pytest.raises(ValueError, match=r"clash with the npz schema's keys"):
        write_npz(tmp_path / "x.npz", cfg, extra={"radii": np.zeros(3)})
    with pytest.raises(ValueError, match=r"clash with the npz schema's keys"):
        write_npz(tmp_path / "x.npz", cfg, extra={"network:pairs": np.zeros((1, 2), int)})


def test_stored_network_is_the_packings(tmp_path, small_packing):
    """The network stored in a packing file (read without the simulator) is the packing's own,
    array for array: the same particles in the same order, contacts, branches, stiffnesses, forces."""
    path = small_packing.save(tmp_path / "p.npz")
    stored = dio.read_npz_network(path)
    net = small_packing.to_network()
    for k in ("positions", "radii", "cell", "origin", "pairs", "branch", "kn", "kt", "fn", "ft", "sliding"):
        np.testing.assert_array_equal(getattr(stored, k), getattr(net, k), err_msg=k)
    assert dio.read_npz_network(small_packing.save(tmp_path / "q.npz")) is not None
    plain = tmp_path / "plain.npz"
    dio.write_npz(plain, dio.read(path))
    assert dio.read_npz_network(plain) is None
