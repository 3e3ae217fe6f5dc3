"""What the robot's uplink delivers, and how the follower fits its traffic into it.

The follower counts the payload bytes it sends (feedback, status, video: the encoded
messages with their MAC, at the publish call) and the leader reports, in its Status, what
it received (``rx_bps``: bits/s of follower -> leader payload over its last 2 s). Each
Command carries ``h2_s``, the leader's estimate of the feedback path's delay (usable in
both clock modes). :class:`UplinkBudget` turns these into a capacity estimate:

- **rate rule.** h2 is at least half the delay rule's rise above its minimum (a queue) and
  the leader's ``rx_bps`` is below ``ratio`` (0.85) of what the follower sent over the
  matching window (the leader's 2 s before the status was sent, shifted back by
  h2): the path is capacity-limited and delivers ``rx_bps``. The first such signal sets
  the capacity to ``rx_bps``; if it persists ``hold_s`` after a cut, the capacity is cut
  again by ``decrease`` (0.7): the queue the path built must drain.
- **delay rule.** h2 stays more than ``delay_rise_s`` (0.05 s) above its minimum over the
  last ``h2_window_s`` (10 s) for ``delay_hold_s`` (0.25 s): a queue is building. Judged
  every tick (the signal comes with every command, not with the leader's 2 Hz status), once
  the leader has reported what it measures: the capacity is cut to ``drain_ratio`` of the
  least of what the leader received and what was sent, and cut again by ``decrease`` every
  ``max(cut_gap_s, 2 excess)`` while h2 still grows faster than 0.2 s/s. A first cut after
  which h2 has not fallen (by a fifth) below its peak since the cut within
  ``max(1 s, 2 peak)``, with no rate signal and no second cut since, is undone (at most
  once in ``undo_gap_s``, 5 s): a queue of ours drains once less is sent, a rise of the
  path's own delay does not. The peak, not the excess at the cut: h2 is the leader's 1 s
  mean, in which a queue goes on rising for up to a second after the cut (measured
  against the excess at the cut, 2 runs in 4 at 300 kbit/s undid every cut, giving video
  back its start budget, and queued 0.4-0.5 s again and again). A rise that lasts
  ``relearn_s`` without falling is the path's own (a slow delay swing, a new route): the h2
  minimum is taken again from the current h2. The shipped intercontinental trace's h2
  varies 129-260 ms, with one 3 s step of +80 ms (one cut, undone when h2 does not fall); a
  queue of ours at a 300 kbit/s cap passes 50 ms within a quarter of a second. At 80 ms a
  40 ms queue stood through the start on a 600 kbit/s uplink and the first cut came late.
- **probing.** With no signal for ``hold_s``, h2 near its minimum (below half the rise) and
  the leader's status arriving, the capacity grows by ``increase_ratio`` of itself per second
  (at least ``increase_bps_per_s``), and by ``ceiling_probe`` (0.5 %) only once it is past
  ``drain_ratio`` of what the path carried at the last cut: a sawtooth at 3 %/s against a
  known ceiling held 150-230 ms queues on a 600 kbit/s uplink.

- **standing queue.** h2 more than ``queue_target_s`` (15 ms) above its minimum over
  ``base_window_s`` (60 s): no probing (the probe slows as h2 nears the target), and with a
  ceiling from a cut the capacity steps down by ``queue_decrease`` (5 %) of itself per
  second, not below 0.8 x the ceiling. The delay rule's 10 s minimum takes in a queue that
  stands longer: at 600 kbit/s with video the slow probe past the ceiling crept on while its
  queue stood 20-45 ms, and the feedback's p99 stood 80-100 ms above video off.

Until the first signal the capacity is unknown (infinite): the **start**. Video starts at
``start_bps`` (64 kbit/s) and grows by ``start_growth`` (x1.3) every second while commands
bring an h2 near its minimum and the budget is less than twice what is sent, up to
``start_max_bps`` (4 Mbit/s, then unlimited), or for ``start_s`` (10 s; then the capacity is
taken as 1.2 x what is sent, and probed); acknowledgements ride on the periodic feedback
until then. h2 is the leader's 1 s moving average, so a queue shows about 0.75 s late: the
growth overshoots a capacity by at most about a fifth before the first cut (x1.6 a second
overshot by 40 % and queued 0.3-0.4 s at 300 kbit/s; a full-rate start, QVGA video and an
acknowledgement per command, 0.6-0.8 Mbit/s, queued 0.5-1 s).

Loss alone (``fb_loss_ppm``) never throttles: a lossy path that delivers what is sent is not
a full one.

:meth:`UplinkBudget.video_budget_bps` gives video what control leaves: capacity minus the
measured control rate minus a margin (``margin`` of the capacity, at least
``margin_min_bps``) so that a queue drains; :meth:`UplinkBudget.feedback_plan` says how
control shrinks while limited (acknowledgements coalesced into the next tick's feedback,
the feedback rate lowered to 25, then 10 Hz, to fit ``control_share`` of the capacity).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from bipedtele.follower.backlog import WindowMin

__all__ = ["FeedbackPlan", "UplinkBudget"]

_BIN_S = 0.1  # resolution of the sent-bytes history [s]
_KEEP_S = 20.0  # sent-bytes history kept [s] (the window, shifted by h2 up to ~10 s)
_GROWING = 0.2  # h2 growing faster than this [s/s] is a queue of ours (a path's swing is slower)


@dataclass
class _PendingCut:
    """The first delay cut of a rise, until judged: what to restore, and h2's peak since."""

    capacity_bps: float
    start_budget_bps: float | None
    ceiling_bps: float | None
    t: float  # when it was cut [s]
    peak_excess_s: float  # h2 above its minimum: at the cut, then the highest since [s]


