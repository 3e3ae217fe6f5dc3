"""Inboxes: admit or drop each incoming message, every check in one place.

A message of one key arrives in an inbox (from a receiver, :mod:`bipedtele.link.receivers`, or a
simulated transport) and is admitted or dropped, each drop counted once under its reason;
the loops take admitted messages out of it and check nothing.

In order, a payload is dropped and counted in a :class:`~bipedtele.link.drops.DropCounter` when:
it is larger than the bound of its kind (``too_large``, before it is copied; under attack,
``too_large_under_attack``), it fails authentication (``no_mac``, ``bad_mac``; under a
session key ``old_session``, ``no_session``; without a key, a signed payload is
``mac_unexpected``), it fails :func:`bipedtele.link.messages.decode` (the
:class:`~bipedtele.link.messages.MessageError` reason; ``unknown_kind``), the peer clock's
offset is not known yet (``clock_not_synced``), its send time is more than
``max_future_s`` ahead of the local clock (``future``), it was sent longer ago than
``max_age_s`` (``too_old``, ``fb_too_old`` at the leader; before the gate: an old replay
never binds it), or the gate refuses it (:class:`~bipedtele.link.gate.SequenceGate`:
``foreign_session``, ``seq_jump``, ``stale``, ``duplicate``; the follower's custody adds
``held``, ``released``). Delay estimators never see a negative delay.

Two inboxes carry the control loop's directions (docs/architecture.md):

- :class:`CommandInbox` (the follower): at take time a command older than
  ``max_cmd_age_s`` is refused (``cmd_too_old``), after a silence longer than the watchdog
  one delayed more than the watchdog beyond the path's baseline delay is refused
  (``cmd_backlog``), and one sent before the command taken last (same leader session) is
  refused (``cmd_reordered``); h1 is fed here with every command taken (docs/method.md).
- :class:`FeedbackInbox` (the leader): h2 is fed with every feedback admitted, and
  feedback the link's judge finds too old is refused (``fb_too_old``).

Both behave the same whether the loop runs in a program or alone (tests, studies: an inbox
fed by ``put`` or polled from a ``source``).
"""

from __future__ import annotations

import functools
import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, NamedTuple, Protocol, TypeVar, cast

import msgspec
from bipedtele.link.auth import UNEXPECTED_MAC_LINE, MacError, MessageAuth, is_signed
from bipedtele.link.clock import ClockSync
from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import MessageGate
from bipedtele.link.messages import MAX_JPEG_BYTES, Command, Feedback, Message, MessageError, VideoFrame, decode

if TYPE_CHECKING:
    from bipedtele.link.session import Handshake

__all__ = [
    "COMMAND_COUNTERS",
    "MAX_CONTROL_PAYLOAD",
    "MAX_VIDEO_PAYLOAD",
    "CommandInbox",
    "FeedbackInbox",
    "Inbox",
    "LatestInbox",
    "QueueInbox",
    "Received",
    "Taken",
]

LOG = logging.getLogger(__name__)

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


#: Largest payload [bytes] read of a control message (command, feedback, clock, status; a
#: status with every counter and its text is under 4 kB) and of a video frame (the JPEG
#: bound plus its envelope). Anything larger is dropped (``too_large``) before it is copied.
MAX_CONTROL_PAYLOAD = 16 * 1024
MAX_VIDEO_PAYLOAD = MAX_JPEG_BYTES + 4 * 1024
#: Under attack (a payload on the key failed authentication within ``UNDER_ATTACK_S``), a
#: payload larger than twice the largest authenticated one plus ``ATTACK_SLACK`` is dropped
#: by its size (``too_large_under_attack``) before it is copied or opened.
UNDER_ATTACK_S = 10.0
ATTACK_SLACK = 64 * 1024
#: The command inbox's counters (in every follower Status).
COMMAND_COUNTERS = ("cmd_accepted", "cmd_too_old", "leader_sessions", "cmd_backlog", "cmd_reordered")


class Payload(Protocol):
    """What an inbox reads of a payload off the wire (a ``zenoh.ZBytes``)."""

    def __len__(self) -> int: ...

    def to_bytes(self) -> bytes: ...


def _const(value: float, _t: float) -> float:
    return value


