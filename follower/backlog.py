"""The path's baseline delay, and the rule that keeps a queued backlog of commands off the robot.

After an outage (a link that stalled, a router that buffered), the commands queued in the
path arrive late and in a burst. Their ages may all be under ``max_cmd_age_s`` and they are
in sequence order, so neither the age limit nor the sequence gate stops them; applied, they
would replay seconds of old operator input. :class:`DelayBaseline` tracks the path's usual
delay, the minimum forward delay h1 over the last ``window_s`` of *accepted* commands, so
the loop can drop a command delayed more than ``watchdog_s`` beyond it (``cmd_backlog``):
no command older than the watchdog, beyond the usual path delay, reaches the robot.

A path whose delay really grew by more than that (a new route) would otherwise stop the
robot for good: when every command has been dropped as backlog for ``relearn_s`` while
commands kept arriving, the baseline is learned again from the commands dropped over the
last ``window_s`` (their minimum delay), and the next ones are accepted. Until then the
baseline is held, however long the outage, so a burst after any outage is dropped.
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["DelayBaseline", "WindowMin"]


class WindowMin:
    """Minimum of ``(t, value)`` samples over a sliding time window (monotonic deque)."""

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        self._q: deque[tuple[float, float]] = deque()

    def add(self, t: float, value: float) -> None:
        """Add a sample ``value`` taken at ``t`` [s]."""
        q = self._q
        while q and q[-1][1] >= value:
            q.pop()
        q.append((t, value))
        self.prune(t)

    def prune(self, now: float) -> None:
        """Forget the samples older than the window at ``now`` [s]."""
        q = self._q
        while q and q[0][0] < now - self.window_s:
            q.popleft()

    def value(self, now: float) -> float | None:
        """Return the minimum over the window at ``now`` [s] (None when empty)."""
        self.prune(now)
        return self._q[0][1] if self._q else None

    def front(self) -> float | None:
        """Return the minimum as of the last ``add`` or ``prune`` (None when empty)."""
        return self._q[0][1] if self._q else None

    def clear(self) -> None:
        """Forget every sample."""
        self._q.clear()


class DelayBaseline:
    """The path's baseline forward delay: the minimum over the recently accepted commands.

    Parameters
    ----------
    window_s : float
        Window of the minimum [s] (about 10 s).
    relearn_s : float
        After this long [s] with every arriving command dropped as backlog, the path's
        delay is taken to have changed and the baseline is learned again.

    Notes
    -----
    Times are on the loop's clock [s]; delays are receive time minus send time [s],
    clamped at 0 by the caller. Not thread-safe: the loop's thread only.
    """

    def __init__(self, window_s: float = 10.0, relearn_s: float = 10.0) -> None:
        if not (math.isfinite(window_s) and window_s > 0 and math.isfinite(relearn_s) and relearn_s > 0):
            raise ValueError(
                f"window_s = {window_s!r}, relearn_s = {relearn_s!r}: allowed: finite numbers of seconds > 0"
            )
        self.relearn_s = float(relearn_s)
        self._accepted = WindowMin(window_s)
        self._dropped = WindowMin(window_s)
        self._held: float | None = None
        self._backlog_since: float | None = None
        self.relearned = 0

    def value(self, now: float) -> float | None:
        """Return the baseline delay [s] at ``now``: the window's minimum, else the last one known.

        None before the first accepted command.
        """
        v = self._accepted.value(now)
        if v is not None:
            self._held = v
        return self._held

    def accepted(self, now: float, delay_s: float) -> None:
        """Record the delay [s] of a command the loop applied at ``now`` [s]."""
        self._accepted.add(now, delay_s)
        self._held = self._accepted.value(now)
        self._backlog_since = None
        self._dropped.clear()

    def dropped(self, now: float, delay_s: float) -> bool:
        """Record a command dropped as backlog; True when the baseline was learned again from them."""
        self._dropped.add(now, delay_s)
        if self._backlog_since is None:
            self._backlog_since = now
            return False
        if now - self._backlog_since < self.relearn_s:
            return False
        self._held = self._dropped.value(now)
        self._accepted.clear()
        self._dropped.clear()
        self._backlog_since = None
        self.relearned += 1
        return True
