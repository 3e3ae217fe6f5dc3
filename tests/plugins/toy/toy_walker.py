"""A toy robot as a third-party part: its settings, its driver and its part in one module.

Registered by one entry point (``bipedtele.robots``: ``toy-walker = toy_walker:PART``). It
walks as a unicycle at the commanded speeds (no dynamics) and appends every call the
follower makes to ``[toy_walker] log_path`` (JSON lines), so a test can see it driven.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from typing import Any, ClassVar

from bipedtele.config.profile import Config, param, resolve_section
from bipedtele.follower.robot import (
    FollowerRobot,
    RobotNotConnectedError,
    RobotObservation,
    RobotPart,
    WalkCommand,
)


@dataclass(frozen=True)
class ToyWalkerConfig:
    """The ``[toy_walker]`` section."""

    log_path: str = param("", doc="JSON-lines file every call is appended to; empty: none")
    sonar_m: float = param(2.0, lo=0.1, hi=5.0, unit="m", doc="what both sonars read")


class ToyWalker(FollowerRobot):
    """A unicycle that walks at the commanded speeds, in wall time."""

    name: ClassVar[str] = "toy-walker"

    def __init__(self, config: ToyWalkerConfig | Config | None = None, **overrides: Any) -> None:
        self.config = resolve_section(config, ToyWalkerConfig, "toy_walker", overrides)
        self._connected = False
        self._cmd = WalkCommand()
        self._pose = [0.0, 0.0, 0.0]
        self._t = time.monotonic()

    def _log(self, call: str, **data: Any) -> None:
        if self.config.log_path:
            with open(self.config.log_path, "a", encoding="utf-8") as f:
                f.write(json.dumps({"call": call, **data}) + "\n")

    def _need(self) -> None:
        if not self._connected:
            raise RobotNotConnectedError("toy-walker: call connect() first")

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        self._connected = True
        self._t = time.monotonic()
        self._log("connect")

    def disconnect(self) -> None:
        if self._connected:
            self.stop()
        self._connected = False
        self._log("disconnect")

    def _move(self) -> float:
        now = time.monotonic()
        dt, self._t = now - self._t, now
        x, y, yaw = self._pose
        v, w = self._cmd.forward_m_s, self._cmd.turn_rad_s
        self._pose = [x + v * math.cos(yaw) * dt, y + v * math.sin(yaw) * dt, yaw + w * dt]
        return now

    def observe(self) -> RobotObservation:
        self._need()
        now = self._move()
        walking = self._cmd.forward_m_s != 0.0 or self._cmd.turn_rad_s != 0.0
        s = self.config.sonar_m
        return RobotObservation(
            now, self._cmd.forward_m_s, self._cmd.turn_rad_s, (*self._pose,), (s, s), 0.0, False, walking
        )

    def send_walk(self, cmd: WalkCommand) -> WalkCommand:
        self._need()
        self._move()
        self._cmd = cmd.clamped(self.limits)
        self._log("send_walk", forward_m_s=self._cmd.forward_m_s, turn_rad_s=self._cmd.turn_rad_s)
        return self._cmd

    def stop(self) -> None:
        self._need()
        self._move()
        self._cmd = WalkCommand(cycle_s=self._cmd.cycle_s, eps_s=self._cmd.eps_s)
        self._log("stop")

    def advance(self, dt: float) -> None:
        self._need()


PART = RobotPart(
    name="toy-walker",
    doc="a unicycle that walks at the commanded speeds (the plugin recipe's example)",
    build=ToyWalker,
    section="toy_walker",
    config=ToyWalkerConfig,
)
