"""`bipedtele demo` end to end: router, delay proxy (the shipped intercontinental trace),
the pybullet follower and the leader with the pilot operator, as separate processes.

Issue 6: all 10 obstacle passes done, 0 falls, 0 collisions, the report JSON complete, and
its delays match the trace (mean within 10 ms over the run's own time span).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bipedtele.link.delaymodels import parse_delay_model
from bipedtele.recording.format import read_records

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

REPORT_KEYS = {
    "min_delay_ms",
    "max_delay_ms",
    "mean_delay_ms",
    "completion_s",
    "passes",
    "forward_error_cm_s",
    "turn_error_deg_s",
    "forward_error_instant_cm_s",
    "turn_error_instant_deg_s",
    "falls",
    "collisions",
    "odometry_source",
}


@pytest.mark.timeout(720)
def test_demo_completes_the_paper_task_under_the_intercontinental_delay(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    out_json = tmp_path / "report.json"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "demo",
            "--headless",
            "--run-dir",
            str(run_dir),
            "--json",
            str(out_json),
            # Video off: nobody watches in a headless test, and it halves the CPU load.
            "--set",
            "follower.camera_fps=0",
        ],
        capture_output=True,
        text=True,
        timeout=700,
    )
    logs = {p.name: p.read_text(errors="replace")[-3000:] for p in run_dir.glob("*.log")}
    assert proc.returncode == 0, f"demo failed: {proc.stderr[-2000:]}\n{logs}"

    report = json.loads(out_json.read_text())
    assert set(report) == REPORT_KEYS
    assert all(report[k] is not None for k in REPORT_KEYS), report
    assert report["passes"] == 10, report
    assert report["odometry_source"] == "footfalls", report  # the demo reads the follower's footfalls
    assert report["falls"] == 0, logs
    assert report["collisions"] == 0, logs

    records = list(read_records(run_dir / "leader.mcap"))
    passes = [r.data for r in records if r.topic == "events" and r.data.get("event") == "pass"]
    assert [p["n"] for p in passes] == list(range(1, 11)), passes
    sides = [p["side"] for p in passes]
    assert sides == ["left", "right"] * 5

    # The delays the system measured match the trace over the same time span.
    plan = json.loads((run_dir / "plan.json").read_text())
    h1 = parse_delay_model(plan["forward"])
    h2 = parse_delay_model(plan["backward"])
    fb = [r.t_recv for r in records if r.topic == "feedback/recv"]
    ts = np.linspace(fb[0], fb[-1], 2000) - plan["t0"]
    expected_ms = 1e3 * float(np.mean([h1.delay_s(t) + h2.delay_s(t) for t in ts]))
    assert report["mean_delay_ms"] == pytest.approx(expected_ms, abs=10.0)
    assert report["min_delay_ms"] >= 0.9 * 1e3 * min(h1.delay_s(t) + h2.delay_s(t) for t in ts)
