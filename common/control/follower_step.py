"""The follower's controller step: a pure function of its state, the command and the observation.

:meth:`FollowerController.step` runs one period of a scheme's follower side: the speed
command the scheme gives the robot from what arrived (its law, then its passivity
controller, clipped to the robot's speeds), the port's energy, the equivalent follower (29)
(with the held fictitious force of (33)) on the received reference, and what the feedback
carries (the scheme's signal, its ``wave``, the port's input energy). The state
(:class:`FollowerState`) is a value: re-running a period is running the step again from the
state kept before it; nothing inside reads a clock or does I/O (the period and the (29)
discretisation are inputs). Every array has a leading runs axis: the real follower loop
calls the step with one run, the reduced-model comparison with all its runs at once. What
the robot does with the command (the reference model (28), the walk, the plant) is the
runner's. Units as in :mod:`~bipedtele.control.schemes.ports`: speeds cm/s (turn: deg/s),
energies N cm (N deg), times s. docs/architecture.md ("Controller steps").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, cast

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.equivalent import equivalent_matrices
from bipedtele.control.leader_step import port_counter
from bipedtele.control.linalg import zoh2
from bipedtele.control.schemes.base import Scheme
from bipedtele.control.schemes.ports import follower_power

__all__ = [
    "FollowerCommand",
    "FollowerController",
    "FollowerFeedback",
    "FollowerObservation",
    "FollowerState",
    "equivalent_steps",
]


class FollowerState(NamedTuple):
    """The follower's state: the equivalent follower (29) and the port's energy.

    Attributes
    ----------
    eq : numpy.ndarray
        ``[eta_e, z_e]`` per channel [cm/s, deg/s], shape (runs, 2, 2).
    e_in, e_out, min_observer : numpy.ndarray
        The port's energy in and out and its least observer [N cm, N deg], (runs, 2).
    """

    eq: np.ndarray
    e_in: np.ndarray
    e_out: np.ndarray
    min_observer: np.ndarray


class FollowerCommand(NamedTuple):
    """The newest command arrived, as the scheme's law reads it.

    Attributes
    ----------
    ref : numpy.ndarray
        ``k_g x_m(t - h1)`` [cm/s, deg/s], (runs, 2).
    wave : numpy.ndarray
        The command's ``wave`` field (zeros when none was sent).
    energy : numpy.ndarray
        The leader port's input energy as received [N cm] (zeros when none was sent).
    gain : numpy.ndarray or float
        The received-wave gain ``sqrt(1 - dh1/dt)`` the runner measured ((runs, 1) or a scalar).
    """

    ref: np.ndarray
    wave: np.ndarray
    energy: np.ndarray
    gain: np.ndarray | float


class FollowerObservation(NamedTuple):
    """What the follower measures and is given this period.

    Attributes
    ----------
    eta : numpy.ndarray
        The robot's measured speed [cm/s, deg/s], (runs, 2).
    zoh : tuple of numpy.ndarray
        This period's exact discretisation of (29) per run, ``(Phi, Gamma)`` of shapes
        (runs, 2, 2, 2) (:func:`equivalent_steps`).
    f_hold : numpy.ndarray or None
        The fictitious force held on (33) this period, (runs, 2) (None: none).
    dt : float
        The period [s].
    """

    eta: np.ndarray
    zoh: tuple[np.ndarray, np.ndarray]
    f_hold: np.ndarray | None
    dt: float


class FollowerFeedback(NamedTuple):
    """What the feedback carries: the scheme's signal, its ``wave`` (None: none) and the port's input energy [N cm]."""

    signal: np.ndarray
    wave: np.ndarray | None
    energy: np.ndarray


def equivalent_steps(s_e: np.ndarray, cfg: ControlConfig, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH of (29) over ``dt`` [s] for equivalent dampings ``s_e`` of shape (m, 2): ``(Phi, Gamma)``, (m, 2, 2, 2)."""
    a_eq, b_eq = equivalent_matrices(np.asarray(s_e, dtype=float), cfg.D, cfg.k_s, cfg.beta_e, cfg.k_z)
    return zoh2(a_eq, b_eq, dt)


