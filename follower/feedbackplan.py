"""How the follower sends its feedback now: :class:`FeedbackPlan` (made by the uplink budget).

:meth:`bipedtele.follower.capacity.UplinkBudget.feedback_plan` makes it every tick; the
follower's loop reads it (acknowledge each command at once or on the next tick, the
periodic rate, the least interval between two).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FeedbackPlan"]


@dataclass(frozen=True)
class FeedbackPlan:
    """How the follower sends its feedback now.

    Attributes
    ----------
    ack_each_command : bool
        Publish a Feedback at once for every command picked up between ticks (True), or
        let the next tick's feedback acknowledge it (at most one feedback per tick).
    rate_hz : float
        Periodic feedback rate [Hz].
    min_interval_s : float
        When acknowledgements are not sent for every command: one is still sent at once
        if the previous feedback left at least this long ago [s] (so the feedback rate,
        periodic plus acknowledgements, stays within what the path carries).
    """

    ack_each_command: bool
    rate_hz: float
    min_interval_s: float = 0.0
