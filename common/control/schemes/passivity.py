"""Time-domain passivity at both ports, as a mixin a scheme composes.

A scheme that lists :class:`Passivity` before its coupling (``class Tdpa(Passivity,
MeasuredSpeed)``) gets the impedance-type controller at the leader
(:func:`~bipedtele.control.schemes.ports.leader_passivity`), the admittance-type controller
at the follower (:func:`~bipedtele.control.schemes.ports.follower_passivity`), and sends its
port's input energy with every message so that the other side's observer can run: the
real loops count a port's energy (:class:`~bipedtele.control.schemes.ports.EnergyCounter`)
only for a scheme that observes it (:meth:`Passivity.count_leader`,
:meth:`Passivity.count_follower`); the comparison counts it for every scheme, to report each
port's observer. Units as in
:mod:`~bipedtele.control.schemes.ports`.
"""

from __future__ import annotations

import numpy as np
from bipedtele.control.schemes.base import LeaderLaw, Scheme
from bipedtele.control.schemes.ports import (
    EnergyCounter,
    follower_passivity,
    follower_power,
    leader_passivity,
    leader_power,
)
from bipedtele.link.messages import MAX_ENERGY

__all__ = ["Passivity"]


class Passivity(Scheme):
    """Passivity observers and controllers at both ports (Ryu, Artigas and Preusche; docs/schemes.md)."""

    def limit_leader(
        self, law: LeaderLaw, r_m: np.ndarray, port: EnergyCounter, other_in: np.ndarray, k_m: np.ndarray, dt: float
    ) -> LeaderLaw:
        """Cut the force where the port would give out more than its observer [N cm] this period."""
        force = leader_passivity(law.force, r_m, port.observer(other_in), dt)
        return LeaderLaw(force, None, law.received)  # the handle follows r_m - F_m / k_m

    def limit_follower(
        self, c: np.ndarray, eta: np.ndarray, port: EnergyCounter, other_in: np.ndarray, k_m: np.ndarray, dt: float
    ) -> np.ndarray:
        """Clip the command so the port gives the robot at most its observer [N cm] this period."""
        return follower_passivity(c, eta, port.observer(other_in), k_m, dt)

    def count_leader(
        self, port: EnergyCounter, law: LeaderLaw, r_m: np.ndarray, other_in: np.ndarray, dt: float
    ) -> None:
        """Count ``P_m = F_m r_m`` over ``dt`` [s] at the leader port."""
        port.add(leader_power(law.force, r_m), dt, other_in)

    def count_follower(
        self, port: EnergyCounter, c: np.ndarray, eta: np.ndarray, other_in: np.ndarray, k_m: np.ndarray, dt: float
    ) -> None:
        """Count ``-k_m (c - eta) c`` over ``dt`` [s] at the follower port."""
        port.add(follower_power(c, eta, k_m), dt, other_in)

    def energy_sent(self, e_in: np.ndarray) -> list[float] | None:
        """Return the port's input energy [N cm] as sent: bounded by what a message may carry."""
        return [min(float(x), MAX_ENERGY) for x in e_in]
