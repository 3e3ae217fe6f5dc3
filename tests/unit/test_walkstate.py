"""The follower's walk state machine (follower/walkstate.py) and FollowerLoop through it.

Every transition of the table, every pair outside it (ignored), the table against the six
booleans the loop kept before (issue 22), and sequences through the loop itself: stop,
refusal, fall latch and re-arm, fault, reset.
"""

from __future__ import annotations

import itertools
import math

import pytest
from bipedtele.config.profile import load_config
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.follower.robot import WalkCommand, WalkRefusedError
from bipedtele.follower.walkstate import TRANSITIONS, WalkEvent, WalkState, next_state
from bipedtele.link.messages import Command, Status
from fakes.kinematic_robot import KinematicRobot

pytestmark = pytest.mark.timeout(60)

S, E = WalkState, WalkEvent
PAIRS = list(itertools.product(WalkState, WalkEvent))
IGNORED = [p for p in PAIRS if p not in TRANSITIONS]


# ---------------------------------------------------------------- the table


@pytest.mark.parametrize(("state", "event"), list(TRANSITIONS), ids=lambda x: x.name)
def test_every_transition_of_the_table(state: WalkState, event: WalkEvent) -> None:
    new = next_state(state, event)
    assert new is TRANSITIONS[state, event]
    assert new is not state  # the table lists changes only


@pytest.mark.parametrize(("state", "event"), IGNORED, ids=lambda x: x.name)
def test_a_pair_outside_the_table_changes_nothing(state: WalkState, event: WalkEvent) -> None:
    assert next_state(state, event) is state


def test_the_table_and_the_ignored_pairs_cover_every_pair() -> None:
    assert len(TRANSITIONS) + len(IGNORED) == len(WalkState) * len(WalkEvent)
    assert len(TRANSITIONS) == 38


@pytest.mark.parametrize("state", list(WalkState), ids=lambda s: s.name)
def test_the_state_properties(state: WalkState) -> None:
    name = state.name
    assert state.latched == name.startswith(("LYING", "LATCHED", "RELEASED"))
    assert state.lying == name.startswith("LYING")
    assert state.refused == ("REFUSED" in name)
    assert state.stop_due == (state in (S.WALKING, S.STOP_PENDING, S.REFUSED_STOP_PENDING))
    assert not (state.latched and state.stop_due)  # the latch keeps the robot still


@pytest.mark.parametrize("state", [s for s in WalkState if s.latched], ids=lambda s: s.name)
def test_a_walk_event_never_ends_the_latch(state: WalkState) -> None:
    for event in (E.WALK_SENT, E.WALK_REFUSED, E.NO_FRESH_COMMAND, E.FAULT):
        assert next_state(state, event) is state


# ---------------------------------------------------------------- the six booleans it replaced

# (walking_cmd, stop_pending, refused, fallen, fall_latched, rearm_off)
Flags = tuple[bool, bool, bool, bool, bool, bool]


def _flags(state: WalkState) -> Flags:
    walking = state is S.WALKING
    stop_pending = state in (S.STOP_PENDING, S.REFUSED_STOP_PENDING)
    rearm_off = state in (S.RELEASED, S.RELEASED_REFUSED)
    return walking, stop_pending, state.refused, state.lying, state.latched, rearm_off


def _old(f: Flags, event: WalkEvent) -> Flags | None:
    """What the loop's booleans did on ``event``; None where the loop never fires it."""
    walking, pending, refused, fallen, latched, rearm = f
    if event is E.FELL:  # _watch on a new fall; _update_latch clears rearm_off in that period
        return None if fallen else (False, False, refused, True, True, False)
    if event is E.STOOD:
        return (walking, pending, refused, False, latched, rearm) if fallen else None
    if event is E.RELEASE:
        return (walking, pending, refused, fallen, latched, True) if latched and not fallen else None
    if event is E.REARM:
        if not latched or fallen:
            return None
        return (walking, pending, refused, fallen, False, False) if rearm else f
    if event is E.FAULT:
        return False, True, refused, fallen, latched, rearm
    if event is E.RESET:
        return False, False, refused, False, False, False
    if latched:  # the walk's own events come only unlatched
        return None
    if event is E.WALK_SENT:
        return True, False, False, fallen, latched, rearm
    if event is E.WALK_REFUSED:
        return False, False, True, fallen, latched, rearm
    assert event is E.NO_FRESH_COMMAND
    return False, False, refused, fallen, latched, rearm


