"""SequenceGate: stale/duplicate rejection, reset on a new sender session."""

from __future__ import annotations

from bipedtele.gate import SequenceGate
from bipedtele.messages import Command


def m(sid: int, seq: int) -> Command:
    return Command(sid=sid, seq=seq, t=1.0)


def test_in_order_accepted_old_rejected() -> None:
    g = SequenceGate()
    assert g.accept(m(7, 1)) is None
    assert g.accept(m(7, 2)) is None
    assert g.accept(m(7, 5)) is None  # gaps are fine (lost messages)
    assert g.accept(m(7, 5)) == "duplicate"
    assert g.accept(m(7, 3)) == "stale"
    assert g.accept(m(7, 6)) is None
    assert g.last == (7, 6)


def test_new_sid_resets() -> None:
    g = SequenceGate()
    assert g.accept(m(1, 1000)) is None
    assert g.accept(m(2, 1)) is None  # peer restarted, seq starts again
    assert g.accept(m(2, 1)) == "duplicate"
    assert g.accept(m(2, 2)) is None
    g.reset()
    assert g.last == (None, -1)
    assert g.accept(m(2, 1)) is None
