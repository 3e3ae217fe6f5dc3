"""``--realtime off``: both programs run their loop faster than real time through the node runtime and end by themselves.

Each program alone, as a real process with its real Zenoh session (peer mode, nothing to
connect to): the follower with the pybullet NAO runs 3 s of robot time, the leader 2 s of
haptic time (2,000 ticks, 200 commands at 100 Hz), and each exits 0 on its own.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

CLI = [sys.executable, "-m", "bipedtele.cli"]
ALONE = ["--set", "network.listen=[]", "--set", "network.connect=[]"]


@pytest.mark.timeout(180)
def test_the_follower_runs_its_duration_of_robot_time_as_fast_as_it_can(tmp_path: Path) -> None:
    res = subprocess.run(
        [*CLI, "follower", "--realtime", "off", "--duration", "3", "--set", "follower.camera_fps=0", *ALONE],
        capture_output=True,
        text=True,
        timeout=150,
        cwd=tmp_path,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert "as fast as possible" in res.stderr and "follower stopping" in res.stderr


@pytest.mark.timeout(120)
def test_the_leader_runs_its_duration_of_haptic_ticks_as_fast_as_it_can(tmp_path: Path) -> None:
    res = subprocess.run(
        [*CLI, "leader", "--realtime", "off", "--duration", "2", "--set", "leader.cockpit=false", *ALONE],
        capture_output=True,
        text=True,
        timeout=100,
        cwd=tmp_path,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    sent = re.search(r"(\d+) commands sent", res.stdout + res.stderr)
    assert sent is not None and 195 <= int(sent.group(1)) <= 205, (res.stdout + res.stderr)[-2000:]
