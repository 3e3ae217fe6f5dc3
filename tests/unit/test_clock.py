"""DelayEstimator (time-windowed mean) and ClockSync (NTP exchange), injected times only."""

from __future__ import annotations

import random

import pytest
from bipedtele.link.clock import ClockSync
from bipedtele.link.delayestimate import DelayEstimator, conservative_delays
from hypothesis import given, settings
from hypothesis import strategies as st


def test_empty_window_is_none() -> None:
    e = DelayEstimator(1.0)
    assert e.value(100.0) is None
    e.update(99.0, 99.5)
    assert e.value(99.5) == pytest.approx(0.5)
    assert e.value(100.49) == pytest.approx(0.5)
    assert e.value(100.5) is None  # window (99.5, 100.5] excludes 99.5
    assert e.value(200.0) is None


def test_time_window_not_count() -> None:
    e = DelayEstimator(1.0)
    # a burst of 10 messages of 0.1 s delay, then 1 message of 0.5 s delay
    for k in range(10):
        t = 10.0 + 0.01 * k
        e.update(t - 0.1, t)
    e.update(10.45, 10.95)
    assert e.value(10.95) == pytest.approx((10 * 0.1 + 0.5) / 11)
    assert e.value(11.0) == pytest.approx((9 * 0.1 + 0.5) / 10)  # 10.00 left the window
    assert e.value(11.095) == pytest.approx(0.5)  # the burst left the window at 11.09
    assert e.count(11.095) == 1


def test_matches_brute_force_under_random_traffic() -> None:
    rng = random.Random(3)
    e = DelayEstimator(0.7)
    samples: list[tuple[float, float]] = []
    t = now = 0.0
    for _ in range(3000):
        t += rng.expovariate(200.0)
        d = rng.uniform(0.05, 0.4)
        e.update(t - d, t)
        samples.append((t, d))
        if rng.random() < 0.3:
            now = max(now, t + rng.uniform(0.0, 0.2))  # queries in time order
            ref = [x for (r, x) in samples if now - 0.7 < r <= now]
            got = e.value(now)
            if ref:
                assert got == pytest.approx(sum(ref) / len(ref), abs=1e-9)
            else:
                assert got is None


def test_memory_bounded() -> None:
    e = DelayEstimator(1000.0, max_samples=100)
    for k in range(10_000):
        e.update(k * 1e-3 - 0.1, k * 1e-3)
    assert len(e._samples) == 100
    assert e.value(10.0) == pytest.approx(0.1)


def test_future_samples_excluded_and_clear() -> None:
    e = DelayEstimator(1.0)
    e.update(0.9, 1.0)
    e.update(1.8, 2.0)
    assert e.value(1.5) == pytest.approx(0.1)
    e.clear()
    assert e.value(2.0) is None


def test_bad_window() -> None:
    with pytest.raises(ValueError):
        DelayEstimator(0.0)


def test_clock_sync_symmetric_path_exact() -> None:
    cs = ClockSync(window=8)
    assert not cs.ready and cs.rtt is None and cs.offset == 0.0
    offset, h = 12.5, 0.1  # remote = local + 12.5; 100 ms each way
    t1 = 1000.0
    t2 = t1 + h + offset
    t3 = t2 + 0.002
    t4 = t3 - offset + h
    s = cs.on_pong(t1, t2, t3, t4)
    assert s is not None and cs.ready
    assert cs.offset == pytest.approx(offset)
    assert cs.rtt == pytest.approx(2 * h)
    assert cs.to_local(t2) == pytest.approx(t1 + h)
    assert cs.to_remote(cs.to_local(5.0)) == pytest.approx(5.0)


