"""The 3D study (``python -m studies.spheres --quick``): one 150-sphere LAMMPS packing, its
statistics, mean field, hierarchy and exact tensor, written and resumed from the cache.

The checks are relations the estimates must satisfy, not values taken from the code: the exact
moduli lie in the hierarchy's certified interval, below the first order and the mean field (the
relaxation only softens). Skipped when ``lmp`` is not on PATH."""
import json
import shutil

import pandas as pd
import pytest

pytestmark = pytest.mark.skipif(shutil.which("lmp") is None, reason="LAMMPS binary 'lmp' not on PATH")


def test_spheres_quick_runs_and_resumes(tmp_path, capsys):
    from studies.spheres import main
    assert main(["--quick", "--out", str(tmp_path)]) == 0
    df = pd.read_csv(tmp_path / "cases.csv")
    assert len(df) == 1
    r = df.iloc[0]
    assert r.N == 150 and r.converged and 0.55 < r.phi < 0.66 and r.Z <= 7
    assert r.Z_all == pytest.approx(r.lammps_Z, rel=1e-12)        # LAMMPS's compute contact/atom
    for m in ("K", "G"):
        assert r[f"{m}_lower"] * (1 - 1e-9) <= r[f"{m}_exact"] <= r[f"{m}_upper"] * (1 + 1e-9)
        assert r[f"{m}_exact"] < r[f"{m}_first"] * (1 + 1e-9) <= r[f"{m}_mf"] * (1 + 1e-9)
    assert r.hier_certified
    text = (tmp_path / "spheres.md").read_text()
    assert "## moduli" in text and "## statistics" in text and "## times" in text
    # resumable: the cached case is reused, no LAMMPS run
    case = next((tmp_path / "packings").glob("*/case.json"))
    before = json.loads(case.read_text())
    capsys.readouterr()
    assert main(["--quick", "--out", str(tmp_path)]) == 0
    assert "packed by LAMMPS" not in capsys.readouterr().out
    assert json.loads(case.read_text()) == before
    # a row measured under the former rattler rule is measured again, the packing reused
    stale = {k: v for k, v in before.items() if k != "rattler_rule"}
    stale["K_exact"] = -1.0
    case.write_text(json.dumps(stale))
    assert main(["--quick", "--out", str(tmp_path)]) == 0
    assert "packed by LAMMPS" not in capsys.readouterr().out
    again = json.loads(case.read_text())
    assert again["K_exact"] == before["K_exact"] and again["rattler_rule"] == before["rattler_rule"]


def test_spheres_refuses_bad_arguments(tmp_path):
    from studies.spheres import main
    with pytest.raises(SystemExit, match="--p-over-kn must be in"):
        main(["--p-over-kn", "0.5", "--out", str(tmp_path)])
