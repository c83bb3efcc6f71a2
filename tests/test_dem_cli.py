"""The DEM command line (python -m dem pack): every output written and readable, bit-exact resume
of an interrupted run, bad input exits 2 naming the option, help text with units."""
import csv
import os
import subprocess
import sys

import numpy as np
import pytest

from dem import io as dio
from dem.engine.packing import PackingResult

BASE = ["--n", "120", "--p-over-kn", "1e-3", "--mu-prep", "0.1", "--mu", "0.49", "--seed", "2",
        "--no-progress"]


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "dem", "pack", *args], capture_output=True,
                          text=True, cwd=cwd)


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    d = tmp_path_factory.mktemp("straight")
    p = run(*BASE, "--out", str(d / "pk.npz"))
    return d, p


def test_cli_writes_every_output(straight):
    d, p = straight
    assert p.returncode == 0, p.stderr
    for name in ("pk.npz", "pk_summary.csv", "pk.png", "pk.lammpstrj", "pk.vtu"):
        assert (d / name).stat().st_size > 0, name
    assert not (d / "pk.checkpoint.npz").exists()  # removed after a converged run
    res = PackingResult.load(d / "pk.npz")
    assert res.report["converged"] and res.report["n"] == 120
    net = res.to_network()
    # the same file read as a dem.io configuration: same disks, same cell, same contacts
    cfg = dio.read(d / "pk.npz")
    assert cfg.n_particles == 120 and np.array_equal(cfg.cell, res.state.h)
    assert np.array_equal(cfg.radii, res.state.radius)
    assert cfg.network(kn=1.0).n_contacts == net.n_contacts
    dump = dio.read(d / "pk.lammpstrj")
    assert dump.n_particles == 120 and np.allclose(dump.cell, res.state.h)
    with open(d / "pk_summary.csv") as fh:
        rows = {(r["section"], r["quantity"]): r["value"] for r in csv.DictReader(fh)}
    # the table holds the packing report and the measurements; the pressure meets its criterion
    for key in ("steps", "wall_s", "psi6", "rel_p_err", "unbalanced", "ke_rel", "converged"):
        assert ("packing", key) in rows, key
    for key in ("nc", "nc_all", "rattler_fraction", "pressure", "fabric_anisotropy", "nbar_delaunay"):
        assert ("measure", key) in rows, key
    assert float(rows[("measure", "pressure")]) == pytest.approx(1e-3, rel=1e-3)
    assert float(rows[("packing", "unbalanced")]) < 1e-5
    assert "nc_all" in p.stdout and "psi6" in p.stdout  # the printed table


