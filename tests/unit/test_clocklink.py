"""ClockLink: answering, pinging and matching, peer-bound and rate-limited.

Driven by hand (``poll``) with fake clocks and a fake publish list; one test runs the
real thread. No Zenoh: the receiver would call ``on_message`` exactly like these tests.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import pytest
from bipedtele.link.clock import ClockSync
from bipedtele.link.clocklink import ClockLink
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import ClockPing, ClockPong, Message

ME, PEER, EVIL = 1111, 2222, 3333
OFFSET = 5.0  # the peer's clock is 5 s ahead of ours


@dataclass(frozen=True)
class Rec:
    """Same shape as bipedtele.link.transport.Received."""

    msg: Any
    t_recv: float


class Clocks:
    """One fake time base: ``wall`` stamps messages, ``mono`` paces the link."""

    def __init__(self) -> None:
        self.t = 1000.0

    def wall(self) -> float:
        return self.t

    def mono(self) -> float:
        return self.t - 900.0


def make(
    sync: ClockSync | None = None, peer: list[int | None] | None = None, **kw: Any
) -> tuple[ClockLink, list[Message], Clocks, DropCounter]:
    sent: list[Message] = []
    clk = Clocks()
    drops = DropCounter("test/clock")
    cell = peer if peer is not None else [None]
    link = ClockLink(
        sent.append,
        ME,
        sync=sync,
        drops=drops,
        clock=clk.wall,
        monotonic=clk.mono,
        peer_sid=lambda: cell[0],
        **kw,
    )
    return link, sent, clk, drops


def pings(sent: list[Message]) -> list[ClockPing]:
    return [m for m in sent if isinstance(m, ClockPing)]


def pongs(sent: list[Message]) -> list[ClockPong]:
    return [m for m in sent if isinstance(m, ClockPong)]


def peer_answer(ping: ClockPing, sent_at: float, h: float = 0.04, sid: int = PEER) -> tuple[ClockPong, float]:
    """The peer's honest answer to ``ping`` and the local time it arrives."""
    t2 = sent_at + h + OFFSET
    t3 = t2 + 0.001
    return ClockPong(sid=sid, seq=ping.seq, t=t3, ping_sid=ME, ping_seq=ping.seq, t1=ping.t, t2=t2), t3 - OFFSET + h


# --------------------------------------------------------------------------- answering


def test_answers_a_ping_with_receive_and_send_times() -> None:
    link, sent, clk, _ = make()
    link.on_message(Rec(ClockPing(sid=PEER, seq=7, t=1234.5), clk.t))
    assert sent == []  # on_message only enqueues
    clk.t += 0.002
    link.poll()
    (p,) = pongs(sent)
    assert (p.sid, p.ping_sid, p.ping_seq, p.t1) == (ME, PEER, 7, 1234.5)
    assert p.t2 == 1000.0 and p.t == pytest.approx(1000.002)
    assert link.answered == 1


def test_own_messages_and_other_pairs_are_ignored() -> None:
    link, sent, clk, drops = make(sync=ClockSync())
    link.on_message(Rec(ClockPing(sid=ME, seq=1, t=clk.t), clk.t))
    link.on_message(Rec(ClockPong(sid=PEER, seq=2, t=clk.t, ping_sid=4444, ping_seq=1, t2=clk.t), clk.t))
    link.poll()
    assert pongs(sent) == [] and link.pongs_rejected == 0 and drops.counts() == {}


def test_flood_is_answered_at_the_rate_limit() -> None:
    """10,000 pings in 1 s from one sender: at most 20/s + the burst are answered, the
    queue never grows beyond its bound and on_message never publishes."""
    link, sent, clk, drops = make(answer_rate_hz=20.0, queue_max=64)
    longest_queue = 0
    for k in range(10_000):
        clk.t += 1e-4
        link.on_message(Rec(ClockPing(sid=EVIL, seq=k + 1, t=clk.t), clk.t))
        longest_queue = max(longest_queue, len(link._q))
        if k % 100 == 99:  # the link's thread runs every 10 ms
            link.poll()
    link.poll()
    burst = 20.0 / 4
    assert 20 <= link.answered <= 20 * 1.0 + burst
    assert len(pongs(sent)) == link.answered
    assert link.rate_limited == 10_000 - link.answered
    assert drops.counts() == {"ping_rate_limited": link.rate_limited}
    assert longest_queue <= 64


