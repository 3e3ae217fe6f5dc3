"""A first delay cut, until judged (:class:`PendingCut`), for :class:`~bipedtele.follower.capacity.UplinkBudget`.

A queue of ours drains within about its own delay once less is sent; a rise of the path's
delay (a route change, a slow swing) does not react to what we send. So the first cut of a
rise is kept with what it replaced, and undone when h2 did not fall (by a fifth below its
peak since the cut) within ``max(1 s, 2 x that peak)``, with no rate signal since. The peak,
not the excess at the cut: h2 is the leader's 1 s mean, in which a queue goes on rising for
up to a second after the cut.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PendingCut"]


@dataclass
class PendingCut:
    """The first delay cut of a rise, until judged: what to restore, and h2's peak since.

    Attributes
    ----------
    capacity_bps : float
        The capacity before the cut [bit/s].
    start_budget_bps : float or None
        The start's video budget before the cut [bit/s] (None: the start was over).
    ceiling_bps : float or None
        The ceiling before the cut [bit/s].
    ceiling_soft : bool
        That ceiling was the echo rule's (the probe past it not slowed).
    t : float
        When it was cut [s].
    peak_excess_s : float
        h2 above its minimum: at the cut, then the highest since [s].
    """

    capacity_bps: float
    start_budget_bps: float | None
    ceiling_bps: float | None
    ceiling_soft: bool
    t: float
    peak_excess_s: float

    def judged(self, now: float, excess_s: float) -> bool:
        """Take h2's excess [s] at ``now`` [s] into the peak; say whether the cut is due to be judged."""
        self.peak_excess_s = max(self.peak_excess_s, excess_s)
        return now - self.t >= max(1.0, 2.0 * self.peak_excess_s)

    def undo(self, excess_s: float, last_rate_cut: float, may: bool) -> bool:
        """Say whether to undo the cut: h2 [s above its minimum] has not fallen by a fifth below its peak, no rate cut came since [s], and an undo ``may`` come now."""
        return excess_s >= 0.8 * self.peak_excess_s and last_rate_cut < self.t and may

    @property
    def restored(self) -> tuple[float, float | None, float | None, bool]:
        """What the cut replaced: capacity, start budget and ceiling [bit/s], and whether that ceiling was soft."""
        return self.capacity_bps, self.start_budget_bps, self.ceiling_bps, self.ceiling_soft
