"""The feedback path's delay h2 and the queue it shows, for :class:`~bipedtele.follower.capacity.UplinkBudget`.

Each Command carries ``h2_s``, the leader's 1 s mean of the feedback path's delay.
:class:`QueueDelay` keeps, from it:

- the **excess**: h2 above its minimum over ``h2_window_s`` (10 s), the minimum held
  through a rise (a queue of ours draining for longer than the window is still measured
  against the delay before it); a rise of more than ``delay_rise_s`` starts a **rise**
  (the delay rule's clock), and one that lasts ``relearn_s`` without falling is the path's
  own delay: the minimum is taken again from the current h2 (**relearn**);
- the **standing queue**: h2 above its minimum over ``base_window_s`` (60 s), a queue that
  stands longer than the delay rule's window takes in (the budget uses the echo's,
  :class:`~bipedtele.follower.owdqueue.OneWayQueue`, while commands echo feedback);
- h2's **slope** over the last 0.5 s, and whether it is **falling** (more than 50 ms
  below its peak over the last 2 s: a queue of ours draining);
- the commands' **gaps**: after a silence longer than ``gap_s`` (an outage, a router
  restart) the leader's figures count the silence, not the path: they are not judged
  until ``quiet_until``.
"""

from __future__ import annotations

import math
from collections import deque

from bipedtele.follower.backlog import WindowMin
from bipedtele.follower.delayrise import StandingQueue
from bipedtele.follower.uplinktuning import UplinkTuning

__all__ = ["QueueDelay"]


class QueueDelay:
    """h2, its minimum and the queue above it (see the module docstring).

    Parameters
    ----------
    tuning : UplinkTuning
        ``window_s``, ``delay_rise_s``, ``h2_window_s``, ``relearn_s``, ``gap_s`` and
        ``base_window_s`` are used here.

    Attributes
    ----------
    h2_s : float or None
        The last h2 [s] (None before the first).
    at : float
        When the last h2 came [s] (the budget's clock).
    excess_s : float
        h2 above its recent minimum [s] (a queue in the path).
    standing_s : float
        h2 above its minimum over ``base_window_s`` [s] (0 until h2 comes).
    rise_since : float or None
        Since when h2 is more than ``delay_rise_s`` above its minimum [s] (None: not).
    episode : bool
        The delay rule cut during this rise (set by the budget; cleared when the rise ends).
    falling : bool
        In the rise, h2 is more than 50 ms below its peak of the last 2 s.
    quiet_until : float
        The leader's figures are not judged before this [s] (after a gap in the commands).
    """

    def __init__(self, tuning: UplinkTuning) -> None:
        self.tuning = tuning
        self._min = WindowMin(tuning.h2_window_s)
        self._standing = StandingQueue(tuning.base_window_s)
        self._base: float | None = None
        self._hist: deque[tuple[float, float]] = deque()
        self._cmd_times: deque[float] = deque()
        self.h2_s: float | None = None
        self.at = -math.inf
        self.excess_s = 0.0
        self.standing_s = 0.0
        self.rise_since: float | None = None
        self.episode = False
        self.falling = False
        self.quiet_until = -math.inf

    def add(self, now: float, h2_s: float) -> bool:
        """Take the h2 a command brought at ``now`` [s].

        Parameters
        ----------
        now : float
            The budget's clock [s].
        h2_s : float
            The leader's feedback-path delay estimate [s] (finite, > 0).

        Returns
        -------
        bool
            True when a rise lasted ``relearn_s``: the minimum was taken again.
        """
        tu = self.tuning
        self.at = now
        self.h2_s = h2 = float(h2_s)
        self._min.add(now, h2)
        self.standing_s = self._standing.add(now, h2)
        wmin = self._min.value(now)
        assert wmin is not None
        # The baseline is held through a rise (a queue of ours draining for longer than
        # the window is still measured against the delay before it).
        if self.rise_since is None or self._base is None or wmin < self._base:
            self._base = wmin
        base = self._base
        hist = self._hist
        hist.append((now, h2))
        while hist and hist[0][0] < now - 2.0:
            hist.popleft()
        if self._cmd_times and now - self._cmd_times[-1] > tu.gap_s:
            # the path was down (an outage, a router restart): the leader's next windows
            # count that silence, not the path's capacity; judge again once they are past it
            self.quiet_until = now + tu.window_s + 1.0
        self._cmd_times.append(now)
        while self._cmd_times and self._cmd_times[0] < now - tu.window_s:
            self._cmd_times.popleft()
        self.excess_s = max(0.0, h2 - base)
        if self.excess_s <= tu.delay_rise_s:
            self.rise_since = None
            self.episode = False
            return False
        self.falling = falling = h2 < max(h for _, h in hist) - 0.05  # a queue of ours draining
        if self.rise_since is None:
            self.rise_since = now
            return False
        if now - self.rise_since < tu.relearn_s or falling:
            return False
        # lasting: the path's own delay, not a queue of ours
        self._min.clear()
        self._min.add(now, h2)
        self._standing.clear()
        self.standing_s = self._standing.add(now, h2)  # 0: the new minimum
        self._base = h2
        self.excess_s = 0.0
        self.rise_since = None
        self.episode = False
        return True

    def slope(self, now: float) -> float:
        """Return h2's growth over the last 0.5 s [s/s] (0 with less than 0.2 s of history)."""
        pts = [(t, h) for t, h in self._hist if t >= now - 0.5]
        if len(pts) < 2 or pts[-1][0] - pts[0][0] < 0.2:
            return 0.0
        return (pts[-1][1] - pts[0][1]) / (pts[-1][0] - pts[0][0])

    @property
    def floor_s(self) -> float | None:
        """h2's minimum over ``base_window_s`` [s] (None before the first h2): the path's delay without a queue."""
        return self._standing.floor(self.at)

    def command_hz(self) -> float:
        """Return the rate of commands bringing h2 over the last ``window_s`` [Hz]."""
        return len(self._cmd_times) / self.tuning.window_s
