"""python -m dem analyse: LAMMPS dump, OVAL D-file (the manual's layout, and a real DEMPLA file),
dem packing npz; numbers against closed forms and against the library called directly; the typed
result and the unchanged JSON/CSV layout; the notes that state every assumption; clear errors."""
import csv
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).parent / "data"


def run(*args):
    return subprocess.run([sys.executable, "-m", "dem", "analyse", *map(str, args)],
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
    # phi = 4 pi/4 / 10 < pi/4: Nbar(phi) does not exist; the theory uses Nbar = 4, flags the
    # prediction and names the substitute (issue 25; it was an error before)
    th = r["theory"]
    assert th["nbar"] == 4.0 and not th["valid_rho"] and "below pi/4" in th["reason_rho"]
    assert "Nbar = 4" in th["reason_rho"]


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
    from dem.engine.packing import PackingProtocol, pack
    res = pack(PackingProtocol(n=150, p_over_kn=1e-3, kn=1.0, mu=0.5, mu_prep=0.05,
                               dispersity=0.2, seed=3, tol_unbalanced=1e-3, tol_ke=1e-6))
    path = tmp_path_factory.mktemp("pk") / "packing.npz"
    res.save(path)
    return path, res


def test_packing_npz_matches_library(packing_npz):
    from dem.analysis.measure import pressure
    from dem.analysis.stiffness import stiffness
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


def test_hierarchy_and_closure_sections(packing_npz):
    """The analysis carries the hierarchy (bounds around the exact value, the library's numbers)
    and the statistics-only closure with its stated error."""
    from dem.analysis.stiffness import stiffness
    from microhom.closure import predict_closure
    from microhom.hierarchy import DEFAULT_TOL, relaxation_hierarchy
    from microhom.structural_sums import network_statistics

    path, res = packing_npz
    net = res.to_network()
    p = run(path, "--prestress", "--json")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    h, c, ex = r["hierarchy"], r["closure"], stiffness(net, prestress=True)
    for m in ("K", "G"):
        exact = getattr(ex, m)
        assert h[f"{m}_upper"] >= exact * (1 - 1e-10)
        assert h[f"{m}_lower"] is None or h[f"{m}_lower"] <= exact * (1 + 1e-10)
        assert abs(h[m] - exact) <= max(h[f"{m}_error"], 1e-9 * exact)
        assert r["comparison"][f"{m}_hierarchy_over_exact"] == pytest.approx(h[m] / exact, rel=1e-12)
    lib = relaxation_hierarchy(net, prestress=True, tol=DEFAULT_TOL, max_order=16)
    assert h["G_upper"] == pytest.approx(lib.G.upper, rel=1e-10) and h["order"] == lib.order
    # the JSON carries the library's validity rule (issue 22)
    assert (h["valid"], h["certified"], h["calibrated"]) == (lib.valid, lib.certified, lib.calibrated)
    st = network_statistics(net)
    cl = predict_closure(nc=st.nc, r=st.r, phi=st.phi, kt_over_kn=c["kt_over_kn"],
                         dispersity=c["dispersity"], kn=float(np.mean(net.kn)),
                         sliding_fraction=c["sliding_fraction"], rattler_fraction=st.rattler_fraction,
                         size_coordination=c["size_coordination"], p_over_kn=c["p_over_kn"],
                         psi6_local=c["psi6_local"])
    assert c["K"] == pytest.approx(float(cl.K), rel=1e-12) and c["error_G"] == pytest.approx(float(cl.error_G))
    q = run(path, "--no-hierarchy", "--json")
    assert json.loads(q.stdout)["hierarchy"] == {"error": "not computed"}
    t = run(path)
    assert "rigorous upper bound" in t.stdout and "closure (statistics only)" in t.stdout
    assert ("FLAGGED: not valid" in t.stdout) == (not lib.valid)


def test_table_and_csv_outputs(packing_npz):
    path, _ = packing_npz
    p = run(path)
    assert p.returncode == 0, p.stderr
    for text in ("coordination", "no rattlers", "vbar", "ebar", "(37)", "measured rho", "alpha",
                 "exact (dem.analysis.stiffness)", "pressure"):
        assert text in p.stdout, text
    p = run(path, "--csv", "--no-exact")
    assert p.returncode == 0, p.stderr
    head, row = csv.reader(io.StringIO(p.stdout))
    assert "coordination.z" in head and len(head) == len(row)


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
    assert p.returncode == 2 and "--format" in p.stderr and "invalid choice" in p.stderr
    p = run(DATA / "radius.dump", "--kn", "-1")
    assert p.returncode == 2 and "kn" in p.stderr


def test_microhom_library_does_not_import_dem():
    code = ("import sys, microhom.moduli, microhom.structural_sums, microhom.network, microhom.__main__;"
            "print(any(m == 'dem' or m.startswith('dem.') for m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "False"


# ---- the typed result, the unchanged JSON/CSV layout, the stated assumptions --------------------

#: section -> keys of the JSON that 'python -m microhom analyse tests/data/radius.dump --kn 2 --json'
#: printed before the command moved (the layout must not change; NaN became null)
OLD_JSON_KEYS = {
    "file": ["source", "format", "forces", "kn", "kt", "branch_length", "read_s", "analyse_s"],
    "network": ["n_particles", "n_contacts", "periodic", "kn_mean", "kt_mean", "forces"],
    "coordination": ["z_all", "z", "n_rattlers", "rattler_fraction", "hist_all", "hist"],
    "structural": ["n_particles", "n_contacts", "nc_all", "nc", "r_all", "r", "rho_all", "rho",
                   "phi", "nbar_phi", "diameter", "sliding_fraction", "vbar", "ebar",
                   "vbar_theory", "ebar_theory", "odd_norm"],
    "stress": ["error"], "theory": ["error"],
    "stiffness": ["K", "G", "K_affine", "G_affine", "C_mandel", "prestress", "n_rattlers",
                  "n_floppy", "n_unstable", "n_dof", "residual", "time_s"],
    "comparison": [], "notes": "list"}
NEW_SECTIONS = ("closure", "hierarchy")
NEW_KEYS = ("spin_arm",)
#: issue 25: rho is the paper's (near neighbours) and says what it used: three keys appended to the
#: structural section; phi < pi/4 (this file) is no longer an error, so theory and comparison fill in
NEW_STRUCTURAL = ["rho_nbar", "rho_note", "rho_neighbours"]
FILLED_SINCE_25 = ("theory", "comparison")


def run_in(capsys, *args):
    """``python -m dem analyse ARGS`` in this process (no interpreter start-up): a
    CompletedProcess-like object with returncode, stdout, stderr."""
    from types import SimpleNamespace

    from dem.__main__ import main
    capsys.readouterr()
    rc = main(["analyse", *map(str, args)])
    out = capsys.readouterr()
    return SimpleNamespace(returncode=rc, stdout=out.out, stderr=out.err)


OLD_CSV_HEADER = "file.source,file.format,file.forces,file.kn,file.kt,file.branch_length,file.read_s,file.analyse_s,network.n_particles,network.n_contacts,network.periodic,network.kn_mean,network.kt_mean,network.forces,coordination.z_all,coordination.z,coordination.n_rattlers,coordination.rattler_fraction,coordination.hist_all,coordination.hist,structural.n_particles,structural.n_contacts,structural.nc_all,structural.nc,structural.r_all,structural.r,structural.rho_all,structural.rho,structural.phi,structural.nbar_phi,structural.diameter,structural.sliding_fraction,structural.vbar,structural.ebar,structural.vbar_theory,structural.ebar_theory,structural.odd_norm,stress.error,theory.error,stiffness.K,stiffness.G,stiffness.K_affine,stiffness.G_affine,stiffness.C_mandel,stiffness.prestress,stiffness.n_rattlers,stiffness.n_floppy,stiffness.n_unstable,stiffness.n_dof,stiffness.residual,stiffness.time_s,notes"


def test_json_and_csv_layout_unchanged_and_typed_result(capsys):
    from dem.analysis.analyse import AnalysisResult, analyse_file
    from microhom.results import Result
    import dataclasses

    p = run_in(capsys, DATA / "radius.dump", "--kn", "2", "--json")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    # issue 11 added two sections (closure, hierarchy) between theory and stiffness; every older
    # section keeps its keys and its order
    assert [k for k in r if k not in NEW_SECTIONS] == list(OLD_JSON_KEYS)
    assert list(r).index("closure") == list(r).index("theory") + 1
    # issue 27 added file.spin_arm (the spin kinematics of the exact stiffness): new, not moved
    old = lambda key: (not any(f"_{n}_" in key for n in NEW_SECTIONS)   # noqa: E731 (new comparison keys)
                       and key.split(".")[-1] not in NEW_KEYS)
    got = {k: ([x for x in v if old(x)] if isinstance(v, dict) else "list") for k, v in r.items()
           if k not in NEW_SECTIONS}
    assert got["structural"] == OLD_JSON_KEYS["structural"] + NEW_STRUCTURAL
    # 4 disks in the cell: no Nbar = 4 neighbourhood fits, so V is over the contacts, and it says both
    note = r["structural"]["rho_note"]
    assert "below pi/4" in note and "contacting neighbours used" in note and r["structural"]["rho_nbar"] is None
    assert {k: v for k, v in got.items() if k not in FILLED_SINCE_25 + ("structural",)} == \
        {k: v for k, v in OLD_JSON_KEYS.items() if k not in FILLED_SINCE_25 + ("structural",)}
    assert "error" not in r["theory"] and not r["theory"]["valid_rho"]
    c = run_in(capsys, DATA / "radius.dump", "--kn", "2", "--csv")
    head = c.stdout.splitlines()[0].split(",")
    new_25 = {f"structural.{k}" for k in NEW_STRUCTURAL}
    kept = [h for h in head if h.split(".")[0] not in NEW_SECTIONS + FILLED_SINCE_25 and old(h) and h not in new_25]
    assert ",".join(kept) == ",".join(h for h in OLD_CSV_HEADER.split(",") if h.split(".")[0] not in FILLED_SINCE_25)
    res = analyse_file(DATA / "radius.dump", kn=2.0)
    assert isinstance(res, AnalysisResult) and isinstance(res, Result)
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.notes = []
    d = res.as_dict()
    d["stiffness"].pop("time_s"), r["stiffness"].pop("time_s")
    for sec in ("network", "coordination", "structural", "stiffness", "notes"):
        assert d[sec] == r[sec], sec


def test_notes_state_frame_kt_and_dispersity(tmp_path, capsys):
    """Row 14 (a 5-frame trajectory: the last frame, said), the kt = kn assumption (LAMMPS
    gran/hooke/history uses 2/7), --kt-ratio, and the identical-disk note for a bidisperse set."""
    from dem import io as dio
    rng = np.random.default_rng(0)
    L = 6.0
    xy = rng.uniform(0, L, (30, 2))
    rad = np.where(np.arange(30) % 2, 0.5, 0.7)
    f = tmp_path / "traj.dump"
    for t in range(5):
        dio.write_lammps_dump(f, dio.Configuration(positions=xy * (1 + 0.01 * t), radii=rad,
                                                   cell=np.diag([L, L]) * (1 + 0.01 * t)),
                              timestep=100 * t, append=t > 0)
    r = json.loads(run_in(capsys, f, "--json", "--no-exact").stdout)
    notes = " ".join(r["notes"])
    assert "frame 5 of 5 (timestep 400)" in notes and "--frame" in notes
    assert "kt = kn assumed" in notes and "2/7" in notes
    assert "identical disks" in notes and "max/min = 1.4" in notes
    first = json.loads(run_in(capsys, f, "--json", "--no-exact", "--frame", "1").stdout)
    assert "frame 1 of 5 (timestep 0)" in " ".join(first["notes"])
    k = json.loads(run_in(capsys, f, "--json", "--no-exact", "--kn", "7", "--kt-ratio", "0.2857142857142857").stdout)
    assert k["network"]["kt_mean"] == pytest.approx(2.0, rel=1e-12)
    assert not any("kt = kn assumed" in n for n in k["notes"])
    assert run_in(capsys, f, "--frame", "0").returncode == 2


def test_tables_carry_units(capsys):
    p = run_in(capsys, DATA / "D0001", "--kn", "2", "--kn-convention", "oval")
    assert "K [N/m]" in p.stdout and "G [N/m]" in p.stdout and "vbar [N m]" in p.stdout
    q = subprocess.run([sys.executable, "-m", "microhom", "predict"], capture_output=True, text=True)
    assert "modulus [N/m]" in q.stdout


def test_cli_messages_name_cli_flags(tmp_path, capsys):
    """Row 13: messages suggested 'pass radius=', 'Pass nbar explicitly', 'pass format=',
    "pass kn_convention='oval'" on the command line."""
    d = tmp_path / "nor.dump"
    d.write_text("ITEM: TIMESTEP\n0\nITEM: NUMBER OF ATOMS\n1\nITEM: BOX BOUNDS pp pp pp\n0 4\n0 4\n"
                 "-0.5 0.5\nITEM: ATOMS id type x y z\n1 1 1 1 0\n")
    p = run_in(capsys, d)
    assert p.returncode == 2 and "--radius" in p.stderr
    assert run_in(capsys, d, "--radius", "0.5", "--no-exact").returncode == 0
    x = tmp_path / "packing.xyz"
    x.write_text("1 2 3\n")
    p = run_in(capsys, x)
    assert p.returncode == 2 and "--format" in p.stderr
    assert "--kn-convention oval" in run_in(capsys, DATA / "D0001", "--no-exact").stdout
    q = subprocess.run([sys.executable, "-m", "microhom", "predict", "--phi", "0.5"],
                       capture_output=True, text=True)
    # below pi/4 Nbar(phi) does not exist: Nbar = 4 is used, flagged (exit 3) and named (issue 25)
    assert q.returncode == 3 and "below pi/4" in q.stdout and "Nbar = 4" in q.stdout
    for text in (p.stderr, q.stderr):
        assert "Traceback" not in text


def test_not_a_lammps_run_folder(tmp_path, capsys):
    """Row 20: "[Errno 2] No such file ... 'files/in.packing'"."""
    p = run_in(capsys, tmp_path)
    assert p.returncode == 2 and "not a LAMMPS run folder" in p.stderr and str(tmp_path) in p.stderr


def test_analyse_moved_and_console_scripts():
    p = subprocess.run([sys.executable, "-m", "microhom", "analyse", "x.dump"], capture_output=True,
                       text=True)
    assert p.returncode == 2 and "python -m dem analyse x.dump" in p.stderr
    import tomllib
    proj = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert proj["project"]["scripts"] == {"microhom": "microhom.__main__:main",
                                          "dem": "dem.__main__:main"}
    h = subprocess.run([sys.executable, "-m", "dem", "analyse", "--help"], capture_output=True,
                       text=True)
    assert "exit codes" in h.stdout and "141" in h.stdout


def test_kt_ratio_is_a_ratio_of_the_physical_stiffnesses_for_oval_files(tmp_path):
    """The same packing written as a LAMMPS dump (kn = 1) and as an OVAL D-file (kn_OVAL = 2, which
    multiplies half the overlap) gives the same network and moduli with kt = 2/7 kn."""
    from dem import io as dio
    from dem.analysis.analyse import load_network
    from microhom import lattices

    net = lattices.triangular(6, 6, diameter=1.0)
    cfg = dio.Configuration.from_network(net)
    dio.write(tmp_path / "p.dump", cfg)
    dio.write(tmp_path / "D0001", cfg, format="oval")
    a, _ = load_network(tmp_path / "p.dump", kn=1.0, kt_ratio=2 / 7)
    b, _ = load_network(tmp_path / "D0001", format="oval", kn=2.0, kt_ratio=2 / 7, kn_convention="oval")
    assert a.n_contacts == b.n_contacts > 0
    assert np.allclose(a.kn, 1.0) and np.allclose(b.kn, 1.0)
    assert np.allclose(a.kt, 2 / 7) and np.allclose(b.kt, 2 / 7)


# ---- the JSON, CSV and table of the committed test files, byte for byte (issue 23.3) ----------
# tests/data/analyse_expected.json was written by the code BEFORE AnalysisResult held the typed
# results (run this file as a script to rewrite it; only ever on purpose): the typed result must
# print exactly what the dict sections printed. Wall times and the checkout's path are masked.

#: (name, command-line arguments after the file) on the committed files of tests/data
GOLDEN_FILES = [
    ("radius.dump", ["--kn", "2"]),                           # theory flagged, stress n/a
    ("D0001", ["--kn", "2", "--kn-convention", "oval"]),       # every section, the lattice
    ("D0001", ["--no-exact", "--no-hierarchy"]),               # "not computed", OVAL note
    ("frictionless_lowp.data", ["--kt", "0", "--prestress", "--hierarchy-tol", "0.5"]),  # warnings
    ("diameter.dump", []),                                     # not jammed, open
    ("sheared.data", ["--rho-neighbours", "contacts", "--alpha", "1.5", "--branch-length", "radii"]),
    ("triclinic.dump", ["--spin-arm", "contact", "--min-contacts", "2"]),
    ("ortho.data", ["--kt-ratio", "0.2857"]),
]
_TIME_KEYS = ("read_s", "analyse_s", "time_s")


def _golden_networks():
    """In-memory networks for the sections no committed file reaches: contact forces (stress,
    pre-stress from the file's fn) and an open cluster (no hierarchy)."""
    from dataclasses import replace

    from microhom import lattices
    from microhom.network import from_overlaps
    lat = lattices.triangular(4, 4, diameter=1.0, kn=1.0, kt=0.5)
    forced = replace(lat, fn=np.full(lat.n_contacts, 1e-2), ft=np.zeros(lat.n_contacts))
    ring = np.array([[np.cos(a), np.sin(a)] for a in np.arange(6) * np.pi / 3])
    cluster = from_overlaps(np.vstack([[0.0, 0.0], 0.99 * ring]), 0.5, None, kn=1.0, kt=1.0)
    return [("lattice with forces, prestress", forced, {"prestress": True}),
            ("open cluster", cluster, {})]


def _mask_text(text):
    import re
    text = text.replace(str(DATA), "tests/data")
    text = re.sub(r'("(?:%s)": )[-+0-9.eE]+' % "|".join(_TIME_KEYS), r'\1"<wall time>"', text)
    return re.sub(r"\b\d+\.\d{3} s\b", "<t> s", text)


def _mask_csv(text):
    head, *rows = list(csv.reader(io.StringIO(text)))
    for row in rows:
        for i, h in enumerate(head):
            if h.split(".")[-1] in _TIME_KEYS:
                row[i] = "<wall time>"
    buf = io.StringIO()
    csv.writer(buf).writerows([head, *rows])
    return buf.getvalue().replace(str(DATA), "tests/data")


def _golden_outputs(capsys):
    """name -> {"json", "csv", "table"}: the command line's three outputs, masked."""
    from dem.analysis import analyse as dan
    out = {}
    for name, args in GOLDEN_FILES:
        key = " ".join([name, *args])
        got = {}
        for flag in ("--json", "--csv", None):
            p = run_in(capsys, DATA / name, *args, *([flag] if flag else []))
            assert p.returncode == 0, (key, p.stderr)
            got[(flag or "--table")[2:]] = _mask_csv(p.stdout) if flag == "--csv" else _mask_text(p.stdout)
        out[key] = got
    for name, net, kw in _golden_networks():
        res = dan.analyse(net, **kw)
        flat = dan.flatten(res)
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(flat))
        w.writeheader()
        w.writerow(flat)
        out[name] = {"json": _mask_text(json.dumps(res.as_dict(), indent=1, allow_nan=False) + "\n"),
                     "csv": _mask_csv(buf.getvalue()), "table": _mask_text(dan.format_table(res) + "\n")}
    return out


GOLDEN = DATA / "analyse_expected.json"


_NUMBER = re.compile(r"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")


def _same_up_to_last_digits(a, b, rel=1e-9):
    """Texts equal character for character outside their numbers; each number equal, or within
    ``rel`` or one unit of its last printed digit (the sparse solver and BLAS in use may differ
    in the last bits of a hierarchy or stiffness figure: SuperLU, CHOLMOD, PARDISO)."""
    if _NUMBER.split(a) != _NUMBER.split(b):
        return False
    for x, y in zip(_NUMBER.findall(a), _NUMBER.findall(b)):
        if x == y:
            continue
        fx, fy = float(x), float(y)
        mant = x.split("e")[0].split("E")[0]
        decimals = len(mant.split(".")[1]) if "." in mant else 0
        exp = int(x.lower().split("e")[1]) if "e" in x.lower() else 0
        unit = 10.0 ** (exp - decimals)
        if abs(fx - fy) > max(rel * max(abs(fx), abs(fy)), 1.0001 * unit):
            return False
    return True


def test_the_number_comparison_has_teeth():
    assert _same_up_to_last_digits('{"K": 0.32235, "n": 3}', '{"K": 0.32236, "n": 3}')
    assert not _same_up_to_last_digits('{"K": 0.32235, "n": 3}', '{"K": 0.32245, "n": 3}')
    assert not _same_up_to_last_digits('{"K": 0.32235, "n": 3}', '{"G": 0.32235, "n": 3}')
    assert not _same_up_to_last_digits("0.3223546492995957", "0.3222815675738244")


def test_outputs_unchanged_byte_for_byte(capsys):
    """The JSON, CSV and table of every golden case equal what the dict-section code printed
    (tests/data/analyse_expected.json; wall times masked): character for character outside the
    numbers, each number to 1e-9 or its last printed digit."""
    expected = json.loads(GOLDEN.read_text())
    got = _golden_outputs(capsys)
    assert list(got) == list(expected)
    for case, outputs in expected.items():
        for kind, text in outputs.items():
            assert _same_up_to_last_digits(got[case][kind], text), f"{case}: {kind} changed"



# ---- one result vocabulary: the sections are the library's typed results (issue 23.3) ---------

def test_sections_are_the_typed_results_on_the_lattice(capsys):
    """On the triangular lattice (D = 1, Z = 6, kn = kt = 1, affine) every estimate has the closed
    form K = Nc phi kn / (2 pi); the typed fields carry it, and the JSON is their view."""
    import dataclasses

    from dem.analysis.analyse import (AnalysisResult, ClosureInputs, Comparison, FileInfo,
                                      NetworkSummary, SectionWarnings, TheoryResult, analyse_file)
    from dem.analysis.measure import Coordination
    from dem.analysis.stiffness import StiffnessResult
    from microhom.closure import ClosurePrediction
    from microhom.hierarchy import HierarchyResult
    from microhom.moduli import Prediction
    from microhom.results import Result
    from microhom.structural_sums import NetworkStatistics

    res = analyse_file(DATA / "D0001", kn=2.0, kn_convention="oval")
    K = 6 * (np.pi / (2 * np.sqrt(3))) * 1.0 / (2 * np.pi)
    assert isinstance(res.file, FileInfo) and res.file.format == "oval"
    assert isinstance(res.network, NetworkSummary) and res.network.n_contacts == 48
    assert isinstance(res.coordination, Coordination) and res.coordination.z == 6.0
    assert isinstance(res.structural, NetworkStatistics)
    assert res.structural.vbar == pytest.approx(res.structural.vbar_theory, rel=1e-12)
    assert isinstance(res.theory, TheoryResult)
    assert isinstance(res.theory.rho_prediction, Prediction) and isinstance(res.theory.alpha_prediction, Prediction)
    assert float(res.theory.rho_prediction.K_mf) == pytest.approx(K, rel=1e-12)
    assert isinstance(res.closure, ClosurePrediction) and isinstance(res.closure_inputs, ClosureInputs)
    assert res.closure_inputs.nc == 6.0
    assert isinstance(res.hierarchy, HierarchyResult)
    assert res.hierarchy.K.upper == pytest.approx(K, rel=1e-10)          # affine lattice: exact
    assert isinstance(res.stiffness, StiffnessResult) and res.stiffness.K == pytest.approx(K, rel=1e-10)
    assert np.asarray(res.stiffness.C_mandel).shape == (3, 3)
    assert isinstance(res.warnings, SectionWarnings) and isinstance(res.comparison, Comparison)
    assert res.comparison.K_hierarchy_over_exact == pytest.approx(1.0, rel=1e-10)
    assert res.comparison.K_mf_over_exact == float(res.theory.rho_prediction.K_mf) / res.stiffness.K
    # the JSON is a view of these fields, value for value
    d = res.as_dict()
    assert d["hierarchy"]["K_upper"] == res.hierarchy.K.upper and d["hierarchy"]["order"] == res.hierarchy.order
    assert d["theory"]["K_rho"] == float(res.theory.rho_prediction.K)
    assert d["theory"]["G_alpha"] == float(res.theory.alpha_prediction.G)
    assert d["stiffness"]["C_mandel"] == np.asarray(res.stiffness.C_mandel).tolist()
    assert d["structural"]["rho"] == res.structural.rho and d["closure"]["K"] == float(res.closure.K)
    assert d["file"]["read_s"] == res.file.read_s
    # every section is a frozen Result (or a plain wall time / the notes)
    for f in dataclasses.fields(AnalysisResult):
        v = getattr(res, f.name)
        if f.name in ("hierarchy_s", "notes", "rho_neighbours"):
            continue
        assert isinstance(v, Result) and type(v).__dataclass_params__.frozen, f.name
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(res, f.name, None)


def test_a_section_not_computed_says_why_and_raises():
    from dem.analysis.analyse import SectionError, analyse, format_table
    from microhom import lattices

    res = analyse(lattices.triangular(4, 4), exact=False, hierarchy=False)
    for sec in (res.stiffness, res.hierarchy, res.stress):
        assert isinstance(sec, SectionError)
    assert res.stiffness == SectionError("not computed") and res.hierarchy_s is None
    with pytest.raises(AttributeError, match=r"'K': this section was not computed \(not computed\)"):
        res.stiffness.K
    with pytest.raises(AttributeError, match="no contact forces"):
        res.stress.pressure
    assert res.as_dict()["stress"] == {"error": "no contact forces in the file"}
    assert res.as_dict()["comparison"] == {} and res.comparison.K_mf_over_exact is None
    assert res.file is None and res.as_dict()["file"] == {}
    assert "exact: n/a (not computed)" in format_table(res)
    with pytest.raises(TypeError, match="AnalysisResult"):
        format_table(res.as_dict())


def test_a_missing_field_raises_never_none():
    """The views name every field they print: a result without one raises (no getattr default
    that would turn a renamed field into a silent None in the report)."""
    import dataclasses
    import re
    from types import SimpleNamespace

    from dem.analysis import analyse as dan
    from microhom import lattices
    from microhom.structural_sums import network_statistics

    st = network_statistics(lattices.triangular(4, 4))
    fields = {f.name: getattr(st, f.name) for f in dataclasses.fields(st)}
    assert dan._statistics_view(SimpleNamespace(**fields), "near")["rho_note"] == st.rho_note
    del fields["rho_note"]
    with pytest.raises(AttributeError, match="rho_note"):
        dan._statistics_view(SimpleNamespace(**fields), "near")
    src = Path(dan.__file__).read_text()
    assert not re.search(r"getattr\([^()]*,[^()]*,", src), "a getattr with a default"
    assert ".get(" not in src.split("def format_table")[1], "the table reads the typed results"


if __name__ == "__main__":      # rewrite the expected outputs (only on purpose: they are the contract)
    class _Cap:
        def readouterr(self):
            from types import SimpleNamespace
            o, e = sys.stdout.getvalue(), sys.stderr.getvalue()
            sys.stdout.seek(0), sys.stdout.truncate(), sys.stderr.seek(0), sys.stderr.truncate()
            return SimpleNamespace(out=o, err=e)
    real = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = io.StringIO(), io.StringIO()
    try:
        outputs = _golden_outputs(_Cap())
    finally:
        sys.stdout, sys.stderr = real
    GOLDEN.write_text(json.dumps(outputs, indent=1) + "\n")
    print(f"wrote {GOLDEN}: {len(outputs)} cases")
