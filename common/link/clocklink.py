"""Clock pings for both nodes: answer the peer's, send ours, feed our ClockSync.

One implementation for the leader and the follower, on its own thread (never the control
loop's). The Zenoh receiver of the clock key hands every decoded
:class:`~bipedtele.link.messages.ClockPing` / :class:`~bipedtele.link.messages.ClockPong` to
:meth:`ClockLink.on_message`, which only filters and enqueues (O(1), never blocks); the
link's thread answers and matches.

* **Answers** (both modes): a ping gets a :class:`~bipedtele.link.messages.ClockPong` with
  ``t2`` = its receive time and ``t3`` = the answer's send time. At most
  ``answer_rate_hz`` pings are answered per second (token bucket, bursts of
  ``max(1, answer_rate_hz / 4)``; excess: ``ping_rate_limited``). While ``peer_sid()``
  names a session only its pings are answered, and those of sessions ``also_answer(sid)``
  admits (the follower: leader sessions that completed the handshake, e.g. one waiting
  for a robot another operator holds); others: ``foreign_session``. Before, any
  session's are. Our own messages are ignored. A ping that waited longer than
  ``hold_max_s`` before its answer could be sent is not answered (``ping_late``): the
  peer would drop the answer.
* **Pings** (``sync`` given, ntp mode): sent at ``ping_rate_hz`` (and at once when the
  followed peer changes), each recorded with its local send time in the
  :class:`~bipedtele.link.clock.ClockSync`; an answer is used only if it matches a ping we
  sent, comes from the followed peer and shows a short hold time (see ClockSync; the
  reasons of the drops are counted).

Ping rate, window and memory: the link does not build the ClockSync; the node does,
as ``ClockSync(clock.ping_window)``, and gives the link ``clock.ping_rate_hz``. The
ClockSync's ``window`` counts *exchanges*: its recent window spans ``ping_window /
ping_rate_hz`` seconds (16 at 4 Hz: 4 s), the time its ``rtt`` (hence the conservative
damping) takes to follow a queue and, outside a queue, a clock step. Its long memory
``memory_s`` (60 s by default) is in *seconds*, whatever the ping rate (240 exchanges
at 4 Hz): the least queued exchange of that time gives the offset while the recent
window is queued, so a one-sided queue shorter than ``memory_s`` does not move the
offset (issue 19). An answer held in a queue longer than the ClockSync's ``expire_s``
(5 s) no longer matches a ping (``pong_unmatched``): the offset is then held as it is.

Every message a link sends on the clock key carries its ``sid`` and one strictly
increasing ``seq`` (pings and answers share the counter). The ``sid`` must be the one
the peer's sequence gate binds to (the node's command or feedback sid), so that
``peer_sid`` on the other side names this process.

Usage (follower; the leader passes its feedback receiver's gate)::

    cmd_gate = SequenceGate(takeover_after_s=fcfg.watchdog_s)
    link = stack.enter_context(ClockLink(
        pubs.clock.put, loop.sid, sync=sync if ntp else None, drops=drops,
        answer_rate_hz=ck.answer_rate_hz, ping_rate_hz=ck.ping_rate_hz,
        peer_sid=lambda: cmd_gate.live_sid))
    stack.enter_context(LatestReceiver(
        session, keys.clock, (ClockPing, ClockPong), drops,
        ignore_sid=loop.sid, on_message=link.on_message))

The clock receiver gets no ``clock_sync``, ``max_future_s`` nor gate: a ping is stamped
on the peer's clock (ntp mode), and the link does its own matching.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from bipedtele.link.clock import ClockSync
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import ClockPing, ClockPong, Message

if TYPE_CHECKING:
    from bipedtele.link.receivers import Received

__all__ = ["ClockLink"]

LOG = logging.getLogger("bipedtele.link.clocklink")

_MAX_WAIT_S = 0.1  # the thread looks at peer_sid() at least this often [s]


class ClockLink:
    """Send, answer and match clock pings off the control loop, bound to the peer.

    Parameters
    ----------
    publish : callable
        Sends one message on the clock key (e.g. ``pubs.clock.put``). Called from the
        link's thread only; an exception is logged and counted (``publish_errors``).
    sid : int
        This process's session id (the one its commands or feedback carry).
    sync : ClockSync, optional
        ntp mode: send pings and feed the answers to it. None (synced mode): only answer.
    drops : DropCounter
        Where dropped clock messages are counted by reason.
    clock : callable
        Time source for message stamps [s]: the same clock that stamps the receiver's
        ``t_recv`` (``time.time``), since ``t2`` comes from there and ``t3`` from here.
    ping_rate_hz : float
        Pings per second in ntp mode [Hz] (> 0). With ``sync.window`` it sets how many
        seconds the ClockSync's recent window spans (``window / ping_rate_hz``); its long
        memory (``sync.memory_s``) is in seconds and does not depend on it.
    answer_rate_hz : float
        Most pings answered per second [Hz] (> 0; ``clock.answer_rate_hz``).
    peer_sid : callable
        Returns the session this node follows now (e.g. ``gate.live_sid`` of the
        command receiver on the follower, of the feedback receiver on the leader), or
        None while it follows none. Polled by the link's thread (at least every 0.1 s).
    also_answer : callable, optional
        ``also_answer(sid) -> bool``: answer this other session's pings too (the
        follower: :meth:`bipedtele.link.session.Handshake.answers`). None: the followed only.
    monotonic : callable
        Monotonic time source for pacing and rate limits [s] (injectable for tests).
    queue_max : int
        Bound of the queue between :meth:`on_message` and the thread (overflow: dropped,
        counted as ``overflow``).
    hold_max_s : float, optional
        Longest wait between a ping's arrival and its answer [s]; default: ``sync``'s
        ``hold_max_s`` or 0.05 s (what the peer's ClockSync accepts).

    Attributes
    ----------
    answered, rate_limited, pings_sent, pongs_accepted, pongs_rejected : int
        Counters (see also :meth:`counters`).

    Notes
    -----
    Use as a context manager (starts and stops the thread) or call :meth:`start` and
    :meth:`close`. Tests may instead drive :meth:`poll` by hand with fake clocks.
    """

    def __init__(
        self,
        publish: Callable[[Message], None],
        sid: int,
        *,
        sync: ClockSync | None,
        drops: DropCounter,
        clock: Callable[[], float] = time.time,
        ping_rate_hz: float = 4.0,
        answer_rate_hz: float = 20.0,
        peer_sid: Callable[[], int | None] = lambda: None,
        also_answer: Callable[[int], bool] | None = None,
        monotonic: Callable[[], float] = time.monotonic,
        queue_max: int = 256,
        hold_max_s: float | None = None,
    ) -> None:
        for name, rate in (("ping_rate_hz", ping_rate_hz), ("answer_rate_hz", answer_rate_hz)):
            if not (math.isfinite(rate) and rate > 0):
                raise ValueError(f"{name} = {rate!r}: allowed: a finite rate > 0 Hz")
        if queue_max < 1:
            raise ValueError(f"queue_max = {queue_max!r}: allowed: an integer >= 1")
        hold = (sync.hold_max_s if sync is not None else 0.05) if hold_max_s is None else hold_max_s
        if not (math.isfinite(hold) and hold > 0):
            raise ValueError(f"hold_max_s = {hold!r}: allowed: a finite number of seconds > 0")
        self.sid = sid
        self.sync = sync
        self.drops = drops
        self.ping_period_s = 1.0 / ping_rate_hz
        self.answer_rate_hz = float(answer_rate_hz)
        self.hold_max_s = float(hold)
        self._publish = publish
        self._clock = clock
        self._mono = monotonic
        self._peer_sid = peer_sid
        self._also_answer = also_answer
        self._peer: int | None = None  # cached for on_message (read without a lock)
        self._seq = 0
        self._next_ping = -math.inf
        # queue and token bucket, shared with the receiver's callback threads
        self._qlock = threading.Lock()
        self._q: deque[Received[Message]] = deque()
        self._qmax = int(queue_max)
        self._burst = max(1.0, self.answer_rate_hz / 4.0)
        self._tokens = self._burst
        self._t_tokens = monotonic()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        # counters
        self.answered = 0
        self.rate_limited = 0
        self.pings_sent = 0
        self.pongs_accepted = 0
        self.pongs_rejected = 0
        self.foreign = 0
        self.overflow = 0
        self.late = 0
        self.publish_errors = 0

    # ------------------------------------------------------------------ receiver side

    def on_message(self, rec: Received[Any]) -> None:
        """Take one received clock message (called from the receiver's callback).

        O(1), never blocks on the network or on the link's work: drops our own
        messages, other sessions' once a peer is followed, pings beyond the answer rate
        and answers to other processes' pings; enqueues the rest for the thread.
        """
        if self._closed:
            return
        msg = rec.msg
        sid = msg.sid
        if sid == self.sid:
            return
        peer = self._peer
        if isinstance(msg, ClockPong) and msg.ping_sid != self.sid:
            return  # another pair's exchange on the shared key
        if not isinstance(msg, (ClockPing, ClockPong)):
            return
        reason = None
        with self._qlock:
            if peer is not None and sid != peer and not self._answers_also(msg):
                self.foreign += 1
                reason = "foreign_session"
            elif isinstance(msg, ClockPing) and not self._take_token():
                self.rate_limited += 1
                reason = "ping_rate_limited"
            elif len(self._q) >= self._qmax:
                self.overflow += 1
                reason = "overflow"
            else:
                self._q.append(rec)
        if reason is None:
            self._wake.set()
        else:
            self.drops.drop(reason, f"clock {msg.KIND} sid={sid} seq={msg.seq}")

    def _answers_also(self, msg: Any) -> bool:
        """Whether a ping of a session other than the followed one is answered too."""
        return isinstance(msg, ClockPing) and self._also_answer is not None and self._also_answer(msg.sid)

    def _take_token(self) -> bool:
        """Token bucket (caller holds ``_qlock``)."""
        now = self._mono()
        elapsed = now - self._t_tokens
        if elapsed > 0:
            self._tokens = min(self._burst, self._tokens + elapsed * self.answer_rate_hz)
        self._t_tokens = max(self._t_tokens, now)
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False

    # ------------------------------------------------------------------ link thread

    def poll(self) -> float:
        """Do the link's pending work once: follow the peer, answer, match, ping.

        Returns
        -------
        float
            Seconds until the next thing is due (the thread waits at most that long).
        """
        now_m = self._mono()
        self._follow_peer(now_m)
        with self._qlock:
            batch, self._q = self._q, deque()
        for rec in batch:
            try:
                if isinstance(rec.msg, ClockPing):
                    self._answer(rec)
                else:
                    self._match(rec)
            except Exception as exc:  # one bad message must not stop the link
                self.drops.drop("clock_error", f"{type(exc).__name__}: {exc}")
        if self.sync is not None and now_m >= self._next_ping:
            late = now_m - self._next_ping
            # keep the cadence; after a stall (or the first time) start again from now
            self._next_ping = (self._next_ping if late < self.ping_period_s else now_m) + self.ping_period_s
            self._ping()
        due = self._next_ping - now_m if self.sync is not None else _MAX_WAIT_S
        return min(max(due, 0.0), _MAX_WAIT_S)

    def _follow_peer(self, now_m: float) -> None:
        try:
            peer = self._peer_sid()
        except Exception as exc:
            LOG.warning("clock link: peer_sid() failed: %s", exc)
            peer = None
        if peer == self._peer:
            return
        self._peer = peer
        if peer is not None and self.sync is not None:
            self.sync.bind(peer)  # forget another session's clock
            self._next_ping = now_m  # and ask the new peer at once

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def _send(self, msg: Message) -> bool:
        try:
            self._publish(msg)
        except Exception as exc:
            self.publish_errors += 1
            if self.publish_errors == 1 or self.publish_errors % 1000 == 0:
                LOG.warning("clock link: publish failed (%d so far): %s", self.publish_errors, exc)
            return False
        return True

    def _answer(self, rec: Received[Any]) -> None:
        msg = rec.msg
        if self._peer is not None and msg.sid != self._peer and not self._answers_also(msg):  # bound after enqueueing
            self.foreign += 1
            self.drops.drop("foreign_session", f"clock ping sid={msg.sid} seq={msg.seq}")
            return
        t2 = rec.t_recv
        t3 = max(self._clock(), t2)
        if not t3 - t2 <= self.hold_max_s:
            self.late += 1
            self.drops.drop("ping_late", f"held {t3 - t2:.3f} s > {self.hold_max_s:g} s")
            return
        pong = ClockPong(sid=self.sid, seq=self._next_seq(), t=t3, ping_sid=msg.sid, ping_seq=msg.seq, t1=msg.t, t2=t2)
        if self._send(pong):
            self.answered += 1

    def _match(self, rec: Received[Any]) -> None:
        msg = rec.msg
        if self.sync is None:
            reason: str | None = "pong_unmatched"  # we send no pings
        else:
            reason = self.sync.on_answer(msg.sid, msg.ping_seq, msg.t2, msg.t, rec.t_recv, peer=self._peer)
        if reason is None:
            self.pongs_accepted += 1
        else:
            self.pongs_rejected += 1
            self.drops.drop(reason, f"clock pong sid={msg.sid} ping_seq={msg.ping_seq}")

    def _ping(self) -> None:
        assert self.sync is not None
        seq = self._next_seq()
        t1 = self._clock()
        self.sync.sent(seq, t1)  # before sending: a fast answer must find it
        if self._send(ClockPing(sid=self.sid, seq=seq, t=t1)):
            self.pings_sent += 1

    def _run(self) -> None:
        wait = 0.0
        while not self._stop.is_set():
            self._wake.wait(wait)
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                wait = self.poll()
            except Exception as exc:  # never let the link thread die
                LOG.warning("clock link: %s: %s", type(exc).__name__, exc)
                wait = _MAX_WAIT_S

    # ------------------------------------------------------------------ lifecycle

    def counters(self) -> dict[str, int]:
        """Return the link's counters (a snapshot)."""
        return {
            "answered": self.answered,
            "rate_limited": self.rate_limited,
            "pings_sent": self.pings_sent,
            "pongs_accepted": self.pongs_accepted,
            "pongs_rejected": self.pongs_rejected,
            "foreign": self.foreign,
            "overflow": self.overflow,
            "late": self.late,
            "publish_errors": self.publish_errors,
        }

    def start(self) -> ClockLink:
        """Start the link's thread (once)."""
        if self._thread is None and not self._closed:
            self._thread = threading.Thread(target=self._run, name="clock-link", daemon=True)
            self._thread.start()
        return self

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the thread (idempotent); later messages are ignored."""
        self._closed = True
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def __enter__(self) -> ClockLink:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
