"""(30) solved on the simulated walker's own tabulated Poincare map (``hybrid_model = "walker"``).

The table (:mod:`bipedtele.control.walker_map`) gives the walker's radius at grid nodes of
``(sigma, tau, T)``; :class:`WalkerSolver` interpolates it and solves the equality of (30)
exactly along the lines where the interpolant is linear, never on a segment that touches a
limit-cycle, fallen or radius >= 1 node.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from bipedtele.control.choice import Choice, choice_cost, target_radius
from bipedtele.control.config import ControlConfig
from bipedtele.control.walker_map import WalkerTable, interp_weights, load_walker_table, weights1
from numpy.typing import ArrayLike

__all__ = ["WalkerSolver"]

LOG = logging.getLogger(__name__)


def _fine(nodes: np.ndarray, lo: float, hi: float, n: int) -> np.ndarray:
    """``n`` values over ``[lo, hi]`` plus the grid nodes inside it, sorted, unique."""
    inside = nodes[(nodes >= lo - 1e-12) & (nodes <= hi + 1e-12)]
    return np.unique(np.concatenate([np.linspace(lo, hi, n), inside]))


@dataclass(frozen=True, eq=False)
class _Pairs:
    """Segments of lines on which the surrogate radius is linear in the free variable.

    One entry per (segment between two free-axis nodes, line of fixed value and ``T``) whose
    ends touch no unstable node and that meets the bounds: ``y = y0 + (x - s0) / inv``.
    """

    s0: np.ndarray
    y0: np.ndarray
    inv: np.ndarray  # dx/dy, 0 on flat segments
    flat: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    fixed: np.ndarray
    t_idx: np.ndarray
    T: np.ndarray


def _pairs(
    nodes: np.ndarray,
    lo: float,
    hi: float,
    y: np.ndarray,
    bad: np.ndarray,
    fixed: np.ndarray,
    t_idx: np.ndarray,
    T: np.ndarray,
) -> _Pairs:
    """Build the usable segments; ``y`` and ``bad`` have shape ``(len(nodes), L)`` (radius and badness at the nodes per line)."""
    n = nodes.size
    if n == 1:  # a single node: a zero-length segment
        s0, s1, y0, y1, b = nodes[:, None], nodes[:, None], y, y, bad
    else:
        s0, s1, y0, y1, b = nodes[:-1, None], nodes[1:, None], y[:-1], y[1:], bad[:-1] | bad[1:]
    seg_lo = np.broadcast_to(np.maximum(s0, lo), y0.shape)
    seg_hi = np.broadcast_to(np.minimum(s1, hi), y0.shape)
    keep = ~b & (seg_lo <= seg_hi)
    dy = y1 - y0
    flat = np.abs(dy) < 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(flat, 0.0, (s1 - s0) / np.where(flat, 1.0, dy))
    line = np.broadcast_to(np.arange(y.shape[1]), y0.shape)
    k = line[keep]
    return _Pairs(
        s0=np.broadcast_to(s0, y0.shape)[keep],
        y0=y0[keep],
        inv=inv[keep],
        flat=flat[keep],
        lo=seg_lo[keep],
        hi=seg_hi[keep],
        fixed=fixed[k],
        t_idx=t_idx[k],
        T=T[k],
    )


def _best(
    p: _Pairs, target_T: np.ndarray, band: float, pref: float, pref_fixed: float, k_sigma: float, k_wt: float
) -> tuple[float, float, float, float]:
    """Cheapest point with ``|y - target| <= band`` over the segments: (cost, free value, fixed value, T)."""
    if p.s0.size == 0:
        return (np.inf, np.nan, np.nan, np.nan)
    tgt = target_T[p.t_idx]
    xa = p.s0 + (tgt - band - p.y0) * p.inv
    xb = p.s0 + (tgt + band - p.y0) * p.inv
    in_band = np.abs(p.y0 - tgt) <= band
    a = np.where(p.flat, np.where(in_band, p.lo, np.inf), np.maximum(np.minimum(xa, xb), p.lo))
    b = np.where(p.flat, p.hi, np.minimum(np.maximum(xa, xb), p.hi))
    x = np.minimum(np.maximum(pref, a), b)
    cost = np.where(a <= b, k_sigma * (np.abs(x - pref) + np.abs(p.fixed - pref_fixed)) + k_wt * p.T, np.inf)
    i = int(np.argmin(cost))
    return (float(cost[i]), float(x[i]), float(p.fixed[i]), float(p.T[i]))


class WalkerSolver:
    """Solver of (30) on the tabulated walker map (``hybrid_model = "walker"``).

    The surrogate radius (:class:`~bipedtele.control.walker_map.WalkerTable`) is
    trilinear over the table's ``(sigma, tau, T)`` nodes, so along a line of fixed ``tau``
    and ``T`` it is piecewise linear in ``sigma`` (and likewise in ``tau``): the equality of
    (30) is then solved exactly on every segment of such a line. The lines are a fine grid
    of the fixed variable (``n_fine`` values plus the table's nodes, and at each call the
    preferred value ``s_e``) times ``n_T`` cycles; the cheapest feasible point over both
    families wins (its cost is within ``k_sigma`` times half a fine step of the optimum over
    the continuum of the fixed variable, exact when the optimum has it at ``s_e``). ``eps``
    is the table's (the walker map was measured there; it must lie in ``eps_range``).
    ``sigma``, ``tau`` and ``T`` are bounded by the config's ranges and the table's (no
    extrapolation). Segments that touch an unstable node (limit cycle, fall, radius >= 1)
    are never used. When nothing is feasible: the stable node (on the lines) whose radius
    is nearest to the target, ``feasible = False``.

    Parameters
    ----------
    cfg : ControlConfig
        Bounds, weights, ``tolerance``, ``equivalent_period``.
    table : WalkerTable, optional
        Default: the shipped table (package data).
    n_fine, n_T : int
        Resolution of the fixed variable's grid and of ``T``.

    Raises
    ------
    ValueError
        If the table and the config's bounds do not overlap, or ``eps`` is outside ``eps_range``.
    """

    def __init__(
        self, cfg: ControlConfig, table: WalkerTable | None = None, *, n_fine: int = 101, n_T: int = 21
    ) -> None:
        tab = table if table is not None else load_walker_table()
        self.cfg, self.table = cfg, tab
        bounds = []
        for name, ax, rng in (
            ("sigma", tab.sigma, cfg.s_r_range),
            ("tau", tab.tau, cfg.s_r_range),
            ("T", tab.T, cfg.T_range),
        ):
            lo, hi = max(float(rng[0]), float(ax[0])), min(float(rng[1]), float(ax[-1]))
            if lo > hi:
                raise ValueError(
                    f"walker table {tab.source}: {name} in [{ax[0]:g}, {ax[-1]:g}] misses the config's range "
                    f"[{rng[0]:g}, {rng[1]:g}]; allowed: overlapping ranges"
                )
            bounds.append((lo, hi))
        if not cfg.eps_range[0] <= tab.eps <= cfg.eps_range[1]:
            raise ValueError(
                f"walker table {tab.source}: eps = {tab.eps:g} s; allowed: within eps_range {list(cfg.eps_range)}"
            )
        self.bounds = bounds
        self.sigma_f = _fine(tab.sigma, *bounds[0], n_fine)
        self.tau_f = _fine(tab.tau, *bounds[1], n_fine)
        self.T_f = _fine(tab.T, *bounds[2], n_T)
        self._rho0 = np.where(tab.unstable, 0.0, tab.rho)
        self._bad = tab.unstable.astype(float)
        self._wt = interp_weights(tab.T, self.T_f)
        self._wt_pos = (self._wt > 0).astype(float)
        self._free_nodes = (tab.sigma, tab.tau)
        # family 0: sigma free, lines over (tau_f, T_f); family 1: tau free, lines over (sigma_f, T_f)
        self._fam = [self._family(0, self.tau_f), self._family(1, self.sigma_f)]
        # the lines at the fixed variable's table nodes, (n_fixed_nodes, n_free, n_T): the line
        # at any fixed value is a blend of two of them (the preferred value's, per call)
        self._node_lines = []
        for c in range(2):
            y, bad = self._lines(c, self._free_nodes[1 - c])
            shape = (self._free_nodes[1 - c].size, self._free_nodes[c].size, self.T_f.size)
            self._node_lines.append(
                (
                    y.reshape(shape[1], shape[0], shape[2]).transpose(1, 0, 2),
                    bad.reshape(shape[1], shape[0], shape[2]).transpose(1, 0, 2),
                )
            )
        self._t_idx = np.arange(self.T_f.size)
        LOG.info(
            "online choice (30): walker map table %s (%d x %d x %d nodes, %d unstable: %d limit cycle, %d fallen; "
            "eps %.3f s; sigma [%g, %g], tau [%g, %g], T [%g, %g] s); (29) discretised over %s",
            tab.source,
            tab.sigma.size,
            tab.tau.size,
            tab.T.size,
            int(tab.unstable.sum()),
            int(tab.limit_cycle.sum()),
            int(tab.fallen.sum()),
            tab.eps,
            *bounds[0],
            *bounds[1],
            *bounds[2],
            "the walking cycle T" if cfg.equivalent_period == "cycle" else f"{cfg.equivalent_period_s:g} s",
        )

    def _lines(self, free: int, fixed_values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radius and badness at the free axis's nodes on the lines (fixed value x T_f): shapes (n_free, L)."""
        nodes = self._free_nodes[1 - free]
        if fixed_values.size == 1:
            w1 = weights1(nodes, float(fixed_values[0]))
            w_fixed = np.full((1, nodes.size), np.nan) if w1 is None else w1[None, :]
        else:
            w_fixed = interp_weights(nodes, fixed_values)
        rho = self._rho0 if free == 0 else self._rho0.transpose(1, 0, 2)
        bad = self._bad if free == 0 else self._bad.transpose(1, 0, 2)
        y = np.einsum("ijk,aj,bk->iab", rho, w_fixed, self._wt)
        b = np.einsum("ijk,aj,bk->iab", bad, (w_fixed > 0).astype(float), self._wt_pos) > 0
        return y.reshape(y.shape[0], -1), b.reshape(b.shape[0], -1)

    def _pref_line(self, free: int, value: float) -> _Pairs:
        """Return the segments of the lines (over ``T_f``) at one value of the fixed variable."""
        nodes = self._free_nodes[1 - free]
        w = weights1(nodes, value)
        y_n, bad_n = self._node_lines[free]
        if w is None:  # not reached: the preferred value is clipped to the table
            y, bad = y_n[0], np.ones(y_n.shape[1:], dtype=bool)
        else:
            (i,) = np.nonzero(w > 0)
            y = np.tensordot(w[i], y_n[i], axes=1)
            bad = np.any(bad_n[i], axis=0)
        n_t = self.T_f.size
        return _pairs(self._free_nodes[free], *self.bounds[free], y, bad, np.full(n_t, value), self._t_idx, self.T_f)

    def _family(self, free: int, fixed_values: np.ndarray) -> tuple[_Pairs, np.ndarray, np.ndarray]:
        y, bad = self._lines(free, fixed_values)
        n_t = self.T_f.size
        fixed = np.repeat(fixed_values, n_t)
        t_idx = np.tile(np.arange(n_t), fixed_values.size)
        return _pairs(self._free_nodes[free], *self.bounds[free], y, bad, fixed, t_idx, self.T_f[t_idx]), y, bad

    def choose(self, s_e: ArrayLike) -> Choice:
        """Solve (30) for ``s_e`` on the table (well under a millisecond)."""
        cfg = self.cfg
        s = np.broadcast_to(np.asarray(s_e, dtype=float), (2,)).copy()
        pref = [float(np.clip(s[c], *self.bounds[c])) for c in range(2)]
        target_T = target_radius(s, self.T_f, cfg)
        band = cfg.tolerance * (1.0 - 1e-6)
        best: tuple[float, float, float, float] = (np.inf, np.nan, np.nan, np.nan)  # cost, sigma, tau, T
        for c in range(2):
            for p in (self._fam[c][0], self._pref_line(c, pref[1 - c])):
                cost, x, fixed, T = _best(p, target_T, band, pref[c], pref[1 - c], cfg.k_sigma, cfg.k_wt)
                if cost < best[0]:
                    best = (cost, x, fixed, T) if c == 0 else (cost, fixed, x, T)
        if np.isfinite(best[0]):
            return self._finish(s, best[1], best[2], best[3], feasible=True)
        return self._nearest(s, target_T, pref)

    def _nearest(self, s: np.ndarray, target_T: np.ndarray, pref: list[float]) -> Choice:
        """Nothing feasible: the stable node on the lines whose radius is nearest to the target."""
        cfg, n_t = self.cfg, self.T_f.size
        near: tuple[float, float, float, float, float] | None = None  # gap, cost, sigma, tau, T
        for c in range(2):
            _, y, bad = self._fam[c]
            nodes = self._free_nodes[c]
            lo, hi = self.bounds[c]
            fixed_values = self.tau_f if c == 0 else self.sigma_f
            target = np.tile(target_T, fixed_values.size)
            inside = (nodes >= lo) & (nodes <= hi)
            gap = np.where(bad | ~inside[:, None], np.inf, np.abs(y - target))
            j, k = np.unravel_index(int(np.argmin(gap)), gap.shape)
            fx, T = float(fixed_values[k // n_t]), float(self.T_f[k % n_t])
            pt = (float(nodes[j]), fx) if c == 0 else (fx, float(nodes[j]))
            cst = cfg.k_sigma * (abs(pt[0] - pref[0]) + abs(pt[1] - pref[1])) + cfg.k_wt * T
            if near is None or (float(gap[j, k]), cst) < near[:2]:
                near = (float(gap[j, k]), cst, *pt, T)
        if near is None or not np.isfinite(near[0]):
            raise ValueError(f"walker table {self.table.source}: no stable node within the config's bounds")
        return self._finish(s, near[2], near[3], near[4], feasible=False)

    def _finish(self, s_e: np.ndarray, sigma: float, tau: float, T: float, *, feasible: bool) -> Choice:
        rh = self.table.radius(sigma, tau, T)
        re = float(target_radius(s_e, np.asarray(T), self.cfg))
        eps = self.table.eps
        return Choice(
            s_r=np.array([sigma, tau]),
            T=T,
            eps=eps,
            rho_hybrid=rh,
            rho_equivalent=re,
            residual=rh - re,
            cost=choice_cost([sigma, tau], T, eps, s_e, self.cfg),
            feasible=feasible,
        )
