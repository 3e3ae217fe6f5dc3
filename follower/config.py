"""The ``[follower]`` section: rates, safety and sensing of the follower loop."""

from __future__ import annotations

from dataclasses import dataclass

from bipedtele.config.profile import param
from bipedtele.follower.robot import Camera, robot_names

__all__ = ["FollowerConfig"]


@dataclass(frozen=True)
class FollowerConfig:
    """Follower loop settings (see follower/loop.py)."""

    robot: str = param(
        "sim", doc="which robot: 'sim' (the pybullet NAO) or 'naoqi' (a real NAO); the bipedtele.robots entry points"
    )
    realtime: bool = param(True, doc="pace the loop in real time (off: as fast as possible, sim only)")
    control_rate_hz: float = param(50.0, lo=5.0, hi=1000.0, unit="Hz", doc="control loop rate")
    feedback_rate_hz: float = param(50.0, lo=1.0, hi=1000.0, unit="Hz", doc="feedback publish rate")
    status_rate_hz: float = param(2.0, lo=0.1, hi=50.0, unit="Hz", doc="status publish rate")
    watchdog_s: float = param(
        0.5, lo=0.05, hi=10.0, unit="s", doc="no new command for this long (local receive time) -> stop and stand"
    )
    max_cmd_age_s: float = param(
        1.5, lo=0.05, hi=30.0, unit="s", doc="commands older than this (sender time) are dropped; above the worst delay"
    )
    backlog_window_s: float = param(
        10.0,
        lo=1.0,
        hi=120.0,
        unit="s",
        doc="baseline delay = minimum h1 of the commands applied over this window; a command delayed more than "
        "watchdog_s beyond it is an outage's backlog and dropped (cmd_backlog)",
    )
    param_update_s: float = param(
        0.005, lo=0.0, hi=1.0, unit="s", doc="recompute (40) and (30) when h1 or h2 moved by more than this"
    )
    camera_fps: float = param(10.0, lo=0.0, hi=30.0, unit="Hz", doc="video rate per camera (0: no video)")
    cameras: list[Camera] = param(default_factory=lambda: ["scene", "head"], doc="cameras to stream: head, scene")
    jpeg_quality: int = param(80, lo=10, hi=100, doc="JPEG quality of video frames")
    sonar_d_safe_m: float = param(0.50, lo=0.05, hi=5.0, unit="m", doc="fictitious force starts at this range")
    sonar_d_stop_m: float = param(0.20, lo=0.01, hi=5.0, unit="m", doc="fictitious force saturates at this range")
    sonar_f_max: float = param(10.0, lo=0.0, hi=100.0, doc="fictitious force per sonar at d_stop (cm/s with k_z = 1)")
    sonar_yaw_deg: float = param(22.0, lo=0.0, hi=90.0, unit="deg", doc="yaw of each sonar axis")

    def __post_init__(self) -> None:
        if self.robot not in robot_names():
            raise ValueError(f"robot: {self.robot!r}: allowed: {', '.join(repr(n) for n in robot_names())}")
        if not self.sonar_d_stop_m < self.sonar_d_safe_m:
            raise ValueError("sonar_d_stop_m, sonar_d_safe_m: allowed: sonar_d_stop_m < sonar_d_safe_m")
