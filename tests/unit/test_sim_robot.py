"""The pybullet NAO (real pybullet, DIRECT): contract, model, config, sensors, cameras, falls."""

from __future__ import annotations

import math
import re

import numpy as np
import pybullet as pb
import pytest
from bipedtele.config.profile import ConfigError, parse_section
from bipedtele.follower.check import RobotContractError, check_robot
from bipedtele.follower.robot import (
    FollowerRobot,
    RobotNotConnectedError,
    WalkCommand,
    make_robot,
)
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.model import NaoGeometry, nao_urdf
from bipedtele.follower.sim.robot import SimNao
from bipedtele.follower.sim.world import TASK_COURSE, Obstacle, WorldConfig


@pytest.mark.timeout(120)
def test_sim_nao_keeps_the_robot_contract() -> None:
    check_robot(lambda: make_robot("sim"))


def test_contract_checker_catches_a_robot_that_does_not_clamp() -> None:
    class Unclamped(SimNao):
        def send_walk(self, cmd: WalkCommand) -> WalkCommand:
            super().send_walk(cmd)
            return cmd

    with pytest.raises(RobotContractError, match="send_walk"):
        check_robot(Unclamped)


def test_urdf_has_nao_leg_dimensions_and_mass() -> None:
    g = NaoGeometry()
    assert g.total_mass == pytest.approx(5.3, abs=0.1)
    assert g.m_torso / g.total_mass == pytest.approx(0.6, abs=0.05)
    text = nao_urdf(g)
    masses = [float(m) for m in re.findall(r'<mass value="([0-9.]+)"', text)]
    assert sum(masses) == pytest.approx(g.total_mass, abs=1e-3)
    assert len(re.findall(r'type="revolute"', text)) == 12
    assert '<origin xyz="0.00000 0.05000 -0.08500"/>' in text  # left hip offset y, z
    assert '<origin xyz="0.00000 0.00000 -0.10000"/>' in text  # thigh
    assert '<origin xyz="0.00000 0.00000 -0.10290"/>' in text  # tibia


def test_make_robot_sim_and_config_errors() -> None:
    assert isinstance(make_robot("sim"), SimNao)
    with pytest.raises(ConfigError, match=r"sim\.bogus"):
        SimNao(bogus=1)
    with pytest.raises(ConfigError, match="cycle_min_s"):
        SimNao(cycle_min_s=3.0, cycle_max_s=2.0)
    with pytest.raises(ConfigError, match=r"world.obstacles\[0\]"):
        parse_section(WorldConfig, {"obstacles": [{"shape": "cylinder", "size": [1, 2, 3]}]}, "world")
    w = parse_section(
        WorldConfig, {"obstacles": [{"shape": "box", "position": [1, 0, 0.2], "size": [0.1, 0.2, 0.4]}]}, "world"
    )
    assert w.obstacles[0] == Obstacle("box", [1.0, 0.0, 0.2], [0.1, 0.2, 0.4])
    with pytest.raises(ConfigError, match="nao_version"):
        parse_section(SimConfig, {"nao_version": "V7"}, "sim")


def test_nan_and_out_of_range_commands_are_clamped() -> None:
    with SimNao() as robot:
        sent = robot.send_walk(WalkCommand(math.nan, math.inf, math.nan, -1.0))
        assert sent.forward_m_s == 0.0 and sent.turn_rad_s == 0.0
        assert robot.limits.cycle_s[0] <= sent.cycle_s <= robot.limits.cycle_s[1]
        sent = robot.send_walk(WalkCommand(1.0, 0.0, 2.0, 0.1))
        assert sent.forward_m_s == pytest.approx(2 * robot.config.max_step_m / 2.0)  # step length bound
        robot.advance(1.0)
        obs = robot.observe()
        assert not obs.fallen and all(math.isfinite(v) for v in (obs.v_hip_m_s, obs.tilt_rad))
    with pytest.raises(RobotNotConnectedError):
        robot.observe()


@pytest.mark.parametrize(("version", "seen"), [("V6", False), ("V4", True)])
def test_sonar_range_follows_the_nao_version(version: str, seen: bool) -> None:
    world = WorldConfig(obstacles=[Obstacle("box", [1.6, 0.0, 0.3], [0.2, 1.0, 0.6])])
    with SimNao(world=world, nao_version=version) as robot:
        left, right = robot.observe().sonar_m
        hi = robot.sonar_range_m[1]
        if seen:  # V3/V4 reach 2.55 m: the wall 1.45 m ahead is seen by both cones
            assert 1.4 < left < 1.8 and 1.4 < right < 1.8
        else:  # V5/V6 reach 0.8 m: nothing, so the maximum
            assert left == right == hi == 0.8


