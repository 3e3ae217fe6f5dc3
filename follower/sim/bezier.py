"""Bezier curves for the gait's joint references (pure numpy).

A curve of degree ``n`` over normalised time ``s`` in [0, 1] is
``q(s) = sum_i C_i B_{n,i}(s)`` with the Bernstein polynomials ``B_{n,i}``. The gait fits
its control points ``C`` to sampled joint angles with both end points pinned, so that
consecutive segments join without a jump.
"""

from __future__ import annotations

from math import comb

import numpy as np

__all__ = ["BezierFitter", "bernstein", "evaluate", "second_derivative"]


def bernstein(n: int, s: float | np.ndarray) -> np.ndarray:
    """Bernstein basis of degree ``n`` at ``s``: shape ``(..., n + 1)``."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)[..., None]
    i = np.arange(n + 1)
    coef = np.array([comb(n, k) for k in range(n + 1)], dtype=float)
    return coef * s**i * (1.0 - s) ** (n - i)


def evaluate(ctrl: np.ndarray, s: float, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Value and time derivative of a Bezier curve.

    Parameters
    ----------
    ctrl : ndarray, shape (n + 1, m)
        Control points of ``m`` curves [rad].
    s : float
        Normalised time in [0, 1].
    duration : float
        Segment duration [s] (for the derivative; > 0).

    Returns
    -------
    q : ndarray, shape (m,)
        Values [rad].
    qd : ndarray, shape (m,)
        Time derivatives [rad/s].
    """
    n = ctrl.shape[0] - 1
    q = bernstein(n, s) @ ctrl
    qd = n * (bernstein(n - 1, s) @ np.diff(ctrl, axis=0)) / duration
    return q, qd


def second_derivative(ctrl: np.ndarray, s: float, duration: float) -> np.ndarray:
    """Second time derivative of a Bezier curve [rad/s^2] (``ctrl`` (n + 1, m) [rad], ``s`` in [0, 1], ``duration`` [s])."""
    n = ctrl.shape[0] - 1
    return n * (n - 1) * (bernstein(n - 2, s) @ np.diff(ctrl, n=2, axis=0)) / (duration * duration)


class BezierFitter:
    """Least-squares fit of Bezier control points to samples, end points pinned.

    Parameters
    ----------
    degree : int
        Curve degree (>= 2).
    samples : int
        Number of equally spaced samples in [0, 1] the fit uses (>= degree + 1).
    """

    def __init__(self, degree: int = 5, samples: int = 12) -> None:
        if degree < 2 or samples < degree + 1:
            raise ValueError("degree >= 2 and samples >= degree + 1 required")
        self.degree = degree
        self.s = np.linspace(0.0, 1.0, samples)
        basis = bernstein(degree, self.s)
        self._b0 = basis[:, :1]
        self._bn = basis[:, -1:]
        self._pinv = np.linalg.pinv(basis[:, 1:-1])

    def fit(self, values: np.ndarray) -> np.ndarray:
        """Control points (degree + 1, m) for samples ``values`` (samples, m) at :attr:`s`."""
        values = np.asarray(values, dtype=float)
        c0, cn = values[:1], values[-1:]
        inner = self._pinv @ (values - self._b0 @ c0 - self._bn @ cn)
        return np.vstack([c0, inner, cn])
