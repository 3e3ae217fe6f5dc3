"""The control-scheme contract: a scheme is one class that holds its own port laws.

A scheme decides, and nothing else differs between schemes:

* **the damping** both sides use, from the delay estimates (:meth:`Scheme.damping`): the
  leader's ``alpha_m`` [N s/m] in (31) and the follower's ``sigma_e`` (units of ``D``), which
  feeds (29) and the online choice (30) of ``(sigma_r, T, eps)``;
* **the leader's port law** (:meth:`Scheme.leader_force`): the coupling force ``F_m`` the
  handle renders and the speed (31) follows, from what the follower sent back, and what the
  command's ``wave`` field carries (:meth:`Scheme.command_wave`);
* **the follower's port law** (:meth:`Scheme.follower_command`): the speed command given to
  the robot from what arrived, and what the follower sends back (:meth:`Scheme.feedback_signal`
  in the reduced comparison, the Feedback message's fields in the real loops:
  :meth:`Scheme.feedback_wave`, :meth:`Scheme.read_feedback`);
* **the passivity observers and controllers** at both ports (:meth:`Scheme.limit_leader`,
  :meth:`Scheme.limit_follower`, :meth:`Scheme.count_leader`, :meth:`Scheme.count_follower`,
  :meth:`Scheme.energy_sent`; identity, nothing counted and nothing sent by default,
  :class:`~bipedtele.control.schemes.passivity.Passivity` composes them).

Every law is written once with numpy broadcasting: the real loops call it on one run
(arrays of shape ``(2,)``, ``[forward, turn]``), the reduced-model comparison on many runs
at once (shape ``(n, 2)``); scalars (``gain``, ``dt``) broadcast. The runners
(:mod:`bipedtele.control.schemes.runtime`, :mod:`bipedtele.studies.compare`) only call these
methods: none of them asks a scheme what kind it is. Units as in
:mod:`~bipedtele.control.schemes.ports`. docs/schemes.md gives each scheme's equations and
source, and how a new one is written.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import ClassVar, NamedTuple

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.damping import schedule_damping_array
from bipedtele.control.schemes.ports import EnergyCounter, WaveGain, wave_gain

__all__ = ["LeaderLaw", "Scheme", "held", "scheduled", "zero_delay"]


class LeaderLaw(NamedTuple):
    """What a scheme's leader port law gives for one period.

    Attributes
    ----------
    force : numpy.ndarray
        Coupling force ``F_m`` the handle renders [N], without the damping ``alpha_m dx_m``.
    follow : numpy.ndarray or None
        The speed the force (31) follows [cm/s, deg/s] when the law feels a speed directly
        (that speed itself); None when it is ``r_m - F_m / k_m`` (:meth:`followed` computes
        it only for the runner that needs it).
    received : numpy.ndarray
        The fed-back signal as the law used it (a wave: already scaled by the gain); what the
        next command's wave is made from (:meth:`Scheme.command_wave`).
    """

    force: np.ndarray
    follow: np.ndarray | None
    received: np.ndarray

    def followed(self, r_m: np.ndarray, k_m: np.ndarray) -> np.ndarray:
        """Return the speed the force follows [cm/s, deg/s]: ``follow``, or ``r_m - F_m / k_m``."""
        return self.follow if self.follow is not None else np.asarray(r_m - self.force / k_m)


class Scheme(ABC):
    """One bilateral control scheme: its damping and its port laws.

    Parameters
    ----------
    cfg : ControlConfig
        Gains and bounds of both sides.
    worst_delays_s : tuple of float
        The largest forward and backward delays the run will see [s] (``h1``, ``h2``);
        only a scheme sized for the worst case reads them.

    Attributes
    ----------
    name : str
        Registered name (``--scheme``).
    title : str
        One line for tables.
    adapts : bool
        Whether the damping follows the measured delays.
    """

    name: ClassVar[str]
    title: ClassVar[str]
    adapts: ClassVar[bool] = False

    def __init__(self, cfg: ControlConfig, worst_delays_s: tuple[float, float] = (0.0, 0.0)) -> None:
        self.cfg = cfg
        self.worst_delays_s = (float(worst_delays_s[0]), float(worst_delays_s[1]))

    @abstractmethod
    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Damping for delay estimates ``h1_s``, ``h2_s`` of shape ``(K,)`` [s].

        Returns
        -------
        (alpha_m, s_e)
            Leader damping [N s/m] and equivalent follower damping, each ``(K, 2)``
            ``[forward, turn]``.
        """

    # -- follower port -------------------------------------------------------------------
    @abstractmethod
    def follower_command(
        self, ref: np.ndarray, wave: np.ndarray, gain: float | np.floating, eta: np.ndarray, k_m: np.ndarray
    ) -> np.ndarray:
        """Return the speed command for the robot [cm/s, deg/s], before any passivity controller.

        Parameters
        ----------
        ref : numpy.ndarray
            The received command ``k_g x_m(t - h1)`` [cm/s, deg/s].
        wave : numpy.ndarray
            The received command's ``wave`` field (zeros when none was sent).
        gain : float
            The received-wave gain ``sqrt(1 - dh1/dt)`` the runner measured.
        eta : numpy.ndarray
            The robot's measured speed [cm/s, deg/s].
        k_m : numpy.ndarray
            Leader gain [N/(cm/s), N/(deg/s)] (the port's effort gain).
        """

    @abstractmethod
    def feedback_signal(self, z_e: Callable[[], np.ndarray], eta: np.ndarray, k_m: np.ndarray) -> np.ndarray:
        """Return what the follower sends back for the leader's law (what :meth:`read_feedback` reads).

        Parameters
        ----------
        z_e : callable
            Gives the equivalent follower's state ``z_e`` (29) [cm/s, deg/s] when called (the
            runner computes it only for a scheme that asks).
        eta : numpy.ndarray
            The robot's measured speed [cm/s, deg/s].
        k_m : numpy.ndarray
            Leader gain (the wave impedance ``b``).
        """

    def feedback_wave(self, eta: np.ndarray, k_m: np.ndarray) -> np.ndarray | None:
        """Return the Feedback message's ``wave`` field for measured speed ``eta`` (None: no wave)."""
        return None

    # -- leader port ---------------------------------------------------------------------
    @abstractmethod
    def read_feedback(self, z_e: np.ndarray, eta: np.ndarray, wave: np.ndarray) -> np.ndarray:
        """Return, from a Feedback message's fields, the signal :meth:`feedback_signal` sent."""

    @abstractmethod
    def leader_force(
        self, r_m: np.ndarray, signal: np.ndarray, gain: float | np.floating, k_m: np.ndarray
    ) -> LeaderLaw:
        """Return the coupling force and the speed the handle follows, before any passivity controller.

        Parameters
        ----------
        r_m : numpy.ndarray
            The commanded speed ``k_g x_m`` now [cm/s, deg/s].
        signal : numpy.ndarray
            What the follower sent back (:meth:`feedback_signal`), as received.
        gain : float
            The received-wave gain ``sqrt(1 - dh2/dt)`` the runner measured.
        k_m : numpy.ndarray
            Leader gain [N/(cm/s), N/(deg/s)].
        """

    def command_wave(self, r_m: np.ndarray, law: LeaderLaw, k_m: np.ndarray) -> np.ndarray | None:
        """Return the command's ``wave`` field for commanded speed ``r_m`` (None: no wave)."""
        return None

    # -- passivity observers and controllers (none unless the scheme composes them) --------
    def limit_leader(
        self, law: LeaderLaw, r_m: np.ndarray, port: EnergyCounter, other_in: np.ndarray, k_m: np.ndarray, dt: float
    ) -> LeaderLaw:
        """Return the leader's law after its passivity controller.

        ``port`` counts this port's energy, ``other_in`` [N cm] is the follower's input energy
        as received, ``dt`` [s] the period. By default: the law unchanged.
        """
        return law

    def limit_follower(
        self, c: np.ndarray, eta: np.ndarray, port: EnergyCounter, other_in: np.ndarray, k_m: np.ndarray, dt: float
    ) -> np.ndarray:
        """Return the follower's command after its passivity controller (as :meth:`limit_leader`; default: ``c``)."""
        return c

    def count_leader(
        self, port: EnergyCounter, law: LeaderLaw, r_m: np.ndarray, other_in: np.ndarray, dt: float
    ) -> None:
        """Count this period's leader port energy for the scheme's observer (default: no observer, nothing)."""
        return None

    def count_follower(
        self, port: EnergyCounter, c: np.ndarray, eta: np.ndarray, other_in: np.ndarray, k_m: np.ndarray, dt: float
    ) -> None:
        """Count this period's follower port energy for the scheme's observer (default: nothing)."""
        return None

    def energy_sent(self, e_in: np.ndarray) -> list[float] | None:
        """Return the ``energy`` field a message carries for port input ``e_in`` [N cm] (None: none)."""
        return None

    # -- the received-wave gain, measured by the runner over a window the runner passes -----
    def gain_meter(self, window_s: float) -> WaveGain:
        """Return the running gain ``sqrt(1 - dh/dt)`` over ``window_s`` [s], one message at a time."""
        return WaveGain(window_s)

    def received_gains(self, newest: np.ndarray, window: int) -> np.ndarray:
        """Return the gain per period from the newest message index per period, over ``window`` periods."""
        return wave_gain(newest, window)


def scheduled(h1_s: np.ndarray, h2_s: np.ndarray, cfg: ControlConfig) -> tuple[np.ndarray, np.ndarray]:
    """(40) evaluated at every delay estimate: shapes ``(K, 2)``."""
    alpha_m, s_e, _, _ = schedule_damping_array(np.asarray(h1_s, dtype=float), np.asarray(h2_s, dtype=float), cfg)
    return alpha_m, s_e


def held(h1_s: float, h2_s: float, cfg: ControlConfig, k_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """(40) evaluated once at ``(h1_s, h2_s)`` [s] and held for ``k_steps`` periods."""
    alpha_m, s_e = scheduled(np.array([h1_s]), np.array([h2_s]), cfg)
    return np.repeat(alpha_m, k_steps, axis=0), np.repeat(s_e, k_steps, axis=0)


def zero_delay(h1_s: np.ndarray, cfg: ControlConfig) -> tuple[np.ndarray, np.ndarray]:
    """(40) at zero delay (its lower bounds), held for as many periods as ``h1_s`` has."""
    return held(0.0, 0.0, cfg, int(np.asarray(h1_s).shape[0]))
