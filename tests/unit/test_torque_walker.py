"""The torque walker's model and joint law: the rigid-body model against pybullet, (14)'s
``y'' = -v`` with the exact model over a walking cycle (checked by an independent KKT solve),
the estimator (observer and torso-mass adaptation) against ``W_hat = 0`` with a wrong model,
the adaptation's estimate, the motor envelope, and walks on joint torques alone.
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import pinocchio as pin
import pybullet as pb
import pytest
from bipedtele.follower.robot import WalkCommand
from bipedtele.follower.sim.flcontrol import FeedbackLinearising, FlInput, FlState, MotorLimits, output_rows
from bipedtele.follower.sim.model import NaoGeometry, nao_urdf
from bipedtele.follower.sim.rigidbody import RigidBodyModel, perturbed_geometry, state_from_pybullet
from bipedtele.follower.sim.torque_config import TorqueConfig
from bipedtele.follower.sim.torque_robot import TorqueNao, motor_limits

pytestmark = [pytest.mark.compute, pytest.mark.timeout(300)]

GEOM = NaoGeometry(rotor_pitch_kgm2=0.0068, rotor_roll_kgm2=0.0162)


def _state(robot: TorqueNao) -> tuple[np.ndarray, np.ndarray]:
    rob, c = robot._robot, robot._client
    pos, orn = pb.getBasePositionAndOrientation(rob, physicsClientId=c)
    lin, ang = pb.getBaseVelocity(rob, physicsClientId=c)
    js = pb.getJointStates(rob, robot._joints, physicsClientId=c)
    q = np.array([s[0] for s in js])
    dq = np.array([s[1] for s in js])
    return state_from_pybullet(np.array(pos), np.array(orn), np.array(lin), np.array(ang), q, dq, robot._com)


def test_the_model_predicts_pybullets_accelerations_in_free_flight() -> None:
    """M, h and the state conversion: the model's joint accelerations are pybullet's (no contact)."""
    c = pb.connect(pb.DIRECT)
    try:
        dt = 1e-3
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        pb.setTimeStep(dt, physicsClientId=c)
        fd, path = tempfile.mkstemp(suffix=".urdf")
        with os.fdopen(fd, "w") as fh:
            fh.write(nao_urdf(GEOM))
        try:
            rob = pb.loadURDF(path, [0, 0, 2], flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        finally:
            os.unlink(path)
        joints = list(range(12))
        for j in [-1, *joints]:
            pb.changeDynamics(rob, j, linearDamping=0, angularDamping=0, jointDamping=0, physicsClientId=c)
        pb.setJointMotorControlArray(rob, joints, pb.VELOCITY_CONTROL, forces=[0] * 12, physicsClientId=c)
        rng = np.random.default_rng(0)
        for j in joints:
            pb.resetJointState(rob, j, rng.uniform(-0.3, 0.3), rng.uniform(-1, 1), physicsClientId=c)
        pb.resetBaseVelocity(rob, [0.1, 0.2, 0.0], [0.5, -0.3, 0.2], physicsClientId=c)
        model = RigidBodyModel(GEOM)
        com = np.array([0.0, 0.0, GEOM.torso_com_z])
        worst = 0.0
        for k in range(6):
            pos, orn = pb.getBasePositionAndOrientation(rob, physicsClientId=c)
            lin, ang = pb.getBaseVelocity(rob, physicsClientId=c)
            js = pb.getJointStates(rob, joints, physicsClientId=c)
            q, v = state_from_pybullet(
                np.array(pos),
                np.array(orn),
                np.array(lin),
                np.array(ang),
                np.array([s[0] for s in js]),
                np.array([s[1] for s in js]),
                com,
            )
            u = rng.uniform(-1.0, 1.0, 12)
            aff = model.affine(q, v, "")
            pb.setJointMotorControlArray(rob, joints, pb.TORQUE_CONTROL, forces=u.tolist(), physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
            js2 = pb.getJointStates(rob, joints, physicsClientId=c)
            measured = (np.array([s[1] for s in js2]) - v[6:]) / dt
            if k > 0:  # pybullet's first step after resetJointState is not a dynamics step
                worst = max(worst, float(np.max(np.abs(measured - (aff.A @ u + aff.b)) / (1.0 + np.abs(measured)))))
        assert worst < 1e-6
    finally:
        pb.disconnect(physicsClientId=c)


def _kkt_joint_acceleration(
    model: RigidBodyModel, q: np.ndarray, v: np.ndarray, u: np.ndarray, contacts: str
) -> np.ndarray:
    """The constrained joint accelerations by one KKT solve (not the projection :meth:`affine` uses)."""
    m, d = model.model, model.data
    pin.forwardKinematics(m, d, q, v, np.zeros(m.nv))
    pin.computeJointJacobians(m, d, q)
    pin.updateFramePlacements(m, d)
    M = pin.crba(m, d, q)
    M = np.triu(M) + np.triu(M, 1).T
    h = pin.nonLinearEffects(m, d, q, v)
    frames = [m.getFrameId(f"{k}_foot") for k in contacts]
    J = np.vstack([pin.getFrameJacobian(m, d, f, pin.LOCAL) for f in frames])
    g = np.concatenate([pin.getFrameAcceleration(m, d, f, pin.LOCAL).vector for f in frames])
    n, k = m.nv, J.shape[0]
    kkt = np.block([[M, -J.T], [J, np.zeros((k, k))]])
    rhs = np.concatenate([np.concatenate([np.zeros(6), u]) - h, -g])
    return np.linalg.solve(kkt, rhs)[6:n]


def test_with_the_exact_model_the_outputs_obey_ddy_equal_minus_v_over_a_walking_cycle() -> None:
    """(14) with the exact model: along a real walking cycle of the torque walker, in single and
    double support, the outputs' accelerations under the computed torques (constrained dynamics
    solved independently) are ``-v`` to numerical precision."""
    robot = TorqueNao(torque=TorqueConfig(model_error=0.0, dob_rate_s=0.0))
    exact = RigidBodyModel(robot.geom)
    law = FeedbackLinearising(exact, dob_rate_s=0.0, limits=None)
    worst, seen = 0.0, set()
    with robot:
        robot.advance(0.3)
        robot.send_walk(WalkCommand(0.04, math.radians(10.0), 1.0, 0.05))
        robot.advance(1.0)
        for _ in range(100):  # one walking cycle, every 10 ms
            robot.advance(0.01)
            q, v = _state(robot)
            g = robot.gait
            qref, dqref = g.update(robot._t)
            inp = FlInput(q, v, qref, dqref, g.acceleration(), g.stance, g.support, 0.05, 0.2)
            _, u, out = law.step(FlState(), inp, 1e-3)
            rows, H, _, _, drift = law.outputs(inp)
            ddq = _kkt_joint_acceleration(exact, q, v, u, g.support)
            ddy = H @ ddq + drift
            worst = max(worst, float(np.max(np.abs(ddy + out.v)) / (1.0 + np.max(np.abs(out.v)))))
            seen.add((g.support, len(rows)))
    assert {("LR", 6), ("L", 12), ("R", 12)} <= seen
    assert worst < 1e-8


def test_output_rows_are_the_stance_legs_six_then_the_swing_legs_six() -> None:
    assert output_rows("L", "LR") == [12, 3, 4, 0, 1, 5]
    assert output_rows("R", "R") == [13, 9, 10, 6, 7, 11, 0, 1, 2, 3, 4, 5]


def test_the_motor_envelope_cuts_driving_torque_with_speed_and_never_braking() -> None:
    lim = MotorLimits(np.full(12, 7.78), np.full(12, 6.4))
    dq = np.array([0.0, 3.2, 6.4, 8.0, -3.2, 3.2] * 2)
    u = np.array([20.0, 20.0, 20.0, 20.0, 20.0, -20.0] * 2)
    out = lim.clip(u, dq)
    assert out[:6] == pytest.approx([7.78, 3.89, 0.0, 0.0, 7.78, -7.78])
    cfg = TorqueConfig()
    env = motor_limits(cfg)
    assert env.stall_nm[3] == pytest.approx(7.78) and env.stall_nm[0] == pytest.approx(11.97)
    assert env.no_load_rad_s[2] == pytest.approx(math.radians(366.83))


def test_the_wrong_model_is_off_by_at_most_the_stated_fraction() -> None:
    g = NaoGeometry()
    w = perturbed_geometry(g, 0.2)
    ratios = [w.m_torso / g.m_torso, w.m_thigh / g.m_thigh, w.m_tibia / g.m_tibia, w.m_foot / g.m_foot]
    assert max(abs(r - 1.0) for r in ratios) == pytest.approx(0.2)
    assert RigidBodyModel(w).mass != pytest.approx(RigidBodyModel(g).mass, rel=1e-3)
    with pytest.raises(ValueError, match="allowed"):
        perturbed_geometry(g, 1.5)


def walk_tracking_rms(model_error: float, dob_rate_s: float, mass_rate_s: float, seconds: float = 4.0) -> float:
    """RMS of the outputs [rad, m] in single support while the torque walker walks (4 cm/s, T = 1 s).

    From 1 s after the walk starts; all 12 outputs of every single-support physics step. The
    shared task of this test and ``bench/flcontrol.py``: the joint law with a model off by
    ``model_error``; ``W_hat`` by the observer at ``dob_rate_s`` and the torso-mass
    adaptation at ``mass_rate_s`` (both 0: ``W_hat = 0`` and the model as it is). Fails if the
    robot falls.
    """
    torque = TorqueConfig(model_error=model_error, dob_rate_s=dob_rate_s, mass_rate_s=mass_rate_s)
    robot = TorqueNao(torque=torque)
    ys: list[np.ndarray] = []
    actuate = robot._actuate

    def recording(*args: np.ndarray) -> None:
        actuate(*args)
        out = robot.last_output
        if out is not None and len(out.rows) == 12 and robot._t > 1.0:
            ys.append(out.y)

    robot._actuate = recording  # type: ignore[method-assign]
    with robot:
        robot.advance(0.5)
        robot.send_walk(WalkCommand(0.04, 0.0, 1.0, 0.05))
        for _ in range(round(seconds / 0.1)):
            robot.advance(0.1)
            assert not robot.observe().fallen
    return float(np.sqrt(np.mean(np.square(ys))))


def test_the_estimator_tracks_at_least_three_times_better_than_w_hat_zero_with_a_wrong_model() -> None:
    """The Done-when of the paper's follower: with the 20 % wrong model, ``W_hat = 0`` against
    the observer with the torso-mass adaptation, on the outputs of a walk's single supports."""
    cfg = TorqueConfig()
    without = walk_tracking_rms(0.2, 0.0, 0.0)
    with_estimator = walk_tracking_rms(0.2, cfg.dob_rate_s, cfg.mass_rate_s)
    assert with_estimator * 3.0 <= without, (with_estimator, without)


