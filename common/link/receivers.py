"""The receive path: a Zenoh subscriber that moves each payload into an inbox.

A receiver is the transport part only: Zenoh's callback hands every payload, with its
receive time, to an :class:`~bipedtele.link.inbox.Inbox`, which admits or drops it (size,
authentication, decoding, clock, age, sequence gate; every check and its drop reason are
in :mod:`bipedtele.link.inbox`). Loops read the newest message only (:class:`LatestReceiver`,
a ring of one; the follower's commands and the leader's feedback go into a
:class:`~bipedtele.link.inbox.CommandInbox` / :class:`~bipedtele.link.inbox.FeedbackInbox` given as
``inbox``); clock pongs, where every message matters, go through the queue-style
:class:`MessageReceiver`. Both hand out :class:`Received` (the message, its receive time
and size). Receivers never raise on bad input.

Sessions are opened by :mod:`bipedtele.link.zenohsession`; keys and publishers are in
:mod:`bipedtele.link.transport`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Generic, TypeVar

import zenoh
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import MessageGate
from bipedtele.link.inbox import (
    ATTACK_SLACK,
    MAX_CONTROL_PAYLOAD,
    MAX_VIDEO_PAYLOAD,
    UNDER_ATTACK_S,
    Inbox,
    LatestInbox,
    QueueInbox,
    Received,
)
from bipedtele.link.messages import Message

__all__ = [
    "ATTACK_SLACK",
    "MAX_CONTROL_PAYLOAD",
    "MAX_VIDEO_PAYLOAD",
    "MAX_ZENOH_MESSAGE",
    "UNDER_ATTACK_S",
    "LatestReceiver",
    "MessageReceiver",
    "Received",
]

M = TypeVar("M", bound=Message)

#: Largest message Zenoh reassembles [bytes] (its defragmentation buffer; Zenoh drops larger).
MAX_ZENOH_MESSAGE = MAX_VIDEO_PAYLOAD + 64 * 1024


class _Receiver(Generic[M]):
    """A subscriber of one key that hands every payload to its inbox."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        inbox: Inbox[M],
        *,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.key = key
        self.inbox = inbox
        self.drops = inbox.drops
        self._clock = clock
        self._lock = threading.Lock()
        self._closed = False
        self._sub = session.declare_subscriber(key, self._on_sample)

    @property
    def gate(self) -> MessageGate | None:
        """The inbox's sequence gate."""
        return self.inbox.gate

    @property
    def max_bytes(self) -> int:
        """Largest payload the inbox reads [bytes]."""
        return self.inbox.max_bytes

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Runs once per message in Zenoh's callback thread.
        t_recv = self._clock()
        try:
            self.inbox.offer(sample.payload, t_recv, sample.key_expr)
        except Exception as exc:  # never let a bad sample kill Zenoh's callback thread
            self.drops.drop("receiver_error", f"{type(exc).__name__}: {exc}")

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
    """Keeps only the newest admitted message of one key (a ring of one).

    Parameters
    ----------
    session : zenoh.Session
    key : str
        Key expression to subscribe to.
    expect : type or tuple of types
        Accepted message class(es); any other kind is dropped (``unknown_kind``).
    drops : DropCounter
        Where dropped messages are counted.
    gate : MessageGate, optional
        Drops stale, duplicated and foreign messages.
    clock : callable
        Local receive-time source [s] (``time.time``).
    inbox : callable, optional
        Builds the inbox (``inbox(drops=..., gate=..., key=..., **checks)``, e.g. a
        :class:`~bipedtele.link.inbox.CommandInbox` with its own settings bound); a
        :class:`~bipedtele.link.inbox.LatestInbox` of ``expect`` by default.
    **checks
        The inbox's checks (:class:`~bipedtele.link.inbox.Inbox`: ``estimator``,
        ``clock_sync``, ``ignore_sid``, ``on_message``, ``auth``, ``handshake``,
        ``max_future_s``, ``max_age_s``, ``on_too_old``). ``on_message`` runs in Zenoh's
        callback thread (keep it short: answer a ping, wake a loop); its exceptions are
        counted as ``receiver_error`` drops.
    """

    inbox: LatestInbox[M]

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        expect: type[M] | tuple[type[M], ...],
        drops: DropCounter,
        gate: MessageGate | None = None,
        *,
        clock: Callable[[], float] = time.time,
        inbox: Callable[..., LatestInbox[M]] | None = None,
        **checks: Any,
    ) -> None:
        if inbox is None:
            box: LatestInbox[M] = LatestInbox(expect, drops, gate, key=key, **checks)
        else:
            box = inbox(drops=drops, gate=gate, key=key, **checks)
        super().__init__(session, key, box, clock=clock)

    @property
    def count(self) -> int:
        """Messages admitted so far."""
        return self.inbox.count

    def latest(self) -> Received[M] | None:
        """Return the newest admitted message (kept; None before the first)."""
        return self.inbox.latest()

    def take(self) -> Received[M] | None:
        """Return the newest admitted message if it was not taken before, else None."""
        return self.inbox.take()


class MessageReceiver(_Receiver[M]):
    """Queue of every admitted message of one key (bounded; overflow is counted).

    Same parameters as :class:`LatestReceiver` (no ``inbox``), plus ``maxlen`` (queue
    bound). When the queue is full the oldest message is dropped and counted as ``overflow``.
    """

    inbox: QueueInbox[M]

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        expect: type[M] | tuple[type[M], ...],
        drops: DropCounter,
        gate: MessageGate | None = None,
        *,
        clock: Callable[[], float] = time.time,
        maxlen: int = 1024,
        **checks: Any,
    ) -> None:
        box: QueueInbox[M] = QueueInbox(expect, drops, gate, key=key, maxlen=maxlen, **checks)
        super().__init__(session, key, box, clock=clock)

    @property
    def count(self) -> int:
        """Messages admitted so far."""
        return self.inbox.count

    def get(self, timeout: float | None = None) -> Received[M] | None:
        """Return the oldest queued message, or None.

        ``timeout`` [s]: None or 0 does not wait; a positive value waits at most that long.
        """
        return self.inbox.get(timeout)

    def drain(self) -> list[Received[M]]:
        """Every queued message, oldest first."""
        return self.inbox.drain()

    def __len__(self) -> int:
        return len(self.inbox)