def _observable(f: Flags) -> Flags:
    """A stop pending while latched is never acted on (the re-arm walks at once, a reset clears it)."""
    walking, pending, refused, fallen, latched, rearm = f
    return walking, pending and not latched, refused, fallen, latched, rearm


FIRED = [(s, e) for s, e in PAIRS if _old(_flags(s), e) is not None]  # what the loop can fire


@pytest.mark.parametrize(("state", "event"), FIRED, ids=lambda x: x.name)
def test_the_table_does_what_the_six_booleans_did(state: WalkState, event: WalkEvent) -> None:
    old = _old(_flags(state), event)
    assert old is not None
    assert _flags(next_state(state, event)) == _observable(old)


def test_every_change_of_the_table_is_one_the_loop_can_fire() -> None:
    assert set(TRANSITIONS) <= set(FIRED)


def test_every_state_maps_to_distinct_booleans() -> None:
    assert len({_flags(s) for s in WalkState}) == len(WalkState)


# ---------------------------------------------------------------- through FollowerLoop


class RefusingRobot(KinematicRobot):
    """Refuses every walk command while ``refuse`` is set (as the NAOqi bridge without its guard)."""

    def __init__(self, fall_at: float = math.inf) -> None:
        super().__init__(fall_at=fall_at)
        self.refuse = True

    def send_walk(self, cmd: WalkCommand) -> WalkCommand:
        if self.refuse:
            raise WalkRefusedError("no watchdog guards this robot")
        return super().send_walk(cmd)


class Run:
    """A FollowerLoop in simulated time; commands arrive at once (as tests/unit/test_follower_loop.py)."""

    def __init__(self, robot: KinematicRobot, on_new_leader=None) -> None:  # type: ignore[no-untyped-def]
        cfg = load_config("default")
        self.t = 1000.0
        self.robot = robot
        self.events: list[str] = []
        self.published: list[object] = []
        self.seq = 0
        self.sid = 7
        self._next: Command | None = None
        robot.connect()
        self.loop = FollowerLoop(
            robot,
            cfg.section("control"),
            cfg.section("follower"),
            command_inbox(cfg.section("follower"), source=self._take),
            self.published.append,
            now=lambda: self.t,
            on_event=lambda n, d: self.events.append(n),
            on_new_leader=on_new_leader,
        )

    def _take(self) -> tuple[Command, float] | None:
        cmd, self._next = self._next, None
        return None if cmd is None else (cmd, self.t)

    def ticks(self, seconds: float, v: float | None = 5.0, enable: bool = True) -> WalkState:
        """Run ``seconds``: a command every tick (``v`` None: none); return the walk state."""
        for _ in range(round(seconds / self.loop.dt)):
            if v is not None:
                self.seq += 1
                self._next = Command(sid=self.sid, seq=self.seq, t=self.t, ref=[v, 0.0], h2_s=0.2, enable=enable)
            self.loop.tick()
            self.robot.advance(self.loop.dt)
            self.t += self.loop.dt
        return self.loop.walk_state

    def silence(self) -> None:
        """Let every command go stale (the robot did not answer meanwhile)."""
        self.t += 2.0 * self.loop.cfg.watchdog_s

    def note(self) -> str:
        return self.loop.status(self.t).text


def test_a_stop_by_the_watchdog_then_by_the_operator() -> None:
    r = Run(KinematicRobot())
    assert r.loop.walk_state is S.STANDING
    assert r.ticks(2.0) is S.WALKING
    assert r.ticks(2.0, v=None) is S.STANDING
    assert r.loop.counters["watchdog_stops"] == 1
    assert r.ticks(2.0) is S.WALKING
    assert r.ticks(1.0, enable=False) is S.STANDING
    assert r.loop.counters["operator_stops"] == 1 and r.loop.counters["watchdog_stops"] == 1
    assert r.events == ["watchdog_stop", "operator_stop"]


