"""The uplink's in-flight cap (follower/delivery.py, InFlight), with a simulated clock."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
import pytest
from bipedtele.follower.capacity import UplinkBudget
from bipedtele.follower.delivery import InFlight
from bipedtele.follower.video import VideoStreamer
from bipedtele.link.messages import VideoFrame

pytestmark = pytest.mark.timeout(30)

FB = 400  # one feedback [bytes]


def _steady(f: InFlight, t0: float, t1: float, *, acks: bool, rtt: float = 0.1, ack_s: float = 0.1) -> dict[str, int]:
    """Feedback every 10 ms and a 2 kB video frame every 50 ms from ``t0`` to ``t1`` [s];
    with ``acks`` the leader acknowledges every ``ack_s`` what it received ``rtt`` ago.
    Return what left: feedback and video messages."""
    out = {"feedback": 0, "video": 0}
    t, next_ack, k = t0, t0, 0
    while t < t1:
        if f.admit_feedback(t):
            f.sent(t, FB)
            out["feedback"] += 1
        if k % 5 == 0 and f.admit_video(2000):
            f.sent(t, 2000)
            out["video"] += 1
        if acks and t >= next_ack:
            next_ack = t + ack_s
            f.acked(t, t - rtt, 8.0 * (FB * 100 + 2000 * 20))  # what the path delivers [bit/s]
        t, k = round(t + 0.01, 6), k + 1
    return out


def test_the_cap_is_open_until_the_first_acknowledgement() -> None:
    f = InFlight()
    assert f.cap_bytes == math.inf and not f.over
    for k in range(1000):
        f.sent(0.001 * k, 10_000)
    assert f.admit_feedback(1.0) and f.admit_video(10_000)
    assert f.bytes == 10_000_000


def test_when_acknowledgements_stop_the_follower_stops_adding_to_the_queue() -> None:
    """A path that delivered, then delivers nothing: within the cap the follower sends on,
    then holds video and feedback (no feedback leaves as a probe: a Status does, see
    test_uplink_echo.py); once acknowledgements come back it sends at its rate again."""
    f = InFlight(gain=2.0, probe_s=1.0)
    before = _steady(f, 0.0, 10.0, acks=True)
    assert before["video"] >= 190 and before["feedback"] >= 990  # the cap never held a delivering path
    cap = f.cap_bytes
    assert math.isfinite(cap) and f.min_rtt_s == pytest.approx(0.1)
    # 8 s without an acknowledgement (the last one advanced at 9.99 s)
    during = _steady(f, 10.0, 18.0, acks=False)
    assert during["video"] <= cap / 2000 + 1  # video stops once the cap is reached
    reached = during["feedback"] * FB + during["video"] * 2000
    assert reached <= cap + FB + 2000, (reached, cap)  # then nothing
    assert f.bytes <= cap + FB + 2000
    late = _steady(f, 18.0, 24.0, acks=False)
    assert late == {"feedback": 0, "video": 0}
    assert f.held["video"] > 0 and f.held["feedback"] > 0
    back = _steady(f, 24.0, 26.0, acks=True)
    assert back["video"] >= 35 and back["feedback"] >= 190


def test_a_lost_feedback_does_not_hold_the_cap_shut() -> None:
    """The acknowledgement names the newest feedback the leader had: what was sent before
    it is delivered or lost, and out of the path either way."""
    f = InFlight(min_bytes=1000.0)
    for k in range(100):
        f.sent(0.01 * k, FB)
    f.acked(1.0, 0.5, 100_000.0)
    assert f.bytes == 49 * FB  # sent after 0.5 s
    f.acked(1.1, 0.3, 100_000.0)  # an older acknowledgement (reordered): nothing changes
    assert f.bytes == 49 * FB
    f.acked(1.2, 0.99, 100_000.0)
    assert f.bytes == 0


def test_the_cap_follows_rate_round_trip_and_acknowledgement_interval() -> None:
    f = InFlight(gain=2.0, min_bytes=100.0, ack_prior_s=0.3)
    f.acked(1.0, 0.9, 800_000.0)  # rtt 0.1 s, no interval yet: the prior
    assert f.cap_bytes == pytest.approx(2.0 * 100_000.0 * (0.1 + 0.3))
    f.acked(1.5, 1.3, 800_000.0)  # rtt 0.2 (the minimum stays 0.1), an interval of 0.5 s
    assert f.cap_bytes == pytest.approx(2.0 * 100_000.0 * (0.1 + 0.5))
    assert InFlight(min_bytes=5000.0).min_bytes == 5000.0
    g = InFlight(min_bytes=5000.0)
    g.acked(1.0, 0.99, 8_000.0)
    assert g.cap_bytes == 5000.0  # the floor: a part and a few feedback always fit


def test_the_acknowledgement_interval_is_one_window_its_mean_and_on_a_lossy_path_its_longest() -> None:
    """The intervals between acknowledgements of the last ``rtt_window_s``: their mean in the
    cap, their longest while the budget calls the path lossy (asked at each use, so the cap
    follows the budget's judgement between two Status); an interval older than the window
    leaves both."""
    lossy = [False]
    f = InFlight(gain=2.0, min_bytes=100.0, rtt_window_s=10.0, lossy=lambda: lossy[0])
    t = 1.0
    for dt in (0.5, 0.5, 1.0, 0.5):  # a Status lost on its way: one interval of 1 s
        f.acked(t, t - 0.1, 800_000.0)
        t += dt
    f.acked(t, t - 0.1, 800_000.0)
    assert f.ack_interval_s == pytest.approx(0.625)
    assert f.cap_bytes == pytest.approx(2.0 * 100_000.0 * (0.1 + 0.625))
    lossy[0] = True
    assert f.cap_bytes == pytest.approx(2.0 * 100_000.0 * (0.1 + 1.0))
    for _ in range(25):  # 12.5 s of 0.5 s intervals: the 1 s one leaves the window
        t += 0.5
        f.acked(t, t - 0.1, 800_000.0)
    assert f.ack_interval_s == pytest.approx(0.5)
    assert f.cap_bytes == pytest.approx(2.0 * 100_000.0 * (0.1 + 0.5))
    lossy[0] = False
    f.reset()
    assert f.ack_interval_s is None


def test_the_cap_asks_the_budget_whether_the_path_is_lossy() -> None:
    """The budget's judgement ends ``lossy_hold_s`` after the leader last reported loss; the
    cap reads it then, not at the next Status."""
    now = [100.0]
    b = UplinkBudget(lambda: now[0])
    t = 100.0
    for k in range(8):  # a Status every 0.5 s, one of them a second late
        now[0] = t = t + (1.0 if k == 3 else 0.5)
        b.on_leader_status({"rx_bps": 400_000, "fb_age_ms": 100, "fb_loss_ppm": 50_000 if k == 0 else 0}, t)
    assert b.lossy
    lossy_cap = b.inflight.cap_bytes
    now[0] = 100.0 + 0.5 + b.tuning.lossy_hold_s + 0.01  # the hold is over; no Status since
    assert not b.lossy and b.inflight.cap_bytes < lossy_cap


@pytest.mark.parametrize("name", ["gain", "min_bytes", "probe_s", "rtt_window_s", "ack_prior_s", "video_share"])
def test_bad_parameters_are_named(name: str) -> None:
    with pytest.raises(ValueError, match=name):
        InFlight(**{name: 0.0})
    with pytest.raises(ValueError, match="video_share"):
        InFlight(video_share=1.5)


def test_video_leaves_the_feedback_its_share_of_the_cap() -> None:
    """Video fills at most ``video_share`` of the cap; feedback is admitted up to the cap."""
    f = InFlight(gain=2.0, min_bytes=100.0, ack_prior_s=0.4)
    f.acked(1.0, 0.9, 800_000.0)  # cap: 2 x 100 kB/s x 0.5 s = 100 kB
    f.sent(1.0, 74_000)
    assert f.admit_video(1000) and not f.admit_video(2000)  # 75 kB: video's room
    assert f.admit_feedback(1.0)
    f.sent(1.0, 25_000)
    assert f.admit_feedback(1.0) and not f.over
    f.sent(1.0, 1_000)
    assert f.over and not f.admit_feedback(1.0)


def test_the_budget_feeds_the_cap_from_the_leaders_status() -> None:
    """UplinkBudget counts what it sends and takes the leader's ``fb_age_ms`` as the acknowledgement."""
    now = [0.0]
    b = UplinkBudget(lambda: now[0])
    for k in range(100):
        now[0] = 0.01 * k
        b.sent(FB, feedback=True)
    now[0] = 1.0
    b.on_leader_status({"rx_bps": 320_000, "fb_age_ms": 300, "fb_loss_ppm": 0}, 1.0)
    assert b.inflight.bytes == 30 * FB  # sent after 0.7 s
    c = b.inflight_counters()
    assert c["uplink_inflight_bytes"] == 30 * FB and c["uplink_inflight_cap"] > 0


def _closed_budget(now: list[float]) -> UplinkBudget:
    """A budget whose cap is shut: a leader (session 7) acknowledged at 2 Hz for 3 s, then 2 s
    without an acknowledgement advancing while commands and statuses kept coming (a stalled uplink)."""
    b = UplinkBudget(lambda: now[0])
    for k in range(300):
        now[0] = 0.01 * k
        b.sent(FB, feedback=True)
        b.update()
        if k % 50 == 49:
            b.on_leader_status({"rx_bps": 320_000, "fb_age_ms": 20, "fb_loss_ppm": 0}, now[0], 7)
    while now[0] < 5.0:  # the uplink stalls; the leader's commands and statuses still come
        now[0] = round(now[0] + 0.01, 6)
        b.on_h2(0.2)
        if b.inflight.admit_feedback(now[0]):
            b.sent(5 * FB, feedback=True)  # feedback and video's worth
        if round(now[0] * 100) % 50 == 49:
            b.on_leader_status(
                {"rx_bps": 320_000, "fb_age_ms": int(1000 * (now[0] - 2.97)), "fb_loss_ppm": 0}, now[0], 7
            )
        b.update()
    assert b.inflight.over and not b.inflight.admit_feedback(now[0])
    return b


def test_a_leader_that_left_releases_the_cap() -> None:
    """No command and no leader Status for ``inflight_release_s`` (0.5 s): nobody acknowledges,
    so the follower's feedback is not held (it was: a killed leader left the robot's feedback
    at the probes' pace, 1-2 s apart; a new leader saw the robot late)."""
    now = [0.0]
    b = _closed_budget(now)
    now[0] += 0.3
    b.update()
    assert b.inflight.over  # 0.3 s of silence: a stalled uplink still
    now[0] += 0.3
    b.update()
    assert not b.inflight.over and b.inflight.admit_feedback(now[0]) and b.inflight.cap_bytes == math.inf


def test_a_new_leader_session_releases_the_cap() -> None:
    """Another leader's Status (a new session) while the cap is shut: it opens at once."""
    now = [0.0]
    b = _closed_budget(now)
    b.on_leader_status({"rx_bps": 0}, now[0], 8)
    assert not b.inflight.over and b.inflight.admit_feedback(now[0])


def test_a_leader_back_from_silence_is_not_taken_for_a_stalled_uplink() -> None:
    """A leader silent for 3 s (frozen, or the whole path down) comes back: its first statuses
    report a feedback age of its own silence. The follower's feedback must go out at once, not
    wait for a probe's echo (it waited: the robot walked 2.2-3.6 s after a frozen leader resumed,
    test_adversary_replay; the first statuses set the stall hold, one message in flight)."""
    now = [0.0]
    b = _closed_budget(now)
    for _ in range(300):  # 3 s: no command, no status
        now[0] = round(now[0] + 0.01, 6)
        b.update()
    b.on_h2(0.2)
    b.on_leader_status({"rx_bps": 0, "fb_age_ms": 3300, "fb_loss_ppm": 0}, now[0], 7)
    b.update()
    assert b.inflight.admit_feedback(now[0])
    b.sent(FB, feedback=True)  # the first feedback is in flight; the next one too (no stall hold)
    now[0] = round(now[0] + 0.01, 6)
    b.on_h2(0.2)
    b.update()
    assert not b.inflight.hold and b.inflight.admit_feedback(now[0])


def test_a_leader_back_from_silence_is_not_taken_for_a_stalled_uplink_by_its_commands_echo() -> None:
    """As above, when the leader's first command comes before its first Status: its echo
    shows the newest feedback from before the silence, which the silence explains too."""
    now = [0.0]
    b = _closed_budget(now)
    for _ in range(300):  # 3 s: no command, no status; the robot's feedback goes on (the cap released)
        now[0] = round(now[0] + 0.01, 6)
        b.update()
        if b.inflight.admit_feedback(now[0]):
            b.sent(FB, feedback=True)
    b.on_h2(0.2)
    b.on_echo([2.97, 3.17], now[0])  # the newest feedback the leader took, sent before the silence
    b.update()
    assert not b.stalled and b.inflight.admit_feedback(now[0])
    b.sent(FB, feedback=True)
    now[0] = round(now[0] + 0.01, 6)
    b.on_h2(0.2)
    b.on_echo([2.97, 3.17], now[0])
    b.update()
    assert not b.inflight.hold and b.inflight.admit_feedback(now[0])


def _acks(f: InFlight, sent: int) -> None:
    """Ten acknowledgements at 10 Hz with a 20 ms round trip (800 kbit/s delivered), then
    ``sent`` bytes and one acknowledgement 80 ms over the minimum."""
    for k in range(10):
        f.acked(0.1 * k, 0.1 * k - 0.02, 800_000.0)
    f.sent(0.95, sent)
    f.acked(1.0, 0.90, 800_000.0)


def test_video_waits_while_the_acknowledgements_show_a_queue_of_ours() -> None:
    """Round trips 80 ms over their minimum with more than a bandwidth-delay product in
    flight: a queue of ours, video waits; the same rise with little in flight (the path's
    own delay rose) does not hold it, nor does one late sample among prompt ones."""
    f = InFlight(gain=2.0, min_bytes=1000.0, video_queue_s=0.05)
    big = 100_000 * 12 // 100 + 2000  # more than one product: 100 kB/s x (0.02 + 0.1) s
    _acks(f, big)
    assert f.queue_s == pytest.approx(0.0, abs=1e-9) and f.admit_video(1000, now=1.01)  # one late sample: noise
    f.acked(1.1, 1.0, 800_000.0)
    f.sent(1.15, big)
    f.acked(1.2, 1.1, 800_000.0)
    assert f.queue_s == pytest.approx(0.08)
    assert f.bytes > f.cap_bytes / f.gain
    assert f.admit_video(1000) and not f.admit_video(1000, now=1.21)
    assert f.admit_video(1000, now=2.5)  # a sample over a second old is not used
    # counted apart from what the cap's room holds (the two are told apart in the Status)
    assert f.held["video_rtt"] == 1 and f.counters()["uplink_held_video_rtt"] == 1
    f.sent(2.6, int(10 * f.cap_bytes))
    assert not f.admit_video(1000) and f.held["video"] == 2 and f.held["video_rtt"] == 1
    g = InFlight(gain=2.0, min_bytes=1000.0, video_queue_s=0.05)
    _acks(g, 100)
    g.sent(1.15, 100)
    g.acked(1.1, 1.0, 800_000.0)
    g.acked(1.2, 1.1, 800_000.0)
    assert g.queue_s == pytest.approx(0.08) and g.admit_video(1000, now=1.21)


class _Cam:
    """A robot whose cameras return a flat QVGA image."""

    def capture(self, cam: str) -> np.ndarray:
        return np.full((240, 320, 3), 128, dtype=np.uint8)


def test_the_video_streamer_holds_frames_the_cap_refuses() -> None:
    """VideoStreamer asks ``admit`` before each frame: refused ones are dropped and counted
    (``held``), and frames flow again once it admits them. Fake clock, real encoder thread."""
    t = [0.0]
    sent: list[VideoFrame] = []
    open_ = [False]
    asked: list[int] = []

    def admit(nbytes: int) -> bool:
        asked.append(nbytes)
        return open_[0]

    v = VideoStreamer(_Cam(), ["head"], 10.0, sent.append, now=lambda: t[0], admit=admit)  # type: ignore[arg-type]
    with v:
        for k in range(200):
            open_[0] = k >= 100  # shut for the first 2 s
            v.maybe_capture(t[0])
            for _ in range(200):  # let the encoder take the frame (latest-only slot)
                with v._cv:
                    if v._slot is None:
                        break
                time.sleep(0.001)
            time.sleep(0.002)
            t[0] += 0.02
    assert v.stats["held"] >= 15 and all(n > 0 for n in asked)
    assert sent and min(f.t for f in sent) >= 2.0 - 1e-9  # nothing left while it was shut
    assert len(sent) >= 15


def _lost_statuses(loss_ppm: int, stall_at: float = math.inf) -> list[float]:
    """20 s of feedback (400 B at 50 Hz) and video (3 kB frames at 20 Hz, each asking the
    cap) with the leader's Status every 0.5 s naming a feedback sent 0.3 s before it, one
    Status in four lost on its way, the leader reporting 0.8 x what was sent (TCP's
    loss-slowed video) and ``loss_ppm`` of feedback loss; from ``stall_at`` [s] its newest
    feedback stays the one it had then. Return the times a frame was held."""
    now = [0.0]
    b = UplinkBudget(lambda: now[0])
    held: list[float] = []
    for k in range(2000):
        now[0] = round(0.01 * (k + 1), 6)
        b.on_h2(0.2)
        if k % 2 == 0:
            b.sent(FB, feedback=True)
        if k % 5 == 0:
            if b.video_budget_bps() != 0.0 and b.admit_video(3000):
                b.sent(3000, video=True)
            else:
                held.append(now[0])
        if k % 50 == 49 and k % 200 != 149:
            age = 0.3 if now[0] <= stall_at else now[0] - stall_at + 0.3
            counters = {"rx_bps": round(0.8 * b.tx_bps()), "fb_age_ms": round(1000 * age), "fb_loss_ppm": loss_ppm}
            b.on_leader_status(counters, now[0])
        b.update()
    return held


def test_on_a_lossy_path_a_lost_status_does_not_hold_video() -> None:
    """The 5 % loss row: a Status lost on its way (one in twenty) left the next
    acknowledgement a second after the last, and against a cap from the acknowledgements'
    mean interval video waited each time (held 125 times in one run, its frame rate dipping
    to 11-15 frames/s). On a path the leader reports lossy the cap allows for the longest
    interval of its window; on a loss-free path the same gaps hold video as before. A path
    that stops delivering still stops the lossy path's video."""
    lossy = _lost_statuses(50_000)
    assert [t for t in lossy if t > 5.0] == [], lossy[-10:]
    clean = _lost_statuses(0)
    assert len([t for t in clean if t > 5.0]) > 10, clean[-10:]
    stalled = _lost_statuses(50_000, stall_at=12.0)
    assert all(round(t, 2) in stalled for t in np.arange(13.01, 20.0, 0.05)), stalled[-10:]


def _gap_from_3_s(seconds: float, check: Callable[[UplinkBudget, float], None] | None = None) -> UplinkBudget:
    """Run a budget ``seconds`` at 100 Hz with the uplink gone from 3 s: feedback 40 ms up the
    path before it, nothing in it; a command every 20 ms echoing the newest feedback the
    leader took; the leader's Status at 2 Hz, none in the gap (its TCP link stops with the
    uplink). ``check(budget, now)`` runs after each tick."""
    now = [0.0]
    b = UplinkBudget(lambda: now[0])
    newest = 0.0  # send time of the newest feedback the leader has
    for k in range(1, round(seconds * 100) + 1):
        now[0] = 0.01 * k
        gap = now[0] > 3.0
        if b.inflight.admit_feedback(now[0]):
            b.sent(FB, feedback=True)
            newest = newest if gap else now[0] - 0.04
        b.on_h2(0.04)
        if k % 2 == 0:
            b.on_echo([newest, newest + 0.04], now[0] - 0.005)
        if k % 50 == 0 and not gap:
            b.on_leader_status(
                {"rx_bps": 1_500_000, "fb_age_ms": round(1000 * (now[0] - newest)), "fb_loss_ppm": 0}, now[0]
            )
        b.update()
        if check is not None:
            check(b, now[0])
    return b


def test_a_stall_is_judged_from_the_commands_echo_when_the_leaders_status_stops_with_the_uplink() -> None:
    """In the split layout the leader's Status rides a TCP link whose acknowledgements go up
    the uplink: in a gap it stops too, while commands (UDP) still come. A gap that began just
    after a Status went unseen on the LTE row: the follower sent feedback into a 4.4 s gap
    until the in-flight cap filled (107 kB, 3 s in), the first to arrive after it 1.99 s old.
    The commands' echo of the newest feedback judges the stall: feedback is held within
    ``stall_s`` past the path's delay."""

    def held(b: UplinkBudget, now: float) -> None:
        if now >= 3.6:  # 0.5 s past the gap and its delay, a command's period more
            assert b.stalled and not b.inflight.admit_feedback(now), now

    b = _gap_from_3_s(8.0, held)
    assert b.signals["stall"] == 1 and b.inflight.bytes <= 60 * FB, b.inflight.bytes  # 0.6 s of feedback at most


def test_a_status_sent_before_the_stall_began_does_not_end_it() -> None:
    """The commands' echo judged the stall; a leader Status sent just before the gap arrives
    late (it waited behind the gap on its TCP link) with the feedback fresh as it was then:
    it says nothing of the path now, and the stall holds until a word sent after it began."""
    b = _gap_from_3_s(4.0)
    assert b.stalled
    b.on_leader_status({"rx_bps": 1_500_000, "fb_age_ms": 40, "fb_loss_ppm": 0}, 2.99)  # sent before the gap
    assert b.stalled and b.signals["stall"] == 1
