"""The receive path: a Zenoh subscriber that authenticates, decodes, checks and gates each message.

Loops read the newest message only (:class:`LatestReceiver`, a ring of one); clock pongs,
where every message matters, go through the queue-style :class:`MessageReceiver`. Both
hand out :class:`Received` (the message, its receive time and size).

Receivers never raise on bad input. In order, a payload is dropped and counted in a
:class:`~bipedtele.drops.DropCounter` when: it is larger than the bound of its kind
(``too_large``, before it is copied), it fails authentication (``no_mac``, ``bad_mac``;
with a :class:`~bipedtele.auth.MessageAuth`, checked before anything is decoded; without
one, a signed payload is ``mac_unexpected``), it fails :func:`bipedtele.messages.decode`
(the :class:`~bipedtele.messages.MessageError` reason), its send time is more than
``max_future_s`` ahead of the local clock (``future``) or the peer clock's offset is not
known yet (``clock_not_synced``), it was sent longer ago than ``max_age_s`` (``too_old``,
before the gate: an old replay never binds it), or an optional
:class:`~bipedtele.gate.SequenceGate` refuses it. Delay estimators never see a negative delay.

Sessions are opened by :mod:`bipedtele.zenohsession`; keys and publishers are in
:mod:`bipedtele.transport`.
"""

from __future__ import annotations

import functools
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, TypeVar, cast

import msgspec
import zenoh
from bipedtele.auth import UNEXPECTED_MAC_LINE, MacError, MessageAuth, is_signed
from bipedtele.clock import ClockSync
from bipedtele.delayestimate import DelayEstimator
from bipedtele.drops import DropCounter
from bipedtele.gate import MessageGate
from bipedtele.messages import MAX_JPEG_BYTES, Message, MessageError, VideoFrame, decode

if TYPE_CHECKING:
    from bipedtele.session import Handshake

__all__ = [
    "MAX_CONTROL_PAYLOAD",
    "MAX_VIDEO_PAYLOAD",
    "MAX_ZENOH_MESSAGE",
    "LatestReceiver",
    "MessageReceiver",
    "Received",
]

M = TypeVar("M", bound=Message)


class Received(msgspec.Struct, Generic[M], frozen=True, gc=False):
    """A valid message and its local receive time.

    Attributes
    ----------
    msg : Message
        The decoded message.
    t_recv : float
        Local receive time (``time.time()`` by default) [s].
    nbytes : int
        Size of the payload as it arrived (MAC included) [bytes].
    """

    msg: M
    t_recv: float
    nbytes: int = 0


#: Largest payload [bytes] a receiver reads of a control message (command, feedback,
#: clock, status; a status with every counter and its text is under 4 kB) and of a video
#: frame (the JPEG bound plus its envelope). Anything larger is dropped (``too_large``)
#: before it is copied, authenticated or decoded.
MAX_CONTROL_PAYLOAD = 16 * 1024
MAX_VIDEO_PAYLOAD = MAX_JPEG_BYTES + 4 * 1024
#: Largest message Zenoh reassembles [bytes] (its defragmentation buffer; Zenoh drops larger).
MAX_ZENOH_MESSAGE = MAX_VIDEO_PAYLOAD + 64 * 1024
#: Under attack (a payload on the key failed authentication within ``UNDER_ATTACK_S``), a
#: payload larger than twice the largest authenticated one of the key plus ``ATTACK_SLACK``
#: is dropped by its size (``too_large_under_attack``) before it is copied or opened: forged
#: frames at the size bound cost neither memory nor the interpreter's lock.
UNDER_ATTACK_S = 10.0
ATTACK_SLACK = 64 * 1024


def _const(value: float, _t: float) -> float:
    return value


