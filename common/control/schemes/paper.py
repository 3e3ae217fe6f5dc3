"""The paper's scheme and the same scheme with its delay adaptation switched off.

``paper``: (40) schedules ``alpha_m`` and ``sigma_e`` on the 1 s delay estimates; the
leader feels the equivalent follower's ``z_e`` (29); the follower takes ``(sigma_r, T, eps)``
from (30) at every impact. ``paper-constant``: the same loop with (40) and (30) evaluated
once at zero delay and held, so the difference between the two is what adapting buys.

Port laws: :class:`EquivalentSpeed`, the speed coupling
(:class:`~bipedtele.control.schemes.speed.SpeedFeedback`) on ``z_e``: the follower sends back
its equivalent follower's state (the Feedback message's ``z_e``; in the reduced comparison,
the reduced model's (29) run on the received command), the leader's force (31) follows it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from bipedtele.control.schemes.base import scheduled, zero_delay
from bipedtele.control.schemes.speed import SpeedFeedback

__all__ = ["EquivalentSpeed", "Paper", "PaperConstant"]


class EquivalentSpeed(SpeedFeedback):
    """The speed coupling on the equivalent follower's ``z_e`` (29)."""

    def feedback_signal(self, z_e: Callable[[], np.ndarray], eta: np.ndarray, k_m: np.ndarray) -> np.ndarray:
        """Return ``z_e`` [cm/s, deg/s]."""
        return z_e()

    def read_feedback(self, z_e: np.ndarray, eta: np.ndarray, wave: np.ndarray) -> np.ndarray:
        """Return the message's ``z_e``."""
        return z_e


class Paper(EquivalentSpeed):
    """Delay-scheduled damping (40), equivalent follower (29), online choice (30)."""

    name = "paper"
    title = "the paper: (40) on the measured delay, z_e fed back, (30) online"
    adapts = True

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at every delay estimate."""
        return scheduled(h1_s, h2_s, self.cfg)


class PaperConstant(EquivalentSpeed):
    """The paper's loop with (40) and (30) at zero delay, held for the run."""

    name = "paper-constant"
    title = "the paper's loop, (40) and (30) at zero delay, held"

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at zero delay, held."""
        return zero_delay(h1_s, self.cfg)
