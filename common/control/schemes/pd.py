"""P+d baselines: the leader feels the robot's observed speed (no equivalent follower).

The classic position-plus-damping coupling (Nuño, Ortega, Basañez; docs/schemes.md), read
in this project's speed coordinates: ``f_m = -k_m (k_g x_m - eta(t - h2)) - alpha_m dx_m``
with ``eta`` the robot's measured speed. The damping is sized by (40):

* ``pd-worst-case``: once, for the largest delays of the run (known beforehand: the best
  case for a constant design), held;
* ``pd-measured``: on the measured delays, as the paper schedules it.

The follower side is the paper's: ``sigma_e`` from (40) feeds the online choice (30).
Port laws: :class:`MeasuredSpeed`, the speed coupling
(:class:`~bipedtele.control.schemes.speed.SpeedFeedback`) on the Feedback message's ``eta``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from bipedtele.control.schemes.base import held, scheduled
from bipedtele.control.schemes.speed import SpeedFeedback

__all__ = ["MeasuredSpeed", "PdMeasured", "PdWorstCase"]


class MeasuredSpeed(SpeedFeedback):
    """The speed coupling on the robot's measured speed ``eta``."""

    def feedback_signal(self, z_e: Callable[[], np.ndarray], eta: np.ndarray, k_m: np.ndarray) -> np.ndarray:
        """Return ``eta`` [cm/s, deg/s] (``z_e`` is not asked for)."""
        return eta

    def read_feedback(self, z_e: np.ndarray, eta: np.ndarray, wave: np.ndarray) -> np.ndarray:
        """Return the message's ``eta``."""
        return eta


class PdWorstCase(MeasuredSpeed):
    """P+d on the observed speed, damping (40) for the run's worst delays, held."""

    name = "pd-worst-case"
    title = "P+d on the robot's speed, (40) sized for the worst delay, held"

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at the run's largest delays, held."""
        w1, w2 = self.worst_delays_s
        return held(w1, w2, self.cfg, int(np.asarray(h1_s).shape[0]))


class PdMeasured(MeasuredSpeed):
    """P+d on the observed speed, damping (40) scheduled on the measured delays."""

    name = "pd-measured"
    title = "P+d on the robot's speed, (40) on the measured delay"
    adapts = True

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at every delay estimate."""
        return scheduled(h1_s, h2_s, self.cfg)
