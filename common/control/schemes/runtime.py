"""A scheme's two sides in a running loop: the controller steps with one run, and the message fields.

The leader loop (1 kHz) and the follower loop (its control rate) keep one of these each. They
hold the controller step's state (:class:`~bipedtele.control.leader_step.LeaderController`,
:class:`~bipedtele.control.follower_step.FollowerController`: the same steps the comparison
runs on all its runs at once, here with one run, arrays of shape ``(1, 2)``) as a value,
measure the received-wave gain over ``[control] wave_window_s`` one message at a time, and say
what their next message carries (a wave variable and the port's input energy, fields ``wave``
and ``energy`` of Command and Feedback, as the scheme decides). Units as in
:mod:`~bipedtele.control.schemes.ports`; times in s on the receiver's clock.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.follower_step import (
    FollowerCommand,
    FollowerController,
    FollowerState,
    equivalent_steps,
)
from bipedtele.control.leader_step import LeaderController, LeaderFeedback, LeaderHandle
from bipedtele.control.schemes.base import Scheme
from bipedtele.control.schemes.ports import WaveGain

__all__ = ["FollowerPort", "LeaderPort", "WaveGain", "received"]


class LeaderPort:
    """The scheme at the leader: the leader step with one run, the speed the force (31) follows, what the command carries.

    Parameters
    ----------
    scheme : Scheme
        The scheme in use.
    k_m : array_like
        Leader gain [N/(cm/s), N/(deg/s)] (the wave impedance ``b``).
    wave_window_s : float
        Window of the received-wave gain [s] (default: ``[control] wave_window_s``'s default).
    """

    def __init__(self, scheme: Scheme, k_m: np.ndarray, wave_window_s: float | None = None) -> None:
        self.scheme = scheme
        self.k_m = np.asarray(k_m, dtype=float)
        self.controller = LeaderController(scheme, self.k_m)
        #: The step's state (a value: keep it to run a period again).
        self.state = self.controller.initial(1)
        self.wave_gain = scheme.gain_meter(_window(wave_window_s))
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
        """Return the speed the force follows [cm/s, deg/s] after this period's step.

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
        signal = self.scheme.read_feedback(z_e, eta, wave)
        fb = LeaderFeedback(_row(signal), _row(energy), self.wave_gain.gain)
        r = _row(r_m)
        # the step's force part: the command it carries is made when one is sent (outgoing)
        self.state, law = self.controller.force(self.state, LeaderHandle(r, dt), fb)
        return np.asarray(law.followed(r, self.k_m)[0])

    def outgoing(self, r_m: np.ndarray) -> tuple[list[float] | None, list[float] | None]:
        """Return the command's ``wave`` (``u_m``) and ``energy``, each None where the scheme has no use for it."""
        cmd = self.controller.command(self.state, _row(r_m))
        wave = None if cmd.wave is None else _pair(cmd.wave[0])
        return wave, self.scheme.energy_sent(cmd.energy[0])


class FollowerPort:
    """The scheme at the follower: the follower step with one run, the speed command, (29), what the feedback carries.

    Parameters
    ----------
    scheme : Scheme
        The scheme in use.
    k_m : array_like
        The leader gain [N/(cm/s), N/(deg/s)] (the wave impedance ``b``, the port's effort gain).
    wave_window_s : float
        Window of the received-wave gain [s] (default: ``[control] wave_window_s``'s default).
    eta_max : array_like
        The robot's largest speeds [cm/s, deg/s]: the command is clipped to them.
    """

    def __init__(
        self,
        scheme: Scheme,
        k_m: np.ndarray,
        wave_window_s: float | None = None,
        eta_max: np.ndarray | float = np.inf,
    ) -> None:
        self.scheme = scheme
        self.k_m = np.asarray(k_m, dtype=float)
        self.controller = FollowerController(scheme, self.k_m, eta_max=eta_max)
        #: The step's state (a value: keep it to run a period again).
        self.state: FollowerState = self.controller.initial(1)
        self.wave_gain = scheme.gain_meter(_window(wave_window_s))
        self._cmd_key: tuple[float, float] | None = None
        self._zoh_key: tuple[float, ...] | None = None
        self._zoh_cfg: ControlConfig | None = None
        self._zoh: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0))

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
        """Return the speed command for the robot [cm/s, deg/s] after this period's law.

        ``ref`` is the received ``k_g x_m(t - h1)``, ``eta`` the measured speeds; ``wave`` and
        ``energy`` the command's fields, sent at ``t_sent``, received at ``t_recv`` [s].
        """
        if self._cmd_key != (t_sent, t_recv):
            self._cmd_key = (t_sent, t_recv)
            self.wave_gain.update(t_sent, t_recv)
        cmd = FollowerCommand(_row(ref), _row(wave), _row(energy), self.wave_gain.gain)
        self.state, c, _ = self.controller.command(self.state, cmd, _row(eta), dt)
        return np.asarray(c[0])

    def equivalent(
        self, ref: np.ndarray, s_e: np.ndarray, f_hold: np.ndarray, cfg: ControlConfig, dt: float
    ) -> np.ndarray:
        """Advance the equivalent follower (29), (33) one period of ``dt`` [s] on ``ref``; return ``z_e`` [cm/s, deg/s]."""
        key = (*np.asarray(s_e, dtype=float).ravel().tolist(), float(dt))
        if self._zoh_key != key or self._zoh_cfg is not cfg:  # (29) discretised again only when its inputs moved
            self._zoh_key, self._zoh_cfg, self._zoh = key, cfg, equivalent_steps(_row(s_e), cfg, dt)
        zoh = self._zoh
        self.state = self.controller.equivalent(self.state, _row(ref), zoh, _row(f_hold))
        return np.asarray(self.state.eq[0, :, 1])

    def outgoing(self, eta: np.ndarray) -> tuple[list[float] | None, list[float] | None]:
        """Return the feedback's ``wave`` (``v_s``) and ``energy``, each None where the scheme has no use for it."""
        state = self.state
        fb = self.controller.feedback(state, _row(eta), lambda: state.eq[:, :, 1])
        return (None if fb.wave is None else _pair(fb.wave[0])), self.scheme.energy_sent(fb.energy[0])


def _window(wave_window_s: float | None) -> float:
    """Return the gain's window [s]: as given, else the control config's default."""
    if wave_window_s is not None:
        return float(wave_window_s)
    default = next(f.default for f in dataclasses.fields(ControlConfig) if f.name == "wave_window_s")
    assert isinstance(default, float)
    return default


def _row(v: np.ndarray | list[float]) -> np.ndarray:
    """One run: a ``[forward, turn]`` pair as shape ``(1, 2)``."""
    return np.asarray(v, dtype=float).reshape(1, 2)


def _pair(v: np.ndarray) -> list[float]:
    return [float(v[0]), float(v[1])]


def received(value: list[float] | None) -> np.ndarray:
    """Return a ``wave`` or ``energy`` field as received: zeros when the sender sent none."""
    return np.zeros(2) if value is None else np.asarray(value, dtype=float)
