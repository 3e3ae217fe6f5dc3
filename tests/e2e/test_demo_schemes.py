"""`bipedtele demo --scheme`: the schemes that change what the messages carry run end to end.

``wave`` (wave variables in Command and Feedback) and ``tdpa`` (energy counters both ways,
passivity controllers at both ports) through the real processes, router and delay proxy on
the shipped trace, for a short drive: the robot walks, nothing falls or hits, and the
recorded messages carry the scheme's fields. The other schemes change only the damping and
which speed the force follows (unit tests of the leader and follower loops); every scheme's
full 10-pass demo is in bench/demo_schemes.py.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bipedtele.recording.format import read_records

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


@pytest.mark.timeout(300)
@pytest.mark.parametrize("scheme", ["wave", "tdpa"])
def test_the_demo_drives_the_robot_with_the_scheme(tmp_path: Path, scheme: str) -> None:
    run_dir = tmp_path / "run"
    out_json = tmp_path / "report.json"
    demo = [sys.executable, "-m", "bipedtele.cli", "demo", "--scheme", scheme, "--headless", "--quiet"]
    proc = subprocess.run(
        [
            *demo,
            "--duration",
            "12",
            "--run-dir",
            str(run_dir),
            "--json",
            str(out_json),
            "--set",
            "follower.camera_fps=0",
        ],
        capture_output=True,
        text=True,
        timeout=280,
    )
    logs = {p.name: p.read_text(errors="replace")[-2000:] for p in run_dir.glob("*.log")}
    assert proc.returncode == 0, f"demo failed: {proc.stderr[-2000:]}\n{logs}"
    report = json.loads(out_json.read_text())
    assert report["falls"] == 0 and report["collisions"] == 0, report
    records = list(read_records(run_dir / "leader.mcap"))
    fb = [r.data for r in records if r.topic == "feedback/recv"]
    cmds = [r.data for r in records if r.topic == "cmd/sent" and r.data["enable"]]
    walking = [f for f in fb if f["state"] == "walking"]
    assert len(walking) > 100, "the robot did not walk"
    assert max(f["eta"][0] for f in walking) > 3.0  # cm/s: it went forward
    if scheme == "wave":
        assert np.abs([c["wave"] for c in cmds]).max() > 1.0
        assert np.abs([f["wave"] for f in walking]).max() > 1.0
    else:
        # energy counters only grow, and both sides put energy in
        e_lead = np.array([c["energy"] for c in cmds])
        assert np.all(np.diff(e_lead, axis=0) >= 0.0) and e_lead[-1].max() > 1.0
        assert max(max(f["energy"]) for f in fb) > 0.0  # the robot gave some back (braking, turning)
