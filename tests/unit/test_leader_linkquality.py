"""The link as the leader measures it: feedback age bound, loss, goodput, video, states."""

from __future__ import annotations

import logging

import pytest
from bipedtele.config.profile import load_config
from bipedtele.leader.app import LeaderApp, fill_link, link_counters
from bipedtele.leader.linkquality import LinkQuality, link_words
from bipedtele.link.messages import MAX_SEQ, Feedback, Status, VideoFrame, encode
from bipedtele.link.receivers import Received
from bipedtele.telemetry import LINK_STATES, LeaderSample

T0 = 1_790_000_000.0
FB_BYTES = 400


class Clock:
    def __init__(self, t: float = T0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def make() -> tuple[LinkQuality, Clock]:
    clock = Clock()
    return LinkQuality(feedback_timeout_s=0.5, clock=clock), clock


def feed(
    lq: LinkQuality,
    clock: Clock,
    seconds: float,
    *,
    delay: float = 0.2,
    seq: list[int] | None = None,
    skip_every: int = 0,
    hz: float = 50.0,
    sid: int = 7,
) -> list[bool]:
    """``seconds`` of feedback at ``hz``, each sent ``delay`` before it arrives; every
    ``skip_every``-th is lost on the way. Returns whether each arrival was accepted."""
    seq = seq if seq is not None else [0]
    got = []
    for _ in range(round(seconds * hz)):
        clock.t += 1.0 / hz
        seq[0] += 1
        if skip_every and seq[0] % skip_every == 0:
            continue
        got.append(lq.on_feedback(sid, seq[0], clock.t - delay, clock.t, FB_BYTES))
    return got


def test_a_healthy_link_is_ok_with_its_age_goodput_and_no_loss() -> None:
    lq, clock = make()
    assert lq.report(follower_present=True).state == "waiting"
    assert all(feed(lq, clock, 3.0, delay=0.3))
    rep = lq.report()
    assert rep.state == "ok" and rep.lost_s is None
    assert rep.fb_age_s == pytest.approx(0.3)
    assert rep.loss_ppm == 0
    assert rep.rx_bps == pytest.approx(8 * FB_BYTES * 50, rel=0.02)  # 100 messages in the last 2 s
    assert rep.fb_arrived == 150 and rep.fb_too_old == 0 and rep.max_age_s == 2.0
    # The age of the newest feedback grows while nothing new arrives.
    clock.t += 0.25
    assert lq.feedback_age() == pytest.approx(0.55)


def test_goodput_is_unknown_until_half_a_second_then_over_the_time_passed() -> None:
    lq, clock = make()
    feed(lq, clock, 0.4)
    assert lq.report().rx_bps is None and lq.report().state == "ok"
    feed(lq, clock, 0.6)  # 1 s of 50 Hz feedback: the rate over 1 s, not over the 2 s window
    rep = lq.report()
    assert rep.rx_bps == pytest.approx(8 * FB_BYTES * 50, rel=0.1) and rep.state == "ok"


def test_feedback_captured_long_ago_is_refused_and_never_shown_as_live() -> None:
    """Issue 20: a restarted leader showed feedback captured 93-103 s earlier as live."""
    lq, clock = make()
    got = feed(lq, clock, 2.0, delay=95.0)
    assert not any(got)
    rep = lq.report()
    assert rep.fb_too_old == rep.fb_arrived == 100
    assert rep.state == "stale" and rep.fb_age_s is None  # arrives, but nothing usable
    # Then live feedback: accepted, ok.
    feed(lq, clock, 1.0, delay=0.3, sid=8)  # (a new session: its numbering is no loss)
    assert lq.report().state == "ok" and lq.report().fb_age_s == pytest.approx(0.3)


def test_the_age_bound_is_2_s_or_the_recent_minimum_delay_plus_1_s() -> None:
    lq, clock = make()
    feed(lq, clock, 1.0, delay=1.6)  # a long path: 1.6 s one way
    assert lq.max_age_s() == pytest.approx(2.6)
    assert all(feed(lq, clock, 1.0, delay=2.5, seq=[100]))  # within the path's own minimum + 1 s
    assert not any(feed(lq, clock, 0.5, delay=2.7, seq=[200]))  # 1.1 s above the minimum
    clock.t += 10.1  # the minimum is forgotten after 10 s without accepted feedback
    assert lq.max_age_s() == 2.0


def test_a_feedback_that_stopped_is_stale_then_lost_for_n_seconds() -> None:
    lq, clock = make()
    feed(lq, clock, 3.0)
    clock.t += 0.6
    assert lq.report().state == "stale"  # older than feedback_timeout_s: the force fades
    clock.t += 0.6
    rep = lq.report()
    assert rep.state == "lost" and rep.lost_s == pytest.approx(1.2)
    assert link_words(rep.state, rep.lost_s) == "link lost for 1.2 s"
    assert rep.rx_bps is not None and rep.rx_bps < 8 * FB_BYTES * 50 * 0.5


def test_sequence_gaps_are_loss_and_above_2_percent_lossy() -> None:
    lq, clock = make()
    feed(lq, clock, 3.0, skip_every=10)
    rep = lq.report()
    assert rep.loss_ppm == pytest.approx(100_000, rel=0.05) and rep.state == "lossy"
    lq2, clock2 = make()
    feed(lq2, clock2, 3.0, skip_every=100)  # 1 %: still ok
    assert lq2.report().state == "ok"
    # A new follower session starts counting afresh (its seq 1 after our 5000 is no loss).
    lq3, clock3 = make()
    feed(lq3, clock3, 1.0, seq=[5000])
    feed(lq3, clock3, 1.0, sid=8)
    assert lq3.report().loss_ppm == 0


def test_capacity_limited_from_the_followers_counters_or_the_goodput_it_sent() -> None:
    lq, clock = make()
    feed(lq, clock, 3.0)
    rx = lq.report().rx_bps
    assert rx is not None
    assert lq.report(follower_counters={"capacity_limited": 1}).state == "capacity-limited"
    assert lq.report(follower_counters={"capacity_limited": 0, "tx_bps": int(rx)}).state == "ok"
    assert lq.report(follower_counters={"tx_bps": int(rx / 0.8)}).state == "capacity-limited"
    # the follower's verdict, when it gives one, is the one shown
    assert lq.report(follower_counters={"capacity_limited": 0, "tx_bps": int(rx / 0.8)}).state == "ok"
    assert lq.report(follower_counters={"falls": 0}).state == "ok"  # counters missing: unknown
    assert lq.report(follower_present=False).state == "no-follower"
    assert link_words("no-follower") == "no follower" and link_words("capacity-limited") == "capacity-limited"


def test_video_rate_and_the_newest_frame() -> None:
    lq, clock = make()
    for _ in range(40):  # 20 fps for 2 s
        clock.t += 0.05
        lq.on_video(clock.t, 12_000, 320, 240)
        lq.on_status(clock.t, 100)
    rep = lq.report()
    assert rep.video_fps == pytest.approx(20.0, abs=0.5)
    assert (rep.video_bytes, rep.video_width, rep.video_height) == (12_000, 320, 240)
    assert rep.state == "waiting"  # no feedback yet


def test_status_counters_are_ints_in_range_and_missing_when_unknown() -> None:
    lq, clock = make()
    assert link_counters(lq.report()) == {}
    feed(lq, clock, 3.0, delay=0.25)
    got = link_counters(lq.report())
    assert set(got) == {"rx_bps", "fb_loss_ppm", "fb_age_ms"}
    assert got["fb_age_ms"] == 250 and got["fb_loss_ppm"] == 0 and got["rx_bps"] > 0
    assert all(isinstance(v, int) and 0 <= v <= MAX_SEQ for v in got.values())
    clock.t += 1e20  # an absurd age is capped to the counters' range
    assert link_counters(lq.report())["fb_age_ms"] == MAX_SEQ


def test_the_sample_carries_the_link_fields_and_leaves_unknown_ones_unset() -> None:
    lq, clock = make()
    feed(lq, clock, 3.0, skip_every=20)
    sample = LeaderSample(t=clock.t)
    counters = {"tx_bps": 10_000_000, "video_quality": 60}
    fill_link(sample, lq.report(follower_counters=counters), counters)
    assert sample.link == "capacity-limited" and sample.link in LINK_STATES
    assert sample.loss_pct == pytest.approx(5.0, rel=0.1) and sample.rx_kbps is not None
    assert sample.tx_kbps == 10_000.0 and sample.video_quality == 60 and sample.capacity_limited is None
    assert sample.fb_age_ms == pytest.approx(200.0) and sample.fb_arrived == 143 and sample.fb_too_old == 0
    assert sample.video_fps is None and sample.link_lost_s is None


# ---------------------------------------------------------------------- the program's wiring


def _fb(seq: int, t: float, cmd_seq: int = 0) -> Feedback:
    return Feedback(sid=9, seq=seq, t=t, z_e=[1.0, 2.0], cmd_seq=cmd_seq)


def test_the_program_hands_the_loop_only_feedback_young_enough(caplog: pytest.LogCaptureFixture) -> None:
    app = LeaderApp(load_config("default", ["leader.cockpit=false", "record.enabled=false"]))
    inbox = app._feedback_inbox(drops=app.node.drops, max_age_s=app.link.max_age_s)  # as the node builds it
    now = T0 + 500.0
    assert inbox.put(_fb(1, now - 95.0), now) is None  # captured 95 s ago
    assert inbox.take_feedback() is None
    assert app.node.drops.counts() == {"fb_too_old": 1}
    assert any("fb_too_old" in r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)
    inbox.put(_fb(2, now - 0.2), now + 0.01)
    got = inbox.take_feedback()
    assert got is not None and got.msg.seq == 2 and got.t_recv == now + 0.01
    assert inbox.put(_fb(3, now - 90.0), now + 0.02) is None  # old again: the young one stays
    got = inbox.latest()
    assert got is not None and got.msg.seq == 2 and inbox.take_feedback() is None
    assert app.node.drops.counts() == {"fb_too_old": 2}
    h2 = inbox.h2.value(now + 0.02)  # fed once, by the young one only
    assert h2 is not None and abs(h2 - 0.21) < 1e-6  # float time stamps near 1.7e9 s
    # only the young one acknowledges commands (a replay older than the bound must not)
    assert (app.link.fb_arrived, app.link.fb_too_old, app.reach.feedback) == (3, 2, 1)


def test_the_program_counts_what_arrives_and_hears_the_followers_status() -> None:
    app = LeaderApp(load_config("default", ["leader.cockpit=false", "record.enabled=false"]))
    t = T0
    st = Status(sid=9, seq=1, t=t, role="follower", counters={"tx_bps": 1000})
    app._on_status(Received(st, t))
    app._on_status(Received(Status(sid=10, seq=1, t=t, role="leader"), t))  # another leader: not the follower
    app._on_video(Received(VideoFrame(sid=9, seq=1, t=t, jpeg=b"x" * 5000), t))
    assert app.reach._last_heard is not None
    rep = app.link.report(t + 2.0)
    assert rep.video_bytes is not None and rep.video_bytes > 5000 and rep.video_width == 320
    assert rep.rx_bps == pytest.approx(8 * (rep.video_bytes + len(encode(st))) / 2.0)


def test_the_summary_counts_feedback_that_arrived_and_what_the_loop_used() -> None:
    """Issue 19: the summary said "4486 feedback received" for a run in which 8281 arrived
    (the loop takes the newest at each tick; several can arrive between two)."""
    from bipedtele.leader.devices.sim_falcon import SimFalcon
    from bipedtele.leader.loop import LeaderLoop
    from bipedtele.leader.report import summary as _summary
    from bipedtele.link.drops import DropCounter
    from bipedtele.link.inbox import FeedbackInbox

    cfg = load_config("default", [])
    dev = SimFalcon()
    dev.connect()
    lq, clock = make()
    newest: list[tuple[Feedback, float]] = []
    loop = LeaderLoop(
        dev,
        None,
        cfg.control,
        lambda c: None,
        FeedbackInbox(source=lambda: newest[-1] if newest else None),
        cfg=cfg.leader,
        clock=clock,
    )
    for k in range(1, 101):  # 100 ticks, two feedback arrive before each
        for j in (2 * k - 1, 2 * k):
            fb = _fb(j, clock.t - 0.1)
            if lq.on_feedback(fb.sid, fb.seq, fb.t, clock.t, FB_BYTES):
                newest.append((fb, clock.t))
        loop.tick(now=clock.t)
        clock.t += 0.001
    line = _summary(loop, "scripted", None, 0.1, DropCounter("t"), None, False, None, lq)
    assert "200 feedback received (100 used by the loop, 0 too old)" in line
    assert loop.feedback_count == 100


def test_an_outages_sequence_gap_is_not_loss() -> None:
    """3 s without feedback (a blackout of the uplink; the follower's feedback of that time
    was lost in it): the gap is no loss, and the link is ok again, not lossy for 2 s."""
    lq, clock = make()
    seq = [0]
    feed(lq, clock, 3.0, seq=seq)
    clock.t += 3.0
    seq[0] += 150  # sent into the dead path
    feed(lq, clock, 0.5, seq=seq)
    rep = lq.report()
    assert rep.loss_ppm == 0 and rep.state == "ok" and lq.outage_gaps == 1
    feed(lq, clock, 1.0, seq=seq, skip_every=10)  # a gap within the flow is loss as before
    assert lq.report().loss_ppm > 0
    # the backlog of a stalled path (1.5 s late, some of it dropped on the way): no loss
    lq2, clock2 = make()
    seq2 = [0]
    feed(lq2, clock2, 3.0, seq=seq2)
    feed(lq2, clock2, 2.5, seq=seq2, delay=1.5, skip_every=3)
    assert lq2.report().loss_ppm == 0 and lq2.outage_gaps > 20
