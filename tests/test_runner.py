"""The resumable case runner: resume, failures recorded, Dask gives the serial table bit for bit."""
import pandas as pd
import pytest

from studies.runner import TIMING_COLUMNS, case_id, demo_case, run_cases


def cases(n=6):
    return [{"seed": s, "n": 200, "kt_over_kn": kt} for s in range(n // 2) for kt in (0.0, 1.0)]


def test_serial_resume_and_failure(tmp_path):
    out = tmp_path / "t.csv"
    cs = cases()
    first = run_cases(demo_case, cs[:3], out, progress=False)
    assert list(first["status"]) == ["ok"] * 3
    calls = []

    def counting(case):
        calls.append(case_id(case))
        return demo_case(case)

    bad = {"seed": 99, "n": 200, "fail": True}
    full = run_cases(counting, cs + [bad], out, progress=False)
    assert calls == [case_id(c) for c in cs[3:] + [bad]]  # finished cases were skipped
    assert list(full["case_id"]) == [case_id(c) for c in cs + [bad]]  # ordered like the case list
    assert full["status"].tolist()[-1] == "error" and "asked to fail" in full["error"].tolist()[-1]
    assert (full["status"][:-1] == "ok").all()
    # the resumed rows equal a fresh serial run
    fresh = run_cases(demo_case, cs, tmp_path / "fresh.csv", progress=False)
    cols = [c for c in fresh.columns if c not in TIMING_COLUMNS]
    pd.testing.assert_frame_equal(full[cols].iloc[:-1].reset_index(drop=True), fresh[cols])


def test_dask_local_cluster_matches_serial_bit_for_bit(tmp_path):
    pytest.importorskip("dask.distributed", reason="Dask is the optional 'dist' extra; CI installs it")
    cs = cases(8)
    serial = run_cases(demo_case, cs, tmp_path / "serial.csv", progress=False)
    dist = run_cases(demo_case, cs, tmp_path / "dask.csv", scheduler="local", workers=2, progress=False)
    cols = [c for c in serial.columns if c not in TIMING_COLUMNS]
    pd.testing.assert_frame_equal(serial[cols], dist[cols], check_exact=True)