@dataclass(frozen=True)
class FeedbackPlan:
    """How the follower sends its feedback now.

    Attributes
    ----------
    ack_each_command : bool
        Publish a Feedback at once for every command picked up between ticks (True), or
        let the next tick's feedback acknowledge it (at most one feedback per tick).
    rate_hz : float
        Periodic feedback rate [Hz].
    min_interval_s : float
        When acknowledgements are not sent for every command: one is still sent at once
        if the previous feedback left at least this long ago [s] (so the feedback rate,
        periodic plus acknowledgements, stays within what the path carries).
    """

    ack_each_command: bool
    rate_hz: float
    min_interval_s: float = 0.0


class UplinkBudget:
    """Capacity estimate of the follower -> leader path and the budgets derived from it.

    Parameters
    ----------
    clock : callable
        Local clock [s] (the loop's clock; a fake one in tests).
    window_s : float
        The leader's ``rx_bps`` window [s] (2 s).
    ratio : float
        Rate rule: limited when ``rx_bps < ratio * tx`` over the matching window.
    delay_rise_s, delay_hold_s : float
        Delay rule: h2 above its recent minimum by more than ``delay_rise_s`` [s] for more
        than ``delay_hold_s`` [s].
    h2_window_s : float
        Window of the h2 minimum [s].
    relearn_s : float
        A delay rise lasting this long [s] is the path's: the h2 minimum is taken again.
    decrease : float
        Multiplicative decrease of the capacity when a rate limit persists after a cut.
    increase_bps_per_s, increase_ratio : float
        Increase while not limited: ``max(increase_bps_per_s, increase_ratio * capacity)``
        per second [bit/s per s, 1/s].
    ceiling_probe : float
        Above ``drain_ratio`` of the rate the path carried at the last cut, the capacity
        grows by this share of itself per second only [1/s].
    cut_gap_s : float
        Shortest time between two cuts of the delay rule [s] (also at least twice the
        excess: a cut shows in h2 one queue delay later).
    hold_s : float
        Time between two cuts, and how long ``limited`` stays on after the last signal [s].
    min_tx_bps : float
        The rate rule is not judged below this sending rate [bit/s] (too few bytes).
    floor_bps : float
        The capacity estimate never goes below this [bit/s].
    margin, margin_min_bps : float
        Video's budget leaves ``max(margin * capacity, margin_min_bps)`` free [-, bit/s].
    control_share : float
        While limited, feedback uses at most this share of the capacity.
    status_timeout_s : float
        Without a leader status for this long [s] the capacity is not probed upward.
    drain_s : float
        Video's margin grows so that a queue of ``excess_s`` (h2 above its minimum) drains
        in about this long [s].
    gap_s : float
        A silence of the commands longer than this [s] (an outage): the leader's figures
        are not judged until its window is past it (they count the silence, not the path).
    start_bps, start_max_bps, start_growth : float
        Video's budget at the start, multiplied by ``start_growth`` every second until a
        signal or until it passes ``start_max_bps`` [bit/s, bit/s, 1/s].
    start_s : float
        After this long [s] of clear path in the start, the capacity is taken as 1.2 x
        what is sent (then probed as after a cut).
    burst_s : float
        A video frame may hold the uplink this long at the estimated capacity [s]
        (:meth:`frame_bits_max`).
    part_s : float
        A video message (a part of a frame, paced) holds it this long at most [s]
        (:meth:`part_bits_max`).
    undo_gap_s : float
        A cut is undone at most once in this long [s]: a rise that comes back soon after
        an undo, at the rate the undo restored, is a queue of ours.
    base_window_s, queue_target_s, queue_decrease : float
        The standing-queue rule: with a known ceiling, the capacity is probed only while
        h2 is within ``queue_target_s`` [s] of its minimum over ``base_window_s`` [s]
        (the probe slows as h2 nears it), and above it the capacity steps down by
        ``queue_decrease`` of itself per second [1/s], not below 0.8 x the ceiling.
    drain_ratio : float
        On the rate rule's first signal the capacity is set to this share of what the
        leader received (below it, so that the queue the path built drains).
    """

    def __init__(
        self,
        clock: Callable[[], float] = time.monotonic,
        *,
        window_s: float = 2.0,
        ratio: float = 0.85,
        delay_rise_s: float = 0.05,
        delay_hold_s: float = 0.25,
        h2_window_s: float = 10.0,
        relearn_s: float = 5.0,
        decrease: float = 0.7,
        increase_bps_per_s: float = 4_000.0,
        increase_ratio: float = 0.03,
        cut_gap_s: float = 0.5,
        ceiling_probe: float = 0.005,
        hold_s: float = 2.0,
        min_tx_bps: float = 16_000.0,
        floor_bps: float = 16_000.0,
        margin: float = 0.1,
        margin_min_bps: float = 8_000.0,
        control_share: float = 0.6,
        status_timeout_s: float = 5.0,
        drain_s: float = 1.0,
        drain_ratio: float = 0.9,
        gap_s: float = 0.5,
        burst_s: float = 0.06,
        part_s: float = 0.015,
        start_bps: float = 64_000.0,
        start_max_bps: float = 4_000_000.0,
        start_growth: float = 1.3,
        start_s: float = 10.0,
        undo_gap_s: float = 5.0,
        base_window_s: float = 60.0,
        queue_target_s: float = 0.015,
        queue_decrease: float = 0.05,
    ) -> None:
        self._clock = clock
        self.window_s = float(window_s)
        self.ratio = float(ratio)
        self.delay_rise_s = float(delay_rise_s)
        self.delay_hold_s = float(delay_hold_s)
        self.relearn_s = float(relearn_s)
        self.decrease = float(decrease)
        self.increase_bps_per_s = float(increase_bps_per_s)
        self.increase_ratio = float(increase_ratio)
        self.cut_gap_s = float(cut_gap_s)
        self.ceiling_probe = float(ceiling_probe)
        self.hold_s = float(hold_s)
        self.min_tx_bps = float(min_tx_bps)
        self.floor_bps = float(floor_bps)
        self.margin = float(margin)
        self.margin_min_bps = float(margin_min_bps)
        self.control_share = float(control_share)
        self.status_timeout_s = float(status_timeout_s)
        self.drain_s = float(drain_s)
        self.drain_ratio = float(drain_ratio)
        self.gap_s = float(gap_s)
        self.burst_s = float(burst_s)
        self.part_s = float(part_s)
        self.start_max_bps = float(start_max_bps)
        self.start_growth = float(start_growth)
        self.start_s = float(start_s)
        self.undo_gap_s = float(undo_gap_s)
        self.queue_target_s = float(queue_target_s)
        self.queue_decrease = float(queue_decrease)
        self._h2_floor = WindowMin(base_window_s)
        #: h2 above its minimum over ``base_window_s`` [s]: a queue standing longer than the
        #: delay rule's window (0 until h2 comes).
        self.standing_s = 0.0
        self._start_clear_s = 0.0
        #: Video's budget until the first signal [bit/s]; None once past ``start_max_bps``.
        self.start_budget_bps: float | None = float(start_bps)
        self._quiet_until = -math.inf
        self._lock = threading.Lock()
        # sent bytes per bin: bin index -> [control, video]
        self._bins: deque[tuple[int, list[int]]] = deque()
        self._h2_min = WindowMin(h2_window_s)
        self._h2: float | None = None
        self._h2_at = -math.inf  # when the last h2 came [s]
        self._h2_base: float | None = None
        self._rise_since: float | None = None
        self._delay_episode = False
        self._falling = False
        self._h2_hist: deque[tuple[float, float]] = deque()
        self._cmd_times: deque[float] = deque()
        #: h2 above its recent minimum [s] (a queue in the path, drained by video's margin).
        self.excess_s = 0.0
        self.capacity_bps = math.inf
        self._last_signal = -math.inf
        self._last_cut = -math.inf
        self._last_status = -math.inf
        self._last_heard = -math.inf  # the leader's last Status (with or without rx_bps)
        self._first_sent: float | None = None
        self._last_update: float | None = None
        self._fb_bits = 0.0  # EWMA of one feedback's size [bit]
        #: The leader's latest figures (``rx_bps``, ``fb_loss_ppm``, ``fb_age_ms``).
        self.leader: dict[str, int] = {}
        self.signals = {"rate": 0, "delay": 0, "relearn": 0, "undone": 0}
        self._undo: _PendingCut | None = None
        self._last_rate_cut = -math.inf
        self._last_undo = -math.inf
        #: What the path carried at the last cut [bit/s] (None before the first).
        self.ceiling_bps: float | None = None

    # ------------------------------------------------------------------ inputs

    def sent(self, nbytes: int, video: bool = False, *, feedback: bool = False) -> None:
        """Count ``nbytes`` of payload sent now (any thread).

        Parameters
        ----------
        nbytes : int
            Encoded message size with its MAC [bytes].
        video : bool
            A video frame (else control: feedback, status).
        feedback : bool
            A Feedback message (its size feeds the feedback rate plan).
        """
        now = self._clock()
        b = int(now / _BIN_S)
        if self._first_sent is None:
            self._first_sent = now
        with self._lock:
            if not self._bins or self._bins[-1][0] != b:
                self._bins.append((b, [0, 0]))
                while self._bins and self._bins[0][0] < b - _KEEP_S / _BIN_S:
                    self._bins.popleft()
            self._bins[-1][1][1 if video else 0] += int(nbytes)
            if feedback:
                bits = 8.0 * nbytes
                self._fb_bits = bits if self._fb_bits == 0.0 else 0.9 * self._fb_bits + 0.1 * bits

    def on_h2(self, h2_s: float) -> None:
        """Feed the leader's feedback-path delay estimate [s] (from each command's ``h2_s``).

        0 (the leader has no estimate yet: its commands carry 0 until feedback came back),
        negative and non-finite values are ignored.
        """
        if not math.isfinite(h2_s) or h2_s <= 0:
            return
        now = self._clock()
        self._h2_at = now
        self._h2 = float(h2_s)
        self._h2_min.add(now, self._h2)
        self._h2_floor.add(now, self._h2)
        floor = self._h2_floor.value(now)
        self.standing_s = max(0.0, self._h2 - floor) if floor is not None else 0.0
        wmin = self._h2_min.value(now)
        assert wmin is not None
        # The baseline is held through a rise (a queue of ours draining for longer than
        # the window is still measured against the delay before it).
        if self._rise_since is None or self._h2_base is None or wmin < self._h2_base:
            self._h2_base = wmin
        base = self._h2_base
        hist = self._h2_hist
        hist.append((now, self._h2))
        while hist and hist[0][0] < now - 2.0:
            hist.popleft()
        if self._cmd_times and now - self._cmd_times[-1] > self.gap_s:
            # the path was down (an outage, a router restart): the leader's next windows
            # count that silence, not the path's capacity; judge again once they are past it
            self._quiet_until = now + self.window_s + 1.0
        self._cmd_times.append(now)
        while self._cmd_times and self._cmd_times[0] < now - self.window_s:
            self._cmd_times.popleft()
        self.excess_s = max(0.0, self._h2 - base)
        if self.excess_s > self.delay_rise_s:
            falling = self._h2 < max(h for _, h in hist) - 0.05  # a queue of ours draining
            self._falling = falling
            if self._rise_since is None:
                self._rise_since = now
            elif now - self._rise_since >= self.relearn_s and not falling:
                # lasting: the path's own delay, not a queue of ours
                self._h2_min.clear()
                self._h2_min.add(now, self._h2)
                self._h2_floor.clear()
                self._h2_floor.add(now, self._h2)
                self.standing_s = 0.0
                self._h2_base = self._h2
                self.excess_s = 0.0
                self._rise_since = None
                self._delay_episode = False
                self.signals["relearn"] += 1
        else:
            self._rise_since = None
            self._delay_episode = False

    def on_leader_status(self, counters: Mapping[str, int], t_sent: float | None = None) -> None:
        """Judge the path from a leader Status.

        Parameters
        ----------
        counters : Mapping[str, int]
            The status's counters; ``rx_bps`` missing or not an int: nothing is judged.
        t_sent : float, optional
            The status's send time on the local clock [s] (default: now; the forward
            delay is small against the 2 s window).
        """
        now = self._clock()
        self.leader = {k: v for k, v in counters.items() if k in ("rx_bps", "fb_loss_ppm", "fb_age_ms")
                       and isinstance(v, int) and not isinstance(v, bool)}  # fmt: skip
        self._last_heard = now
        rx = self.leader.get("rx_bps")
        if rx is None:
            return
        self._last_status = now
        if now < self._quiet_until:
            return
        ts = now if t_sent is None or not math.isfinite(t_sent) else min(float(t_sent), now)
        h2 = self._h2 or 0.0
        tx = self._rate(ts - h2 - self.window_s, ts - h2)
        # a full path queues: without h2 above its minimum, rx below tx is the windows'
        # misalignment (traffic sent before the leader listened, a step of the video rate)
        # or loss, not the path's capacity
        queued = self.excess_s >= 0.5 * self.delay_rise_s
        rate_limited = queued and tx >= self.min_tx_bps and rx < self.ratio * tx
        if rate_limited:
            self.signals["rate"] += 1
            episode = now - self._last_signal < self.hold_s
            self._last_signal = now
            self._last_rate_cut = now
            self.ceiling_bps = float(rx)  # a path that queues delivers what it carries
            if not episode:  # the path delivers rx: aim a little below it, so its queue drains
                self.capacity_bps = max(self.floor_bps, self.drain_ratio * float(rx))
                self._last_cut = now
            elif ts - h2 - self.window_s >= self._last_cut:  # still over, judged on a window sent after the cut
                self.capacity_bps = max(self.floor_bps, self.decrease * float(rx))
                self._last_cut = now

    def update(self) -> None:
        """Judge the delay rule and probe upward while not limited; call it every tick."""
        now = self._clock()
        last, self._last_update = self._last_update, now
        self._delay_rule(now)
        self._check_cut(now)
        if math.isfinite(self.capacity_bps) and self._undo is None:
            self.start_budget_bps = None  # the path said what it carries: the start is over
        elif (
            last is not None
            and self.start_budget_bps is not None
            and now - self._h2_at < self.gap_s
            and self.excess_s <= 0.5 * self.delay_rise_s
        ):
            dt = max(0.0, now - last)
            self._start_clear_s += dt
            tx = self.tx_bps()
            if self.start_budget_bps < 2.0 * tx + self.floor_bps:
                # grown only while h2 says the path is clear and the budget is near what is
                # sent (a budget far above the sending rate was never tested)
                self.start_budget_bps *= self.start_growth**dt
            if self.start_budget_bps > self.start_max_bps:
                self.start_budget_bps = None
            elif self._start_clear_s >= self.start_s:
                # clear for start_s: the path carries what was sent; probe on from a little
                # above it (twice it overshot a 600 kbit/s uplink by 200 ms at once)
                self.capacity_bps = 1.2 * tx + self.floor_bps
                self.start_budget_bps = None
        if last is None or not math.isfinite(self.capacity_bps):
            return
        dt = max(0.0, now - last)
        fresh = now - self._last_status <= self.status_timeout_s and now - self._h2_at < self.gap_s
        if fresh and self.standing_s > self.queue_target_s:
            # a queue standing longer than the delay rule's window (a slow probe past the
            # ceiling builds one that rule's minimum takes in): no probing; against a ceiling
            # the path showed at a cut, step down towards 0.8 x it (a rise of the path's own
            # delay costs at most that, for base_window_s)
            if self.ceiling_bps is not None and self.capacity_bps > 0.8 * self.ceiling_bps:
                low = 0.8 * self.ceiling_bps
                self.capacity_bps = max(low, self.capacity_bps * (1.0 - self.queue_decrease * dt))
            return
        if self.limited or now - self._last_status > self.status_timeout_s:
            return
        if self.excess_s > 0.5 * self.delay_rise_s:
            return  # a queue is still there: not the moment to ask for more
        step = max(self.increase_bps_per_s, self.increase_ratio * self.capacity_bps)
        if self.ceiling_bps is not None and self.capacity_bps >= self.drain_ratio * self.ceiling_bps:
            # past what the path carried at the last cut: probe slowly (a path's capacity
            # changes now and then; a sawtooth against a known ceiling only builds queues)
            step = self.ceiling_probe * self.capacity_bps
        step *= 1.0 - min(1.0, self.standing_s / self.queue_target_s)  # slower as a standing queue nears the target
        probed = self.capacity_bps + step * dt
        # probe near what is used: an estimate far above the sending rate was never tested
        self.capacity_bps = max(self.capacity_bps, min(probed, 2.0 * self.tx_bps() + self.floor_bps))

    def _h2_slope(self, now: float) -> float:
        """Growth of h2 over the last 0.5 s [s/s] (0 with less than 0.2 s of history)."""
        pts = [(t, h) for t, h in self._h2_hist if t >= now - 0.5]
        if len(pts) < 2 or pts[-1][0] - pts[0][0] < 0.2:
            return 0.0
        return (pts[-1][1] - pts[0][1]) / (pts[-1][0] - pts[0][0])

    def _check_cut(self, now: float) -> None:
        """Undo a delay cut after which h2 did not fall: the path's delay rose, not our queue.

        A queue of ours drains within about its own delay once less is sent; a rise of the
        path's delay (a route change, a slow swing) does not react to what we send.
        """
        if self._undo is None:
            return
        u = self._undo
        u.peak_excess_s = max(u.peak_excess_s, self.excess_s)  # h2 is the leader's 1 s mean: a queue peaks in it late
        if now - u.t < max(1.0, 2.0 * u.peak_excess_s):
            return
        self._undo = None
        if (
            self.excess_s >= 0.8 * u.peak_excess_s
            and self._last_rate_cut < u.t
            and now - self._last_undo >= self.undo_gap_s
        ):
            self.capacity_bps, self.start_budget_bps, self.ceiling_bps = (
                u.capacity_bps,
                u.start_budget_bps,
                u.ceiling_bps,
            )
            self._last_signal = -math.inf
            self._last_undo = now
            self.signals["undone"] += 1

    def _delay_rule(self, now: float) -> None:
        """Cut the capacity when a queue of ours is building (see the module docstring)."""
        if self._rise_since is None or now - self._rise_since < self.delay_hold_s:
            return
        if now - self._last_heard > self.status_timeout_s or now < self._quiet_until:
            return  # no leader status (nothing could undo a cut), or just after a silence
        if now - self._last_cut < max(self.cut_gap_s, 2.0 * self.excess_s):
            self._last_signal = now
            return
        if self._delay_episode and self._falling:
            self._last_signal = now
            return  # the last cut is draining the queue
        slope = self._h2_slope(now)
        if self._delay_episode and slope < _GROWING:
            # h2 stays up after a cut but does not grow fast: the last cut holds the queue
            # (the rate rule judges what remains), or the path's delay rose (a step of the route)
            return
        start = now - self.window_s if self._first_sent is None else max(now - self.window_s, self._first_sent)
        tx = self._rate(start, now)  # over what has passed of the window since sending began
        # a queue fed at tx grows by (tx - C) / C seconds per second: the path carries about
        # tx / (1 + slope); the leader's rx (a 2 s window, late) bounds it too
        ref = tx / (1.0 + max(0.0, slope))
        rx = self.leader.get("rx_bps")
        if rx is not None and rx > 0:
            ref = min(ref, float(rx)) if ref > 0 else float(rx)
        cut = self.drain_ratio * ref
        if self._delay_episode:
            # still growing after a cut: the queue is ours (a path's step does not grow on)
            cut = min(cut, self.decrease * self.capacity_bps)
            self._undo = None
        else:  # the first cut of a rise: undone if the queue does not drain (_check_cut)
            self._undo = _PendingCut(self.capacity_bps, self.start_budget_bps, self.ceiling_bps, now, self.excess_s)
        if ref > 0:
            self.ceiling_bps = ref
        self.capacity_bps = max(self.floor_bps, min(self.capacity_bps, cut))
        self.signals["delay"] += 1
        self._delay_episode = True
        self._last_cut = self._last_signal = now

    # ------------------------------------------------------------------ outputs

    def _rate(self, a: float, b: float, which: int | None = None) -> float:
        """Sent rate over ``[a, b)`` [bit/s]: control (0), video (1) or both (None)."""
        if b <= a:
            return 0.0
        ia, ib = int(a / _BIN_S), int(b / _BIN_S)
        total = 0
        with self._lock:
            for i, (c, v) in self._bins:
                if ia <= i < ib:
                    total += (c + v) if which is None else (c, v)[which]
        return 8.0 * total / max(_BIN_S, (ib - ia) * _BIN_S)

    def tx_bps(self, which: str | None = None) -> float:
        """Sent rate over the last ``window_s`` [bit/s]: ``control``, ``video`` or all (None)."""
        now = self._clock()
        idx = None if which is None else ("control", "video").index(which)
        return self._rate(now - self.window_s, now, idx)

    @property
    def limited(self) -> bool:
        """True while the path is capacity-limited (a signal within the last ``hold_s``)."""
        return self._clock() - self._last_signal < self.hold_s

    def video_budget_bps(self) -> float | None:
        """Video's budget [bit/s]: capacity - control's measured rate - margin; None: unlimited.

        Before the first signal: the start budget (``start_budget_bps``).
        """
        cap = self.capacity_bps
        if not math.isfinite(cap):
            return self.start_budget_bps
        # a queue in the path (h2 above its minimum) is drained within ``drain_s``
        drain = cap * self.excess_s / self.drain_s if self.limited else 0.0
        margin = max(self.margin * cap, self.margin_min_bps, drain)
        return max(0.0, cap - self.tx_bps("control") - margin)

    def frame_bits_max(self) -> float | None:
        """Largest video frame [bit]: one that holds the uplink ``burst_s`` at most; None: unlimited.

        Measured against the start's budget during the start, then against what the path
        carried at the last cut; unlimited on a path that never queued.

        A frame leaves as one burst: at 300 kbit/s a 4 kB frame delays the feedback behind
        it by 107 ms, whatever the frame rate.
        """
        if self.start_budget_bps is not None and not math.isfinite(self.capacity_bps):
            return self.start_budget_bps * self.burst_s  # the start: small frames
        if self.ceiling_bps is None:
            return None  # the path never queued: no rate to hold a frame against
        return min(self.capacity_bps, self.ceiling_bps) * self.burst_s

    def part_bits_max(self) -> float | None:
        """Largest video message [bit]: one that holds the uplink ``part_s`` at most; None: whole frames.

        Measured like :meth:`frame_bits_max`. A frame leaves as one burst, and the
        feedback queued behind it waits for all of it (on a 600 kbit/s uplink with video
        at 20 frames/s the feedback's p50 rose from 10 to 27 ms, its p90 to 40 ms); cut
        into parts paced at video's budget, it waits for one part.
        """
        largest = self.frame_bits_max()
        return None if largest is None else largest * self.part_s / self.burst_s

    def feedback_plan(self, rate_hz: float) -> FeedbackPlan:
        """How to send feedback now, given the configured rate ``rate_hz`` [Hz].

        Every command is acknowledged at once, at ``rate_hz``, while that (the periodic
        feedback plus one per command received) fits ``control_share`` of the capacity
        (always once the start is over with the capacity unknown; during the start the
        acknowledgements ride on the periodic feedback). Otherwise the acknowledgements ride on the next
        tick's feedback, and the rate is the highest of ``rate_hz``, 25 and 10 Hz that fits.
        As the capacity is probed back up, the plan returns to full rate.
        """
        fits = self.control_share * self.capacity_bps
        cmd_hz = len(self._cmd_times) / self.window_s
        if not math.isfinite(fits) and self.start_budget_bps is not None:
            # the start: the path is not known yet; acknowledgements ride on the periodic
            # feedback (an acknowledgement per command doubles control's rate)
            return FeedbackPlan(False, rate_hz, 1.0 / rate_hz if rate_hz > 0 else 0.0)
        if not math.isfinite(fits) or (rate_hz + cmd_hz) * self._fb_bits <= fits:
            return FeedbackPlan(True, rate_hz)
        # the feedback rate the path carries: acknowledgements fill what the periodic
        # feedback leaves (no step from "every command" to "none" as the capacity moves)
        total_hz = fits / self._fb_bits if self._fb_bits > 0 else rate_hz
        min_interval = 1.0 / total_hz if total_hz > 0 else math.inf
        for hz in (rate_hz, 25.0, 10.0):
            if hz <= rate_hz and hz * self._fb_bits <= fits:
                return FeedbackPlan(False, hz, min_interval)
        return FeedbackPlan(False, min(rate_hz, 10.0), min_interval)
