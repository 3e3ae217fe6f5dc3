"""What the robot's uplink delivered: a delivery-rate estimate that survives gaps.

The leader reports in each Status what it received of ours over its last 2 s (``rx_bps``):
bytes the path *delivered* per interval, the delivery rate BBR estimates its bottleneck
from (Cardwell et al., "BBR: congestion-based congestion control", ACM Queue 2016). What
the follower *sent* while the path was blocked says nothing of what it carries; what
arrived does, and the highest rate delivered lately is a lower bound of the capacity
(the path carried it).

:class:`DeliveryRate` keeps the windowed maximum of those samples, with two rules of its
own:

- **stalls do not age it.** While the path is stalled (the leader's newest feedback is far
  older than the path's delay: a blackout, a near-zero stretch of a cellular link), its
  samples are left out and the window's clock stops: after a gap the estimate is the last
  good one, not the collapse;
- **samples age out over delivering time only**: ``window_s`` (10 s) of time during which
  the path delivered, so a path whose capacity really fell is believed after that long.

Not thread-safe: the follower's loop thread only.
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["DeliveryRate"]


class DeliveryRate:
    """Windowed maximum of the delivery rate over delivering time (see the module docstring).

    Parameters
    ----------
    window_s : float
        How much delivering time [s] a sample is kept (10 s).

    Attributes
    ----------
    stalled : bool
        The last judgement said the path is stalled (set by :meth:`sample`).
    stalls : int
        How many stalls began.
    stall_since : float or None
        When the current stall began [s] (None: not stalled).
    """

    def __init__(self, window_s: float = 10.0) -> None:
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"window_s = {window_s!r}: allowed: a number of seconds > 0")
        self.window_s = float(window_s)
        self._active_s = 0.0  # delivering time so far [s]
        self._last_t: float | None = None
        self._max: deque[tuple[float, float]] = deque()  # (active time, bit/s), values decreasing
        self.stalled = False
        self.stalls = 0
        self.stall_since: float | None = None

    def sample(self, t: float, rx_bps: float, stalled: bool) -> None:
        """Take one delivery-rate sample.

        Parameters
        ----------
        t : float
            When the leader measured it, on the follower's clock [s] (non-decreasing).
        rx_bps : float
            What the path delivered over the leader's window [bit/s] (>= 0).
        stalled : bool
            Whether the path is stalled now (its samples are left out, its time not counted).
        """
        last, self._last_t = self._last_t, t
        if stalled:
            if not self.stalled:
                self.stalls += 1
                self.stall_since = t
            self.stalled = True
            return
        if last is not None and not self.stalled:
            self._active_s += max(0.0, t - last)
        self.stalled, self.stall_since = False, None
        if not (math.isfinite(rx_bps) and rx_bps > 0):
            return
        q = self._max
        while q and q[-1][1] <= rx_bps:
            q.pop()
        q.append((self._active_s, float(rx_bps)))
        while q and q[0][0] < self._active_s - self.window_s:
            q.popleft()

    @property
    def max_bps(self) -> float | None:
        """The highest rate delivered over the last ``window_s`` of delivering time [bit/s] (None: no sample)."""
        return self._max[0][1] if self._max else None
