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

The gate is generic: the inboxes of every kind (commands, feedback, video, status) use it
(:mod:`bipedtele.link.inbox`, where every check on an incoming message is made).

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

Without the message key (``rollback_after > 0``, the inboxes' setting then) a jump is
provisional: when ``rollback_after`` messages of the bound session in a row (consecutive
seqs) arrive stale but newer than the seq accepted before the jump, the jump was not the
sender's (a forged copy) and the gate rolls back to them (the last of them is accepted).
So one forged message with a high seq blocks the real sender for at most
``rollback_after - 1`` of its messages (2 at the default 3: 20 ms at the leader's 100 Hz
commands), whatever its seq, instead of up to ``elapsed * max_rate_hz + seq_margin``.
The inboxes drop messages older than their age bound before the gate, so an old copy
(finding 2: seq + 519 stamped 3,605 s old) never reaches it.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Protocol

from bipedtele.link.messages import Message

__all__ = ["DROP_REASONS", "FollowedSessionGate", "MessageGate", "SequenceGate"]

#: Every reason :meth:`SequenceGate.accept` may return.
DROP_REASONS = ("foreign_session", "seq_jump", "stale", "duplicate")


class MessageGate(Protocol):
    """What an inbox asks of a gate: accept one message or name why not."""

    def accept(self, msg: Message) -> str | None:
        """Return None if ``msg`` is accepted, else the drop reason."""
        ...


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
    rollback_after : int
        0: no rollback (with the message key: a jump cannot be forged). Otherwise this
        many consecutive stale messages of the bound session, newer than the seq accepted
        before the latest jumps, undo the jumps (module docstring).

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
        rollback_after: int = 0,
    ) -> None:
        if not (math.isfinite(takeover_after_s) and takeover_after_s > 0):
            raise ValueError(f"takeover_after_s = {takeover_after_s!r}: allowed: a finite number of seconds > 0")
        if not (math.isfinite(max_rate_hz) and max_rate_hz > 0):
            raise ValueError(f"max_rate_hz = {max_rate_hz!r}: allowed: a finite rate > 0 Hz")
        if seq_margin < 0:
            raise ValueError(f"seq_margin = {seq_margin!r}: allowed: an integer >= 0")
        self.takeover_after_s = float(takeover_after_s)
        self.max_rate_hz = float(max_rate_hz)
        if rollback_after < 0:
            raise ValueError(f"rollback_after = {rollback_after!r}: allowed: an integer >= 0")
        self.seq_margin = int(seq_margin)
        self.rollback_after = int(rollback_after)
        self.rollbacks = 0
        self._pre_jump: int | None = None  # seq accepted before the first jump not yet confirmed
        self._run_seq = -1  # newest of the current run of stale-but-newer messages
        self._run = 0
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
                    if seq == last:
                        return "duplicate"
                    pre = self._pre_jump
                    if pre is None or seq <= pre or self.rollback_after == 0:
                        return "stale"
                    # newer than the seq before a jump: the real sender's, if a run follows
                    self._run = self._run + 1 if seq == self._run_seq + 1 else 1
                    self._run_seq = seq
                    if self._run < self.rollback_after:
                        return "stale"
                    self.rollbacks += 1
                    self._pre_jump = None
                    self._run, self._run_seq = 0, -1
                elif live and seq - last > (elapsed if elapsed > 0.0 else 0.0) * self.max_rate_hz + self.seq_margin:
                    return "seq_jump"
                elif seq > last + 1 and self._pre_jump is None:
                    self._pre_jump = last
            elif live and self._sid is not None:
                return "foreign_session"
            else:
                self._pre_jump = None
                self._run, self._run_seq = 0, -1
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
            self._pre_jump = None
            self._run, self._run_seq = 0, -1


class FollowedSessionGate:
    """Accept only newer messages of the session another gate follows.

    The follower's inbox of leader Status: only the leader whose commands it takes (the
    command gate's bound session) reports on the uplink the follower fits its traffic
    into. A leader waiting for the robot, or one that released it, says nothing of the
    driver's path (the sites test's hand-over: the budget read the waiting operator's
    Status, without a feedback age, for the rest of the first operator's drive). Another
    session's message is dropped as ``foreign_session``; within the followed session
    ``inner`` judges order and jumps (reset when the followed session changes).

    Parameters
    ----------
    follow : callable
        The session followed now (None: none yet; everything is dropped).
    inner : SequenceGate, optional
        The order and jump checks within that session (default: ``SequenceGate()``).
    """

    def __init__(self, follow: Callable[[], int | None], inner: SequenceGate | None = None) -> None:
        self._follow = follow
        self.inner = inner if inner is not None else SequenceGate()

    def accept(self, msg: Message) -> str | None:
        """Return None if ``msg`` is accepted, else the drop reason (:data:`DROP_REASONS`)."""
        sid = self._follow()
        if sid is None or msg.sid != sid:
            return "foreign_session"
        if self.inner.bound_sid != sid:
            self.inner.reset()  # a new followed session: its own sequence
        return self.inner.accept(msg)
