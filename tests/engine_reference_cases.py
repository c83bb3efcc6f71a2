"""Short runs of the laws and engine paths that ``law_reference_cases`` does not cover (the LAMMPS
law, rolling resistance, a sheared cell, the fused kick), recorded before the engine's
throughput work.

``tests/data/engine_reference.npz`` holds the final positions, velocities, spins, rotations, cell
and contact history of these runs, computed by the engine of commit 890360b (before the pair loop
read the list by particle blocks, before the kick kept its sums in registers and before the
cell-list search gathered the particles by bin). Those changes are refactors: the engine must
reproduce the recorded runs bit for bit (``tests/test_contact_laws.py``). Regenerate only with the
code of that commit (``git archive 890360b | tar -x -C old``; ``PYTHONPATH=old python
tests/engine_reference_cases.py``), never with the code under test.
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import law_reference_cases as ref  # noqa: E402
from dem.engine.cell import PressureServo, StrainRate  # noqa: E402
from dem.engine.contact_laws import HertzRolling, LammpsHookeHistory, LinearFriction  # noqa: E402


def _servo():
    return PressureServo(p_target=80.0, max_rate=5e-3)


CASES = {
    # name: (law, Simulation keywords, loop and guard fields by name: law_reference_cases.simulation)
    "lammps_servo": (lambda: LammpsHookeHistory(kn=1e4, kt=8e3, gamma_n=5.0, mu=0.4),
                     lambda: dict(startup="lammps", control=_servo())),
    "lammps_fused": (lambda: LammpsHookeHistory(kn=1e4, kt=1e4, gamma_n=3.0, mu=0.5, gamma_t=1.0),
                     lambda: dict(startup="lammps", fuse=True)),
    # contact_arms=False: the recorded runs took the radii as spin arms
    "hertz_rolling": (lambda: HertzRolling(kh=3e5, mu=0.4, delta_ref=0.02, mu_r=0.1, restitution=0.5,
                                           contact_arms=False),
                      lambda: dict(control=_servo())),
    "linear_shear": (lambda: LinearFriction(kn=1e4, kt=1e4, mu=0.5, restitution=0.7, tangential_damping=True,
                                            contact_arms=False),
                     lambda: dict(control=StrainRate([[0.0, 0.2], [0.0, 0.0]]))),
    "linear_fused": (lambda: LinearFriction(kn=1e4, kt=7e3, mu=0.3, contact_arms=False), lambda: dict(fuse=True)),
}
STEPS = 400
FIELDS = ref.FIELDS + ("L",)


def run_case(name, cases=None):
    """Run case ``name`` of ``cases`` (default :data:`CASES`) for STEPS steps from
    :func:`law_reference_cases.initial_state` (local damping 0.2, skin 0.02, a spatial sort every
    3 builds) and return the final state, the last ``out`` vector and the number of builds."""
    law_f, kw_f = (CASES if cases is None else cases)[name]
    law = law_f()
    st = ref.initial_state(law.needs_spin)
    sim = ref.simulation(st, law, damping=0.2, skin=0.02, sort_every=3, **kw_f())
    sim.run(STEPS)
    return st, sim.out.copy(), sim.n_rebuilds


if __name__ == "__main__":
    ref.record(Path(__file__).resolve().parent / "data" / "engine_reference.npz", CASES, run_case, FIELDS)
