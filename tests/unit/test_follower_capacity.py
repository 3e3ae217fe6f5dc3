"""UplinkBudget (follower/capacity.py) on synthetic paths, with a fake clock.

A fluid model of the robot's uplink: what the follower sends enters a FIFO queue drained
at the path's capacity (none: infinite), a share ``loss`` is lost, the rest arrives after
the path's base delay h2(t) plus the queue's delay. The leader sums what arrives over 2 s
and sends ``rx_bps`` in its Status at 2 Hz (150 ms on the way back); each command (100 Hz)
carries the leader's h2 as the leader computes it: the mean delay (base + queue at the send)
of the feedback that arrived over the last second (a queue shows late in it). The follower sends feedback (380 B; 50 Hz plus an
acknowledgement per 100 Hz command unless coalesced), a status (600 B, 2 Hz), and video at
``min(want, budget)``.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable

import pytest
from bipedtele.follower.capacity import UplinkBudget
from bipedtele.follower.video import MIN_PART_BYTES
from bipedtele.link.delaymodels import parse_delay_model

pytestmark = pytest.mark.timeout(60)

FB_BYTES = 380
STATUS_BYTES = 600
DT = 0.01


class Sim:
    def __init__(
        self,
        cap_bps: float = math.inf,
        base_h2: Callable[[float], float] = lambda t: 0.18,
        loss: float = 0.0,
        video_want_bps: float = 800_000.0,
        reported_loss_ppm: int = 0,
        echo: bool = False,
    ) -> None:
        self.t = 1000.0
        self.echo = echo  # commands echo the newest feedback's stamps; video asks admit_video
        self.cap = cap_bps
        self.base_h2 = base_h2
        self.loss = loss
        self.rng = random.Random(1)
        self.want = video_want_bps
        self.reported_loss_ppm = reported_loss_ppm  # the feedback loss the leader reports [ppm]
        self.budget = UplinkBudget(lambda: self.t)
        self.queue_bits = 0.0
        self.arrivals: deque[tuple[float, float]] = deque()  # (arrival time, bits)
        self.in_flight: deque[tuple[float, float]] = deque()
        self.statuses: deque[tuple[float, dict[str, int], float]] = deque()  # (arrive, counters, t_sent)
        self.next_status = self.t
        self.next_fb = self.t
        self.next_st = self.t
        self.video_credit = 0.0
        self.parts: deque[tuple[float, int]] = deque()  # a frame's parts waiting for their pace: (due, bytes)
        self.first_arrival: float | None = None
        self.fb_delays: deque[tuple[float, float]] = deque()  # feedback on its way: (arrival, delay)
        self.h2_window: deque[tuple[float, float]] = deque()  # arrived in the last second
        self.log: list[dict[str, float]] = []

    def queue_s(self) -> float:
        return self.queue_bits / self.cap if math.isfinite(self.cap) else 0.0

    def send(self, nbytes: int, video: bool = False, feedback: bool = False) -> None:
        self.budget.sent(nbytes, video, feedback=feedback)
        if self.rng.random() >= self.loss:
            self.queue_bits += 8 * nbytes

    def _frame(self, nbytes: int, part_bits_max: float | None, pace_bps: float) -> None:
        """Send a frame as the program does: in parts of at most ``part_bits_max`` (600 bytes
        the least), each after the one before has left at ``pace_bps`` (follower/video.py)."""
        part = nbytes if part_bits_max is None else max(MIN_PART_BYTES, int(part_bits_max / 8))
        due = max(self.t, self.parts[-1][0] + 8 * self.parts[-1][1] / pace_bps) if self.parts else self.t
        while nbytes > 0:
            n = min(part, nbytes)
            self.parts.append((due, n))
            due += 8 * n / pace_bps if pace_bps > 0 else 0.0
            nbytes -= n

    def step(self) -> None:
        t, b = self.t, self.budget
        d = self.base_h2(t) + self.queue_s()  # a feedback sent now
        self.fb_delays.append((t + d, d))
        while self.fb_delays and self.fb_delays[0][0] <= t:
            self.h2_window.append(self.fb_delays.popleft())
        while self.h2_window and self.h2_window[0][0] <= t - 1.0:
            self.h2_window.popleft()
        if self.h2_window:  # the command of this period carries the leader's 1 s mean
            b.on_h2(sum(x for _, x in self.h2_window) / len(self.h2_window))
            if self.echo:  # and the newest feedback's send and receive times (h1 taken as 0)
                arrived, delay = self.h2_window[-1]
                b.on_echo((arrived - delay, arrived))
        plan = b.feedback_plan(50.0)
        if plan.ack_each_command:
            self.send(FB_BYTES, feedback=True)  # the acknowledgement of this command
        if t >= self.next_fb:
            self.next_fb += 1.0 / plan.rate_hz
            self.send(FB_BYTES, feedback=True)
        if t >= self.next_st:
            self.next_st += 0.5
            self.send(STATUS_BYTES)
        vb = b.video_budget_bps()
        rate = self.want if vb is None else min(self.want, vb)
        self.video_credit += rate * DT / 8
        largest = b.frame_bits_max()  # 10 kB frames, smaller where the uplink is slow
        frame = 10_000 if largest is None else max(1_000, min(10_000, round(largest / 8)))
        while self.video_credit >= frame:
            self.video_credit -= frame
            if not self.echo or b.admit_video(frame):  # a frame refused is dropped
                self._frame(frame, b.part_bits_max(), rate)
        while self.parts and self.parts[0][0] <= t:
            self.send(self.parts.popleft()[1], video=True)
        # the path
        out = self.queue_bits if not math.isfinite(self.cap) else min(self.queue_bits, self.cap * DT)
        self.queue_bits -= out
        if out:
            self.in_flight.append((t + self.base_h2(t), out))  # queued already
        while self.in_flight and self.in_flight[0][0] <= t:
            self.arrivals.append(self.in_flight.popleft())
        while self.arrivals and self.arrivals[0][0] < t - 2.0:
            self.arrivals.popleft()
        if self.first_arrival is None and self.arrivals:
            self.first_arrival = self.arrivals[0][0]
        if t >= self.next_status:  # the leader's status, 150 ms to the follower; rx once its window is warm
            self.next_status += 0.5
            counters = {"fb_loss_ppm": self.reported_loss_ppm, "fb_age_ms": 200}
            if self.first_arrival is not None and t - self.first_arrival >= 0.5:
                counters["rx_bps"] = round(sum(bits for _, bits in self.arrivals) / min(2.0, t - self.first_arrival))
            self.statuses.append((t + 0.15, counters, t))
        while self.statuses and self.statuses[0][0] <= t:
            _, counters, ts = self.statuses.popleft()
            b.on_leader_status(counters, ts)
        b.update()
        self.log.append(
            {
                "t": t,
                "tx": b.tx_bps(),
                "video_budget": -1.0 if vb is None else vb,
                "queue_s": self.queue_s(),
                "limited": float(b.limited),
                "cap": b.capacity_bps,
            }
        )
        self.t += DT

    def run(self, seconds: float) -> list[dict[str, float]]:
        n0 = len(self.log)
        for _ in range(round(seconds / DT)):
            self.step()
        return self.log[n0:]


def test_capped_at_300_kbit_s_with_video_wanting_800_the_budget_fits_under_the_cap_within_5_s() -> None:
    """Control alone (feedback with an acknowledgement per command) wants 466 kbit/s here:
    the queue must be caught by h2's growth, not by the leader's 2 s rate window (which let
    it reach 3.2 s at the start and 0.75 s in the sawtooth before)."""
    sim = Sim(cap_bps=300_000.0)
    first = sim.run(8.0)
    assert any(r["limited"] for r in first)
    assert max(r["queue_s"] for r in first) < 0.6, max(r["queue_s"] for r in first)
    # the leader's 1 s mean shows the queue after the cut at its peak: no undo (each undo
    # gave video back its start budget, and the queue came back: 15 in 38 s before)
    assert sim.budget.signals["undone"] == 0, sim.budget.signals
    settled = [r for r in first if r["t"] >= first[-1]["t"] - 1.0]
    assert all(r["tx"] < 300_000 for r in settled), max(r["tx"] for r in settled)
    rest = sim.run(30.0)
    # under the cap on average, the queue short, video on
    assert sum(r["tx"] for r in rest) / len(rest) < 300_000
    assert max(r["queue_s"] for r in rest) < 0.2, max(r["queue_s"] for r in rest)
    assert sum(r["queue_s"] for r in rest) / len(rest) < 0.06
    assert min(r["video_budget"] for r in rest[-1000:]) > 50_000
    # no frame holds the uplink longer than 60 ms
    largest = sim.budget.frame_bits_max()
    assert largest is not None and largest / 300_000 <= 0.07
    # control shrank while limited: no acknowledgement per command
    assert not sim.budget.feedback_plan(50.0).ack_each_command or not sim.budget.limited


def test_a_queue_standing_at_600_kbit_s_is_not_probed_into() -> None:
    """Issue 19: at 600 kbit/s with video, the probe past the ceiling crept on while the
    queue it built stood below the delay rule's 50 ms, which its 10 s minimum took in (the
    feedback's p99 stood 80-100 ms above video off). The standing-queue rule measures h2
    against its 60 s minimum: no probe while it stands 15 ms above it, and a step down
    toward the ceiling. Before it, this path queued up to 118 ms after the first 30 s."""
    sim = Sim(cap_bps=600_000.0)
    log = sim.run(120.0)
    late = [r for r in log if r["t"] >= log[0]["t"] + 30.0]
    assert max(r["queue_s"] for r in late) < 0.08, max(r["queue_s"] for r in late)
    assert min(r["video_budget"] for r in late) > 150_000  # video keeps a good part of the path


def test_the_echoed_one_way_delay_keeps_the_feedback_out_of_videos_queue() -> None:
    """Issue 33: h2, the leader's 1 s mean, shows a queue about 0.75 s late: on a 600 kbit/s
    path the start's growth queued the feedback up to 250 ms (3.5 % of this run over 50 ms),
    and on the kernel's token bucket each probe past its rate did so for one to two seconds
    (h2's p99 88-100 ms above video off). Each command's echo of the newest feedback shows
    the queue one command later: video waits while it is over 30 ms, and a queue that
    drains once it waits cuts the estimate. (Frames here leave whole, up to 60 ms of the
    path each once it is known: the program cuts them into 15 ms parts.) Before, 3.5 % of
    this run was over 50 ms; now under 2 %."""
    sim = Sim(cap_bps=600_000.0, echo=True)
    log = sim.run(90.0)
    queue = [r["queue_s"] for r in log]
    assert max(queue) < 0.03 + 0.06 + 0.01, max(queue)  # the valve's 30 ms and one whole frame
    assert sim.budget.signals["echo"] >= 1 and sim.budget.owd.rebased == 0, sim.budget.signals
    assert sum(q > 0.05 for q in queue) / len(queue) < 0.02
    late = [r for r in log if r["t"] >= log[0]["t"] + 15.0]
    assert sum(r["queue_s"] for r in late) / len(late) < 0.03  # no standing queue
    assert sum(r["tx"] for r in late) / len(late) > 0.7 * 600_000  # and the path stays used


def _slotted_h2(t: float) -> float:
    """A link that delivers in slots: 100 ms clear, 200 ms 15 ms slower, again [s]."""
    return 0.18 + (0.015 if t % 0.3 >= 0.1 else 0.0)


def test_after_an_echo_cut_on_a_slotted_link_the_probe_is_not_slowed_past_its_ceiling() -> None:
    """On a link that delivers in slots an echo cut's ceiling neither slows the probe nor holds
    frames under the capacity: a crossing costs a 30 ms queue now. On the LTE and 3G rows a
    dip of the link's own capacity set it, and the 0.5 %/s probe past it held video at 4-11
    frames/s for the rest of the run; frames held to it stayed at QVGA quality 48 (4.5 kB)
    with the estimate at 800 kbit/s."""
    sim = Sim(cap_bps=600_000.0, base_h2=_slotted_h2, echo=True)
    sim.run(30.0)
    assert sim.budget.signals["echo"] >= 1 and sim.budget.signals["delay"] == 0, sim.budget.signals
    ceiling = sim.budget.ceiling_bps
    assert ceiling is not None
    sim.cap = 1_200_000.0  # the path's capacity doubles
    log = sim.run(20.0)
    # probed at up to 3 %/s (0.5 %/s past a cut's ceiling: about +10 % in 20 s)
    assert log[-1]["cap"] > 1.3 * log[0]["cap"], (log[0]["cap"], log[-1]["cap"], sim.budget.signals)
    largest = sim.budget.frame_bits_max()
    assert sim.budget.ceiling_bps == ceiling and sim.budget.capacity_bps > 1.2 * ceiling
    assert largest == pytest.approx(sim.budget.capacity_bps * sim.budget.tuning.burst_s)


def test_after_an_echo_cut_on_a_smooth_link_the_probe_past_its_ceiling_is_slow() -> None:
    """Behind the kernel's 600 kbit/s token bucket (the path's own waits 0.7-1.0 ms) each
    crossing of the bucket's rate queued the feedback 30-50 ms until the echo cut; probed
    back at 3 %/s past the cut's ceiling it crossed again every 8 s or so (10-11 cuts in
    90 s), which made the p99 with video 45-50 ms over video off (goal 50). There the ceiling
    is a known rate: past 0.9 x it the probe goes at 0.5 %/s."""
    sim = Sim(cap_bps=600_000.0, echo=True)
    sim.run(30.0)
    echo_cuts = sim.budget.signals["echo"]
    assert echo_cuts >= 1 and sim.budget.signals["delay"] == 0, sim.budget.signals
    log = sim.run(30.0)
    assert sim.budget.signals["echo"] - echo_cuts <= 1, sim.budget.signals
    assert max(x["cap"] for x in log) < 1.1 * 600_000.0, max(x["cap"] for x in log)


def test_an_undone_delay_cut_gives_back_an_echo_cuts_soft_ceiling() -> None:
    """A delay cut's undo restores what the cut replaced: the capacity, the start's budget
    and the ceiling, and whether that ceiling was soft (an echo cut's on a link that delivers
    in slots: the probe past it is not slowed). Before, the undo left the echo's ceiling
    marked as the delay rule's: a step of the path's own delay after an echo cut slowed the
    probe to 0.5 %/s for good. Here the echo cut comes while the link delivers in slots, the
    step 35 s later on a smooth path (the delay cut's ceiling hard)."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    b.start_budget_bps, b.capacity_bps = None, 1_000_000.0  # past the start, probing
    ow = [0.02]  # the echoed feedback's one-way delay [s]
    slots = [0.01]  # the link's slot waits: 200 ms of every 300 this much slower [s]

    def h2(s: float) -> float:  # the path's delay steps +120 ms at 45 s (the 1 s mean ramps)
        return 0.18 + 0.12 * min(1.0, s - 45.0) if s >= 45.0 else 0.18

    def each(k: int) -> None:
        b.on_h2(h2(t[0]))
        slow = slots[0] if t[0] % 0.3 >= 0.1 else 0.0
        b.on_echo((t[0] - 0.05, t[0] - 0.05 + ow[0] + slow))
        b.sent(300, feedback=True)
        b.sent(int((b.video_budget_bps() or 0.0) * 0.01 / 8), video=True)
        if k % 50 == 0 and t[0] > 1.0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": 0, "fb_age_ms": 200}, t[0])

    _ticks(b, t, 1000, each)
    slots[0] = 0.0
    for _ in range(2):  # a queue of ours twice within a second (on a slotted link a lone one is a dip)
        for k in range(30):  # growing 0.2 s/s: video waits, and it drains
            ow[0] = 0.02 + 0.002 * (k + 1)
            _ticks(b, t, 1, lambda j, k=k: each(1000 + k))
        assert not b.admit_video(1000)
        ow[0] = 0.02
        _ticks(b, t, 20, lambda k: each(1030 + k))
    assert b.signals["echo"] == 1 and b.signals["delay"] == 0 and b.owd.dips == 1, b.signals
    _ticks(b, t, 3400, lambda k: each(1050 + k))  # to 45 s: a smooth path for 34 s
    _ticks(b, t, 1000, lambda k: each(4500 + k))  # the step: cut by the delay rule, then undone
    assert b.signals["delay"] == 1 and b.signals["undone"] == 1, b.signals
    before = b.capacity_bps
    _ticks(b, t, 1000, lambda k: each(5500 + k))
    # probed at up to 3 %/s past the echo's ceiling (0.5 %/s past a delay cut's: +5 % in 10 s)
    assert b.capacity_bps > 1.2 * before, (before, b.capacity_bps, b.ceiling_bps)


def _slow_rise(b: UplinkBudget, t: list[float], ow: list[float], each: Callable[[int], None]) -> None:
    """A rise of the echoed one-way delay ``ow[0]`` [s] at 0.2 s/s (as fast as a queue of
    ours grows), video waiting once it is over 30 ms, then drained (0.5 s in all)."""
    for k in range(30):
        ow[0] = 0.02 + 0.002 * (k + 1)
        _ticks(b, t, 1, lambda j, k=k: each(1000 + k))
    assert not b.admit_video(1000)
    ow[0] = 0.02
    _ticks(b, t, 20, lambda j: each(1030 + j))


def _echoing_budget(
    capacity_bps: float, rate: list[float], ow: list[float]
) -> tuple[UplinkBudget, list[float], Callable[[int], None]]:
    """A budget past the start at ``capacity_bps``, a tick's sending at ``rate[0]`` [bit/s], its
    commands echoing a one-way delay of ``ow[0]`` [s], the leader's status every 0.5 s."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    b.start_budget_bps, b.capacity_bps = None, capacity_bps

    def each(k: int) -> None:
        b.on_h2(0.18)
        b.on_echo((t[0] - 0.05, t[0] - 0.05 + ow[0]))
        b.sent(int(rate[0] * 0.01 / 8), video=True)
        if k % 50 == 0 and t[0] > 1.0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": 0, "fb_age_ms": 200}, t[0])

    return b, t, each


def test_an_echo_cut_keeps_what_the_path_delivered_lately() -> None:
    """An echo cut takes the capacity to 0.9 x what was sent, not below 0.9 x what the path
    delivered in its last 30 s of delivering (``DeliveryRate``): video waiting out the
    path's queues sends less, and on the 3G row cuts to 0.9 x what was sent took the
    estimate 235 -> 136 kbit/s in four cuts on a link carrying 500-650."""
    ow, rate = [0.02], [400_000.0]
    b, t, each = _echoing_budget(400_000.0, rate, ow)
    _ticks(b, t, 500, each)  # 5 s delivering 400 kbit/s
    rate[0] = 200_000.0  # then sending half that
    _ticks(b, t, 300, each)
    assert b.delivery.max_bps == pytest.approx(400_000.0, rel=0.02) and b.tx_bps() == pytest.approx(200_000.0, rel=0.02)
    _slow_rise(b, t, ow, each)
    assert b.signals["echo"] == 1, b.signals
    assert b.capacity_bps == pytest.approx(0.9 * 400_000.0, rel=0.02), b.capacity_bps  # not 0.9 x 200 kbit/s


def test_an_echo_cut_keeps_what_the_path_delivered_before_the_last_cuts() -> None:
    """What the path delivered is kept 30 s of delivering (``delivery_window_s``), longer than
    the echo rule's cycle: on the 3G row a cut came every 10 s or so, each probed back, and
    with 10 s the floor had forgotten the rate before the last cut (235 -> 194 -> 182 -> 170
    -> 161 kbit/s in four cuts over 45 s, on a link carrying 340-1,060 kbit/s in every second
    outside its gap). Here 15 s of sending half what was delivered before: still the floor."""
    ow, rate = [0.02], [400_000.0]
    b, t, each = _echoing_budget(400_000.0, rate, ow)
    _ticks(b, t, 500, each)  # 5 s delivering 400 kbit/s
    rate[0] = 200_000.0  # then 15 s sending half that (video waiting out the path's queues)
    _ticks(b, t, 1500, each)
    _slow_rise(b, t, ow, each)
    assert b.signals["echo"] == 1, b.signals
    assert b.capacity_bps == pytest.approx(0.9 * 400_000.0, rel=0.02), b.capacity_bps  # not 0.9 x 200 kbit/s


def test_a_lone_slow_rise_under_the_last_cuts_ceiling_is_the_paths_dip() -> None:
    """After an echo cut the estimate is under what the path carried at it: a lone rise
    there, however slow, is the path's (a queue of ours needs more sent than the path
    carried), waited out and not cut; past that ceiling a lone slow rise is a crossing of a
    known rate (a token bucket's) and is cut. On the 3G row the trace's slow rises cut the
    estimate 6 times in 90 s while only rises faster than 0.5 s/s were dips."""
    ow, rate = [0.02], [400_000.0]
    b, t, each = _echoing_budget(450_000.0, rate, ow)
    _ticks(b, t, 500, each)
    _slow_rise(b, t, ow, each)  # no ceiling yet: a queue of ours
    assert b.signals["echo"] == 1 and b.ceiling_bps is not None and b.capacity_bps < b.ceiling_bps, b.signals
    _ticks(b, t, 150, each)  # 1.5 s: alone again, the estimate still under the ceiling
    _slow_rise(b, t, ow, each)
    assert b.signals["echo"] == 1 and b.owd.dips == 1, (b.signals, b.owd.counters())
    b.capacity_bps = 1.1 * b.ceiling_bps  # probed past it
    _ticks(b, t, 150, each)
    _slow_rise(b, t, ow, each)
    assert b.signals["echo"] == 2 and b.owd.dips == 1, (b.signals, b.owd.counters())


def test_a_lone_dip_of_the_path_is_waited_out_not_cut() -> None:
    """A rise of the echoed one-way delay by 60 ms between two feedback (a cellular link's
    scheduling gap: a queue of ours cannot grow that fast) closes the valve, and video waits
    it out; the estimate stays. Before, each such dip cut it to 0.9 of what was sent (about
    0.8 of it), a ratchet on the 3G and LTE rows."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    b.start_budget_bps, b.capacity_bps = None, 1_000_000.0  # past the start
    ow = [0.02]  # the echoed feedback's one-way delay [s]

    def each(k: int) -> None:
        b.on_h2(0.18)
        b.on_echo((t[0] - 0.05, t[0] - 0.05 + ow[0]))
        b.sent(300, feedback=True)
        if b.admit_video(1000):
            b.sent(int((b.video_budget_bps() or 0.0) * 0.01 / 8), video=True)
        if k % 50 == 0 and t[0] > 1.0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": 0, "fb_age_ms": 200}, t[0])

    _ticks(b, t, 1000, each)
    found = b.capacity_bps
    ow[0] = 0.08
    _ticks(b, t, 10, lambda k: each(1000 + k))
    ow[0] = 0.02
    _ticks(b, t, 100, lambda k: each(1010 + k))
    assert b.owd.held > 0 and b.signals["echo"] == 0 and b.capacity_bps >= found, (b.owd.counters(), b.signals)
    assert b.owd.dips == 1


def test_uncapped_never_throttles() -> None:
    """Video's budget grows x1.3 a second from 64 kbit/s while it is used, then never binds
    (always at least what video wants)."""
    sim = Sim()
    start = sim.run(25.0)  # the start, and its end (1.2 x what is sent, probed up at 3 %/s)
    assert start[0]["video_budget"] == 64_000 and all(not r["limited"] for r in start)
    log = sim.run(30.0)
    assert all(not r["limited"] and (r["video_budget"] == -1.0 or r["video_budget"] >= 800_000) for r in log)
    assert sim.budget.feedback_plan(50.0) == sim.budget.feedback_plan(50.0).__class__(True, 50.0)
    assert sim.budget.tx_bps() > 800_000


def test_the_probe_stays_within_a_quarter_of_what_is_sent() -> None:
    """Video wanting 150 kbit/s on an uncapped path: the estimate grows only near what is
    sent (BBR's probing gain, 1.25). At twice what is sent it grew untested to 30 % over a
    600 kbit/s token bucket, and an acknowledgement per command (a step of control) then
    queued the feedback 100-200 ms."""
    sim = Sim(video_want_bps=150_000.0)
    log = sim.run(60.0)
    tx = sim.budget.tx_bps()
    assert sim.budget.capacity_bps <= 1.25 * max(r["tx"] for r in log) + 16_000.0, (sim.budget.capacity_bps, tx)
    assert log[-1]["video_budget"] >= 150_000.0  # video still gets what it wants


def test_one_percent_random_loss_alone_does_not_throttle() -> None:
    sim = Sim(loss=0.01)
    log = sim.run(40.0)
    assert not any(r["limited"] for r in log) and sim.budget.signals["rate"] == sim.budget.signals["delay"] == 0
    assert log[-1]["video_budget"] == -1.0 or log[-1]["video_budget"] > 800_000


@pytest.mark.parametrize("which", ["sine", "shipped"])
def test_slow_delay_swings_alone_do_not_turn_video_off(which: str) -> None:
    """+-200 ms over 10 s (a 20 s sine), and the shipped trace's h2: video keeps most of its rate."""
    if which == "sine":
        base = lambda t: 0.38 + 0.2 * math.sin(2 * math.pi * t / 20.0)  # noqa: E731
    else:
        model = parse_delay_model("trace:intercontinental:h2")
        base = lambda t: model.delay_s(t - 1000.0)  # noqa: E731
    sim = Sim(base_h2=base)
    sim.run(20.0)  # the start
    log = sim.run(100.0)
    budgets = [r["video_budget"] for r in log]
    known = [v for v in budgets if v >= 0]
    # the sine's rises (0.4 s in 10 s) each cost one cut to 0.9 of the rate sent; the
    # shipped trace's one step (+80 ms for 3 s) one cut, then probing back. Both hold the
    # probe while h2 stands above its 60 s minimum (the standing-queue rule), so the rate
    # sent at the one cut is lower: the shipped trace's budget dipped to 177 kbit/s there
    # (over 400 kbit/s before that rule); on the real path the trace's video kept 18 fps
    floor = 100_000
    assert not known or min(known) > floor, min(known)
    video = [max(0.0, min(800_000.0, v if v >= 0 else 800_000.0)) for v in budgets]
    assert sum(video) / len(video) > 400_000
    sent_video = sim.budget.tx_bps("video")
    assert sent_video > 400_000


def _ticks(b: UplinkBudget, t: list[float], n: int, each: Callable[[int], None]) -> None:
    """Run ``n`` ticks of 10 ms on the budget's clock ``t``: advance it, feed the tick
    (``each(k)``: commands, what is sent, the leader's status), then ``b.update()``."""
    for k in range(n):
        t[0] += 0.01
        each(k)
        b.update()


def test_without_the_leaders_status_nothing_is_cut() -> None:
    """No leader status: nothing could undo a cut (probing needs it), so h2 alone cuts nothing."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    for _ in range(800):
        b.sent(10_000, video=True)
        b.on_h2(0.2 if t[0] < 2 else 2.0)
        b.update()
        t[0] += 0.01
    assert math.isinf(b.capacity_bps) and not b.limited and b.signals["delay"] == 0


def test_bad_leader_figures_are_ignored() -> None:
    t = [10.0]
    b = UplinkBudget(lambda: t[0])
    b.on_h2(float("nan"))
    b.on_h2(-1.0)
    b.on_leader_status({"rx_bps": True, "fb_age_ms": 3})  # a bool is no rate
    assert math.isinf(b.capacity_bps) and b.leader == {"fb_age_ms": 3}


def test_an_outage_is_not_taken_for_a_full_path() -> None:
    """After 3 s without commands (a router restart), the leader's next windows count the
    silence (rx far below what was sent before it): the budget does not cut the capacity."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])

    def run(seconds: float, rx_bps: int | None) -> None:
        def each(k: int) -> None:
            b.on_h2(0.05)
            b.sent(500, feedback=True)  # 400 kbit/s of feedback
            if abs(t[0] % 0.5) < 0.01 and rx_bps is not None:
                b.on_leader_status({"rx_bps": rx_bps, "fb_loss_ppm": 0, "fb_age_ms": 50})

        _ticks(b, t, round(seconds / 0.01), each)

    run(12.0, 400_000)
    assert not b.limited and b.capacity_bps >= 1.2 * 400_000  # after the start: 1.2 x what is sent
    t[0] += 3.0  # the outage: nothing in, nothing out
    run(0.6, 40_000)  # the leader's first statuses after it: its 2 s window holds the silence
    run(5.0, 400_000)
    assert b.capacity_bps >= 1.2 * 400_000 and not b.limited, (b.capacity_bps, b.signals)
    assert b.signals["rate"] == b.signals["delay"] == 0


def _known_path(capacity_bps: float, fb_bytes: int) -> UplinkBudget:
    """A budget past the start with the path known at ``capacity_bps``, after 3 s of a command every 10 ms and a ``fb_bytes`` feedback every 20 ms."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    b.start_budget_bps, b.capacity_bps = None, capacity_bps

    def each(k: int) -> None:
        b.on_h2(0.05)
        if k % 2 == 0:
            b.sent(fb_bytes, feedback=True)

    _ticks(b, t, 300, each)
    return b


def test_video_leaves_control_what_the_feedback_plan_sends_not_its_2_s_mean() -> None:
    """When the plan steps to an acknowledgement per command, control's measured rate (a
    2 s mean) still shows the periodic feedback alone. Video's budget leaves the planned
    rate: before, video kept the difference for 2 s on top of control's step, and on a
    600 kbit/s token bucket the feedback queued 50-100 ms for a second."""
    b = _known_path(1_000_000.0, 200)
    plan = b.feedback_plan(50.0)
    assert plan.ack_each_command  # 150 feedback/s fit 0.6 of 1 Mbit/s
    planned = plan.control_bps(100.0, 1600.0)
    assert planned == pytest.approx(240_000.0) and b.tx_bps("control") == pytest.approx(80_000.0, rel=0.05)
    vb = b.video_budget_bps()
    assert vb is not None and vb <= 1_000_000.0 - 0.98 * planned - 100_000.0, vb


def test_acknowledgements_at_once_take_only_what_video_at_its_most_leaves() -> None:
    """An acknowledgement sent at once, beyond the periodic feedback, comes after video: on
    a 600 kbit/s token bucket the coalesced plan's acknowledgements filled 60 % of the
    estimate (control 160 -> 320 kbit/s as the probe grew it), video's budget fell to 10
    frames/s and the step queued the feedback. The periodic feedback keeps priority."""
    b = _known_path(700_000.0, 380)
    alone = b.feedback_plan(50.0)  # no video: acknowledgements fill 60 % of the estimate
    assert not alone.ack_each_command and alone.min_interval_s < 0.01, alone
    plan = b.feedback_plan(50.0, video_bps=500_000.0)  # 2 cameras x 10 frames/s x 3.1 kB
    assert plan.rate_hz == 50.0 and plan.min_interval_s == pytest.approx(0.02), plan
    assert b.video_budget_bps() == pytest.approx(700_000.0 - 50 * 3040.0 - 70_000.0, rel=0.03)
    b.capacity_bps = 1_200_000.0  # room for both: every command acknowledged at once again
    assert b.feedback_plan(50.0, video_bps=464_000.0).ack_each_command


def test_feedback_above_25_hz_takes_at_most_half_of_what_the_margin_leaves() -> None:
    """The periodic feedback keeps priority over video up to 25 Hz; a rate above it shares the
    path with video. On the 3G row 50 Hz fitted 0.6 of an estimate of 253 kbit/s: control
    went from 90 to 164 kbit/s and video's budget from 129 to 75 kbit/s (12 to 7.5-8
    frames/s) as the estimate rose."""
    b = _known_path(266_000.0, 380)  # a feedback of 3040 bits: 50 Hz is 152 kbit/s
    plan = b.feedback_plan(50.0, video_bps=500_000.0)
    assert plan.rate_hz == 25.0 and not plan.ack_each_command, plan  # 152 > (266 - 26.6) / 2
    b.capacity_bps = 400_000.0
    assert b.feedback_plan(50.0, video_bps=500_000.0).rate_hz == 50.0  # 152 <= (400 - 40) / 2
    b.capacity_bps = 160_000.0
    assert b.feedback_plan(50.0, video_bps=500_000.0).rate_hz == 25.0  # the floor keeps 0.6 of it


def _step_under_loss(loss_ppm: int, every: int = 1) -> tuple[float, float, dict[str, int]]:
    """A path whose delay steps +120 ms at 30 s and back at 33 s, as the leader's 1 s mean
    shows it (a ramp over 1 s), TCP's video arriving at 60 % of what is sent when loss
    slows it, the leader's status every 0.5 s (the loss in one of ``every``, 0 in the
    others): return the capacity before the step and 8 s after it, and the rules' counts."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    b.start_budget_bps, b.capacity_bps = None, 1_000_000.0  # past the start, probing

    def h2(s: float) -> float:
        if 30.0 <= s < 33.0:
            return 0.18 + 0.12 * min(1.0, s - 30.0)
        return 0.30 - 0.12 * (s - 33.0) if 33.0 <= s < 34.0 else 0.18

    def each(k: int) -> None:
        b.on_h2(h2(t[0]))
        b.sent(300, feedback=True)
        b.sent(int((b.video_budget_bps() or 0.0) * 0.01 / 8), video=True)
        if k % 50 == 0 and t[0] > 1.0:
            rx = round(0.6 * b.tx_bps()) if loss_ppm else round(b.tx_bps())
            shown = loss_ppm if (k // 50) % every == 0 else 0
            b.on_leader_status({"rx_bps": rx, "fb_loss_ppm": shown, "fb_age_ms": 200}, t[0])

    _ticks(b, t, 2991, each)
    before = b.capacity_bps  # at 29.9 s, before the step
    _ticks(b, t, 809, lambda k: each(2991 + k))
    return before, b.capacity_bps, dict(b.signals)


def test_a_step_of_the_paths_delay_under_loss_is_not_taken_for_a_full_path() -> None:
    """With 1 % loss the rate rule took the step for a queue and the loss-slowed rate for the
    capacity: it cut to what arrived and set its ceiling there (the bench's 1 % loss row:
    9.9 and 7.8 frames/s against 16.0 without loss), also when judged only after the delay
    rule's cut (the 1 s mean goes on rising after it). On a lossy path the delay rule alone
    judges: the step is its cut's undo."""
    before, after, signals = _step_under_loss(10_000)
    assert signals["rate"] == 0 and signals["delay"] == 1 and signals["undone"] == 1, signals
    assert after >= before, (after, before)
    clean = _step_under_loss(0)  # without loss: the same verdict
    assert clean[2]["undone"] == 1 and clean[1] >= clean[0], clean


def test_a_path_stays_lossy_between_the_leaders_windows_that_show_no_loss() -> None:
    """The leader's loss is over its last 2 s: at 1 % loss one window in three of 100
    feedback has none, and the rate rule then judged TCP's loss-slowed video (bench, trace +
    1 % loss, seed 3: one rate cut to 334 kbit/s, 12.8 frames/s against 17.5 without
    loss). Here two statuses in three show no loss."""
    before, after, signals = _step_under_loss(10_000, every=3)
    assert signals["rate"] == 0 and after >= before, (signals, after, before)


def test_a_full_lossy_path_is_still_cut() -> None:
    """300 kbit/s with 1 % loss reported by the leader: the delay rule cuts, and the queue
    stays short (loss does not hide a full path)."""
    sim = Sim(cap_bps=300_000.0, loss=0.01, reported_loss_ppm=10_000)
    sim.run(8.0)
    rest = sim.run(30.0)
    assert sim.budget.signals["delay"] >= 1
    assert sum(r["tx"] for r in rest) / len(rest) < 300_000
    assert max(r["queue_s"] for r in rest) < 0.2, max(r["queue_s"] for r in rest)


def test_the_start_takes_the_most_the_path_carried_not_a_dip_at_its_end() -> None:
    """A clear start sending 400 kbit/s, then 200 for its last 3 s (TCP's video slowed by
    loss sends less): the capacity is taken from the 400 the path carried. From what was
    sent at the start's end (a dip), the 5 % loss row's start took 383 kbit/s where 370
    had been sent 4 s before with h2 clear, and its video ran 18 % under the loss-free
    run's (13.5 against 16.5 frames/s)."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])

    def each(k: int) -> None:  # a command every 10 ms, h2 clear
        b.on_h2(0.05)
        b.sent(500 if t[0] < 7.0 else 250)  # 400 kbit/s, then 200
        if k % 50 == 0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": 0, "fb_age_ms": 50})

    _ticks(b, t, 1200, each)  # 12 s
    assert b.start_budget_bps is None and math.isfinite(b.capacity_bps)  # the start is over
    assert b.capacity_bps >= 1.2 * 390_000, b.capacity_bps


def _start_with_video_climbing(most_bps: float | None) -> UplinkBudget:
    """A clear start sending 160 kbit/s of control, video 250 kbit/s (climbing its levels,
    whatever the budget) for 12 s and then what the start's budget offers up to 600 kbit/s;
    ``most_bps``: video's most as the budget is told it. Return the budget as the start ends
    (16 s at most)."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])

    def each(k: int) -> None:
        b.on_h2(0.05)
        b.sent(200, feedback=True)
        video = 250_000.0 if t[0] < 12.0 else min(600_000.0, b.video_budget_bps() or 600_000.0)
        b.sent(round(video * 0.01 / 8), video=True)
        if k % 50 == 0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": 0, "fb_age_ms": 50})

    for k in range(1600):
        t[0] += 0.01
        each(k)
        b.update(most_bps)
        if math.isfinite(b.capacity_bps):
            break
    assert b.start_budget_bps is None and math.isfinite(b.capacity_bps)  # the start is over
    return b


def test_the_start_waits_for_video_to_send_what_it_offers() -> None:
    """The 5 % loss row (seed 2): video, climbing its levels, sent 270 of the 524 kbit/s the
    start offered when its 10 s of clear path ended; the capacity taken from that peak left
    video 344 kbit/s, 9.5-14 frames/s for 30 s against 17-20 in the loss-free run. With
    video's most known, the start goes on until video sends what it is offered (BBR's
    application-limited rule), and takes the capacity from what the path then carried."""
    told, blind = _start_with_video_climbing(600_000.0), _start_with_video_climbing(None)
    assert blind.capacity_bps == pytest.approx(1.2 * 410_000 + blind.floor_bps, rel=0.05)  # the old take
    assert told.capacity_bps >= 1.2 * (160_000 + 0.8 * 600_000), told.capacity_bps  # video sent 0.8 of its most


def test_the_start_takes_the_capacity_after_twice_its_time_if_video_never_sends_its_offer() -> None:
    """Video that never sends what it is offered (a camera slower than configured) does
    not keep the start open: after twice ``start_s`` of clear path the capacity is taken."""
    b = _start_under(0, most_bps=2_000_000.0)
    assert b.capacity_bps == pytest.approx(1.2 * 360_000 + b.floor_bps, rel=0.05)


def _start_under(loss_ppm: int, most_bps: float | None = None) -> UplinkBudget:
    """A clear start (h2 flat) sending 160 kbit/s of control and 200 of video whatever the
    budget, the leader reporting ``loss_ppm`` of feedback loss, video's most ``most_bps``
    [bit/s] as the budget is told it (None: not). Return the budget after 22 s or the start."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])

    def each(k: int) -> None:
        b.on_h2(0.05)
        b.sent(200, feedback=True)
        b.sent(250, video=True)
        if k % 50 == 0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": loss_ppm, "fb_age_ms": 50})

    for k in range(1200 if most_bps is None else 2300):  # 12 s, or 23 s
        t[0] += 0.01
        each(k)
        b.update(most_bps)
    assert b.start_budget_bps is None and math.isfinite(b.capacity_bps)  # the start is over
    return b


def test_on_a_lossy_path_the_start_takes_what_was_sent_too() -> None:
    """Taking the start's budget with control's rate on a path the leader reports lossy (so
    that TCP's loss-slowed video would not set the capacity) was tried: behind the kernel's
    600 kbit/s token bucket one feedback lost at 6.5 s made the path lossy, the start took
    1,050 kbit/s (its budget, about twice what was sent, with control) and queued the
    bucket 112-134 ms until the delay rule cut, the row's p99 55 ms against 2 with video
    off. A path with loss takes 1.2 x the most sent, as one without."""
    lossy, clean = _start_under(50_000), _start_under(0)
    assert lossy.lossy
    assert lossy.capacity_bps == pytest.approx(clean.capacity_bps, rel=0.01), (lossy.capacity_bps, clean.capacity_bps)
    assert clean.capacity_bps == pytest.approx(1.2 * 360_000 + clean.floor_bps, rel=0.05)  # what was sent


def _standing_run(echo_owd_s: Callable[[float], float]) -> UplinkBudget:
    """5 s of an idle path (h2 40 ms), then 30 s sending video at its budget with h2 at 58 ms
    (the 3G row: a link's slots make each feedback wait longer as more is sent); the echoed
    feedback's one-way delay is ``echo_owd_s(t)`` [s]. Return the budget."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    b.start_budget_bps, b.capacity_bps = None, 150_000.0  # past the start
    sending = [False]

    def each(k: int) -> None:
        b.on_h2(0.058 if sending[0] else 0.040)
        b.on_echo((t[0] - 0.05, t[0] - 0.05 + echo_owd_s(t[0])))
        if sending[0]:
            b.sent(300, feedback=True)
            b.sent(int((b.video_budget_bps() or 0.0) * 0.01 / 8), video=True)
        if k % 50 == 0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": 0, "fb_age_ms": 200}, t[0])

    _ticks(b, t, 500, each)
    sending[0] = True
    _ticks(b, t, 3000, each)
    return b


def test_the_standing_queue_is_the_echos_not_h2_over_the_idle_paths() -> None:
    """The 3G row: h2 came to 39-42 ms with nothing sent (before video, after a stall) and
    stood at 55-60 ms at a fifth of the link while the echo showed 2-8 ms of queue. Against
    the idle h2 the standing queue read 15-20 ms, over its 15 ms target, and held the probe
    (147 kbit/s for the last 40 s of a run on a link carrying 500-650). The fresh echo's
    one-way delay over its 60 s minimum shows no standing queue: the probe goes on. One that
    stands 20 ms above it (under the valve's 30 ms) still holds the probe."""
    clear = _standing_run(lambda t: 0.02)
    assert clear.standing_s == pytest.approx(0.0, abs=1e-9)
    assert clear.capacity_bps > 1.5 * 150_000.0, (clear.capacity_bps, clear.signals)
    queued = _standing_run(lambda t: 0.02 if t < 5.0 else 0.04)
    assert queued.standing_s == pytest.approx(0.02)
    # held once the queue has stood for the standing queue's hold (1 s of the probe's 3 %/s)
    assert queued.capacity_bps < 1.02 * 150_000.0, (queued.capacity_bps, queued.signals)


def _lossy_probe(wait_s: float) -> UplinkBudget:
    """19.5 s past the start at 300 kbit/s on a path the leader reports 5 % lossy, h2 flat; 1.5 s
    of each 2 the echoed feedback waits ``wait_s`` [s] longer (behind retransmissions, chained
    longer than the standing queue's 1 s hold, which takes shorter ones out)."""
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    b.start_budget_bps, b.capacity_bps = None, 300_000.0  # past the start

    def each(k: int) -> None:
        b.on_h2(0.2)
        b.on_echo((t[0] - 0.2, t[0] + (wait_s if k % 200 < 150 and t[0] > 1.0 else 0.0)))
        b.sent(int((b.video_budget_bps() or 0.0) * 0.01 / 8), video=True)
        b.sent(400, feedback=True)
        if k % 50 == 0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": 50_000, "fb_age_ms": 250})

    _ticks(b, t, 1950, each)  # 19.5 s, ending 1.5 s into a wait
    return b


def test_on_a_lossy_path_the_standing_queue_reads_h2_not_the_echo() -> None:
    """5 % loss on TCP: each feedback behind a lost segment waits a round trip for its
    retransmission, in order, so three echoes in a row often carry 100-300 ms of wait that
    is no queue. Read on the echo, the standing queue held the 5 % loss row's probe (0.6 %/s
    against 1.1 %/s on h2). The standing queue's 1 s hold takes out waits shorter than it;
    chained longer, with the leader reporting the loss, h2 (flat here) judges them: the
    probe climbs as with no wait in the echo."""
    lossy, clean = _lossy_probe(0.02), _lossy_probe(0.0)  # 20 ms: under the valve, over the target
    assert lossy.lossy and lossy.owd.standing_s > 0.015  # the echo reads the waits as a standing queue
    assert lossy.standing_s == pytest.approx(0.0, abs=1e-9)
    assert lossy.capacity_bps >= 0.95 * clean.capacity_bps, (lossy.capacity_bps, clean.capacity_bps)


def _delay_cut_then_probe(wait_s: float) -> tuple[UplinkBudget, float]:
    """A budget past the start at 1 Mbit/s whose commands echo a link's slots (200 ms of every
    300 ``wait_s`` [s] slower), h2 rising 0.2 s/s for 0.75 s (a queue of ours) and draining;
    return it 10 s after the delay rule's cut, and the capacity the cut left [bit/s]."""
    t, h2 = [0.0], [0.18]
    b = UplinkBudget(lambda: t[0])
    b.start_budget_bps, b.capacity_bps = None, 1_000_000.0

    def each(k: int) -> None:
        b.on_h2(h2[0])
        slow = wait_s if t[0] % 0.3 >= 0.1 else 0.0
        b.on_echo((t[0] - 0.05, t[0] - 0.03 + slow))
        b.sent(300, feedback=True)
        b.sent(int((b.video_budget_bps() or 0.0) * 0.01 / 8), video=True)
        if k % 50 == 0 and t[0] > 1.0:
            b.on_leader_status({"rx_bps": round(b.tx_bps()), "fb_loss_ppm": 0, "fb_age_ms": 200}, t[0])

    _ticks(b, t, 1500, each)
    for k in range(75):
        h2[0] = 0.18 + 0.002 * (k + 1)
        _ticks(b, t, 1, lambda j, k=k: each(1500 + k))
    h2[0] = 0.18
    _ticks(b, t, 100, lambda k: each(1575 + k))
    assert b.signals["delay"] == 1 and b.signals["undone"] == 0 and b.signals["echo"] == 0, b.signals
    cut = b.capacity_bps
    _ticks(b, t, 1000, lambda k: each(1675 + k))
    return b, cut


def test_a_delay_cut_on_a_link_that_delivers_in_slots_leaves_a_soft_ceiling() -> None:
    """On the 3G row a delay cut's ceiling (the rate sent when the trace's slow second came)
    held the estimate at 175 kbit/s for the last 40 s of two runs, probed at 0.5 %/s past
    0.9 x it, on a link carrying 340-1,060 kbit/s in every second outside its gap. Where the
    echo's own waits (its queue's upper quartile, video's valve open) are slotted_s (2.5 ms) or
    more, the link delivers in slots and its capacity moves with them: the ceiling is soft and
    the probe goes on at up to 3 %/s. On a link that delivers smoothly (the kernel's token
    bucket: 0.7-1.0 ms) the ceiling stays hard."""
    slotted, cut = _delay_cut_then_probe(0.01)
    assert slotted.capacity_bps > 1.15 * cut, (cut, slotted.capacity_bps, slotted.ceiling_bps)
    smooth, cut = _delay_cut_then_probe(0.0)
    assert smooth.capacity_bps < 1.1 * cut, (cut, smooth.capacity_bps, smooth.ceiling_bps)