def test_bound_peer_is_answered_through_a_foreign_flood() -> None:
    peer: list[int | None] = [PEER]
    link, sent, clk, drops = make(peer=peer)
    link.poll()  # the link learns the peer
    for k in range(5000):
        clk.t += 1e-4
        link.on_message(Rec(ClockPing(sid=EVIL, seq=k + 1, t=clk.t), clk.t))
        if k == 2500:
            link.on_message(Rec(ClockPing(sid=PEER, seq=9, t=clk.t), clk.t))
        if k % 100 == 99:
            link.poll()
    link.poll()
    assert [(p.ping_sid, p.ping_seq) for p in pongs(sent)] == [(PEER, 9)]
    assert drops.counts() == {"foreign_session": 5000}


def test_before_a_peer_is_bound_anyone_is_answered_and_late_pings_are_not() -> None:
    link, sent, clk, drops = make()
    link.on_message(Rec(ClockPing(sid=EVIL, seq=1, t=clk.t), clk.t))
    link.on_message(Rec(ClockPing(sid=PEER, seq=1, t=clk.t), clk.t - 0.2))  # stuck 200 ms
    link.poll()
    assert [p.ping_sid for p in pongs(sent)] == [EVIL]
    assert drops.counts() == {"ping_late": 1}


# --------------------------------------------------------------------------- pinging


def test_pings_at_the_rate_and_feeds_matching_answers() -> None:
    sync = ClockSync(window=8)
    link, sent, clk, _ = make(sync=sync, ping_rate_hz=4.0)
    for _ in range(32):  # 2 s in 62.5 ms steps (binary-exact)
        link.poll()
        clk.t += 0.0625
    ps = pings(sent)
    assert [p.t - 1000.0 for p in ps] == [0.25 * k for k in range(8)]
    assert len({p.seq for p in ps}) == len(ps) and all(p.sid == ME for p in ps)
    answer, t4 = peer_answer(ps[-1], ps[-1].t)
    link.on_message(Rec(answer, t4))
    link.poll()
    assert link.pongs_accepted == 1 and sync.ready
    assert sync.offset == pytest.approx(OFFSET)
    assert sync.rtt == pytest.approx(0.08)


def test_one_sided_queue_does_not_move_the_offset_through_the_link() -> None:
    """Issue 19, item 3, end to end through the link as the nodes wire it
    (``ClockSync(clock.ping_window)``, 4 Hz): 20 ms round trips, then the peer's answers
    queue 2 s for 25 s (a capped uplink on the peer's side). Before the fix the offset
    moved by 1 s once the 16 pings of the window were all queued; now it stays exact,
    while ``rtt`` follows the queue (the damping is scheduled from it)."""
    sync = ClockSync(16)
    link, sent, clk, drops = make(sync=sync, peer=[PEER], ping_rate_hz=4.0)
    pending: list[tuple[float, ClockPong]] = []
    answered = 0
    worst = 0.0
    rtts: list[float] = []
    for _ in range(int(60.0 / 0.0625)):  # 60 s in 62.5 ms steps
        for t4, pong in [p for p in pending if p[0] <= clk.t]:
            link.on_message(Rec(pong, t4))
        pending = [p for p in pending if p[0] > clk.t]
        link.poll()
        for ping in pings(sent)[answered:]:
            queued = 2.0 if 20.0 <= ping.t - 1000.0 < 45.0 else 0.0
            pong, t4 = peer_answer(ping, ping.t, h=0.01)
            pending.append((t4 + queued, pong))
            answered += 1
        if sync.ready:
            worst = max(worst, abs(sync.offset - OFFSET))
            if 30.0 <= clk.t - 1000.0 < 45.0:
                assert sync.rtt is not None
                rtts.append(sync.rtt)
        clk.t += 0.0625
    assert link.pongs_accepted > 200 and drops.counts() == {}
    assert worst < 1e-6
    assert rtts and min(rtts) == pytest.approx(2.020)
    assert sync.queueing_s == pytest.approx(0.0, abs=1e-9) and sync.min_rtt == pytest.approx(0.020)


