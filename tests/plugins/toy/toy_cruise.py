"""A toy operator model as a third-party part, in one module.

Registered by one entry point (``bipedtele.operators``: ``toy-cruise = toy_cruise:PART``).
It intends a constant forward speed (``[leader] pilot_speed_cm_s``, an existing setting: an
operator may read any section of the profile) and never finishes.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from bipedtele.leader.operator import Operator, OperatorContext, OperatorPart
from bipedtele.link.messages import Feedback


class ToyCruise(Operator):
    """Forward at a constant speed, no turn."""

    name: ClassVar[str] = "toy-cruise"

    def __init__(self, speed_cm_s: float, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.speed_cm_s = float(speed_cm_s)

    def intended_speed(self, t: float, feedback: Feedback | None) -> np.ndarray:
        return np.array([self.speed_cm_s, 0.0])


def _build(ctx: OperatorContext) -> Operator:
    return ToyCruise(ctx.leader.pilot_speed_cm_s, ctx.k_g, ctx.workspace_m, ctx.hand)


PART = OperatorPart(name="toy-cruise", doc="forward at a constant speed (the plugin recipe's example)", build=_build)
