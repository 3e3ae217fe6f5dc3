"""CP vs VP on the pybullet follower (study --walker) and the calibration from the walker."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from bipedtele.cli import main
from bipedtele.config.profile import load_config
from bipedtele.control.config import ControlConfig
from bipedtele.follower.sim.calibrate import calibrate
from bipedtele.follower.sim.poincare import MapSettings
from bipedtele.studies.study import CASES, StudyParams, case_inputs
from bipedtele.studies.walker_study import run_walker_study, walker_run

pytestmark = pytest.mark.compute  # CPU-bound and deterministic: run beside the other unit tests (scripts/test.sh)


@pytest.fixture(scope="module")
def sections() -> tuple:
    cfg = load_config("default", [])
    return cfg.section("control"), cfg.section("follower"), cfg.section("sim")


@pytest.mark.timeout(300)
def test_walker_study_is_deterministic_and_cp_holds_its_parameters(sections: tuple) -> None:
    control, follower, sim = sections
    a = run_walker_study(control, follower, sim, runs=1, duration_s=4.0, cases=(CASES[2],))
    b = run_walker_study(control, follower, sim, runs=1, duration_s=4.0, cases=(CASES[2],))
    ca, cb = a["cases"][0], b["cases"][0]
    assert ca["cp"]["runs"][0]["forward_error"] == cb["cp"]["runs"][0]["forward_error"]
    assert ca["vp"]["runs"][0]["turn_error"] == cb["vp"]["runs"][0]["turn_error"]
    inp = case_inputs(CASES[2], 1, 0, control, StudyParams(duration_s=4.0), T_bounds=(0.8, 2.0))
    np.testing.assert_allclose(ca["cp"]["mean_s_r"], inp.cp_s_r[0])
    assert ca["cp"]["mean_T_s"] == pytest.approx(inp.cp_T[0])
    assert ca["vp"]["mean_T_s"] == pytest.approx(0.8)  # (30) asks 0.5 s, the robot's shortest is 0.8 s
    for s in ("cp", "vp"):
        assert ca[s]["falls"] == 0 and ca[s]["forward_error"] > 0 and math.isfinite(ca[s]["turn_error"])
    assert ca["h1_ms"] == pytest.approx(300.0) and ca["h2_ms"] == pytest.approx(100.0)


@pytest.mark.timeout(300)
def test_delay_reaches_the_walker(sections: tuple) -> None:
    control, follower, sim = sections
    params = StudyParams(duration_s=6.0)
    inp = case_inputs(CASES[0], 1, 0, control, params)
    common = {
        "switch": inp.switch,
        "intent": inp.intent,
        "control": control,
        "follower": follower,
        "sim": sim,
        "params": params,
        "cp": None,
    }
    fast = walker_run(h1=np.full(600, 0.002), h2=np.full(600, 0.002), **common)
    slow = walker_run(h1=np.full(600, 1.0), h2=np.full(600, 1.0), **common)
    assert slow.forward_error != fast.forward_error
    assert slow.ticks == fast.ticks == 300


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_study_walker_command(tmp_path: Path) -> None:
    out, md = tmp_path / "w.json", tmp_path / "w.md"
    rc = main(["study", "--walker", "--runs", "1", "--duration", "3", "--json", str(out), "--markdown", str(md)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert [c["name"] for c in data["cases"]] == [c.name for c in CASES]
    rows = [line for line in md.read_text().splitlines() if line.startswith("| ") and "---" not in line]
    assert len(rows) == 1 + len(CASES)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_calibration_identifies_dp_and_k_v() -> None:
    st = MapSettings(warmup_s=8.0, average_cycles=2)
    # calibrate() runs both identifications (20 cycles, a 30 s step) and returns them: one
    # run, not three (the same checks on shorter separate runs took 49 s of the suite)
    out = calibrate(settings=st, points=[([0.0, 0.0], 0.8)])
    reset, resp = out["dp"], out["speed_response"]
    assert 0.0 < reset["dp"] <= 1.2 and reset["touchdowns"] >= 10
    assert 0.9 < reset["dp_torso"] <= 1.2  # the position walker: the torso keeps its speed across an impact
    assert resp["k_v"] == pytest.approx(ControlConfig().D[0] / resp["tau_s"])
    assert 0.5 < resp["tau_s"] < 20.0 and resp["rms"] < 0.3  # a first-order response fits the walker
    assert 0.9 < resp["gain"] < 1.1  # the servo's integral action: v_hip reaches the reference
    p = out["points"][0]
    assert math.isfinite(p["rho_walker"]) and p["rho_reduced_speed_loop"] != p["rho_reduced"]
    assert out["set"][0] == 'control.hybrid_model="speed-loop"'
