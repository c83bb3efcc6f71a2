"""Faults injected into `dem pack` and its writers (issue 15 rows 1, 2, 4, 11, 16 and the friction
rows): each case gives a clean answer, a documented exit code and keeps the checkpoint."""
import csv
import errno
import os
import stat
import subprocess
import sys

import numpy as np
import pytest

import dem.__main__ as cli
import dem.analysis.plot
from dem import runtime
from dem.engine.integrate import Simulation
from dem.engine.packing import BYTES_PER_PARTICLE, PackingProtocol, PackingResult, pack
from dem.engine.state import State

BASE = ["--n", "40", "--p-over-kn", "1e-3", "--mu", "0.3", "--mu-prep", "0.3", "--seed", "2",
        "--tol-unbalanced", "1e-3", "--no-progress"]
PROTO = PackingProtocol(n=40, p_over_kn=1e-3, kn=1.0, mu=0.3, mu_prep=0.3, seed=2,
                        tol_unbalanced=1e-3, tol_ke=1e-6)


def _csv(path):
    with open(path) as fh:
        return {row["quantity"]: row["value"] for row in csv.DictReader(fh)}


def test_resume_after_a_finished_run_reports_its_real_criteria(tmp_path):
    """Row 1 (API): the final checkpoint of a converged run resumes to its own report."""
    ck = tmp_path / "ck.npz"
    first = pack(PROTO, checkpoint=ck)
    assert first.report["converged"] and ck.exists()
    again = pack(PROTO, checkpoint=ck)
    r0, r1 = first.report, again.report
    assert r1["already_converged"] and r1["resumed"] and r1["converged"]
    for k in ("steps", "pressure", "rel_p_err", "unbalanced", "ke_rel", "particle_steps_per_s", "Z"):
        assert r1[k] == r0[k], k
    assert 0 < r1["rel_p_err"] < 1e-3 and np.isfinite(r1["unbalanced"])
    assert np.array_equal(again.state.x, first.state.x)
    # the checkpoint of another protocol is refused, naming the fields that differ
    with pytest.raises(ValueError, match=r"another protocol \(fields \['mu'\] differ\)"):
        pack(PROTO.replace(mu=0.2), checkpoint=ck)


def test_kill_after_summary_then_resume(tmp_path, monkeypatch, capsys):
    """Row 1 (CLI) and the `--out ref/p.npz` friction row: the folder is created; a kill after
    the summary CSV (before the checkpoint is removed) then --resume gives the real criteria."""
    out = tmp_path / "ref" / "p.npz"
    real = cli._print_table

    def killed(rows, stream):
        raise KeyboardInterrupt    # stands for kill -9 right after the outputs were written

    monkeypatch.setattr(cli, "_print_table", killed)
    assert cli.main(["pack", *BASE, "--out", str(out)]) == cli.EXIT_INTERRUPTED
    first = _csv(tmp_path / "ref" / "p_summary.csv")
    assert (tmp_path / "ref" / "p.checkpoint.npz").exists()
    monkeypatch.setattr(cli, "_print_table", real)
    capsys.readouterr()
    assert cli.main(["pack", "--resume", "--no-progress", "--out", str(out)]) == 0
    assert "already converged" in capsys.readouterr().err
    again = _csv(tmp_path / "ref" / "p_summary.csv")
    for k in ("converged", "steps", "pressure", "rel_p_err", "unbalanced", "ke_rel",
              "particle_steps_per_s"):
        assert again[k] == first[k], k
    assert float(again["rel_p_err"]) < 1e-3 and again["converged"] == "True"
    assert not (tmp_path / "ref" / "p.checkpoint.npz").exists()


def test_unwritable_out_folder_is_found_before_computing(tmp_path, monkeypatch, capsys):
    """Row 2: a folder that cannot be made or written -> one line with the path, exit 1, and
    nothing computed (the packer is never called)."""
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setattr(cli, "pack", lambda *a, **k: pytest.fail("computed before the check"))
    assert cli.main(["pack", *BASE, "--out", str(blocker / "p.npz")]) == cli.EXIT_MACHINE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(blocker) in err[0] and "Traceback" not in err[0]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a folder without write permission")
def test_read_only_folder(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        assert cli.main(["pack", *BASE, "--out", str(ro / "p.npz")]) == cli.EXIT_MACHINE
        assert str(ro) in capsys.readouterr().err
    finally:
        ro.chmod(stat.S_IRWXU)


def _full_disk_after(n_ok, monkeypatch):
    """atomic_write raises ENOSPC after ``n_ok`` successful writes."""
    real = runtime.atomic_write
    count = [0]

    def writer(path, write, binary=True):
        count[0] += 1
        if count[0] > n_ok:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), os.fspath(path))
        return real(path, write, binary)

    monkeypatch.setattr("dem.engine.state.atomic_write", writer)
    monkeypatch.setattr("dem.engine.packing.atomic_write", writer)


