"""The delayed-teleoperation predictor against a kinematic robot with a known delay."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bipedtele.follower.robot import WalkCommand
from bipedtele.leader.predictor import CommandLog, DelayPredictor

from tests.fakes.kinematic_robot import KinematicRobot

CM = 100.0


def _ref(t: float) -> tuple[float, float]:
    """A varied operator: forward 4..9 cm/s, turn swinging +-20 deg/s, steps included."""
    v = 6.5 + 2.5 * math.sin(0.4 * t)
    w = 20.0 * math.sin(0.7 * t) if int(t / 7.0) % 2 == 0 else (15.0 if int(t) % 4 < 2 else -15.0)
    return v, w


@pytest.mark.timeout(30)
@pytest.mark.parametrize(("h1", "h2"), [(0.18, 0.20), (0.36, 0.40)])
def test_predicted_present_pose_is_close_to_the_true_one(h1: float, h2: float) -> None:
    """Commands reach the robot h1 after they are sent, feedback the leader h2 after it
    left; the prediction of the present pose is within 1 cm and 1 deg of the truth,
    and at least 10 times closer than the pose the feedback shows."""
    cycle = 1.0  # the kinematic robot's lag is half a cycle: the predictor's tau
    robot = KinematicRobot()
    robot.connect()
    pred = DelayPredictor(tau_s=cycle / 2, step_s=0.01)
    dt = 0.01
    sent: list[tuple[float, tuple[float, float]]] = []  # (t_send, ref)
    fbs: list[tuple[float, tuple[float, float, float], tuple[float, float]]] = []
    i_cmd = i_fb = 0  # next command to apply, next feedback to see
    applied, seen = (0.0, 0.0), None
    err_pred, err_delayed, err_yaw = [], [], []
    truth: list[tuple[float, float, float]] = []
    ahead: list[tuple[int, float, float]] = []  # (step it is for, x, y)
    for k in range(4000):  # 40 s
        t = k * dt
        ref = _ref(t)
        sent.append((t, ref))
        pred.add_command(t, ref)
        while i_cmd < len(sent) and sent[i_cmd][0] <= t - h1 + 1e-9:  # arrived at the robot
            applied = sent[i_cmd][1]
            i_cmd += 1
        robot.send_walk(WalkCommand(applied[0] / CM, math.radians(applied[1]), cycle, 0.1))
        obs = robot.observe()
        fbs.append((t, obs.pose, (obs.v_hip_m_s * CM, math.degrees(obs.turn_rate_rad_s))))
        truth.append(obs.pose)
        robot.advance(dt)
        while i_fb < len(fbs) and fbs[i_fb][0] <= t - h2 + 1e-9:  # arrived at the leader
            seen = fbs[i_fb]
            i_fb += 1
        if t < 5.0 or seen is None:
            continue
        t_fb, pose_fb, speed_fb = seen
        now, later = pred.predict_now_and_ahead(pose_fb, speed_fb, t_fb, t, h1)
        x, y, yaw = truth[k]
        err_pred.append(math.hypot(now.x - x, now.y - y))
        err_yaw.append(abs(math.remainder(now.yaw - yaw, 2 * math.pi)))
        err_delayed.append(math.hypot(pose_fb[0] - x, pose_fb[1] - y))
        ahead.append((k + round(h1 / dt), later.x, later.y))
    # The pose predicted h1 ahead, against the truth once that time came.
    ahead_errors = [math.hypot(x - truth[j][0], y - truth[j][1]) for j, x, y in ahead if j < len(truth)]
    e_pred, e_delayed = float(np.max(err_pred)), float(np.mean(err_delayed))
    assert e_pred < 0.01, e_pred  # m
    assert math.degrees(float(np.max(err_yaw))) < 1.0
    assert float(np.mean(err_pred)) * 10 < e_delayed, (np.mean(err_pred), e_delayed)
    assert e_delayed > 0.01  # the delay matters: the shown pose lags by a centimetre or more
    print(
        f"h1 {h1} h2 {h2}: delayed {e_delayed * 100:.2f} cm, predicted mean/max {np.mean(err_pred) * 100:.3f}/{e_pred * 100:.3f} cm, ahead max {max(ahead_errors) * 100:.3f} cm"
    )
    assert float(np.max(ahead_errors)) < 0.015


def test_without_commands_the_robot_coasts_down_with_the_lag() -> None:
    pred = DelayPredictor(tau_s=0.5)
    p = pred.predict((0.0, 0.0, 0.0), (10.0, 0.0), 0.0, 10.0, 0.2)
    # v decays as 10 e^{-t/0.5} cm/s: distance 10 cm/s * 0.5 s = 5 cm.
    assert p.x == pytest.approx(0.05, abs=1e-3) and p.y == pytest.approx(0.0, abs=1e-9)
    assert p.v == pytest.approx(0.0, abs=1e-3)
    # Capped by max_horizon_s (5 s): 10 s asked, 5 s integrated.
    assert p.t == pytest.approx(5.0)


def test_constant_turn_gives_an_arc() -> None:
    pred = DelayPredictor(tau_s=0.0, step_s=0.005)
    pred.add_command(-1.0, (10.0, 90.0))  # 10 cm/s, 90 deg/s
    p = pred.predict((0.0, 0.0, 0.0), (10.0, 90.0), 0.0, 1.0, 0.1)
    r = 0.1 / math.radians(90.0)  # m
    assert p.yaw == pytest.approx(math.pi / 2, abs=1e-6)
    assert (p.x, p.y) == pytest.approx((r, r), abs=1e-4)


def test_command_log_holds_each_reference_until_the_next() -> None:
    log = CommandLog(keep_s=5.0)
    log.add(1.0, (1.0, 2.0))
    log.add(2.0, (3.0, 4.0))
    log.add(1.5, (9.0, 9.0))  # out of order: ignored
    log.add(3.0, (math.nan, 1.0))  # non-finite: a zero reference
    got = log.refs_at(np.array([0.5, 1.0, 1.9, 2.5, 3.5]))
    assert got.tolist() == [[0.0, 0.0], [1.0, 2.0], [1.0, 2.0], [3.0, 4.0], [0.0, 0.0]]
    log.add(10.0, (5.0, 5.0))
    assert len(log) == 1  # older than keep_s before the newest: forgotten
    with pytest.raises(ValueError, match="keep_s"):
        CommandLog(keep_s=0.0)
    with pytest.raises(ValueError, match="tau_s"):
        DelayPredictor(tau_s=-1.0)
