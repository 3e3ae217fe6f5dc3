"""Wave variables with the gain for a time-varying delay.

Niemeyer and Slotine's wave transform with Lozano, Chopra and Spong's correction
(docs/schemes.md): the leader sends ``u_m = sqrt(2b) r_m - v_m`` and feels
``F_m = b r_m - sqrt(2b) v_m``; the follower commands ``r_s = (sqrt(2/b) u_s + eta) / 2``
(its speed controller of gain ``b``, solved with the wave relation) and sends back
``v_s = sqrt(b/2) eta``. Each received wave is scaled by ``sqrt(1 - dh/dt)`` (at most 1),
so the channel stores no energy while the delay grows. ``b = k_m`` [N/(cm/s), N/(deg/s)].
The channel is passive for any delay, so the damping is not scheduled: (40) and (30) at
zero delay.
"""

from __future__ import annotations

import numpy as np
from bipedtele.control.schemes.base import Scheme, zero_delay

__all__ = ["Wave"]


class Wave(Scheme):
    """Wave variables, time-varying-delay gain, zero-delay damping."""

    name = "wave"
    title = "wave variables with the time-varying-delay gain"
    feedback = "wave"

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at zero delay, held: the wave channel is passive for any delay."""
        return zero_delay(h1_s, self.cfg)
