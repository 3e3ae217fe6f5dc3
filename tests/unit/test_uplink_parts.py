"""The uplink budget's parts (issue 22): its tuning, the sent-bytes log, the h2 tracker, and
``UplinkBudget.update`` reading what was sent once per call."""

from __future__ import annotations

import pytest
from bipedtele.follower.capacity import UplinkBudget, UplinkTuning
from bipedtele.follower.queuedelay import QueueDelay
from bipedtele.follower.sentlog import SentLog

pytestmark = pytest.mark.timeout(60)


def test_the_tuning_keeps_floats_and_the_budget_reads_it_as_attributes() -> None:
    b = UplinkBudget(lambda: 0.0, increase_bps_per_s=5000, hold_s=3.0)
    assert b.tuning.increase_bps_per_s == 5000.0 and isinstance(b.tuning.increase_bps_per_s, float)
    assert b.hold_s == 3.0 and b.part_s == UplinkTuning().part_s
    assert UplinkBudget(lambda: 0.0, UplinkTuning(hold_s=4.0), ratio=0.5).tuning == UplinkTuning(hold_s=4.0, ratio=0.5)
    with pytest.raises(TypeError):
        UplinkBudget(lambda: 0.0, no_such_knob=1.0)
    with pytest.raises(AttributeError):
        _ = b.no_such_knob


def test_the_sent_log_splits_control_and_video_per_window() -> None:
    log = SentLog()
    for k in range(20):  # 2 s: 100 B control and 1000 B video every 0.1 s
        log.add(10.0 + 0.1 * k + 0.05, 100, feedback=True)
        log.add(10.0 + 0.1 * k + 0.05, 1000, video=True)
    assert log.first_sent == pytest.approx(10.05)
    assert log.rate(10.0, 12.0, 0) == pytest.approx(8 * 100 / 0.1)
    assert log.rate(10.0, 12.0, 1) == pytest.approx(8 * 1000 / 0.1)
    assert log.rate(10.0, 12.0) == pytest.approx(8 * 1100 / 0.1)
    assert log.rate(12.0, 12.0) == 0.0
    assert log.fb_bits == pytest.approx(800.0)


def test_a_lasting_rise_of_h2_is_relearned_a_short_one_is_a_queue() -> None:
    q = QueueDelay(UplinkTuning())
    t = 0.0
    for _ in range(100):  # 1 s at 150 ms
        assert not q.add(t, 0.15)
        t += 0.01
    assert q.excess_s == 0.0 and q.rise_since is None
    relearned = False
    for _ in range(700):  # +100 ms, held 7 s: the path's own delay after relearn_s (5 s)
        relearned = q.add(t, 0.25) or relearned
        t += 0.01
        if not relearned:
            assert q.excess_s == pytest.approx(0.1) and q.rise_since is not None
    assert relearned and q.excess_s == 0.0 and q.rise_since is None
    assert q.command_hz() == pytest.approx(100.0, rel=0.02)


def test_update_reads_what_was_sent_once() -> None:
    t = [1000.0]
    b = UplinkBudget(lambda: t[0], start_s=2.0)
    calls = [0]
    rate = b._log.rate

    def counted(*args: object) -> float:
        calls[-1] += 1
        return rate(*args)  # type: ignore[arg-type]

    b._log.rate = counted  # type: ignore[method-assign]
    for k in range(600):  # 6 s of clear path: the start ends, then the capacity is probed
        t[0] += 0.01
        b.sent(400, feedback=True)
        b.sent(1000, video=True)
        b.on_h2(0.15)
        if k % 50 == 0:
            b.on_leader_status({"rx_bps": round(b.tx_bps())}, t[0])
        calls.append(0)
        b.update()
        assert calls[-1] <= 1
    assert b.start_budget_bps is None and b.capacity_bps > 0  # past the start, probing
