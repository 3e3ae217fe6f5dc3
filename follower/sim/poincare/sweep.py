"""The follower's operating point and the grid of the walker's radius next to the reduced model's."""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.poincare.map import walker_rho
from bipedtele.follower.sim.poincare.state import MapSettings, alignment_quantum, check_alignment

LOG = logging.getLogger(__name__)


def grid(sigmas: Sequence[float], Ts: Sequence[float]) -> list[tuple[float, float]]:
    """Return the ``(sigma_r, T)`` points of a grid, sigma-major."""
    return [(float(s), float(t)) for s in sigmas for t in Ts]


def operating_point(
    control: ControlConfig, sim: SimConfig, control_rate_hz: float = 50.0, physics_hz: float | None = None
) -> dict[str, Any]:
    """Return the follower's parameters at zero delay: (40) then (30), as the robot applies them.

    The robot clamps ``T`` and ``eps`` to what it accepts; ``T`` is then rounded to the
    nearest cycle whose touchdowns fall on control ticks (:func:`alignment_quantum`) at
    ``physics_hz`` [Hz] (default ``sim.physics_hz``).
    """
    from bipedtele.control.damping import schedule_damping
    from bipedtele.control.online import OnlineChooser

    choice = OnlineChooser(control).choose(schedule_damping(0.0, 0.0, control).s_e)
    q = 2.0 * alignment_quantum(sim.physics_hz if physics_hz is None else physics_hz, control_rate_hz)
    T = float(np.clip(choice.T, sim.cycle_min_s, sim.cycle_max_s))
    T = float(
        np.clip(round(T / q) * q, math.ceil(sim.cycle_min_s / q - 1e-9) * q, math.floor(sim.cycle_max_s / q + 1e-9) * q)
    )
    return {
        "sigma_r": [float(v) for v in choice.s_r],
        "T": T,
        "eps": float(np.clip(choice.eps, 0.02, 1.0)),
        "T_chosen": float(choice.T),
        "eps_chosen": float(choice.eps),
    }


# ----------------------------------------------------------------------------- grid and CLI


def _point(args: tuple[list[float], float, float, ControlConfig, SimConfig, MapSettings]) -> dict[str, Any]:
    from bipedtele.control.hybrid import rho_hybrid

    s_r, T, eps, control, sim, settings = args
    r = walker_rho(s_r, T, eps, control=control, sim=sim, settings=settings)
    loop = dataclasses.replace(control, hybrid_model="speed-loop").hybrid()
    row = {
        "sigma_r": [float(v) for v in s_r],
        "T": float(T),
        "eps": float(eps),
        "rho_walker": r.rho_walker,
        "rho_reduced": rho_hybrid(s_r, T, eps, control.dp, control),
        "rho_reduced_speed_loop": rho_hybrid(s_r, T, eps, loop.dp, loop),
        "fixed_point_speed": r.fixed_point_speed,
        "fixed_point_v_hip": r.fixed_point_v_hip,
        "fixed_point_turn": r.fixed_point_turn,
        "residual": r.residual,
        "spread": r.spread,
        "contraction": r.contraction,
        "transient": r.transient,
        "fallen": r.fallen,
        "eigenvalues": [[float(z.real), float(z.imag)] for z in r.eigenvalues[:6]],
        "evaluations": r.evaluations,
        "sim_seconds": r.sim_seconds,
        "forward_std": r.forward_std,
        "turn_std": r.turn_std,
        "limit_cycle": r.limit_cycle,
    }
    if r.newton is not None:
        row["newton"] = r.newton
    return row


def poincare_grid(
    sigmas: Sequence[float],
    Ts: Sequence[float],
    *,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
    settings: MapSettings | None = None,
    jobs: int = 1,
) -> dict[str, Any]:
    """Compute the walker's and the reduced model's radii over ``sigma_r`` x ``T``.

    Both channels' ``sigma_r``; plus the follower's operating point (:func:`operating_point`).

    Returns
    -------
    dict
        ``{"points": [...], "operating_point": {...}, "v_ref", "turn_ref", "foot",
        "control_rate_hz", "lead_s", "warmup_s", "speed_loop": {"dp", "k_v"}}``; each point
        has ``sigma_r``, ``T``, ``rho_walker``, ``rho_reduced``, ``rho_reduced_speed_loop``,
        ``fixed_point_speed`` [cm/s] and diagnostics (``residual``, ``spread`` in
        perturbation sizes, ``fallen``, ``forward_std`` [cm/s], ``turn_std`` [deg/s],
        ``limit_cycle``, the largest ``eigenvalues``). With ``settings.newton_iterations``
        the operating point (only) also gets ``newton`` (:meth:`NewtonResult.as_dict`).
    """
    control = control or ControlConfig()
    sim = sim or SimConfig()
    st = settings or MapSettings()
    op = operating_point(control, sim, st.control_rate_hz, st.physics_hz(sim))
    eps = op["eps"]
    for T in Ts:
        check_alignment(T, st.physics_hz(sim), st.control_rate_hz)
    grid_st = dataclasses.replace(st, newton_iterations=0)
    tasks = [([s, s], T, eps, control, sim, grid_st) for s, T in grid(sigmas, Ts)]
    tasks.append((op["sigma_r"], op["T"], eps, control, sim, st))
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs) as pool:
            rows = list(pool.map(_point, tasks))
    else:
        rows = []
        for t in tasks:
            rows.append(_point(t))
            LOG.info("poincare: sigma_r %s T %.2f: rho_walker %.3f", t[0], t[1], rows[-1]["rho_walker"])
    op_row = rows.pop()
    op_row.update({k: op[k] for k in ("T_chosen", "eps_chosen")})
    return {
        "points": rows,
        "operating_point": op_row,
        "v_ref": st.v_ref,
        "turn_ref": st.turn_ref,
        "foot": st.foot,
        "control_rate_hz": st.control_rate_hz,
        "lead_s": st.lead_s,
        "warmup_s": st.warmup_s,
        "delta_scale": st.delta_scale,
        "speed_loop": {"dp": control.calibrated_dp, "k_v": control.calibrated_k_v},
    }
