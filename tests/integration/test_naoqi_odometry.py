"""NaoqiRobot's footfalls against the fake NAO over real libqi: the odometry read once per
step period while walking gives the per-step speed NAO was asked for."""

from __future__ import annotations

import itertools
import math
import sys
import time
from pathlib import Path

import pytest
from bipedtele.follower.naoqi import NaoqiRobot
from bipedtele.follower.robot import WalkCommand

pytest.importorskip("qi")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fakes.fake_naoqi import FakeNaoqi

pytestmark = pytest.mark.timeout(60)


def test_footfalls_sample_the_odometry_once_per_step_period() -> None:
    with FakeNaoqi() as fake:
        fake.control().set_obstacles([])
        robot = NaoqiRobot(url=fake.url, call_timeout_s=2.0, allow_unguarded=True)
        robot.connect()
        try:
            assert robot.footfall() is None
            sent = robot.send_walk(WalkCommand(0.04, math.radians(10.0), 1.0, 0.1))
            seen = []
            deadline = time.monotonic() + 2.5
            while time.monotonic() < deadline:
                robot.observe()
                ff = robot.footfall()
                if ff is not None and (not seen or seen[-1].n != ff.n):
                    seen.append(ff)
                time.sleep(0.02)
        finally:
            robot.disconnect()
    step = sent.cycle_s / 2.0
    assert len(seen) >= 3
    for a, b in itertools.pairwise(seen):
        dt = b.t - a.t
        assert step - 1e-6 <= dt <= step + 0.1  # one step period (observed at about 50 Hz)
        assert b.step_s == pytest.approx(dt)
        ahead = (b.pose[0] - a.pose[0]) * math.cos(a.pose[2]) + (b.pose[1] - a.pose[1]) * math.sin(a.pose[2])
        assert ahead / dt == pytest.approx(sent.forward_m_s, rel=0.1)
        assert (b.pose[2] - a.pose[2]) / dt == pytest.approx(sent.turn_rad_s, rel=0.1)
