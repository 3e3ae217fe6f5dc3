"""One-way delay estimation: the moving average of measured delays, and the round-trip bound.

A receiver feeds :class:`DelayEstimator` with every accepted message (send time on its own
clock, receive time): in ``[clock] mode = "synced"`` the sender's time as stamped, in
``ntp`` mode converted first with :meth:`bipedtele.link.clock.ClockSync.to_local`. An ntp
offset is only right for a symmetric path, so the split of the round trip into h1 and h2
is uncertain by the path asymmetry; the stability conditions (paper eq. 40) then use
:func:`conservative_delays`, the bound h1 = h2 = round trip, which holds whatever the
asymmetry.

All times are in seconds.
"""

from __future__ import annotations

import math
import threading
from collections import deque

__all__ = ["DelayEstimator", "conservative_delays"]

_INF = math.inf


class DelayEstimator:
    """Time-windowed moving average of one-way delays.

    The estimate at time ``now`` is the mean delay of the messages *received* in the
    window ``(now - window_s, now]`` (the paper's 1 s moving average, a time window, not
    a message count). ``None`` if no message arrived in the window.

    Parameters
    ----------
    window_s : float
        Window length [s], > 0.
    max_samples : int
        Bound on the samples kept; beyond it the oldest are discarded (memory stays
        bounded whatever the message rate).

    Notes
    -----
    ``update`` and ``value`` are O(1) amortised. Receive times are assumed to be
    non-decreasing (a sample received earlier than the previous one is treated as
    received at the same time as it) and ``value`` is assumed to be queried with a
    non-decreasing ``now``: samples that left the window are forgotten. Thread-safe.

    Time sanity: each delay sample is clamped to ``[0, MAX_SAMPLE_S]`` (a message
    apparently received before it was sent, through a clock offset error, has delay 0;
    the upper bound only keeps the running sum finite), so the mean is never negative,
    whatever the running-sum rounding; :meth:`value` never returns a negative number.
    Samples with a non-finite time are ignored (they say nothing about the link).
    """

    #: Largest delay sample kept [s] (larger ones are clamped; keeps the sum finite).
    MAX_SAMPLE_S = 1.0e9
    #: Updates between two exact re-sums of the running sum (bounds its rounding drift).
    _FSUM_EVERY = 100_000

    def __init__(self, window_s: float = 1.0, max_samples: int = 65536) -> None:
        if not (window_s > 0 and math.isfinite(window_s)):
            raise ValueError(f"window_s = {window_s!r}: allowed: a finite number > 0 s")
        if max_samples < 1:
            raise ValueError("max_samples must be >= 1")
        self.window_s = float(window_s)
        self._max = max_samples
        self._samples: deque[tuple[float, float]] = deque()
        self._sum = 0.0
        self._last_recv = -math.inf
        self._lock = threading.Lock()
        self._until_fsum = self._FSUM_EVERY

    def update(self, t_sent: float, t_recv: float) -> None:
        """Add one message.

        Parameters
        ----------
        t_sent : float
            Send time on the *local* clock [s] (in ntp mode: converted with
            :meth:`ClockSync.to_local`).
        t_recv : float
            Local receive time [s].
        """
        # Once per received message: no function calls besides the lock and the append.
        if not (-_INF < t_sent < _INF and -_INF < t_recv < _INF):  # NaN fails too
            return
        with self._lock:
            if t_recv < self._last_recv:
                t_recv = self._last_recv
            else:
                self._last_recv = t_recv
            delay = t_recv - t_sent
            if not delay > 0.0:
                delay = 0.0
            elif delay > self.MAX_SAMPLE_S:
                delay = self.MAX_SAMPLE_S
            samples = self._samples
            samples.append((t_recv, delay))
            self._sum += delay
            if len(samples) > self._max:
                self._sum -= samples.popleft()[1]
            self._until_fsum -= 1
            if not self._until_fsum:  # bound floating-point drift of the running sum
                self._until_fsum = self._FSUM_EVERY
                self._sum = math.fsum(d for _, d in samples)

    def value(self, now: float) -> float | None:
        """Mean one-way delay [s] of the samples received in ``(now - window_s, now]``.

        Returns
        -------
        float or None
            The mean, ``>= 0`` and finite; None if no sample is in the window.
        """
        with self._lock:
            samples = self._samples
            start = now - self.window_s
            while samples and samples[0][0] <= start:
                self._sum -= samples.popleft()[1]
            if not samples:
                self._sum = 0.0
                return None
            total, n = self._sum, len(samples)
            # Samples stamped after ``now`` (rare: a query with an older time) are excluded.
            i = n - 1
            while i >= 0 and samples[i][0] > now:
                total -= samples[i][1]
                n -= 1
                i -= 1
            if not n:
                return None
            mean = total / n
            return mean if mean > 0.0 else 0.0  # rounding of the running sum: never < 0

    def count(self, now: float) -> int:
        """Return the number of samples in the window ending at ``now``."""
        self.value(now)
        with self._lock:
            return sum(1 for t, _ in self._samples if t <= now)

    def clear(self) -> None:
        """Forget every sample (e.g. after the peer restarted)."""
        with self._lock:
            self._samples.clear()
            self._sum = 0.0
            self._last_recv = -math.inf


def conservative_delays(rtt: float) -> tuple[float, float]:
    """Delays for the stability conditions when only the round trip is known.

    In ntp mode the split of the round trip into h1 and h2 is unknown (up to the path
    asymmetry). Since each one-way delay is at most the round trip, ``h1 = h2 = rtt``
    is a safe upper bound for conditions that grow with the delays (eq. 40).

    Parameters
    ----------
    rtt : float
        Round trip [s].

    Returns
    -------
    (h1, h2) : tuple of float
        Both equal to ``rtt`` [s].
    """
    return (rtt, rtt)
