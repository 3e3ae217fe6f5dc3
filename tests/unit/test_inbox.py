"""The inboxes: every check on an incoming message in one place, one counter per reason.

Each drop reason is counted once per message; the delay estimators are fed once per
message (h1 at the follower when a command is taken, h2 at the leader when feedback is
admitted); a loop hosted behind a Zenoh receiver (the program's path: payloads into the
inbox) and a loop run alone (its inbox polled from a source) give the same results.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.follower.backlog import DelayBaseline
from bipedtele.follower.custody import CustodyGate
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.leader.devices.sim_falcon import SimFalcon
from bipedtele.leader.loop import LeaderLoop
from bipedtele.link.auth import MessageAuth
from bipedtele.link.clock import ClockSync
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import SequenceGate
from bipedtele.link.inbox import COMMAND_COUNTERS, CommandInbox, FeedbackInbox, LatestInbox, Received
from bipedtele.link.messages import Command, Feedback, Status, encode
from bipedtele.link.receivers import LatestReceiver
from fake_zenoh_session import FakeSession, Payload
from fakes.kinematic_robot import KinematicRobot

pytestmark = pytest.mark.timeout(60)

T0 = 1_700_000_000.0
KEY = "bipedtele/nao1/cmd"


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


# ------------------------------------------------------------------ admission: one count per reason


def test_each_admission_reason_is_counted_once_under_its_name() -> None:
    clock = Clock(T0)
    drops = DropCounter("cmd")
    sync = ClockSync()
    inbox: LatestInbox[Command] = LatestInbox(
        Command,
        drops,
        SequenceGate(takeover_after_s=0.5, clock=clock),
        key=KEY,
        max_future_s=0.25,
        max_age_s=1.5,
        clock_sync=sync,
    )

    def offer(data: bytes) -> Received[Command] | None:
        return inbox.offer(Payload(data), clock.t, KEY)

    assert offer(encode(Command(sid=1, seq=1, t=T0))) is None  # no clock answer yet
    assert sync.on_pong(T0 - 0.002, T0 - 0.001, T0 - 0.001, T0) is not None  # offset 0, rtt 2 ms: synced
    assert offer(b"\x00" * (inbox.max_bytes + 1)) is None
    assert offer(b"\x93not msgpack") is None
    assert offer(MessageAuth(b"k" * 32).sign(encode(Command(sid=1, seq=1, t=T0)), KEY)) is None
    assert offer(encode(Status(sid=1, seq=1, t=T0))) is None
    assert offer(encode(Command(sid=1, seq=1, t=T0 + 1.0))) is None
    assert offer(encode(Command(sid=1, seq=1, t=T0 - 2.0))) is None
    assert offer(encode(Command(sid=1, seq=5, t=T0))) is not None
    assert offer(encode(Command(sid=1, seq=5, t=T0))) is None
    assert offer(encode(Command(sid=1, seq=4, t=T0))) is None
    assert offer(encode(Command(sid=2, seq=9, t=T0))) is None
    counts = drops.counts()
    assert counts.pop("clock_not_synced") == 1 and counts.pop("too_large") == 1
    assert counts.pop("mac_unexpected") == 1 and counts.pop("future") == 1 and counts.pop("too_old") == 1
    assert counts.pop("duplicate") == 1 and counts.pop("stale") == 1 and counts.pop("foreign_session") == 1
    # the decoder's reasons: the garbage and the wrong kind, one each
    assert sum(counts.values()) == 2, counts
    assert inbox.count == 1


def test_custody_refusals_are_counted_by_the_command_inbox_too() -> None:
    clock = Clock(T0)
    drops = DropCounter("cmd")
    inbox = CommandInbox(
        1.5, 0.5, DelayBaseline(), drops=drops, gate=CustodyGate(SequenceGate(clock=clock), "nao1", clock=clock)
    )
    assert inbox.put(Command(sid=1, seq=1, t=T0, operator="alice"), T0) is not None
    assert inbox.put(Command(sid=2, seq=1, t=T0, operator="bob"), T0) is None
    assert inbox.put(Command(sid=2, seq=2, t=T0, operator="bob", release=True, enable=False), T0) is None
    assert drops.counts() == {"held": 1, "released": 1}


# ------------------------------------------------------------------ the command inbox's take checks


def _inbox(**kwargs: Any) -> CommandInbox:
    return CommandInbox(1.0, 0.5, DelayBaseline(window_s=10.0, relearn_s=10.0), **kwargs)


def test_each_take_reason_is_counted_once_and_h1_is_fed_once_per_command_taken() -> None:
    inbox = _inbox()
    t = T0
    got = inbox.put(Command(sid=1, seq=1, t=t - 0.1), t)
    assert got is not None and len(inbox.h1._samples) == 0  # admission never feeds h1
    taken = inbox.take_command(t)
    assert taken is not None and taken.new_session and len(inbox.h1._samples) == 1
    assert inbox.take_command(t) is None and len(inbox.h1._samples) == 1  # nothing new: nothing fed
    # too old by the time it is taken
    inbox.put(Command(sid=1, seq=2, t=t - 0.2), t)
    assert inbox.take_command(t + 0.9) is None
    # sent before the one applied (same session)
    inbox.put(Command(sid=1, seq=3, t=t - 0.15), t + 0.01)
    assert inbox.take_command(t + 0.01) is None
    # after a silence longer than the watchdog, 0.8 s later than the 0.1 s baseline: backlog
    inbox.put(Command(sid=1, seq=4, t=t + 0.2), t + 1.1)
    assert inbox.take_command(t + 1.1) is None
    # a new leader session, fresh
    inbox.put(Command(sid=2, seq=1, t=t + 1.15), t + 1.2)
    taken = inbox.take_command(t + 1.2)
    assert taken is not None and taken.new_session
    assert inbox.counters == {
        "cmd_accepted": 2,
        "cmd_too_old": 1,
        "leader_sessions": 2,
        "cmd_backlog": 1,
        "cmd_reordered": 1,
    }
    assert len(inbox.h1._samples) == 5  # every command taken, refused or not, once
    assert set(COMMAND_COUNTERS) == set(inbox.counters)


def test_the_follower_status_carries_the_inbox_counters_in_the_loops_order() -> None:
    robot = KinematicRobot()
    robot.connect()
    cfg = load_config("default")
    published: list[Any] = []
    loop = FollowerLoop(
        robot,
        cfg.section("control"),
        cfg.section("follower"),
        command_inbox(cfg.section("follower")),
        published.append,
        now=lambda: 100.0,
    )
    loop.inbox.put(Command(sid=3, seq=1, t=99.9, ref=[5.0, 0.0]), 100.0)
    loop.tick()
    st = [m for m in published if isinstance(m, Status)][-1]
    assert list(st.counters)[:2] == ["cmd_accepted", "cmd_too_old"]
    assert st.counters["cmd_accepted"] == 1 and st.counters["leader_sessions"] == 1
    assert st.counters == loop.counters


# ------------------------------------------------------------------ hosted by a receiver or alone: the same


def _commands() -> list[tuple[Command, float]]:
    """A leader's commands at 100 Hz, 120 ms on the way, a gap, a too old one and a backlog one."""
    out = []
    for k in range(300):
        t_sent = T0 + 0.01 * k
        if 150 <= k < 202:
            continue  # lost: nothing arrives from 1.61 to 2.14 s
        out.append((Command(sid=5, seq=k + 1, t=t_sent, ref=[6.0, 3.0 * math.sin(k / 30)], h2_s=0.1), t_sent + 0.12))
    out.append((Command(sid=5, seq=151, t=T0 + 0.3, ref=[-6.0, 0.0]), T0 + 1.9))  # 1.6 s old: too old
    out.append((Command(sid=5, seq=152, t=T0 + 1.47, ref=[-6.0, 0.0]), T0 + 2.115))  # after the silence: backlog
    return sorted(out, key=lambda a: a[1])  # in arrival order


