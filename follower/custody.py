"""Who holds the robot: hand-over between operators by explicit release and take.

Several operators may be named for one robot (``bipedtele setup fleet --operator
alice=nao1 --operator bob=nao1``). The robot follows one leader session at a time (the
command gate, :class:`bipedtele.link.gate.SequenceGate`); :class:`CustodyGate` adds who may
be that session:

- The first operator whose command is accepted **holds** the robot.
- The holder's own sessions follow the gate's rule: a restarted leader of the same
  operator takes over after the watchdog's silence, as before.
- Another operator's commands are refused (``held``, counted and logged on the robot's
  side) while the robot is held, however long the holder has been silent: no silent
  take-over. The holder **releases** the robot (cockpit button Release; a leader also
  releases when it exits): a command with ``release`` set, a stop. Then the robot is free
  and the next operator's command **takes** it.
- A released leader's own stops, once another holds the robot, are dropped quietly
  (``released``), not counted as refusals.

Operators are told apart by :attr:`bipedtele.link.messages.Command.operator`, the leader's
router login. It is authenticated as far as the message key goes: the operators of one
robot share its key (docs/fleet.md), so this is a rule among them against mistakes (two
people driving one robot), not a barrier between them; the router's ACL keeps everyone
else off the robot. Leaders without names (one pair, no router logins) are one operator:
the old rule (take-over after the watchdog's silence).

A robot held by an operator who is gone for good (a crashed laptop) is freed by
restarting the follower.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command, Message

__all__ = ["CUSTODY_REASONS", "CustodyGate", "refused_line"]

LOG = logging.getLogger("bipedtele.follower.custody")

#: The drop reasons :meth:`CustodyGate.accept` adds to the gate's.
CUSTODY_REASONS = ("held", "released")


class CustodyGate:
    """A command gate that also keeps who holds the robot.

    Parameters
    ----------
    gate : SequenceGate
        The session gate it wraps (its rule applies within the holder's sessions).
    robot_id : str
        The robot's id, for the log lines.
    log_interval_s : float
        At most one refusal line per operator in this time [s].
    clock : callable
        Monotonic time [s] (injectable).

    Notes
    -----
    Thread-safe (Zenoh's callback thread calls :meth:`accept`, the loop reads
    :attr:`held_by`). Same interface as :class:`SequenceGate` where the command inbox and the
    clock link use it (``accept``, ``live_sid``, ``bound_sid``, ``last``).
    """

    def __init__(
        self,
        gate: SequenceGate,
        robot_id: str = "",
        *,
        log_interval_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.gate = gate
        self.robot_id = robot_id
        self.log_interval_s = float(log_interval_s)
        self._clock = clock
        self._logged: dict[str, float] = {}  # refused operator -> when its line was logged
        self._lock = threading.Lock()
        self._holder: str | None = None
        self.takes = 0  # operators that took the robot (the first one included)
        self.releases = 0  # releases by the holder

    @property
    def held_by(self) -> str | None:
        """The operator holding the robot (``""``: an unnamed one), None when free."""
        with self._lock:
            return self._holder

    def accept(self, msg: Message) -> str | None:
        """Check one command; None if accepted, else the drop reason.

        Reasons: the gate's, ``held`` (another operator holds the robot) or ``released``
        (a released leader's stop while another holds it).
        """
        if not isinstance(msg, Command):
            return self.gate.accept(msg)
        op = msg.operator
        with self._lock:
            holder = self._holder
            if holder is not None and op != holder:
                if msg.release:
                    return "released"
                self._log_refusal(op, holder)
                return "held"
            reason = self.gate.accept(msg)
            if reason is not None:
                return reason
            if msg.release:
                self.gate.release()  # any session may be next
                if holder is not None:
                    self._holder = None
                    self.releases += 1
                    LOG.info(
                        "robot %s released by %s: free, the next operator's command takes it",
                        self.robot_id,
                        op or "its operator",
                    )
            elif holder is None:
                self._holder = op
                self.takes += 1
                LOG.info("robot %s taken by %s", self.robot_id, op or "an operator without a name")
        return None

    def _log_refusal(self, operator: str, holder: str) -> None:
        now = self._clock()
        if now - self._logged.get(operator, -float("inf")) < self.log_interval_s:
            return
        if len(self._logged) >= 64:
            self._logged.clear()
        self._logged[operator] = now
        LOG.warning("%s", refused_line(self.robot_id, operator, holder))

    # -------------------------------------------------------------- the gate's interface

    @property
    def live_sid(self) -> int | None:
        """The followed session while live (see :attr:`SequenceGate.live_sid`)."""
        return self.gate.live_sid

    @property
    def bound_sid(self) -> int | None:
        """The followed session (see :attr:`SequenceGate.bound_sid`)."""
        return self.gate.bound_sid

    @property
    def last(self) -> tuple[int | None, int]:
        """``(sid, seq)`` of the newest accepted command."""
        return self.gate.last


def refused_line(robot_id: str, operator: str, holder: str) -> str:
    """Return the robot side's line for a refused operator's commands."""
    return (
        f"commands from {operator or 'an unnamed operator'} refused: robot {robot_id} is held by "
        f"{holder or 'an unnamed operator'}, who must release it first (cockpit: Release); no silent take-over"
    )
