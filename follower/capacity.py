"""What the robot's uplink delivers, and how the follower fits its traffic into it.

The follower counts the payload bytes it sends (feedback, status, video: the encoded
messages with their MAC, at the publish call); the leader reports in its Status what it
received (``rx_bps``: bits/s over its last 2 s), its feedback loss and the newest
feedback's age; each Command carries ``h2_s`` (the leader's 1 s mean of the feedback
path's delay) and echoes the newest feedback's stamps. :class:`UplinkBudget` turns these
into a capacity estimate by these rules (docs/follower.md, "Normal end, backlog, and the
robot's uplink": each rule, its figures and what it replaced):

- **rate rule**: h2 over its minimum and ``rx_bps`` under ``ratio`` of what was sent over the
  matching window: the capacity is ``drain_ratio`` x ``rx_bps``, again x ``decrease`` if it persists.
- **delay rule**: h2 more than ``delay_rise_s`` over its ``h2_window_s`` minimum for
  ``delay_hold_s``: a cut to ``drain_ratio`` of what the path carries (sent / (1 + h2's
  slope), and ``rx_bps``), again by ``decrease`` while h2 grows; a first cut after which h2
  does not fall is undone (:class:`~bipedtele.follower.cutundo.PendingCut`); a rise lasting
  ``relearn_s`` is the path's own (the minimum taken again). Its ceiling (what the path
  carried) slows the probe past it, except on a link that delivers in slots (the echo's own
  waits at ``slotted_s`` or more: its capacity moves with them).
- **echo rule**: the echoed feedback's one-way delay ``owd_queue_s`` over its minimum holds
  video (:class:`~bipedtele.follower.owdqueue.OneWayQueue`); a queue that drained once video
  waited was ours: a cut to ``drain_ratio`` of what was carried, not below ``drain_ratio``
  of what the path delivered lately, its ceiling as the delay rule's; a lone **dip** cuts
  nothing, nor a closing within the path's own waits (a link that delivers in slots: there
  every lone closing is a dip).
- **probing**: no signal for ``hold_s`` and h2 clear: up by ``increase_ratio`` a second (at
  least ``increase_bps_per_s``), never over ``probe_gain`` x what is sent, by
  ``ceiling_probe`` only past ``drain_ratio`` of a hard ceiling.
- **standing queue**: the echo's delay, its least over 1 s (h2's on a lossy path), over its
  ``base_window_s`` minimum by more than ``queue_target_s``: no probe, and against a hard
  ceiling a step down by ``queue_decrease`` a second, not below 0.8 x it.
- **start** (:class:`~bipedtele.follower.startphase.StartPhase`): until the first signal
  video's budget starts at ``start_bps`` and grows by ``start_growth`` a second while the
  path is clear; after ``start_s``, once video sends what the start offers it (twice
  ``start_s`` at most), the capacity is taken as 1.2 x the most sent (on a lossy path too:
  a single lost feedback makes a path lossy), unlimited past ``start_max_bps``.
- **loss**: with the leader's feedback loss at ``lossy_ppm`` or more within ``lossy_hold_s``
  the rate and echo rules do not judge (TCP's video slowed by loss arrives below what was
  sent whatever the path carries): loss alone never throttles.
- **stall**: the newest feedback older than h2's 60 s minimum by more than ``stall_s`` with
  something of ours undelivered, judged on each word of the leader (its Status, and each
  command's echo): video pauses, feedback at ``stall_fb_hz``, no rule cuts;
  after it the capacity restarts from what the path delivered before
  (:class:`~bipedtele.follower.delivery.DeliveryRate`), and a ceiling set in a dip is
  recovered at ``start_growth`` a second.
- **in flight** (:class:`~bipedtele.follower.delivery.InFlight`, BBR's cwnd): what was sent
  after the newest acknowledged feedback, capped near twice the bandwidth-delay product (on
  a lossy path with the longest interval between acknowledgements: a lost Status).

:meth:`UplinkBudget.video_budget_bps` gives video what control leaves (capacity - control's
rate - a margin of ``margin`` of the capacity, at least ``margin_min_bps``, and enough to
drain h2's queue within ``drain_s``); :meth:`UplinkBudget.feedback_plan` says how control
shrinks while limited (:func:`~bipedtele.follower.feedbackplan.plan_feedback`). The parts,
each in its module: ``UplinkTuning``, ``SentLog``, ``QueueDelay``, ``PendingCut``,
``OneWayQueue``, ``InFlight``, ``DeliveryRate``, ``StartPhase``, ``StallJudge``; the rules are here.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

from bipedtele.follower.cutundo import PendingCut
from bipedtele.follower.delivery import DeliveryRate, InFlight
from bipedtele.follower.feedbackplan import FeedbackPlan, plan_feedback
from bipedtele.follower.leadersilence import LeaderSilence
from bipedtele.follower.owdqueue import OneWayQueue
from bipedtele.follower.queuedelay import QueueDelay
from bipedtele.follower.sentlog import SentLog
from bipedtele.follower.stall import StallJudge
from bipedtele.follower.startphase import StartPhase
from bipedtele.follower.uplinktuning import UplinkTuning

__all__ = ["FeedbackPlan", "UplinkBudget", "UplinkTuning"]

_GROWING = 0.2  # h2 growing faster than this [s/s] is a queue of ours (a path's swing is slower)
_TUNING = UplinkTuning.names()
#: The leader's Status counters the budget reads: its receive rate, the feedback's loss and
#: age, and the echo of the newest follower Status's send stamp (``uplink_t_us``) [us].
_LEADER_KEYS = ("rx_bps", "fb_loss_ppm", "fb_age_ms", "uplink_t_echo_us")


class UplinkBudget:
    """Capacity estimate of the follower -> leader path and the budgets derived from it.

    Parameters
    ----------
    clock : callable
        Local clock [s] (the loop's clock; a fake one in tests).
    tuning : UplinkTuning, optional
        The rules' parameters (default: :class:`UplinkTuning`'s defaults).
    **overrides : float
        Parameters of :class:`UplinkTuning` set here (``UplinkBudget(clock, hold_s=3.0)``).
        Each is also read as an attribute of the budget (``budget.part_s``).

    Attributes
    ----------
    capacity_bps : float
        The path's capacity estimate [bit/s] (infinite: unknown, the start).
    start_budget_bps : float or None
        Video's budget until the first signal [bit/s]; None once the start is over.
    ceiling_bps : float or None
        What the path carried at the last cut [bit/s] (None before the first).
    leader : dict
        The leader's latest figures (``rx_bps``, ``fb_loss_ppm``, ``fb_age_ms``).
    signals : dict
        How often each rule fired: ``rate``, ``delay``, ``relearn``, ``undone``.
    """

    def __init__(
        self, clock: Callable[[], float] = time.monotonic, tuning: UplinkTuning | None = None, **overrides: float
    ) -> None:
        self._clock = clock
        self.tuning = replace(tuning or UplinkTuning(), **overrides)
        self._log = SentLog()
        self._q = QueueDelay(self.tuning)
        self.capacity_bps = math.inf
        self.start_budget_bps: float | None = self.tuning.start_bps
        self._startphase = StartPhase()
        self.ceiling_bps: float | None = None
        self.leader: dict[str, int] = {}
        self.signals = {"rate": 0, "delay": 0, "relearn": 0, "undone": 0, "stall": 0, "echo": 0}
        self.delivery = DeliveryRate(self.tuning.delivery_window_s)
        tu = self.tuning
        self.inflight = InFlight(
            tu.inflight_gain,
            tu.inflight_min_bytes,
            tu.probe_s,
            video_queue_s=tu.video_queue_s,
            lossy=lambda: self.lossy,  # a Status lost on its way: an acknowledgement late
        )
        self.owd = OneWayQueue(
            tu.owd_queue_s,
            steep_slope=2.0 * (tu.probe_gain - 1.0),
            standing_window_s=tu.base_window_s,
            slotted_s=tu.slotted_s,
        )
        self._owd_drained = 0  # the echo rule's queues of ours judged so far
        self._undo: PendingCut | None = None
        self._last_signal = -math.inf
        self._last_cut = -math.inf
        self._last_rate_cut = -math.inf
        self._last_undo = -math.inf
        self._last_status = -math.inf
        self._last_heard = -math.inf  # the leader's last Status (with or without rx_bps)
        self._last_cmd = -math.inf  # the last command taken
        self._silence = LeaderSilence(tu.inflight_release_s, tu.stall_s)
        self._stall = StallJudge(tu.stall_s, tu.status_timeout_s, self.delivery, self._silence, self.inflight)
        self._leader_sid: int | None = None  # the session of the leader's last Status
        self._last_update: float | None = None
        self._plan_bps = 0.0  # the feedback rate of the last plan [bit/s]
        self._lossy_until = -math.inf  # lossy until then (see lossy_hold_s)
        self._soft = False  # the ceiling was set on a slotted link: the probe past it is not slowed

    def __getattr__(self, name: str) -> float:
        """Read a tuning parameter as the budget's attribute (``budget.hold_s``)."""
        if name in _TUNING:
            return float(getattr(self.__dict__["tuning"], name))
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def excess_s(self) -> float:
        """h2 above its recent minimum [s] (a queue in the path, drained by video's margin)."""
        return self._q.excess_s

    @property
    def standing_s(self) -> float:
        """A queue standing longer than the delay rule's window [s]: the echo's one-way delay (its least over 1 s) over its ``base_window_s`` minimum.

        h2's where no fresh echo comes, or on a lossy path: there feedback behind a lost
        segment waits for its retransmission, and the echo reads waits chained longer than
        its 1 s hold as a queue (on the 5 % loss row, before the hold, the estimate climbed
        0.6 %/s, 614 -> 872 kbit/s in 57 s; 1.1 %/s on h2 in the run before).
        """
        return self.owd.standing_s if self.owd.fresh(self._clock()) and not self.lossy else self._q.standing_s

    # ------------------------------------------------------------------ inputs

    def sent(self, nbytes: int, video: bool = False, *, feedback: bool = False, at: float | None = None) -> None:
        """Count ``nbytes`` of payload sent now (any thread).

        Parameters
        ----------
        nbytes : int
            Encoded message size with its MAC [bytes].
        video : bool
            A video frame (else control: feedback, status).
        feedback : bool
            A Feedback message (its size feeds the feedback rate plan).
        at : float, optional
            Its send time for the in-flight count [s] (a Status: its stamp ``uplink_t_us``,
            which the leader echoes; default now).
        """
        now = self._clock()
        self._log.add(now, nbytes, video, feedback)
        self.inflight.sent(now if at is None else min(now, at), nbytes)

    def on_h2(self, h2_s: float) -> None:
        """Feed the leader's feedback-path delay estimate [s] (from each command's ``h2_s``).

        0 (the leader has no estimate yet: its commands carry 0 until feedback came back),
        negative and non-finite values are ignored.
        """
        self._silence.heard(self._clock())  # a command taken: a leader is there (the in-flight cap's release)
        self._last_cmd = self._clock()
        if not math.isfinite(h2_s) or h2_s <= 0:
            return
        if self._q.add(self._clock(), h2_s):
            self.signals["relearn"] += 1

    def on_echo(self, echo: Sequence[float], t_sent: float | None = None) -> None:
        """Feed a command's echo of the newest feedback: its send stamp [s, ours] and receive time [s, the leader's].

        With ``t_sent``, the command's send time on the local clock [s], the echo judges a
        stall too (after the leader's first Status): the leader's Status may stop with the
        uplink (in the split layout it rides a TCP link whose acknowledgements go up it),
        and a gap that began just after one went unseen: on the LTE row the follower sent
        feedback into a 4.4 s gap until the in-flight cap filled (107 kB, 3 s in), and the
        first one to arrive after it was 1.99 s old.
        """
        now = self._clock()
        under = self.ceiling_bps is not None and self.capacity_bps < self.ceiling_bps  # a lone rise: the path's dip
        self.owd.echo(now, float(echo[0]), float(echo[1]), under_ceiling=under)
        if t_sent is not None and math.isfinite(t_sent) and self._last_status > -math.inf:
            self._judge_stall(now, min(float(t_sent), now), None, float(echo[0]))

    def on_leader_status(
        self, counters: Mapping[str, int], t_sent: float | None = None, sid: int | None = None
    ) -> None:
        """Judge the path from a leader Status.

        Parameters
        ----------
        counters : Mapping[str, int]
            The status's counters; ``rx_bps`` missing or not an int: nothing is judged.
        t_sent : float, optional
            The status's send time on the local clock [s] (default: now; the forward
            delay is small against the 2 s window).
        sid : int, optional
            The leader's session: another one than the last status's releases the in-flight
            cap (what the earlier session acknowledged says nothing of the new one's path).
        """
        tu = self.tuning
        now = self._clock()
        if sid is not None and sid != self._leader_sid:
            if self._leader_sid is not None:
                self.inflight.reset()
            self._leader_sid = sid
        self.leader = {
            k: v for k, v in counters.items() if k in _LEADER_KEYS and isinstance(v, int) and not isinstance(v, bool)
        }
        self._silence.heard(now)
        if self.leader.get("fb_loss_ppm", 0) >= tu.lossy_ppm:  # TCP's video slowed by loss arrives below tx
            self._lossy_until = now + tu.lossy_hold_s
        age_ms = self.leader.get("fb_age_ms")
        self._silence.on_status(now, None if age_ms is None else age_ms / 1000.0, self._q.floor_s or 0.0)
        self._last_heard = now
        echo = self.leader.get("uplink_t_echo_us")
        if echo is not None and echo / 1e6 <= now:  # a Status of ours arrived: what was sent before it did too
            self.inflight.delivered(now, echo / 1e6)
        rx = self.leader.get("rx_bps")
        if rx is None:
            return
        self._last_status = now
        ts = now if t_sent is None or not math.isfinite(t_sent) else min(float(t_sent), now)
        t_fb = None if age_ms is None else ts - age_ms / 1000.0
        stalled = self._judge_stall(now, ts, rx, t_fb)
        if age_ms is not None:  # everything sent up to the newest feedback the leader had: delivered
            self.inflight.acked(now, ts - age_ms / 1000.0, self.delivery.max_bps)
        if stalled:
            return
        if now < self._q.quiet_until:
            return
        h2 = self._q.h2_s or 0.0
        tx = self._log.rate(ts - h2 - tu.window_s, ts - h2)
        # a full path queues: without h2 above its minimum, rx below tx is the windows'
        # misalignment (traffic sent before the leader listened, a step of the video rate)
        # or loss, not the path's capacity; on a lossy path the delay rule alone judges
        queued = self._q.excess_s >= 0.5 * tu.delay_rise_s
        rate_limited = queued and not self.lossy and tx >= tu.min_tx_bps and rx < tu.ratio * tx
        if rate_limited:
            self.signals["rate"] += 1
            episode = now - self._last_signal < tu.hold_s
            self._last_signal = now
            self._last_rate_cut = now
            self.ceiling_bps, self._soft = float(rx), False  # a path that queues delivers what it carries
            if not episode:  # the path delivers rx: aim a little below it, so its queue drains
                self.capacity_bps = max(tu.floor_bps, tu.drain_ratio * float(rx))
                self._last_cut = now
            elif ts - h2 - tu.window_s >= self._last_cut:  # still over, judged on a window sent after the cut
                self.capacity_bps = max(tu.floor_bps, tu.decrease * float(rx))
                self._last_cut = now

    @property
    def lossy(self) -> bool:
        """True while a leader Status showed feedback loss within ``lossy_hold_s``: only the delay rule judges."""
        return self._clock() < self._lossy_until

    @property
    def stalled(self) -> bool:
        """True while the path is stalled (see the module docstring); False without a recent leader Status or command that judged it."""
        return self._stall.current(self._clock(), self._last_heard)

    def _judge_stall(self, now: float, ts: float, rx: int | None, t_fb: float | None) -> bool:
        """Judge a stall on a word of the leader (:meth:`StallJudge.judge`); restart the capacity after one."""
        verdict = self._stall.judge(now, ts, rx, t_fb, self._q.floor_s or 0.0)
        if verdict.began:
            self.signals["stall"] += 1
            self._undo = None  # a cut that the gap's queue caused is not judged by it
        if verdict.ended:
            self._restart(now)
        return verdict.stalled

    def _restart(self, now: float) -> None:
        """After a stall: the capacity from what the path delivered before it, not the collapse."""
        tu, best = self.tuning, self.delivery.max_bps
        self._q.quiet_until = now + tu.window_s + 1.0  # the leader's window and h2 hold the gap
        if best is None or not math.isfinite(self.capacity_bps):
            return
        self.capacity_bps = max(self.capacity_bps, tu.drain_ratio * best)
        if self.ceiling_bps is not None:
            self.ceiling_bps = max(self.ceiling_bps, best)
        self._last_signal = -math.inf

    def update(self, video_most_bps: float | None = None) -> None:
        """Judge the delay rule and probe upward while not limited; call it every tick.

        ``video_most_bps``: what video sends at its most [bit/s] (None or 0: not known, or no
        video); the start takes the capacity once video sends 0.8 of what the start offers
        it or of that much (:class:`~bipedtele.follower.startphase.StartPhase`).
        """
        tu, q = self.tuning, self._q
        now = self._clock()
        last, self._last_update = self._last_update, now
        if now - max(self._last_heard, self._last_cmd) > tu.inflight_release_s:
            self.inflight.reset()  # nobody acknowledges: the leader left, or the whole path is down
            self._silence.released(max(self._last_heard, self._last_cmd))
        self._delay_rule(now)
        self._echo_rule(now)
        self._check_cut(now)
        tx = self._log.rate(now - tu.window_s, now)  # what is sent [bit/s], read once
        if math.isfinite(self.capacity_bps) and self._undo is None:
            self.start_budget_bps = None  # the path said what it carries: the start is over
        elif (
            last is not None and self.start_budget_bps is not None and now - q.at < tu.gap_s and self._start_clear(now)
        ):
            self.start_budget_bps, taken = self._startphase.step(
                tu,
                self.start_budget_bps,
                max(0.0, now - last),
                tx,
                video_most_bps or 0.0,
                lambda: self._log.rate(now - tu.window_s, now, 1),  # what video sends
            )
            if taken is not None:
                self.capacity_bps = taken
        if last is None or not math.isfinite(self.capacity_bps) or self.stalled:
            return
        dt = max(0.0, now - last)
        fresh = now - self._last_status <= tu.status_timeout_s and now - q.at < tu.gap_s
        standing = self.standing_s
        if fresh and standing > tu.queue_target_s:
            # a queue the delay rule's window takes in (a slow probe past the ceiling): no probe;
            # against a cut's ceiling step down towards 0.8 x it (a rise of the path's own costs that)
            if self.ceiling_bps is not None and not self._soft and self.capacity_bps > 0.8 * self.ceiling_bps:
                low = 0.8 * self.ceiling_bps
                self.capacity_bps = max(low, self.capacity_bps * (1.0 - tu.queue_decrease * dt))
            return
        if self.limited or now - self._last_status > tu.status_timeout_s:
            return
        if q.excess_s > 0.5 * tu.delay_rise_s:
            return  # a queue is still there: not the moment to ask for more
        step = max(tu.increase_bps_per_s, tu.increase_ratio * self.capacity_bps)
        if self.ceiling_bps is not None and not self._soft and self.capacity_bps >= tu.drain_ratio * self.ceiling_bps:
            # past what the path carried at the last cut: probe slowly (a sawtooth against a
            # known ceiling built 150-230 ms queues)
            step = tu.ceiling_probe * self.capacity_bps
        step *= 1.0 - min(1.0, standing / tu.queue_target_s)  # slower as a standing queue nears the target
        # recovery: a ceiling under half what the path delivered lately was set in a dip: back fast
        best = self.delivery.max_bps or 0.0
        known = tu.drain_ratio * best if self.ceiling_bps is None or self.ceiling_bps < 0.5 * best else 0.0
        if self.capacity_bps < known:
            step = max(step, (tu.start_growth - 1.0) * self.capacity_bps)
            if self.ceiling_bps is not None:
                self.ceiling_bps = max(self.ceiling_bps, self.capacity_bps)  # frames sized to the path again
        probed = self.capacity_bps + step * dt
        # probe near what is used: an estimate far above the sending rate was never tested
        self.capacity_bps = max(self.capacity_bps, min(probed, max(tu.probe_gain * tx + tu.floor_bps, known)))

    def _start_clear(self, now: float) -> bool:
        """Say whether the path shows no queue of ours for the start: the fresh echo's (else h2's excess) under half the delay rule's rise.

        The echo shows a queue 0.75 s before h2 (a 1 s mean), and not a link's scheduling
        waits: on the 3G row (h2 30-44 ms over its minimum, the echo's 1-4 ms) judged on h2
        the start's budget stayed at 71 kbit/s for 10 s.
        """
        rise = 0.5 * self.tuning.delay_rise_s
        if self.owd.fresh(now):
            return self.owd.queue_s <= rise
        return self._q.excess_s <= rise

    def _check_cut(self, now: float) -> None:
        """Undo a delay cut after which h2 did not fall: the path's delay rose, not our queue.

        A queue of ours drains within about its own delay once less is sent; a rise of the
        path's delay (a route change, a slow swing) does not react to what we send.
        """
        u = self._undo
        if u is None or not u.judged(now, self._q.excess_s):
            return
        self._undo = None
        if u.undo(self._q.excess_s, self._last_rate_cut, now - self._last_undo >= self.tuning.undo_gap_s):
            self.capacity_bps, self.start_budget_bps, self.ceiling_bps, self._soft = u.restored
            self._last_signal = -math.inf
            self._last_undo = now
            self.signals["undone"] += 1

    def _echo_rule(self, now: float) -> None:
        """Cut the capacity when a queue of ours drained once video waited (see the module docstring)."""
        tu, drained = self.tuning, self.owd.drained
        if drained == self._owd_drained:
            return
        self._owd_drained = drained
        # as the delay rule: not without a leader status, just after a silence, in a stall; and
        # not on a lossy path (a lost feedback's retransmission is no queue: loss never cuts)
        if now - self._last_heard > tu.status_timeout_s or now < self._q.quiet_until or self.stalled or self.lossy:
            return
        if (ref := self._carried(self._log.rate(now - tu.window_s, now))) <= 0:
            return
        self.signals["echo"] += 1
        self.ceiling_bps, self._soft = ref, self._slotted(now)  # a known rate only on a smooth link
        # not below what the path delivered lately (the 3G row's ratchet: 235 -> 136 kbit/s in 4 cuts)
        known = tu.drain_ratio * (self.delivery.max_bps or 0.0)
        self.capacity_bps = max(tu.floor_bps, min(self.capacity_bps, max(tu.drain_ratio * ref, known)))
        self._last_signal = now

    def _slotted(self, now: float) -> bool:
        """Say whether the link delivers in slots: the echo's own waits at ``slotted_s`` or more (its capacity moves with them)."""
        return self.owd.noise_s(now) >= self.tuning.slotted_s

    def _carried(self, sent_bps: float) -> float:
        """Return what the path carried [bit/s]: the least of ``sent_bps`` and ``rx_bps`` (either, when one is 0)."""
        rx = float(self.leader.get("rx_bps") or 0)
        return min(sent_bps, rx) if sent_bps > 0 and rx > 0 else max(sent_bps, rx)

    def _delay_rule(self, now: float) -> None:
        """Cut the capacity when a queue of ours is building (see the module docstring)."""
        tu, q = self.tuning, self._q
        if q.rise_since is None or now - q.rise_since < tu.delay_hold_s:
            return
        if now - self._last_heard > tu.status_timeout_s or now < q.quiet_until or self.stalled:
            return  # no leader status (nothing could undo a cut), just after a silence, or in a stall
        if now - self._last_cut < max(tu.cut_gap_s, 2.0 * q.excess_s):
            self._last_signal = now
            return
        if q.episode and q.falling:
            self._last_signal = now
            return  # the last cut is draining the queue
        slope = q.slope(now)
        if q.episode and slope < _GROWING:
            # h2 stays up after a cut but does not grow fast: the last cut holds the queue
            # (the rate rule judges what remains), or the path's delay rose (a step of the route)
            return
        first = self._log.first_sent
        start = now - tu.window_s if first is None else max(now - tu.window_s, first)
        tx = self._log.rate(start, now)  # over what has passed of the window since sending began
        # a queue fed at tx grows by (tx - C) / C seconds per second: the path carries about
        # tx / (1 + slope); the leader's rx (a 2 s window, late) bounds it too
        ref = self._carried(tx / (1.0 + max(0.0, slope)))
        cut = tu.drain_ratio * ref
        if q.episode:
            # still growing after a cut: the queue is ours (a path's step does not grow on)
            cut = min(cut, tu.decrease * self.capacity_bps)
            self._undo = None
        else:  # the first cut of a rise: undone if the queue does not drain (_check_cut)
            was = (self.capacity_bps, self.start_budget_bps, self.ceiling_bps, self._soft)
            self._undo = PendingCut(*was, now, q.excess_s)
        if ref > 0:
            self.ceiling_bps, self._soft = ref, self._slotted(now)  # a known rate only on a smooth link
        self.capacity_bps = max(tu.floor_bps, min(self.capacity_bps, cut))
        self.signals["delay"] += 1
        q.episode = True
        self._last_cut = self._last_signal = now

    # ------------------------------------------------------------------ outputs

    def admit_video(self, nbytes: int) -> bool:
        """Say whether a video message of ``nbytes`` [bytes] may leave now (the one-way queue, the in-flight cap and the queue it saw)."""
        if self.owd.closed(now := self._clock()):
            self.owd.held += 1
            return False
        return self.inflight.admit_video(nbytes, now)

    def inflight_counters(self) -> dict[str, int]:
        """Return the uplink's figures for the Status: in flight (:meth:`InFlight.counters`), the one-way queue, control's rate [bit/s]."""
        return {
            **self.inflight.counters(),
            **self.owd.counters(),
            "uplink_tx_control_bps": round(self.tx_bps("control")),
        }

    def tx_bps(self, which: str | None = None) -> float:
        """Sent rate over the last ``window_s`` [bit/s]: ``control``, ``video`` or all (None)."""
        now = self._clock()
        idx = None if which is None else ("control", "video").index(which)
        return self._log.rate(now - self.tuning.window_s, now, idx)

    @property
    def limited(self) -> bool:
        """True while the path is capacity-limited (a signal within the last ``hold_s``)."""
        return self._clock() - self._last_signal < self.tuning.hold_s

    @property
    def margin_bps(self) -> float:
        """Capacity kept free so that a queue drains [bit/s]: ``margin`` of it, at least ``margin_min_bps`` (0 while unknown)."""
        cap = self.capacity_bps
        return max(self.tuning.margin * cap, self.tuning.margin_min_bps) if math.isfinite(cap) else 0.0

    def video_budget_bps(self) -> float | None:
        """Video's budget [bit/s]: capacity - control's measured rate - margin; None: unlimited.

        Before the first signal: the start budget (``start_budget_bps``); 0 while the path is stalled.
        """
        tu = self.tuning
        cap = self.capacity_bps
        if self.stalled:
            return 0.0  # the path delivers nothing: what video sends would only queue
        if not math.isfinite(cap):
            return self.start_budget_bps
        # a queue in the path (h2 above its minimum) is drained within ``drain_s``
        drain = cap * self._q.excess_s / tu.drain_s if self.limited else 0.0
        margin = max(self.margin_bps, drain)
        # control as measured (a 2 s mean) or as the plan now sends it, whichever is more
        return max(0.0, cap - max(self.tx_bps("control"), self._plan_bps) - margin)

    def frame_bits_max(self) -> float | None:
        """Largest video frame [bit]: one that holds the uplink ``burst_s`` at most; None: unlimited.

        Measured against the start's budget during the start, then against the capacity,
        never above what the path carried at the last rate or delay cut (not an echo cut's:
        on the LTE row it held frames to 4.5 kB at 600-800 kbit/s); unlimited on a path
        that never queued.

        A frame leaves as one burst: at 300 kbit/s a 4 kB frame delays the feedback behind
        it by 107 ms, whatever the frame rate.
        """
        if self.start_budget_bps is not None and not math.isfinite(self.capacity_bps):
            return self.start_budget_bps * self.tuning.burst_s  # the start: small frames
        if self.ceiling_bps is None:
            return None  # the path never queued: no rate to hold a frame against
        rate = self.capacity_bps if self._soft else min(self.capacity_bps, self.ceiling_bps)
        return rate * self.tuning.burst_s

    def part_bits_max(self) -> float | None:
        """Largest video message [bit]: one that holds the uplink ``part_s`` at most; None: whole frames.

        Measured like :meth:`frame_bits_max`. A frame leaves as one burst, and the
        feedback queued behind it waits for all of it (on a 600 kbit/s uplink with video
        at 20 frames/s the feedback's p50 rose from 10 to 27 ms, its p90 to 40 ms); cut
        into parts paced at video's budget, it waits for one part.
        """
        largest = self.frame_bits_max()
        return None if largest is None else largest * self.tuning.part_s / self.tuning.burst_s

    def feedback_plan(self, rate_hz: float, video_bps: float = 0.0) -> FeedbackPlan:
        """How to send feedback now, given the configured rate ``rate_hz`` [Hz] and video's most ``video_bps`` [bit/s].

        Every command is acknowledged at once, at ``rate_hz``, while that (the periodic
        feedback plus one per command received) fits ``control_share`` of the capacity and
        what video at its most (its top level at its configured rate) leaves of the capacity
        less the margin (always once the start is over with the capacity unknown; during
        the start the acknowledgements ride on the periodic feedback). Otherwise the
        acknowledgements ride on the next tick's feedback, and the rate is the highest of
        ``rate_hz``, 25 and 10 Hz that fits ``control_share``, above 25 Hz also half of what
        the margin leaves (on the 3G row 50 Hz at 253 kbit/s took control from 90 to 164 kbit/s,
        video from 12 to 7.5-8 frames/s). As the capacity is probed back up, the plan returns to full rate.
        """
        tu, cmd_hz, fb_bits, cap = self.tuning, self._q.command_hz(), self._log.fb_bits, self.capacity_bps
        margin = self.margin_bps
        plan = plan_feedback(
            rate_hz,
            tu.control_share * cap,
            cmd_hz,
            fb_bits,
            start=self.start_budget_bps is not None,
            stall_hz=tu.stall_fb_hz if self.stalled else None,
            ack_room_bps=cap - margin - video_bps,
            above_floor_bps=0.5 * (cap - margin),
        )
        self._plan_bps = plan.control_bps(cmd_hz, fb_bits)
        return plan