def test_clock_sync_min_rtt_filter_and_asymmetry() -> None:
    cs = ClockSync(window=4)
    offset = -3.0

    def exchange(t1: float, fwd: float, bwd: float) -> None:
        t2 = t1 + fwd + offset
        t3 = t2 + 0.001
        cs.on_pong(t1, t2, t3, t3 - offset + bwd)

    exchange(0.0, 0.30, 0.30)  # queued: big rtt
    exchange(1.0, 0.10, 0.10)  # best
    exchange(2.0, 0.25, 0.20)
    assert cs.offset == pytest.approx(offset)
    assert cs.rtt == pytest.approx(0.2)
    # the best one falls out of the window of 4
    for k in range(3):
        exchange(3.0 + k, 0.15, 0.11)
    # asymmetric path: offset error is half the asymmetry, the rtt is exact
    assert cs.rtt == pytest.approx(0.26)
    assert cs.offset - offset == pytest.approx((0.15 - 0.11) / 2)


def test_clock_sync_rejects_inconsistent() -> None:
    cs = ClockSync(window=4)
    assert cs.on_pong(10.0, 5.0, 4.0, 11.0) is None  # t3 < t2
    assert cs.on_pong(10.0, 5.0, 5.1, 9.0) is None  # t4 < t1
    assert cs.on_pong(10.0, 5.0, 7.0, 11.0) is None  # negative rtt
    assert cs.on_pong(float("nan"), 5.0, 5.0, 11.0) is None
    assert cs.rejected == 4 and not cs.ready
    with pytest.raises(ValueError):
        ClockSync(window=0)


def test_conservative_delays() -> None:
    assert conservative_delays(0.37) == (0.37, 0.37)


# --------------------------------------------------------------------------- bound to the peer

OFFSET, H = 7.25, 0.05  # remote = local + 7.25 s; 50 ms each way


def honest(cs: ClockSync, seq: int, t1: float, sid: int = 9, peer: int | None = None) -> str | None:
    """Send ping ``seq`` at t1 and feed the honest answer of ``sid``."""
    cs.sent(seq, t1)
    t2 = t1 + H + OFFSET
    t3 = t2 + 0.001
    return cs.on_answer(sid, seq, t2, t3, t3 - OFFSET + H, peer=peer)


def test_answer_must_match_an_outstanding_ping_and_counts_once() -> None:
    cs = ClockSync(window=4)
    assert honest(cs, 1, 100.0) is None
    assert cs.offset == pytest.approx(OFFSET) and cs.rtt == pytest.approx(2 * H)
    # a forged answer to a ping never sent: 5 s offset shift in the old API
    assert cs.on_answer(9, 77, 200.0, 200.0, 100.2) == "pong_unmatched"
    # the same ping answered twice
    assert cs.on_answer(9, 1, 107.3, 107.3, 100.2) == "pong_unmatched"
    assert cs.offset == pytest.approx(OFFSET)
    assert cs.rejections == {"pong_unmatched": 2} and cs.rejected == 2


def test_t1_is_local_so_a_fast_forged_answer_cannot_shrink_the_round_trip() -> None:
    """Attack (issue 10, item 4): the forger answers ping 1 claiming t1 = t4 - 1 ms and a
    zero hold; t1 is not in the API any more, the measured t4 - t1 stands."""
    cs = ClockSync(window=16)
    cs.sent(1, 100.0)
    t4 = 100.2  # the forged answer arrives 200 ms after the ping left
    assert cs.on_answer(9, 1, 50.0, 50.0, t4) is None
    assert cs.rtt == pytest.approx(0.2)


def test_hold_time_is_bounded() -> None:
    cs = ClockSync(window=16, hold_max_s=0.05)
    cs.sent(1, 100.0)
    # forged hold of 0.19 s would turn a 0.2 s round trip into 0.01 s
    assert cs.on_answer(9, 1, 500.0, 500.19, 100.2) == "pong_hold"
    assert not cs.ready
    assert cs.outstanding == 1  # a rejected answer does not consume the ping
    assert cs.on_answer(9, 1, 500.0, 500.04, 100.2) is None  # within the bound: accepted
    assert cs.rtt is not None and cs.rtt >= (100.2 - 100.0) - 0.05 - 1e-12


def test_forged_hold_rejected_in_the_low_level_api_too() -> None:
    """The old on_pong accepted any hold: with t3 - t2 = 5 s a 5.1 s round trip read as 0.1 s."""
    cs = ClockSync(window=4)
    assert cs.on_pong(100.0, 300.0, 305.0, 105.1) is None
    assert cs.rtt is None
    assert cs.rejected == 1


