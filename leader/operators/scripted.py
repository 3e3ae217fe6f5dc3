"""``scripted``: a profile of intended speeds over time (``(t, v, w)`` points, linear or step)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from bipedtele.leader.operator import Hand, Operator, OperatorContext
from bipedtele.link.messages import Feedback

__all__ = ["ScriptedOperator"]


class ScriptedOperator(Operator):
    """Intended speeds from a profile of ``(t [s], forward [cm/s], turn [deg/s])`` points.

    ``interp="linear"`` interpolates between points, ``"step"`` holds each point's value
    until the next. Before the first point and after the last, the end values hold; the
    operator is done once ``t`` passes the last point, unless ``hold_last``: then it is
    never done and keeps the last point's speed (the program's ``--duration`` ends the
    run). With ``wait_for_feedback`` (the default) the profile's time starts at the first
    update with feedback, as an operator waits for the robot to appear before driving it;
    before that the intent is zero.
    """

    name = "scripted"

    def __init__(
        self,
        points: Sequence[Sequence[float]],
        k_g: Sequence[float],
        interp: str = "linear",
        workspace_m: float = 0.05,
        hand: Hand | None = None,
        wait_for_feedback: bool = True,
        hold_last: bool = False,
    ) -> None:
        super().__init__(k_g, workspace_m, hand)
        self.wait_for_feedback = wait_for_feedback
        self.hold_last = hold_last
        self.t_start: float | None = None
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        if len(pts) == 0 or np.any(np.diff(pts[:, 0]) < 0) or not np.all(np.isfinite(pts)):
            raise ValueError("points: allowed: finite [t, forward, turn] rows with non-decreasing t")
        if interp not in ("linear", "step"):
            raise ValueError(f"interp = {interp!r}: allowed: 'linear', 'step'")
        self.points = pts
        self.interp = interp
        self._t = 0.0

    def intended_speed(self, t: float, feedback: Feedback | None) -> np.ndarray:
        """Intended [forward cm/s, turn deg/s] at device time ``t`` [s] (see the class docstring)."""
        if self.t_start is None:
            if self.wait_for_feedback and feedback is None:
                return np.zeros(2)
            self.t_start = t
        t = t - self.t_start
        self._t = t
        ts = self.points[:, 0]
        if self.interp == "step":
            i = max(0, int(np.searchsorted(ts, t, side="right")) - 1)
            return self.points[i, 1:].copy()
        return np.array([np.interp(t, ts, self.points[:, 1]), np.interp(t, ts, self.points[:, 2])])

    @property
    def done(self) -> bool:
        """True once the task is finished (see the class docstring)."""
        return bool(not self.hold_last and self._t > self.points[-1, 0])


def build(ctx: OperatorContext) -> Operator:
    lc = ctx.leader
    return ScriptedOperator(lc.script, ctx.k_g, lc.script_interp, ctx.workspace_m, ctx.hand, hold_last=ctx.hold_script)
