"""The control-scheme contract: where a bilateral scheme acts in the loop.

A scheme decides three things, and nothing else differs between schemes:

* **the damping** both sides use, from the delay estimates: the leader's ``alpha_m``
  [N s/m] in (31) and the follower's ``sigma_e`` (units of ``D``), which feeds (29) and the
  online choice (30) of ``(sigma_r, T, eps)``;
* **what the follower sends back** for the leader's force (:data:`Feedback`): the
  equivalent follower's ``z_e`` (29), the robot's observed speed, or a wave variable;
* **whether passivity controllers act** at both ports (time-domain passivity).

The loops that run a scheme (the reduced-model comparison, :mod:`bipedtele.control.compare`)
implement the three message contents and the port laws once
(:mod:`bipedtele.control.schemes.ports`); a scheme only names them. docs/schemes.md gives
each scheme's equations and source.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar, Literal

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.damping import schedule_damping_array

__all__ = ["Feedback", "Scheme", "held", "scheduled", "zero_delay"]

#: What the follower sends back for the leader's force: ``"equivalent"`` (``z_e`` of (29)),
#: ``"measured"`` (the robot's observed speed), ``"wave"`` (the wave variable ``v_s``).
Feedback = Literal["equivalent", "measured", "wave"]


class Scheme(ABC):
    """One bilateral control scheme.

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
    feedback : Feedback
        What the follower sends back.
    passivity : bool
        Passivity observers and controllers at both ports.
    adapts : bool
        Whether the damping follows the measured delays.
    """

    name: ClassVar[str]
    title: ClassVar[str]
    feedback: ClassVar[Feedback] = "equivalent"
    passivity: ClassVar[bool] = False
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
