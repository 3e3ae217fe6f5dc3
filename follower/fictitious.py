"""Fictitious force f_v from the two chest sonars (paper Sec. 3.2.1).

Each sonar ``i`` looks along a yaw ``psi_i`` (left positive) and reports a range ``d_i``.
It contributes a repulsive force along its axis, pointing back at the robot, whose
magnitude rises linearly from 0 at ``d_safe`` to ``f_max`` at ``d_stop`` and saturates
closer than that. The force is split into its **tangential** part (along the robot's
forward axis; positive opposes forward motion) and its **normal** part (lateral).
The two cones overlap in front of the robot, so one obstacle straight ahead is seen by
both sonars: the tangential part is the larger of the two sonars' (not their sum, which
would count that obstacle twice and push the robot backwards at half the range); the
normal part is their difference (it points away from the nearer side). Only the
tangential part slows the robot (through ``k_z`` in eq. 28); the operator steers around
the obstacle, warned by the force and the video.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FictitiousForce"]


@dataclass(frozen=True)
class FictitiousForce:
    """Sonar ranges -> fictitious force.

    Attributes
    ----------
    d_safe : float
        Range at which the force starts [m].
    d_stop : float
        Range at which it reaches ``f_max`` [m].
    f_max : float
        Largest magnitude per sonar (model units: with k_z = 1 it is the forward speed
        removed, in cm/s).
    sonar_yaw_rad : float
        Yaw of each sonar axis from the forward axis [rad] (left +, right -).
    """

    d_safe: float = 0.50
    d_stop: float = 0.20
    f_max: float = 10.0
    sonar_yaw_rad: float = math.radians(22.0)

    def __post_init__(self) -> None:
        if not 0.0 < self.d_stop < self.d_safe:
            raise ValueError(f"d_stop = {self.d_stop}, d_safe = {self.d_safe}: allowed: 0 < d_stop < d_safe")

    def magnitude(self, d: float) -> float:
        """Force magnitude of one sonar at range ``d`` [m] (0 for non-finite ranges)."""
        if not math.isfinite(d):
            return 0.0
        x = (self.d_safe - d) / (self.d_safe - self.d_stop)
        return self.f_max * min(max(x, 0.0), 1.0)

    def __call__(self, left_m: float, right_m: float) -> np.ndarray:
        """``[tangential, normal]`` from the left and right ranges [m].

        Tangential is positive when it opposes forward motion; normal is positive when it
        pushes the robot to the left (obstacle on the right).
        """
        fl, fr = self.magnitude(left_m), self.magnitude(right_m)
        c, s = math.cos(self.sonar_yaw_rad), math.sin(self.sonar_yaw_rad)
        tangential = max(fl, fr) * c
        normal = (fr - fl) * s
        return np.array([tangential, normal])
