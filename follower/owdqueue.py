"""The feedback's one-way delay above its minimum, from each command's echo: a queue of ours, seen fast.

Each Command echoes the newest Feedback the leader took: its send stamp (the follower's
clock) and when the leader received it (the leader's clock), ``Command.fb_echo``. Their
difference is the feedback's one-way delay plus the two clocks' offset; the offset cancels
in its rise over its minimum (LEDBAT's one-way delay signal, no clock sync needed). That
rise is a queue in the uplink, seen one command after the feedback that met it: about h2 +
h1 late, where the leader's h2 (a 1 s mean) shows it about 0.75 s late and its Status's
round trip up to a status period (0.5 s) late. On a 600 kbit/s token bucket each probe past
the bucket's rate queued the feedback 50-165 ms for one to two seconds before either saw it.

:class:`OneWayQueue` closes a valve while that queue exceeds ``queue_max_s``: video waits
(:meth:`~bipedtele.follower.capacity.UplinkBudget.admit_video`), so that the feedback
behind it waits about that long at most, plus one video part (``part_s`` at the path's
rate). A rise that does not drain within a round trip (plus ``settle_s``) after video
stopped is the path's own delay (a route's step, a slow swing): the minimum is taken
again from it (**rebase**) and the valve opens. A queue of ours drains once video stops
(**drained**: the path carries less than was sent, and the budget cuts its estimate); one
that drained while the valve held no video drained by itself (a burst of the path's, a
short dip of a cellular link's capacity) and proves nothing: on the LTE row such spikes
cut the estimate five times in 90 s, 622 -> 309 kbit/s, each one probed back slowly.

A queue of ours grows only as fast as what is sent exceeds what the path carries, and the
probe keeps the estimate under 1.25 x what is sent: 0.25 s/s. A rise faster than
``steep_slope`` since the queue was last under half ``queue_max_s``, with no other
closing of the valve within ``lone_s``, is a **dip** of the path's own (a cellular link's
scheduling gap): video waits it out and the budget cuts nothing. Replayed through this
class, the echoes of four cellular runs (LTE, 3G) were lone dips in 23 of 36 closings, those
of the kernel's 600 kbit/s token bucket in none of 9 (2 of 10 at 300 kbit/s); each such
dip had cut the estimate by a fifth (the 3G row's ratchet, 229 -> 117 kbit/s on a link
carrying 500-650). A valve closing again within ``lone_s`` is a capacity below what is
sent: judged as before. A lone closing while the budget's estimate is under what the path
carried at its last cut is a dip however slowly it rose (a queue of ours needs more sent
than the path carried); past it, a crossing of a known rate (a token bucket's) is ours. On
the 3G row the trace's slow rises (a stretch at 240-360 kbit/s for 200-600 ms) had cut
the estimate 6 times in 90 s, each probed back slowly, where only the steep ones were dips.

A link that delivers in slots makes the echo wait whatever is sent: the queue's upper
quartile over the last 30 s while the valve was open (:meth:`OneWayQueue.noise_s`, the
**path's own waits**), replayed from the bench's recordings, was 8.3-10.3 ms on the 3G
row, 4.7-6.8 ms on LTE and 0.7-1.0 ms behind the kernel's 600 kbit/s token bucket. A
closing whose queue never passed ``queue_max_s`` by more than those waits proves nothing
(**jitter**, not judged); with the waits at ``slotted_s`` or more a lone closing is the
link's dip however slowly it rose (its slow stretches of 200-600 ms at 240-360 kbit/s
build a queue as slowly as ours). On the 3G row these closings had cut the estimate 14
times in 90 s (205-245 kbit/s on a link carrying 340-1,060 in every second outside its
gap); the token bucket's waits stay under both, and its crossings are cut as before.

The same current delay, its least over the last :data:`STANDING_HOLD_S` (1 s), over its
minimum across ``standing_window_s`` (60 s) is the **standing queue** (``standing_s``): a
queue standing longer than the valve's 10 s window takes in, which holds the budget's probe.
The hold keeps the slots' waits out of it: replayed from a 3G run's echoes (trace seconds
50-90, after the delay cut its slowest stretch brings), the current delay over the 60 s
minimum was 2.2 / 6.0 / 13.4 ms at p25 / p50 / p75 and over the 15 ms target 21 % of the
time, slowing the probe to 0.53 of its rate on average; the least over 1 s was 0.6 / 1.1 /
1.5 ms (never over the target; the probe's rate 0.92).

The queue is the least of the last three samples and of every sample of the last
2 x ``queue_max_s`` (:class:`~bipedtele.follower.delayrise.DelayRise`): a link that delivers
in slots (the cellular traces' 1500-byte opportunities, 50 ms apart where the 3G trace
carries 240 kbit/s) makes three feedback in a row wait on one slot, whatever the queue.
That least lags a step by up to the span, so a rise is measured from the last sample under
half ``queue_max_s``, not a third: on the LTE row, steps from 12-13 ms to 33-46 ms within
20 ms, measured from the last sample under 10 ms (60-100 ms before the valve closed), read
0.3-0.45 s/s and cut the estimate (5 cuts in 90 s). A queue of ours at 0.25 s/s still needs
60 ms from half ``queue_max_s`` to over it. (The replay above was with a third; with half,
one LTE run's closings were dips in 12 of 18 against 9, the 600 kbit/s token bucket's in 1
of 12 against 0, and at 300 kbit/s 5 of 12 against 2.)
"""

