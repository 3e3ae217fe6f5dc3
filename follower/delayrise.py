"""A delay's rise over its recent minimum: the queue in a path, from delay samples (:class:`DelayRise`).

Each sample of a delay (a round trip, a one-way delay with the clocks' offset in it) is the
path's delay plus its queue plus waits of one sign: the time a feedback lay at the leader
before its status went, a command's period before its echo. LEDBAT's current-delay filter
takes them out: the queue is the least of the last few samples (and, with a span, of every
sample within it) over the minimum of the window (the base delay). Used by
:class:`~bipedtele.follower.delivery.InFlight` (the Status round trip) and
:class:`~bipedtele.follower.owdqueue.OneWayQueue` (the echoed feedback's one-way delay).
:class:`StandingQueue` is the same delay over a longer window's minimum: a queue that
stands longer than the short window takes in (h2's in
:class:`~bipedtele.follower.queuedelay.QueueDelay`, the echo's in ``OneWayQueue``).
"""

from __future__ import annotations

import math
from collections import deque

from bipedtele.follower.backlog import WindowMin

__all__ = ["DelayRise", "StandingQueue"]


class DelayRise:
    """The least of the last ``n`` delay samples (and of all within ``span_s``) over their minimum across ``window_s``.

    Parameters
    ----------
    window_s : float
        Window of the minimum (the base delay) [s].
    n : int
        Samples the current delay is the least of.
    span_s : float
        The current delay is also the least of every sample of the last ``span_s`` [s]: a
        link that delivers in slots waits up to a slot's gap, whatever the queue.
    """

    def __init__(self, window_s: float = 10.0, n: int = 3, span_s: float = 0.0) -> None:
        if not (math.isfinite(window_s) and window_s > 0) or n < 1 or not (math.isfinite(span_s) and span_s >= 0):
            raise ValueError(
                f"window_s = {window_s!r}, n = {n!r}, span_s = {span_s!r}: allowed: a finite window > 0, n >= 1, a finite span >= 0"
            )
        self._min = WindowMin(window_s)
        self._n, self._span_s = n, float(span_s)
        self._recent: deque[tuple[float, float]] = deque()

    def add(self, t: float, delay_s: float) -> float:
        """Take a sample ``delay_s`` [s] at ``t`` [s]; return the rise: the current delay over the minimum [s], >= 0."""
        self._min.add(t, delay_s)
        recent = self._recent
        recent.append((t, delay_s))
        while len(recent) > self._n and (not self._span_s or recent[0][0] < t - self._span_s):  # no span: the last n
            recent.popleft()
        base = self._min.value(t)
        return max(0.0, min(d for _, d in recent) - (delay_s if base is None else base))

    def rebase(self, t: float) -> None:
        """Take the current delay as the new minimum at ``t`` [s] (the path's own delay rose)."""
        current = self.current
        self._min.clear()
        if current is not None:
            self._min.add(t, current)

    @property
    def current(self) -> float | None:
        """The current delay [s]: the least of the last samples (None before the first)."""
        return min((d for _, d in self._recent), default=None)

    @property
    def minimum(self) -> float | None:
        """The minimum [s] as of the last sample (None before the first)."""
        return self._min.front()

    def clear(self) -> None:
        """Forget every sample."""
        self._min.clear()
        self._recent.clear()


class StandingQueue:
    """A delay over its minimum across ``window_s``: a queue standing longer than a shorter window takes in.

    Parameters
    ----------
    window_s : float
        Window of the minimum [s] (60 s: the budget's ``base_window_s``).
    hold_s : float
        The delay taken is the least of every sample of the last ``hold_s`` [s] (0: the last
        sample alone): a queue standing that long shows whole, a link's waits for its
        delivery slots, gone within it, do not.
    """

    def __init__(self, window_s: float, hold_s: float = 0.0) -> None:
        if not (math.isfinite(window_s) and window_s > 0) or not (math.isfinite(hold_s) and 0 <= hold_s < window_s):
            raise ValueError(
                f"window_s = {window_s!r}, hold_s = {hold_s!r}: allowed: a finite window > 0, a finite hold >= 0 and under the window"
            )
        self._floor = WindowMin(window_s)
        self._hold = WindowMin(hold_s) if hold_s > 0 else None

    def add(self, t: float, delay_s: float) -> float:
        """Take a delay ``delay_s`` [s] at ``t`` [s]; return the least over ``hold_s`` over the window's minimum [s], >= 0."""
        self._floor.add(t, delay_s)
        if self._hold is not None:
            self._hold.add(t, delay_s)
            held = self._hold.front()  # never None after an add (a delay may be <= 0: the clocks' offset)
            delay_s = delay_s if held is None else held
        base = self._floor.value(t)
        return 0.0 if base is None else max(0.0, delay_s - base)

    def floor(self, t: float) -> float | None:
        """Return the window's minimum at ``t`` [s] (None before the first sample)."""
        return self._floor.value(t)

    def clear(self) -> None:
        """Forget every sample (the path's own delay changed)."""
        self._floor.clear()
        if self._hold is not None:
            self._hold.clear()
