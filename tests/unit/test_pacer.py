"""The one pacer of both nodes (bipedtele.pacer), on a fake clock."""

from __future__ import annotations

import threading
import time

import pytest
from bipedtele.pacer import Pacer, PeriodStats

pytestmark = pytest.mark.timeout(20)


class FakeClock:
    """A clock that only moves when the pacer sleeps (plus what the 'work' costs)."""

    def __init__(self, oversleep_s: float = 0.0) -> None:
        self.t = 100.0
        self.oversleep_s = oversleep_s
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.t

    def sleep(self, timeout_s: float, wake: threading.Event) -> bool:
        self.sleeps.append(timeout_s)
        if wake.is_set():
            return True
        # a zero sleep is a yield: it costs a microsecond
        self.t += timeout_s + self.oversleep_s if timeout_s > 0 else 1e-6
        return False


def make(period: float = 0.01, oversleep: float = 0.0, spin: float = 0.0) -> tuple[Pacer, FakeClock]:
    clk = FakeClock(oversleep)
    return Pacer(period, spin_s=spin, clock=clk, sleep=clk.sleep), clk


def test_period_kept_on_the_grid() -> None:
    pacer, clk = make(0.01)
    times = []
    for _ in range(50):
        clk.t += 0.003  # the tick's work
        assert pacer.wait()
        times.append(clk.t)
    assert times == pytest.approx([100.0 + 0.01 * (k + 1) for k in range(50)])
    assert pacer.missed == 0 and pacer.late_ticks == 0


def test_no_drift_with_oversleep_and_varying_work() -> None:
    """Each wait ends on the grid start + k*period: oversleeps and work never accumulate."""
    pacer, clk = make(0.001, oversleep=0.0002)
    for k in range(1, 2001):
        clk.t += 0.0004 if k % 3 else 0.0007
        assert pacer.wait()
        # an oversleep makes this tick late by at most the oversleep, never more
        assert 100.0 + 0.001 * k <= clk.t <= 100.0 + 0.001 * k + 0.0002 + 1e-9
    assert pacer.k == 2000 and pacer.missed == 0


def test_overrun_skips_missed_deadlines_and_counts_them() -> None:
    pacer, clk = make(0.01)
    assert pacer.wait()  # t = 100.01
    clk.t += 0.035  # a long tick: 100.045; deadlines 100.02, .03, .04 passed
    assert pacer.wait()  # returns at once, no burst of catch-up ticks
    assert clk.t == pytest.approx(100.045)
    assert pacer.late_ticks == 1
    assert pacer.missed == 2  # .02 (this late tick) is run; .03 and .04 skipped
    assert pacer.wait()
    assert clk.t == pytest.approx(100.05)  # back on the original grid
    assert pacer.deadline == pytest.approx(100.06)


def test_a_late_tick_within_one_period_is_not_skipped() -> None:
    pacer, clk = make(0.01)
    clk.t += 0.015  # late for 100.01 by 5 ms
    assert pacer.wait()
    assert pacer.late_ticks == 1 and pacer.missed == 0
    assert pacer.wait()
    assert clk.t == pytest.approx(100.02)


def test_spin_phase_sleeps_short_of_the_deadline() -> None:
    pacer, clk = make(0.001, spin=0.0003)
    clk.sleeps.clear()
    assert pacer.wait()
    assert clk.sleeps[0] == pytest.approx(0.0007)
    assert all(s == 0.0 for s in clk.sleeps[1:])  # then yields until the deadline
    assert 100.001 <= clk.t <= 100.001 + 2e-6


def test_notify_cuts_the_wait_short_and_keeps_the_deadline() -> None:
    pacer, clk = make(0.01)
    pacer.notify()
    assert pacer.wait() is False
    assert clk.t == 100.0 and pacer.k == 0
    assert pacer.wait() is True  # the event was cleared: the same deadline is waited for
    assert clk.t == pytest.approx(100.01) and pacer.k == 1


def test_stop_ends_every_wait() -> None:
    pacer, clk = make(0.01)
    pacer.stop()
    assert pacer.stopped
    assert pacer.wait() is False
    assert pacer.wait() is False
    assert clk.t == 100.0


def test_stop_from_another_thread_ends_a_real_wait() -> None:
    pacer = Pacer(30.0)
    threading.Timer(0.05, pacer.stop).start()
    t0 = time.monotonic()
    assert pacer.wait() is False
    assert time.monotonic() - t0 < 10.0


def test_bad_period_is_refused() -> None:
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="period_s"):
            Pacer(bad)


def test_period_stats_ring() -> None:
    st = PeriodStats(capacity=4)
    for k in range(10):
        st.add(0.01 * k)
    assert st.times().tolist() == pytest.approx([0.06, 0.07, 0.08, 0.09])
    s = st.summary(0.01)
    assert s["rate_hz"] == pytest.approx(100.0)
    assert s["err_max_s"] == pytest.approx(0.0, abs=1e-12)
