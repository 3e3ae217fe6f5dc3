"""Online choice of ``(sigma_r, T, eps)``, eq. (30) (cascade step V.3).

Problem (30), for the current equivalent damping ``s_e = [s_e_v, s_e_d]``::

    minimise   k_sigma (|sigma - s_e_v| + |tau - s_e_d|) + k_wt T + k_eps eps
    subject to | max|l_hybrid|(sigma, tau, T, eps) - max|l_equivalent|(s_e, T) | <= tolerance
               sigma, tau in s_r_range,  T in T_range,  eps in eps_range

``T`` and ``eps`` are shared by both channels (one walking cycle), ``sigma_r = [sigma, tau]``
is per channel. ``max|l_equivalent|`` is the spectral radius of (29) discretised over the
same walking cycle ``T`` by default (both sides of the equality are then contractions per
cycle); ``control.equivalent_period = "fixed"`` discretises it over
``equivalent_period_s`` instead (with the control period, 0.01 s, ``max|l_equivalent|`` is
about 0.997 and the equality has no solution in the bounds; docs/method.md). The hybrid
side is chosen by ``control.hybrid_model``; the chooser logs which:

* ``"paper"``: the reduced model (20)-(23) with the paper's ``dp`` and ``k_v``;
* ``"speed-loop"``: the same model with ``calibrated_dp`` and ``calibrated_k_v`` as
  ``bipedtele calibrate`` identifies them on the simulated walker; what they measure is the
  follower's own speed loop (28)+(12) (an ideal robot that applies every commanded speed
  gives the same ``k_v`` and dead time), not the walker (docs/walker_map.md);
* ``"walker"``: the tabulated radius of the simulated walker's own Poincare map over
  ``(sigma, tau, T)`` at one ``eps`` (:mod:`bipedtele.control.walker_map`), interpolated,
  with the limit-cycle region (and any node whose radius is >= 1 or that fell) excluded:
  :class:`WalkerSolver`.

Structure used by both solvers: ``max|l_hybrid| = max(r_v(sigma, T), r_d(tau, T), r_j(eps, T))``
where each block radius is continuous and increasing in its own variable (checked when the
table is built). For a fixed ``T`` the problem is then solved exactly: every block must stay
under ``target + tol`` (an upper bound on each variable), each variable sits at its preferred
value (``s_e``, ``s_e``, ``eps_min``) clipped to that bound, and if no block reaches
``target - tol`` the block that is cheapest to raise is raised to it. The outer problem is
one-dimensional in ``T``.

* :func:`solve_exact`: exact block radii and bisection inverses, a fine ``T`` grid plus a
  bounded scalar refinement. Offline.
* :class:`OnlineChooser`: the block radii tabulated once over ``(sigma, T)`` (the joint
  block is analytic), inverses by table interpolation, ``T`` on the table's grid. The band
  is narrowed by the table's measured interpolation error so that the exact residual of its
  answer stays within the tolerance. One call costs well under a millisecond.

When no point satisfies the equality (``target`` outside the achievable range of
``max|l_hybrid|`` for every ``T``), both return the point whose ``max|l_hybrid|`` is nearest
to ``max|l_equivalent|`` (all variables at their lower bounds if the target is too low, at
their upper bounds if it is too high) with ``feasible = False``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from bipedtele.control.choice import Choice, choice_cost, equivalent_period, finish_choice, target_radius
from bipedtele.control.config import ControlConfig
from bipedtele.control.hybrid import rho_joint, rho_speed_block
from bipedtele.control.walker_map import WalkerTable
from bipedtele.control.walker_solver import WalkerSolver
from numpy.typing import ArrayLike
from scipy.optimize import minimize_scalar

__all__ = ["Choice", "OnlineChooser", "WalkerSolver", "choice_cost", "equivalent_period", "solve_exact"]

LOG = logging.getLogger(__name__)


# Block interface: rho(b, x, T) and inv(b, y, T) (root of rho_b(., T) = y, NaN outside).
RhoFn = Callable[[int, np.ndarray, np.ndarray], np.ndarray]
InvFn = Callable[[int, np.ndarray, np.ndarray], np.ndarray]


def _solve_on_T(
    T: np.ndarray,
    target: np.ndarray,
    band: float,
    pref: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    w: np.ndarray,
    rho: RhoFn,
    inv: InvFn,
    k_wt: float,
    bounds_rho: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact per-T solution given block radii and inverses.

    ``pref`` is (3,), or (3, n) for a preference per column (many problems side by side).

    ``bounds_rho`` optionally gives the block radii at the lower and upper bounds, shapes
    (3, n) (they do not depend on ``s_e``, so the table precomputes them).

    Returns
    -------
    (cost, x, feasible)
        ``cost`` (n,), ``x`` (3, n) = sigma, tau, eps, ``feasible`` (n,) bool; infeasible
        entries have ``cost = inf``.
    """
    n = T.shape[0]
    y_hi = target + band
    y_lo = target - band
    x_base = np.empty((3, n))
    r_base = np.empty((3, n))
    if bounds_rho is None:
        r_min = np.stack([rho(b, np.full(n, lo[b]), T) for b in range(3)])
        r_max = np.stack([rho(b, np.full(n, hi[b]), T) for b in range(3)])
    else:
        r_min, r_max = bounds_rho
    up = np.empty((3, n))
    for b in range(3):
        root = inv(b, y_hi, T)
        up[b] = np.where(r_max[b] <= y_hi, hi[b], np.where(r_min[b] > y_hi, np.nan, root))
        x_base[b] = np.clip(pref[b], lo[b], np.where(np.isnan(up[b]), lo[b], up[b]))
        r_base[b] = rho(b, x_base[b], T)
    upper_ok = np.all(r_min <= y_hi, axis=0)
    reached = np.max(r_base, axis=0) >= y_lo
    cost0 = np.sum(w[:, None] * np.abs(x_base - pref.reshape(3, -1)), axis=0)
    extra = np.full((3, n), np.inf)
    x_new = x_base.copy()
    for b in range(3):
        low = np.where(r_min[b] >= y_lo, lo[b], inv(b, y_lo, T))
        ok = (r_max[b] >= y_lo) & (low <= up[b])
        cand = np.maximum(x_base[b], low)
        e = w[b] * (np.abs(cand - pref[b]) - np.abs(x_base[b] - pref[b]))
        extra[b] = np.where(ok, e, np.inf)
        x_new[b] = cand
    best_b = np.argmin(extra, axis=0)
    best_extra = extra[best_b, np.arange(n)]
    x = x_base.copy()
    need = ~reached
    cols = np.nonzero(need & np.isfinite(best_extra))[0]
    x[best_b[cols], cols] = x_new[best_b[cols], cols]
    feasible = upper_ok & (reached | np.isfinite(best_extra))
    cost = np.where(feasible, cost0 + np.where(reached, 0.0, best_extra) + k_wt * T, np.inf)
    return cost, x, feasible


