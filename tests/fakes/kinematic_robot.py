"""A kinematic stand-in for a walking robot, at the hardware boundary of FollowerRobot.

It realises the commanded forward speed and turn rate with a first-order lag of half a
walking cycle (the gait changes step length once per step), integrates the pose, and
reports sonar ranges to a wall at ``wall_x`` [m]. Used to test the follower loop's logic
(watchdog, stale commands, falls, parameters) quickly; the real pybullet NAO is tested in
tests/integration/.
"""

from __future__ import annotations

import math

from bipedtele.follower.robot import (
    FollowerRobot,
    RobotNotConnectedError,
    RobotObservation,
    WalkCommand,
    WalkLimits,
)


class KinematicRobot(FollowerRobot):
    """Unicycle with a lagged speed response; falls when told to (``fall_at`` [s])."""

    name = "kinematic"
    limits = WalkLimits()

    def __init__(self, wall_x: float = math.inf, fall_at: float = math.inf) -> None:
        self.wall_x = wall_x
        self.fall_at = fall_at
        self._connected = False
        self.t = 0.0
        self.x = self.y = self.yaw = 0.0
        self.v = self.w = 0.0
        self.cmd = WalkCommand()
        self.stopping = False
        self.sent: list[WalkCommand] = []
        self.stops = 0

    @property
    def is_connected(self) -> bool:
        return self._connected

    def _check(self) -> None:
        if not self._connected:
            raise RobotNotConnectedError("kinematic robot: call connect() first")

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        if self._connected:
            self.stop()
        self._connected = False

    def observe(self) -> RobotObservation:
        self._check()
        ahead = (self.wall_x - self.x) / max(math.cos(self.yaw), 1e-3) if self.wall_x < math.inf else 0.8
        sonar = min(max(ahead, 0.2), 0.8)
        fallen = self.t >= self.fall_at
        return RobotObservation(
            t=self.t,
            v_hip_m_s=self.v,
            turn_rate_rad_s=self.w,
            pose=(self.x, self.y, self.yaw),
            sonar_m=(sonar, sonar),
            tilt_rad=1.2 if fallen else 0.0,
            fallen=fallen,
            walking=abs(self.v) > 1e-4 or abs(self.w) > 1e-4,
            in_contact=self.x >= self.wall_x - 0.05,
        )

    def send_walk(self, cmd: WalkCommand) -> WalkCommand:
        self._check()
        self.cmd = cmd.clamped(self.limits)
        self.stopping = False
        self.sent.append(self.cmd)
        return self.cmd

    def stop(self) -> None:
        self.stops += 1
        self.cmd = WalkCommand(cycle_s=self.cmd.cycle_s, eps_s=self.cmd.eps_s)
        self.stopping = True

    def advance(self, dt: float) -> None:
        self._check()
        tau = self.cmd.cycle_s / 2
        a = min(dt / tau, 1.0)
        self.v += a * (self.cmd.forward_m_s - self.v)
        self.w += a * (self.cmd.turn_rad_s - self.w)
        if self.stopping and abs(self.v) < 1e-3 and abs(self.w) < 1e-3:
            self.v = self.w = 0.0
        self.yaw += self.w * dt
        self.x += self.v * math.cos(self.yaw) * dt
        self.y += self.v * math.sin(self.yaw) * dt
        self.t += dt
