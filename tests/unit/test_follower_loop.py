"""The follower loop's logic in simulated time, around a kinematic robot at the hardware
boundary: tracking, watchdog stop and resume, stale commands, release, falls, collisions,
delay estimate and the online parameters. The pybullet NAO runs the same loop in
tests/integration/test_follower_sim.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bipedtele.config import load_config
from bipedtele.follower.loop import FollowerLoop
from bipedtele.messages import Command, Feedback, Status
from fakes.kinematic_robot import KinematicRobot

pytestmark = pytest.mark.timeout(60)


class Harness:
    """Drives a FollowerLoop in simulated time with a scripted leader and a delay h1."""

    def __init__(self, robot: KinematicRobot, h1: float = 0.0, **overrides: str) -> None:
        sets = [f"{k.replace('__', '.')}={v}" for k, v in overrides.items()]
        cfg = load_config("default", sets)
        self.t = 1000.0
        self.robot = robot
        self.h1 = h1
        self.sent: list[tuple[float, Command]] = []  # (arrival time, command)
        self.published: list[object] = []
        self.events: list[tuple[str, dict]] = []
        self.seq = 0
        robot.connect()
        self.loop = FollowerLoop(
            robot, cfg.section("control"), cfg.section("follower"), self.latest, self.published.append,
            now=lambda: self.t, on_event=lambda n, d: self.events.append((n, d)),
        )

    def latest(self) -> tuple[Command, float] | None:
        arrived = [(ta, c) for ta, c in self.sent if ta <= self.t]
        return (arrived[-1][1], arrived[-1][0]) if arrived else None

    def command(self, v: float, w: float, enable: bool = True, sent_at: float | None = None) -> None:
        self.seq += 1
        t_sent = self.t if sent_at is None else sent_at
        self.sent.append((t_sent + self.h1, Command(sid=7, seq=self.seq, t=t_sent, ref=[v, w], h2_s=0.2, enable=enable)))

    def run(self, seconds: float, v: float | None = None, w: float = 0.0, cmd_every: float = 0.01) -> list:
        tels = []
        next_cmd = self.t
        for _ in range(round(seconds / self.loop.dt)):
            if v is not None and self.t >= next_cmd:
                self.command(v, w)
                next_cmd += cmd_every
            tels.append(self.loop.tick())
            self.robot.advance(self.loop.dt)
            self.t += self.loop.dt
        return tels


def test_tracks_forward_and_turn_speed() -> None:
    h = Harness(KinematicRobot())
    h.run(30.0, v=5.0, w=4.0)
    obs = h.robot.observe()
    assert obs.v_hip_m_s * 100 == pytest.approx(5.0, abs=0.2)
    assert math.degrees(obs.turn_rate_rad_s) == pytest.approx(4.0, abs=0.2)
    fb = [m for m in h.published if isinstance(m, Feedback)]
    assert fb[-1].state == "walking"
    np.testing.assert_allclose(fb[-1].z_e, [5.0, 4.0], atol=0.3)


def test_watchdog_stops_then_resumes() -> None:
    h = Harness(KinematicRobot())
    h.run(10.0, v=5.0)
    assert h.robot.v > 0.03
    tels = h.run(5.0, v=None)  # leader gone: no new command
    assert h.loop.counters["watchdog_stops"] == 1
    assert h.robot.stops >= 1 and h.robot.v == 0.0
    assert tels[-1].state == "standing"
    assert [e for e, _ in h.events] == ["watchdog_stop"]
    h.run(10.0, v=5.0)  # leader back (same or new session): walks again
    assert h.robot.v > 0.03 and h.loop.telemetry.state == "walking"


def test_released_device_stops_the_robot() -> None:
    h = Harness(KinematicRobot())
    h.run(8.0, v=5.0)
    for _ in range(100):
        h.command(5.0, 0.0, enable=False)
        h.loop.tick()
        h.robot.advance(h.loop.dt)
        h.t += h.loop.dt
    assert h.robot.stopping and h.loop.telemetry.state in ("stopping", "standing")


def test_commands_older_than_the_age_limit_are_dropped() -> None:
    h = Harness(KinematicRobot(), follower__max_cmd_age_s="1.0")
    h.command(5.0, 0.0, sent_at=h.t - 2.0)
    h.run(2.0)
    assert h.loop.counters["cmd_too_old"] == 1
    assert h.loop.counters["cmd_accepted"] == 0
    assert h.robot.sent == []


def test_h1_estimate_follows_the_forward_delay() -> None:
    h = Harness(KinematicRobot(), h1=0.25)
    h.run(5.0, v=3.0)
    assert h.loop.telemetry.h1_s == pytest.approx(0.25, abs=1e-6)
    fb = [m for m in h.published if isinstance(m, Feedback)][-1]
    assert fb.h1_s == pytest.approx(0.25, abs=1e-6)


def test_fall_stops_and_is_reported_once() -> None:
    h = Harness(KinematicRobot(fall_at=5.0))  # robot time [s] starts at 0
    h.run(8.0, v=5.0)
    assert h.loop.counters["falls"] == 1
    assert h.loop.telemetry.state == "fallen"
    st = [m for m in h.published if isinstance(m, Status)][-1]
    assert st.counters["falls"] == 1 and st.state == "fallen"


def test_obstacle_slows_the_robot_before_contact() -> None:
    h = Harness(KinematicRobot(wall_x=1.2))
    h.run(60.0, v=5.0)
    assert h.loop.counters["collisions"] == 0
    assert h.robot.x < 1.2 - 0.25
    assert h.loop.telemetry.f_v[0] > 0


def test_walk_parameters_come_from_the_online_choice() -> None:
    h = Harness(KinematicRobot())
    h.run(3.0, v=5.0)
    sent = h.robot.sent[-1]
    lim = h.robot.limits
    assert lim.cycle_s[0] <= sent.cycle_s <= lim.cycle_s[1]
    fb = [m for m in h.published if isinstance(m, Feedback)][-1]
    assert pytest.approx(sent.cycle_s) == fb.T and fb.eps == pytest.approx(sent.eps_s)
    assert all(v > 0 for v in fb.s_e)


def test_conservative_split_uses_the_round_trip_for_both_delays() -> None:
    robot = KinematicRobot()
    robot.connect()
    cfg = load_config("default")
    seen: list[tuple[float, float]] = []
    loop = FollowerLoop(
        robot, cfg.section("control"), cfg.section("follower"), lambda: None, lambda m: None,
        now=lambda: 0.0, conservative_rtt=lambda: 0.4,
    )
    original = loop._update_parameters

    def spy(h1: float, h2: float) -> None:
        seen.append((h1, h2))
        original(h1, h2)

    loop._update_parameters = spy  # type: ignore[method-assign]
    loop.tick()
    assert seen == [(0.4, 0.4)]
