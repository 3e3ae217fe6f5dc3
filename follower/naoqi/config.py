"""A real NAO as a part (``--robot naoqi``) and its ``[naoqi]`` section: how to reach it, walk and sensor settings.

The driver (:class:`bipedtele.follower.naoqi.robot.NaoqiRobot`) is loaded only when
:data:`PART` builds one (``qi`` itself only when it connects).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from bipedtele.config.profile import ConfigError, param
from bipedtele.follower.robot import RobotPart
from bipedtele.parts import lazy

__all__ = ["PART", "SONAR_RANGES_M", "NaoqiConfig"]

#: Reliable sonar range [m] per NAO head/body version (docs/hardware.md).
SONAR_RANGES_M: dict[str, tuple[float, float]] = {
    "v5": (0.20, 0.80),
    "v6": (0.20, 0.80),
    "v4": (0.25, 2.55),
    "v3": (0.25, 2.55),
}


@dataclass(frozen=True)
class NaoqiConfig:
    """Connection, walk and sensor settings of the NAOqi bridge (follower/naoqi/robot.py).

    Walk timing: NAO's walk takes a normalised ``MaxStepFrequency`` in [0, 1]; 0 gives the
    longest step period ``max_step_period_s`` and 1 the shortest ``min_step_period_s``.
    One walking cycle T is two steps, so T is realisable in
    ``[2 min_step_period_s, 2 max_step_period_s]``.
    """

    url: str = param(
        "tcp://nao.local:9559", doc="NAOqi URL: tcp://HOST:9559, or tcps://HOST:9503 (NAOqi >= 2.9, with user/password)"
    )
    user: str = param("", doc="user for tcps:// (NAOqi >= 2.9), usually 'nao'")
    password: str = param("", doc="password for tcps:// (prefer password_file)")
    password_file: str = param("", doc="file whose first line is the password")
    connect_timeout_s: float = param(10.0, lo=0.1, hi=300.0, unit="s", doc="session connect timeout")
    call_timeout_s: float = param(
        2.0, lo=0.05, hi=60.0, unit="s", doc="longest wait for one NAOqi call before the robot counts as gone"
    )
    posture_timeout_s: float = param(30.0, lo=1.0, hi=300.0, unit="s", doc="longest wait for wakeUp and StandInit")
    posture_speed: float = param(0.5, lo=0.05, hi=1.0, doc="ALRobotPosture.goToPosture speed fraction")
    reconnect_timeout_s: float = param(30.0, lo=0.0, hi=3600.0, unit="s", doc="reconnect(): give up after this long")
    reconnect_backoff_s: list[float] = param(
        default_factory=lambda: [0.2, 5.0], unit="s", doc="reconnect(): first and largest wait between tries (doubling)"
    )
    # ---- walk
    max_step_x_m: float = param(
        0.04, lo=0.001, hi=0.08, unit="m", doc="MaxStepX: longest forward step (NAO default 0.04)"
    )
    max_step_y_m: float = param(
        0.14, lo=0.101, hi=0.16, unit="m", doc="MaxStepY: lateral foot separation bound (NAO default 0.14)"
    )
    max_step_theta_rad: float = param(
        0.349, lo=0.001, hi=0.524, unit="rad", doc="MaxStepTheta: largest turn per step (NAO default 0.349)"
    )
    step_height_m: float = param(0.02, lo=0.005, hi=0.04, unit="m", doc="StepHeight (NAO default 0.02)")
    min_step_period_s: float = param(0.40, lo=0.1, hi=2.0, unit="s", doc="step period at MaxStepFrequency = 1")
    max_step_period_s: float = param(0.60, lo=0.1, hi=2.0, unit="s", doc="step period at MaxStepFrequency = 0")
    max_forward_m_s: float = param(
        0.10, lo=0.0, lo_open=True, hi=0.2, unit="m/s", doc="largest forward speed asked of NAO"
    )
    max_turn_rad_s: float = param(
        math.radians(20.0), lo=0.0, lo_open=True, hi=1.5, unit="rad/s", doc="largest turn rate asked of NAO"
    )
    use_sensors: bool = param(False, doc="odometry from joint sensors (getRobotPosition(True)) instead of commands")
    # ---- sensors
    sonar_version: Literal["v3", "v4", "v5", "v6"] = param(
        "v6", doc="NAO version: sets the reliable sonar range (v5/v6 0.20-0.80 m, v3/v4 0.25-2.55 m)"
    )
    fall_tilt_rad: float = param(0.8, lo=0.1, hi=1.6, unit="rad", doc="torso tilt beyond this counts as fallen")
    camera_fps: float = param(
        15.0, lo=1.0, hi=30.0, unit="Hz", doc="frame rate asked of ALVideoDevice (top camera, QVGA RGB)"
    )
    client_name: str = param("bipedtele", doc="name used for ALSonar / ALVideoDevice subscriptions")
    # ---- watchdog beside the robot (follower/naoqi/nao_guard.py, docs/hardware.md)
    allow_unguarded: bool = param(
        False,
        doc="walk even when no BipedteleGuard answers (--unguarded-robot-may-keep-walking): a follower that dies "
        "or loses the robot's network then leaves the NAO walking its last move",
    )
    guard_heartbeat_hz: float = param(20.0, lo=10.0, hi=100.0, unit="Hz", doc="heartbeat rate to the BipedteleGuard")

    def __post_init__(self) -> None:
        scheme = self.url.partition("://")[0]
        if scheme not in ("tcp", "tcps") or "://" not in self.url:
            raise ValueError(f"url = {self.url!r}: allowed: tcp://HOST:PORT or tcps://HOST:PORT")
        if self.password and self.password_file:
            raise ValueError("password and password_file: allowed: at most one of them")
        if not self.min_step_period_s < self.max_step_period_s:
            raise ValueError("min_step_period_s, max_step_period_s: allowed: min_step_period_s < max_step_period_s")
        lo, hi = self.reconnect_backoff_s if len(self.reconnect_backoff_s) == 2 else (-1.0, -1.0)
        if not 0 < lo <= hi:
            raise ValueError(
                f"reconnect_backoff_s = {self.reconnect_backoff_s!r}: allowed: [first s, largest s] with 0 < first <= largest"
            )

    @property
    def sonar_range_m(self) -> tuple[float, float]:
        """Reliable (min, max) sonar range [m] of this NAO version."""
        return SONAR_RANGES_M[self.sonar_version]

    @property
    def cycle_range_s(self) -> tuple[float, float]:
        """Realisable walking cycle T [s] (two steps)."""
        return 2.0 * self.min_step_period_s, 2.0 * self.max_step_period_s

    def resolved_password(self) -> str:
        """Return the password, read from ``password_file`` where set.

        Raises
        ------
        ConfigError
            The password file cannot be read.
        """
        if not self.password_file:
            return self.password
        try:
            text = Path(self.password_file).read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"naoqi.password_file = {self.password_file!r}: cannot read ({exc.strerror})") from None
        return text.splitlines()[0].strip() if text.strip() else ""


#: ``--robot naoqi`` (entry point ``bipedtele.robots``).
PART = RobotPart(
    name="naoqi",
    doc="a real NAO through NAOqi",
    build=lazy("bipedtele.follower.naoqi.robot:NaoqiRobot"),
    section="naoqi",
    config=NaoqiConfig,
)
