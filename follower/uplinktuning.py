"""The parameters of the follower's uplink budget (:class:`~bipedtele.follower.capacity.UplinkBudget`).

The rules they tune are described in :mod:`bipedtele.follower.capacity`; the defaults are
the ones measured there (300 kbit/s to 4 Mbit/s uplinks, the shipped intercontinental trace).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

__all__ = ["UplinkTuning"]


@dataclass(frozen=True)
class UplinkTuning:
    """How :class:`~bipedtele.follower.capacity.UplinkBudget` judges the path (all floats).

    Attributes
    ----------
    window_s : float
        The leader's ``rx_bps`` window [s] (2 s).
    ratio : float
        Rate rule: limited when ``rx_bps < ratio * tx`` over the matching window [-].
    delay_rise_s, delay_hold_s : float
        Delay rule: h2 above its recent minimum by more than ``delay_rise_s`` [s] for more
        than ``delay_hold_s`` [s].
    h2_window_s : float
        Window of the h2 minimum [s].
    relearn_s : float
        A delay rise lasting this long [s] is the path's: the h2 minimum is taken again.
    decrease : float
        Multiplicative decrease of the capacity when a rate limit persists after a cut [-].
    increase_bps_per_s, increase_ratio : float
        Increase while not limited: ``max(increase_bps_per_s, increase_ratio * capacity)``
        per second [bit/s per s, 1/s].
    probe_gain : float
        The probe never takes the capacity above this times what is sent, plus
        ``floor_bps`` (BBR's probing gain): an estimate far above the sending rate was never
        tested [-].
    cut_gap_s : float
        Shortest time between two cuts of the delay rule [s] (also at least twice the
        excess: a cut shows in h2 one queue delay later).
    ceiling_probe : float
        Above ``drain_ratio`` of the rate the path carried at the last cut, the capacity
        grows by this share of itself per second only [1/s].
    hold_s : float
        Time between two cuts, and how long ``limited`` stays on after the last signal [s].
    min_tx_bps : float
        The rate rule is not judged below this sending rate [bit/s] (too few bytes).
    floor_bps : float
        The capacity estimate never goes below this [bit/s].
    margin, margin_min_bps : float
        Video's budget leaves ``max(margin * capacity, margin_min_bps)`` free [-, bit/s].
    control_share : float
        While limited, feedback uses at most this share of the capacity [-].
    status_timeout_s : float
        Without a leader status for this long [s] the capacity is not probed upward.
    drain_s : float
        Video's margin grows so that a queue of ``excess_s`` (h2 above its minimum) drains
        in about this long [s].
    drain_ratio : float
        On the rate rule's first signal the capacity is set to this share of what the
        leader received (below it, so that the queue the path built drains) [-].
    gap_s : float
        A silence of the commands longer than this [s] (an outage): the leader's figures
        are not judged until its window is past it (they count the silence, not the path).
    burst_s : float
        A video frame may hold the uplink this long at the estimated capacity [s]
        (``frame_bits_max``).
    part_s : float
        A video message (a part of a frame, paced) holds it this long at most [s]
        (``part_bits_max``).
    start_bps, start_max_bps, start_growth : float
        Video's budget at the start, multiplied by ``start_growth`` every second until a
        signal or until it passes ``start_max_bps`` [bit/s, bit/s, 1/s].
    start_s : float
        After this long [s] of clear path in the start, the capacity is taken as 1.2 x
        what is sent (then probed as after a cut).
    undo_gap_s : float
        A cut is undone at most once in this long [s]: a rise that comes back soon after
        an undo, at the rate the undo restored, is a queue of ours.
    base_window_s, queue_target_s, queue_decrease : float
        The standing-queue rule: the capacity is probed only while the echo's one-way
        delay (its least over 1 s; h2 where no echo comes or on a lossy path) is within
        ``queue_target_s`` [s] of its minimum over ``base_window_s`` [s] (the probe slows
        as it nears it), and above it, against a known ceiling, the capacity steps down by
        ``queue_decrease`` of itself per second [1/s], not below 0.8 x the ceiling.
    stall_s : float
        The path is stalled when the leader's newest feedback is older than h2's minimum
        over ``base_window_s`` by more than this [s]: video pauses, feedback drops to
        ``stall_fb_hz``, and the capacity restarts from what the path delivered before.
    stall_fb_hz : float
        Feedback rate while stalled [Hz] (the newest only: no acknowledgement per command).
    inflight_gain, inflight_min_bytes, probe_s : float
        The in-flight cap (:class:`~bipedtele.follower.delivery.InFlight`): its gain over
        the bandwidth-delay product [-], its least value [bytes], and over it, with no
        acknowledgement advancing for ``probe_s`` [s], one feedback as a probe (backing off x2).
    inflight_release_s : float
        No command taken and no leader Status for this long [s]: nobody acknowledges (the
        leader left, or the whole path is down), and the cap is released until a leader
        acknowledges again (a new leader gets feedback at once, not at the probes' pace).
    video_queue_s : float
        Video waits while the leader's last acknowledgement showed the round trip this much
        [s] above its minimum (the path's queue, one status period late).
    delivery_window_s : float
        The delivery rate's maximum is kept this long [s] of time the path delivered: the
        echo rule's floor, longer than its cycle (on the 3G row a cut every 10 s or so, each
        probed back: with 10 s the floor forgot the rate before the last cut, 235 -> 161
        kbit/s in four cuts). The in-flight cap and the restart after a stall read the same
        maximum.
    owd_queue_s : float
        Video waits while the feedback's one-way delay, echoed by each command, is this
        much [s] above its minimum (:class:`~bipedtele.follower.owdqueue.OneWayQueue`): with
        a video part holding the path at most ``part_s``, the feedback waits under 50 ms.
    slotted_s : float
        A link whose own waits (:meth:`~bipedtele.follower.owdqueue.OneWayQueue.noise_s`, the
        echo's queue's upper quartile over 30 s while video's valve was open) are at least
        this [s] delivers in slots and its capacity moves with them: a lone closing of the
        valve is its dip, and no cut's ceiling slows the probe (on a smooth link both the
        echo rule's and the delay rule's do). Set between the classes the bench's recordings
        showed: 3G 8.3-10.3 ms, LTE 4.7-6.8 ms, the kernel's 600 kbit/s token bucket 0.7-1.0
        ms. On 3G a delay cut's hard ceiling held the estimate at 175 kbit/s for the last
        40 s of two runs, probed at 0.5 %/s.
    lossy_ppm : float
        With the leader's feedback loss at or above this [ppm], the rate rule does not
        judge (TCP's video slowed by loss arrives below what was sent whatever the path
        carries): the delay rule alone judges a lossy path.
    lossy_hold_s : float
        A path stays lossy this long [s] after a Status showed it: the leader's loss is over
        its last 2 s, and at 1 % loss one window in three of 100 feedback has none (the rate
        rule then judged TCP's loss-slowed video and cut: 12.8 frames/s against 17.5).
    """

    window_s: float = 2.0
    ratio: float = 0.85
    delay_rise_s: float = 0.05
    delay_hold_s: float = 0.25
    h2_window_s: float = 10.0
    relearn_s: float = 5.0
    decrease: float = 0.7
    increase_bps_per_s: float = 4_000.0
    increase_ratio: float = 0.03
    probe_gain: float = 1.25
    cut_gap_s: float = 0.5
    ceiling_probe: float = 0.005
    hold_s: float = 2.0
    min_tx_bps: float = 16_000.0
    floor_bps: float = 16_000.0
    margin: float = 0.1
    margin_min_bps: float = 8_000.0
    control_share: float = 0.6
    status_timeout_s: float = 5.0
    drain_s: float = 1.0
    drain_ratio: float = 0.9
    gap_s: float = 0.5
    burst_s: float = 0.06
    part_s: float = 0.015
    start_bps: float = 64_000.0
    start_max_bps: float = 4_000_000.0
    start_growth: float = 1.3
    start_s: float = 10.0
    undo_gap_s: float = 5.0
    base_window_s: float = 60.0
    queue_target_s: float = 0.015
    queue_decrease: float = 0.05
    stall_s: float = 0.5
    stall_fb_hz: float = 5.0
    delivery_window_s: float = 30.0
    inflight_gain: float = 2.0
    inflight_min_bytes: float = 4000.0
    probe_s: float = 1.0
    inflight_release_s: float = 0.5
    video_queue_s: float = 0.05
    lossy_ppm: float = 1000.0
    lossy_hold_s: float = 30.0
    owd_queue_s: float = 0.03
    slotted_s: float = 0.0025

    def __post_init__(self) -> None:
        for f in fields(self):  # ints given (4000) are kept as floats, as the budget computes
            object.__setattr__(self, f.name, float(getattr(self, f.name)))

    @classmethod
    def names(cls) -> frozenset[str]:
        """Return the parameters' names."""
        return frozenset(f.name for f in fields(cls))
