"""Clock-offset synchronisation: the peer's clock from 4-timestamp ping exchanges.

Two clock modes (``[clock] mode``):

``synced``
    Leader and follower share one clock (same host, docker, or hosts disciplined by
    chrony/PTP). The one-way delay of a message is ``t_recv - t_sent`` directly.
``ntp``
    The clocks differ by an unknown offset. A 4-timestamp ping exchange
    (:class:`ClockSync`) estimates the offset (remote minus local) from the exchanges
    with the smallest round trip (the least queued one of the last ``memory_s``, 60 s,
    while the recent ones are queued: a one-sided queue does not move it); the
    receiver converts the sender's send time to its own clock with
    :meth:`ClockSync.to_local` before feeding the
    :class:`~bipedtele.link.delayestimate.DelayEstimator`. The
    exchange is bound to the peer: ``t1`` is kept locally per ping, answers must match
    a ping we sent, come from the bound peer and show a short responder hold time (see
    :class:`ClockSync`).

    Caveat: the offset estimate assumes a symmetric path. If the forward and backward
    delays differ by ``a = h_fwd - h_bwd``, the estimated offset is wrong by ``a / 2``,
    so each measured one-way delay is wrong by ``±a / 2``. The *sum* h1 + h2 (the round
    trip) is exact; the *split* between h1 and h2 is only known up to the asymmetry.
    For the stability conditions (paper eq. 40) use
    :func:`~bipedtele.link.delayestimate.conservative_delays`, the bound h1 = h2 = round trip,
    which holds whatever the asymmetry.

The delay estimation (:class:`DelayEstimator`, :func:`conservative_delays`) is in
:mod:`bipedtele.link.delayestimate`; both names are re-exported here.

All times are in seconds.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

from bipedtele.link.delayestimate import DelayEstimator, conservative_delays

__all__ = ["ClockSync", "DelayEstimator", "SyncSample", "conservative_delays"]

_INF = math.inf


@dataclass(frozen=True)
class SyncSample:
    """One NTP-style exchange.

    Attributes
    ----------
    offset : float
        Remote clock minus local clock [s], assuming a symmetric path.
    rtt : float
        Round trip without the responder's processing time [s].
    t4 : float
        Local time the answer arrived [s].
    """

    offset: float
    rtt: float
    t4: float


class ClockSync:
    """Clock offset from 4-timestamp ping exchanges, min-RTT filtered over a long memory.

    The requester sends a ping at ``t1`` (local clock); the responder receives it at
    ``t2`` and answers at ``t3`` (remote clock); the answer arrives at ``t4`` (local)::

        offset = ((t2 - t1) + (t3 - t4)) / 2      # remote - local
        rtt    = (t4 - t1) - (t3 - t2)

    An exchange's offset is off by half its path asymmetry, so a queue on one direction
    only (e.g. a capped uplink) shifts it by half the queue. The least queued exchanges
    give the estimate, chosen in two stages:

    1. **Recent window**: of the last ``window`` exchanges, the one with the smallest
       round trip ``R`` (the newest of equal ones). Its round trip is :attr:`rtt`.
    2. **Long memory**: of the exchanges of the last ``memory_s`` seconds (local
       clock, times of arrival), the best one ``L`` by a drift-aged quality (NTP's
       clock filter): ``rtt + 2 * drift_ppm * 1e-6 * age``. Two clocks drift apart
       by at most ``drift_ppm``, so an exchange of age ``a`` is worth one with a round
       trip ``2 * drift * a`` longer: a stale best exchange is replaced once drift may
       have made it worse than a newer one.

    The offset comes from ``R`` while its round trip is within the tolerance of ``L``'s
    aged quality, ``tolerance_s + tolerance_rel * L.rtt`` (the normal case: exactly
    the estimate of the recent window, fresh after drift and clock steps); otherwise
    ``R`` is queued and the offset comes from ``L``. So a one-sided queue, however long
    its delay, moves the offset by at most half the tolerance, for as long as one
    exchange of the last ``memory_s`` seconds was not queued. A queue lasting longer
    than ``memory_s`` cannot be told from a lasting path change: it is then believed.

    :attr:`rtt` stays the recent window's round trip (as before): it follows a queue,
    so the damping scheduled from it (:func:`conservative_delays`) is never lowered by
    the long memory. :attr:`min_rtt` (the best round trip in memory), :attr:`last_rtt`
    and :attr:`queueing_s` (their difference) show the queue.

    The offset is exact only for a symmetric path: with forward/backward delays
    ``h_f``, ``h_b`` it is off by ``(h_f - h_b) / 2``. One-way delays computed with it
    are therefore only known up to the path asymmetry; only their sum is exact. See
    :func:`conservative_delays` for a bound that does not depend on the split.

    Local clock steps: an answer arriving more than ``STEP_BACK_S`` before the latest
    one (our clock was stepped back) starts the memory and the window afresh (the older
    exchanges are on another time base); a smaller reordering counts as arriving with
    the latest one. A forward step only ages the older exchanges.

    Bound to the peer (use :meth:`sent` and :meth:`on_answer`; :class:`~bipedtele.link.clocklink.ClockLink`
    does it for the apps):

    * ``t1`` is kept *locally* per outstanding ping sequence number and never read from
      the answer. An answer is accepted only for an outstanding ping (each answered once;
      a ping expires ``expire_s`` after it was sent; at most ``max_outstanding`` are
      kept, the oldest forgotten first), otherwise dropped as ``pong_unmatched``.
    * Only answers of the peer session are used: the one given as ``peer`` (the session
      the app's sequence gate follows); others are dropped as ``foreign_session``. While
      no peer is given (none followed yet), any session's answer is used. The estimate
      always comes from one session: an accepted answer of another session than the
      previous samples' (:attr:`peer`), or :meth:`bind` to another session, forgets them
      (another process may run on another clock).
    * The responder's hold time ``t3 - t2`` must be at most ``hold_max_s`` (an honest
      responder answers at once), else ``pong_hold``. So a forged answer cannot make the
      round trip shorter than ``(t4 - t1) - hold_max_s``, ``t4 - t1`` being measured
      locally: it cannot lower the delay-scheduled damping (eq. 40 with
      :func:`conservative_delays`) by more than what ``hold_max_s`` of delay requires.
    * Non-finite times, ``t4 < t1`` or ``t3 < t2``: ``pong_inconsistent``.

    Residual risk: whoever can publish on the clock key with the peer's sid and sees our
    pings (an on-path party: the router, or a user the router's ACL lets subscribe to
    the clock key) can answer a ping before the peer does. It cannot shorten the round
    trip (see above), but it can choose ``t2`` and so shift the offset (hence the
    converted send times of the peer's messages) by any amount; too old commands are
    then dropped (the robot stops, fail-safe), too young ones lower the *split* delay
    estimates, which is why the stability conditions use :func:`conservative_delays`
    in ntp mode. With the long memory, one such answer with a short round trip (a
    claimed hold of up to ``hold_max_s``) may give the offset for up to ``memory_s``
    (not only ``window`` exchanges); :attr:`rtt`, hence the damping, is unaffected.
    With ``network.message_key_file`` set, a forged answer does not even decode (it
    carries no valid MAC): such a party can then only delay answers, which only raises
    the round trip (more damping) and, the least queued exchange being kept, does not
    move the offset.

    Parameters
    ----------
    window : int
        Number of recent exchanges of the recent window (>= 1); ``[clock] ping_window``.
        At the ping rate ``r`` it spans ``window / r`` seconds (16 at 4 Hz: 4 s): the
        time :attr:`rtt` takes to follow a change of the path, and the longest a clock
        step takes to be followed outside a queue.
    memory_s : float
        Long memory [s] (> 0, finite): how long the least queued exchange is kept for
        the offset, hence the longest one-sided queue that does not move it.
    drift_ppm : float
        Bound on the rate difference of the two clocks [ppm] (>= 0, finite): ages the
        quality of older exchanges by ``2 * drift_ppm * 1e-6`` s per s.
    tolerance_s, tolerance_rel : float
        The recent best exchange gives the offset while its round trip is at most the
        long memory's best quality plus ``tolerance_s + tolerance_rel * L.rtt``
        ([s] and a fraction, >= 0, finite). The offset error from a one-sided queue is
        at most half of it: 7.5 ms on a 20 ms path with the defaults (a tolerance of
        0.005 + 0.5 * 0.020 = 15 ms).
    hold_max_s : float
        Largest responder hold time ``t3 - t2`` accepted [s] (> 0).
    expire_s : float
        An outstanding ping not answered within this time is forgotten [s] (> 0).
    max_outstanding : int
        Most outstanding pings kept (>= 1).

    Notes
    -----
    Each exchange costs O(window) (the recent window, as before) plus O(1) amortised
    (the long memory's sliding-window minima); each minimum holds at most
    ``MAX_MEMORY`` exchanges (beyond it the oldest candidates are forgotten).
    Thread-safe: the ClockLink thread feeds it while the control loop reads the offset.
    """

    #: An answer arriving this long [s] before the latest one means our clock stepped back.
    STEP_BACK_S = 0.1
    #: Most exchanges kept in each long-memory minimum (bounds memory at any ping rate).
    MAX_MEMORY = 16384

    def __init__(
        self,
        window: int = 16,
        *,
        memory_s: float = 60.0,
        drift_ppm: float = 50.0,
        tolerance_s: float = 0.005,
        tolerance_rel: float = 0.5,
        hold_max_s: float = 0.05,
        expire_s: float = 5.0,
        max_outstanding: int = 64,
    ) -> None:
        if window < 1:
            raise ValueError(f"window = {window!r}: allowed: an integer >= 1")
        if not (math.isfinite(memory_s) and memory_s > 0):
            raise ValueError(f"memory_s = {memory_s!r}: allowed: a finite number of seconds > 0")
        for name, v in (("drift_ppm", drift_ppm), ("tolerance_s", tolerance_s), ("tolerance_rel", tolerance_rel)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} = {v!r}: allowed: a finite number >= 0")
        if not (math.isfinite(hold_max_s) and hold_max_s > 0):
            raise ValueError(f"hold_max_s = {hold_max_s!r}: allowed: a finite number of seconds > 0")
        if not (math.isfinite(expire_s) and expire_s > 0):
            raise ValueError(f"expire_s = {expire_s!r}: allowed: a finite number of seconds > 0")
        if max_outstanding < 1:
            raise ValueError(f"max_outstanding = {max_outstanding!r}: allowed: an integer >= 1")
        self.window = int(window)
        self.memory_s = float(memory_s)
        self.drift_ppm = float(drift_ppm)
        self.tolerance_s = float(tolerance_s)
        self.tolerance_rel = float(tolerance_rel)
        self.hold_max_s = float(hold_max_s)
        self.expire_s = float(expire_s)
        self.max_outstanding = int(max_outstanding)
        self._age_rate = 2.0 * self.drift_ppm * 1e-6  # quality lost per second of age
        self._hist: deque[SyncSample] = deque(maxlen=window)  # the recent window
        self._recent: SyncSample | None = None  # R: least round trip of the window
        # Long memory: sliding-window minima over (now - memory_s, now] as monotonic
        # deques of (arrival time on the memory's time base, key, sample), keys
        # increasing from the front (the minimum) to the back.
        self._by_quality: deque[tuple[float, float, SyncSample]] = deque()  # key: aged quality
        self._by_rtt: deque[tuple[float, float, SyncSample]] = deque()  # key: round trip
        self._t0 = 0.0  # time base of the memory's keys (precision with epoch times)
        self._now = -_INF  # latest arrival time [s] (local clock)
        self._last: SyncSample | None = None
        self._best: SyncSample | None = None  # the exchange the offset comes from
        self._lock = threading.Lock()
        self._outstanding: dict[int, float] = {}  # ping seq -> t1 (local), oldest first
        self._peer: int | None = None
        self._rejections: dict[str, int] = {}

    # ------------------------------------------------------------------ peer-bound API

    def sent(self, seq: int, t1: float) -> None:
        """Record a ping we sent: sequence number ``seq`` at local time ``t1`` [s]."""
        with self._lock:
            out = self._outstanding
            out.pop(seq, None)
            out[seq] = t1
            # forget expired pings and keep the number bounded (oldest first)
            while out:
                oldest_seq, oldest_t1 = next(iter(out.items()))
                if len(out) > self.max_outstanding or not t1 - oldest_t1 <= self.expire_s:
                    if oldest_seq == seq:
                        break
                    del out[oldest_seq]
                else:
                    break

    def on_answer(
        self, sid: int, ping_seq: int, t2: float, t3: float, t4: float, *, peer: int | None = None
    ) -> str | None:
        """Add the answer to one of our pings, if it is acceptable.

        Parameters
        ----------
        sid : int
            Session id of the answering process.
        ping_seq : int
            Which of our pings it answers (its sequence number as given to :meth:`sent`).
        t2, t3 : float
            Receive and answer times on the responder's clock [s].
        t4 : float
            Local time the answer arrived [s].
        peer : int, optional
            The peer session followed by the caller (e.g. its sequence gate's
            ``live_sid``); None: any session (none is followed yet).

        Returns
        -------
        str or None
            None if accepted (the exchange is added), otherwise the reason it was dropped
            (``foreign_session``, ``pong_unmatched``, ``pong_hold``,
            ``pong_inconsistent``), also counted in :attr:`rejections`.
        """
        with self._lock:
            if peer is not None and sid != peer:
                return self._reject("foreign_session")
            t1 = self._outstanding.get(ping_seq)
            if t1 is None:
                return self._reject("pong_unmatched")
            if math.isfinite(t4) and not t4 - t1 <= self.expire_s:
                del self._outstanding[ping_seq]
                return self._reject("pong_unmatched")
            reason = self._check(t1, t2, t3, t4)
            if reason is not None:
                return self._reject(reason)
            del self._outstanding[ping_seq]
            self._bind(sid)
            self._add(t1, t2, t3, t4)
            return None

    def bind(self, peer: int | None) -> None:
        """Follow session ``peer`` from now on: forget samples of any other session.

        Call it when the followed peer changes, so that the estimate of the previous one
        is not used until the new one answers (None: no change).
        """
        with self._lock:
            self._bind(peer)

    def _bind(self, peer: int | None) -> None:
        if peer is not None and peer != self._peer:
            self._forget()
            self._peer = peer

    def _forget(self) -> None:
        """Forget every exchange (caller holds the lock)."""
        self._hist.clear()
        self._by_quality.clear()
        self._by_rtt.clear()
        self._recent = self._last = self._best = None
        self._now = -_INF

    @property
    def peer(self) -> int | None:
        """Session id whose answers the estimate comes from (None before any)."""
        with self._lock:
            return self._peer

    @property
    def outstanding(self) -> int:
        """Number of pings sent and not yet answered nor expired."""
        with self._lock:
            return len(self._outstanding)

    @property
    def rejections(self) -> dict[str, int]:
        """Rejected answers per reason (a copy)."""
        with self._lock:
            return dict(self._rejections)

    @property
    def rejected(self) -> int:
        """Rejected answers in all."""
        with self._lock:
            return sum(self._rejections.values())

    def clear(self) -> None:
        """Forget the samples and the peer (outstanding pings stay valid)."""
        with self._lock:
            self._forget()
            self._peer = None

    # ------------------------------------------------------------------ exchanges

    def on_pong(self, t1: float, t2: float, t3: float, t4: float) -> SyncSample | None:
        """Add one exchange given all four times (t1, t4 local; t2, t3 remote) [s].

        Low-level: the caller vouches for ``t1`` (prefer :meth:`sent` and
        :meth:`on_answer`, which never take ``t1`` from the answer). The same consistency
        and hold-time checks apply.

        Returns
        -------
        SyncSample or None
            The exchange, or None if it is inconsistent (non-finite times, negative
            round trip or responder time, hold time above ``hold_max_s``) and was
            rejected.
        """
        with self._lock:
            reason = self._check(t1, t2, t3, t4)
            if reason is not None:
                self._reject(reason)
                return None
            return self._add(t1, t2, t3, t4)

    def _check(self, t1: float, t2: float, t3: float, t4: float) -> str | None:
        if not all(math.isfinite(v) for v in (t1, t2, t3, t4)) or t4 < t1 or t3 < t2:
            return "pong_inconsistent"
        if t3 - t2 > self.hold_max_s:
            return "pong_hold"
        if (t4 - t1) - (t3 - t2) < 0:
            return "pong_inconsistent"
        return None

    def _add(self, t1: float, t2: float, t3: float, t4: float) -> SyncSample:
        s = SyncSample(offset=((t2 - t1) + (t3 - t4)) / 2.0, rtt=(t4 - t1) - (t3 - t2), t4=t4)
        if t4 < self._now - self.STEP_BACK_S:
            self._forget()  # our clock was stepped back: the older exchanges are on another base
        if t4 > self._now:
            self._now = t4
        if not self._by_rtt:
            self._t0 = self._now
        now = self._now - self._t0  # a slightly reordered answer counts as arriving now
        self._last = s
        # recent window: least round trip, the newest of equal ones
        self._hist.append(s)
        self._recent = recent = min(reversed(self._hist), key=lambda x: x.rtt)
        # long memory: sliding-window minima of the aged quality and of the round trip
        self._push(self._by_quality, now, s.rtt - self._age_rate * now, s)
        self._push(self._by_rtt, now, s.rtt, s)
        best = self._by_quality[0][2]  # L
        aged = best.rtt + self._age_rate * (now - self._by_quality[0][0])
        if recent.rtt <= aged + self.tolerance_s + self.tolerance_rel * best.rtt:
            best = recent  # not queued: the freshest good exchange
        self._best = best
        return s

    def _push(self, q: deque[tuple[float, float, SyncSample]], now: float, key: float, s: SyncSample) -> None:
        """Add to a sliding-window minimum and drop what left ``(now - memory_s, now]``."""
        while q and q[-1][1] >= key:  # never again the minimum: a newer one is as good
            q.pop()
        q.append((now, key, s))
        start = now - self.memory_s
        while q[0][0] <= start or len(q) > self.MAX_MEMORY:
            q.popleft()  # never the newest: it arrived at ``now``

    def _reject(self, reason: str) -> str:
        self._rejections[reason] = self._rejections.get(reason, 0) + 1
        return reason

    # ------------------------------------------------------------------ estimate

    @property
    def ready(self) -> bool:
        """True once at least one valid exchange is known."""
        with self._lock:
            return self._best is not None

    @property
    def offset(self) -> float:
        """Remote clock minus local clock [s] (0.0 before any exchange)."""
        with self._lock:
            return self._best.offset if self._best else 0.0

    @property
    def rtt(self) -> float | None:
        """Least round trip of the recent window (the last ``window`` exchanges) [s].

        The path's round trip now, queues included: the conservative delays
        ``h1 = h2 = rtt`` (:func:`conservative_delays`) schedule the damping from it.
        None before any exchange.
        """
        with self._lock:
            return self._recent.rtt if self._recent else None

    @property
    def offset_rtt(self) -> float | None:
        """Round trip of the exchange the offset comes from [s] (None before any).

        :attr:`rtt` while the recent window is not queued; the long memory's best
        exchange's (at most :attr:`rtt`) while it is.
        """
        with self._lock:
            return self._best.rtt if self._best else None

    @property
    def min_rtt(self) -> float | None:
        """Least round trip of the exchanges of the last ``memory_s`` seconds [s].

        The path without queues (None before any exchange).
        """
        with self._lock:
            return self._by_rtt[0][2].rtt if self._by_rtt else None

    @property
    def last_rtt(self) -> float | None:
        """Round trip of the latest accepted exchange [s] (None before any)."""
        with self._lock:
            return self._last.rtt if self._last else None

    @property
    def queueing_s(self) -> float | None:
        """Queueing on the path now: :attr:`last_rtt` minus :attr:`min_rtt` [s], >= 0.

        The round trip's excess over the best one in memory; it does not say in which
        direction the queue is (None before any exchange).
        """
        with self._lock:
            if self._last is None or not self._by_rtt:
                return None
            return max(0.0, self._last.rtt - self._by_rtt[0][2].rtt)

    def to_local(self, remote_t: float) -> float:
        """Convert a time on the remote clock to the local clock [s]."""
        return remote_t - self.offset

    def to_remote(self, local_t: float) -> float:
        """Convert a time on the local clock to the remote clock [s]."""
        return local_t + self.offset
