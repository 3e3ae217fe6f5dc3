"""OneWayQueue (follower/owdqueue.py): the echoed feedback's one-way delay, its queue and video's valve.

Simulated time: an echo every 10 ms (a command at 100 Hz) of a feedback sent 50 ms
before, its one-way delay as the test says; the two clocks apart by an offset that must
cancel.
"""

from __future__ import annotations

import pytest
from bipedtele.follower.capacity import UplinkBudget
from bipedtele.follower.owdqueue import OneWayQueue

pytestmark = pytest.mark.timeout(30)

OFFSET_S = 5_000.0  # the leader's clock ahead of the follower's [s]


def _feed(q: OneWayQueue, t0: float, seconds: float, delay_s: float) -> float:
    """Echo a feedback every 10 ms from ``t0`` [s] for ``seconds``, its one-way delay ``delay_s`` [s]; return the time after."""
    t = t0
    for _ in range(round(seconds / 0.01)):
        sent = t - 0.05  # the feedback the newest command echoes left 50 ms ago
        q.echo(t, sent, sent + delay_s + OFFSET_S)
        t += 0.01
    return t


def _ramp(q: OneWayQueue, t0: float, start_s: float, end_s: float, slope: float) -> float:
    """Echo a feedback every 10 ms from ``t0`` [s], its one-way delay rising from ``start_s`` to ``end_s`` [s] at ``slope`` [s/s]; return the time after."""
    t, d = t0, start_s
    while d < end_s - 1e-9:
        d = min(end_s, d + slope * 0.01)
        q.echo(t, t - 0.05, t - 0.05 + d + OFFSET_S)
        t += 0.01
    return t


def test_a_queue_of_ours_closes_the_valve_until_it_drains() -> None:
    """A queue of ours grows as fast as what is sent exceeds the path: here 0.2 s/s (the probe
    stays under 1.25 x what is sent)."""
    q = OneWayQueue(queue_max_s=0.03)
    t = _feed(q, 100.0, 2.0, 0.02)
    assert q.queue_s == pytest.approx(0.0, abs=1e-9) and not q.closed(t)
    t = _ramp(q, t, 0.02, 0.07, 0.2)  # to 50 ms of queue
    assert q.closed(t) and q.queue_s == pytest.approx(0.04, abs=0.001)  # the least of the last 60 ms
    q.held += 1  # the budget held a video message meanwhile
    t = _feed(q, t, 0.1, 0.03)  # video waited: it drained, a queue of ours
    assert not q.closed(t) and q.rebased == 0 and (q.drained, q.passed, q.dips) == (1, 0, 0)


def test_a_lone_steep_rise_is_the_paths_dip_and_a_second_within_a_second_is_ours() -> None:
    """A queue that rises faster than steep_slope (0.5 s/s: twice what the probe can build)
    is a dip of the path's (a cellular link's scheduling): video waits it out and nothing is
    cut. On the 3G and LTE rows 13 of 17 such dips cut the estimate by a fifth each (a
    ratchet: 229 -> 117 kbit/s on a link carrying 500-650), where the kernel's token bucket
    at 600 kbit/s showed no steep rise in 9 crossings. The valve closing again within
    ``lone_s`` is a capacity below what is sent: ours."""
    q = OneWayQueue(queue_max_s=0.03, steep_slope=0.5, lone_s=1.0)
    t = _feed(q, 100.0, 2.0, 0.02)
    t = _feed(q, t, 0.1, 0.07)  # a step: +50 ms between two feedback
    assert q.closed(t)
    q.held += 1
    t = _feed(q, t, 0.1, 0.02)
    assert not q.closed(t) and (q.dips, q.drained) == (1, 0)
    t = _feed(q, t, 0.3, 0.02)
    t = _feed(q, t, 0.1, 0.07)  # again 0.4 s later: not alone
    q.held += 1
    t = _feed(q, t, 0.1, 0.02)
    assert (q.dips, q.drained) == (1, 1)


