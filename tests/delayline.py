"""In-process delay line for simulations and tests (no network, no threads)."""

from __future__ import annotations

from collections import deque
from typing import Generic, TypeVar

from bipedtele.link.delaymodels import ConstDelay, DelayModel

__all__ = ["DelayLine"]

T = TypeVar("T")


class DelayLine(Generic[T]):
    """FIFO that releases each item at its push time plus a delay.

    Order is kept like on a TCP link: an item is never released before an item pushed
    earlier, so with a time-varying delay a short-delayed item waits behind a
    long-delayed one (its release time is ``max(t_push + delay, previous release)``).

    Parameters
    ----------
    model : DelayModel or float
        Delay model, or a constant delay [s].
    """

    def __init__(self, model: DelayModel | float) -> None:
        self.model: DelayModel = model if isinstance(model, DelayModel) else ConstDelay(float(model))
        self._q: deque[tuple[float, T]] = deque()
        self._last_release = float("-inf")

    def push(self, t_now: float, item: T) -> float:
        """Insert ``item`` at time ``t_now`` [s]; return its release time [s]."""
        release = max(t_now + self.model.delay_s(t_now), self._last_release)
        self._last_release = release
        self._q.append((release, item))
        return release

    def pop_ready(self, t_now: float) -> list[T]:
        """Items whose release time is <= ``t_now`` [s], oldest first."""
        out = []
        q = self._q
        while q and q[0][0] <= t_now:
            out.append(q.popleft()[1])
        return out

    def next_release(self) -> float | None:
        """Release time of the next item [s], None if empty."""
        return self._q[0][0] if self._q else None

    def __len__(self) -> int:
        return len(self._q)

    def clear(self) -> None:
        """Drop every pending item."""
        self._q.clear()
