"""The pybullet NAO really walks, turns and stops (real pybullet, faster than real time).

Each test drives :class:`SimNao` directly with ``send_walk``/``advance``/``observe`` at a
50 Hz control rate and asserts the walking behaviour.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from bipedtele.follower.robot import RobotObservation, WalkCommand
from bipedtele.follower.sim.robot import SimNao
from bipedtele.follower.sim.world import Obstacle, WorldConfig

DT = 0.02  # control period [s]

pytestmark = [pytest.mark.slow]


def drive(robot: SimNao, seconds: float, cmd: WalkCommand | None) -> list[RobotObservation]:
    """Send ``cmd`` (None: stop) every control period for ``seconds``; the observations."""
    out = []
    for _ in range(round(seconds / DT)):
        if cmd is None:
            robot.stop()
        else:
            robot.send_walk(cmd)
        robot.advance(DT)
        out.append(robot.observe())
    return out


@pytest.mark.timeout(120)
def test_straight_walk_60s_tracks_5cm_s_without_falling() -> None:
    with SimNao() as robot:
        obs = drive(robot, 60.0, WalkCommand(0.05, 0.0, 1.0, 0.1))
        cyc = robot.cycle_speed()
    assert not any(o.fallen for o in obs)
    v = np.array([o.v_hip_m_s for o in obs if o.t > 5.0])
    assert np.mean(np.abs(v - 0.05)) < 0.01  # eq. (8), instantaneous over each control period
    assert abs(np.mean(v) - 0.05) < 0.003
    # it really moves: ground speed of the torso (the linearisation of eq. 8 overestimates slightly)
    x, y, yaw = obs[-1].pose
    assert 0.040 < cyc < 0.055
    assert 2.2 < x < 3.1 and abs(y) < 0.3 and abs(yaw) < math.radians(15)
    assert max(o.joint_error_rad for o in obs) < math.radians(3)


@pytest.mark.timeout(90)
def test_turning_at_4_deg_s_while_walking() -> None:
    ref = math.radians(4.0)
    with SimNao() as robot:
        obs = drive(robot, 30.0, WalkCommand(0.05, ref, 1.0, 0.1))
    assert not any(o.fallen for o in obs)
    turn = np.array([o.turn_rate_rad_s for o in obs if o.t > 5.0])
    assert abs(math.degrees(np.mean(turn) - ref)) < 1.0
    # per walking cycle (the yaw moves in single support only, so within a cycle it pulses)
    per_cycle = turn[: len(turn) // 50 * 50].reshape(-1, 50).mean(axis=1)
    assert np.mean(np.abs(np.degrees(per_cycle - ref))) < 1.0
    total = obs[-1].pose[2] - obs[0].pose[2]
    assert total == pytest.approx(ref * 30.0, abs=math.radians(15))


@pytest.mark.timeout(120)
def test_speed_and_turn_steps_do_not_make_it_fall() -> None:
    plan = [
        (3.0, WalkCommand(0.0)),
        (8.0, WalkCommand(0.08, 0.0, 1.0)),
        (6.0, WalkCommand(0.0)),
        (6.0, WalkCommand(0.04, math.radians(10), 1.0)),
        (6.0, WalkCommand(0.04, math.radians(-10), 1.0)),
        (5.0, WalkCommand(0.0, math.radians(10), 1.0)),
        (5.0, WalkCommand(0.0, math.radians(-10), 1.0)),
        (4.0, WalkCommand(0.0)),
    ]
    with SimNao() as robot:
        obs: list[RobotObservation] = []
        for seconds, cmd in plan:
            obs += drive(robot, seconds, cmd)
    assert not any(o.fallen for o in obs)
    assert max(o.tilt_rad for o in obs) < math.radians(10)
    assert not obs[-1].walking
    v8 = np.array([o.v_hip_m_s for o in obs if 6.0 < o.t < 11.0])
    assert np.mean(v8) == pytest.approx(0.08, abs=0.01)


@pytest.mark.timeout(90)
@pytest.mark.parametrize("cycle", [0.8, 1.0, 2.0])
def test_stop_stands_within_one_cycle(cycle: float) -> None:
    with SimNao() as robot:
        v = min(0.05, robot.gait.max_forward(cycle))
        for k in range(3):
            drive(robot, 3.0 + 0.23 * k * cycle, WalkCommand(v, 0.0, cycle, 0.1))
            assert robot.observe().walking
            t_stop = robot.observe().t
            robot.stop()
            obs = drive(robot, cycle + 2.0, None)
            stood = next(o.t for o in obs if not o.walking)
            assert stood - t_stop <= cycle + DT
            after = [o for o in obs if o.t >= stood + 0.5]
            assert not any(o.fallen or o.walking for o in obs if o.t >= stood)
            # standing still: no drift, no speed
            moved = np.subtract(after[-1].pose, after[0].pose)
            assert np.abs(moved[:2]).max() < 0.005 and abs(moved[2]) < math.radians(1)
            assert np.abs([o.v_hip_m_s for o in after]).max() < 0.005


@pytest.mark.timeout(60)
def test_obstacle_ahead_is_seen_closer_and_closer_by_the_sonar() -> None:
    # a wall whose face is 0.6 m ahead of the robot's start
    world = WorldConfig(obstacles=[Obstacle("box", [0.7, 0.0, 0.3], [0.2, 0.8, 0.6])])
    with SimNao(world=world) as robot:
        first = robot.observe().sonar_m
        obs = drive(robot, 6.0, WalkCommand(0.05, 0.0, 1.0, 0.1))
    lo, hi = robot.sonar_range_m
    assert all(lo < r < hi for r in first)
    assert first[0] == pytest.approx(first[1], abs=0.03)
    ranges = np.array([min(o.sonar_m) for o in obs])
    assert ranges[-1] < first[0] - 0.15
    # decreasing as it approaches (per half second, beyond the sway's wobble)
    half = ranges[: len(ranges) // 25 * 25].reshape(-1, 25).mean(axis=1)
    assert np.all(np.diff(half) < 0.002)
    assert not any(o.in_contact or o.fallen for o in obs)
