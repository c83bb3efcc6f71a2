"""The floppy count of the exact stiffness (``dem.analysis.stiffness``, counted by
``microhom.factor.count_zero_modes``) on two corpus packings where it was off by one, against
the pebble game (``microhom.rigidity``, a combinatorial count of the same rigidity matrix).

``tests/data/floppy_rows.npz`` holds the two networks (1000 disks each, kn = 1, analysed at kt = 0):
``pack_study_s3`` (identical disks, mu_prep 0.05, p/kn 1e-3, seed 3) has a rigid mode whose
singular value in the rigidity matrix is 3.8e-8 of the largest, so 1.4e-15 in the Hessian's pencil:
every rule on the Hessian counted it floppy (4 instead of 3); ``lammps_prep_s2`` (LAMMPS-prepared,
seed 2) has a zero mode whose pivot is 1.3e-2 of its diagonal: SuperLU's rescaling rule missed it
(62 instead of 63). A dense SVD of the rigidity matrix gives 3 and 63 at every threshold from 1e-12
to 1e-8 of the largest singular value (docs/stiffness.md, "Floppy modes")."""
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from dem.analysis.stiffness import (assemble, count_modes, factorise, reduce_system, stiffness)
from microhom.factor import available_backends
from microhom.network import ContactNetwork
from microhom.rigidity import pebble_game

DATA = Path(__file__).parent / "data" / "floppy_rows.npz"
#: the pebble game's counts (and the dense SVD's, docs/stiffness.md)
EXPECTED = {"pack_study_s3": 3, "lammps_prep_s2": 63}
SOLVERS = [s for s in ("splu", "pardiso") if s in available_backends()]


def _network(name):
    z = np.load(DATA)
    c = z[f"{name}/pairs"].shape[0]
    assert json.loads(str(z[f"{name}/meta"]))["corpus_key"].startswith(name.rsplit("_", 1)[0])
    return ContactNetwork(positions=z[f"{name}/positions"], radii=z[f"{name}/radii"], cell=z[f"{name}/cell"],
                          pairs=z[f"{name}/pairs"].astype(np.int64), branch=z[f"{name}/branch"],
                          kn=np.ones(c), kt=np.zeros(c), sliding=np.zeros(c, bool))


@pytest.mark.parametrize("name", list(EXPECTED))
def test_the_pebble_game_counts_the_recorded_floppy_modes(name):
    assert pebble_game(_network(name)).n_floppy == EXPECTED[name]


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("name", list(EXPECTED))
def test_exact_floppy_count_agrees_with_the_rigidity_matrix(name, solver):
    """n_floppy equals the game's count with both solvers; every warning is one of the result's
    flags (a friction-made packing at kt = 0 can be not jammed: said, not silent)."""
    net = _network(name)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        r = stiffness(net, solver=solver)
    assert r.n_floppy == EXPECTED[name]
    assert sorted(str(w.message) for w in rec) == sorted(f for f in r.flags if not f.startswith("floppy"))


def test_the_hessian_alone_over_counts_the_soft_rigid_mode():
    """The reproduction: on the Hessian's pencil alone (no rigidity factor) the identical-disk
    packing has one zero mode more than its rigidity matrix (a rigid mode at 1.4e-15 < eta)."""
    red = reduce_system(assemble(_network("pack_study_s3")))
    assert count_modes(factorise(red, "splu"), red, psd=True).n_floppy == EXPECTED["pack_study_s3"] + 1