from __future__ import annotations

import math
from collections import deque

from bipedtele.follower.delayrise import DelayRise, StandingQueue

__all__ = ["NOISE_WINDOW_S", "STANDING_HOLD_S", "OneWayQueue"]

#: The path's own waits are the queue's upper quartile over this long [s] (over 10 s they
#: swung 3.9-8.1 ms on the LTE row, 4.7-6.8 over 30 s).
NOISE_WINDOW_S = 30.0

#: The standing queue takes the current delay's least over this long [s]: a queue of ours
#: standing 10 s stands 1 s; a link's waits for its slots (50 ms apart at 240 kbit/s, slow
#: stretches of 200-600 ms on the 3G trace) do not.
STANDING_HOLD_S = 1.0


class OneWayQueue:
    """The uplink's queue from the echoed feedback's one-way delay, and the valve it closes for video.

    Parameters
    ----------
    queue_max_s : float
        Video waits while the queue exceeds this [s].
    window_s : float
        Window of the one-way delay's minimum [s].
    settle_s : float
        A queue that has not drained this long [s] after a round trip since the valve
        closed is the path's own delay: rebased.
    fresh_s : float
        An echo older than this [s] closes nothing (no command came: nothing to judge).
    steep_slope : float
        A rise faster than this [s/s] is the path's dip (see the module docstring).
    lone_s : float
        A steep rise is a dip only with no other closing of the valve this long before it [s].
    standing_window_s : float
        Window of the standing queue's minimum [s].
    slotted_s : float
        With the path's own waits (:meth:`noise_s`) at least this [s] when the valve closes,
        the link delivers in slots: a lone closing is its dip however slowly it rose (inf: never).

    Attributes
    ----------
    queue_s : float
        The one-way delay above its minimum [s] (the least of the last three samples).
    standing_s : float
        The same delay's least over :data:`STANDING_HOLD_S` above its minimum over
        ``standing_window_s`` [s]: a queue standing longer than ``window_s`` takes in (0
        until an echo came).
    at : float
        When the last new sample came [s].
    held : int
        Video messages the valve held back (a frame's later part once per 10 ms it waits).
    rebased : int
        Rises taken for the path's own delay.
    drained : int
        Rises that drained once video waited (the valve held some): queues of ours (the
        budget cuts on each).
    passed : int
        Rises that drained while the valve held no video: not judged.
    dips : int
        Lone steep rises that drained once video waited: the path's dips, not judged.
    jitter : int
        Rises that drained once video waited but never passed ``queue_max_s`` by more than
        the path's own waits (:meth:`noise_s` when the valve closed): not judged.
    """

    def __init__(
        self,
        queue_max_s: float = 0.03,
        window_s: float = 10.0,
        settle_s: float = 0.2,
        fresh_s: float = 1.0,
        steep_slope: float = 0.5,
        lone_s: float = 1.0,
        standing_window_s: float = 60.0,
        slotted_s: float = math.inf,
    ) -> None:
        given = {
            "queue_max_s": queue_max_s,
            "window_s": window_s,
            "settle_s": settle_s,
            "steep_slope": steep_slope,
            "lone_s": lone_s,
            "standing_window_s": standing_window_s,
        }
        for name, v in given.items():
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} = {v!r}: allowed: a finite number > 0")
        self.queue_max_s, self.settle_s, self.fresh_s = float(queue_max_s), float(settle_s), float(fresh_s)
        self.steep_slope, self.lone_s = float(steep_slope), float(lone_s)
        if not slotted_s > 0:
            raise ValueError(f"slotted_s = {slotted_s!r}: allowed: a number > 0 (inf: never)")
        self.slotted_s = float(slotted_s)
        self._clear = (-math.inf, 0.0)  # the last sample under half queue_max: (its send stamp [s], queue [s])
        self._last_close = -math.inf
        self._dip = False  # the open rise is a lone dip of the path's
        self._rise = DelayRise(window_s, span_s=2.0 * queue_max_s)
        self._standing = StandingQueue(standing_window_s, STANDING_HOLD_S)  # over a 60 s minimum
        self._last_sent = -math.inf
        self._closed_at: float | None = None
        self._settle_until = math.inf
        self.queue_s = 0.0
        self.standing_s = 0.0
        self.at = -math.inf
        self.held = 0
        self.rebased = 0
        self.drained = 0
        self.passed = 0
        self.dips = 0
        self._held_at_close = 0
        self._open: deque[tuple[float, float]] = deque()  # (t [s], queue [s]) while the valve was open, NOISE_WINDOW_S
        self._peak = 0.0  # the open closing's highest queue [s]
        self._noise_at_close = 0.0
        self.jitter = 0

    def echo(self, now: float, t_sent: float, t_recv: float, *, under_ceiling: bool = False) -> None:
        """Take a command's echo at ``now`` [s]: the newest feedback's send stamp [s, ours] and receive time [s, the leader's].

        The same feedback echoed again (no newer one arrived) is no new sample.
        ``under_ceiling``: the budget's estimate is under what the path carried at its last
        cut, so a lone closing is the path's dip however slowly it rose (module docstring).
        """
        if not (math.isfinite(t_sent) and math.isfinite(t_recv)) or t_sent <= self._last_sent:
            return
        self._last_sent = t_sent
        self.queue_s = self._rise.add(now, t_recv - t_sent)  # the one-way delay plus the clocks' offset
        self._stand(now)
        self.at = now
        if self.queue_s <= 0.5 * self.queue_max_s:
            self._clear = (t_sent, self.queue_s)
        if self.queue_s <= self.queue_max_s:
            self._open.append((now, self.queue_s))
            while self._open[0][0] < now - NOISE_WINDOW_S:
                self._open.popleft()
            if self._closed_at is not None and self.held > self._held_at_close and self._dip:
                self.dips += 1  # a lone dip of the path's, video waited it out
            elif self._closed_at is not None and self.held > self._held_at_close and self._within_noise():
                self.jitter += 1  # no higher than the path's own waits: proves nothing
            elif self._closed_at is not None and self.held > self._held_at_close:
                self.drained += 1  # it drained once video waited: a queue of ours
            elif self._closed_at is not None:
                self.passed += 1  # it drained with no video held: by itself
            self._closed_at = None
            return
        if self._closed_at is None:  # video waits from now; a queue of ours shows drained a round trip later
            self._closed_at, self._held_at_close = now, self.held
            self._noise_at_close, self._peak = self.noise_s(now), self.queue_s
            sent, low = self._clear  # risen faster than steep_slope since the queue was low: the path's
            steep = self.queue_s - low > self.steep_slope * (t_sent - sent)
            slotted = self._noise_at_close >= self.slotted_s  # a link's slow stretch, however slow the rise
            self._dip = (steep or under_ceiling or slotted) and now - self._last_close >= self.lone_s
            self._last_close = now
            self._settle_until = now + max(0.0, now - t_sent) + self.settle_s
            return
        self._peak = max(self._peak, self.queue_s)
        if now > self._settle_until:  # it did not drain: the path's own delay rose
            self._rise.rebase(now)
            self._standing.clear()
            self._stand(now)
            self.queue_s = 0.0
            self._closed_at = None
            self.rebased += 1

    def noise_s(self, now: float) -> float:
        """Return the path's own waits at ``now`` [s]: the queue's upper quartile over :data:`NOISE_WINDOW_S` while the valve was open.

        A link that delivers in slots makes the echo wait whatever is sent (the module
        docstring's figures).
        """
        ordered = sorted(q for t, q in self._open if t >= now - NOISE_WINDOW_S)
        if not ordered:
            return 0.0
        return ordered[(3 * (len(ordered) - 1)) // 4]

    def _within_noise(self) -> bool:
        """Say whether the closing that drained never passed ``queue_max_s`` by more than the path's waits when it closed."""
        return self._peak <= self.queue_max_s + self._noise_at_close

    def _stand(self, now: float) -> None:
        """Take the current delay into the standing queue's minimum at ``now`` [s]."""
        current = self._rise.current
        assert current is not None
        self.standing_s = self._standing.add(now, current)

    def fresh(self, now: float) -> bool:
        """Say whether the last sample came within ``fresh_s`` of ``now`` [s] (commands are coming: the queue is current)."""
        return now - self.at < self.fresh_s

    def closed(self, now: float) -> bool:
        """Say whether video waits at ``now`` [s]: the queue is over ``queue_max_s`` and the echo is fresh."""
        return self._closed_at is not None and self.fresh(now)

    def counters(self) -> dict[str, int]:
        """Return the Status figures: the queue [ms], video held, rises rebased, drained with video held / without."""
        return {
            "uplink_owd_ms": round(1000.0 * self.queue_s),
            "uplink_owd_held": self.held,
            "uplink_rebased": self.rebased,
            "uplink_owd_drained": self.drained,
            "uplink_owd_passed": self.passed,
            "uplink_owd_dips": self.dips,
            "uplink_owd_jitter": self.jitter,
        }
