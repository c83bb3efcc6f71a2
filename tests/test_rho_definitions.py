"""studies.rho_definitions end to end on one small DEM packing: the side-by-side table and its null model."""

import numpy as np
import pandas as pd
import pytest


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MICROHOM_CACHE", str(tmp_path / "packings"))
    return tmp_path


def test_rho_table_on_a_dem_packing(cache):
    from microhom.structural_sums import network_statistics
    from studies import rho_definitions
    from studies.cases import DEFAULTS, get_packing

    table = rho_definitions.report(300, [1], out=cache / "rho", n_null=5)
    assert list(table["V summed over"]) == list(rho_definitions.LABELS.values())
    cases = pd.read_csv(cache / "rho" / "cases.csv")
    assert (cache / "rho" / "table.md").exists()
    row = cases.iloc[0]
    net = get_packing({**DEFAULTS, "n": 300, "seed": 1})[0].to_network()
    assert row.rho_contacts == pytest.approx(network_statistics(net, rho_neighbours="contacts").rho, rel=1e-12)
    assert row.rho_near == pytest.approx(network_statistics(net, rho_neighbours="near").rho, rel=1e-12)
    assert row.rho_near == pytest.approx(network_statistics(net).rho, rel=1e-12)  # the default (issue 25)
    assert row.degree_delaunay == pytest.approx(6.0, abs=1e-12)  # Euler on a torus
    assert row.degree_near == pytest.approx(row.nbar, abs=1 / 300)
    # the contacting-only definition is mostly definition: its null model is close to the measured rho
    assert 0 < row.null_contacts <= row.rho_contacts + 3 * row.null_std_contacts
    for name in ("contacts", "near", "delaunay"):
        assert np.isfinite(row[f"rho_{name}"]) and np.isfinite(row[f"null_{name}"])
