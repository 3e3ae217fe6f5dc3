"""The surrogate table of the walker's map over forward x turn damping x cycle (``--table``)."""

from __future__ import annotations

import itertools
import logging
from collections.abc import Sequence
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.control.walker_map import TABLE_FORMAT
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.poincare.map import walker_rho
from bipedtele.follower.sim.poincare.state import MapSettings, check_alignment
from bipedtele.follower.sim.poincare.sweep import operating_point

LOG = logging.getLogger(__name__)


#: The table's fields, each a nested list ``[sigma][tau][T]`` (:func:`walker_table`).
_FIELDS = (
    "rho",
    "limit_cycle",
    "fallen",
    "forward_std",
    "turn_std",
    "speed",
    "turn_rate",
    "residual",
    "spread",
    "contraction",
)


def _table_point(args: tuple[float, float, float, float, ControlConfig, SimConfig, MapSettings]) -> dict[str, Any]:
    sigma, tau, T, eps, control, sim, settings = args
    r = walker_rho([sigma, tau], T, eps, control=control, sim=sim, settings=settings)
    return {
        "rho": r.rho_walker,
        "limit_cycle": r.limit_cycle,
        "fallen": r.fallen,
        "forward_std": r.forward_std,
        "turn_std": r.turn_std,
        "speed": r.fixed_point_speed,
        "turn_rate": r.fixed_point_turn,
        "residual": r.residual,
        "spread": r.spread,
        "contraction": r.contraction,
    }


def walker_table(
    sigmas: Sequence[float],
    taus: Sequence[float],
    Ts: Sequence[float],
    *,
    eps: float | None = None,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
    settings: MapSettings | None = None,
    jobs: int = 1,
) -> dict[str, Any]:
    """Tabulate the walker's map over ``sigma`` (forward) x ``tau`` (turn) x ``T``.

    The surrogate that ``control.hybrid_model = "walker"`` interpolates in (30)
    (:mod:`bipedtele.control.walker_map`, docs/walker_map.md). Every grid point is one
    :func:`walker_rho` (warm-up, the averaged fixed point, the central-difference radius of
    (26); the contraction only when ``settings.contraction``).

    Parameters
    ----------
    sigmas, taus : sequence of float
        Forward and turn real damping (cm/s and deg/s channels, the units of ``D``).
    Ts : sequence of float
        Walking cycles [s], each aligned (:func:`check_alignment`).
    eps : float, optional
        Joint servo time constant [s]; default the follower's operating point's (what (30)
        picks, ``eps_range[0]``).

    Returns
    -------
    dict
        ``format``, the axes ``sigma``, ``tau``, ``T``, ``eps``; per field (``rho``,
        ``limit_cycle``, ``fallen``, ``forward_std`` [cm/s], ``turn_std`` [deg/s],
        ``speed`` [cm/s], ``turn_rate`` [deg/s], ``residual``, ``spread``,
        ``contraction``) a nested list indexed ``[sigma][tau][T]``; ``settings`` (the
        operating conditions) and ``wall_s``.
    """
    import time

    control = control or ControlConfig()
    sim = sim or SimConfig()
    st = settings or MapSettings(contraction=False)
    if eps is None:
        eps = operating_point(control, sim, st.control_rate_hz)["eps"]
    for T in Ts:
        check_alignment(T, sim.physics_hz, st.control_rate_hz)
    axes = ([float(v) for v in sigmas], [float(v) for v in taus], [float(v) for v in Ts])
    for name, ax in zip(("sigma", "tau", "T"), axes, strict=True):
        if any(b <= a for a, b in itertools.pairwise(ax)):
            raise ConfigError(f"--{name} {ax}: allowed: strictly increasing values")
    # T-major last, largest T first in the queue: the slow points start early
    tasks = [(s, t, T, eps, control, sim, st) for s in axes[0] for t in axes[1] for T in axes[2]]
    order = sorted(range(len(tasks)), key=lambda i: -tasks[i][2])
    t0 = time.perf_counter()
    rows = _table_rows(tasks, order, jobs)
    ns, nt, n_t = (len(a) for a in axes)

    def field(key: str) -> list[list[list[Any]]]:
        return [[[rows[(i * nt + j) * n_t + k][key] for k in range(n_t)] for j in range(nt)] for i in range(ns)]

    return {
        "format": TABLE_FORMAT,
        "sigma": axes[0],
        "tau": axes[1],
        "T": axes[2],
        "eps": float(eps),
        **{k: field(k) for k in _FIELDS},
        "settings": _table_settings(st, sim, control),
        "wall_s": time.perf_counter() - t0,
    }


def _table_rows(tasks: list[Any], order: list[int], jobs: int) -> list[dict[str, Any]]:
    """Run the table's points (in ``order``, on ``jobs`` processes); rows in the tasks' order."""
    rows: list[dict[str, Any]] = [{} for _ in tasks]
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs) as pool:
            for k, row in zip(order, pool.map(_table_point, [tasks[i] for i in order]), strict=True):
                rows[k] = row
                LOG.info(
                    "table: sigma %.2f tau %.2f T %.2f: rho %.3f%s",
                    *tasks[k][:3],
                    row["rho"],
                    " limit cycle" if row["limit_cycle"] else "",
                )
    else:
        for k in order:
            rows[k] = _table_point(tasks[k])
            LOG.info("table: sigma %.2f tau %.2f T %.2f: rho %.3f", *tasks[k][:3], rows[k]["rho"])
    return rows


def _table_settings(st: MapSettings, sim: SimConfig, control: ControlConfig) -> dict[str, Any]:
    """Return the operating conditions a table was made under (stored with it)."""
    return {
        "v_ref": st.v_ref,
        "turn_ref": st.turn_ref,
        "foot": st.foot,
        "control_rate_hz": st.control_rate_hz,
        "lead_s": st.lead_s,
        "warmup_s": st.warmup_s,
        "average_cycles": st.average_cycles,
        "delta_scale": st.delta_scale,
        "physics_hz": sim.physics_hz,
        "D": list(control.D),
        "k_s": list(control.k_s),
        "k_z": list(control.k_z),
        "beta_r": list(control.beta_r),
    }