class Inbox(Generic[M]):
    """Admit or drop the messages of one key (module docstring); keeps nothing.

    Parameters
    ----------
    expect : type or tuple of types
        Accepted message class(es); any other kind is dropped (``unknown_kind``).
    drops : DropCounter
        Where dropped messages are counted, one count per message under its reason.
    gate : MessageGate, optional
        Drops stale, duplicated and foreign messages (the only de-duplication).
    key : str
        The key expression (log lines; the topic a signed payload names when exact).
    estimator : DelayEstimator, optional
        Fed with every admitted message (send time on the local clock, receive time).
    clock_sync : ClockSync, optional
        ntp mode: send times to the local clock; not ready yet: ``clock_not_synced``.
    ignore_sid : int, optional
        Messages of this session (our own on a shared key) are ignored silently.
    on_message : callable, optional
        Called with every admitted :class:`Received` (in the transport's thread).
    auth : MessageAuth, optional
        Every payload must carry a valid tag (``no_mac``, ``bad_mac``).
    handshake : Handshake, optional
        Instead of ``auth``: a session key's tag; an admitted message marks its session live.
    max_future_s : float, optional
        Send time more than this ahead of the receive time [s]: ``future``.
    max_age_s : float or callable, optional
        Sent longer ago than this [s] (a callable gets the receive time): ``too_old``.
    on_too_old : callable, optional
        Called with a message refused as too old instead of counting ``too_old``.
    """

    def __init__(
        self,
        expect: type[M] | tuple[type[M], ...],
        drops: DropCounter,
        gate: MessageGate | None = None,
        *,
        key: str = "",
        estimator: DelayEstimator | None = None,
        clock_sync: ClockSync | None = None,
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
        self._expect: tuple[type[M], ...] = expect if isinstance(expect, tuple) else (expect,)
        # one expected class: decode() refuses the others itself; several: checked after
        self._decode_as: type[M] | None = self._expect[0] if len(self._expect) == 1 else None
        self.max_bytes = MAX_VIDEO_PAYLOAD if VideoFrame in self._expect else MAX_CONTROL_PAYLOAD
        self.drops, self.gate, self.estimator = drops, gate, estimator
        self.clock_sync, self.auth, self.handshake = clock_sync, auth, handshake
        self.max_future_s = max_future_s
        self._max_age: Callable[[float], float] | None = (
            None
            if max_age_s is None
            else max_age_s
            if callable(max_age_s)
            else functools.partial(_const, float(max_age_s))
        )
        self._on_too_old = on_too_old
        self._on_message = on_message
        # the key expression the sender signed: ours when exact, else the sample's
        self._mac_topic = None if not key or any(c in key for c in "*$") else key
        self._ignore_sid = ignore_sid
        self._largest_good = 0  # the largest authenticated payload [bytes]
        self._bad_t = -math.inf  # when a payload last failed authentication (local clock)

    def offer(self, zbytes: Payload, t_recv: float, key_expr: object = None) -> Received[M] | None:
        """Admit one payload as it came off the wire; the admitted message or None (dropped).

        ``key_expr`` is the sample's key (what a signed payload names when the inbox's key
        is a wildcard).
        """
        # Once per message in the transport's thread, from cold caches: each check below
        # is kept, with as few Python calls as the checks allow.
        drops = self.drops
        nbytes = len(zbytes)
        if nbytes > self.max_bytes:  # before the copy, the MAC and the decoder
            drops.drop("too_large", f"{self.key}: {nbytes} bytes (at most {self.max_bytes})")
            return None
        if nbytes > 2 * self._largest_good + ATTACK_SLACK and t_recv - self._bad_t < UNDER_ATTACK_S:
            drops.drop(
                "too_large_under_attack",
                f"{self.key}: {nbytes} bytes while forged payloads arrive "
                f"(the largest authenticated: {self._largest_good})",
            )
            return None
        payload = zbytes.to_bytes()
        skey = None
        if self.handshake is not None or self.auth is not None:
            topic = self._mac_topic or str(key_expr)
            try:
                if self.handshake is not None:
                    payload, skey = self.handshake.open(payload, topic)
                else:
                    payload = self.auth.verify(payload, topic)  # type: ignore[union-attr]
            except MacError as exc:
                if exc.reason in ("bad_mac", "no_mac"):
                    self._bad_t = t_recv
                drops.drop(exc.reason, f"{self.key}: {exc.detail}")
                return None
            if nbytes > self._largest_good:
                self._largest_good = nbytes
        elif is_signed(payload):  # not for the decoder: name the missing key, not msgpack
            drops.drop("mac_unexpected", f"{self.key}: {UNEXPECTED_MAC_LINE}")
            return None
        try:
            got = decode(payload, self._decode_as)
        except MessageError as exc:
            drops.drop(exc.reason, exc.detail)
            return None
        if self._decode_as is None and not isinstance(got, self._expect):
            drops.drop("unknown_kind", f"k={got.KIND!r}")
            return None
        # one of the expected kinds: decode() checked it, or the line above
        return self._admit(cast(M, got), t_recv, nbytes, skey)

    def put(self, msg: M, t_recv: float, nbytes: int = 0) -> Received[M] | None:
        """Admit one decoded message (a simulated transport); the admitted message or None."""
        return self._admit(msg, t_recv, nbytes, None)

    def _admit(self, msg: M, t_recv: float, nbytes: int, skey: Any) -> Received[M] | None:
        """Run the message's checks (sender, clock, future, age, gate), then feed the estimator."""
        if msg.sid == self._ignore_sid:
            return None  # our own message on a shared key (clock, status)
        drops = self.drops
        t_sent = msg.t
        sync = self.clock_sync
        if sync is not None:
            if not sync.ready:
                drops.drop("clock_not_synced", f"{self.key}: the peer's clock offset is not known yet")
                return None
            t_sent = sync.to_local(t_sent)
        if self.max_future_s is not None and t_sent - t_recv > self.max_future_s:
            drops.drop("future", f"{self.key}: sid={msg.sid} seq={msg.seq} stamped {t_sent - t_recv:.3f} s ahead")
            return None
        max_age = self._max_age
        if max_age is not None and t_recv - t_sent > max_age(t_recv):
            # before the gate and the delay estimator: an old message (a replay, a queue's
            # backlog) never binds the gate nor moves the delay estimate
            self._too_old(Received(msg, t_recv, nbytes), t_sent)
            return None
        if self.gate is not None:
            reason = self.gate.accept(msg)
            if reason is not None:
                drops.drop(reason, f"sid={msg.sid} seq={msg.seq}")
                return None
        if skey is not None and self.handshake is not None:
            self.handshake.accepted(skey, msg.sid)  # authenticated, fresh, gated: the session is live
        if self.estimator is not None:
            # never negative: a message seemingly received before it was sent counts as 0
            self.estimator.update(t_sent if t_sent < t_recv else t_recv, t_recv)
        rec = Received(msg, t_recv, nbytes)
        return rec if self._deliver(rec, t_sent) else None

    def _too_old(self, rec: Received[M], t_sent: float) -> None:
        if self._on_too_old is not None:
            self._on_too_old(rec)
        else:
            self.drops.drop(
                "too_old", f"{self.key}: sid={rec.msg.sid} seq={rec.msg.seq} sent {rec.t_recv - t_sent:.3f} s ago"
            )

    def _deliver(self, rec: Received[M], t_sent: float) -> bool:
        """Keep an admitted message, then tell ``on_message``; False when it was dropped after all."""
        self._keep(rec)
        if self._on_message is not None:
            self._on_message(rec)
        return True

    def _keep(self, rec: Received[M]) -> None:
        """Store an admitted message (the inboxes that keep messages)."""


class LatestInbox(Inbox[M]):
    """An inbox that keeps the newest admitted message only (a ring of one)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._lock = threading.Lock()
        self._latest: Received[M] | None = None
        self._fresh = False
        self.count = 0  # admitted messages

    def _keep(self, rec: Received[M]) -> None:
        with self._lock:
            self._latest = rec
            self._fresh = True
            self.count += 1

    def latest(self) -> Received[M] | None:
        """Return the newest admitted message (kept; None before the first)."""
        with self._lock:
            return self._latest

    def take(self) -> Received[M] | None:
        """Return the newest admitted message if it was not taken before, else None."""
        with self._lock:
            if not self._fresh:
                return None
            self._fresh = False
            return self._latest


class QueueInbox(Inbox[M]):
    """An inbox that queues every admitted message (``maxlen``; the oldest is dropped as ``overflow``)."""

    def __init__(self, *args: Any, maxlen: int = 1024, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._q: deque[Received[M]] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition(threading.Lock())
        self.count = 0  # admitted messages

    def _keep(self, rec: Received[M]) -> None:
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
        """Return the oldest queued message, or None (``timeout`` [s]: None or 0 does not wait)."""
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


class Baseline(Protocol):
    """The path's baseline delay (:class:`bipedtele.follower.backlog.DelayBaseline`)."""

    relearn_s: float

    def value(self, now: float) -> float | None: ...

    def accepted(self, now: float, delay_s: float) -> None: ...

    def dropped(self, now: float, delay_s: float) -> bool: ...


class Taken(NamedTuple):
    """A command taken from the :class:`CommandInbox`: apply it."""

    msg: Command
    t_recv: float
    new_session: bool  # the first command of a new leader session


def _same(t: float) -> float:
    return t


class CommandInbox(LatestInbox[Command]):
    """The follower's commands: admitted as :class:`Inbox` does, checked again when taken.

    Parameters
    ----------
    max_cmd_age_s : float
        A command sent longer ago than this when it is taken is refused (``cmd_too_old``) [s].
    watchdog_s : float
        The follower's watchdog [s]: after a silence this long, a command delayed more than
        this beyond ``baseline`` is an outage's backlog (``cmd_backlog``).
    baseline : Baseline
        The path's baseline delay, told of every command taken and refused as backlog.
    drops : DropCounter, optional
        Where admission drops are counted (a new one named ``cmd`` when omitted).
    source : callable, optional
        ``() -> (Command, t_recv) | None``, polled at each take: a transport without a
        receiver (a loop run alone); what it gives is admitted as by :meth:`put`.
    to_local : callable
        Converts a sender time to the local clock (identity with a synced clock) [s].
    delay_window_s : float
        Window of the h1 moving average [s] (docs/method.md).
    on_take : callable, optional
        Called with every command taken, before its checks (the program hears the
        leader's h2 from it).
    **admission
        The :class:`Inbox` checks (``gate``, ``max_age_s`` of admission, ``auth`` ...).
    """

    def __init__(
        self,
        max_cmd_age_s: float,
        watchdog_s: float,
        baseline: Baseline,
        *,
        drops: DropCounter | None = None,
        source: Callable[[], tuple[Command, float] | None] | None = None,
        to_local: Callable[[float], float] = _same,
        delay_window_s: float = 1.0,
        on_take: Callable[[Command], None] | None = None,
        **admission: Any,
    ) -> None:
        super().__init__(Command, drops if drops is not None else DropCounter("cmd"), **admission)
        self.max_cmd_age_s = float(max_cmd_age_s)
        self.watchdog_s = float(watchdog_s)
        self.baseline = baseline
        self._source = source
        self._to_local = to_local
        self._on_take = on_take
        #: The forward-delay (h1) estimator: fed once, with every command taken.
        self.h1 = DelayEstimator(delay_window_s)
        self.counters: dict[str, int] = dict.fromkeys(COMMAND_COUNTERS, 0)
        self._last: Command | None = None  # the command taken last
        self._last_recv = -math.inf
        self._leader_sid: int | None = None
        self._next_backlog_log = -math.inf

    def take_command(self, now: float) -> Taken | None:
        """Return the newest command not taken before if it passes the take checks, else None.

        ``now`` is the local time [s]. h1 is fed with every command taken, refused or not.
        """
        if self._source is not None:
            got = self._source()
            if got is not None:
                self.put(got[0], got[1])
        rec = self.take()
        if rec is None:
            return None
        msg, t_recv = rec.msg, rec.t_recv
        if self._on_take is not None:
            self._on_take(msg)
        t_sent = self._to_local(msg.t)  # within max_future_s of the receive time: admission checked
        # a send time a little after the receive time (clock jitter) is a zero delay
        self.h1.update(min(t_sent, t_recv), t_recv)
        if now - t_sent > self.max_cmd_age_s:
            self.counters["cmd_too_old"] += 1
            return None
        delay = max(0.0, t_recv - t_sent)
        if self._backlog(now, delay, t_recv):
            return None
        last = self._last
        if last is not None and msg.sid == last.sid and msg.t < last.t:
            # Never apply a command sent before one already applied (the gate orders by
            # seq; this holds whatever the sender's seq and clock did).
            self.counters["cmd_reordered"] += 1
            return None
        self.baseline.accepted(now, delay)
        self._last, self._last_recv = msg, t_recv
        self.counters["cmd_accepted"] += 1
        new = msg.sid != self._leader_sid
        if new:
            self._leader_sid = msg.sid
            self.counters["leader_sessions"] += 1
        return Taken(msg, t_recv, new)

    def _backlog(self, now: float, delay: float, t_recv: float) -> bool:
        """Return True (counted, logged) when the command is an outage's backlog (module docstring)."""
        base = self.baseline.value(now)
        if base is None or delay <= base + self.watchdog_s or t_recv - self._last_recv <= self.watchdog_s:
            # While commands keep coming (no silence), a slow rise of the delay (the
            # trace's peaks) is the path's and stays accepted.
            return False
        self.counters["cmd_backlog"] += 1
        if self.baseline.dropped(now, delay):
            LOG.warning(
                "every command for %.0f s came %.2f s or more late: the path's delay changed, baseline now %.3f s",
                self.baseline.relearn_s,
                delay,
                self.baseline.value(now),
            )
        elif now >= self._next_backlog_log:
            self._next_backlog_log = now + 5.0
            LOG.warning(
                "dropping a command queued in the path: delay %.3f s, baseline %.3f s, watchdog %.2f s (%d so far)",
                delay,
                base,
                self.watchdog_s,
                self.counters["cmd_backlog"],
            )
        return True


class FeedbackInbox(LatestInbox[Feedback]):
    """The leader's feedback: admitted as :class:`Inbox` does, h2 fed, the link's judgement.

    Parameters
    ----------
    drops : DropCounter, optional
        Where drops are counted (a new one named ``feedback`` when omitted).
    delay_window_s : float
        Window of the h2 moving average [s] (docs/method.md).
    judge : callable, optional
        ``judge(received, t_sent) -> bool``: whether an admitted feedback (and one refused
        as too old, which it is also shown) is young enough to use (the program's link
        quality, docs/leader.md); refused ones are dropped as ``fb_too_old``.
    max_age_s : float or callable, optional
        The age bound checked before the gate [s] (a callable gets the receive time);
        too old: ``fb_too_old`` (with a judge) or ``too_old``.
    source : callable, optional
        ``() -> (Feedback, t_recv) | None``, polled at each take (a loop run alone); what
        it gives that was not given before is admitted as by :meth:`put`.
    **admission
        The other :class:`Inbox` checks.
    """

    def __init__(
        self,
        drops: DropCounter | None = None,
        *,
        delay_window_s: float = 1.0,
        judge: Callable[[Received[Feedback], float], bool] | None = None,
        source: Callable[[], tuple[Feedback, float] | None] | None = None,
        **admission: Any,
    ) -> None:
        #: The backward-delay (h2) estimator: fed once, with every feedback admitted.
        self.h2 = DelayEstimator(delay_window_s)
        if admission.pop("estimator", None) is not None:
            raise ValueError("estimator: allowed: none (the feedback inbox feeds its own h2)")
        super().__init__(
            Feedback, drops if drops is not None else DropCounter("feedback"), estimator=self.h2, **admission
        )
        self._judge = judge
        self._source = source
        self._given: tuple[int, int, float] | None = None
        self.taken = 0  # feedback taken by the loop

    def _too_old(self, rec: Received[Feedback], t_sent: float) -> None:
        if self._judge is None:
            super()._too_old(rec, t_sent)
        elif self._judge(rec, t_sent):  # shown to the link (arrivals, loss); its bound may differ
            self._keep(rec)
        else:
            self._refuse(rec, t_sent)

    def _deliver(self, rec: Received[Feedback], t_sent: float) -> bool:
        # the program's hooks (recording) see every feedback the gate let through, then the
        # judge; only feedback young enough to use is kept for the loop
        if self._on_message is not None:
            self._on_message(rec)
        if self._judge is not None and not self._judge(rec, t_sent):
            self._refuse(rec, t_sent)
            return False
        self._keep(rec)
        return True

    def _refuse(self, rec: Received[Feedback], t_sent: float) -> None:
        bound = self._max_age(rec.t_recv) if self._max_age is not None else math.nan
        self.drops.drop(
            "fb_too_old",
            f"feedback sid={rec.msg.sid} seq={rec.msg.seq} sent "
            f"{rec.t_recv - t_sent:.1f} s ago (bound {bound:.1f} s): not shown as live",
        )

    def take_feedback(self) -> Received[Feedback] | None:
        """Return the newest usable feedback not taken before, else None."""
        if self._source is not None:
            got = self._source()
            if got is not None and (got[0].sid, got[0].seq, got[1]) != self._given:
                self._given = (got[0].sid, got[0].seq, got[1])
                self.put(got[0], got[1])
        rec = self.take()
        if rec is not None:
            self.taken += 1
        return rec
