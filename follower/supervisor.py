"""Keeps the follower running through robot faults, and the robot stopped while they last.

:class:`RobotSupervisor` runs the loop's tick and the robot's ``advance`` for the
program. Any exception in either (a NAOqi call that timed out or answered garbage, a
robot that vanished, a bug) is a *fault*: it is logged (the first one in full, then at
most one line every ``log_every_s``), counted, and handed to
:meth:`FollowerLoop.fault`, which stops the robot if it can still be reached. The
process never exits because of it.

- A robot that still answers (a call timed out, a bad answer): the next tick simply runs
  again; the loop stops the robot once more before anything else unless a fresh command
  makes it walk.
- A robot whose link is down (``is_connected`` false): :meth:`FollowerRobot.connect` is
  tried again, first after ``backoff_s[0]`` and then doubling up to ``backoff_s[1]``,
  for as long as the process runs. The NAOqi bridge stops the robot first thing when the
  link comes back (``connect`` calls ``stopMove`` before anything else). Meanwhile the
  loop publishes its Status (state ``error``) at its status rate.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from bipedtele.follower.loop import FollowerLoop, FollowerTelemetry
from bipedtele.follower.robot import FollowerRobot

__all__ = ["RobotSupervisor"]

LOG = logging.getLogger(__name__)


class RobotSupervisor:
    """Runs ``loop.tick()`` and ``robot.advance(dt)``, turning every failure into a safe stop.

    Parameters
    ----------
    robot : FollowerRobot
        The connected robot the loop drives.
    loop : FollowerLoop
        The follower loop around ``robot``.
    backoff_s : (float, float)
        First and largest wait between reconnect tries [s] (doubling).
    log_every_s : float
        At most one log line per this many seconds while faults go on [s].
    monotonic : callable
        Clock for the back-off and the log rate [s].
    """

    def __init__(
        self,
        robot: FollowerRobot,
        loop: FollowerLoop,
        *,
        backoff_s: tuple[float, float] = (0.2, 5.0),
        log_every_s: float = 5.0,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.robot = robot
        self.loop = loop
        self.backoff_s = backoff_s
        self.log_every_s = log_every_s
        self._mono = monotonic
        self.faults = 0
        self.reconnects = 0
        self._faulted = False
        self._since_log = 0
        self._next_log = -float("inf")
        self._next_try = -float("inf")
        self._wait = backoff_s[0]

    @property
    def faulted(self) -> bool:
        """True from a fault until the next tick that runs through."""
        return self._faulted

    def tick(self) -> FollowerTelemetry | None:
        """One control period; None when the robot could not be driven in it."""
        if not self.robot.is_connected:
            self._reconnect()
            return None
        try:
            tel = self.loop.tick()
        except Exception as exc:
            self._fault("tick", exc)
            return None
        if self._faulted:
            self._faulted = False
            LOG.warning("robot answers again after %d faults: following commands again", self._since_log + 1)
            self._since_log = 0
            self._next_log = -float("inf")
        return tel

    def advance(self, dt: float) -> None:
        """Let ``dt`` of robot time pass (skipped while the link is down)."""
        if not self.robot.is_connected:
            return
        try:
            self.robot.advance(dt)
        except Exception as exc:
            self._fault("advance", exc)

    # ------------------------------------------------------------------ internals

    def _fault(self, where: str, exc: Exception) -> None:
        self.faults += 1
        self._faulted = True
        now = self._mono()
        if now >= self._next_log:
            self._next_log = now + self.log_every_s
            more = f" ({self._since_log} more faults since the last line)" if self._since_log else ""
            if isinstance(exc, RuntimeError):
                LOG.error("robot fault in %s: %s; stopping the robot, the follower keeps running%s", where, exc, more)
            else:  # not a robot error: a bug; the traceback helps
                LOG.exception("unexpected error in %s; stopping the robot, the follower keeps running%s", where, more)
            self._since_log = 0
        else:
            self._since_log += 1
        self.loop.fault(exc)
        if not self.robot.is_connected:
            self._next_try = now + self.backoff_s[0]
            self._wait = self.backoff_s[0]

    def _reconnect(self) -> None:
        self.loop.publish_status()
        now = self._mono()
        if now < self._next_try:
            return
        try:
            self.robot.connect()
        except Exception as exc:
            self._wait = min(self.backoff_s[1], self._wait * 2.0)
            self._next_try = self._mono() + self._wait
            if now >= self._next_log:
                self._next_log = now + self.log_every_s
                LOG.warning("robot still unreachable (%s); retrying every %.1f s at most", exc, self._wait)
            return
        self.reconnects += 1
        self._wait = self.backoff_s[0]
        LOG.warning("robot link back (reconnect %d): robot stopped; following commands again", self.reconnects)
