"""NaoqiRobot against the fake NAO served over real libqi in a separate process.

Tests that only check how walk commands map to ALMotion run the bridge with
``allow_unguarded``; the guard's own tests start the real guard (nao_guard.py) beside the
fake robot.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.follower.naoqi import NaoqiConfig, NaoqiRobot, move_config_for
from bipedtele.follower.naoqi.session import UserTokenAuthenticatorFactory
from bipedtele.follower.robot import (
    RobotError,
    RobotNotConnectedError,
    WalkCommand,
    WalkRefusedError,
    make_robot,
)
from bipedtele.follower.video import VideoStreamer

pytest.importorskip("qi")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fakes.fake_naoqi import FakeNaoqi, free_port

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def fake():
    with FakeNaoqi() as f:
        yield f


@pytest.fixture
def robot(fake):
    fake.control().set_obstacles([])
    r = NaoqiRobot(url=fake.url, call_timeout_s=2.0, allow_unguarded=True)
    r.connect()
    yield r
    r.disconnect()


def _until(cond, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError("condition not met in time")


def test_cycle_sets_step_frequency_and_speed_limits():
    cfg = NaoqiConfig()
    for cycle, freq in [(0.8, 1.0), (1.0, 0.5), (1.2, 0.0), (3.0, 0.0), (0.3, 1.0)]:
        move, sent = move_config_for(WalkCommand(forward_m_s=0.05, cycle_s=cycle), cfg)
        assert move.step_frequency == pytest.approx(freq)
        assert sent.cycle_s == pytest.approx(2 * move.step_period_s)
        assert cfg.cycle_range_s[0] - 1e-9 <= sent.cycle_s <= cfg.cycle_range_s[1] + 1e-9
    move, sent = move_config_for(WalkCommand(forward_m_s=1.0, turn_rad_s=-5.0, cycle_s=1.2), cfg)
    assert sent.forward_m_s == pytest.approx(0.04 / 0.6)  # MaxStepX per 0.6 s step
    assert sent.turn_rad_s == pytest.approx(-cfg.max_turn_rad_s)
    names = [p[0] for p in move.as_naoqi()]
    assert names == ["MaxStepX", "MaxStepY", "MaxStepTheta", "MaxStepFrequency", "StepHeight"]
    _, sent = move_config_for(WalkCommand(forward_m_s=float("nan"), cycle_s=1.0), cfg)
    assert sent.forward_m_s == 0.0


def test_connect_stops_wakes_stands_and_subscribes_sonar(fake, robot):
    assert robot.is_connected
    calls = [c[1] for c in fake.calls() if c[1] in ("stopMove", "wakeUp", "goToPosture", "subscribe")]
    assert calls[-4:] == ["stopMove", "wakeUp", "goToPosture", "subscribe"]
    state = fake.state()
    assert state["awake"] and state["posture"] == "StandInit"
    assert state["sonar_subscribers"] == ["bipedtele"]
    obs = robot.observe()
    assert obs.pose == (0.0, 0.0, 0.0) and not obs.walking and not obs.fallen


def test_walk_sends_clamped_move_and_odometry_advances(fake, robot):
    sent = robot.send_walk(WalkCommand(forward_m_s=0.5, turn_rad_s=1.0, cycle_s=1.0, eps_s=0.1))
    assert sent.forward_m_s == pytest.approx(0.08)  # 0.04 m per 0.5 s step
    assert sent.turn_rad_s == pytest.approx(robot.limits.max_turn_rad_s)
    assert sent.cycle_s == pytest.approx(1.0)
    x, y, theta, config = fake.calls("move")[-1][2]
    assert (x, y, theta) == pytest.approx((0.08, 0.0, robot.limits.max_turn_rad_s))
    assert dict(config)["MaxStepFrequency"] == pytest.approx(0.5)
    assert dict(config)["MaxStepX"] == pytest.approx(0.04) and dict(config)["StepHeight"] == pytest.approx(0.02)
    obs = _until(lambda: (o := robot.observe()).pose[0] > 0.02 and o)
    assert obs.walking and obs.v_hip_m_s == pytest.approx(0.08)
    assert obs.turn_rate_rad_s == pytest.approx(robot.limits.max_turn_rad_s)
    assert obs.pose[2] > 0.0


def test_stop_after_walk_stands_still(fake, robot):
    robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
    assert robot.observe().walking
    robot.stop()
    robot.stop()  # repeatable
    assert fake.calls()[-1][1] == "stopMove"
    obs = robot.observe()
    assert not obs.walking and obs.v_hip_m_s == 0.0
    x0 = obs.pose[0]
    time.sleep(0.1)
    assert robot.observe().pose[0] == pytest.approx(x0)


def test_sonar_sees_obstacles_within_the_version_range(fake):
    ctl = fake.control()
    ctl.set_pose(0.0, 0.0, 0.0)
    ctl.set_obstacles([[0.6, 0.0, 0.1]])  # 0.5 m ahead: both cones
    with NaoqiRobot(url=fake.url) as r:
        assert r.observe().sonar_m == pytest.approx((0.5, 0.5), abs=1e-6)
        ctl.set_obstacles([[0.4, 0.35, 0.05]])  # ahead-left only
        left, right = r.observe().sonar_m
        assert left < 0.5 and right == pytest.approx(0.8)
        ctl.set_obstacles([[1.6, 0.0, 0.1]])  # beyond V5/V6's reliable 0.8 m
        assert r.observe().sonar_m == pytest.approx((0.8, 0.8))
    with NaoqiRobot(url=fake.url, sonar_version="v4") as r:  # V3/V4: up to 2.55 m
        assert r.observe().sonar_m == pytest.approx((1.5, 1.5), abs=1e-6)
    assert fake.state()["sonar_subscribers"] == []
    ctl.set_obstacles([])


def test_tilt_from_inertial_angles_means_fallen(fake, robot):
    ctl = fake.control()
    ctl.set_memory("Device/SubDeviceList/InertialSensor/AngleY/Sensor/Value", 1.4)
    try:
        obs = robot.observe()
        assert obs.fallen and obs.tilt_rad == pytest.approx(1.4)
    finally:
        ctl.set_memory("Device/SubDeviceList/InertialSensor/AngleY/Sensor/Value", 0.0)
    assert not robot.observe().fallen


def test_head_camera_gives_qvga_rgb_frames(fake):
    with NaoqiRobot(url=fake.url, camera_fps=15) as r:
        a = r.capture("head")
        b = r.capture("head")
        assert r.capture("scene") is None
        assert a is not None and b is not None
        assert a.shape == (240, 320, 3) and a.dtype == np.uint8
        assert not np.array_equal(a, b)  # new frames
        assert a[0, 0, 2] == 128 and a[10, 0, 1] == 10  # decoded in row-major RGB order
        sub = fake.calls("subscribeCamera")[-1][2]
        assert sub[1:] == [0, 1, 11, 15]  # top camera, kQVGA, kRGBColorSpace, fps
    assert fake.state()["video_subscribers"] == []  # unsubscribed on disconnect


def test_bad_answers_raise_robot_error_and_the_bridge_survives(fake, robot):
    ctl = fake.control()
    cases = [
        ("getRobotVelocity", "string", "getRobotVelocity"),
        ("getRobotPosition", "nan", "getRobotPosition"),
        ("getListData", "short", "getListData"),
        ("moveIsActive", "string", "moveIsActive"),
    ]
    for method, kind, word in cases:
        ctl.set_fault(method, kind)
        try:
            with pytest.raises(RobotError, match=word) as info:
                robot.observe()
            assert "\n" not in str(info.value)
        finally:
            ctl.set_fault(method, "")
        assert robot.is_connected
        robot.observe()
    ctl.set_fault("getImageRemote", "short")
    try:
        with pytest.raises(RobotError, match="bytes"):
            robot.capture("head")
    finally:
        ctl.set_fault("getImageRemote", "")
    assert robot.capture("head").shape == (240, 320, 3)


def test_robot_vanishing_mid_walk_then_reconnect():
    with FakeNaoqi() as fake:
        robot = NaoqiRobot(
            url=fake.url,
            call_timeout_s=1.0,
            connect_timeout_s=1.0,
            reconnect_backoff_s=[0.1, 0.5],
            allow_unguarded=True,
        )
        robot.connect()
        robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
        fake.kill()
        with pytest.raises(RobotError, match="gone"):
            robot.observe()
        assert not robot.is_connected
        robot.stop()  # safe: logs, does not raise
        with pytest.raises(RobotNotConnectedError):
            robot.send_walk(WalkCommand(forward_m_s=0.05))
        with pytest.raises(RobotError, match="still unreachable"):
            robot.reconnect(timeout_s=0.5)
        fake.start()
        robot.reconnect(timeout_s=15.0)
        assert robot.is_connected
        names = [c[1] for c in fake.calls()]
        assert names.index("stopMove") < names.index("wakeUp")  # stopped first thing
        assert robot.observe().pose == (0.0, 0.0, 0.0)
        robot.disconnect()
        robot.disconnect()  # idempotent
        with pytest.raises(RobotNotConnectedError):
            robot.observe()


def test_unreachable_robot_is_one_clear_line():
    robot = NaoqiRobot(url=f"tcp://127.0.0.1:{free_port()}", connect_timeout_s=1.0)
    with pytest.raises(RobotError, match="cannot reach NAOqi") as info:
        robot.connect()
    assert "\n" not in str(info.value)
    assert not robot.is_connected
    with pytest.raises(RobotNotConnectedError):
        robot.stop()


def test_credentials_go_through_the_authenticator_factory(fake, tmp_path):
    factory = UserTokenAuthenticatorFactory("nao", "s3cret")
    assert factory.newAuthenticator().initialAuthData() == {"user": "nao", "token": "s3cret"}
    pw = tmp_path / "pw"
    pw.write_text("s3cret\n")
    cfg = NaoqiConfig(url=fake.url, user="nao", password_file=str(pw))
    assert cfg.resolved_password() == "s3cret"
    with NaoqiRobot(cfg) as r:  # an open (tcp) NAOqi accepts any credentials
        assert r.is_connected


def test_registered_robot_and_config_section():
    cfg = load_config("default", ["naoqi.url=tcp://10.1.2.3:9559", "naoqi.sonar_version=v4"])
    r = make_robot("naoqi", config=cfg)
    assert isinstance(r, NaoqiRobot) and r.config.url == "tcp://10.1.2.3:9559"
    assert r.config.sonar_range_m == (0.25, 2.55)
    with pytest.raises(RobotNotConnectedError):
        r.observe()
    with pytest.raises(ConfigError, match="url"):
        load_config("default", ["naoqi.url=http://nao"])
    with pytest.raises(ConfigError, match="unknown key"):
        NaoqiRobot(urll="tcp://x:1")


def test_contract_checker(fake):
    check = pytest.importorskip(
        "bipedtele.follower.check", reason="the contract checker (follower/check.py) is not there yet"
    )
    fake.control().set_obstacles([])
    check.check_robot(lambda: NaoqiRobot(url=fake.url, allow_unguarded=True))


# ---------------------------------------------------------------- faults (issue 10 items 1, 10)


def test_a_timed_out_call_is_not_a_lost_link_the_robot_stops_and_walks_again(fake, robot):
    robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
    robot.config = robot.config.__class__(**{**robot.config.__dict__, "call_timeout_s": 0.3})
    ctl = fake.control()
    ctl.set_fault("getRobotVelocity", "hang")
    try:
        with pytest.raises(RobotError, match="timed out") as info:
            robot.observe()
        assert "gone" not in str(info.value)
        assert robot.is_connected  # slow is not gone
        t_stop = time.time()
        robot.stop()  # reaches NAO: the other calls still answer
        assert any(c[3] >= t_stop for c in fake.calls("stopMove"))
        assert fake.state()["vel"] == [0.0, 0.0, 0.0]
    finally:
        ctl.set_fault("getRobotVelocity", "")
    robot.observe()
    robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
    assert fake.state()["vel"][0] > 0.0


def test_disconnect_after_the_link_dropped_stops_nao_over_a_new_session():
    with FakeNaoqi() as fake:
        robot = NaoqiRobot(url=fake.url, call_timeout_s=1.0, connect_timeout_s=1.0, allow_unguarded=True)
        robot.connect()
        robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
        fake.kill()
        with pytest.raises(RobotError, match="gone"):
            robot.observe()
        fake.start()  # NAO reachable again (same port), the old session is dead
        robot.disconnect()
        assert [c[1] for c in fake.calls()] == ["stopMove"]  # only a stop: no wake-up, no posture


def test_camera_data_typed_as_a_string_costs_frames_not_the_follower():
    with FakeNaoqi(image_data="string") as fake, NaoqiRobot(url=fake.url, allow_unguarded=True) as robot:
        with pytest.raises(RobotError, match="str"):
            robot.capture("head")
        with VideoStreamer(robot, ["head"], 10.0, lambda f: None) as video:
            for k in range(5):
                video.maybe_capture(k * 0.1)  # never raises
        assert video.stats["errors"] == 5 and video.stats["captured"] == 0
        robot.observe()  # the robot is fine
        robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))


# ---------------------------------------------------------------- the NAO guard (issue 10)

GUARD = Path(__file__).resolve().parents[2] / "follower" / "naoqi" / "nao_guard.py"


def _start_guard(url: str, log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as fh:
        proc = subprocess.Popen([sys.executable, str(GUARD), "--url", url], stdout=fh, stderr=subprocess.STDOUT)
    _until(lambda: "registered" in log.read_text(), 20.0)
    return proc


def test_without_a_guard_the_bridge_refuses_to_walk_in_one_line(fake, caplog):
    fake.control().set_obstacles([])
    with caplog.at_level(logging.ERROR), NaoqiRobot(url=fake.url) as robot:
        n_moves = len(fake.calls("move"))
        for _ in range(5):
            with pytest.raises(WalkRefusedError, match="--unguarded-robot-may-keep-walking") as info:
                robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
        assert "bipedtele nao-guard --naoqi-url " + fake.url in str(info.value)
        assert "\n" not in str(info.value)
        assert len(fake.calls("move")) == n_moves and fake.state()["vel"] == [0.0, 0.0, 0.0]
    refusals = [r for r in caplog.records if "refusing to walk" in r.getMessage()]
    assert len(refusals) == 2  # once at connect, once when a walk was refused; not per tick


def test_with_a_guard_the_bridge_walks_and_a_vanished_guard_makes_it_stand(tmp_path):
    with FakeNaoqi() as fake:
        guard = _start_guard(fake.url, tmp_path / "guard.log")
        try:
            with NaoqiRobot(url=fake.url, call_timeout_s=1.0) as robot:
                assert robot.guarded
                for _ in range(20):  # the loop's ticks keep the heartbeats going
                    robot.observe()
                    robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
                    time.sleep(0.05)
                assert fake.state()["vel"][0] > 0.0
                guard.kill()  # the guard dies: the bridge must not walk unguarded
                guard.wait(10)
                t_kill = time.time()

                def refused() -> bool:
                    robot.observe()
                    try:
                        robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
                    except WalkRefusedError:
                        return True
                    time.sleep(0.02)
                    return False

                _until(refused, 3.0)
                assert any(c[3] >= t_kill for c in fake.calls("stopMove"))
                assert fake.state()["vel"] == [0.0, 0.0, 0.0]
                guard = _start_guard(fake.url, tmp_path / "guard2.log")

                def walks() -> bool:
                    robot.observe()
                    try:
                        robot.send_walk(WalkCommand(forward_m_s=0.05, cycle_s=1.0))
                    except WalkRefusedError:
                        time.sleep(0.05)
                        return False
                    return True

                _until(walks, 10.0)
                assert fake.state()["vel"][0] > 0.0
            # a clean disconnect releases the guard: only the bridge's own stop
            n_stops = len(fake.calls("stopMove"))
            time.sleep(1.0)
            assert len(fake.calls("stopMove")) == n_stops
        finally:
            guard.kill()
            guard.wait(10)
