"""`bipedtele demo --scheme toy-damped`: a scheme from another distribution drives the robot.

The toy scheme (``tests/plugins/toy/toy_scheme.py``, registered by one line of the toy
distribution's ``entry_points.txt``; nothing in bipedtele names it) runs in both real loops
through router and delay proxy on the shipped trace, for a short drive (12 s): the robot
walks forward, nothing falls or hits, both sides ran the toy (the leader's recording says
``scheme = "toy-damped"`` and its handle damping is the toy's fixed one, (40) at zero delay
plus the toy's extra, on every tick), and the messages carry no wave and no energy (the toy
asks for none). The reduced-model comparison with it is tests/integration/test_toy_scheme.py.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bipedtele.recording.format import read_records
from bipedtele.recording.recorder import read_metadata

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

PLUGIN = Path(__file__).resolve().parents[1] / "plugins" / "toy"


@pytest.mark.timeout(150)
def test_the_demo_drives_the_robot_with_the_toy_scheme(tmp_path: Path) -> None:
    sys.path.insert(0, str(PLUGIN))
    try:
        from toy_scheme import EXTRA_ALPHA_M
    finally:
        sys.path.remove(str(PLUGIN))
    run_dir, out_json = tmp_path / "run", tmp_path / "report.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(PLUGIN), os.environ.get("PYTHONPATH", "")) if p)}
    demo = [
        sys.executable,
        "-m",
        "bipedtele.cli",
        "demo",
        "--scheme",
        "toy-damped",
        "--headless",
        "--quiet",
        "--duration",
        "12",
        "--run-dir",
        str(run_dir),
        "--json",
        str(out_json),
        "--set",
        "follower.camera_fps=0",
    ]
    proc = subprocess.run(demo, capture_output=True, text=True, timeout=140, env=env)
    logs = {p.name: p.read_text(errors="replace")[-2000:] for p in run_dir.glob("*.log")}
    assert proc.returncode == 0, f"demo failed: {proc.stderr[-2000:]}\n{logs}"
    report = json.loads(out_json.read_text())
    assert report["falls"] == 0 and report["collisions"] == 0, report
    meta = read_metadata(run_dir / "leader.mcap")
    assert json.loads(meta["config"])["control"]["scheme"] == "toy-damped"
    records = list(read_records(run_dir / "leader.mcap"))
    walking = [r.data for r in records if r.topic == "feedback/recv" and r.data["state"] == "walking"]
    assert len(walking) > 100, "the robot did not walk"
    assert max(f["eta"][0] for f in walking) > 3.0  # cm/s: it went forward
    alpha = np.array([[s["alpha_m_v"], s["alpha_m_w"]] for s in (r.data for r in records if r.topic == "leader/state")])
    assert np.all(alpha >= EXTRA_ALPHA_M), "the leader did not use the toy's damping"
    cmds = [r.data for r in records if r.topic == "cmd/sent"]
    assert all(c["wave"] is None and c["energy"] is None for c in cmds)
