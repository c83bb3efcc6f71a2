"""Short runs of the laws with contact-point spin arms (``contact_arms=True``), recorded before the
arms became a compile-time choice.

``tests/data/arms_reference.npz`` holds the final positions, velocities, spins, rotations, cell and
contact history of these runs, computed by the engine of commit 97df224, where the arms were a
boolean field read at run time (the vectorised loop computed ``|l| / (r_i + r_j)`` for every pair
and selected). Since then the arms are part of the sub-model's numba type; that is a refactor:
the engine must reproduce the recorded runs bit for bit (``tests/test_contact_laws.py``).
Regenerate only with the code of that commit (``git archive 97df224 | tar -x -C old``;
``PYTHONPATH=old python tests/arms_reference_cases.py``), never with the code under test.
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import engine_reference_cases as eref  # noqa: E402
import law_reference_cases as ref  # noqa: E402
from dem.engine import contact_models as cm  # noqa: E402
from dem.engine.contact_laws import ContactLaw, HertzMindlin, HertzRolling, LinearFriction  # noqa: E402

CASES = {
    # name: (law, Simulation keywords); the vectorised loop under a servo, fused, and the serial loop
    "linear_arms_servo": (lambda: LinearFriction(kn=1e4, kt=7e3, mu=0.3, restitution=0.7, tangential_damping=True,
                                                 contact_arms=True),
                          lambda: dict(control=eref._servo())),
    "linear_arms_fused": (lambda: LinearFriction(kn=1e4, kt=7e3, mu=0.3, contact_arms=True), lambda: dict(fuse=True)),
    "hertz_arms": (lambda: HertzMindlin(kh=3e5, mu=0.4, delta_ref=0.02, kt_ratio=0.5, restitution=0.5,
                                        contact_arms=True),
                   lambda: dict(control=eref._servo())),
    "rolling_arms": (lambda: HertzRolling(kh=3e5, mu=0.4, delta_ref=0.02, mu_r=0.1, restitution=0.5,
                                          contact_arms=True),
                     lambda: dict(control=eref._servo())),
    "massgamma_arms": (lambda: ContactLaw(cm.Hooke(1e4), cm.MassGamma(30.0, 15.0), cm.LinearHistory(8e3, 0.4, True)),
                       lambda: dict(control=eref._servo())),
}
STEPS = 400
FIELDS = eref.FIELDS


def run_case(name):
    """Run case ``name`` of :data:`CASES` as :func:`engine_reference_cases.run_case` runs its own."""
    return eref.run_case(name, CASES)


if __name__ == "__main__":
    ref.record(Path(__file__).resolve().parent / "data" / "arms_reference.npz", CASES, run_case, FIELDS)
