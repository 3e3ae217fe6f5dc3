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

Time sanity. The scheduler never raises on a delay: each one passes through
:func:`sanitize_delay` first. A negative delay (a message apparently received before it
was sent: clock offset error, running-sum rounding such as h = -1.4e-14) is read as 0 s.
A non-finite delay (NaN, +-inf) says nothing about the link, so it is read as
:data:`SAFE_DELAY_S`, the largest delay a message may carry: the safe side, since the
damping that (40) requires grows with the delays. Finite large delays are used as they are
(a real measurement), bounded by :data:`MAX_SCHEDULED_DELAY_S`, the largest difference of
two valid message times, only so that the products stay finite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.link.messages import MAX_DELAY_S, MAX_TIME, MIN_TIME

__all__ = [
    "MAX_SCHEDULED_DELAY_S",
    "SAFE_DELAY_S",
    "Damping",
    "sanitize_delay",
    "schedule_damping",
    "schedule_damping_array",
]

#: Delay [s] used in place of a non-finite one: the largest a message may carry.
SAFE_DELAY_S: float = float(MAX_DELAY_S)
#: Upper bound of a finite delay [s]: no two valid message times differ by more.
MAX_SCHEDULED_DELAY_S: float = float(MAX_TIME - MIN_TIME)


def sanitize_delay(h_s: float) -> float:
    """Return a delay the control laws can use [s]: ``>= 0`` and finite.

    Parameters
    ----------
    h_s : float
        Measured or received delay [s], possibly negative or not finite.

    Returns
    -------
    float
        For a finite value ``h_s`` clipped to ``[0, MAX_SCHEDULED_DELAY_S]``;
        :data:`SAFE_DELAY_S` for NaN or +-inf (the safe side: more damping). Never raises
        (anything ``float()`` cannot read is treated as NaN).
    """
    try:
        h = float(h_s)
    except (TypeError, ValueError, OverflowError):
        return SAFE_DELAY_S
    if not math.isfinite(h):
        return SAFE_DELAY_S
    return min(h, MAX_SCHEDULED_DELAY_S) if h > 0.0 else 0.0


def _sanitize_array(h_s: np.ndarray) -> np.ndarray:
    h = np.asarray(h_s, dtype=float)
    return np.where(np.isfinite(h), np.clip(h, 0.0, MAX_SCHEDULED_DELAY_S), SAFE_DELAY_S)


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
        Any value is accepted: each is read through :func:`sanitize_delay` (negative ->
        0 s, NaN or +-inf -> :data:`SAFE_DELAY_S`).
    cfg : ControlConfig
        Gains ``k_m``, ``k_g``, ``k_s``, ``D``, the relative ``margin`` and the lower bounds
        ``alpha_m_min``, ``s_e_min``.

    Notes
    -----
    Never raises on a delay value: a tick must not end on a timestamp.
    """
    h1, h2 = sanitize_delay(h1_s), sanitize_delay(h2_s)
    return Damping(*schedule_damping_array(np.asarray(h1, dtype=float), np.asarray(h2, dtype=float), cfg))


def schedule_damping_array(
    h1_s: np.ndarray, h2_s: np.ndarray, cfg: ControlConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised :func:`schedule_damping` for delay arrays of shape ``(n,)`` [s].

    Delays are sanitised element-wise as in :func:`sanitize_delay` (negative -> 0 s,
    non-finite -> :data:`SAFE_DELAY_S`).

    Returns
    -------
    (alpha_m, s_e, lambda_m, lambda_se)
        Arrays of shape ``(n, 2)`` (``(2,)`` for scalar delays).
    """
    h1_s = _sanitize_array(h1_s)[..., None]
    h2_s = _sanitize_array(h2_s)[..., None]
    k_pos = np.asarray(cfg.k_m, dtype=float) * np.asarray(cfg.k_g, dtype=float)
    k_s = np.asarray(cfg.k_s, dtype=float)
    d = np.asarray(cfg.D, dtype=float)
    lead = h1_s + 0.25 * h2_s
    foll = 0.25 * h1_s + h2_s
    scale = 1.0 + cfg.margin
    alpha_m = np.maximum(cfg.alpha_m_min, scale * k_pos * lead)
    s_e = np.maximum(cfg.s_e_min, scale * k_s * foll - d)
    return alpha_m, s_e, alpha_m / k_pos - lead, (s_e + d) / k_s - foll
