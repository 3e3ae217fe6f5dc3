"""Reject stale, duplicated and out-of-order messages.

Each sender stamps its messages with a session id ``sid`` (random per process start)
and a strictly increasing ``seq``. A :class:`SequenceGate` accepts a message only if its
``seq`` is newer than every message accepted before from the same ``sid``. A new
``sid`` means the peer restarted: the gate resets and accepts it.
"""

from __future__ import annotations

import threading

from bipedtele.messages import Message

__all__ = ["SequenceGate"]


class SequenceGate:
    """Accept only messages newer than the last accepted one (per sender session).

    Notes
    -----
    A message from an *older* sid arriving after a restart cannot be told apart from a
    new restart; Zenoh delivers in order per publisher, so after a restart the old
    session's messages are no longer in flight and this case does not arise in practice.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._sid: int | None = None
        self._seq = -1

    def accept(self, msg: Message) -> str | None:
        """Check one message.

        Returns
        -------
        str or None
            None if the message is accepted (and becomes the newest), otherwise the
            drop reason: ``duplicate`` (same seq as the newest) or ``stale`` (older).
        """
        with self._lock:
            if msg.sid != self._sid:
                self._sid = msg.sid
                self._seq = msg.seq
                return None
            if msg.seq == self._seq:
                return "duplicate"
            if msg.seq < self._seq:
                return "stale"
            self._seq = msg.seq
            return None

    @property
    def last(self) -> tuple[int | None, int]:
        """``(sid, seq)`` of the newest accepted message (``(None, -1)`` before any)."""
        with self._lock:
            return self._sid, self._seq

    def reset(self) -> None:
        """Forget the sender (the next message is accepted whatever its seq)."""
        with self._lock:
            self._sid = None
            self._seq = -1