def test_full_disk_during_the_run_keeps_the_checkpoint(tmp_path, monkeypatch, capsys):
    """Row 2: the second checkpoint write fails -> exit 1, one line, the first checkpoint kept
    intact, no temporary file left."""
    _full_disk_after(1, monkeypatch)
    out = tmp_path / "p.npz"
    rc = cli.main(["pack", *BASE, "--out", str(out), "--checkpoint-every", "500",
                   "--checkpoint-seconds", "1e9"])
    assert rc == cli.EXIT_MACHINE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "p.checkpoint.npz" in err[0] and "No space left" in err[0]
    assert State.load(tmp_path / "p.checkpoint.npz").step == 500
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".tmp_")]


def test_full_disk_while_writing_outputs_then_resume(tmp_path, monkeypatch, capsys):
    """Row 1 variant: the PNG cannot be written (disk full) -> exit 1 with the checkpoint kept;
    after space is freed, --resume finishes with the stored criteria."""
    def full(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "p.png"))

    monkeypatch.setattr(dem.analysis.plot, "plot_packing", full)
    out = tmp_path / "p.npz"
    assert cli.main(["pack", *BASE, "--out", str(out)]) == cli.EXIT_MACHINE
    err = capsys.readouterr().err
    assert "p.png" in err and "--resume" in err and "Traceback" not in err
    monkeypatch.undo()
    assert cli.main(["pack", "--resume", "--no-progress", "--out", str(out)]) == 0
    r = PackingResult.load(out).report
    assert r["converged"] and r["rel_p_err"] < 1e-3 and np.isfinite(r["unbalanced"])


def test_huge_n_is_refused_up_front(capsys):
    """Row 4: 1e9 disks need ~270 GB: refused before anything is allocated."""
    for text in ("1000000000", "1e9"):
        assert cli.main(["pack", "--n", text, "--no-progress"]) == cli.EXIT_BAD_INPUT
        err = capsys.readouterr().err
        assert "--n" in err and f"{BYTES_PER_PARTICLE} B per particle" in err and "available" in err
        assert "allowed: n <=" in err
    with pytest.raises(ValueError, match="n = 1000000000"):
        pack(PackingProtocol(n=10 ** 9))


_KILL_MID_WRITE = """
import os, sys
from dem.runtime import atomic_write
def write(fh):
    fh.write(b"x" * 100000)
    fh.flush()
    os._exit(9)           # the process dies in the middle of the write
atomic_write(sys.argv[1], write)
"""


def test_orphan_temporaries_of_a_killed_write_are_removed_on_resume(tmp_path):
    """Row 11: a process killed during a checkpoint write leaves .tmp_<name>.*; resuming removes
    it (and only it)."""
    ck = tmp_path / "ck.npz"
    pack(PROTO, checkpoint=ck, max_steps=1000)
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    p = subprocess.run([sys.executable, "-c", _KILL_MID_WRITE, str(ck)], env=env)
    assert p.returncode == 9
    orphans = [f for f in os.listdir(tmp_path) if f.startswith(".tmp_ck.npz.")]
    assert len(orphans) == 1
    other = tmp_path / ".tmp_other.npz.abc.npz"
    other.write_bytes(b"someone else's")
    pack(PROTO, checkpoint=ck, max_steps=1100)
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".tmp_ck.npz.")]
    assert other.exists()
    assert State.load(ck).step == 1100
    # the CLI also removes those of its packing file (a kill while the outputs were written)
    orphan = tmp_path / ".tmp_p.npz.xyz.npz"
    orphan.write_bytes(b"half a packing")
    assert cli.main(["pack", *BASE, "--out", str(tmp_path / "p.npz")]) == 0
    assert not orphan.exists() and other.exists()


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_written_files_follow_the_umask(tmp_path, mask):
    """Row 16: packing and checkpoint files get 0666 less the umask (mkstemp gave 0600)."""
    old = os.umask(mask)
    try:
        r = pack(PROTO.replace(n=30), max_steps=200, checkpoint=tmp_path / "ck.npz")
        r.save(tmp_path / "p.npz")
    finally:
        os.umask(old)
    for f in ("ck.npz", "p.npz"):
        assert stat.S_IMODE(os.stat(tmp_path / f).st_mode) == 0o666 & ~mask, f


def test_checkpoint_every_means_steps_on_the_cli_too(tmp_path, monkeypatch, capsys):
    """Friction row: --checkpoint-every counts steps, as checkpoint_every in the API;
    --checkpoint-seconds counts wall time."""
    orig = Simulation.run

    def interrupted(self, n, **kw):
        if self.state.step >= 1250:
            raise KeyboardInterrupt
        return orig(self, n, **kw)

    monkeypatch.setattr(Simulation, "run", interrupted)
    out = tmp_path / "p.npz"
    rc = cli.main(["pack", *BASE, "--out", str(out), "--checkpoint-every", "600",
                   "--checkpoint-seconds", "1e9"])
    assert rc == cli.EXIT_INTERRUPTED
    assert State.load(tmp_path / "p.checkpoint.npz").step == 1200