def test_resume_after_interruption_is_bit_exact(straight, tmp_path):
    d, p = straight
    full = PackingResult.load(d / "pk.npz")
    steps = full.report["steps"]
    out = str(tmp_path / "pk.npz")
    # interrupted: not converged within a small step budget (not a multiple of the check period)
    first = run(*BASE, "--out", out, "--max-steps", str(steps // 2 + 37))
    assert first.returncode == 3, first.stderr
    assert "NOT CONVERGED" in first.stderr
    assert PackingResult.load(out).report["converged"] is False  # outputs written and flagged
    assert (tmp_path / "pk.checkpoint.npz").exists()
    # a fresh start over a checkpoint is refused
    again = run(*BASE, "--out", out)
    assert again.returncode == 2 and "--resume" in again.stderr
    resumed = run("--resume", "--no-progress", "--out", out)
    assert resumed.returncode == 0, resumed.stderr
    back = PackingResult.load(out)
    assert back.report["resumed"] and back.report["steps"] == steps
    for name in ("x", "v", "omega", "h", "nl_ft"):
        assert np.array_equal(getattr(back.state, name), getattr(full.state, name)), name
    assert np.array_equal(dio.read(out).positions, dio.read(d / "pk.npz").positions)


@pytest.mark.parametrize("args, option, text", [
    (["--n", "1"], "--n", "an integer in [2, 1e9], got 1.0"),
    (["--n", "50", "--p-over-kn", "-1e-4"], "--p-over-kn", "(0, 0.1]"),
    (["--n", "50", "--mu", "-0.1"], "--mu", "[0, 10]"),
    (["--n", "50", "--dispersity", "0.7"], "--dispersity", "[0, 0.5)"),
    (["--n", "50", "--kt-over-kn", "20"], "--kt-over-kn", "[0, 10]"),
    (["--n", "50", "--tol-unbalanced", "2"], "--tol-unbalanced", "(0, 1)"),
    (["--n", "50", "--damping-compaction", "1"], "--damping-compaction", "None or in [0, 1)"),
    (["--n", "50", "--kn", "nan"], "--kn", "> 0 [N/m]"),
    (["--n", "50", "--phi0", "0.5", "--no-gas-overlaps"], "--phi0", "(0, 0.45)"),
    (["--n", "50", "--check-every", "2.5"], "--check-every", "an integer >= 1"),
    (["--n", "50", "--checkpoint-seconds", "-1"], "--checkpoint-seconds", ">= 0 [s]"),
    (["--n", "50", "--checkpoint-every", "0"], "--checkpoint-every", ">= 1"),
    (["--n", "50", "--threads", "0"], "--threads", "[1, 1024]"),
    (["--n", "50", "--max-steps", "abc"], "--max-steps", "an integer >= 1"),
    (["--n", "50", "--p-target", "100"], "--p-target", "--kn"),
    (["--n", "50", "--p-target", "1e3", "--kn", "1e3"], "--p-target", "(0, 0.1]"),
    (["--n", "50", "--p-target", "1", "--kn", "1e3", "--p-over-kn", "1e-3"], "--p-target",
     "not both"),
    (["--n", "50", "--out", "x.txt"], "--out", ".npz"),
    (["--resume"], "--resume", "checkpoint"),
    (["--n", "abc"], "--n", "an integer in [2, 1e9], got 'abc'"),
    (["--n", "2.5"], "--n", "an integer in [2, 1e9], got 2.5"),
    (["--n", "1e10"], "--n", "an integer in [2, 1e9], got 10000000000.0"),
    (["--n", "1e9"], "--n", "allowed: n <="),     # in the protocol's range, beyond the memory
])
def test_bad_input_exits_2_naming_the_option(tmp_path, args, option, text):
    p = run(*args, "--no-progress", cwd=tmp_path)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert option in p.stderr and text in p.stderr, p.stderr
    assert not list(tmp_path.iterdir())  # nothing written


def test_absolute_units(tmp_path):
    out = tmp_path / "si.npz"
    p = run("--n", "60", "--p-target", "2e3", "--kn", "1e6", "--mu", "0", "--mu-prep", "0",
            "--dispersity", "0.2", "--tol-unbalanced", "1e-3", "--no-progress", "--out", str(out))
    assert p.returncode == 0, p.stderr
    r = PackingResult.load(out).report
    assert r["p_over_kn"] == pytest.approx(2e-3, rel=1e-3) and r["kn"] == 1e6
    assert r["p_target"] == pytest.approx(2e3, rel=1e-15)
    proto = PackingResult.load(out).protocol
    assert proto.kn == 1e6 and proto.p_over_kn == 2e3 / 1e6 and proto.dispersity == 0.2


def test_help_explains_units():
    p = run("--help")
    assert p.returncode == 0
    text = " ".join(p.stdout.split())
    for s in ("p/kn", "[N/m]", "SECONDS", "--resume", "--checkpoint-every", "dimensionless",
              "unbalanced force ratio", "exit codes", "force per length", "247 B per particle"):
        assert s in text, s
    # one option per protocol field, with the protocol's own range text and default
    from dem.engine.packing import PackingProtocol
    for name, (default, prm) in PackingProtocol.params().items():
        opt = "--" + name.replace("_", "-")
        assert opt in text, opt
        if prm.kind != "bool":
            assert prm.allowed_text() in text, (opt, prm.allowed_text())


def test_unstable_run_exits_4_and_keeps_checkpoint(tmp_path, monkeypatch, capsys):
    from dem.__main__ import main
    from dem.engine.integrate import Simulation
    from dem.engine.state import State

    orig = Simulation.run

    def poisoned(self, n, **kw):
        out = orig(self, n, **kw)
        if self.state.step >= 1050:
            self.state.v[0, 0] = np.nan
        return out

    monkeypatch.setattr(Simulation, "run", poisoned)
    out = tmp_path / "u.npz"
    rc = main(["pack", *BASE, "--out", str(out), "--checkpoint-seconds", "1e-9"])
    assert rc == 4
    err = capsys.readouterr().err
    assert "unstable" in err and "NaN" in err and "step 1000" in err
    assert State.load(tmp_path / "u.checkpoint.npz").step == 1000
    assert not out.exists()
