"""A contract checker for any :class:`FollowerRobot` (in the spirit of Gymnasium's ``check_env``).

``check_robot(factory)`` builds fresh robots with ``factory()`` and checks what the
follower loop relies on (see :mod:`bipedtele.follower.robot`):

- every method but ``connect``/``disconnect`` raises :class:`RobotNotConnectedError`
  before ``connect()`` and after ``disconnect()``;
- ``connect()`` and ``disconnect()`` are idempotent; the ``with`` block connects and
  disconnects;
- ``observe()`` returns a :class:`RobotObservation` with finite numbers of the right shape;
- ``send_walk()`` returns the command it sent, within :attr:`limits`, also for commands
  out of range, NaN or infinite;
- ``stop()`` is safe at any time, repeatedly; ``advance(dt)`` accepts 0 and small steps and
  robot time never goes back;
- ``capture()`` returns None or an ``H x W x 3`` uint8 image.

The first violation raises :class:`RobotContractError` naming the check.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import fields

import numpy as np
from bipedtele.follower.robot import (
    Camera,
    FollowerRobot,
    RobotNotConnectedError,
    RobotObservation,
    WalkCommand,
    WalkLimits,
)

__all__ = ["RobotContractError", "check_robot"]


class RobotContractError(AssertionError):
    """A robot does not keep the :class:`FollowerRobot` contract."""


def _expect(cond: bool, what: str) -> None:
    if not cond:
        raise RobotContractError(what)


def _raises_not_connected(robot: FollowerRobot, when: str) -> None:
    calls: dict[str, Callable[[], object]] = {
        "observe()": robot.observe,
        "send_walk()": lambda: robot.send_walk(WalkCommand()),
        "stop()": robot.stop,
        "advance(0.01)": lambda: robot.advance(0.01),
    }
    for name, call in calls.items():
        try:
            call()
        except RobotNotConnectedError:
            continue
        except Exception as exc:
            raise RobotContractError(
                f"{name} {when}: raised {type(exc).__name__}, expected RobotNotConnectedError"
            ) from exc
        raise RobotContractError(f"{name} {when}: returned, expected RobotNotConnectedError")


def _check_observation(obs: object) -> RobotObservation:
    _expect(isinstance(obs, RobotObservation), f"observe() returned {type(obs).__name__}, expected RobotObservation")
    assert isinstance(obs, RobotObservation)
    for f in fields(obs):
        v = getattr(obs, f.name)
        if isinstance(v, bool):
            continue
        values = v if isinstance(v, tuple) else (v,)
        _expect(
            all(isinstance(x, int | float) and math.isfinite(x) for x in values),
            f"observe().{f.name} = {v!r}: expected finite numbers",
        )
    _expect(len(obs.pose) == 3, f"observe().pose = {obs.pose!r}: expected (x, y, yaw)")
    _expect(len(obs.sonar_m) == 2, f"observe().sonar_m = {obs.sonar_m!r}: expected (left, right)")
    _expect(all(r >= 0 for r in obs.sonar_m), f"observe().sonar_m = {obs.sonar_m!r}: expected ranges >= 0")
    _expect(obs.tilt_rad >= 0, f"observe().tilt_rad = {obs.tilt_rad}: expected >= 0")
    _expect(obs.joint_error_rad >= 0, f"observe().joint_error_rad = {obs.joint_error_rad}: expected >= 0")
    return obs


def _within(cmd: WalkCommand, limits: WalkLimits) -> bool:
    vals = (cmd.forward_m_s, cmd.turn_rad_s, cmd.cycle_s, cmd.eps_s)
    tol = 1e-9
    return (
        all(math.isfinite(v) for v in vals)
        and abs(cmd.forward_m_s) <= limits.max_forward_m_s + tol
        and abs(cmd.turn_rad_s) <= limits.max_turn_rad_s + tol
        and limits.cycle_s[0] - tol <= cmd.cycle_s <= limits.cycle_s[1] + tol
        and limits.eps_s[0] - tol <= cmd.eps_s <= limits.eps_s[1] + tol
    )


_BAD_COMMANDS = (
    WalkCommand(10.0, 10.0, 100.0, 100.0),
    WalkCommand(-10.0, -10.0, 0.0, 0.0),
    WalkCommand(math.nan, math.nan, math.nan, math.nan),
    WalkCommand(math.inf, -math.inf, math.inf, -math.inf),
)


def check_robot(factory: Callable[[], FollowerRobot], advance_s: float = 0.5) -> None:
    """Check that robots made by ``factory`` keep the :class:`FollowerRobot` contract.

    Parameters
    ----------
    factory : callable
        Returns a new, unconnected robot.
    advance_s : float
        Robot time [s] to let pass while walking (the simulator steps this much).

    Raises
    ------
    RobotContractError
        The first violation found, naming the check.
    """
    robot = factory()
    _expect(isinstance(robot, FollowerRobot), f"factory() returned {type(robot).__name__}, expected a FollowerRobot")
    _expect(not robot.is_connected, "is_connected: true before connect()")
    _raises_not_connected(robot, "before connect()")
    robot.disconnect()  # idempotent even before connect
    try:
        robot.connect()
        robot.connect()
        _expect(robot.is_connected, "is_connected: false after connect()")
        first = _check_observation(robot.observe())
        robot.stop()
        robot.stop()
        robot.advance(0.0)
        for cmd in _BAD_COMMANDS:
            sent = robot.send_walk(cmd)
            _expect(
                isinstance(sent, WalkCommand), f"send_walk({cmd}) returned {type(sent).__name__}, expected WalkCommand"
            )
            _expect(_within(sent, robot.limits), f"send_walk({cmd}) returned {sent}: outside {robot.limits}")
        good = WalkCommand(
            0.5 * robot.limits.max_forward_m_s,
            0.0,
            float(np.mean(robot.limits.cycle_s)),
            float(np.mean(robot.limits.eps_s)),
        )
        sent = robot.send_walk(good)
        _expect(_within(sent, robot.limits), f"send_walk({good}) returned {sent}: outside {robot.limits}")
        t_prev = first.t
        steps = max(1, round(advance_s / 0.05))
        for _ in range(steps):
            robot.advance(0.05)
            obs = _check_observation(robot.observe())
            _expect(obs.t >= t_prev, f"observe().t went back: {obs.t} < {t_prev}")
            t_prev = obs.t
        robot.stop()
        robot.advance(0.01)
        robot.stop()
        _check_observation(robot.observe())
        cams: tuple[Camera, ...] = ("head", "scene")
        for cam in cams:
            img = robot.capture(cam)
            if img is not None:
                _expect(
                    isinstance(img, np.ndarray) and img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8,
                    f"capture({cam!r}): expected None or an H x W x 3 uint8 array",
                )
    finally:
        robot.disconnect()
    robot.disconnect()
    _expect(not robot.is_connected, "is_connected: true after disconnect()")
    _raises_not_connected(robot, "after disconnect()")

    other = factory()
    with other as entered:
        _expect(entered is other, "__enter__ must return the robot")
        _expect(other.is_connected, "with block: not connected inside")
        _check_observation(other.observe())
    _expect(not other.is_connected, "with block: still connected after leaving it")
