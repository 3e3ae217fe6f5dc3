"""What the follower sent on its uplink: payload bytes in 0.1 s bins, for :class:`~bipedtele.follower.capacity.UplinkBudget`.

The follower counts every message it publishes (feedback, status, video: the encoded
message with its MAC) at the publish call, from any thread; the budget reads the rate sent
over a window (its own, or the leader's ``rx_bps`` window shifted back by h2).
"""

from __future__ import annotations

import threading
from collections import deque

__all__ = ["SentLog"]

_BIN_S = 0.1  # resolution of the sent-bytes history [s]
_KEEP_S = 20.0  # sent-bytes history kept [s] (the window, shifted by h2 up to ~10 s)


class SentLog:
    """Payload bytes sent, per 0.1 s bin, control and video apart (thread-safe).

    Attributes
    ----------
    first_sent : float or None
        When the first byte was counted [s] (None before).
    fb_bits : float
        Moving average (EWMA, 0.1) of one Feedback message's size [bit] (0 before the first).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        # sent bytes per bin: bin index -> [control, video]
        self._bins: deque[tuple[int, list[int]]] = deque()
        self.first_sent: float | None = None
        self.fb_bits = 0.0

    def add(self, now: float, nbytes: int, video: bool = False, feedback: bool = False) -> None:
        """Count ``nbytes`` of payload sent at ``now``.

        Parameters
        ----------
        now : float
            The budget's clock [s].
        nbytes : int
            Encoded message size with its MAC [bytes].
        video : bool
            A video frame (else control: feedback, status).
        feedback : bool
            A Feedback message (its size feeds :attr:`fb_bits`).
        """
        b = int(now / _BIN_S)
        if self.first_sent is None:
            self.first_sent = now
        with self._lock:
            if not self._bins or self._bins[-1][0] != b:
                self._bins.append((b, [0, 0]))
                while self._bins and self._bins[0][0] < b - _KEEP_S / _BIN_S:
                    self._bins.popleft()
            self._bins[-1][1][1 if video else 0] += int(nbytes)
            if feedback:
                bits = 8.0 * nbytes
                self.fb_bits = bits if self.fb_bits == 0.0 else 0.9 * self.fb_bits + 0.1 * bits

    def rate(self, a: float, b: float, which: int | None = None) -> float:
        """Return the rate sent over ``[a, b)`` [bit/s]: control (0), video (1) or both (None).

        Parameters
        ----------
        a, b : float
            The window's start and end on the budget's clock [s] (0 when ``b <= a``).
        which : int, optional
            0: control, 1: video, None: both.
        """
        if b <= a:
            return 0.0
        ia, ib = int(a / _BIN_S), int(b / _BIN_S)
        total = 0
        with self._lock:
            for i, (c, v) in self._bins:
                if ia <= i < ib:
                    total += (c + v) if which is None else (c, v)[which]
        return 8.0 * total / max(_BIN_S, (ib - ia) * _BIN_S)
