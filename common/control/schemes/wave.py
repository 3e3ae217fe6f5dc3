"""Wave variables with the gain for a time-varying delay.

Niemeyer and Slotine's wave transform with Lozano, Chopra and Spong's correction
(docs/schemes.md): the leader sends ``u_m = sqrt(2b) r_m - v_m`` and feels
``F_m = b r_m - sqrt(2b) v_m``; the follower commands ``r_s = (sqrt(2/b) u_s + eta) / 2``
(its speed controller of gain ``b``, solved with the wave relation) and sends back
``v_s = sqrt(b/2) eta``. Each received wave is scaled by ``sqrt(1 - dh/dt)`` (at most 1),
so the channel stores no energy while the delay grows. ``b = k_m`` [N/(cm/s), N/(deg/s)].
The channel is passive for any delay, so the damping is not scheduled: (40) and (30) at
zero delay.

The gain ``sqrt(1 - dh/dt)`` is measured by the runner over a window the runner passes
explicitly (:meth:`~bipedtele.control.schemes.base.Scheme.gain_meter`,
:meth:`~bipedtele.control.schemes.base.Scheme.received_gains`): ``[control] wave_window_s``
(:class:`~bipedtele.control.config.ControlConfig`), one setting for every runner.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from bipedtele.control.schemes.base import LeaderLaw, Scheme, zero_delay
from bipedtele.control.schemes.ports import wave_follower, wave_leader

__all__ = ["Wave"]


class Wave(Scheme):
    """Wave variables, time-varying-delay gain, zero-delay damping."""

    name = "wave"
    title = "wave variables with the time-varying-delay gain"

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at zero delay, held: the wave channel is passive for any delay."""
        return zero_delay(h1_s, self.cfg)

    def follower_command(
        self, ref: np.ndarray, wave: np.ndarray, gain: float | np.floating, eta: np.ndarray, k_m: np.ndarray
    ) -> np.ndarray:
        """Return ``r_s = (sqrt(2/b) g u_s + eta) / 2`` [cm/s, deg/s] from the received wave ``u_s``."""
        c, _ = wave_follower(gain * np.asarray(wave, dtype=float), eta, k_m)
        return np.asarray(c)

    def feedback_signal(self, z_e: Callable[[], np.ndarray], eta: np.ndarray, k_m: np.ndarray) -> np.ndarray:
        """Return the wave ``v_s = sqrt(b/2) eta`` (``z_e`` is not asked for)."""
        return wave_follower(np.zeros_like(eta), eta, k_m)[1]

    def feedback_wave(self, eta: np.ndarray, k_m: np.ndarray) -> np.ndarray | None:
        """Return ``v_s`` for the Feedback message's ``wave`` field."""
        return self.feedback_signal(lambda: eta, eta, k_m)

    def read_feedback(self, z_e: np.ndarray, eta: np.ndarray, wave: np.ndarray) -> np.ndarray:
        """Return the message's ``wave``."""
        return wave

    def leader_force(
        self, r_m: np.ndarray, signal: np.ndarray, gain: float | np.floating, k_m: np.ndarray
    ) -> LeaderLaw:
        """Return ``F_m = b r_m - sqrt(2b) g v_s`` [N]; the handle follows ``r_m - F_m / b``."""
        v_rx = gain * np.asarray(signal, dtype=float)
        force, _ = wave_leader(r_m, v_rx, k_m)
        return LeaderLaw(force, None, v_rx)

    def command_wave(self, r_m: np.ndarray, law: LeaderLaw, k_m: np.ndarray) -> np.ndarray | None:
        """Return ``u_m = sqrt(2b) r_m - g v_s`` for the command's ``wave`` field."""
        return wave_leader(r_m, law.received, k_m)[1]
