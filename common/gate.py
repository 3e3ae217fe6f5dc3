"""Reject stale, duplicated, out-of-order and foreign messages.

Each sender stamps its messages with a session id ``sid`` (random per process start)
and a strictly increasing ``seq``. A :class:`SequenceGate` follows ONE sender session at
a time (a follower follows one leader):

* It binds to the first session it accepts a message from.
* A message from another session is dropped (``foreign_session``) unless the bound one
  has been silent (no accepted message) for longer than ``takeover_after_s``, or
  :meth:`SequenceGate.release` was called: then the new session takes over (this is how
  a restarted peer, which draws a new sid, is followed again).
* Within the bound session a message is accepted only if its ``seq`` is newer than every
  accepted one (``duplicate``, ``stale`` otherwise), and only if the jump is one the
  sender could have produced since the last accepted message: at most
  ``elapsed * max_rate_hz + seq_margin`` (``seq_jump`` otherwise). One forged message
  with ``seq = 2**63 - 1`` is therefore dropped, instead of making every later message of
  the real sender stale (its stop included).

The gate is generic: receivers of every kind (commands, feedback, video, status) use it.

Bounds (what a forger without the message key can still do, see docs on
``network.message_key_file``): a message carrying the bound sid and a seq within the
allowed jump is accepted, and makes the real sender's next at most
``elapsed * max_rate_hz + seq_margin`` messages stale (elapsed since the last accepted
message; about 105 messages 1 ms after one at the defaults). A bound session that went
silent is not bound to a jump bound: its first newer message after more than
``takeover_after_s`` of silence is accepted whatever its seq (a sender faster than
``max_rate_hz``, e.g. a tool running faster than real time, recovers after a burst of
losses). With the message key set none of this can be forged (sid and seq are MAC'd) and
replays are dropped as ``stale``/``duplicate`` while the session is bound.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from bipedtele.messages import Message

__all__ = ["DROP_REASONS", "SequenceGate"]

#: Every reason :meth:`SequenceGate.accept` may return.
DROP_REASONS = ("foreign_session", "seq_jump", "stale", "duplicate")


class SequenceGate:
    """Accept only newer messages of one bound sender session.

    Parameters
    ----------
    takeover_after_s : float
        Silence of the bound session [s] (no accepted message) after which another
        session may take over (> 0; e.g. the follower's watchdog period).
    clock : callable
        Monotonic time source [s] (injectable for tests).
    max_rate_hz : float
        Most messages per second a legitimate sender produces [Hz] (> 0): bounds the seq
        jump accepted after ``elapsed`` seconds to ``elapsed * max_rate_hz + seq_margin``.
    seq_margin : int
        Seq jump always allowed (>= 0): lost messages, bursts.

    Notes
    -----
    Thread-safe (Zenoh callbacks call :meth:`accept`; the app may call :meth:`release`).
    Zenoh delivers in order per publisher, so a bound session's own messages never arrive
    stale in practice.
    """

    def __init__(
        self,
        takeover_after_s: float = 0.5,
        clock: Callable[[], float] = time.monotonic,
        max_rate_hz: float = 5000.0,
        seq_margin: int = 100,
    ) -> None:
        if not (math.isfinite(takeover_after_s) and takeover_after_s > 0):
            raise ValueError(f"takeover_after_s = {takeover_after_s!r}: allowed: a finite number of seconds > 0")
        if not (math.isfinite(max_rate_hz) and max_rate_hz > 0):
            raise ValueError(f"max_rate_hz = {max_rate_hz!r}: allowed: a finite rate > 0 Hz")
        if seq_margin < 0:
            raise ValueError(f"seq_margin = {seq_margin!r}: allowed: an integer >= 0")
        self.takeover_after_s = float(takeover_after_s)
        self.max_rate_hz = float(max_rate_hz)
        self.seq_margin = int(seq_margin)
        self._clock = clock
        self._lock = threading.Lock()
        self._sid: int | None = None
        self._seq = -1
        self._t_accept = -math.inf

    def accept(self, msg: Message) -> str | None:
        """Check one message.

        Returns
        -------
        str or None
            None if the message is accepted (it becomes the newest and its session the
            bound one), otherwise the drop reason: ``foreign_session`` (another session
            while the bound one is live), ``duplicate`` (same seq as the newest),
            ``stale`` (older) or ``seq_jump`` (newer by more than the sender could have
            produced).
        """
        # Once per received message, in Zenoh's callback thread: one clock call, one lock,
        # no allocation, the fields read once. The same checks, in the same order.
        now = self._clock()
        sid = msg.sid
        seq = msg.seq
        with self._lock:
            elapsed = now - self._t_accept
            live = elapsed <= self.takeover_after_s  # False for NaN times: silent
            if sid == self._sid:
                last = self._seq
                if seq <= last:
                    return "duplicate" if seq == last else "stale"
                if live and seq - last > (elapsed if elapsed > 0.0 else 0.0) * self.max_rate_hz + self.seq_margin:
                    return "seq_jump"
            elif live and self._sid is not None:
                return "foreign_session"
            self._sid = sid
            self._seq = seq
            self._t_accept = now
        return None

    @property
    def last(self) -> tuple[int | None, int]:
        """``(sid, seq)`` of the newest accepted message (``(None, -1)`` before any)."""
        with self._lock:
            return self._sid, self._seq

    @property
    def bound_sid(self) -> int | None:
        """The session followed now (None before the first message or after :meth:`reset`).

        It stays set after :meth:`release` until another session's message is accepted.
        """
        with self._lock:
            return self._sid

    @property
    def live_sid(self) -> int | None:
        """The bound session while it is live, else None.

        Live: a message accepted within ``takeover_after_s``; the session another may not
        take over from.

        Meant for peer binding elsewhere (``ClockLink(peer_sid=lambda: gate.live_sid)``):
        when the followed session falls silent, whoever takes over is followed there too.
        """
        now = self._clock()
        with self._lock:
            return self._sid if now - self._t_accept <= self.takeover_after_s else None

    def release(self) -> None:
        """Let any session take over at its next message (e.g. the operator released).

        The bound session may also continue: its next newer message is accepted whatever
        the jump. Stale and duplicate messages of it are still dropped.
        """
        with self._lock:
            self._t_accept = -math.inf

    def reset(self) -> None:
        """Forget the sender (the next message is accepted whatever its sid and seq)."""
        with self._lock:
            self._sid = None
            self._seq = -1
            self._t_accept = -math.inf
