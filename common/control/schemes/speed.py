"""The speed coupling several schemes share: the leader feels a speed the follower sends back.

The leader's force (31) follows a speed ``s`` sent back by the follower, ``F_m = k_m (r_m -
s)`` (so the handle follows ``s`` itself), and the follower commands the received reference
``k_g x_m(t - h1)`` as it is. Which speed ``s`` is sent back (the equivalent follower's ``z_e``
or the robot's measured ``eta``) is the scheme's: :meth:`SpeedFeedback.feedback_signal` and
:meth:`SpeedFeedback.read_feedback`. No wave, no gain: the ``gain`` arguments are unused.
"""

from __future__ import annotations

import numpy as np
from bipedtele.control.schemes.base import LeaderLaw, Scheme

__all__ = ["SpeedFeedback"]


class SpeedFeedback(Scheme):
    """The leader feels ``k_m (r_m - s)`` for the speed ``s`` sent back; the follower commands ``ref``."""

    def follower_command(
        self, ref: np.ndarray, wave: np.ndarray, gain: float | np.floating, eta: np.ndarray, k_m: np.ndarray
    ) -> np.ndarray:
        """Return the received reference ``ref`` as the robot's command [cm/s, deg/s]."""
        return np.asarray(ref, dtype=float)

    def leader_force(
        self, r_m: np.ndarray, signal: np.ndarray, gain: float | np.floating, k_m: np.ndarray
    ) -> LeaderLaw:
        """Return ``F_m = k_m (r_m - s)`` [N]; the handle follows ``s`` (the signal as it arrived)."""
        follow = np.asarray(signal, dtype=float)
        return LeaderLaw(k_m * (r_m - follow), follow, follow)
