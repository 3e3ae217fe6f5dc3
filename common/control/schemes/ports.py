"""Port laws shared by every loop that runs a scheme: wave transform and passivity control.

All functions work element-wise on arrays of any shape (a ``[forward, turn]`` pair, or
runs x channels). Units: speeds ``r``, ``eta`` in cm/s (turn: deg/s), wave impedance ``b``
and gain ``k_m`` in N/(cm/s), forces in N, energies in N cm (N deg on the turn channel),
periods in s.

Port powers, the same for every scheme so that their observers compare:

* leader port: ``P_m = F_m r_m`` with ``r_m = k_g x_m`` the commanded speed and ``F_m`` the
  coupling force the handle renders (without the damping ``alpha_m dx_m``); positive when
  the operator puts energy into the channel;
* follower port: ``P_s = k_m (c - eta) c`` with ``c`` the speed command given to the robot;
  positive when the channel drives the robot.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = [
    "EnergyCounter",
    "WaveGain",
    "follower_passivity",
    "follower_power",
    "leader_passivity",
    "leader_power",
    "wave_follower",
    "wave_gain",
    "wave_leader",
]


def wave_leader(r_m: np.ndarray, v_rx: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Leader side of the wave transform.

    Parameters
    ----------
    r_m : numpy.ndarray
        Commanded speed ``k_g x_m`` [cm/s, deg/s].
    v_rx : numpy.ndarray
        Received wave ``v`` (already scaled by :func:`wave_gain`).
    b : numpy.ndarray
        Wave impedance [N/(cm/s)].

    Returns
    -------
    (F_m, u_m)
        The coupling force felt [N] and the wave to send.
    """
    s = np.sqrt(2.0 * b)
    return b * r_m - s * v_rx, s * r_m - v_rx


def wave_follower(u_rx: np.ndarray, eta: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Follower side: the speed command and the wave sent back.

    The follower's speed controller ``F_s = b (r_s - eta)`` solved with the wave relation
    ``r_s = (sqrt(2b) u_s - F_s) / b``.

    Returns
    -------
    (r_s, v_s)
        Speed command [cm/s, deg/s] and the wave to send, ``sqrt(b/2) eta``.
    """
    return 0.5 * (np.sqrt(2.0 / b) * u_rx + eta), np.sqrt(0.5 * b) * eta


def wave_gain(newest: np.ndarray, window: int) -> np.ndarray:
    """``sqrt(1 - dh/dt)``, at most 1, per period, from which message is the newest received.

    Parameters
    ----------
    newest : numpy.ndarray, shape (K,)
        Index of the newest message received at each period (-1: none), one message sent
        per period.
    window : int
        Periods over which ``1 - dh/dt`` is measured (messages advanced per period).
    """
    idx = np.maximum(np.asarray(newest, dtype=float), 0.0)
    w = max(1, int(window))
    before = np.concatenate([np.zeros(w), idx[:-w]]) if idx.size > w else np.zeros_like(idx)
    rate = (idx - before) / w
    return np.asarray(np.sqrt(np.clip(rate, 0.0, 1.0)))


class WaveGain:
    """``sqrt(1 - dh/dt)``, at most 1, from the messages received over the last ``window_s``.

    The running form of :func:`wave_gain` for a loop that sees one message at a time:
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


def leader_power(f_m: np.ndarray, r_m: np.ndarray) -> np.ndarray:
    """Leader port power ``P_m = F_m r_m`` [N cm/s] (positive: the operator puts energy in)."""
    return np.asarray(f_m * r_m)


def follower_power(c: np.ndarray, eta: np.ndarray, k_m: np.ndarray) -> np.ndarray:
    """Follower port power into the channel ``-k_m (c - eta) c`` [N cm/s] (negative: it drives the robot)."""
    return np.asarray(-k_m * (c - eta) * c)


def leader_passivity(f_m: np.ndarray, r_m: np.ndarray, observer: np.ndarray, dt: float) -> np.ndarray:
    """Impedance-type passivity controller at the leader: bound the energy the port gives out.

    The port may give out at most ``observer`` [N cm] (energy the follower put in, as
    received, less what the leader port gave out so far) this period: ``F_m r_m dt >=
    -observer``. Where the coupling force ``f_m`` [N] would exceed it, the force is cut to the
    bound (a damping on ``r_m`` added only then).
    """
    floor = -np.maximum(observer, 0.0) / dt
    power = f_m * r_m
    small = np.abs(r_m) < 1e-9
    bound = np.where(small, f_m, floor / np.where(small, 1.0, r_m))
    return np.asarray(np.where(power < floor, bound, f_m))


def follower_passivity(c: np.ndarray, eta: np.ndarray, observer: np.ndarray, k_m: np.ndarray, dt: float) -> np.ndarray:
    """Admittance-type passivity controller at the follower: bound the energy given to the robot.

    The command ``c`` [cm/s] is clipped to the interval where ``k_m (c - eta) c dt <=
    observer`` (the roots of that quadratic in ``c``), so the port never gives out more than
    the leader put in.
    """
    budget = np.maximum(observer, 0.0) / (k_m * dt)
    root = np.sqrt(eta * eta + 4.0 * budget)
    return np.asarray(np.clip(c, 0.5 * (eta - root), 0.5 * (eta + root)))


class EnergyCounter:
    """Energy in and out at one port, and its passivity observer.

    Parameters
    ----------
    shape : tuple of int
        Shape of the port's signals (e.g. ``(runs, 2)``).
    """

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.e_in = np.zeros(shape)
        self.e_out = np.zeros(shape)
        self.min_observer = np.zeros(shape)

    @classmethod
    def holding(cls, e_in: np.ndarray, e_out: np.ndarray, min_observer: np.ndarray) -> EnergyCounter:
        """Return a counter that starts from copies of these energies [N cm] (the arrays stay as they are)."""
        port = cls.__new__(cls)
        port.e_in, port.e_out, port.min_observer = e_in.copy(), e_out.copy(), min_observer.copy()
        return port

    def observer(self, other_in: np.ndarray) -> np.ndarray:
        """Passivity observer [N cm]: the other port's input as received less this port's output."""
        return np.asarray(other_in - self.e_out)

    def add(self, power: np.ndarray, dt: float, other_in: np.ndarray) -> None:
        """Count one period at ``power`` [N cm/s] (positive: into the channel) and track the observer."""
        self.e_in += np.maximum(power, 0.0) * dt
        self.e_out += np.maximum(-power, 0.0) * dt
        self.min_observer = np.minimum(self.min_observer, other_in - self.e_out)