def test_only_the_bound_peer_is_used() -> None:
    cs = ClockSync(window=4)
    # no peer followed yet: any answerer is used
    assert honest(cs, 1, 100.0, sid=9) is None
    assert cs.peer == 9
    cs.sent(2, 101.0)
    # the app's gate follows session 9: another session's answer is dropped
    assert cs.on_answer(5, 2, 0.0, 0.0, 101.1, peer=9) == "foreign_session"
    assert cs.offset == pytest.approx(OFFSET)
    # the peer changed (a restarted follower on another host): old samples are forgotten
    assert cs.on_answer(9, 2, 108.3, 108.3, 101.1, peer=5) == "foreign_session"
    cs.bind(5)
    assert not cs.ready and cs.peer == 5
    assert cs.on_answer(5, 2, 101.05, 101.051, 101.1, peer=5) is None
    assert cs.peer == 5 and cs.offset == pytest.approx(0.0005, abs=1e-9)
    assert cs.rejections == {"foreign_session": 2}
    # unbound again (no live peer): an answer of another session replaces the samples
    assert honest(cs, 3, 102.0, sid=9) is None
    assert cs.peer == 9 and cs.offset == pytest.approx(OFFSET)
    assert cs.rtt == pytest.approx(2 * H)  # not min-filtered with session 5's samples


def test_outstanding_pings_expire_and_are_bounded() -> None:
    cs = ClockSync(window=4, expire_s=2.0, max_outstanding=8)
    cs.sent(1, 100.0)
    assert cs.on_answer(9, 1, 100.0, 100.0, 102.5) == "pong_unmatched"  # 2.5 s > 2 s
    assert cs.outstanding == 0
    for k in range(100):
        cs.sent(10 + k, 200.0 + 0.01 * k)
    assert cs.outstanding == 8
    assert cs.on_answer(9, 10, 0.0, 0.0, 201.0) == "pong_unmatched"  # forgotten (oldest)
    cs.sent(500, 203.5)  # 2.5 s later: all earlier ones expire
    assert cs.outstanding == 1
    assert honest(cs, 501, 203.6) is None


def test_inconsistent_answers() -> None:
    cs = ClockSync(window=4)
    cs.sent(1, 100.0)
    assert cs.on_answer(9, 1, float("nan"), 5.0, 100.1) == "pong_inconsistent"
    assert cs.on_answer(9, 1, 5.0, 4.0, 100.1) == "pong_inconsistent"  # t3 < t2
    assert cs.on_answer(9, 1, 5.0, 5.0, 99.0) == "pong_inconsistent"  # t4 < t1
    assert cs.on_answer(9, 1, 5.0, 5.04, 100.01) == "pong_inconsistent"  # negative rtt
    with pytest.raises(ValueError, match="allowed"):
        ClockSync(hold_max_s=0.0)
    with pytest.raises(ValueError, match="allowed"):
        ClockSync(expire_s=float("inf"))
    with pytest.raises(ValueError, match="allowed"):
        ClockSync(max_outstanding=0)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(0.0, 1e9),
    st.floats(-1e9, 1e9),
    st.floats(0.0, 1.0),
    st.floats(0.0, 10.0),
    st.integers(0, 2**63 - 1),
    st.integers(0, 2**32 - 1),
)
def test_no_answer_makes_the_round_trip_shorter_than_measured_minus_hold(
    t2: float, hold: float, t1_frac: float, elapsed: float, seq: int, sid: int
) -> None:
    """Whatever t2, t3, seq and sid a forger picks, an accepted answer's round trip is at
    least the locally measured t4 - t1 minus hold_max_s (so the damping of (40) scheduled
    from it is at least the one for that)."""
    cs = ClockSync(hold_max_s=0.05)
    t1 = 1000.0 + t1_frac
    cs.sent(5, t1)
    t4 = t1 + elapsed
    reason = cs.on_answer(sid, seq, t2, t2 + hold, t4)
    if reason is None:
        assert seq == 5
        assert cs.rtt is not None and cs.rtt >= (t4 - t1) - 0.05 - 1e-9
    else:
        assert not cs.ready
