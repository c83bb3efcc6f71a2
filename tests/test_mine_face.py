"""The advancing face (quasi-static stages, energy partition) and Salamon's stability check
(dem.scenes.mine.face)."""
from __future__ import annotations

import numpy as np
import pytest

from dem.scenes.mine import MineParams, build_scene
from dem.scenes.mine.excavation import static_excavation
from dem.scenes.mine.face import (advance_face, overburden_stiffness, probe_stiffness, salamon_verdict)

SMALL = dict(width=6.0, height=5.0, seam_top=2.5, elastic_layer=1.0, floor="rock", floor_layer=1.0, loading="spring",
             absorbing=True, K0=0.6, n_disl=0, gas="none", ramp_time=0.005)
"""A 150-cell scene: the adit, a rock floor, the overburden spring and absorbing boundaries."""
EK_TOL = 1e-5


@pytest.fixture(scope="module")
def elastic_face():
    return advance_face(MineParams(**SMALL, elastic=True), n_steps=2, ek_tol=EK_TOL)


def test_face_stages_are_quasi_static_and_balance_energy(elastic_face):
    """Every stage meets the kinetic-energy criterion (Ek over the last 5 ms <= 1e-5 of the stage's
    released work) and its energy balance closes to 1e-4 of the boundary work."""
    fa = elastic_face
    assert len(fa.stages) == 3 and [s.face_m for s in fa.stages] == [0.0, 0.5, 1.0]
    for s in fa.stages:
        assert s.converged and s.Ek_end_J_per_m <= EK_TOL * s.released_J_per_m
        total = s.W_boundary_J_per_m + s.released_J_per_m
        assert abs(s.residual_J_per_m) < 1e-4 * total, (s.stage, s.residual_J_per_m, total)
        bal = (s.W_boundary_J_per_m - s.released_J_per_m + s.W_gas_J_per_m
               - (s.dU_J_per_m + s.Ek_end_J_per_m + s.D_interfaces_J_per_m + s.D_radiated_J_per_m))
        assert abs(bal - s.residual_J_per_m) < 0.05 * total        # Ek_end (synchronous) vs shadow Ek
        assert s.n_removed == (0 if s.stage == 0 else 5) and s.n_broken_new == 0
    assert fa.k_overburden_Pa_per_m == pytest.approx(overburden_stiffness(MineParams(**SMALL)))
    assert fa.k_overburden_Pa_per_m == pytest.approx(60e9 / 50.0)     # (lambda + 2 mu) / 50 m for E 50 GPa, nu 1/4


def test_elastic_staged_face_equals_one_static_excavation(elastic_face):
    """Elastic, the staged quasi-static face ends where one static solve of the final opening does
    (path independence): within 1 % of the displacement."""
    big = build_scene(MineParams(**SMALL, elastic=True, adit_width=3.0 + 2 * 1.0))
    du, _ = static_excavation(big.model)
    u_direct = big.model.u0 + du
    u_staged = elastic_face.final.u
    assert u_staged.shape == u_direct.shape
    err = np.linalg.norm(u_staged - u_direct) / np.linalg.norm(du)
    assert err < 1e-2, err


def test_elastic_wedge_stiffens_and_is_stable(elastic_face):
    """Without strength limits the wedge picks up the load of each removed slice: its secant
    stiffness is positive, the open-crack and glued bounds of the local mine stiffness coincide
    (no crack), and Salamon says stable."""
    st = elastic_face.stages
    for s in st[1:]:
        assert s.k_secant_N_per_m2 > 0
        assert s.k_lms_lo_N_per_m2 == pytest.approx(s.k_lms_hi_N_per_m2, rel=1e-9)
    assert elastic_face.salamon.verdict == "stable"


def test_profile_per_stage_starts_at_the_face(elastic_face):
    """Fig. 1: the seam's mid-height row at each stage starts at the current face; the abutment peak
    moves with the face and is above the virgin stress."""
    p0 = MineParams(**SMALL).p_top
    peaks = []
    for s in elastic_face.stages:
        assert s.x_m.min() > s.face_m - 0.5 and s.x_m.min() < s.face_m + 0.6
        k = int(np.argmin(s.syy_Pa))
        assert -s.syy_Pa[k] > p0
        peaks.append(s.x_m[k])
    assert peaks[-1] > peaks[0]


def test_face_refuses_to_cut_the_dislocation():
    with pytest.raises(ValueError, match="n_steps"):
        advance_face(MineParams(**{**SMALL, "n_disl": 1, "disl_first": 0.3, "disl_angle_deg": 60.0,
                                   "gas": "interface", "fault_law": "plane", "disl_phi_deg": 22.0},
                                elastic=True), n_steps=2, ek_tol=1e-2)
    with pytest.raises(ValueError, match="ek_tol"):
        advance_face(MineParams(**SMALL), ek_tol=0.0)


