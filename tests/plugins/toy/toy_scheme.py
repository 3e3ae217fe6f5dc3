"""A toy control scheme as a third-party part, in one module.

Registered by one entry point (``bipedtele.schemes``: ``toy-damped = toy_scheme:ToyDamped``).
Its law, written from the :class:`~bipedtele.control.schemes.base.Scheme` contract alone
(docs/schemes.md, "Writing a scheme"):

* the follower commands the received reference ``k_g x_m(t - h1)`` as it is and sends back
  the robot's measured speed ``eta`` (the Feedback message's ``eta``);
* the leader feels ``F_m = k_m (k_g x_m - eta(t - h2))`` [N] and its handle damping is (40)
  at zero delay plus a fixed :data:`EXTRA_ALPHA_M` [N s/m], never scheduled on the delay;
* no wave, no passivity controllers, nothing extra on the wire.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from bipedtele.control.schemes.base import LeaderLaw, Scheme, zero_delay

#: Extra handle damping [N s/m] per channel ``[forward, turn]``, on top of (40) at zero delay:
#: a round number above what (40) asks at the shipped trace's largest delays (0.37 s each way:
#: about 35 N s/m forward, 44 N s/m turn; docs/schemes.md).
EXTRA_ALPHA_M = np.array([40.0, 50.0])


class ToyDamped(Scheme):
    """The robot's measured speed fed back, a fixed extra handle damping."""

    name = "toy-damped"
    title = "toy: the robot's speed fed back, a fixed extra handle damping"

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at zero delay with :data:`EXTRA_ALPHA_M` added to ``alpha_m``, held."""
        alpha_m, s_e = zero_delay(h1_s, self.cfg)
        return alpha_m + EXTRA_ALPHA_M, s_e

    def follower_command(
        self, ref: np.ndarray, wave: np.ndarray, gain: float | np.floating, eta: np.ndarray, k_m: np.ndarray
    ) -> np.ndarray:
        """Return the received reference [cm/s, deg/s]."""
        return np.asarray(ref, dtype=float)

    def feedback_signal(self, z_e: Callable[[], np.ndarray], eta: np.ndarray, k_m: np.ndarray) -> np.ndarray:
        """Return the robot's measured speed [cm/s, deg/s]."""
        return np.asarray(eta, dtype=float)

    def read_feedback(self, z_e: np.ndarray, eta: np.ndarray, wave: np.ndarray) -> np.ndarray:
        """Return the Feedback message's ``eta``."""
        return np.asarray(eta, dtype=float)

    def leader_force(
        self, r_m: np.ndarray, signal: np.ndarray, gain: float | np.floating, k_m: np.ndarray
    ) -> LeaderLaw:
        """Return ``F_m = k_m (r_m - eta)`` [N]; the handle follows ``eta``."""
        eta = np.asarray(signal, dtype=float)
        return LeaderLaw(k_m * (r_m - eta), eta, eta)