def test_a_lone_slow_rise_under_the_ceiling_is_a_dip_and_past_it_ours() -> None:
    """A lone closing after a rise as slow as a queue of ours (0.2 s/s): with the budget's
    estimate under what the path carried at its last cut, the path's dip; past it, ours."""
    for under, counts in ((True, (1, 0)), (False, (0, 1))):
        q = OneWayQueue(queue_max_s=0.03, steep_slope=0.5, lone_s=1.0)
        t = _feed(q, 100.0, 2.0, 0.02)
        d = 0.02
        while d < 0.07:
            d += 0.002
            q.echo(t, t - 0.05, t - 0.05 + d + OFFSET_S, under_ceiling=under)
            t += 0.01
        assert q.closed(t)
        q.held += 1
        _feed(q, t, 0.1, 0.02)
        assert (q.dips, q.drained) == counts, under


def test_a_step_from_a_standing_few_milliseconds_is_still_a_dip() -> None:
    """The LTE row's spikes: the delay stood 12-13 ms over its minimum (a link's scheduling),
    then stepped to 33-46 ms within 20 ms. Measured from the last sample under a third of
    queue_max (60-100 ms before the valve closed, as the least of the last 60 ms lags the
    step) it read 0.3-0.45 s/s and was cut, 5 times in 90 s. A queue of ours at 0.25 s/s is
    still no dip."""
    q = OneWayQueue(queue_max_s=0.03, steep_slope=0.5, lone_s=1.0)
    t = _feed(q, 100.0, 2.0, 0.02)
    t = _feed(q, t, 0.2, 0.0325)  # 12.5 ms over the minimum
    t = _feed(q, t, 0.1, 0.06)  # a step to 40 ms
    assert q.closed(t)
    q.held += 1
    t = _feed(q, t, 0.1, 0.0325)
    assert not q.closed(t) and (q.dips, q.drained) == (1, 0)
    ours = OneWayQueue(queue_max_s=0.03, steep_slope=0.5, lone_s=1.0)
    t = _feed(ours, 200.0, 2.0, 0.02)
    t = _feed(ours, t, 0.2, 0.0325)
    t = _ramp(ours, t, 0.0325, 0.07, 0.25)  # the probe's fastest queue of ours
    assert ours.closed(t)
    ours.held += 1
    _feed(ours, t, 0.1, 0.0325)
    assert (ours.dips, ours.drained) == (0, 1)


def _slots(q: OneWayQueue, t0: float, seconds: float, wait_s: float) -> float:
    """Echo as a link that delivers in slots: 100 ms clear, 200 ms ``wait_s`` [s] slower, again; return the time after."""
    t = t0
    for _ in range(round(seconds / 0.3)):
        t = _feed(q, t, 0.1, 0.02)
        t = _feed(q, t, 0.2, 0.02 + wait_s)
    return t


def _close_at_40_ms(q: OneWayQueue, t: float) -> float:
    """A queue of ours of 40 ms (risen at 0.2 s/s), video held, drained; return the time after."""
    t = _ramp(q, t, 0.02, 0.06, 0.2)
    t = _feed(q, t, 0.08, 0.06)
    assert q.closed(t) and q.queue_s == pytest.approx(0.04)
    q.held += 1
    return _feed(q, t, 0.1, 0.02)


def _close_at_60_ms(q: OneWayQueue, t: float) -> float:
    """A queue of 60 ms (risen at 0.2 s/s), video held, drained; return the time after."""
    t = _ramp(q, t, 0.02, 0.08, 0.2)
    t = _feed(q, t, 0.08, 0.08)
    assert q.closed(t)
    q.held += 1
    return _feed(q, t, 0.1, 0.02)


def test_a_closing_no_higher_than_the_paths_own_waits_proves_nothing() -> None:
    """On the 3G row the echo's queue was 8-10 ms or more a quarter of the time whatever was sent
    (a link that delivers in slots; the kernel's 600 kbit/s token bucket: 0.7-1.0 ms), and 14
    closings in 90 s drained once video waited, each cutting the estimate: 205-245 kbit/s on a
    link carrying 340-1,060 in every second outside its gap. A closing that never passed
    queue_max_s by more than that quartile is the path's scheduling; on a clear path the same
    closing is ours."""
    q = OneWayQueue(queue_max_s=0.03)
    t = _slots(q, 100.0, 10.0, 0.015)
    assert q.noise_s(t) == pytest.approx(0.015)
    _close_at_40_ms(q, t)
    assert (q.jitter, q.drained, q.dips) == (1, 0, 0)
    clear = OneWayQueue(queue_max_s=0.03)
    t = _feed(clear, 100.0, 10.0, 0.02)
    assert clear.noise_s(t) == 0.0
    _close_at_40_ms(clear, t)
    assert (clear.jitter, clear.drained, clear.dips) == (0, 1, 0)


