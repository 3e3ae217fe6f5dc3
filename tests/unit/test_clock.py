"""DelayEstimator (time-windowed mean) and ClockSync (NTP exchange), injected times only."""

from __future__ import annotations

import random

import pytest
from bipedtele.clock import ClockSync, DelayEstimator, conservative_delays


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