# ----------------------------------------------------------------------------- Salamon's check
def test_probe_stiffness_of_springs_in_series():
    """Roof on a spring k1 and floor on a spring k2: pushing them apart with F sees k1 k2 / (k1 + k2)."""
    import scipy.sparse as sp
    k1, k2, F = 3e9, 7e9, 2.5e6
    K = sp.diags([k1, k2]).tocsc()
    f = np.array([F, -F])
    assert probe_stiffness(K, f, F) == pytest.approx(k1 * k2 / (k1 + k2), rel=1e-9)   # 1e-12 diagonal shift


def _softening_element_run(k_soft, k_mine, m=1.0, steps=200000):
    """A mass between a loading spring ``k_mine`` (its far end pulled slowly) and an element that is
    elastic (stiffness 1) up to a peak force 1 and then softens with slope -k_soft to zero, started
    in equilibrium at 95 % of the peak. Returns the largest speed of the mass over the loading rate
    (explicit dynamics, 5 % of critical damping)."""
    k_e, Fp = 1.0, 1.0
    xp = Fp / k_e

    def fe(x):
        return k_e * x if x <= xp else max(Fp - k_soft * (x - xp), 0.0)

    w = np.sqrt((k_e + k_mine) / m)
    dt = 0.05 / w
    rate = 5e-3 * xp * w                       # quasi-static loading
    x = 0.95 * xp
    v, U, vmax = 0.0, x + k_e * x / k_mine, 0.0
    c = 0.05 * 2 * m * w
    for _ in range(steps):
        U += rate * dt
        a = (k_mine * (U - x) - fe(x) - c * v) / m
        v += a * dt
        x += v * dt
        vmax = max(vmax, abs(v))
        if x > xp + 1.2 * Fp / k_soft:
            break
    return vmax / rate


@pytest.mark.parametrize("ratio", [0.5, 0.8, 1.25, 2.0])
def test_salamon_criterion_matches_a_softening_element_against_a_spring(ratio):
    """The known answer: a softening element loaded through a spring of stiffness k descends
    quasi-statically when its post-peak slope |k_post| < k and snaps (speed >> loading rate) when
    |k_post| > k. The dynamic run and :func:`salamon_verdict` agree."""
    k_mine = 0.4
    k_soft = ratio * k_mine
    speed = _softening_element_run(k_soft, k_mine)
    verdict = salamon_verdict(-k_soft, k_mine, k_mine)
    assert verdict == ("stable" if ratio < 1 else "unstable")
    if verdict == "stable":
        assert speed < 1.0 / (1.0 - ratio) * 1.5 + 1.0, speed      # follows the load: v ~ rate k/(k - k_s)
    else:
        assert speed > 50.0, speed


def test_salamon_verdict_brackets():
    assert salamon_verdict(1e9, 1.0, 2.0) == "stable"
    assert salamon_verdict(-1.5, 1.0, 2.0) == "undecided"
    assert salamon_verdict(-0.5, 1.0, 2.0) == "stable"
    assert salamon_verdict(-3.0, 1.0, 2.0) == "unstable"
    assert salamon_verdict(float("nan"), 1.0, 2.0) == "no data"


# ----------------------------------------------------------------------------- the study: quick, killed, resumed
def test_face_study_quick_is_killed_and_resumes(tmp_path):
    """``python -m studies.mine_face --quick`` killed (SIGKILL) after its first finished case resumes:
    the re-run keeps the finished cases (same rows, not re-run) and completes the rest, the stages
    are quasi-static and the figures are written."""
    import os
    import subprocess
    import sys
    import time

    import pandas as pd

    from studies.mine_face import main
    out = tmp_path / "face"
    env = dict(os.environ, NUMBA_NUM_THREADS="1", PYTHONPATH=os.getcwd())
    proc = subprocess.Popen([sys.executable, "-m", "studies.mine_face", "--quick", "--out", str(out), "--no-progress"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    csv = out / "cases.csv"
    try:
        for _ in range(12000):     # poll up to about 10 minutes (a bound on the wait, not a timing)
            if csv.exists() and len(pd.read_csv(csv)) >= 1:
                break
            if proc.poll() is not None:
                break
            time.sleep(0.05)
    finally:
        proc.kill()
        proc.wait()
    before = pd.read_csv(csv)
    assert 1 <= len(before) < 4, "the run was not killed mid-way"
    assert main(["--quick", "--out", str(out), "--no-progress"]) == 0
    after = pd.read_csv(csv).set_index("case_id")
    assert len(after) == 4 and (after.status == "ok").all()
    # the cases of the killed run are kept as they were written, not re-run (their rows, the
    # recorded run time among them, are unchanged)
    kept = after.loc[before.case_id].reset_index()[before.columns]
    pd.testing.assert_frame_equal(kept, before, check_dtype=False)
    st = pd.read_csv(out / "stages.csv")
    assert len(st) == 8 and st.converged.all()
    for f in ("profile", "energy", "wedge"):
        assert (out / f"fig_face_{f}.png").exists()
