"""The LAMMPS input deck of :func:`dem.engine.lammps.write_inputs`, pinned as text (issue 23).

``tests/data/lammps_deck_2d.in`` and ``tests/data/lammps_deck_3d.in`` were written by the code
*before* ``write_inputs`` and ``_input_text`` were split into named steps (commit 6c3213d, by
``write_inputs`` itself with the protocols below), so a refactoring that changes one character of
a deck fails here. The 2D deck has the friction switch (``mu != mu_prep``: three phases), the 3D
one has none (frictionless, two phases) and a contact dashpot (``restitution``).

The fifth line, ``# protocol {...}``, is the protocol's ``as_dict()`` as JSON: it is compared to
that instead of to the pinned text, so that a new :class:`~dem.engine.packing.PackingProtocol`
field (which the deck does not map) does not fail this test.
"""
import json
from pathlib import Path

import pytest

from dem.engine.lammps import INPUT_NAME, write_inputs
from dem.engine.packing import PackingProtocol

DATA = Path(__file__).parent / "data"
P2 = PackingProtocol(n=20, p_over_kn=1e-3, kn=1.0, mu=0.5, mu_prep=0.05, dispersity=0.2, seed=1)
P3 = PackingProtocol(n=20, p_over_kn=2e-3, kn=3.0, kt_over_kn=0.5, mu=0.0, mu_prep=0.0,
                     dispersity=0.1, seed=7, restitution=0.6, check_every=50, dt_over_dtcrit=0.9,
                     jam_p=0.02)


@pytest.mark.parametrize("name, protocol, dimension", [("lammps_deck_2d.in", P2, 2),
                                                       ("lammps_deck_3d.in", P3, 3)])
def test_deck_text_is_pinned(tmp_path, name, protocol, dimension):
    write_inputs(tmp_path, protocol, dimension=dimension)
    got = (tmp_path / INPUT_NAME).read_text().split("\n")
    want = (DATA / name).read_text().split("\n")
    assert json.loads(got[4][len("# protocol "):]) == protocol.as_dict()
    assert want[4].startswith("# protocol {")
    got[4] = want[4] = "# protocol"
    assert len(got) == len(want)
    for k, (g, w) in enumerate(zip(got, want)):
        assert g == w, f"line {k + 1} of {name} differs"


def test_the_pinned_decks_differ_where_the_protocols_do():
    """The two pins are not the same text: the friction switch (phase 3) only in 2D, the 3D
    lines (``dimension 3``, ``set density``, a servo on z) only in 3D."""
    two = (DATA / "lammps_deck_2d.in").read_text()
    three = (DATA / "lammps_deck_3d.in").read_text()
    assert "PACK_PHASE name=test" in two and "PACK_PHASE name=test" not in three
    assert "fix             e2d all enforce2d" in two and "enforce2d" not in three
    assert "dimension       3" in three and "z variable v_dlz v_vlz" in three
