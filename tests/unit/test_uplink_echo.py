"""The uplink's probes and their acknowledgement: a Status probes, the leader echoes its stamp.

Over the in-flight cap (or in a stall) a feedback never leaves: one sent into a path that
does not deliver arrives old, and the operator would be shown it. A follower Status leaves
as a probe after 1, 2, 4, 8 s without an acknowledgement; the leader echoes the newest
Status's send stamp (``uplink_t_us`` -> ``uplink_t_echo_us``), which acknowledges
everything the follower sent before it.
"""

from __future__ import annotations

import pytest
from bipedtele.follower.capacity import UplinkBudget
from bipedtele.follower.delivery import InFlight
from bipedtele.leader.linkquality import LinkQuality
from bipedtele.leader.report import link_counters

pytestmark = pytest.mark.timeout(30)


def _over(f: InFlight, t: float) -> None:
    """Fill the cap: 1 Mbit/s delivered, 0.1 s round trip (with the 0.5 s acknowledgement interval: 150 kB), then 150 kB sent at ``t``."""
    f.acked(t, t - 0.1, 1_000_000.0)
    for k in range(30):
        f.sent(t + 0.001 * k, 5000)
    assert f.over


def test_over_the_cap_no_feedback_leaves_and_a_status_probes_backing_off() -> None:
    """Before, a feedback left as the probe (1.4 s old on arrival on the emulated LTE row)."""
    f = InFlight(gain=2.0, probe_s=1.0)
    _over(f, 10.0)
    t, fb, probes = 10.05, 0, []
    while t < 18.0:
        fb += f.admit_feedback(t)
        if f.admit_probe(t):
            probes.append(round(t, 2))
        t = round(t + 0.05, 2)
    assert fb == 0 and f.held["feedback"] > 0
    assert probes == [11.0, 13.0, 17.0], probes  # 1 s after the last acknowledgement, then 2, 4 s
    assert f.held["probes"] == 3 and f.held["status"] > 0


def test_the_echo_of_a_status_acknowledges_what_was_sent_before_it() -> None:
    f = InFlight(gain=2.0, probe_s=1.0)
    _over(f, 10.0)
    f.sent(11.0, 600)  # the probe, counted at its stamp
    f.sent(11.2, 400)  # sent after it: still in flight
    f.delivered(14.0, 11.0)
    assert f.bytes == 400
    f.delivered(14.1, 10.5)  # an older echo (reordered): nothing changes
    assert f.bytes == 400
    assert f.min_rtt_s == pytest.approx(0.1)  # an echo is no round-trip sample


def test_a_stall_holds_feedback_until_nothing_of_ours_waits_in_the_path() -> None:
    """In a stall the cap is one message (TCP's window after a timeout): a feedback leaves
    only when what is in flight was acknowledged, so it queues behind nothing of ours."""
    f = InFlight(gain=2.0, probe_s=1.0, min_bytes=100_000.0)
    f.acked(10.0, 9.9, 1_000_000.0)
    f.sent(10.0, 600)
    assert not f.over  # far under the cap
    f.hold = True
    assert f.over and not f.admit_feedback(10.1)
    f.delivered(10.2, 10.0)
    assert not f.over and f.admit_feedback(10.2)


def test_the_budget_takes_the_leaders_echo_and_ends_a_stall_on_fresh_feedback() -> None:
    now = [0.0]
    b = UplinkBudget(lambda: now[0])
    for k in range(100):  # a delivering path: feedback acknowledged 0.05 s after its send
        now[0] = 0.1 * k
        b.on_h2(0.04)
        b.sent(400, feedback=True)
        b.on_leader_status({"rx_bps": 500_000, "fb_age_ms": 50, "fb_loss_ppm": 0}, now[0])
        b.update()
    assert not b.stalled and not b.inflight.hold
    for k in range(100, 120):  # the uplink stops: the newest feedback ages
        now[0] = 0.1 * k
        b.on_h2(0.04)
        b.on_leader_status({"rx_bps": 0, "fb_age_ms": 50 + 100 * (k - 99), "fb_loss_ppm": 0}, now[0])
        b.update()
    assert b.stalled and b.inflight.hold
    b.sent(600, at=12.0)  # a probe, counted at its stamp
    now[0] = 12.5
    b.on_leader_status({"rx_bps": 10_000, "fb_age_ms": 2_550, "uplink_t_echo_us": 12_000_000}, now[0])
    assert b.inflight.bytes == 0 and b.inflight.admit_feedback(now[0])  # one feedback may go: it arrives fresh
    now[0] = 12.7
    b.on_leader_status({"rx_bps": 10_000, "fb_age_ms": 60, "uplink_t_echo_us": 12_000_000}, now[0])
    assert not b.stalled and not b.inflight.hold


def test_the_leader_echoes_the_newest_follower_status_stamp() -> None:
    link = LinkQuality(clock=lambda: 100.0)
    rep = link.report(100.0, follower_counters={"tx_bps": 1000, "uplink_t_us": 99_500_000})
    assert rep.status_echo_us == 99_500_000
    assert link_counters(rep)["uplink_t_echo_us"] == 99_500_000
    for bad in ({}, {"uplink_t_us": True}, None):
        rep = link.report(100.0, follower_counters=bad)
        assert rep.status_echo_us is None and "uplink_t_echo_us" not in link_counters(rep)