def test_forged_pong_for_a_ping_never_sent_is_rejected() -> None:
    sync = ClockSync()
    link, sent, clk, drops = make(sync=sync)
    link.poll()
    (ping,) = pings(sent)
    forged = ClockPong(sid=PEER, seq=50, t=clk.t, ping_sid=ME, ping_seq=ping.seq + 1000, t1=clk.t, t2=clk.t)
    link.on_message(Rec(forged, clk.t + 0.01))
    link.poll()
    assert not sync.ready and link.pongs_rejected == 1
    assert drops.counts() == {"pong_unmatched": 1}


def test_pong_from_another_session_is_rejected() -> None:
    sync = ClockSync()
    peer: list[int | None] = [PEER]
    link, sent, _clk, drops = make(sync=sync, peer=peer)
    link.poll()
    (ping,) = pings(sent)
    forged, t4 = peer_answer(ping, ping.t, sid=EVIL)
    link.on_message(Rec(forged, t4))
    link.poll()
    assert not sync.ready
    assert drops.counts() == {"foreign_session": 1}
    honest, t4 = peer_answer(ping, ping.t)
    link.on_message(Rec(honest, t4))
    link.poll()
    assert sync.ready and sync.peer == PEER


def test_pong_with_a_huge_hold_time_is_rejected() -> None:
    sync = ClockSync(hold_max_s=0.05)
    link, sent, _clk, drops = make(sync=sync)
    link.poll()
    (ping,) = pings(sent)
    t2 = ping.t + OFFSET
    forged = ClockPong(sid=PEER, seq=1, t=t2 + 0.3, ping_sid=ME, ping_seq=ping.seq, t1=ping.t, t2=t2)
    link.on_message(Rec(forged, ping.t + 0.35))  # would read as a 50 ms round trip
    link.poll()
    assert not sync.ready
    assert drops.counts() == {"pong_hold": 1}


def test_t1_of_the_answer_is_ignored() -> None:
    """Attack (issue 10, item 4): an answer claiming t1 = t4 - 1 ms. The round trip used is
    the locally measured one (here 300 ms), so damping from it cannot drop."""
    sync = ClockSync()
    link, sent, _clk, _ = make(sync=sync)
    link.poll()
    (ping,) = pings(sent)
    t4 = ping.t + 0.3
    lie = ClockPong(sid=PEER, seq=1, t=t4 + OFFSET, ping_sid=ME, ping_seq=ping.seq, t1=t4 - 0.001, t2=t4 + OFFSET)
    link.on_message(Rec(lie, t4))
    link.poll()
    assert sync.ready and sync.rtt == pytest.approx(0.3)


def test_each_ping_is_answered_once() -> None:
    sync = ClockSync()
    link, sent, _clk, drops = make(sync=sync)
    link.poll()
    (ping,) = pings(sent)
    answer, t4 = peer_answer(ping, ping.t)
    link.on_message(Rec(answer, t4))
    link.on_message(Rec(answer, t4 + 0.001))  # replayed
    link.poll()
    assert link.pongs_accepted == 1 and drops.counts() == {"pong_unmatched": 1}


def test_peer_change_forgets_the_old_clock_and_pings_at_once() -> None:
    sync = ClockSync()
    peer: list[int | None] = [PEER]
    link, sent, clk, _ = make(sync=sync, peer=peer, ping_rate_hz=1.0)
    link.poll()
    (ping,) = pings(sent)
    answer, t4 = peer_answer(ping, ping.t)
    link.on_message(Rec(answer, t4))
    clk.t += 0.1
    link.poll()
    assert sync.ready
    peer[0] = EVIL + 1  # the gate now follows a restarted peer
    clk.t += 0.1
    link.poll()
    assert not sync.ready
    assert len(pings(sent)) == 2  # at once, not a second after the first