def test_a_closing_past_the_paths_own_waits_is_ours() -> None:
    """The same slotted path, a queue of 60 ms: past 30 + 15 ms, ours (the budget cuts)."""
    q = OneWayQueue(queue_max_s=0.03)
    t = _slots(q, 100.0, 10.0, 0.015)
    _close_at_60_ms(q, t)
    assert (q.jitter, q.drained) == (0, 1)


def test_on_a_link_that_delivers_in_slots_a_lone_closing_is_its_dip() -> None:
    """With the path's own waits at slotted_s or more (the 3G row's 8-10 ms, LTE's 5-7 ms),
    a lone closing is the link's slow stretch however slowly the queue rose: waited out, not
    cut (on 3G the estimate was cut 13-21 times in 90 s, and then probed back at 1-3 %/s). A
    second closing within a second is a capacity under what is sent: ours. A link that
    delivers smoothly (the kernel's token bucket: 0.7-1.0 ms) keeps the rule as it was: its
    crossings rise as slowly, and each costs the feedback a queue until the cut."""
    q = OneWayQueue(queue_max_s=0.03, slotted_s=0.0025)
    t = _slots(q, 100.0, 10.0, 0.015)
    t = _close_at_60_ms(q, t)
    assert (q.dips, q.drained, q.jitter) == (1, 0, 0)
    t = _feed(q, t, 0.2, 0.02)
    _close_at_60_ms(q, t)  # within a second of the last closing
    assert (q.dips, q.drained, q.jitter) == (1, 1, 0)
    smooth = OneWayQueue(queue_max_s=0.03, slotted_s=0.0025)
    t = _feed(smooth, 100.0, 10.0, 0.02)
    _close_at_60_ms(smooth, t)
    assert (smooth.dips, smooth.drained) == (0, 1)


def test_a_spike_that_drains_with_no_video_held_proves_nothing() -> None:
    """On the LTE row, spikes of the link's own (a short dip of its capacity) that drained
    before any video waited cut the estimate five times in 90 s, 622 -> 309 kbit/s."""
    q = OneWayQueue(queue_max_s=0.03)
    t = _feed(q, 100.0, 2.0, 0.02)
    t = _feed(q, t, 0.1, 0.07)
    assert q.closed(t)
    _feed(q, t, 0.05, 0.02)
    assert (q.drained, q.passed) == (0, 1)


def test_a_rise_of_the_paths_own_delay_is_rebased_after_a_round_trip() -> None:
    """A step of +80 ms that does not drain once video waits: video resumes a round trip
    (here 50 ms) plus 0.2 s later, and the new delay is the minimum."""
    q = OneWayQueue(queue_max_s=0.03, settle_s=0.2)
    t = _feed(q, 100.0, 2.0, 0.02)
    t1 = _feed(q, t, 0.2, 0.1)
    assert q.closed(t1) and q.rebased == 0
    t2 = _feed(q, t1, 0.3, 0.1)
    assert not q.closed(t2) and q.rebased == 1 and q.queue_s == 0.0
    _feed(q, t2, 0.5, 0.12)  # 20 ms above the new minimum: open
    assert q.queue_s == pytest.approx(0.02) and q.rebased == 1


