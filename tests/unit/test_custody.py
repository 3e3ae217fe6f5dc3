"""Hand-over (issue 23): another operator takes the robot only after the holder's release."""

from __future__ import annotations

import logging

import pytest
from bipedtele.follower.custody import CustodyGate
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command, Status, decode, encode

pytestmark = pytest.mark.timeout(30)


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _gate(clock: Clock) -> CustodyGate:
    return CustodyGate(SequenceGate(takeover_after_s=0.5, clock=clock), "nao1", clock=clock)


def _cmd(sid: int, seq: int, operator: str, release: bool = False) -> Command:
    return Command(sid=sid, seq=seq, t=0.0, operator=operator, release=release, enable=not release)


def test_another_operator_is_refused_however_long_the_holder_is_silent(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    g = _gate(clock)
    assert g.accept(_cmd(1, 1, "alice")) is None and g.held_by == "alice" and g.takes == 1
    clock.t = 0.1
    with caplog.at_level(logging.WARNING, "bipedtele.follower.custody"):
        assert g.accept(_cmd(2, 1, "bob")) == "held"
        clock.t = 0.2
        assert g.accept(_cmd(2, 2, "bob")) == "held"  # counted, not logged again within 5 s
        clock.t = 60.0  # alice silent a minute: the old rule would have let bob take over
        assert g.accept(_cmd(2, 3, "bob")) == "held"
    assert g.held_by == "alice"
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and all("commands from bob refused: robot nao1 is held by alice" in x for x in lines), lines


def test_the_same_operator_takes_over_after_silence_as_before() -> None:
    clock = Clock()
    g = _gate(clock)
    assert g.accept(_cmd(1, 1, "alice")) is None
    assert g.accept(_cmd(3, 1, "alice")) == "foreign_session"  # alice's old session still live
    clock.t = 0.6
    assert g.accept(_cmd(3, 2, "alice")) is None and g.live_sid == 3 and g.takes == 1


def test_release_then_take() -> None:
    clock = Clock()
    g = _gate(clock)
    assert g.accept(_cmd(1, 1, "alice")) is None
    clock.t = 0.01
    assert g.accept(_cmd(1, 2, "alice", release=True)) is None  # a stop, accepted
    assert g.held_by is None and g.releases == 1
    clock.t = 0.02  # at once, not after the watchdog's silence
    assert g.accept(_cmd(2, 1, "bob")) is None and g.held_by == "bob" and g.live_sid == 2
    # alice's released leader goes on sending stops: dropped quietly, not refusals
    assert g.accept(_cmd(1, 3, "alice", release=True)) == "released"
    assert g.accept(_cmd(1, 4, "alice")) == "held"  # alice presses Take: held by bob now
    assert g.held_by == "bob" and g.takes == 2


def test_unnamed_operators_keep_the_watchdog_rule() -> None:
    clock = Clock()
    g = _gate(clock)
    assert g.accept(_cmd(1, 1, "")) is None and g.held_by == ""
    assert g.accept(_cmd(2, 1, "")) == "foreign_session"
    clock.t = 0.6
    assert g.accept(_cmd(2, 2, "")) is None


def test_operator_and_holder_travel_on_the_wire() -> None:
    cmd = decode(encode(_cmd(1, 1, "alice", release=True)))
    assert isinstance(cmd, Command) and cmd.operator == "alice" and cmd.release
    st = decode(encode(Status(sid=1, seq=1, t=0.0, held_by="bob", operator="carol")))
    assert isinstance(st, Status) and st.held_by == "bob" and st.operator == "carol"
    with pytest.raises(Exception):  # noqa: B017 - a name that is no login is refused on decode
        decode(encode(Command(sid=1, seq=1, t=0.0, operator="bad name!")))
