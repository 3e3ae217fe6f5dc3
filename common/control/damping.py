"""Online damping scheduler, eq. (40) (cascade step V.2).

Conditions (40), per channel::

    lambda_m  = alpha_m / (k_m k_g) - h1 - h2/4   > 0
    lambda_se = (sigma_e + D) / k_s  - h1/4 - h2  > 0

Units. The paper writes ``alpha_m / k_m``; with (31) written as
``f_m = -k_m (k_g x_m - z_e) - alpha_m dx_m`` the gain on the handle *position* is
``k_m k_g`` [N/m] and ``alpha_m`` is [N s/m], so ``alpha_m / (k_m k_g)`` is in seconds, as a
delay bound must be. ``alpha_m / k_m`` alone would be in cm/m (or deg/m), which cannot be
compared with h1. We therefore read ``k_m`` in (40) as ``k_m k_g`` (docs/method.md). The
second condition is dimensionally consistent as written: ``D/k_s`` and ``sigma_e/k_s`` are
in seconds.

The scheduler returns the *smallest* ``alpha_m`` and ``sigma_e`` that satisfy (40) with a
relative margin ``m`` on the delay terms, bounded below::

    alpha_m = max(alpha_m_min, (1 + m) k_m k_g (h1 + h2/4))
    sigma_e = max(sigma_e_min, (1 + m) k_s (h1/4 + h2) - D)

With ``m = 0`` the result lies on the boundary (``lambda = 0``) unless a lower bound is
active; ``m > 0`` makes the inequalities strict: ``lambda_m >= m (h1 + h2/4)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from bipedtele.control.config import ControlConfig

__all__ = ["Damping", "schedule_damping", "schedule_damping_array"]


@dataclass(frozen=True, eq=False)  # array fields: compare fields explicitly
class Damping:
    """Result of the scheduler, all ``[forward, turn]`` arrays of shape (2,).

    Attributes
    ----------
    alpha_m : numpy.ndarray
        Leader damping [N s/m].
    s_e : numpy.ndarray
        Equivalent follower damping sigma_e (units of D, i.e. k_s times seconds).
    lambda_m : numpy.ndarray
        Slack of the first condition of (40) [s].
    lambda_se : numpy.ndarray
        Slack of the second condition of (40) [s].
    """

    alpha_m: np.ndarray
    s_e: np.ndarray
    lambda_m: np.ndarray
    lambda_se: np.ndarray


def schedule_damping(h1_s: float, h2_s: float, cfg: ControlConfig) -> Damping:
    """Smallest leader and equivalent-follower damping satisfying (40).

    Parameters
    ----------
    h1_s, h2_s : float
        Forward (leader -> follower) and backward delays [s], e.g. the 1 s moving averages.
    cfg : ControlConfig
        Gains ``k_m``, ``k_g``, ``k_s``, ``D``, the relative ``margin`` and the lower bounds
        ``alpha_m_min``, ``s_e_min``.

    Raises
    ------
    ValueError
        If a delay is negative or not finite.
    """
    for name, h in (("h1_s", h1_s), ("h2_s", h2_s)):
        if not (math.isfinite(h) and h >= 0.0):
            raise ValueError(f"{name} = {h!r}: allowed: a finite delay >= 0 s")
    return Damping(*schedule_damping_array(np.asarray(h1_s, dtype=float), np.asarray(h2_s, dtype=float), cfg))


def schedule_damping_array(
    h1_s: np.ndarray, h2_s: np.ndarray, cfg: ControlConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised :func:`schedule_damping` for delay arrays of shape ``(n,)`` [s] (unchecked).

    Returns
    -------
    (alpha_m, s_e, lambda_m, lambda_se)
        Arrays of shape ``(n, 2)`` (``(2,)`` for scalar delays).
    """
    h1_s = np.asarray(h1_s, dtype=float)[..., None]
    h2_s = np.asarray(h2_s, dtype=float)[..., None]
    k_pos = np.asarray(cfg.k_m, dtype=float) * np.asarray(cfg.k_g, dtype=float)
    k_s = np.asarray(cfg.k_s, dtype=float)
    d = np.asarray(cfg.D, dtype=float)
    lead = h1_s + 0.25 * h2_s
    foll = 0.25 * h1_s + h2_s
    scale = 1.0 + cfg.margin
    alpha_m = np.maximum(cfg.alpha_m_min, scale * k_pos * lead)
    s_e = np.maximum(cfg.s_e_min, scale * k_s * foll - d)
    return alpha_m, s_e, alpha_m / k_pos - lead, (s_e + d) / k_s - foll