def test_a_queue_standing_longer_than_the_window_is_the_standing_queue() -> None:
    """A queue of 20 ms (under the valve's 30 ms) for 15 s: the 10 s minimum takes it in,
    the 60 s one does not; a rebase (the path's own delay rose) starts both again, and a
    rise after it shows once it has stood for the hold (1 s)."""
    q = OneWayQueue(queue_max_s=0.03, standing_window_s=60.0)
    t = _feed(q, 100.0, 2.0, 0.02)
    t = _feed(q, t, 15.0, 0.04)
    assert q.queue_s == pytest.approx(0.0, abs=1e-9) and q.standing_s == pytest.approx(0.02)
    t = _feed(q, t, 0.5, 0.2)  # a step of the path's own that does not drain
    assert q.rebased == 1 and q.standing_s == pytest.approx(0.0, abs=1e-9)
    _feed(q, t, 1.5, 0.21)
    assert q.standing_s == pytest.approx(0.01)


def _slow_stretches(q: OneWayQueue, t0: float, seconds: float, queue_s: float) -> float:
    """Echo every 10 ms from ``t0`` [s] for ``seconds`` on a link whose slow stretches (300 ms
    of every 700, as the 3G trace's 200-600 ms) make each feedback wait 12 ms longer, over a
    queue of ours ``queue_s`` [s]; return the time after (it ends inside a slow stretch)."""
    t = t0
    for k in range(round(seconds / 0.01)):
        sent = t - 0.05
        wait = 0.012 if k % 70 >= 40 else 0.0
        q.echo(t, sent, sent + 0.1 + queue_s + wait + OFFSET_S)
        t += 0.01
    return t


def test_a_links_slow_stretches_are_no_standing_queue_a_queue_of_ours_is() -> None:
    """On the 3G row the echo's current delay over its 60 s minimum was over the 15 ms target
    21 % of the time after the delay cut of its slowest seconds, the slots' waits, and it
    slowed the budget's probe to half its rate. The standing queue is the current delay's
    least over 1 s: a link's waits that come and go within it are none; 20 ms of ours under
    them, standing 3 s, is."""
    q = OneWayQueue(queue_max_s=0.03, standing_window_s=60.0)
    t = _slow_stretches(q, 100.0, 20.29, 0.0)
    assert q.queue_s > 0.01  # the echo waits in a slow stretch
    assert q.standing_s == pytest.approx(0.0, abs=1e-9)
    _slow_stretches(q, t, 3.49, 0.02)
    assert q.standing_s == pytest.approx(0.02)


def test_the_same_echo_again_is_no_sample_and_an_old_one_closes_nothing() -> None:
    """The queue is the least of the last three samples and of every sample of the last
    2 x queue_max_s (60 ms): a link that delivers in slots (a cellular link's) makes each
    feedback wait up to a slot's gap, whatever the queue."""
    q = OneWayQueue(queue_max_s=0.03)
    t = _feed(q, 100.0, 1.0, 0.02)
    q.echo(t, t - 0.02, t + 0.08 + OFFSET_S)  # 100 ms on its way: 80 ms above the minimum
    q.echo(t + 0.01, t - 0.02, t + 0.08 + OFFSET_S)  # the same again: no sample
    for k in range(2, 6):
        q.echo(t + 0.01 * k, t - 0.02 + 0.01 * k, t + 0.08 + 0.01 * k + OFFSET_S)
    assert not q.closed(t + 0.05)  # the sample of 60 ms ago was low
    q.echo(t + 0.06, t + 0.04, t + 0.14 + OFFSET_S)
    assert q.closed(t + 0.06)
    assert not q.closed(t + 1.1)  # no command for a second: nothing to judge video by


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="queue_max_s"):
        OneWayQueue(queue_max_s=0.0)
    with pytest.raises(ValueError, match="lone_s"):
        OneWayQueue(lone_s=float("nan"))
    with pytest.raises(ValueError, match="standing_window_s"):
        OneWayQueue(standing_window_s=-1.0)
    with pytest.raises(ValueError, match="slotted_s"):
        OneWayQueue(slotted_s=0.0)


def test_the_budget_holds_video_while_the_valve_is_closed() -> None:
    t = [100.0]
    b = UplinkBudget(lambda: t[0])
    assert b.admit_video(1000)
    for d in (0.02, 0.02, 0.02, *[0.09] * 8):
        t[0] += 0.01
        b.on_echo((t[0] - 0.2, t[0] - 0.2 + d + OFFSET_S))
    assert not b.admit_video(1000) and b.owd.held == 1
    assert b.inflight_counters()["uplink_owd_ms"] == 70