class _Receiver(Generic[M]):
    """Shared authentication/decoding/validation/gating for the receivers."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        expect: type[M] | tuple[type[M], ...],
        drops: DropCounter,
        gate: MessageGate | None = None,
        *,
        estimator: DelayEstimator | None = None,
        clock_sync: ClockSync | None = None,
        clock: Callable[[], float] = time.time,
        ignore_sid: int | None = None,
        on_message: Callable[[Received[M]], None] | None = None,
        auth: MessageAuth | None = None,
        max_future_s: float | None = None,
        max_age_s: float | Callable[[float], float] | None = None,
        on_too_old: Callable[[Received[M]], None] | None = None,
        handshake: Handshake | None = None,
    ) -> None:
        if max_future_s is not None and not max_future_s > 0:
            raise ValueError(f"max_future_s = {max_future_s!r}: allowed: None or a number > 0 s")
        if max_age_s is not None and not callable(max_age_s) and not max_age_s > 0:
            raise ValueError(f"max_age_s = {max_age_s!r}: allowed: None, a number > 0 s or a callable")
        self.key = key
        self._on_message = on_message
        self._expect: tuple[type[M], ...] = expect if isinstance(expect, tuple) else (expect,)
        # one expected class: decode() refuses the others itself; several: checked after
        self._decode_as: type[M] | None = self._expect[0] if len(self._expect) == 1 else None
        self.max_bytes = MAX_VIDEO_PAYLOAD if VideoFrame in self._expect else MAX_CONTROL_PAYLOAD
        self.drops = drops
        self.gate = gate
        self.estimator = estimator
        self.clock_sync = clock_sync
        self.auth = auth
        self.handshake = handshake
        self.max_future_s = max_future_s
        self._max_age: Callable[[float], float] | None = (
            None
            if max_age_s is None
            else max_age_s
            if callable(max_age_s)
            else functools.partial(_const, float(max_age_s))
        )
        self._on_too_old = on_too_old
        # the key expression the sender signed: ours when exact, else the sample's
        self._mac_topic = None if any(c in key for c in "*$") else key
        self._clock = clock
        self._ignore_sid = ignore_sid
        self._largest_good = 0  # the largest authenticated payload [bytes]
        self._bad_t = -float("inf")  # when a payload last failed authentication (local clock)
        self._lock = threading.Lock()
        self.count = 0
        self._closed = False
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Runs once per message in Zenoh's callback thread, from cold caches: each check
        # below is kept, with as few Python calls as the checks allow.
        t_recv = self._clock()
        drops = self.drops
        try:
            zbytes = sample.payload
            nbytes = len(zbytes)
            if nbytes > self.max_bytes:  # before the copy, the MAC and the decoder
                drops.drop("too_large", f"{self.key}: {nbytes} bytes (at most {self.max_bytes})")
                return
            if nbytes > 2 * self._largest_good + ATTACK_SLACK and t_recv - self._bad_t < UNDER_ATTACK_S:
                drops.drop("too_large_under_attack", f"{self.key}: {nbytes} bytes while forged payloads arrive "
                           f"(the largest authenticated: {self._largest_good})")  # fmt: skip
                return
            payload = zbytes.to_bytes()
            skey = None
            if self.handshake is not None or self.auth is not None:
                try:
                    if self.handshake is not None:
                        payload, skey = self.handshake.open(payload, self._mac_topic or str(sample.key_expr))
                    else:
                        payload = self.auth.verify(payload, self._mac_topic or str(sample.key_expr))  # type: ignore[union-attr]
                except MacError as exc:
                    if exc.reason in ("bad_mac", "no_mac"):
                        self._bad_t = t_recv
                    drops.drop(exc.reason, f"{self.key}: {exc.detail}")
                    return
                if nbytes > self._largest_good:
                    self._largest_good = nbytes
            elif is_signed(payload):  # not for the decoder: name the missing key, not msgpack
                drops.drop("mac_unexpected", f"{self.key}: {UNEXPECTED_MAC_LINE}")
                return
            try:
                got = decode(payload, self._decode_as)
            except MessageError as exc:
                drops.drop(exc.reason, exc.detail)
                return
            if self._decode_as is None and not isinstance(got, self._expect):
                drops.drop("unknown_kind", f"k={got.KIND!r}")
                return
            msg = cast(M, got)  # one of the expected kinds: decode() checked it, or the line above
            if msg.sid == self._ignore_sid:
                return  # our own message on a shared key (clock, status)
            t_sent = msg.t
            sync = self.clock_sync
            if sync is not None:
                if not sync.ready:
                    drops.drop("clock_not_synced", f"{self.key}: the peer's clock offset is not known yet")
                    return
                t_sent = sync.to_local(t_sent)
            if self.max_future_s is not None and t_sent - t_recv > self.max_future_s:
                drops.drop("future", f"{self.key}: sid={msg.sid} seq={msg.seq} stamped {t_sent - t_recv:.3f} s ahead")
                return
            max_age = self._max_age
            if max_age is not None and t_recv - t_sent > max_age(t_recv):
                # before the gate and the delay estimator: an old message (a replay, a
                # queue's backlog) never binds the gate nor moves the delay estimate
                if self._on_too_old is not None:
                    self._on_too_old(Received(msg, t_recv, nbytes))
                else:
                    drops.drop("too_old", f"{self.key}: sid={msg.sid} seq={msg.seq} sent {t_recv - t_sent:.3f} s ago")
                return
            if self.gate is not None:
                reason = self.gate.accept(msg)
                if reason is not None:
                    drops.drop(reason, f"sid={msg.sid} seq={msg.seq}")
                    return
            if skey is not None and self.handshake is not None:
                self.handshake.accepted(skey, msg.sid)  # authenticated, fresh, gated: the session is live
            if self.estimator is not None:
                # a delay is never negative: a message seemingly received before it was
                # sent (clock offset error, rounding) counts as delay 0
                self.estimator.update(t_sent if t_sent < t_recv else t_recv, t_recv)
            rec = Received(msg, t_recv, nbytes)
            self._deliver(rec)
            if self._on_message is not None:
                self._on_message(rec)
        except Exception as exc:  # never let a bad sample kill Zenoh's callback thread
            drops.drop("receiver_error", f"{type(exc).__name__}: {exc}")

    def _deliver(self, rec: Received[M]) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Undeclare the subscriber (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._sub.undeclare()

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LatestReceiver(_Receiver[M]):
    """Keeps only the newest valid message of one key (a ring of one).

    Parameters
    ----------
    session : zenoh.Session
    key : str
        Key expression to subscribe to.
    expect : type or tuple of types
        Accepted message class(es); any other kind is dropped (``unknown_kind``).
    drops : DropCounter
        Where invalid/stale messages are counted.
    gate : MessageGate, optional
        Drops stale and duplicated messages.
    estimator : DelayEstimator, optional
        Fed with every accepted message (send time, receive time) at reception, so the
        delay estimate sees every message, not only those the loop takes.
    clock_sync : ClockSync, optional
        ntp mode: converts the sender's send time to the local clock first; until it
        is ready (no clock answer yet, so the peer's clock may differ by anything) every
        message is dropped as ``clock_not_synced``. Never give it to the receiver of
        the clock answers themselves.
    clock : callable
        Local receive-time source [s] (``time.time``).
    ignore_sid : int, optional
        Messages with this sid (our own, on a shared key) are ignored silently.
    on_message : callable, optional
        Called with each accepted :class:`Received` in Zenoh's callback thread (keep
        it short: answer a ping, wake a loop). Exceptions are counted as
        ``receiver_error`` drops.
    auth : MessageAuth, optional
        Every payload must carry a valid tag: unsigned ones are dropped as ``no_mac``,
        wrong tags as ``bad_mac``, before anything is decoded.
    handshake : Handshake, optional
        Instead of ``auth``: every payload must carry a tag under a session key this side
        holds (:meth:`~bipedtele.session.Handshake.open`; else ``old_session``, or
        ``no_session`` for one under the master key); a message that passes every check
        (the gate included) marks its session live (and binds a follower to it).
    max_future_s : float, optional
        A message whose send time (on the local clock, after ``clock_sync``) is more
        than this ahead of its receive time [s] is dropped as ``future``
        (``[clock] max_future_s``). None: no check.
    max_age_s : float or callable, optional
        A message sent longer ago than this [s] (receive time minus send time on the
        local clock; a callable is given the receive time and returns the bound) is
        dropped as ``too_old`` before the gate and the delay estimator see it, so a
        replay of old traffic never binds the gate. None: no check.
    on_too_old : callable, optional
        Called with a message refused as too old instead of counting the drop (the
        caller counts it, e.g. the leader's ``fb_too_old``).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._latest: Received[M] | None = None
        self._fresh = False
        super().__init__(*args, **kwargs)

    def _deliver(self, rec: Received[M]) -> None:
        with self._lock:
            self._latest = rec
            self._fresh = True
            self.count += 1

    def latest(self) -> Received[M] | None:
        """Return the newest valid message (kept; None before the first)."""
        with self._lock:
            return self._latest

    def take(self) -> Received[M] | None:
        """Return the newest valid message if it was not taken before, else None."""
        with self._lock:
            if not self._fresh:
                return None
            self._fresh = False
            return self._latest


class MessageReceiver(_Receiver[M]):
    """Queue of every valid message of one key (bounded; overflow is counted).

    Same parameters as :class:`LatestReceiver`, plus ``maxlen`` (queue bound). When the
    queue is full the oldest message is dropped and counted as ``overflow``.
    """

    def __init__(self, *args: Any, maxlen: int = 1024, **kwargs: Any) -> None:
        self._q: deque[Received[M]] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition(threading.Lock())
        super().__init__(*args, **kwargs)

    def _deliver(self, rec: Received[M]) -> None:
        overflow = False
        with self._cond:
            if len(self._q) >= self._maxlen:
                self._q.popleft()
                overflow = True
            self._q.append(rec)
            self.count += 1
            self._cond.notify_all()
        if overflow:
            self.drops.drop("overflow", self.key)

    def get(self, timeout: float | None = None) -> Received[M] | None:
        """Return the oldest queued message, or None.

        ``timeout`` [s]: None or 0 does not wait; a positive value waits at most that long.
        """
        with self._cond:
            if not self._q and timeout:
                self._cond.wait_for(lambda: bool(self._q), timeout)
            return self._q.popleft() if self._q else None

    def drain(self) -> list[Received[M]]:
        """Every queued message, oldest first."""
        with self._cond:
            out = list(self._q)
            self._q.clear()
            return out

    def __len__(self) -> int:
        with self._cond:
            return len(self._q)