class FollowerController:
    """One scheme's follower side as a pure step.

    Parameters
    ----------
    scheme : Scheme
        The scheme whose laws run.
    k_m : array_like
        Leader gain [N/(cm/s), N/(deg/s)] (the wave impedance ``b``, the port's effort gain).
    eta_max : array_like
        The robot's largest speeds [cm/s, deg/s]: the command is clipped to them (default: none).
    observe_every_port : bool
        Count the port's energy for every scheme (the comparison's observer metric);
        otherwise only a scheme with an observer counts it, as the real loop does.
    """

    def __init__(
        self, scheme: Scheme, k_m: np.ndarray, *, eta_max: np.ndarray | float = np.inf, observe_every_port: bool = False
    ) -> None:
        self.scheme = scheme
        self.k_m = np.asarray(k_m, dtype=float)
        self.eta_max = np.asarray(eta_max, dtype=float)
        self.observe_every_port = observe_every_port

    def initial(self, runs: int) -> FollowerState:
        """Return the state before the first period: (29) at rest, nothing counted."""
        z = np.zeros((runs, 2))
        return FollowerState(np.zeros((runs, 2, 2)), z, z.copy(), z.copy())

    def step(
        self, state: FollowerState, command: FollowerCommand | None, observation: FollowerObservation
    ) -> tuple[FollowerState, np.ndarray | None, FollowerFeedback, dict[str, np.ndarray]]:
        """Run one period; return the state after it, the speed command, the feedback and the events.

        ``command`` None: no fresh command (no walk: the command is None, nothing is
        counted, (29) runs on a zero reference). Events: ``port_limited``, per run, where
        the passivity controller changed the scheme's command.
        """
        events: dict[str, np.ndarray] = {}
        walk = None
        ref = np.zeros_like(np.asarray(observation.eta, dtype=float))
        if command is not None:
            state, walk, events = self.command(state, command, observation.eta, observation.dt)
            ref = np.asarray(command.ref, dtype=float)
        state = self.equivalent(state, ref, observation.zoh, observation.f_hold)
        z_e = state.eq[:, :, 1]
        return state, walk, self.feedback(state, observation.eta, lambda: z_e), events

    def command(
        self, state: FollowerState, command: FollowerCommand, eta: np.ndarray, dt: float
    ) -> tuple[FollowerState, np.ndarray, dict[str, np.ndarray]]:
        """Return the state after the port's law, the speed command [cm/s, deg/s] and the events (the law part of :meth:`step`)."""
        scheme, k_m = self.scheme, self.k_m
        eta = np.asarray(eta, dtype=float)
        other_in = np.asarray(command.energy, dtype=float)
        port = port_counter(state.e_in, state.e_out, state.min_observer)
        # a gain per run ((runs, 1)) broadcasts as the contract's scalar gain does
        wanted = scheme.follower_command(command.ref, command.wave, cast(float, command.gain), eta, k_m)
        c = scheme.limit_follower(wanted, eta, port, other_in, k_m, dt)
        if self.observe_every_port:
            port.add(follower_power(c, eta, k_m), dt, other_in)
        else:
            scheme.count_follower(port, c, eta, other_in, k_m, dt)
        limited = np.any(np.asarray(c) != np.asarray(wanted), axis=-1)
        c = np.clip(c, -self.eta_max, self.eta_max)
        new = FollowerState(state.eq, port.e_in, port.e_out, port.min_observer)
        return new, np.asarray(c), ({"port_limited": limited} if limited.any() else {})

    def equivalent(
        self, state: FollowerState, ref: np.ndarray, zoh: tuple[np.ndarray, np.ndarray], f_hold: np.ndarray | None
    ) -> FollowerState:
        """Return the state with (29) advanced one period on ``ref`` (and (33)'s held force ``f_hold``)."""
        phi, gam = zoh
        eq = np.einsum("ncij,ncj->nci", phi, state.eq) + gam[..., 0] * np.asarray(ref, dtype=float)[:, :, None]
        if f_hold is not None:
            eq = eq + gam[..., 1] * np.asarray(f_hold, dtype=float)[:, :, None]
        return state._replace(eq=eq)

    def feedback(self, state: FollowerState, eta: np.ndarray, z_e: Callable[[], np.ndarray]) -> FollowerFeedback:
        """Return what the feedback carries for measured speed ``eta`` (``z_e`` gives (29)'s state when asked)."""
        eta = np.asarray(eta, dtype=float)
        signal = self.scheme.feedback_signal(z_e, eta, self.k_m)
        return FollowerFeedback(np.asarray(signal), self.scheme.feedback_wave(eta, self.k_m), state.e_in)
