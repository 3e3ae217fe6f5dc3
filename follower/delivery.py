"""What the robot's uplink delivered: a delivery-rate estimate that survives gaps.

The leader reports in each Status what it received of ours over its last 2 s (``rx_bps``):
bytes the path *delivered* per interval, the delivery rate BBR estimates its bottleneck
from (Cardwell et al., "BBR: congestion-based congestion control", ACM Queue 2016). What
the follower *sent* while the path was blocked says nothing of what it carries; what
arrived does, and the highest rate delivered lately is a lower bound of the capacity
(the path carried it).

:class:`DeliveryRate` keeps the windowed maximum of those samples, with two rules of its
own:

- **stalls do not age it.** While the path is stalled (the leader's newest feedback is far
  older than the path's delay: a blackout, a near-zero stretch of a cellular link), its
  samples are left out and the window's clock stops: after a gap the estimate is the last
  good one, not the collapse;
- **samples age out over delivering time only**: ``window_s`` (the budget's
  ``delivery_window_s``, 30 s) of time during which the path delivered, so a path whose
  capacity really fell is believed after that long.

Not thread-safe: the follower's loop thread only.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from collections.abc import Callable

from bipedtele.follower.delayrise import DelayRise

__all__ = ["DeliveryRate", "InFlight"]


class DeliveryRate:
    """Windowed maximum of the delivery rate over delivering time (see the module docstring).

    Parameters
    ----------
    window_s : float
        How much delivering time [s] a sample is kept (the budget keeps 30 s).

    Attributes
    ----------
    stalled : bool
        The last judgement said the path is stalled (set by :meth:`sample`).
    stalls : int
        How many stalls began.
    stall_since : float or None
        When the current stall began [s] (None: not stalled).
    """

    def __init__(self, window_s: float = 10.0) -> None:
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"window_s = {window_s!r}: allowed: a number of seconds > 0")
        self.window_s = float(window_s)
        self._active_s = 0.0  # delivering time so far [s]
        self._last_t: float | None = None
        self._max: deque[tuple[float, float]] = deque()  # (active time, bit/s), values decreasing
        self.stalled = False
        self.stalls = 0
        self.stall_since: float | None = None

    def sample(self, t: float, rx_bps: float, stalled: bool) -> None:
        """Take one delivery-rate sample.

        Parameters
        ----------
        t : float
            When the leader measured it, on the follower's clock [s] (one earlier than the
            last sample's, a Status sent before the last command judged, counts as at it).
        rx_bps : float
            What the path delivered over the leader's window [bit/s] (>= 0).
        stalled : bool
            Whether the path is stalled now (its samples are left out, its time not counted).
        """
        last = self._last_t
        t = t if last is None else max(t, last)
        self._last_t = t
        if stalled:
            if not self.stalled:
                self.stalls += 1
                self.stall_since = t
            self.stalled = True
            return
        if last is not None and not self.stalled:
            self._active_s += max(0.0, t - last)
        self.stalled, self.stall_since = False, None
        if not (math.isfinite(rx_bps) and rx_bps > 0):
            return
        q = self._max
        while q and q[-1][1] <= rx_bps:
            q.pop()
        q.append((self._active_s, float(rx_bps)))
        while q and q[0][0] < self._active_s - self.window_s:
            q.popleft()

    @property
    def max_bps(self) -> float | None:
        """The highest rate delivered over the last ``window_s`` of delivering time [bit/s] (None: no sample)."""
        return self._max[0][1] if self._max else None


class InFlight:
    """Bytes sent on the uplink and not yet known delivered, capped near the bandwidth-delay product.

    BBR bounds what a sender keeps in flight to about twice the bandwidth-delay product
    (Cardwell et al. 2016): when the path stops delivering, the sender stops adding to its
    queue within about one round trip, whatever its rate estimate says. Here the
    acknowledgement is the leader's Status: the newest feedback it received was sent at
    ``t_status - fb_age_ms`` (the follower's clock), so everything the follower sent up to
    then has left the path's queue (one FIFO queue at the bottleneck; a message lost there
    is counted delivered, so loss never holds the cap shut). What was sent after it is in
    flight.

    The cap is ``gain x rate x (min_rtt + ack_interval)`` [bytes], at least ``min_bytes``:
    the delivery rate (:class:`DeliveryRate`), the least round trip seen over ``rtt_window_s``
    (status receive time minus the acknowledged feedback's send time) and the mean interval
    between acknowledgements over the same window (the leader's status period: a sender acknowledged every 0.5 s
    keeps up to 0.5 s of its rate in flight between two, BBR's allowance for aggregated
    acknowledgements; ``ack_prior_s`` until two were seen: a cap learnt from one round
    trip alone held a LAN's feedback for a status period after every hand-over). The gain
    leaves room for a rate above the one delivered so far (the delivery rate of an
    application-limited sender is what it sent, and a cap at it would only ratchet down).
    Until the first acknowledgement with a rate the cap is infinite. On a path the budget
    calls lossy (``lossy``, asked at each use) the interval is the longest of the window, not the mean: a
    Status lost on its way (one in twenty at 5 % loss) leaves the next acknowledgement two
    periods after the last, and against the mean each one held video (125 frames in one
    90 s run, docs/network.md).

    Video fills at most ``video_share`` of the cap: the rest is the feedback's between two
    acknowledgements (video that filled the cap held every feedback until the next
    acknowledgement, up to a status period: the operator's feedback aged by it). Over the
    cap video waits and feedback is held (the newest is sent once the cap opens):
    what is in flight is acknowledged once the path delivers again, and that opens the cap,
    so nothing sent in a gap waits in the path's queue to arrive stale after it. A feedback
    never leaves over the cap: one sent into a stalled path can only arrive old, and the
    operator would be shown it. Only when no acknowledgement advanced for ``probe_s`` (what
    was in flight may have been lost) one follower Status leaves as a probe
    (:meth:`admit_probe`), then again after twice as long, up to ``8 probe_s`` (TCP's
    retransmission back-off); the leader echoes the newest Status's send stamp
    (``uplink_t_us``, TCP's timestamp echo), which acknowledges everything sent before it,
    so the first feedback leaves once the path is known to deliver and arrives fresh.
    Each acknowledgement is also a round-trip sample: its rise over the
    minimum is the path's queue now (``queue_s``, the least of the last three samples over
    the minimum), seen a few status periods after it formed rather than through the
    leader's 1 s mean of h2 (about 0.75 s late; LEDBAT's and BBR's signal); while it
    exceeds ``video_queue_s`` video waits too, so that no more than about that much link
    time queues ahead of the feedback. See docs/network.md, "No backlog of the robot's
    own". Thread-safe (the video thread counts too).

    Parameters
    ----------
    gain : float
        Multiple of the bandwidth-delay product kept in flight [-] (2, BBR's cwnd gain).
    min_bytes : float
        The least cap [bytes] (a frame part and a few feedback always fit).
    probe_s : float
        Over the cap without an acknowledgement advancing for this long [s], one Status
        leaves as a probe (then after 2, 4, 8 times as long); a feedback never does.
    rtt_window_s : float
        Window of the round trip's minimum [s].
    video_queue_s : float
        Video waits while the last round trip exceeds its minimum by more than this [s]
        (a sample older than ``1 s`` is not used).
    video_share : float
        Share of the cap video may fill [-] (the rest is the feedback's).
    ack_prior_s : float
        The acknowledgements' interval taken until two were seen [s] (the leader's default
        status period).
    lossy : callable, optional
        Says whether the path is lossy now (the budget's judgement, from the leader's
        feedback loss): the cap then allows for the longest interval between
        acknowledgements of the window. Default: never.
    """

    def __init__(
        self,
        gain: float = 2.0,
        min_bytes: float = 4000.0,
        probe_s: float = 1.0,
        rtt_window_s: float = 10.0,
        video_queue_s: float = 0.05,
        video_share: float = 0.75,
        ack_prior_s: float = 0.5,
        lossy: Callable[[], bool] | None = None,
    ) -> None:
        checked = (
            ("gain", gain),
            ("min_bytes", min_bytes),
            ("probe_s", probe_s),
            ("rtt_window_s", rtt_window_s),
            ("video_queue_s", video_queue_s),
            ("ack_prior_s", ack_prior_s),
        )
        for name, v in checked:
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} = {v!r}: allowed: a finite number > 0")
        if not (math.isfinite(video_share) and 0 < video_share <= 1):
            raise ValueError(f"video_share = {video_share!r}: allowed: a number in (0, 1]")
        self.video_share, self.ack_prior_s = float(video_share), float(ack_prior_s)
        self.gain, self.min_bytes, self.probe_s = float(gain), float(min_bytes), float(probe_s)
        self._lock = threading.Lock()
        self._sent: deque[tuple[float, int]] = deque()  # (send time [s], bytes), in send order
        self._bytes = 0
        self._acked_t = -math.inf
        self._rtt = DelayRise(rtt_window_s)  # the round trip's minimum and the queue above it
        self._last_ack: float | None = None
        self._rtt_window_s = float(rtt_window_s)
        self._intervals: deque[tuple[float, float]] = deque()  # (when [s], interval [s]) of the window
        self._lossy = lossy if lossy is not None else (lambda: False)
        self.rate_bps: float | None = None
        self._last_probe = -math.inf
        self._progress = -math.inf  # when an acknowledgement last advanced [s]
        self._backoff = 1.0  # the probe interval's multiple (doubles per probe, up to 8)
        self.video_queue_s = float(video_queue_s)
        #: The last round trip above its minimum [s] (the path's queue when it was acknowledged).
        self.queue_s = 0.0
        #: Set by the budget while the path is stalled: the cap is then one message (TCP's
        #: window after a retransmission timeout): a feedback leaves only when nothing of
        #: ours waits in the path, so it arrives fresh; over it, Status probes only.
        self.hold = False
        #: Messages held back by the cap: ``feedback`` (coalesced), ``video`` (waited or
        #: dropped; ``video_rtt`` of them by the round trip's queue, not the cap's room),
        #: ``status`` (not a probe); ``probes``: the Status sent over it as probes.
        self.held = {"feedback": 0, "video": 0, "video_rtt": 0, "status": 0, "probes": 0}

    def sent(self, t: float, nbytes: int) -> None:
        """Count ``nbytes`` [bytes] sent at ``t`` [s] (any thread)."""
        with self._lock:
            if self._sent and t < self._sent[-1][0]:
                t = self._sent[-1][0]  # threads may stamp out of order: keep the queue sorted
            self._sent.append((t, int(nbytes)))
            self._bytes += int(nbytes)

    def acked(self, now: float, t_delivered: float, rate_bps: float | None) -> None:
        """Take an acknowledgement: everything sent up to ``t_delivered`` [s] was delivered.

        Parameters
        ----------
        now : float
            When the acknowledgement arrived [s].
        t_delivered : float
            Send time of the newest feedback the leader had received [s] (the follower's clock).
        rate_bps : float or None
            The path's delivery rate now [bit/s] (None: not known; the cap stays open).
        """
        if not math.isfinite(t_delivered):
            return
        if self._last_ack is not None and now > self._last_ack:
            with self._lock:  # the video thread reads them (cap_bytes)
                self._interval(now, now - self._last_ack)
        self._last_ack = now
        self.rate_bps = rate_bps if rate_bps is not None and rate_bps > 0 else None
        # each sample adds the wait between the feedback's arrival and the status (up to a
        # feedback period): noise of one sign, which the filter takes out
        with self._lock:  # the video thread reads the minimum (cap_bytes)
            self.queue_s = self._rtt.add(now, max(0.0, now - t_delivered))
        self.delivered(now, t_delivered)

    def _interval(self, now: float, dt: float) -> None:
        """Take the interval ``dt`` [s] between two acknowledgements, the second at ``now`` [s] (under the lock)."""
        self._intervals.append((now, dt))
        while self._intervals[0][0] < now - self._rtt_window_s:
            self._intervals.popleft()

    def _interval_s(self, longest: bool) -> float | None:
        """Return the window's mean interval between acknowledgements, or its longest [s] (None until two were seen)."""
        with self._lock:
            gaps = [dt for _, dt in self._intervals]
        if not gaps:
            return None
        return max(gaps) if longest else sum(gaps) / len(gaps)

    @property
    def ack_interval_s(self) -> float | None:
        """The mean interval between acknowledgements over the window [s] (None until two were seen)."""
        return self._interval_s(longest=False)

    def delivered(self, now: float, t_delivered: float) -> None:
        """Take the leader's word that everything sent up to ``t_delivered`` [s] arrived (no round-trip sample).

        The echo of a follower Status's send stamp: a probe, or a Status sent a status
        period before the leader's report (too old to be a round-trip sample).

        Parameters
        ----------
        now : float
            When the word arrived [s].
        t_delivered : float
            Send time of the newest message the leader had received [s] (the follower's clock).
        """
        if not math.isfinite(t_delivered):
            return
        with self._lock:
            if t_delivered <= self._acked_t:
                return
            self._acked_t = t_delivered
            self._progress, self._backoff = now, 1.0
            while self._sent and self._sent[0][0] <= t_delivered:
                self._bytes -= self._sent.popleft()[1]

    def reset(self) -> None:
        """Forget what is in flight and what the acknowledgements said: the cap is open (infinite) until the next one.

        For a leader that left (nobody acknowledges) or a new leader session (its own path
        and acknowledgements); the counts of what was held stay. Called every tick while
        nobody acknowledges: a reset state is left as it is.
        """
        if (
            self._last_ack is None
            and self.rate_bps is None
            and not self._sent
            and self._rtt.minimum is None
            and not self.hold
        ):
            return
        with self._lock:
            self._sent.clear()
            self._bytes = 0
            self._acked_t = -math.inf
            self._rtt.clear()
            self._intervals.clear()
        self._last_ack = None
        self.rate_bps = None
        self._last_probe = self._progress = -math.inf
        self._backoff = 1.0
        self.queue_s = 0.0
        self.hold = False

    @property
    def bytes(self) -> int:
        """Bytes in flight: sent after the newest acknowledged feedback."""
        with self._lock:
            return self._bytes

    def undelivered(self, after: float, by: float) -> bool:
        """Say whether a message sent after ``after`` and by ``by`` [s] is still in flight.

        With ``after`` the send time of the newest feedback the leader has and ``by`` the
        latest send time that should have arrived by now: the path failed to deliver.
        """
        with self._lock:  # the log is in send order: the first sent after ``after`` by bisection
            i = bisect.bisect_right(self._sent, after, key=lambda entry: entry[0])
            return i < len(self._sent) and self._sent[i][0] <= by

    @property
    def min_rtt_s(self) -> float | None:
        """The least round trip over the window [s] (None before the first acknowledgement)."""
        with self._lock:
            return self._rtt.minimum

    @property
    def cap_bytes(self) -> float:
        """The cap [bytes]: ``gain x rate x (min_rtt + ack_interval)``, at least ``min_bytes``; infinite until known."""
        rtt = self.min_rtt_s
        if self.rate_bps is None or rtt is None:
            return math.inf
        interval = self._interval_s(longest=self._lossy())  # the longest is at least the mean
        ack = self.ack_prior_s if interval is None else interval
        return max(self.min_bytes, self.gain * self.rate_bps / 8.0 * (rtt + ack))

    @property
    def over(self) -> bool:
        """True while what is in flight reaches the cap; while :attr:`hold` is set, while anything is in flight."""
        return self.bytes > 0 if self.hold else self.bytes >= self.cap_bytes

    def admit_feedback(self, now: float) -> bool:
        """Say whether a feedback may leave at ``now`` [s]: only under the cap.

        Over it the feedback is held (the next one carries the newest state): one sent
        into a path that does not deliver arrives old, and the operator would be shown it.
        """
        if not self.over:
            return True
        self.held["feedback"] += 1
        return False

    def admit_probe(self, now: float) -> bool:
        """Say whether a Status may leave at ``now`` [s]: under the cap, or as a probe over it.

        Over the cap, with no acknowledgement advancing for ``probe_s`` (then 2, 4, 8 times
        as long after each probe), one Status leaves: the leader's echo of it tells the
        follower that the path delivers again, also when what was in flight was lost.
        """
        if not self.over:
            return True
        wait = self.probe_s * self._backoff
        if now - max(self._progress, self._last_probe) >= wait:
            self._last_probe = now
            self._backoff = min(8.0, 2.0 * self._backoff)
            self.held["probes"] += 1
            return True
        self.held["status"] += 1
        return False

    def admit_video(self, nbytes: int, now: float | None = None) -> bool:
        """Say whether a video message of ``nbytes`` [bytes] fits under the cap now.

        Video fills at most ``video_share`` of the cap (its room). A message larger than
        half the room is taken once what is in flight leaves half the room free (a frame
        larger than the cap is never shut out for good). With ``now`` [s]: not while the
        last acknowledgement (under 1 s old) showed more than ``video_queue_s`` of queue
        with more than ``cap / gain`` in flight.
        """
        cap = self.cap_bytes
        room = self.video_share * cap
        ok, valve = self.bytes + min(float(nbytes), 0.5 * room) <= room, False
        if ok and now is not None and self._last_ack is not None and now - self._last_ack < 1.0:
            # a queue of ours: the round trip rose and more than one bandwidth-delay product is
            # in flight (a rise of the path's own delay with nothing queued keeps under it)
            valve = self.bytes > cap / self.gain and self.queue_s > self.video_queue_s
            ok = not valve
        if not ok:
            with self._lock:
                self.held["video"] += 1
                self.held["video_rtt"] += valve
        return ok

    def counters(self) -> dict[str, int]:
        """Return the Status figures: bytes in flight, the cap [bytes] (0: open), what was held, the round trip's queue [ms]."""
        cap = self.cap_bytes
        return {
            "uplink_inflight_bytes": self.bytes,
            "uplink_inflight_cap": round(cap) if math.isfinite(cap) else 0,
            "uplink_held_feedback": self.held["feedback"],
            "uplink_held_video": self.held["video"],
            "uplink_held_video_rtt": self.held["video_rtt"],
            "uplink_probes": self.held["probes"],
            "uplink_queue_ms": round(1000.0 * self.queue_s),
        }
