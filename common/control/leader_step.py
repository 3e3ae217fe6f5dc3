"""The leader's controller step: a pure function of its state, the handle and the feedback.

:meth:`LeaderController.step` runs one period of a scheme's leader port: the coupling force
the handle renders (the scheme's law, then its passivity controller), the port's energy, and
what the next command carries (the scheme's ``wave`` and the port's input energy). The state
(:class:`LeaderState`) is a value: keeping it is all it takes to run a period again, and
nothing inside reads a clock or does I/O (the period ``dt`` is an input). Every array has a
leading runs axis: the real leader loop calls the step with one run (shape ``(1, 2)``), the
reduced-model comparison with all its runs at once. The handle's damping and the slew and
force limits are the runner's (the device, the plant). Units as in
:mod:`~bipedtele.control.schemes.ports`: speeds cm/s (turn: deg/s), forces N, energies N cm
(N deg), times s. docs/architecture.md ("Controller steps").
"""

from __future__ import annotations

from typing import NamedTuple, cast

import numpy as np
from bipedtele.control.schemes.base import LeaderLaw, Scheme
from bipedtele.control.schemes.ports import EnergyCounter, leader_power

__all__ = [
    "LeaderCommand",
    "LeaderController",
    "LeaderFeedback",
    "LeaderForce",
    "LeaderHandle",
    "LeaderState",
    "port_counter",
]


class LeaderState(NamedTuple):
    """The leader port's state: its energy and the last law (arrays of shape ``(runs, 2)``).

    Attributes
    ----------
    e_in, e_out : numpy.ndarray
        Energy the port put into the channel and took out of it [N cm, N deg].
    min_observer : numpy.ndarray
        Least passivity observer seen [N cm, N deg].
    force : numpy.ndarray
        The last coupling force [N].
    received : numpy.ndarray
        The fed-back signal as the last law used it (what a command's wave is made from).
    """

    e_in: np.ndarray
    e_out: np.ndarray
    min_observer: np.ndarray
    force: np.ndarray
    received: np.ndarray


class LeaderHandle(NamedTuple):
    """The handle this period: the commanded speed ``r_m = k_g x_m`` [cm/s, deg/s], ``(runs, 2)``, and the period ``dt`` [s]."""

    r_m: np.ndarray
    dt: float


class LeaderFeedback(NamedTuple):
    """What arrived from the follower (the newest feedback).

    Attributes
    ----------
    signal : numpy.ndarray
        What the follower sent back for the leader's law (:meth:`Scheme.feedback_signal`;
        from a Feedback message: :meth:`Scheme.read_feedback`), ``(runs, 2)``.
    energy : numpy.ndarray
        The follower port's input energy as received [N cm] (zeros when none was sent).
    gain : numpy.ndarray or float
        The received-wave gain ``sqrt(1 - dh2/dt)`` the runner measured (``(runs, 1)`` or a scalar).
    """

    signal: np.ndarray
    energy: np.ndarray
    gain: np.ndarray | float


class LeaderForce(NamedTuple):
    """The force of one period: the coupling force ``F_m`` [N] and the speed (31) follows [cm/s, deg/s]."""

    force: np.ndarray
    follow: np.ndarray


class LeaderCommand(NamedTuple):
    """What a command carries besides the reference: the scheme's ``wave`` (None: none) and the port's input energy [N cm]."""

    wave: np.ndarray | None
    energy: np.ndarray


class LeaderController:
    """One scheme's leader port as a pure step.

    Parameters
    ----------
    scheme : Scheme
        The scheme whose laws run.
    k_m : array_like
        Leader gain [N/(cm/s), N/(deg/s)] (the wave impedance ``b``).
    observe_every_port : bool
        Count the port's energy for every scheme (the comparison reports each port's
        observer); otherwise only a scheme with an observer counts it
        (:meth:`Scheme.count_leader`), as the real loop does.
    """

    def __init__(self, scheme: Scheme, k_m: np.ndarray, *, observe_every_port: bool = False) -> None:
        self.scheme = scheme
        self.k_m = np.asarray(k_m, dtype=float)
        self.observe_every_port = observe_every_port

    def initial(self, runs: int) -> LeaderState:
        """Return the state before the first period: nothing counted, no law yet."""
        z = np.zeros((runs, 2))
        return LeaderState(z, z.copy(), z.copy(), z.copy(), z.copy())

    def step(
        self, state: LeaderState, handle: LeaderHandle, feedback: LeaderFeedback | None
    ) -> tuple[LeaderState, LeaderForce, LeaderCommand]:
        """Run one period: the force from what arrived, the port's energy, the command sent with the handle at ``r_m``.

        With no feedback yet (``None``) no force is rendered, the handle follows itself and
        nothing is counted.
        """
        r_m = np.asarray(handle.r_m, dtype=float)
        if feedback is None:
            return state, LeaderForce(np.zeros_like(r_m), r_m), self.command(state, r_m)
        state, law = self.force(state, handle, feedback)
        return state, LeaderForce(law.force, law.followed(r_m, self.k_m)), self.command(state, r_m)

    def force(
        self, state: LeaderState, handle: LeaderHandle, feedback: LeaderFeedback
    ) -> tuple[LeaderState, LeaderLaw]:
        """Return the state after this period's law and the law (the force part of :meth:`step`)."""
        scheme, k_m, dt = self.scheme, self.k_m, handle.dt
        r_m = np.asarray(handle.r_m, dtype=float)
        other_in = np.asarray(feedback.energy, dtype=float)
        port = port_counter(state.e_in, state.e_out, state.min_observer)
        # a gain per run ((runs, 1)) broadcasts as the contract's scalar gain does
        law = scheme.leader_force(r_m, feedback.signal, cast(float, feedback.gain), k_m)
        law = scheme.limit_leader(law, r_m, port, other_in, k_m, dt)
        if self.observe_every_port:
            port.add(leader_power(law.force, r_m), dt, other_in)
        else:
            scheme.count_leader(port, law, r_m, other_in, dt)
        new = LeaderState(port.e_in, port.e_out, port.min_observer, np.asarray(law.force), np.asarray(law.received))
        return new, law

    def command(self, state: LeaderState, r_m: np.ndarray) -> LeaderCommand:
        """Return what a command sent now with the handle at ``r_m`` [cm/s, deg/s] carries, after the last law."""
        law = LeaderLaw(state.force, None, state.received)
        return LeaderCommand(self.scheme.command_wave(np.asarray(r_m, dtype=float), law, self.k_m), state.e_in)


def port_counter(e_in: np.ndarray, e_out: np.ndarray, min_observer: np.ndarray) -> EnergyCounter:
    """Return an energy counter holding copies of a state's port energy (the state stays as it was)."""
    return EnergyCounter.holding(e_in, e_out, min_observer)