def _walk(torque: TorqueConfig, v: float, omega: float, cycle_s: float, seconds: float) -> tuple[TorqueNao, float]:
    """Walk ``seconds`` [s] at ``v`` [m/s], ``omega`` [rad/s] (ramped over 4 s); return the robot and when it fell (nan)."""
    robot = TorqueNao(torque=torque)
    with robot:
        robot.advance(0.5)
        for k in range(round(seconds / 0.1)):
            a = min(1.0, (k + 1) / 40)
            robot.send_walk(WalkCommand(v * a, omega * a, cycle_s, 0.05))
            robot.advance(0.1)
            obs = robot.observe()
            if obs.fallen:
                return robot, obs.t
    return robot, math.nan


def test_the_torso_mass_estimate_finds_the_true_mass_and_keeps_a_right_one() -> None:
    """The wrong model's torso is 20 % heavy: the estimate goes to 1/1.2 of it (within 3 %);
    with the exact model it stays at 1 (within 3 %)."""
    wrong, fell = _walk(TorqueConfig(model_error=0.2), 0.06, 0.0, 1.0, 10.0)
    assert math.isnan(fell)
    assert wrong._fl.torso_scale == pytest.approx(1.0 / 1.2, rel=0.03)
    exact, fell = _walk(TorqueConfig(model_error=0.0), 0.06, 0.0, 1.0, 10.0)
    assert math.isnan(fell)
    assert exact._fl.torso_scale == pytest.approx(1.0, rel=0.03)


