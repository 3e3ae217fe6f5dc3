"""The paper's scheme and the same scheme with its delay adaptation switched off.

``paper``: (40) schedules ``alpha_m`` and ``sigma_e`` on the 1 s delay estimates; the
leader feels the equivalent follower's ``z_e`` (29); the follower takes ``(sigma_r, T, eps)``
from (30) at every impact. ``paper-constant``: the same loop with (40) and (30) evaluated
once at zero delay and held, so the difference between the two is what adapting buys.
"""

from __future__ import annotations

import numpy as np
from bipedtele.control.schemes.base import Scheme, scheduled, zero_delay

__all__ = ["Paper", "PaperConstant"]


class Paper(Scheme):
    """Delay-scheduled damping (40), equivalent follower (29), online choice (30)."""

    name = "paper"
    title = "the paper: (40) on the measured delay, z_e fed back, (30) online"
    feedback = "equivalent"
    adapts = True

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at every delay estimate."""
        return scheduled(h1_s, h2_s, self.cfg)


class PaperConstant(Scheme):
    """The paper's loop with (40) and (30) at zero delay, held for the run."""

    name = "paper-constant"
    title = "the paper's loop, (40) and (30) at zero delay, held"
    feedback = "equivalent"

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at zero delay, held."""
        return zero_delay(h1_s, self.cfg)
