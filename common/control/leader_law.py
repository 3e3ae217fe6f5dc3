"""The leader's force law, eq. (31).

``f_m = -k_m (k_g x_m - z_e(t - h2)) + g_m(x_m) - alpha_m dx_m``, per channel
``[forward, turn]``. Units: ``x_m`` [m], ``dx_m`` [m/s], ``z_e`` [cm/s, deg/s],
``k_g`` [(cm/s)/m, (deg/s)/m], ``k_m`` [N/(cm/s), N/(deg/s)], ``alpha_m`` [N s/m],
``g_m`` [N]. The product ``k_m k_g`` [N/m] is the stiffness on the handle position; see
:mod:`bipedtele.control.damping` for why (40) is read with it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["leader_force"]


def leader_force(
    x_m: ArrayLike,
    dx_m: ArrayLike,
    z_e_delayed: ArrayLike,
    *,
    k_m: ArrayLike,
    k_g: ArrayLike,
    alpha_m: ArrayLike,
    g_m: ArrayLike = 0.0,
) -> np.ndarray:
    """Leader control force, eq. (31), unclamped (the device clamps it).

    Parameters
    ----------
    x_m : array_like, shape (2,) or (..., 2)
        Handle position [m], ``[forward, turn]`` axes.
    dx_m : array_like
        Handle velocity [m/s].
    z_e_delayed : array_like
        Equivalent follower speed as received, ``z_e(t - h2)`` [cm/s, deg/s].
    k_m : array_like
        Leader gain [N/(cm/s), N/(deg/s)].
    k_g : array_like
        Position-to-speed map [(cm/s)/m, (deg/s)/m].
    alpha_m : array_like
        Injected leader damping [N s/m] (from :func:`~bipedtele.control.damping.schedule_damping`).
    g_m : array_like
        Gravity compensation of the device [N] (0 when the device compensates itself).

    Returns
    -------
    numpy.ndarray
        Force [N], same shape as ``x_m``.
    """
    x = np.asarray(x_m, dtype=float)
    return np.asarray(
        -np.asarray(k_m, dtype=float) * (np.asarray(k_g, dtype=float) * x - np.asarray(z_e_delayed, dtype=float))
        + np.asarray(g_m, dtype=float)
        - np.asarray(alpha_m, dtype=float) * np.asarray(dx_m, dtype=float)
    )