def _fallback(T: np.ndarray, target: np.ndarray, lo: np.ndarray, hi: np.ndarray, rho: RhoFn) -> tuple[int, np.ndarray]:
    """Nearest achievable ``max|l_hybrid|`` when nothing is feasible: (index of T, x)."""
    n = T.shape[0]
    r_lo = np.max([rho(b, np.full(n, lo[b]), T) for b in range(3)], axis=0)
    r_hi = np.max([rho(b, np.full(n, hi[b]), T) for b in range(3)], axis=0)
    dist = np.maximum.reduce([r_lo - target, target - r_hi, np.zeros(n)])
    i = int(np.argmin(dist))
    x = lo.copy() if target[i] < r_lo[i] else hi.copy()
    return i, x


def _problem(s_e: ArrayLike, cfg: ControlConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    s = np.broadcast_to(np.asarray(s_e, dtype=float), (2,)).copy()
    lo = np.array([cfg.s_r_range[0], cfg.s_r_range[0], cfg.eps_range[0]], dtype=float)
    hi = np.array([cfg.s_r_range[1], cfg.s_r_range[1], cfg.eps_range[1]], dtype=float)
    pref = np.clip(np.array([s[0], s[1], cfg.eps_range[0]]), lo, hi)
    w = np.array([cfg.k_sigma, cfg.k_sigma, cfg.k_eps], dtype=float)
    return s, lo, hi, pref, w


def _joint_inv(y: np.ndarray, T: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((y > 0) & (y < 1), -T / (2.0 * np.log(np.clip(y, 1e-300, 1 - 1e-16))), np.nan)


# ------------------------------------------------------------------------------ exact


def _exact_blocks(cfg: ControlConfig, lo: np.ndarray, hi: np.ndarray) -> tuple[RhoFn, InvFn]:
    cfg = cfg.hybrid()
    (m, i_), (kv, kd), (bv, bd) = (np.asarray(v, dtype=float) for v in (cfg.D, cfg.k_s, cfg.beta_r))

    def rho(b: int, x: np.ndarray, T: np.ndarray) -> np.ndarray:
        if b == 0:
            return np.asarray(rho_speed_block(x, T, m, kv, bv, cfg.dp))
        if b == 1:
            return np.asarray(rho_speed_block(x, T, i_, kd, bd, cfg.dp_turn))
        return np.asarray(rho_joint(T, x))

    def inv(b: int, y: np.ndarray, T: np.ndarray) -> np.ndarray:
        if b == 2:
            return _joint_inv(y, T)
        a = np.full(T.shape, lo[b])
        c = np.full(T.shape, hi[b])
        for _ in range(64):
            mid = 0.5 * (a + c)
            below = rho(b, mid, T) <= y
            a = np.where(below, mid, a)
            c = np.where(below, c, mid)
        return np.asarray(0.5 * (a + c))

    return rho, inv


def solve_exact(s_e: ArrayLike, cfg: ControlConfig, *, n_T: int = 901) -> Choice:
    """Solve (30) offline.

    Exact block radii, an ``n_T``-point ``T`` grid, then a bounded scalar refinement of
    ``T`` around the best grid point.

    Parameters
    ----------
    s_e : array_like, shape (2,)
        Equivalent damping ``[s_e_v, s_e_d]`` (from the scheduler (40)).
    cfg : ControlConfig
        Bounds, weights, ``tolerance``, ``dp`` and the model gains.

    With ``hybrid_model = "walker"`` the model is the interpolated table itself:
    :class:`WalkerSolver` on a fine grid (1001 values per damping, 201 cycles).
    """
    if cfg.hybrid_model == "walker":
        return WalkerSolver(cfg, n_fine=1001, n_T=201).choose(s_e)
    s, lo, hi, pref, w = _problem(s_e, cfg)
    rho, inv = _exact_blocks(cfg, lo, hi)
    band = cfg.tolerance * (1.0 - 1e-6)
    T = np.linspace(cfg.T_range[0], cfg.T_range[1], n_T)
    cost, x, feas = _solve_on_T(T, target_radius(s, T, cfg), band, pref, lo, hi, w, rho, inv, cfg.k_wt)
    if not np.any(feas):
        i, xf = _fallback(T, target_radius(s, T, cfg), lo, hi, rho)
        return finish_choice(s, xf, float(T[i]), cfg, feasible=False)
    i = int(np.argmin(cost))
    best_T, best_x, best_c = float(T[i]), x[:, i], float(cost[i])

    def f(t: float) -> float:
        tt = np.array([t])
        c, _, _ = _solve_on_T(tt, target_radius(s, tt, cfg), band, pref, lo, hi, w, rho, inv, cfg.k_wt)
        return float(c[0]) if np.isfinite(c[0]) else 1e300

    a, b = float(T[max(i - 1, 0)]), float(T[min(i + 1, n_T - 1)])
    if b > a:
        res = minimize_scalar(f, bounds=(a, b), method="bounded", options={"xatol": 1e-9})
        if res.fun < best_c:
            tt = np.array([float(res.x)])
            _, xx, _ = _solve_on_T(tt, target_radius(s, tt, cfg), band, pref, lo, hi, w, rho, inv, cfg.k_wt)
            best_T, best_x = float(res.x), xx[:, 0]
    return finish_choice(s, best_x, best_T, cfg, feasible=True)


# ------------------------------------------------------------------------------ online


class OnlineChooser:
    """Tabulated solver of (30) for the online path (built in a few milliseconds).

    Parameters
    ----------
    cfg : ControlConfig
        Model gains, ``dp``, bounds, weights and ``tolerance``.
    n_sigma, n_T : int
        Table resolution over ``s_r_range`` and ``T_range``.

    Raises
    ------
    ValueError
        If a block radius is not increasing in its damping (the solver's premise).
    """

    def __init__(
        self, cfg: ControlConfig, *, n_sigma: int = 1001, n_T: int = 181, walker_table: WalkerTable | None = None
    ) -> None:
        self.cfg = cfg
        self.model = cfg.hybrid_model
        self._memo: dict[tuple[float, ...], Choice] = {}
        self._many: dict[tuple[float, float], tuple[np.ndarray, float]] = {}  # choose_many's answers
        self._walker: WalkerSolver | None = None
        if cfg.hybrid_model == "walker":
            self._walker = WalkerSolver(cfg, walker_table)
            self.T, self.sigma = self._walker.T_f, self._walker.sigma_f
            return
        self.T = np.linspace(cfg.T_range[0], cfg.T_range[1], n_T)
        self.sigma = np.linspace(cfg.s_r_range[0], cfg.s_r_range[1], n_sigma)
        self._ds = self.sigma[1] - self.sigma[0]
        hm = cfg.hybrid()
        (m, i_), (kv, kd), (bv, bd) = (np.asarray(v, dtype=float) for v in (hm.D, hm.k_s, hm.beta_r))
        LOG.info(
            "online choice (30): %s reduced model (dp %.3f, dp_turn %.3f, k_v %.3f, k_delta %.3f); "
            "(29) discretised over %s",
            cfg.hybrid_model,
            hm.dp,
            hm.dp_turn,
            kv,
            kd,
            "the walking cycle T" if cfg.equivalent_period == "cycle" else f"{cfg.equivalent_period_s:g} s",
        )
        sg, tg = self.sigma[:, None], self.T[None, :]
        self._tab = np.stack(
            [rho_speed_block(sg, tg, m, kv, bv, hm.dp), rho_speed_block(sg, tg, i_, kd, bd, hm.dp_turn)]
        )
        if not np.all(np.diff(self._tab, axis=1) > 0):
            raise ValueError("max|l_hybrid| of a speed block is not increasing in sigma_r: the solver does not apply")
        # Interpolation error of the table (at the midpoints), to keep the exact residual in band.
        mid = 0.5 * (sg[1:] + sg[:-1])
        exact_mid = np.stack(
            [rho_speed_block(mid, tg, m, kv, bv, hm.dp), rho_speed_block(mid, tg, i_, kd, bd, hm.dp_turn)]
        )
        self.interp_error = float(np.max(np.abs(exact_mid - 0.5 * (self._tab[:, 1:] + self._tab[:, :-1]))))
        self.band = cfg.tolerance - 2.0 * self.interp_error
        if self.band <= 0:
            raise ValueError(
                f"tolerance = {cfg.tolerance} is below the table's interpolation error; allowed: > {2 * self.interp_error:.2e}"
            )
        self._cols = np.arange(n_T)
        # Column-major flat copies: entry (row i, column c) is at c * n_sigma + i.
        self._flat = [np.ascontiguousarray(t.T).ravel() for t in self._tab]
        self._base = self._cols * n_sigma
        self._n_bisect = int(np.ceil(np.log2(n_sigma - 1)))
        _, lo, hi, _, _ = _problem([0.0, 0.0], cfg)
        self._bounds_rho = (
            np.stack([self._rho(b, np.full(n_T, lo[b]), self.T) for b in range(3)]),
            np.stack([self._rho(b, np.full(n_T, hi[b]), self.T) for b in range(3)]),
        )

    def _rho(self, b: int, x: np.ndarray, T: np.ndarray, base: np.ndarray | None = None) -> np.ndarray:
        if b == 2:
            return np.asarray(rho_joint(T, x))
        f = (x - self.sigma[0]) / self._ds
        i = np.clip(f.astype(int), 0, self.sigma.size - 2)
        frac = f - i
        k = (self._base if base is None else base) + i
        flat = self._flat[b]
        y0 = flat.take(k)
        return np.asarray(y0 + (flat.take(k + 1) - y0) * frac)

    def _inv(self, b: int, y: np.ndarray, T: np.ndarray, base: np.ndarray | None = None) -> np.ndarray:
        if b == 2:
            return _joint_inv(y, T)
        flat = self._flat[b]
        base = self._base if base is None else base
        # Vectorised bisection over the rows of every column: tab[i] <= y < tab[i + 1].
        i = np.zeros(T.shape[0], dtype=np.intp)
        j = np.full(T.shape[0], self.sigma.size - 1, dtype=np.intp)
        for _ in range(self._n_bisect):
            mid = (i + j) >> 1
            below = flat.take(base + mid) <= y
            i = np.where(below, mid, i)
            j = np.where(below, j, mid)
        y0 = flat.take(base + i)
        y1 = flat.take(base + i + 1)
        frac = np.clip((y - y0) / (y1 - y0), 0.0, 1.0)
        return np.asarray(self.sigma[i] + frac * self._ds)

    def choose(self, s_e: ArrayLike) -> Choice:
        """Solve (30) for the equivalent damping ``s_e`` (shape (2,)); < 1 ms per call.

        Answers are memoised per exact ``s_e`` value (the scheduler (40) often returns the
        same ``s_e``, e.g. its lower bound, for many delay estimates).
        """
        key = tuple(float(v) for v in np.broadcast_to(np.asarray(s_e, dtype=float), (2,)))
        hit = self._memo.get(key)
        if hit is not None:
            return hit
        out = self._choose(key)
        if len(self._memo) >= 1024:
            self._memo.clear()
        self._memo[key] = out
        return out

    def _choose(self, s_e: ArrayLike) -> Choice:
        if self._walker is not None:
            return self._walker.choose(s_e)
        s, lo, hi, pref, w = _problem(s_e, self.cfg)
        target = target_radius(s, self.T, self.cfg)
        cost, x, feas = _solve_on_T(
            self.T, target, self.band, pref, lo, hi, w, self._rho, self._inv, self.cfg.k_wt, self._bounds_rho
        )
        if not feas.any():
            i, xf = _fallback(self.T, target, lo, hi, self._rho)
            return finish_choice(s, xf, float(self.T[i]), self.cfg, feasible=False)
        i = int(np.argmin(cost))
        return finish_choice(s, x[:, i], float(self.T[i]), self.cfg, feasible=True)

    def choose_many(self, s_e: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Solve (30) for many equivalent dampings at once; return each ``s_r`` and ``T``.

        The answers of :meth:`choose`, one by one (tested equal), with the table's work done
        for all of them in one pass: the comparison chooses the next cycle of hundreds of
        runs, each with its own delays.

        Parameters
        ----------
        s_e : array_like
            Equivalent dampings, shape (m, 2) [N s/m, N m s/rad].

        Returns
        -------
        (s_r, T)
            The real dampings chosen, (m, 2), and the cycle times [s], (m,).
        """
        s_e = np.asarray(s_e, dtype=float).reshape(-1, 2)
        if self._walker is not None or s_e.shape[0] == 0:
            picks = [self.choose(s) for s in s_e]
            return np.array([c.s_r for c in picks]).reshape(-1, 2), np.array([c.T for c in picks])
        keys = [(float(a), float(b)) for a, b in s_e]
        todo = list(dict.fromkeys(k for k in keys if k not in self._many))
        if len(self._many) + len(todo) > 65536:  # full: start again with this batch's answers
            self._many.clear()
            todo = list(dict.fromkeys(keys))
        if todo:
            s_r, T = self._solve_many(np.array(todo))
            self._many.update(zip(todo, zip(s_r, T, strict=True), strict=True))
        answers = [self._many[k] for k in keys]
        return np.array([a[0] for a in answers]), np.array([a[1] for a in answers])

    def _solve_many(self, s_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Solve (30) for the dampings ``s_e`` (m, 2) side by side (the table's model)."""
        m, n_T = s_e.shape[0], self.T.size
        problems = [_problem(s, self.cfg) for s in s_e]
        _, lo, hi, _, w = problems[0]
        pref = np.repeat(np.stack([p[3] for p in problems], axis=1), n_T, axis=1)
        target = np.concatenate([target_radius(p[0], self.T, self.cfg) for p in problems])
        T, base = np.tile(self.T, m), np.tile(self._base, m)
        bounds = (np.tile(self._bounds_rho[0], (1, m)), np.tile(self._bounds_rho[1], (1, m)))
        cost, x, feas = _solve_on_T(
            T,
            target,
            self.band,
            pref,
            lo,
            hi,
            w,
            lambda b, v, t: self._rho(b, v, t, base),
            lambda b, v, t: self._inv(b, v, t, base),
            self.cfg.k_wt,
            bounds,
        )
        cost, feas, x = cost.reshape(m, n_T), feas.reshape(m, n_T), x.reshape(3, m, n_T)
        s_r, t_out = np.empty((m, 2)), np.empty(m)
        for i in range(m):
            if feas[i].any():
                j = int(np.argmin(cost[i]))
                s_r[i], t_out[i] = x[:2, i, j], self.T[j]
            else:  # nothing in band: the nearest achievable, as choose does
                c = self.choose(s_e[i])
                s_r[i], t_out[i] = c.s_r, c.T
        return s_r, t_out
