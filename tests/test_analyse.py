"""python -m microhom analyse: LAMMPS dump, OVAL D-file, dem packing npz; numbers against closed
forms and against the library called directly; clear errors."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).parent / "data"


def run(*args):
    return subprocess.run([sys.executable, "-m", "microhom", "analyse", *map(str, args)],
                          capture_output=True, text=True)


def test_lammps_dump_chain_of_four_disks():
    # 4 touching disks in a row in a 4 x 2.5 periodic cell: Z = 2 everywhere, a closed chain
    p = run(DATA / "radius.dump", "--kn", "2", "--json")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    assert r["file"]["format"] == "lammps-dump"
    assert r["network"]["n_contacts"] == 4
    assert r["coordination"]["z_all"] == 2.0 and r["coordination"]["hist_all"] == [0, 0, 4]
    # a periodic chain along x carries only xx: C_xxxx = kn L_c^2 N_c / A = 2 * 1 * 4 / 10
    C = np.array(r["stiffness"]["C_mandel"])
    assert C[0, 0] == pytest.approx(0.8, rel=1e-12)
    assert np.allclose(np.delete(C.ravel(), 0), 0, atol=1e-12)
    # phi = 4 pi/4 / 10 < pi/4: the theory cannot derive Nbar and says so, the rest still runs
    assert "error" in r["theory"] and "phi" in r["theory"]["error"]


def test_oval_lattice_equals_closed_form_with_kn_convention():
    # triangular lattice, D = 1, Z = 6: K = G = sqrt(3)/2 * kn/... exact and mean field coincide
    # (kn = kt); OVAL's kn multiplies half the overlap, so kn_oval = 2 gives kn = 1
    p = run(DATA / "D0001", "--kn", "2", "--kn-convention", "oval", "--json")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    assert r["network"]["kn_mean"] == 1.0
    assert r["coordination"]["z"] == 6.0
    K_closed = 6 * (np.pi / (2 * np.sqrt(3))) * 1.0 / (2 * np.pi)    # Nc phi kn / (2 pi)
    assert r["stiffness"]["K"] == pytest.approx(K_closed, rel=1e-10)
    assert r["theory"]["K_mf"] == pytest.approx(K_closed, rel=1e-12)
    assert r["structural"]["vbar"] == pytest.approx(r["structural"]["vbar_theory"], rel=1e-12)
    assert not any("OVAL" in n for n in r["notes"])       # convention given: no warning


def test_oval_without_convention_warns_in_notes():
    p = run(DATA / "D0001", "--no-exact")
    assert p.returncode == 0, p.stderr
    assert "kn_convention" in p.stdout and "notes:" in p.stdout


@pytest.fixture(scope="module")
def packing_npz(tmp_path_factory):
    from dem.packing import pack
    res = pack(150, p_over_kn=1e-3, kn=1.0, mu=0.5, mu_prep=0.05, dispersity=0.2, seed=3,
               tol_unbalanced=1e-3, tol_ke=1e-6)
    path = tmp_path_factory.mktemp("pk") / "packing.npz"
    res.save(path)
    return path, res


def test_packing_npz_matches_library(packing_npz):
    from dem.measure import pressure
    from dem.stiffness import stiffness
    from microhom.moduli import predict_from_network
    from microhom.structural_sums import network_statistics

    path, res = packing_npz
    net = res.to_network()
    p = run(path, "--prestress", "--json")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    assert r["file"]["format"] == "packing" and r["network"]["forces"]
    st = network_statistics(net)
    assert r["coordination"]["z"] == pytest.approx(st.nc, rel=1e-14)
    assert r["structural"]["rho"] == pytest.approx(st.rho, rel=1e-12)
    assert r["stress"]["pressure"] == pytest.approx(pressure(net), rel=1e-12)
    assert r["stress"]["pressure"] == pytest.approx(1e-3, rel=2e-3)   # the packing's target
    pr = predict_from_network(net, warn=False)
    assert r["theory"]["K_rho"] == pytest.approx(float(pr.K), rel=1e-12)
    ex = stiffness(net, prestress=True)
    assert r["stiffness"]["K"] == pytest.approx(ex.K, rel=1e-9)
    assert r["stiffness"]["G"] == pytest.approx(ex.G, rel=1e-9)
    assert r["comparison"]["G_mf_over_exact"] > 1.0     # mean field overestimates G


def test_table_and_csv_outputs(packing_npz):
    path, _ = packing_npz
    p = run(path)
    assert p.returncode == 0, p.stderr
    for text in ("coordination", "no rattlers", "vbar", "ebar", "(37)", "measured rho", "alpha",
                 "exact (dem.stiffness)", "pressure"):
        assert text in p.stdout, text
    p = run(path, "--csv", "--no-exact")
    assert p.returncode == 0, p.stderr
    head, row = p.stdout.strip().splitlines()
    assert "coordination.z" in head.split(",") and len(head.split(",")) == len(row.split(","))


def test_dem_io_npz_and_branch_length(tmp_path, packing_npz):
    from dem import io
    _, res = packing_npz
    net = res.to_network()
    f = tmp_path / "cfg.npz"
    io.write(f, io.Configuration.from_network(net))
    p = run(f, "--branch-length", "radii", "--json", "--no-exact")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    assert r["file"]["format"] == "npz" and r["network"]["n_contacts"] == net.n_contacts
    # |c| = r_i + r_j: vbar/(37) is exactly 1 whatever the overlaps
    assert r["structural"]["vbar"] == pytest.approx(r["structural"]["vbar_theory"], rel=1e-12)


def test_errors_name_file_line_field(tmp_path):
    bad = tmp_path / "bad.dump"
    bad.write_text("ITEM: TIMESTEP\n0\nITEM: NUMBER OF ATOMS\n2\nITEM: BOX BOUNDS pp pp pp\n0 4\n0 4\n"
                   "-0.5 0.5\nITEM: ATOMS id type radius x y z\n1 1 0.5 1 1 0\n2 1 -0.5 2 1 0\n")
    p = run(bad)
    assert p.returncode == 2
    assert "bad.dump" in p.stderr and "line 11" in p.stderr and "radius" in p.stderr
    p = run(tmp_path / "missing.dump")
    assert p.returncode == 2 and "missing.dump" in p.stderr
    p = run(bad, "--format", "nonsense")
    assert p.returncode == 2 and "unknown format" in p.stderr
    p = run(DATA / "radius.dump", "--kn", "-1")
    assert p.returncode == 2 and "kn" in p.stderr


def test_microhom_library_does_not_import_dem():
    code = ("import sys, microhom.moduli, microhom.structural_sums, microhom.network, microhom.__main__;"
            "print(any(m == 'dem' or m.startswith('dem.') for m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "False"