def test_a_refusal_is_reported_once_and_ends_with_a_walk() -> None:
    robot = RefusingRobot()
    r = Run(robot)
    assert r.ticks(1.0) is S.REFUSED
    assert r.events == ["walk_refused"] and r.loop.counters["walk_refused"] == round(1.0 / r.loop.dt)
    assert "refuses to walk" in r.note()
    r.loop.fault(RuntimeError("lost the robot"))
    assert r.loop.walk_state is S.REFUSED_STOP_PENDING
    assert "refuses to walk" in r.note()  # the refusal is still the news
    stops = robot.stops
    r.silence()
    assert r.ticks(0.5, v=None) is S.REFUSED
    assert robot.stops == stops + 1  # the pending stop, once, not counted
    assert r.loop.counters["watchdog_stops"] == 0
    assert r.ticks(0.5) is S.REFUSED and r.events == ["walk_refused"]
    robot.refuse = False
    assert r.ticks(1.0) is S.WALKING
    assert "refuses" not in r.note()
    robot.refuse = True
    assert r.ticks(0.5) is S.REFUSED and r.events == ["walk_refused", "walk_refused"]


def test_a_fall_latches_until_the_robot_stands_and_the_operator_rearms() -> None:
    robot = KinematicRobot(fall_at=2.0)
    r = Run(robot)
    assert r.ticks(3.0) is S.LYING
    assert r.loop.counters["falls"] == 1 and r.events == ["fall"]
    assert r.ticks(0.5, enable=False) is S.LYING  # a release while lying does not count
    assert "fall latched" in r.note()
    robot.fall_at = math.inf  # stood up
    n_sent = len(robot.sent)
    assert r.ticks(1.0) is S.LATCHED  # still held forward: no walking
    assert len(robot.sent) == n_sent
    assert r.ticks(0.5, enable=False) is S.RELEASED
    assert r.ticks(0.5, v=None) is S.RELEASED  # a stale command does not re-arm
    assert r.ticks(1.0) is S.WALKING
    assert r.events == ["fall", "rearmed"]
    robot.fall_at = robot.t + 0.5  # falls again while walking
    assert r.ticks(1.0) is S.LYING
    assert r.loop.counters["falls"] == 2


def test_a_fall_after_a_refusal_keeps_the_refusal_reported() -> None:
    robot = RefusingRobot(fall_at=1.0)
    r = Run(robot)
    assert r.ticks(0.5) is S.REFUSED
    assert r.ticks(1.0) is S.LYING_REFUSED
    robot.fall_at = math.inf
    assert r.ticks(0.2) is S.LATCHED_REFUSED
    assert r.ticks(0.2, enable=False) is S.RELEASED_REFUSED
    assert r.ticks(0.2) is S.REFUSED  # re-armed, and refused again: not reported again
    assert r.events == ["walk_refused", "fall", "rearmed"]


def test_a_fault_while_walking_stops_again_once_without_a_fresh_command() -> None:
    robot = KinematicRobot()
    r = Run(robot)
    r.ticks(2.0)
    r.loop.fault(RuntimeError("timeout"))
    assert r.loop.walk_state is S.STOP_PENDING and r.loop.telemetry.state == "error"
    stops = robot.stops
    r.silence()
    assert r.ticks(0.5, v=None) is S.STANDING
    assert robot.stops == stops + 1 and r.loop.counters["watchdog_stops"] == 0
    r.loop.fault(RuntimeError("timeout"))
    assert r.ticks(1.0) is S.WALKING  # a fresh command walks at once


def test_a_reset_forgets_the_latch() -> None:
    robot = KinematicRobot(fall_at=1.0)
    r = Run(robot, on_new_leader=lambda sid: True)
    assert r.ticks(2.0) is S.LYING
    robot.fall_at = math.inf
    r.sid = 8  # a new leader session: the robot is put back on its start pose
    assert r.ticks(1.0) is S.WALKING
    assert r.loop.counters["resets"] == 2 and r.events.count("reset") == 2
    st = [m for m in r.published if isinstance(m, Status)][-1]
    assert st.counters["falls"] == 1
