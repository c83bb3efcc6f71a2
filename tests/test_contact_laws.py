"""Contact laws composed from sub-models (dem.contact_models): bit-identity with the hand-written
kernels they replaced, fused against separate integration, history layout, the rolling-resistance
law added as one sub-model, and bad coefficients named."""
import math

import numpy as np
import pytest

from dem import contact_models as cm
from dem.contact_laws import (ContactLaw, Frictionless, HertzMindlin, HertzRolling, LammpsHookeHistory,
                              LinearFriction, law_from_meta)
from dem.integrate import Simulation, critical_dt
from dem.state import State
import law_reference_cases as ref

REF = np.load(__import__("pathlib").Path(__file__).parent / "data" / "law_reference.npz")


@pytest.mark.parametrize("name", list(ref.CASES))
def test_composed_laws_reproduce_the_old_kernels_bit_for_bit(name):
    st, out, nreb = ref.run_case(name)
    assert nreb == int(REF[f"{name}/n_rebuilds"])
    for f in ref.FIELDS:
        key = f"{name}/{f}"
        a = getattr(st, f)
        if key not in REF.files:
            assert a is None, f
            continue
        assert np.array_equal(a, REF[key]), f"{name}: {f} differs from the recorded trajectory"
    assert np.array_equal(out, REF[f"{name}/out"])
