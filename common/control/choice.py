"""One solution of (30) and what every solver of it shares: the functional, the target radius.

:mod:`bipedtele.control.online` (the reduced model) and :mod:`bipedtele.control.walker_solver`
(the walker's tabulated map) both answer with a :class:`Choice`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.equivalent import equivalent_max_real
from bipedtele.control.hybrid import rho_blocks
from numpy.typing import ArrayLike

__all__ = ["Choice", "choice_cost", "equivalent_period", "finish_choice", "target_radius"]


@dataclass(frozen=True, eq=False)  # array fields: compare fields explicitly
class Choice:
    """One solution of (30).

    Attributes
    ----------
    s_r : numpy.ndarray, shape (2,)
        Real damping ``[sigma, tau]``.
    T : float
        Walking cycle time [s].
    eps : float
        Joint servo time constant [s].
    rho_hybrid : float
        ``max|l_hybrid|`` at the choice (exact).
    rho_equivalent : float
        ``max|l_equivalent|(s_e)`` over the cycle ``T``.
    residual : float
        ``rho_hybrid - rho_equivalent``.
    cost : float
        Value of the functional of (30).
    feasible : bool
        ``|residual| <= tolerance`` was reachable within the bounds.
    """

    s_r: np.ndarray
    T: float
    eps: float
    rho_hybrid: float
    rho_equivalent: float
    residual: float
    cost: float
    feasible: bool


def choice_cost(s_r: ArrayLike, T: float, eps: float, s_e: ArrayLike, cfg: ControlConfig) -> float:
    """Return the functional of (30)."""
    d = np.abs(np.asarray(s_r, dtype=float) - np.asarray(s_e, dtype=float)).sum()
    return float(cfg.k_sigma * d + cfg.k_wt * T + cfg.k_eps * eps)


def equivalent_period(T: ArrayLike, cfg: ControlConfig) -> np.ndarray:
    """Return the period over which (29) is discretised in (30) for candidate cycles ``T`` [s].

    ``cfg.equivalent_period = "cycle"``: ``T`` itself; ``"fixed"``: ``equivalent_period_s``.
    """
    t = np.asarray(T, dtype=float)
    if cfg.equivalent_period == "cycle":
        return t
    return np.full(t.shape, cfg.equivalent_period_s)


def target_radius(s_e: np.ndarray, T: np.ndarray, cfg: ControlConfig) -> np.ndarray:
    """``max|l_equivalent|(s_e)`` over the periods (29) is discretised on for cycles ``T`` [s]."""
    return np.exp(equivalent_period(T, cfg) * float(np.max(equivalent_max_real(s_e, cfg))))


def finish_choice(s_e: np.ndarray, x: np.ndarray, T: float, cfg: ControlConfig, feasible: bool) -> Choice:
    """Build the :class:`Choice` for ``x = [sigma, tau, eps]`` at cycle ``T`` [s], radii evaluated exactly."""
    sig, tau, eps = (float(v) for v in x)
    hm = cfg.hybrid()
    f, t, j = rho_blocks(sig, tau, T, eps, hm.dp, hm)
    rh = float(max(f, t, j))
    re = float(target_radius(s_e, np.asarray(T), cfg))
    return Choice(
        s_r=np.array([sig, tau]),
        T=float(T),
        eps=eps,
        rho_hybrid=rh,
        rho_equivalent=re,
        residual=rh - re,
        cost=choice_cost([sig, tau], T, eps, s_e, cfg),
        feasible=feasible,
    )
