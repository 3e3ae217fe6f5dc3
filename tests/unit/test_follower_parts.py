"""Reference model (28)+(12), the fictitious force (Sec. 3.2.1) and the video streamer's fault handling."""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import pytest
from bipedtele.control.reference import RealFollowerReference
from bipedtele.follower.fictitious import FictitiousForce
from bipedtele.follower.robot import RobotError
from bipedtele.follower.video import VideoStreamer
from bipedtele.link.messages import VideoFrame
from fakes.kinematic_robot import KinematicRobot

pytestmark = pytest.mark.timeout(30)


def _plant(eta_cmd: np.ndarray, state: np.ndarray, dt: float, tau: float = 0.6) -> np.ndarray:
    """A walking robot realising the commanded speed with a first-order lag tau [s]."""
    return state + dt / tau * (eta_cmd - state)


def test_reference_tracks_reference_on_a_lagging_robot() -> None:
    dt = 0.02
    ref_model = RealFollowerReference([4.5, 1.0], [1.0, 1.0], [1.0, 0.0], [0.5, 0.5], dt)
    robot = np.zeros(2)
    ref = np.array([5.0, 4.0])
    for _ in range(int(40 / dt)):
        eta = ref_model.step(ref, robot, np.array([2.0, 2.0]))
        robot = _plant(eta, robot, dt)
    np.testing.assert_allclose(robot, ref, atol=0.05)
    np.testing.assert_allclose(ref_model.z_r, ref, atol=0.05)


def test_fictitious_force_lowers_the_equilibrium_speed() -> None:
    dt = 0.02
    ref_model = RealFollowerReference([4.5, 1.0], [1.0, 1.0], [1.0, 0.0], [0.5, 0.5], dt)
    robot = np.zeros(2)
    for _ in range(int(60 / dt)):
        eta = ref_model.step(np.array([5.0, 0.0]), robot, np.array([2.0, 2.0]), np.array([3.0, 0.0]))
        robot = _plant(eta, robot, dt)
    # At rest: measured speed = ref - k_z f_v / k_s = 5 - 3.
    assert robot[0] == pytest.approx(2.0, abs=0.05)


def test_anti_windup_bounds_the_command() -> None:
    ref_model = RealFollowerReference([4.5, 1.0], [1.0, 1.0], [1.0, 0.0], [0.5, 0.5], 0.02)
    for _ in range(5000):  # robot never moves: the integrator would grow without bound
        eta = ref_model.step(np.array([50.0, 50.0]), np.zeros(2), np.zeros(2), eta_max=np.array([10.0, 20.0]))
    np.testing.assert_allclose(eta, [10.0, 20.0])


def test_reference_rejects_bad_period() -> None:
    with pytest.raises(ValueError, match="dt"):
        RealFollowerReference([1, 1], [1, 1], [0, 0], [1, 1], 0.0)


def test_fictitious_force_profile() -> None:
    f = FictitiousForce(d_safe=0.7, d_stop=0.3, f_max=10.0, sonar_yaw_rad=math.radians(22.0))
    c, s = math.cos(math.radians(22.0)), math.sin(math.radians(22.0))
    np.testing.assert_allclose(f(0.8, 0.8), [0.0, 0.0])  # nothing close
    np.testing.assert_allclose(f(0.5, 0.5), [5.0 * c, 0.0])  # halfway, seen by both: counted once
    np.testing.assert_allclose(f(0.1, 0.9), [10.0 * c, -10.0 * s])  # obstacle on the left
    np.testing.assert_allclose(f(0.9, 0.2), [10.0 * c, 10.0 * s])  # on the right -> push left
    np.testing.assert_allclose(f(float("nan"), float("inf")), [0.0, 0.0])


def test_fictitious_force_rejects_inverted_ranges() -> None:
    with pytest.raises(ValueError, match="d_stop"):
        FictitiousForce(d_safe=0.3, d_stop=0.5)


class _BadCamera(KinematicRobot):
    """A robot whose camera fails in the ways a bridge sees: an undecodable answer, a
    wrong array, then a good frame."""

    def __init__(self) -> None:
        super().__init__()
        self.answers: list[object] = []

    def capture(self, camera: str = "head") -> np.ndarray | None:
        answer = self.answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        return answer  # type: ignore[return-value]


def test_camera_faults_cost_frames_never_the_loop(caplog: pytest.LogCaptureFixture) -> None:
    robot = _BadCamera()
    robot.connect()
    robot.answers = [
        RobotError("ALVideoDevice image data is str: expected raw bytes"),
        RobotError("ALVideoDevice image data is str: expected raw bytes"),
        np.zeros((4, 4), dtype=np.float64),  # not an RGB image
        np.full((24, 32, 3), 7, dtype=np.uint8),
    ]
    frames: list[VideoFrame] = []
    with (
        caplog.at_level(logging.WARNING),
        VideoStreamer(robot, ["head"], 10.0, frames.append, now=lambda: 0.0) as video,
    ):
        for k in range(4):
            video.maybe_capture(k * 0.1)  # must not raise
        deadline = time.monotonic() + 5.0
        while not frames and time.monotonic() < deadline:
            time.sleep(0.01)
    assert video.stats["errors"] == 3 and video.stats["captured"] == 1
    assert len(frames) == 1 and frames[0].width == 32
    lines = [r for r in caplog.records if "frame skipped" in r.getMessage()]
    assert len(lines) == 1  # rate-limited
