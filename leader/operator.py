"""The operator models' contract: the human force f_h of eq. (1) for a simulated leader device.

Every model decides an *intended* speed pair [forward cm/s, turn deg/s], turns it into an
intended handle position ``x_d = ref / k_g`` (inside the workspace) and moves the handle
with a :class:`Hand`: a PD "hand" of limited stiffness, damping and strength pulling the
handle toward a smoothed ``x_d``. The device's force feedback therefore pushes the hand
off its target, as it does a human's: the operator feels the coordination error and
yields to it partly.

The models are parts, one module each in :mod:`bipedtele.leader.operators` (``scripted``,
``pilot``, ``browser``), each registered by its :data:`PART` (an :class:`OperatorPart`) as
one entry point of ``bipedtele.operators``; :func:`make_operator` builds one by name.

The loop calls :meth:`Operator.update` (at its command rate) with the device time and the
latest feedback; the device calls :meth:`Operator.hand_force` at every integration step.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from bipedtele.link.messages import Feedback
from bipedtele.parts import PART_GROUPS, Part, Parts
from bipedtele.telemetry import LeaderSample

__all__ = [
    "OPERATORS",
    "Hand",
    "Operator",
    "OperatorContext",
    "OperatorPart",
    "make_operator",
    "operator_names",
]


class Hand:
    """A human hand holding the handle: f_h = k_h (x_d - x) - b_h dx, |f_h| <= f_max.

    The target ``x_d`` follows the commanded target through a first-order lag of time
    constant ``tau_s`` (reaction and arm dynamics).

    Parameters
    ----------
    stiffness_n_m : float
        Hand stiffness k_h [N/m].
    damping_n_s_m : float
        Hand damping b_h [N s/m].
    force_max_n : float
        Largest force per axis the hand exerts [N].
    tau_s : float
        Time constant of the target smoothing [s] (0: none).
    """

    def __init__(
        self,
        stiffness_n_m: float = 300.0,
        damping_n_s_m: float = 8.0,
        force_max_n: float = 15.0,
        tau_s: float = 0.15,
    ) -> None:
        self.k = float(stiffness_n_m)
        self.b = float(damping_n_s_m)
        self.f_max = float(force_max_n)
        self.tau = float(tau_s)
        self.target = np.zeros(2)
        self.x_d = np.zeros(2)
        self._t_last: float | None = None

    def set_target(self, x_target_m: np.ndarray) -> None:
        """Where the hand wants the handle [m] per axis."""
        self.target = np.asarray(x_target_m, dtype=float).reshape(2).copy()

    def hand_force(self, t: float, x_m: np.ndarray, dx_m: np.ndarray) -> np.ndarray:
        """Force [N] on the handle at device time ``t`` [s] (see the class docstring)."""
        dt = 0.0 if self._t_last is None else max(0.0, t - self._t_last)
        self._t_last = t
        if self.tau > 0.0:
            self.x_d += (self.target - self.x_d) * (1.0 - math.exp(-dt / self.tau))
        else:
            self.x_d = self.target.copy()
        f = self.k * (self.x_d - x_m) - self.b * dx_m
        return np.clip(f, -self.f_max, self.f_max)


class Operator(abc.ABC):
    """Base of the operator models (see the module docstring).

    Parameters
    ----------
    k_g : sequence of float
        Handle position -> [forward cm/s, turn deg/s] per metre (eq. 7, 11).
    workspace_m : float
        Half-width of the handle workspace [m]; targets stay 2 % inside it.
    hand : Hand, optional
        The hand that moves the handle.
    """

    name: ClassVar[str] = ""

    def __init__(self, k_g: Sequence[float], workspace_m: float = 0.05, hand: Hand | None = None) -> None:
        self.k_g = np.asarray(k_g, dtype=float).reshape(2)
        self.workspace_m = float(workspace_m)
        self.hand = hand or Hand()
        self.intended = np.zeros(2)

    def update(self, t: float, feedback: Feedback | None) -> None:
        """Decide the intended speeds at device time ``t`` [s] from the latest feedback."""
        self.intended = np.asarray(self.intended_speed(t, feedback), dtype=float).reshape(2)
        lim = 0.98 * self.workspace_m
        self.hand.set_target(np.clip(self.intended / self.k_g, -lim, lim))

    @abc.abstractmethod
    def intended_speed(self, t: float, feedback: Feedback | None) -> np.ndarray:
        """Intended [forward cm/s, turn deg/s] at device time ``t`` [s]."""

    def hand_force(self, t: float, x_m: np.ndarray, dx_m: np.ndarray) -> np.ndarray:
        """f_h [N] (the :class:`bipedtele.leader.device.OperatorHand` protocol)."""
        return self.hand.hand_force(t, x_m, dx_m)

    def observe_sample(self, sample: LeaderSample) -> None:  # noqa: B027 - optional hook
        """Observe the loop's telemetry sample made right after each command.

        The sample (:class:`~bipedtele.telemetry.LeaderSample`) holds what was sent, the
        delay estimates, the clocks; models that use it override this.
        """

    @property
    def done(self) -> bool:
        """True when the operator has finished its task (never, for open-ended ones)."""
        return False

    def progress(self) -> dict[str, Any]:
        """Plain-data progress for telemetry."""
        return {"operator": self.name, "done": self.done, "intended": self.intended.tolist()}


@dataclass(frozen=True)
class OperatorContext:
    """What an operator factory may use to build its operator.

    Attributes
    ----------
    cfg : bipedtele.config.profile.Config
        Loaded profile (``[leader]`` and ``[control]`` are used).
    workspace_m : float
        The device's workspace half-width [m].
    joystick : callable or None
        The cockpit's joystick reader (``None`` without a cockpit).
    hold_script : bool
        ``scripted``: hold the last point's speed instead of finishing.
    """

    cfg: Any
    workspace_m: float = 0.05
    joystick: Callable[[], tuple[float, float, float] | None] | None = None
    hold_script: bool = False

    @property
    def leader(self) -> Any:
        """The ``[leader]`` section."""
        return self.cfg.sections["leader"]

    @property
    def k_g(self) -> list[float]:
        """Handle position -> speed gains of ``[control]`` (eq. 7, 11)."""
        return list(self.cfg.sections["control"].k_g)

    @property
    def hand(self) -> Hand:
        """A hand built from the ``[leader] hand_*`` settings."""
        lc = self.leader
        return Hand(lc.hand_stiffness_n_m, lc.hand_damping_n_s_m, lc.hand_force_max_n, lc.hand_tau_s)


@dataclass(frozen=True)
class OperatorPart(Part):
    """An operator model the leader offers (``--operator``, ``[leader] operator``).

    One entry point of ``bipedtele.operators``. ``build(ctx)`` takes an
    :class:`OperatorContext` and returns an :class:`Operator` whose ``name`` is the part's.
    Operators read ``[leader]`` and ``[control]``: a part brings no section of its own
    unless it sets :attr:`~bipedtele.parts.Part.config`.
    """


#: The operator models: the entry points of ``bipedtele.operators`` (the recipe: docs/architecture.md).
OPERATORS: Parts[OperatorPart] = Parts("operator", PART_GROUPS["operator"], OperatorPart)


def operator_names() -> list[str]:
    """Return the names of the operator models offered, sorted (nothing is imported)."""
    return OPERATORS.names()


def make_operator(
    name: str,
    cfg: Any,
    *,
    workspace_m: float = 0.05,
    joystick: Callable[[], tuple[float, float, float] | None] | None = None,
    hold_script: bool = False,
) -> Operator:
    """Build the registered operator ``name`` from a config.

    Parameters
    ----------
    name : str
        Operator model (one of :func:`operator_names`).
    cfg : bipedtele.config.profile.Config
        Loaded profile (``[leader]`` and ``[control]`` are used).
    workspace_m : float
        The device's workspace half-width [m].
    joystick : callable, optional
        The cockpit's joystick reader (required for ``browser``).
    hold_script : bool
        ``scripted``: hold the last point's speed instead of finishing (the run has a
        duration that ends it).

    Returns
    -------
    Operator
        The operator, ready for :meth:`Operator.update`.

    Raises
    ------
    ValueError
        No such operator (the message lists the allowed ones), or one that cannot be
        built from these settings.
    """
    operator: Operator = OPERATORS.get(name).build(OperatorContext(cfg, workspace_m, joystick, hold_script))
    return operator
