"""The speed observer, eq. (12): ``z_r' = (eta - z_r) / beta_r``, per channel.

Discretised exactly for an input held over the period (zero-order hold), so it is exact at
any control period: ``z_r[k+1] = a z_r[k] + (1 - a) eta[k]``, ``a = exp(-dt / beta_r)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["Observer"]


class Observer:
    """First-order observer of the real follower's speeds.

    Parameters
    ----------
    beta_r : array_like, shape (2,)
        Time constants [s] (``beta_r^{-1}`` is the observer gain), > 0.
    dt : float
        Control period [s], > 0.
    """

    def __init__(self, beta_r: ArrayLike, dt: float) -> None:
        self.beta_r = np.asarray(beta_r, dtype=float).reshape(2)
        if np.any(self.beta_r <= 0) or not dt > 0:
            raise ValueError(f"beta_r = {self.beta_r.tolist()}, dt = {dt}: allowed: both > 0")
        self.dt = float(dt)
        self._a = np.exp(-self.dt / self.beta_r)
        self.z_r = np.zeros(2)

    def reset(self, value: ArrayLike = 0.0) -> None:
        """Set the estimate ``z_r`` [cm/s, deg/s]."""
        self.z_r = np.broadcast_to(np.asarray(value, dtype=float), (2,)).copy()

    def step(self, eta: ArrayLike) -> np.ndarray:
        """Advance one period with the measured speeds ``eta`` [cm/s, deg/s]; return ``z_r``."""
        self.z_r = self._a * self.z_r + (1.0 - self._a) * np.asarray(eta, dtype=float)
        return self.z_r.copy()
