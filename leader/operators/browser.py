"""``browser``: the intended handle position comes from the cockpit's virtual joystick."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from bipedtele.leader.operator import Hand, Operator, OperatorContext
from bipedtele.link.messages import Feedback

__all__ = ["BrowserOperator"]


class BrowserOperator(Operator):
    """Intended handle position from the cockpit's virtual joystick.

    ``joystick()`` returns ``(x, y, t)`` with x, y in [-1, 1] (x right, y up) and ``t`` the
    time of the last browser input (``time.time()``), or ``None``. Joystick up moves the
    handle forward (forward speed), joystick right turns right (negative turn speed,
    yaw counter-clockwise positive). With no input, or input older than ``timeout_s``
    (the page went away), the hand holds the handle at zero.
    """

    name = "browser"

    def __init__(
        self,
        joystick: Callable[[], tuple[float, float, float] | None],
        k_g: Sequence[float],
        workspace_m: float = 0.05,
        hand: Hand | None = None,
        timeout_s: float = 1.0,
        clock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(k_g, workspace_m, hand)
        self.joystick = joystick
        self.timeout_s = timeout_s
        self.clock = clock
        self.active = False

    def intended_speed(self, t: float, feedback: Feedback | None) -> np.ndarray:
        """Intended [forward cm/s, turn deg/s] at device time ``t`` [s] (see the class docstring)."""
        js = self.joystick()
        self.active = False
        if js is None:
            return np.zeros(2)
        x, y, t_js = js
        if not (math.isfinite(x) and math.isfinite(y)) or self.clock() - t_js > self.timeout_s:
            return np.zeros(2)
        self.active = True
        pos = np.array([np.clip(y, -1, 1), -np.clip(x, -1, 1)]) * 0.98 * self.workspace_m
        return pos * self.k_g

    def progress(self) -> dict[str, Any]:
        """Plain-data progress for telemetry."""
        return {**super().progress(), "joystick_active": self.active}


def build(ctx: OperatorContext) -> Operator:
    if ctx.joystick is None:
        raise ValueError("operator 'browser' needs the cockpit (set leader.cockpit = true)")
    return BrowserOperator(ctx.joystick, ctx.k_g, ctx.workspace_m, ctx.hand)
