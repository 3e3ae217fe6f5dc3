"""Without the message key, a forged high sequence number blocks the real sender briefly (issue 20, finding 2).

Before: one forged copy with seq + 519 (within the jump bound) made the next 519 messages
of the real leader stale: at 100 Hz the robot stopped for 6.26 s. Now the jump is
provisional: 3 consecutive messages of the real sender newer than the seq before it undo
it, so a forged message costs at most 2 of the sender's messages, whatever its seq.
"""

from __future__ import annotations

import logging

import pytest
from bipedtele.leader.reach import KEY_MISMATCH, REFUSED, CommandReach
from bipedtele.link.auth import BAD_MAC_LINE, NO_MAC_LINE, UNEXPECTED_MAC_LINE
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command, Feedback


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _blocked(gate: SequenceGate, clock: Clock, jump: int, n: int = 300) -> int:
    """Run a 100 Hz sender that pauses 0.1 s after 1 s; one forged copy (seq + jump) in the pause.

    Return how many of the real sender's messages the gate dropped.
    """
    dropped, pause = 0, 0.0
    for seq in range(1, n + 1):
        if seq == 100:
            pause = 0.1  # 0.1 s of silence: a jump of up to 0.1 * 5000 + 100 = 600 is plausible
            clock.t = seq * 0.01 + 0.09
            assert gate.accept(Command(sid=5, seq=seq + jump)) is None  # the forged copy passes
        clock.t = seq * 0.01 + pause
        if gate.accept(Command(sid=5, seq=seq)) is not None:
            dropped += 1
    return dropped


def test_a_forged_high_seq_blocks_the_real_sender_for_two_messages_at_most() -> None:
    clock = Clock()
    gate = SequenceGate(takeover_after_s=0.5, clock=clock, max_rate_hz=5000.0, seq_margin=100, rollback_after=3)
    assert _blocked(gate, clock, 519) == 2 and gate.rollbacks == 1
    assert gate.last == (5, 300)


def test_without_rollback_the_forged_seq_blocks_for_its_whole_jump() -> None:
    clock = Clock()
    gate = SequenceGate(takeover_after_s=0.5, clock=clock, rollback_after=0)
    assert _blocked(gate, clock, 519) == 201  # seq 100 to the end: 5.19 s of a longer run at 100 Hz (the old code)
    assert gate.rollbacks == 0


def test_a_rollback_never_accepts_what_came_before_the_jump() -> None:
    clock = Clock()
    gate = SequenceGate(takeover_after_s=0.5, clock=clock, rollback_after=3)
    for seq in (1, 2, 3, 50):  # a loss gap 3 -> 50
        assert gate.accept(Command(sid=5, seq=seq)) is None
    assert [gate.accept(Command(sid=5, seq=s)) for s in (1, 2, 3)] == ["stale", "stale", "stale"]
    assert [gate.accept(Command(sid=5, seq=s)) for s in (4, 6, 7)] == ["stale", "stale", "stale"]  # not consecutive
    assert gate.accept(Command(sid=5, seq=8)) is None  # 6, 7, 8: a run of 3 newer than 3
    assert gate.accept(Command(sid=5, seq=8)) == "duplicate"


def test_a_key_mismatch_is_named_not_the_acl(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    counts: dict[str, int] = {}
    for reason, line in (("mac_unexpected", UNEXPECTED_MAC_LINE), ("no_mac", NO_MAC_LINE), ("bad_mac", BAD_MAC_LINE)):
        caplog.clear()
        counts.clear()
        reach = CommandReach(lambda: 10, window_s=1.5, clock=clock, key_drops=counts.copy)
        with caplog.at_level(logging.WARNING, logger="bipedtele.leader"):
            for _ in range(40):
                clock.t += 0.05
                counts[reason] = counts.get(reason, 0) + 1
                reach.check(True)
        text = " ".join(r.getMessage() for r in caplog.records)
        assert KEY_MISMATCH in text and line in text and REFUSED not in text and "ACL" not in text, text
        assert reach.never_reached and reach.key_reason == reason and reach.key_line == line
    # heard, no key problem: the ACL verdict stays
    counts.clear()
    reach = CommandReach(lambda: 10, window_s=1.5, clock=clock, key_drops=counts.copy)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="bipedtele.leader"):
        for _ in range(40):
            clock.t += 0.05
            reach.on_feedback(Feedback(sid=3, seq=1, cmd_seq=0))
            reach.check(True)
    assert REFUSED in " ".join(r.getMessage() for r in caplog.records) and reach.key_reason is None
