"""How the follower sends its feedback now: :class:`FeedbackPlan` (made by the uplink budget).

:meth:`bipedtele.follower.capacity.UplinkBudget.feedback_plan` makes it every tick; the
follower's loop reads it (acknowledge each command at once or on the next tick, the
periodic rate, the least interval between two).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["FLOOR_HZ", "FeedbackPlan", "plan_feedback"]

#: The feedback rate that keeps priority over video while the path is limited [Hz]; a
#: periodic rate above it shares the path with video.
FLOOR_HZ = 25.0


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

    def control_bps(self, command_hz: float, feedback_bits: float) -> float:
        """Return the feedback rate this plan commits to [bit/s], given the commands' rate [Hz] and a feedback's size [bit].

        The periodic feedback, and with an acknowledgement per command one per command
        (acknowledgements riding on the next tick leave at most every ``min_interval_s``,
        only as commands come, each standing for the period's feedback: their rate is what
        is measured). Video's budget leaves at least this to control: the measured rate is a
        2 s mean, so a plan that steps to an acknowledgement per command would otherwise
        send it on top of video for 2 s.
        """
        hz = self.rate_hz + (command_hz if self.ack_each_command else 0.0)
        return hz * feedback_bits


def plan_feedback(
    rate_hz: float,
    fits_bps: float,
    command_hz: float,
    feedback_bits: float,
    *,
    start: bool = False,
    stall_hz: float | None = None,
    ack_room_bps: float = math.inf,
    above_floor_bps: float = math.inf,
) -> FeedbackPlan:
    """How to send feedback now (:meth:`bipedtele.follower.capacity.UplinkBudget.feedback_plan` explains the rule).

    Parameters
    ----------
    rate_hz : float
        The configured periodic feedback rate [Hz].
    fits_bps : float
        What control may use of the path [bit/s] (infinite: unknown).
    command_hz, feedback_bits : float
        The commands' rate [Hz] and a feedback's size [bit].
    start : bool
        The path is not known yet: acknowledgements ride on the periodic feedback.
    stall_hz : float, optional
        The path is stalled: the newest only, at most this often [Hz].
    ack_room_bps : float, optional
        What feedback beyond the periodic rate (acknowledgements sent at once) may use
        [bit/s]: what video at its most leaves of the capacity (default: no bound but
        ``fits_bps``). The periodic feedback keeps priority over video; an acknowledgement
        sent at once instead of on the next periodic feedback does not.
    above_floor_bps : float, optional
        What a periodic rate above :data:`FLOOR_HZ` may use [bit/s] (default: no bound
        but ``fits_bps``): the floor keeps priority over video, a rate above it shares
        the path with video (:meth:`~bipedtele.follower.capacity.UplinkBudget.feedback_plan`).
    """
    if stall_hz is not None:
        hz = min(rate_hz, stall_hz)
        return FeedbackPlan(False, hz, 1.0 / hz if hz > 0 else 0.0)
    if not math.isfinite(fits_bps) and start:
        # the path is not known yet: acknowledgements ride on the periodic feedback (an
        # acknowledgement per command doubles control's rate)
        return FeedbackPlan(False, rate_hz, 1.0 / rate_hz if rate_hz > 0 else 0.0)
    if not math.isfinite(fits_bps):
        return FeedbackPlan(True, rate_hz)
    acks_bps = min(fits_bps, ack_room_bps)
    if (rate_hz + command_hz) * feedback_bits <= acks_bps:
        return FeedbackPlan(True, rate_hz)

    def fits(h: float) -> bool:  # the floor's rates before video, a rate above it shares the path with video
        return h <= rate_hz and h * feedback_bits <= (fits_bps if h <= FLOOR_HZ else min(fits_bps, above_floor_bps))

    hz = next((h for h in (rate_hz, FLOOR_HZ, 10.0) if fits(h)), min(rate_hz, 10.0))
    # the feedback rate the path carries: acknowledgements fill what the periodic
    # feedback leaves of it (no step from "every command" to "none" as the capacity moves)
    total_hz = max(hz, acks_bps / feedback_bits) if feedback_bits > 0 else hz
    return FeedbackPlan(False, hz, 1.0 / total_hz if total_hz > 0 else math.inf)
