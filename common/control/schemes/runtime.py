"""A scheme's two sides in a running loop: what the leader feels, what the follower commands.

The leader loop (1 kHz) and the follower loop (its control rate) keep one of these each. They
call the scheme's port laws (:class:`~bipedtele.control.schemes.base.Scheme`: one run, arrays
of shape ``(2,)``) on the newest message, let the scheme count the energy at their port
(a scheme with a passivity observer does), and say what their next message carries (a wave variable and the port's input energy, fields ``wave`` and
``energy`` of Command and Feedback, as the scheme decides). Units as in
:mod:`~bipedtele.control.schemes.ports`; times in s on the receiver's clock.
"""

from __future__ import annotations

import numpy as np
from bipedtele.control.schemes.base import LeaderLaw, Scheme
from bipedtele.control.schemes.ports import EnergyCounter, WaveGain

__all__ = ["LOOP_WAVE_WINDOW_S", "FollowerPort", "LeaderPort", "WaveGain", "received"]

#: Window over which the real loops measure the received-wave gain ``sqrt(1 - dh/dt)`` [s]
#: (the reduced comparison uses its own, ``CompareParams.wave_window_s``; docs/schemes.md).
LOOP_WAVE_WINDOW_S = 0.5


class LeaderPort:
    """The scheme at the leader: the speed the force (31) follows, and what the command carries.

    Parameters
    ----------
    scheme : Scheme
        The scheme in use.
    k_m : array_like
        Leader gain [N/(cm/s), N/(deg/s)] (the wave impedance ``b``).
    """

    def __init__(self, scheme: Scheme, k_m: np.ndarray) -> None:
        self.scheme = scheme
        self.k_m = np.asarray(k_m, dtype=float)
        self.port = EnergyCounter((2,))
        self.wave_gain = scheme.gain_meter(LOOP_WAVE_WINDOW_S)
        self._law = LeaderLaw(np.zeros(2), None, np.zeros(2))
        self._fb_key: tuple[float, float] | None = None

    def felt_speed(
        self,
        r_m: np.ndarray,
        z_e: np.ndarray,
        eta: np.ndarray,
        wave: np.ndarray,
        energy: np.ndarray,
        t_sent: float,
        t_recv: float,
        dt: float,
    ) -> np.ndarray:
        """Return the speed the force follows [cm/s, deg/s] and count this period's port energy.

        Parameters
        ----------
        r_m : numpy.ndarray
            The commanded speed ``k_g x_m`` now.
        z_e, eta, wave, energy : numpy.ndarray
            The newest feedback's fields.
        t_sent, t_recv : float
            Its send stamp and arrival [s].
        dt : float
            This period [s].
        """
        if self._fb_key != (t_sent, t_recv):
            self._fb_key = (t_sent, t_recv)
            self.wave_gain.update(t_sent, t_recv)
        scheme, other_in = self.scheme, np.asarray(energy, dtype=float)
        signal = scheme.read_feedback(z_e, eta, wave)
        law = scheme.leader_force(r_m, signal, self.wave_gain.gain, self.k_m)
        law = scheme.limit_leader(law, r_m, self.port, other_in, self.k_m, dt)
        scheme.count_leader(self.port, law, r_m, other_in, dt)
        self._law = law
        return law.followed(r_m, self.k_m)

    def outgoing(self, r_m: np.ndarray) -> tuple[list[float] | None, list[float] | None]:
        """Return the command's ``wave`` (``u_m``) and ``energy``, each None where the scheme has no use for it."""
        wave = self.scheme.command_wave(r_m, self._law, self.k_m)
        return (None if wave is None else _pair(wave)), self.scheme.energy_sent(self.port.e_in)


class FollowerPort:
    """The scheme at the follower: the speed command given to the robot, and what the feedback carries.

    Parameters
    ----------
    scheme : Scheme
        The scheme in use.
    k_m : array_like
        The leader gain [N/(cm/s), N/(deg/s)] (the wave impedance ``b``, the port's effort gain).
    """

    def __init__(self, scheme: Scheme, k_m: np.ndarray) -> None:
        self.scheme = scheme
        self.k_m = np.asarray(k_m, dtype=float)
        self.port = EnergyCounter((2,))
        self.wave_gain = scheme.gain_meter(LOOP_WAVE_WINDOW_S)
        self._cmd_key: tuple[float, float] | None = None

    def command(
        self,
        ref: np.ndarray,
        eta: np.ndarray,
        wave: np.ndarray,
        energy: np.ndarray,
        t_sent: float,
        t_recv: float,
        dt: float,
    ) -> np.ndarray:
        """Return the speed command for the robot [cm/s, deg/s] and count this period's port energy.

        ``ref`` is the received ``k_g x_m(t - h1)``, ``eta`` the measured speeds; ``wave`` and
        ``energy`` the command's fields, sent at ``t_sent``, received at ``t_recv`` [s].
        """
        if self._cmd_key != (t_sent, t_recv):
            self._cmd_key = (t_sent, t_recv)
            self.wave_gain.update(t_sent, t_recv)
        scheme, k_m = self.scheme, self.k_m
        eta = np.asarray(eta, dtype=float)
        other_in = np.asarray(energy, dtype=float)
        c = scheme.follower_command(ref, wave, self.wave_gain.gain, eta, k_m)
        c = scheme.limit_follower(c, eta, self.port, other_in, k_m, dt)
        scheme.count_follower(self.port, c, eta, other_in, k_m, dt)
        return np.asarray(c)

    def outgoing(self, eta: np.ndarray) -> tuple[list[float] | None, list[float] | None]:
        """Return the feedback's ``wave`` (``v_s``) and ``energy``, each None where the scheme has no use for it."""
        wave = self.scheme.feedback_wave(np.asarray(eta, dtype=float), self.k_m)
        return (None if wave is None else _pair(wave)), self.scheme.energy_sent(self.port.e_in)


def _pair(v: np.ndarray) -> list[float]:
    return [float(v[0]), float(v[1])]


def received(value: list[float] | None) -> np.ndarray:
    """Return a ``wave`` or ``energy`` field as received: zeros when the sender sent none."""
    return np.zeros(2) if value is None else np.asarray(value, dtype=float)
