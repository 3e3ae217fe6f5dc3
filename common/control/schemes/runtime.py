"""A scheme's two sides in a running loop: what the leader feels, what the follower commands.

The leader loop (1 kHz) and the follower loop (its control rate) keep one of these each. They
apply the scheme's port laws (:mod:`bipedtele.control.schemes.ports`) to the newest message,
count the energy at their port, and say what their next message carries (a wave variable and
the port's input energy, fields ``wave`` and ``energy`` of Command and Feedback). Units as in
:mod:`~bipedtele.control.schemes.ports`; times in s on the receiver's clock.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from bipedtele.control.schemes.base import Scheme
from bipedtele.control.schemes.ports import (
    EnergyCounter,
    follower_passivity,
    leader_passivity,
    wave_follower,
    wave_leader,
)
from bipedtele.messages import MAX_ENERGY

__all__ = ["FollowerPort", "LeaderPort", "WaveGain", "received"]


class WaveGain:
    """``sqrt(1 - dh/dt)``, at most 1, from the messages received over the last ``window_s``.

    ``1 - dh/dt`` is the time between the send stamps of the oldest and the newest message of
    the window over the time between their arrivals: a growing delay spreads the arrivals.

    Parameters
    ----------
    window_s : float
        Window [s].
    """

    def __init__(self, window_s: float = 0.5) -> None:
        self.window_s = float(window_s)
        self._seen: deque[tuple[float, float]] = deque()
        self.gain = 1.0

    def update(self, t_sent: float, t_recv: float) -> float:
        """Take a new message sent at ``t_sent`` and received at ``t_recv`` [s]; return the gain."""
        seen = self._seen
        if seen and t_sent <= seen[-1][0]:
            return self.gain  # not newer: no information on the rate
        seen.append((t_sent, t_recv))
        while len(seen) > 2 and seen[-1][1] - seen[0][1] > self.window_s:
            seen.popleft()
        (s0, r0), (s1, r1) = seen[0], seen[-1]
        if r1 - r0 > 1e-6:
            self.gain = float(np.sqrt(np.clip((s1 - s0) / (r1 - r0), 0.0, 1.0)))
        return self.gain


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
        self.wave_gain = WaveGain()
        self._v_rx = np.zeros(2)
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
        other_in = np.asarray(energy, dtype=float)
        if self.scheme.feedback == "wave":
            self._v_rx = self.wave_gain.gain * np.asarray(wave, dtype=float)
            f_m, _ = wave_leader(r_m, self._v_rx, self.k_m)
        else:
            follow = np.asarray(z_e if self.scheme.feedback == "equivalent" else eta, dtype=float)
            f_m = self.k_m * (r_m - follow)
            if not self.scheme.passivity:
                return follow  # exactly what arrived: (31) as written; no energy to count (none is sent)
        if self.scheme.passivity:
            f_m = leader_passivity(f_m, r_m, self.port.observer(other_in), dt)
            self.port.add(f_m * r_m, dt, other_in)
        return np.asarray(r_m - f_m / self.k_m)

    def outgoing(self, r_m: np.ndarray) -> tuple[list[float] | None, list[float] | None]:
        """Return the command's ``wave`` (``u_m``) and ``energy``, each None where the scheme has no use for it."""
        wave = _pair(wave_leader(r_m, self._v_rx, self.k_m)[1]) if self.scheme.feedback == "wave" else None
        return wave, (_energy(self.port.e_in) if self.scheme.passivity else None)


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
        self.wave_gain = WaveGain()
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
        eta = np.asarray(eta, dtype=float)
        if self.scheme.feedback == "wave":
            c, _ = wave_follower(self.wave_gain.gain * np.asarray(wave, dtype=float), eta, self.k_m)
        else:
            c = np.asarray(ref, dtype=float)
        other_in = np.asarray(energy, dtype=float)
        if self.scheme.passivity:  # the counters are sent only by a passivity scheme
            c = follower_passivity(c, eta, self.port.observer(other_in), self.k_m, dt)
            self.port.add(-self.k_m * (c - eta) * c, dt, other_in)
        return np.asarray(c)

    def outgoing(self, eta: np.ndarray) -> tuple[list[float] | None, list[float] | None]:
        """Return the feedback's ``wave`` (``v_s``) and ``energy``, each None where the scheme has no use for it."""
        wave = None
        if self.scheme.feedback == "wave":
            wave = _pair(wave_follower(np.zeros(2), np.asarray(eta, dtype=float), self.k_m)[1])
        return wave, (_energy(self.port.e_in) if self.scheme.passivity else None)


def _pair(v: np.ndarray) -> list[float]:
    return [float(v[0]), float(v[1])]


def _energy(e: np.ndarray) -> list[float]:
    """Return the energy counters as sent: bounded by what a message may carry."""
    return [min(float(x), MAX_ENERGY) for x in e]


def received(value: list[float] | None) -> np.ndarray:
    """Return a ``wave`` or ``energy`` field as received: zeros when the sender sent none."""
    return np.zeros(2) if value is None else np.asarray(value, dtype=float)
