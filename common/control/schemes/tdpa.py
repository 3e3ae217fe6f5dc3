"""Two-port time-domain passivity: observers and controllers at both ports.

Ryu, Artigas and Preusche's scheme for a time-varying delay (docs/schemes.md), on the P+d
coupling of the robot's observed speed with zero-delay damping. Each side counts the energy
that enters the channel at its port and sends the count with its messages; each side's
observer compares the energy the other side put in (as received) with the energy that left
at its own port, and its controller dissipates the difference before it turns negative
(:mod:`bipedtele.control.schemes.ports`). Composed of
:class:`~bipedtele.control.schemes.passivity.Passivity` (the controllers and the energy
fields) and :class:`~bipedtele.control.schemes.pd.MeasuredSpeed` (the coupling).
"""

from __future__ import annotations

import numpy as np
from bipedtele.control.schemes.base import zero_delay
from bipedtele.control.schemes.passivity import Passivity
from bipedtele.control.schemes.pd import MeasuredSpeed

__all__ = ["Tdpa"]


class Tdpa(Passivity, MeasuredSpeed):
    """P+d on the observed speed with passivity controllers at both ports."""

    name = "tdpa"
    title = "time-domain passivity observers and controllers at both ports"

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at zero delay, held: the passivity controllers act in its place."""
        return zero_delay(h1_s, self.cfg)