def _run_follower(hosted: bool) -> tuple[list[Any], dict[str, int], dict[str, int]]:
    cfg = load_config("default")
    fcfg = cfg.section("follower")
    robot = KinematicRobot()
    robot.connect()
    clock = Clock(T0)
    drops = DropCounter("cmd")
    arrivals = _commands()
    pending: list[tuple[Command, float] | None] = [None]
    if hosted:
        session = FakeSession()
        rx: LatestReceiver[Command] = LatestReceiver(
            session,
            KEY,
            Command,
            drops,
            SequenceGate(clock=clock),
            clock=clock,
            max_future_s=0.25,
            max_age_s=fcfg.max_cmd_age_s,
            inbox=lambda **kw: command_inbox(fcfg, **kw),
        )  # type: ignore[arg-type]
        assert isinstance(rx.inbox, CommandInbox)
        inbox = rx.inbox
    else:
        inbox = command_inbox(
            fcfg,
            drops=drops,
            source=lambda: pending[0],
            gate=SequenceGate(clock=clock),
            max_future_s=0.25,
            max_age_s=fcfg.max_cmd_age_s,
        )
    loop = FollowerLoop(robot, cfg.section("control"), fcfg, inbox, lambda m: None, now=clock)
    tels = []
    i = 0
    while clock.t < T0 + 4.0:
        pending[0] = None
        while i < len(arrivals) and arrivals[i][1] <= clock.t:
            cmd, t_recv = arrivals[i]
            if hosted:
                saved, clock.t = clock.t, t_recv
                session.put_bytes(encode(cmd))
                clock.t = saved
            else:
                pending[0] = (cmd, t_recv)  # a ring of one: the newest arrival
            i += 1
        tel = loop.tick()
        tels.append((tel.state, tel.ref.copy(), tel.h1_s, tel.z_e.copy()))
        robot.advance(loop.dt)
        clock.t += loop.dt
    return tels, loop.counters, drops.counts()