def test_synced_mode_answers_but_never_pings() -> None:
    link, sent, clk, drops = make(sync=None)
    for _ in range(10):
        link.poll()
        clk.t += 0.5
    assert pings(sent) == []
    link.on_message(Rec(ClockPong(sid=PEER, seq=1, t=clk.t, ping_sid=ME, ping_seq=1, t2=clk.t), clk.t))
    link.poll()
    assert drops.counts() == {"pong_unmatched": 1}


def test_publish_errors_do_not_stop_the_link() -> None:
    calls = []

    def failing(msg: Message) -> None:
        calls.append(msg)
        raise RuntimeError("session closed")

    clk = Clocks()
    link = ClockLink(failing, ME, sync=ClockSync(), drops=DropCounter("t"), clock=clk.wall, monotonic=clk.mono)
    link.on_message(Rec(ClockPing(sid=PEER, seq=1, t=clk.t), clk.t))
    link.poll()
    assert link.publish_errors == 2 and link.answered == 0 and link.pings_sent == 0 and len(calls) == 2


def test_bad_parameters() -> None:
    for kw in ({"ping_rate_hz": 0.0}, {"answer_rate_hz": float("nan")}, {"queue_max": 0}, {"hold_max_s": -1.0}):
        with pytest.raises(ValueError, match="allowed"):
            ClockLink(lambda m: None, ME, sync=None, drops=DropCounter("t"), **kw)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- real thread


@pytest.mark.timeout(20)
def test_two_links_synchronise_over_their_threads() -> None:
    """Leader and follower links wired back to back (a lossless in-process 'network' with
    a 10 ms delay each way), each bound to the other: both clocks sync, no drops."""
    drops_a, drops_b = DropCounter("a"), DropCounter("b")
    sync_a, sync_b = ClockSync(), ClockSync()
    links: dict[str, ClockLink] = {}
    timers: list[threading.Timer] = []

    def wire(to: str) -> Any:
        def publish(msg: Message) -> None:
            def deliver() -> None:
                links[to].on_message(Rec(msg, time.time()))

            t = threading.Timer(0.01, deliver)
            timers.append(t)
            t.start()

        return publish

    a = ClockLink(wire("b"), ME, sync=sync_a, drops=drops_a, ping_rate_hz=20.0, peer_sid=lambda: PEER)
    b = ClockLink(wire("a"), PEER, sync=sync_b, drops=drops_b, ping_rate_hz=20.0, peer_sid=lambda: ME)
    links.update(a=a, b=b)
    with a, b:
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not (a.pongs_accepted >= 3 and b.pongs_accepted >= 3):
            time.sleep(0.02)
    for t in timers:
        t.join(1.0)
    assert a.pongs_accepted >= 3 and b.pongs_accepted >= 3
    assert abs(sync_a.offset) < 0.05 and abs(sync_b.offset) < 0.05  # one clock in fact
    rtt = sync_a.rtt
    assert rtt is not None and rtt >= 0.02  # two 10 ms legs can never read shorter
    assert drops_a.counts().get("foreign_session", 0) == 0 and drops_b.counts().get("foreign_session", 0) == 0
    n = a.pings_sent
    time.sleep(0.2)
    assert a.pings_sent == n  # stopped


def test_a_session_also_answered_gets_its_pings_answered_while_another_is_followed() -> None:
    """Issue 23, hand-over: the follower follows alice's session and also answers a leader
    session that completed the handshake (one waiting for the robot); others stay foreign."""
    waiting = 5555
    link, sent, clk, drops = make(peer=[PEER], also_answer=lambda sid: sid == waiting)
    link.poll()
    for k, sid in enumerate((PEER, waiting, EVIL)):
        clk.t += 0.1
        link.on_message(Rec(ClockPing(sid=sid, seq=k + 1, t=clk.t), clk.t))
        link.poll()
    assert [p.ping_sid for p in pongs(sent)] == [PEER, waiting]
    assert drops.counts() == {"foreign_session": 1}
