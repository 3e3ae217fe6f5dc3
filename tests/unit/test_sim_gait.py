"""The simulated NAO's gait generator (pure numpy, no physics)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bipedtele.follower.sim.bezier import BezierFitter, evaluate
from bipedtele.follower.sim.gait import (
    ANKLE,
    AROLL,
    HIP,
    KNEE,
    ROLL,
    YAW,
    Gait,
    GaitConfig,
    hip_speed,
    hip_x,
    ik_linear,
    ik_sagittal,
    p_hip_linear,
)
from bipedtele.follower.sim.model import _LIMITS_DEG, NaoGeometry

L1, L2 = NaoGeometry().thigh, NaoGeometry().tibia
DT = 0.002


def run(gait: Gait, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    ts = np.arange(t0, t1, DT)
    qs, qds, stance = [], [], []
    for t in ts:
        q, qd = gait.update(float(t))
        qs.append(q)
        qds.append(qd)
        stance.append(gait.stance)
    return ts, np.array(qs), np.array(qds), stance


def test_bezier_fit_reproduces_a_polynomial_and_pins_the_ends() -> None:
    fit = BezierFitter(5, 12)
    y = np.stack([1 + 2 * fit.s - 3 * fit.s**3, np.sin(fit.s)], axis=1)
    ctrl = fit.fit(y)
    for s in (0.0, 0.3, 0.77, 1.0):
        q, qd = evaluate(ctrl, s, 2.0)
        assert q[0] == pytest.approx(1 + 2 * s - 3 * s**3, abs=1e-9)
        assert qd[0] == pytest.approx((2 - 9 * s**2) / 2.0, abs=1e-9)
        assert q[1] == pytest.approx(math.sin(s), abs=1e-5)
    np.testing.assert_allclose(ctrl[0], y[0])
    np.testing.assert_allclose(ctrl[-1], y[-1])


def test_inverse_kinematics_round_trip() -> None:
    x = np.linspace(-0.04, 0.04, 9)
    h = np.full_like(x, 0.185)
    th1, th2 = ik_sagittal(x, h, L1, L2)
    np.testing.assert_allclose(L1 * np.sin(th1) + L2 * np.sin(th2), x, atol=1e-12)
    np.testing.assert_allclose(L1 * np.cos(th1) + L2 * np.cos(th2), h, atol=1e-12)
    assert np.all(th2 > th1)  # knee bends forward
    th1, th2 = ik_linear(x, h, L1, L2)
    np.testing.assert_allclose(L1 * th1 + L2 * th2, x, atol=1e-10)
    np.testing.assert_allclose(L1 * np.cos(th1) + L2 * np.cos(th2), h, atol=1e-10)
    # eq. (8) with the ankle at -(hip + knee)
    assert p_hip_linear(float(th1[2]), float(th2[2] - th1[2]), L1, L2) == pytest.approx(x[2], abs=1e-10)


@pytest.mark.parametrize("cycle", [0.8, 1.0, 2.0])
def test_hip_advances_over_the_stance_foot_at_the_commanded_speed(cycle: float) -> None:
    gait = Gait()
    v = 0.5 * gait.max_forward(cycle)
    gait.command(v, 0.0, cycle)
    ts, q, qd, stance = run(gait, 0.0, 3 * cycle + 2.0)
    o = [0 if s == "L" else 6 for s in stance]
    x = np.array([hip_x(qq[k + HIP], qq[k + KNEE], L1, L2) for qq, k in zip(q, o, strict=True)])
    same = np.array([a == b for a, b in zip(stance[1:], stance[:-1], strict=True)])
    rate = np.diff(x) / DT
    late = ts[1:] > cycle + 1.0  # after the start step
    np.testing.assert_allclose(rate[same & late], v, rtol=0.03, atol=2e-4)
    # eq. (8) with its lever arms at the current posture is that rate
    v8 = np.array(
        [
            hip_speed(qq[k + HIP], qq[k + KNEE], dd[k + HIP], dd[k + KNEE], L1, L2)
            for qq, dd, k in zip(q, qd, o, strict=True)
        ]
    )
    np.testing.assert_allclose(v8[1:][same & late], v, rtol=0.03, atol=2e-4)
    # eq. (8) with the bare link lengths (linearised about straight legs) reads about 10 % fast
    p = np.array([p_hip_linear(qq[k + HIP], qq[k + KNEE], L1, L2) for qq, k in zip(q, o, strict=True)])
    assert float(np.median(np.diff(p)[same & late] / DT)) == pytest.approx(1.1 * v, rel=0.03)
    # the stance leg switches at impact, where x jumps back by about a step
    assert (~same[late[: len(same)]]).sum() >= 4


def test_gait_keeps_the_torso_upright_and_feet_flat() -> None:
    gait = Gait()
    gait.command(0.06, math.radians(10), 1.0)
    _, q, _, _ = run(gait, 0.0, 4.0)
    for o in (0, 6):
        np.testing.assert_allclose(q[:, o + ANKLE], -(q[:, o + HIP] + q[:, o + KNEE]), atol=2e-3)
        np.testing.assert_allclose(q[:, o + AROLL], -q[:, o + ROLL], atol=2e-3)


def test_references_are_continuous_through_start_commands_and_stop() -> None:
    gait = Gait()
    gait.command(0.05, 0.0, 1.0)
    parts = [run(gait, 0.0, 2.3)[1]]
    gait.command(0.08, math.radians(15), 0.8)
    parts.append(run(gait, 2.3, 4.1)[1])
    gait.command(-0.03, math.radians(-10), 1.7)
    parts.append(run(gait, 4.1, 7.0)[1])
    gait.stop()
    parts.append(run(gait, 7.0, 10.0)[1])
    q = np.concatenate(parts)
    # no jump: no increment faster than NAO's fastest leg joint (about 6.4 rad/s)
    assert np.abs(np.diff(q, axis=0)).max() < 6.4 * DT
    assert not gait.walking


@pytest.mark.parametrize("cycle", [0.8, 1.0, 2.0])
def test_stop_stands_within_one_cycle(cycle: float) -> None:
    for t_stop in np.linspace(3.0, 3.0 + cycle, 4):
        gait = Gait()
        gait.command(0.05, 0.0, cycle)
        run(gait, 0.0, float(t_stop))
        gait.stop()
        walking_until = float(t_stop)
        q = qd = np.zeros(12)
        for t in np.arange(t_stop, t_stop + cycle + 0.2, 0.01):
            q, qd = gait.update(float(t))
            if gait.walking:
                walking_until = float(t)
        assert walking_until - t_stop <= cycle + 1e-9
        assert not gait.walking
        np.testing.assert_allclose(qd, 0.0, atol=1e-9)
        assert abs(q[ROLL]) < 1e-6 and abs(q[6 + ROLL]) < 1e-6  # no sway left


@pytest.mark.parametrize("v", [0.0, 0.04])
def test_turn_spreads_over_the_whole_step(v: float) -> None:
    cfg = GaitConfig()
    gait = Gait(cfg)
    omega, cycle = math.radians(15.0), 1.0
    gait.command(v, omega, cycle)
    ts, q, qd, stance = run(gait, 0.0, 6.0)
    ts_step, phi = cycle / 2.0, cfg.double_support
    half = omega * ts_step * (1.0 + phi) / 2.0  # a foot turns the torso by 2 half while on the ground
    # the swing leg leads: a foot lands turned by +half and lifts at -half
    for k in range(4, 10):
        t0 = k * cycle / 2.0
        i0, i_lo = int(np.searchsorted(ts, t0 + 1e-9)), int(np.searchsorted(ts, t0 + phi * ts_step))
        o = 0 if stance[i0] == "L" else 6
        assert q[i0, o + YAW] == pytest.approx(half, abs=2e-3)
        assert q[i_lo, 6 - o + YAW] == pytest.approx(-half, abs=2e-3)
        # the stance hip yaw turns at -omega all step long, so the torso turns at omega
        inside = (ts >= t0 + 0.01) & (ts < t0 + ts_step - 0.01)
        np.testing.assert_allclose(qd[inside, o + YAW], -omega, atol=1e-3)
        # in double support both feet are down: both yaws turn at -omega
        ds = (ts >= t0 + 0.01) & (ts < t0 + phi * ts_step - 0.01)
        np.testing.assert_allclose(qd[ds][:, [YAW, 6 + YAW]], -omega, atol=1e-3)


def test_swing_foot_clears_the_ground_by_the_step_height() -> None:
    cfg = GaitConfig()
    gait = Gait(cfg)
    gait.command(0.05, 0.0, 1.0)
    _, q, _, stance = run(gait, 0.0, 4.0)
    lift = []
    for qq, st in zip(q, stance, strict=True):
        o = 6 if st == "L" else 0  # the swing leg
        th1, th2 = qq[o + HIP], qq[o + HIP] + qq[o + KNEE]
        h = (L1 * np.cos(th1) + L2 * np.cos(th2)) * np.cos(qq[o + ROLL])
        lift.append(cfg.leg_height_m - h)
    assert max(lift) == pytest.approx(cfg.step_height_m, abs=2e-3)


@pytest.mark.parametrize("cycle", [0.8, 2.0])
def test_fastest_walk_and_turn_stay_within_nao_joint_limits(cycle: float) -> None:
    gait = Gait()
    gait.command(10.0, 10.0, cycle)  # clamped to the gait's limits
    _, q, _, _ = run(gait, 0.0, 3 * cycle + 1.0)
    for i, name in enumerate(("HipYaw", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll")):
        lo, hi = np.radians(_LIMITS_DEG[name])
        span = max(hi, -lo) if name in ("HipRoll", "AnkleRoll", "HipYaw") else None
        for o in (0, 6):
            vals = q[:, o + i]
            if span is not None:  # the right leg's mirrored limits: check the magnitude
                assert np.abs(vals).max() <= span
            else:
                assert lo <= vals.min() and vals.max() <= hi


@pytest.mark.parametrize("cycle", [0.8, 1.0, 2.0])
def test_sway_puts_the_pendulum_zmp_on_the_stance_foot(cycle: float) -> None:
    cfg = GaitConfig()
    tau = np.linspace(0.0, cycle / 2, 2001)
    y = cfg.sway(cycle, tau) * cfg.sway_com_ratio
    ydd = np.gradient(np.gradient(y, tau), tau)
    zmp = y - ydd * cfg.com_height_m / 9.81
    ss = (tau > cfg.double_support * cycle / 2 + 0.02) & (tau < cycle / 2 - 0.02)
    np.testing.assert_allclose(zmp[ss], cfg.zmp_y_m, atol=0.1 * cfg.zmp_y_m)