def test_a_follower_loop_behind_a_receiver_and_one_alone_give_the_same_results() -> None:
    hosted, alone = _run_follower(True), _run_follower(False)
    assert len(hosted[0]) == len(alone[0])
    for a, b in zip(hosted[0], alone[0], strict=True):
        assert a[0] == b[0] and a[2] == pytest.approx(b[2], abs=1e-9)
        np.testing.assert_allclose(a[1], b[1], atol=1e-12)
        np.testing.assert_allclose(a[3], b[3], atol=1e-12)
    assert hosted[1] == alone[1] and hosted[1]["cmd_accepted"] > 100
    # the late one: refused at admission (too_old), before h1 and the gate saw it
    assert hosted[2] == alone[2] == {"too_old": 1} and alone[1]["cmd_too_old"] == 0
    assert hosted[1]["cmd_backlog"] == 1 and hosted[1]["watchdog_stops"] == 2  # the gap, the end


def _run_leader(hosted: bool) -> tuple[list[float | None], int]:
    cfg = load_config("default")
    dev = SimFalcon()
    dev.connect()
    clock = Clock(T0)
    pending: list[tuple[Feedback, float] | None] = [None]
    if hosted:
        session = FakeSession()
        rx: LatestReceiver[Feedback] = LatestReceiver(
            session,
            "bipedtele/nao1/feedback",
            Feedback,
            DropCounter("feedback"),
            SequenceGate(clock=clock),
            clock=clock,
            max_future_s=0.25,
            inbox=FeedbackInbox,
        )
        assert isinstance(rx.inbox, FeedbackInbox)
        inbox = rx.inbox
    else:
        inbox = FeedbackInbox(source=lambda: pending[0])
    loop = LeaderLoop(dev, None, cfg.control, lambda c: None, inbox, cfg=cfg.leader, clock=clock)
    h2s = []
    for k in range(2000):
        clock.t = T0 + 0.001 * k
        pending[0] = None
        if k % 10 == 0:
            fb = Feedback(sid=8, seq=k // 10 + 1, t=clock.t - 0.05 - 0.02 * (k % 30 == 0), z_e=[1.0, 0.5], h1_s=0.1)
            if hosted:
                session.put_bytes(encode(fb), "bipedtele/nao1/feedback")
            else:
                pending[0] = (fb, clock.t)
        loop.tick(now=clock.t)
        h2s.append(loop.h2)
    return h2s, loop.feedback_count


def test_a_leader_loop_behind_a_receiver_and_one_alone_feed_h2_the_same() -> None:
    (hosted, n_hosted), (alone, n_alone) = _run_leader(True), _run_leader(False)
    assert n_hosted == n_alone == 200
    assert hosted == pytest.approx(alone, abs=1e-9)
    assert hosted[-1] is not None and 0.05 < hosted[-1] < 0.06


def test_the_feedback_inbox_feeds_its_own_h2_only() -> None:
    with pytest.raises(ValueError, match="estimator"):
        FeedbackInbox(estimator=object())