def test_sonar_cones_see_their_own_side_and_clamp_at_the_minimum() -> None:
    world = WorldConfig(
        obstacles=[
            Obstacle("cylinder", [0.5, 0.35, 0.3], [0.06, 0.6]),
            Obstacle("box", [0.12, -0.25, 0.3], [0.05, 0.3, 0.6]),
        ]
    )
    with SimNao(world=world) as robot:
        left, right = robot.observe().sonar_m
        assert 0.45 < left < 0.65  # the cylinder ahead-left, 22 degrees + cone
        assert right == pytest.approx(0.20)  # the box right beside: below the minimum range


def test_cameras_render_qvga_rgb() -> None:
    world = WorldConfig(obstacles=list(TASK_COURSE))
    with SimNao(world=world) as robot:
        head = robot.capture("head")
        scene = robot.capture("scene")
        for img in (head, scene):
            assert img is not None and img.shape == (240, 320, 3) and img.dtype == np.uint8
            assert img.reshape(-1, 3).std(axis=0).max() > 5  # not a blank frame
        assert robot.capture("bogus") is None
    ahead = WorldConfig(obstacles=[Obstacle("box", [1.0, 0.0, 0.25], [0.2, 0.3, 0.5])])
    with SimNao(world=ahead) as robot:
        head = robot.capture("head")
        # the head camera sees the red box straight ahead (reddish pixels in the centre)
        assert head is not None
        centre = head[135:175, 140:180].astype(int)
        assert (centre[..., 0] - centre[..., 2]).mean() > 80


def test_a_pushed_robot_is_reported_fallen() -> None:
    with SimNao() as robot:
        assert not robot.observe().fallen
        pb.resetBasePositionAndOrientation(
            robot._robot, [0, 0, 0.2], pb.getQuaternionFromEuler([1.2, 0, 0]), physicsClientId=robot._client
        )
        robot.advance(1.0)
        obs = robot.observe()
        assert obs.fallen and obs.tilt_rad > math.radians(45)
        robot.stop()  # safe when down
        robot.send_walk(WalkCommand(0.05))
        robot.advance(0.2)


def test_disconnect_is_idempotent_and_releases_pybullet() -> None:
    robot: FollowerRobot = SimNao()
    robot.connect()
    client = robot._client
    robot.disconnect()
    robot.disconnect()
    assert not pb.isConnected(physicsClientId=client)


@pytest.mark.timeout(120)
def test_reset_pose_puts_a_walked_or_fallen_robot_back_on_the_start_standing() -> None:
    world = WorldConfig(obstacles=[Obstacle(shape="box", position=[2.0, 0.0, 0.25], size=[0.2, 0.3, 0.5])])
    with SimNao(world=world) as robot:
        start = robot.observe()
        robot.send_walk(WalkCommand(forward_m_s=0.06, turn_rad_s=0.2, cycle_s=1.0))
        robot.advance(6.0)
        moved = robot.observe()
        assert moved.pose[0] > 0.15 and abs(moved.pose[2]) > 0.3
        robot.reset_pose()
        back = robot.observe()
        assert back.t >= moved.t  # robot time never runs backwards
        assert back.pose == pytest.approx(start.pose, abs=0.01)
        assert not back.fallen and not back.walking
        assert back.sonar_m == pytest.approx(start.sonar_m, abs=0.01)  # the same world
        pb.resetBasePositionAndOrientation(
            robot._robot, [0, 0, 0.2], pb.getQuaternionFromEuler([1.2, 0, 0]), physicsClientId=robot._client
        )
        robot.advance(1.0)
        assert robot.observe().fallen
        robot.reset_pose()
        assert not robot.observe().fallen
        robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))  # and it walks again
        robot.advance(5.0)
        again = robot.observe()
        assert 0.1 < again.pose[0] < 0.4 and not again.fallen


def test_reset_on_leader_is_refused_for_a_real_nao(tmp_path) -> None:
    import subprocess
    import sys

    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "follower",
            "--robot",
            "naoqi",
            "--reset-on-leader",
            "--set",
            f'record.dir="{tmp_path}"',
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--reset-on-leader" in lines[0] and "simulator" in lines[0], proc.stderr
    assert list(tmp_path.iterdir()) == []  # nothing written
