"""The follower loop's walk state: a state machine in place of six booleans.

:class:`~bipedtele.follower.loop.FollowerLoop` keeps one :class:`WalkState` and moves it
only through :data:`TRANSITIONS`, a table ``(state, event) -> state`` (:func:`next_state`).
A pair not in the table leaves the state as it is: the event changes nothing there
(``NO_FRESH_COMMAND`` while standing, ``FAULT`` while the fall latch holds: the latch
already keeps the robot still), or the loop never fires it there (``WALK_SENT`` while
latched).

Three things make up a state:

- **motion**: standing, walking (a walk command was accepted), or a stop pending (after a
  fault the next period without a fresh command stops the robot again: the first stop may
  not have reached it);
- **the fall latch**: after a fall the robot walks again only once it stands and the
  operator re-arms it (a command with ``enable`` false, then a fresh one with ``enable``
  true); while latched the robot lies, stands waiting for the release, or stands released
  waiting for the enable;
- **a refusal reported**: the robot refused the last walk command (the ``walk_refused``
  event is emitted once, then the status says so) until a walk command is accepted again;
  a fall or a reset does not end it.

The ``*_REFUSED`` states are the latch's states with a refusal reported.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["TRANSITIONS", "WalkEvent", "WalkState", "next_state"]


class WalkState(enum.Enum):
    """Where the follower's walk is (see the module docstring).

    Attributes
    ----------
    STANDING
        Not walking, nothing pending: the robot stands (or comes to a stand).
    WALKING
        The robot accepted the last walk command; a period without a fresh command stops it
        and counts the stop (``operator_stops`` or ``watchdog_stops``).
    STOP_PENDING
        A fault stopped the robot, perhaps without reaching it: the next period without a
        fresh command sends the stop again (not counted).
    REFUSED
        The robot refused the last walk command and stands; the refusal was reported.
    REFUSED_STOP_PENDING
        ``REFUSED``, and a fault since: a stop is pending as in ``STOP_PENDING``.
    LYING
        Fall latched, the robot lies on the floor: nothing re-arms it.
    LATCHED
        Fall latched, the robot stands again: waits for the operator's release.
    RELEASED
        Fall latched, the robot stands and the operator released: the next fresh command
        with ``enable`` true re-arms it.
    LYING_REFUSED, LATCHED_REFUSED, RELEASED_REFUSED
        ``LYING``, ``LATCHED``, ``RELEASED`` with a refusal reported before the fall.
    """

    STANDING = "standing"
    WALKING = "walking"
    STOP_PENDING = "stop_pending"
    REFUSED = "refused"
    REFUSED_STOP_PENDING = "refused_stop_pending"
    LYING = "lying"
    LATCHED = "latched"
    RELEASED = "released"
    LYING_REFUSED = "lying_refused"
    LATCHED_REFUSED = "latched_refused"
    RELEASED_REFUSED = "released_refused"

    @property
    def latched(self) -> bool:
        """True while the fall latch holds: the robot is not asked to walk."""
        return self in _LATCHED

    @property
    def lying(self) -> bool:
        """True while the robot was last seen on the floor (a new fall cannot start)."""
        return self in (WalkState.LYING, WalkState.LYING_REFUSED)

    @property
    def refused(self) -> bool:
        """True while a refusal to walk is reported (since the last walk accepted)."""
        return self in _REFUSED

    @property
    def stop_due(self) -> bool:
        """True when a period without a fresh command must stop the robot."""
        return self in (WalkState.WALKING, WalkState.STOP_PENDING, WalkState.REFUSED_STOP_PENDING)


_LATCHED = frozenset(
    {
        WalkState.LYING,
        WalkState.LATCHED,
        WalkState.RELEASED,
        WalkState.LYING_REFUSED,
        WalkState.LATCHED_REFUSED,
        WalkState.RELEASED_REFUSED,
    }
)
_REFUSED = frozenset(
    {
        WalkState.REFUSED,
        WalkState.REFUSED_STOP_PENDING,
        WalkState.LYING_REFUSED,
        WalkState.LATCHED_REFUSED,
        WalkState.RELEASED_REFUSED,
    }
)


class WalkEvent(enum.Enum):
    """What happens to the walk, in the order the loop fires it in a period.

    Attributes
    ----------
    FELL
        An observation says fallen (torso tilt) while the robot was not lying: a new fall;
        the robot was stopped and the latch holds.
    STOOD
        The robot, lying, is observed upright again (the latch still holds).
    RELEASE
        Latched and upright, the latest command has ``enable`` false: the operator let go.
    REARM
        Latched, upright and released, a fresh command has ``enable`` true: the latch ends.
    WALK_SENT
        The robot accepted a walk command.
    WALK_REFUSED
        The robot refused a walk command (it stopped itself and said why).
    NO_FRESH_COMMAND
        A period, unlatched, without a fresh command with ``enable`` true (none for
        ``watchdog_s``, or the operator released): the robot is stopped if it walked or a
        stop is pending.
    FAULT
        A tick or a robot call failed: the robot was stopped, perhaps without reaching it.
    RESET
        The robot was put back on its start pose (a new leader session): walk and latch
        are forgotten (a reported refusal is not).
    """

    FELL = "fell"
    STOOD = "stood"
    RELEASE = "release"
    REARM = "rearm"
    WALK_SENT = "walk_sent"
    WALK_REFUSED = "walk_refused"
    NO_FRESH_COMMAND = "no_fresh_command"
    FAULT = "fault"
    RESET = "reset"


_S, _E = WalkState, WalkEvent

#: Every change of state: ``(state, event) -> next state`` (a pair not here changes nothing).
TRANSITIONS: Mapping[tuple[WalkState, WalkEvent], WalkState] = MappingProxyType(
    {
        # a fall stops the robot and latches; a reported refusal is kept
        (_S.STANDING, _E.FELL): _S.LYING,
        (_S.WALKING, _E.FELL): _S.LYING,
        (_S.STOP_PENDING, _E.FELL): _S.LYING,
        (_S.LATCHED, _E.FELL): _S.LYING,
        (_S.RELEASED, _E.FELL): _S.LYING,
        (_S.REFUSED, _E.FELL): _S.LYING_REFUSED,
        (_S.REFUSED_STOP_PENDING, _E.FELL): _S.LYING_REFUSED,
        (_S.LATCHED_REFUSED, _E.FELL): _S.LYING_REFUSED,
        (_S.RELEASED_REFUSED, _E.FELL): _S.LYING_REFUSED,
        # the re-arm: stand, release, enable
        (_S.LYING, _E.STOOD): _S.LATCHED,
        (_S.LYING_REFUSED, _E.STOOD): _S.LATCHED_REFUSED,
        (_S.LATCHED, _E.RELEASE): _S.RELEASED,
        (_S.LATCHED_REFUSED, _E.RELEASE): _S.RELEASED_REFUSED,
        (_S.RELEASED, _E.REARM): _S.STANDING,
        (_S.RELEASED_REFUSED, _E.REARM): _S.REFUSED,
        # the robot's answer to a walk command
        (_S.STANDING, _E.WALK_SENT): _S.WALKING,
        (_S.STOP_PENDING, _E.WALK_SENT): _S.WALKING,
        (_S.REFUSED, _E.WALK_SENT): _S.WALKING,
        (_S.REFUSED_STOP_PENDING, _E.WALK_SENT): _S.WALKING,
        (_S.STANDING, _E.WALK_REFUSED): _S.REFUSED,
        (_S.WALKING, _E.WALK_REFUSED): _S.REFUSED,
        (_S.STOP_PENDING, _E.WALK_REFUSED): _S.REFUSED,
        (_S.REFUSED_STOP_PENDING, _E.WALK_REFUSED): _S.REFUSED,
        # no fresh command: stop what walks or has a stop pending
        (_S.WALKING, _E.NO_FRESH_COMMAND): _S.STANDING,
        (_S.STOP_PENDING, _E.NO_FRESH_COMMAND): _S.STANDING,
        (_S.REFUSED_STOP_PENDING, _E.NO_FRESH_COMMAND): _S.REFUSED,
        # a fault: stop again at the next period without a fresh command
        (_S.STANDING, _E.FAULT): _S.STOP_PENDING,
        (_S.WALKING, _E.FAULT): _S.STOP_PENDING,
        (_S.REFUSED, _E.FAULT): _S.REFUSED_STOP_PENDING,
        # back on the start pose: walk and latch forgotten
        (_S.WALKING, _E.RESET): _S.STANDING,
        (_S.STOP_PENDING, _E.RESET): _S.STANDING,
        (_S.LYING, _E.RESET): _S.STANDING,
        (_S.LATCHED, _E.RESET): _S.STANDING,
        (_S.RELEASED, _E.RESET): _S.STANDING,
        (_S.REFUSED_STOP_PENDING, _E.RESET): _S.REFUSED,
        (_S.LYING_REFUSED, _E.RESET): _S.REFUSED,
        (_S.LATCHED_REFUSED, _E.RESET): _S.REFUSED,
        (_S.RELEASED_REFUSED, _E.RESET): _S.REFUSED,
    }
)


def next_state(state: WalkState, event: WalkEvent) -> WalkState:
    """Return the state after ``event`` in ``state`` (``state`` itself when the pair is not in :data:`TRANSITIONS`).

    Parameters
    ----------
    state : WalkState
        The state now.
    event : WalkEvent
        What happened.

    Returns
    -------
    WalkState
        The next state.
    """
    return TRANSITIONS.get((state, event), state)