def test_with_the_wrong_model_the_walker_turns_fast_only_with_the_adaptation() -> None:
    """20 % wrong model, T = 0.8 s, 8 cm/s and 20 deg/s to the right: with the torso-mass
    adaptation it walks 12 s; with the observer alone (the model's mass kept) it falls."""
    _, fell = _walk(TorqueConfig(model_error=0.2), 0.08, -math.radians(20.0), 0.8, 12.0)
    assert math.isnan(fell)
    _, fell = _walk(TorqueConfig(model_error=0.2, mass_rate_s=0.0), 0.08, -math.radians(20.0), 0.8, 12.0)
    assert fell < 12.0


def test_the_torque_walker_walks_on_joint_torques_alone_with_the_exact_model() -> None:
    with TorqueNao(torque=TorqueConfig(model_error=0.0, dob_rate_s=0.0)) as robot:
        robot.advance(0.5)
        x0 = robot.observe().pose[0]
        robot.send_walk(WalkCommand(0.04, 0.0, 1.0, 0.05))
        for _ in range(80):
            robot.advance(0.1)
            obs = robot.observe()
            assert not obs.fallen, obs
        assert obs.pose[0] - x0 > 0.2  # 8 s at 4 cm/s asked
        assert 0.03 < robot.cycle_speed() < 0.06
        assert robot.saturated_steps == 0


def test_a_held_joint_servo_falls_where_the_online_choice_does_not() -> None:
    """``bench/stability_pair.py``'s pair, shortened: on the shipped trace, the same operator and
    delays, the torque walker with the joint servo held at ``eps = 0.5 s`` falls; with (30)
    choosing ``(sigma_r, T, eps)`` on this walker's reduced model it does not."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import stability_pair as pair  # the bench script's runs, so the test runs what it prints

    out = pair.runs(15.0, "intercontinental", ("(30) online", "held eps = 0.5 s"))
    assert {name: run.fell for name, run in out.items()} == {"(30) online": False, "held eps = 0.5 s": True}
