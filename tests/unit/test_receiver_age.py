"""Receivers drop old messages before the sequence gate binds to them (issue 20, finding 1).

A replay of captured traffic stamped long ago, from another session, arrives while a new
leader starts. Before: the gate bound to the replay's session first (the age check came
later, in the loop), and the new leader's commands were dropped as ``foreign_session``
for as long as the replay went on. Now the receiver drops the replay as ``too_old``
before the gate, and the new leader's first command is accepted.
"""

from __future__ import annotations

from typing import Any

from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command
from bipedtele.link.receivers import LatestReceiver, Received
from fake_zenoh_session import FakeSession

T0 = 1_700_000_000.0


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _receiver(max_age_s: Any, **kwargs: Any) -> tuple[FakeSession, LatestReceiver[Command], DropCounter, Clock]:
    session, drops, clock = FakeSession(), DropCounter("cmd"), Clock(T0)
    gate = SequenceGate(takeover_after_s=0.5, clock=clock)
    rx: LatestReceiver[Command] = LatestReceiver(
        session,
        "bipedtele/nao1/cmd",
        Command,
        drops,
        gate,
        clock=clock,
        max_future_s=0.25,
        max_age_s=max_age_s,
        **kwargs,
    )  # type: ignore[arg-type]
    return session, rx, drops, clock


def test_a_replay_stamped_90_s_ago_never_binds_the_gate_and_the_new_leader_is_accepted_at_once() -> None:
    estimator = DelayEstimator(1.0)
    session, rx, drops, clock = _receiver(1.5, estimator=estimator)
    accepted = 0
    for i in range(200):  # 2 s: the replay at 5 Hz... and faster, interleaved with the new leader at 100 Hz
        clock.t = T0 + 0.01 * i
        if i % 5 == 0:
            session.put(Command(sid=111, seq=5000 + i, t=clock.t - 90.0))  # captured 90 s earlier
        session.put(Command(sid=222, seq=i + 1, t=clock.t - 0.005))
        got = rx.take()
        if got is not None and got.msg.sid == 222:
            accepted += 1
    assert accepted == 200  # the first one included: no wait for the watchdog's silence
    assert drops.counts() == {"too_old": 40}
    assert rx.gate is not None and rx.gate.bound_sid == 222
    h1 = estimator.value(clock.t)
    assert h1 is not None and h1 < 0.01  # h1 never saw a 90 s delay


def test_the_bound_may_be_a_callable_and_the_caller_may_count_the_drop() -> None:
    refused: list[Received[Command]] = []
    session, rx, drops, _clock = _receiver(lambda t: 2.0, on_too_old=refused.append)
    session.put(Command(sid=7, seq=1, t=T0 - 2.5))
    session.put(Command(sid=7, seq=2, t=T0 - 1.9))
    assert [r.msg.seq for r in refused] == [1] and drops.total == 0
    got = rx.take()
    assert got is not None and got.msg.seq == 2
