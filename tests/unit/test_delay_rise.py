"""DelayRise (follower/delayrise.py): the least of the last three delays (or of a span's) over the window's minimum."""

from __future__ import annotations

import pytest
from bipedtele.follower.backlog import WindowMin
from bipedtele.follower.delayrise import DelayRise, StandingQueue

pytestmark = pytest.mark.timeout(30)


def test_one_high_sample_is_no_queue_three_are() -> None:
    r = DelayRise(window_s=10.0)
    assert r.add(0.0, 0.10) == 0.0 and r.minimum == 0.10
    assert r.add(0.1, 0.20) == 0.0  # a wait of one sign: the least of the last three is still 0.10
    assert r.add(0.2, 0.20) == 0.0
    assert r.add(0.3, 0.20) == pytest.approx(0.10)  # three in a row: a queue


def test_with_a_span_the_current_delay_is_the_least_of_every_sample_in_it() -> None:
    """A link that delivers in slots 50 ms apart: each feedback waits up to a slot's gap.
    Three samples 10 ms apart can all wait on one slot; over 60 ms one of them is lucky."""
    r = DelayRise(window_s=10.0, span_s=0.06)
    r.add(0.0, 0.10)
    for k, wait in enumerate((0.04, 0.03, 0.02, 0.01, 0.0, 0.04, 0.03, 0.02), start=1):
        assert r.add(0.01 * k, 0.10 + wait) == 0.0, k  # a lucky sample within the last 60 ms
    plain = DelayRise(window_s=10.0)
    plain.add(0.0, 0.10)
    rises = [plain.add(0.01 * k, 0.10 + w) for k, w in enumerate((0.04, 0.04, 0.04), start=1)]
    assert rises[-1] == pytest.approx(0.04)  # three waits on one slot: a queue, for three samples only
    for k in range(9, 17):  # a queue: every sample high
        r.add(0.01 * k, 0.15)
    assert r.add(0.17, 0.15) == pytest.approx(0.05)


def test_the_minimum_is_over_the_window_and_rebase_takes_the_current_delay() -> None:
    r = DelayRise(window_s=1.0)
    r.add(0.0, 0.05)
    for k in range(1, 4):
        r.add(0.5 * k, 0.12)
    assert r.minimum == pytest.approx(0.12)  # the 50 ms sample left the window
    r.add(1.6, 0.30)
    r.add(1.7, 0.30)
    r.add(1.8, 0.30)
    r.rebase(1.8)
    assert r.minimum == pytest.approx(0.30) and r.add(1.9, 0.31) == pytest.approx(0.0)
    r.clear()
    assert r.minimum is None


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="window_s"):
        DelayRise(window_s=0.0)
    with pytest.raises(ValueError, match="span_s"):
        DelayRise(span_s=-0.1)
    for window_s, hold_s in ((0.0, 0.0), (60.0, -1.0), (1.0, 1.0), (60.0, float("nan"))):
        with pytest.raises(ValueError, match="hold_s"):
            StandingQueue(window_s, hold_s)


def test_the_standing_queue_is_the_least_over_its_hold_a_delay_at_or_below_zero_included() -> None:
    """One-way delays carry the clocks' offset, so a least of 0 or below is a delay, not none."""
    q = StandingQueue(60.0, hold_s=1.0)
    assert q.add(0.0, -0.05) == 0.0
    assert q.add(0.5, 0.0) == 0.0  # the least over the last second is still -0.05
    assert q.add(1.2, 0.02) == pytest.approx(0.05)  # -0.05 has left the hold: 0.0 over -0.05
    q.clear()
    assert q.add(2.0, 0.3) == 0.0 and q.floor(2.0) == 0.3


def test_window_min_keeps_its_least_over_the_window() -> None:
    lo = WindowMin(1.0)
    for t, v in ((0.0, 0.5), (0.4, 1.0), (0.8, 0.2), (1.2, 0.7)):
        lo.add(t, v)
    assert lo.front() == 0.2
    assert lo.value(1.9) == 0.7  # only the sample at 1.2 s is left
