"""Footfalls of a robot that reports its pose but not its touchdowns (a real NAO).

NAO's walk engine reports odometry (``ALMotion.getRobotPosition``), not touchdowns. The
:class:`StepSampler` reads that pose once per step period while the robot walks: each
sample is a :class:`~bipedtele.follower.robot.Footfall` one step period after the previous
one. The yaw of a walking robot changes in pulses, one per step (the hip yaws in single
support), so the change over any window of exactly one step period at a steady command
is the change of one step, whatever the window's phase: the sampled footfalls give the
same per-step odometry speed as the real touchdowns (docs/recording.md).
"""

from __future__ import annotations

import math

from bipedtele.follower.robot import Footfall

__all__ = ["StepSampler"]


class StepSampler:
    """One footfall per step period while walking.

    A sample is taken at the first observation at least one step period after the previous
    sample, so observations at the control rate place footfalls within one control period
    of the step period; the footfall's ``step_s`` is the time really elapsed since the
    previous sample. Standing still ends the chain: the next walk starts a new one (its
    first sample is a start point, not a footfall).
    """

    def __init__(self) -> None:
        self._n = 0
        self._last: tuple[float, tuple[float, float, float]] | None = None
        self._footfall: Footfall | None = None

    @property
    def footfall(self) -> Footfall | None:
        """The latest footfall (None before the first)."""
        return self._footfall

    def update(self, t: float, pose: tuple[float, float, float], walking: bool, step_s: float) -> Footfall | None:
        """Feed one observation; return the latest footfall.

        Parameters
        ----------
        t : float
            Observation time [s].
        pose : (float, float, float)
            x [m], y [m], yaw [rad] (odometry).
        walking : bool
            The robot is stepping.
        step_s : float
            The step period the robot walks with now [s] (T/2).
        """
        if not walking or not math.isfinite(t) or not step_s > 0:
            self._last = None
            return self._footfall
        if self._last is None:
            self._last = (t, pose)
        elif t - self._last[0] >= step_s - 1e-9:
            self._n += 1
            self._footfall = Footfall(self._n, t, pose, t - self._last[0])
            self._last = (t, pose)
        return self._footfall
