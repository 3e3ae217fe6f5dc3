"""Calibration of the reduced model (20)-(23) from the simulated walker (``bipedtele calibrate``).

The reduced model has two numbers the walker can give: the reset factor ``dp`` (the hip
speed kept across an impact) and the forward gain ``k_v`` (with the reference mass ``M``,
the speed response between impacts, ``M v' = k_v (v_ref - v)`` at ``sigma_r = 0``).
Both are identified on the walker the follower runs (physics, gait and the follower's
servo, :class:`~bipedtele.follower.sim.poincare.WalkerServo`):

``dp``
    At steady walking with the paper's reference speeds, for every touchdown: the torso's
    forward speed at the end of the control period that holds the gait's touchdown over
    that at the end of the period before it; the median over the touchdowns
    (``dp_torso``: the speed the impact keeps, what the reset (22) models). Reported next
    to it: the same ratio of the hip speed of eq. (8) as the follower measures it (mean
    over a control period, ``dp``) and of the means over the half steps (``dp_step``).
    The hip speed is measured over the stance foot, so in the period of a touchdown it
    also holds the landing foot's own motion: on the position walker, whose joints track
    their references exactly, the two ratios agree (1.04 and 1.05); on the torque walker
    the landing foot still moves when it lands and the hip's ratio is 0.06 (quartiles
    -0.13 to 0.18) while the torso keeps 0.96 of its speed (docs/method.md).
``k_v``
    A step of the forward reference (2 -> 5 cm/s, no turn, ``sigma_r = 0``); the hip
    speed averaged over a walking cycle is fitted by the first-order response
    ``v(t) = v1 + (v0 - v1) exp(-(t - t_d)/tau)``; ``k_v = M / tau``. The fit's root mean
    square error, the dead time ``t_d`` and the steady gain are reported.

The reduced model's reset (22) only loses speed: its ``dp`` lies in (0, 1] (and so does
``control.calibrated_dp``). A measured median above 1 (the hip of eq. (8) a few per cent
faster in the first control period after a touchdown than in the last before, as with the
gait that walks at the commanded ground speed) means the impact costs the walker no speed;
the model then gets ``dp = 1`` (:func:`model_dp`), and the measured median is reported
next to it.

Then the walker's spectral radius (:mod:`.poincare`) at a few ``(sigma_r, T)`` is set next
to the reduced model's with the paper's values and with the identified ones. The config
switch ``control.hybrid_model = "speed-loop"`` (with ``control.calibrated_dp`` and
``control.calibrated_k_v``) makes the online choice (30) use that model.

What the identification measures is the follower's own speed loop, the reference model (28)
with the observer (12) at the control rate, not the walker: the review of issue 21 found
that a robot applying every commanded speed exactly gives the same ``k_v`` (1.2) and dead
time (0.20 s). Hence the
model's name, ``"speed-loop"`` (it was ``"calibrated"``). The walker's own map is
``hybrid_model = "walker"`` (``bipedtele poincare --table``, docs/walker_map.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pybullet as pb
from bipedtele.config.profile import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.control.hybrid import rho_hybrid
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.poincare import MapSettings, WalkerMap, add_walker_arg, operating_point, walker_torque
from scipy.optimize import curve_fit

__all__ = ["add_calibrate_parser", "calibrate", "identify_dp", "identify_speed_response", "model_dp"]

LOG = logging.getLogger(__name__)


def identify_dp(
    T: float,
    *,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
    settings: MapSettings | None = None,
    cycles: int = 20,
) -> dict[str, Any]:
    """Reset factor of the walker at cycle ``T`` [s] (module docstring).

    Returns
    -------
    dict
        ``dp_torso`` (median of the torso's ratios: the model's ``dp``), ``dp`` (median of
        the hip's), ``dp_iqr`` (its [25 %, 75 %] quantiles), ``dp_step`` (half-step means),
        ``touchdowns`` (count), ``T``.
    """
    control = control or ControlConfig()
    st = settings or MapSettings()
    s_r = [0.0, 0.0]
    ratios: list[float] = []
    step_ratios: list[float] = []
    with WalkerMap(s_r, T, st_eps(control), control=control, sim=sim, settings=st) as m:
        sv, robot = m.servo, m.robot
        sv.tick()
        sv.run(st.warmup_s)
        half = round(T / 2.0 / sv.dt)
        speeds: list[float] = []
        torso: list[float] = []
        stance: list[str] = []
        for _ in range(round(cycles * T / sv.dt)):
            sv.step()
            speeds.append(float(sv.eta_meas[0]))
            torso.append(_torso_forward(robot))
            stance.append(robot.gait.stance)
    v, w = np.asarray(speeds), np.asarray(torso)
    torso_ratios: list[float] = []
    for k in range(1, len(stance)):
        if stance[k] != stance[k - 1] and k + 1 < len(v) and k >= half and k + half <= len(v):
            # the control period ending at tick k holds the touchdown; k - 1 is the last before
            before = v[k - 1]
            if abs(before) > 1e-6:
                ratios.append(float(v[k] / before))
                step_ratios.append(float(v[k : k + half].mean() / v[k - half : k].mean()))
            if abs(w[k - 1]) > 1e-6:
                torso_ratios.append(float(w[k] / w[k - 1]))
    if not ratios:
        raise RuntimeError("no touchdown observed: the walker did not walk")
    q25, q75 = np.percentile(ratios, [25, 75])
    return {
        "dp": float(np.median(ratios)),
        "dp_iqr": [float(q25), float(q75)],
        "dp_step": float(np.median(step_ratios)),
        "dp_torso": float(np.median(torso_ratios)) if torso_ratios else math.nan,
        "touchdowns": len(ratios),
        "T": T,
    }


def _torso_forward(robot: Any) -> float:
    """Return the torso's forward speed along its heading now [cm/s] (pybullet's base velocity)."""
    lin, _ = pb.getBaseVelocity(robot._robot, physicsClientId=robot._client)
    yaw = robot._base()[2]
    return 100.0 * (lin[0] * math.cos(yaw) + lin[1] * math.sin(yaw))


def model_dp(measured: float) -> float:
    """Return the reduced model's reset factor for a measured median ``dp``: clipped to (0, 1].

    Raises :class:`ValueError` for a measured ratio <= 0 (the walker stopped or reversed).
    """
    if not measured > 0.0:
        raise ValueError(f"measured dp {measured!r}: the walker did not walk forward across its impacts")
    return min(float(measured), 1.0)


def st_eps(control: ControlConfig) -> float:
    """Return the joint servo eps the online choice (30) picks with the default weights: the lower bound."""
    return float(control.eps_range[0])


def _first_order(t: np.ndarray, tau: float, t_d: float, v0: float, v1: float) -> np.ndarray:
    s = np.clip(t - t_d, 0.0, None)
    return v1 + (v0 - v1) * np.exp(-s / tau)


def identify_speed_response(
    T: float,
    *,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
    settings: MapSettings | None = None,
    v0: float = 2.0,
    v1: float = 5.0,
    duration_s: float = 30.0,
) -> dict[str, Any]:
    """Closed-loop forward speed step response of the walker and the fitted ``k_v``.

    Returns
    -------
    dict
        ``tau_s``, ``dead_time_s``, ``k_v`` (= ``M / tau``), ``gain`` (final cycle-mean
        v_hip over ``v1``), ``ground_gain`` (final cycle-mean ground speed over ``v1``),
        ``rms`` [cm/s] of the fit, ``T``, ``v0``, ``v1``.
    """
    control = control or ControlConfig()
    st = settings or MapSettings()
    with WalkerMap(
        [0.0, 0.0],
        T,
        st_eps(control),
        control=control,
        sim=sim,
        settings=MapSettings(v_ref=v0, turn_ref=0.0, control_rate_hz=st.control_rate_hz, torque=st.torque),
    ) as m:
        sv, robot = m.servo, m.robot
        sv.tick()
        sv.run(st.warmup_s)
        sv.ref = np.array([v1, 0.0])
        n = round(duration_s / sv.dt)
        v = np.empty(n)
        xy = np.empty((n, 3))
        for k in range(n):
            sv.step()
            v[k] = sv.eta_meas[0]
            xy[k] = robot._base()[:3]
    w = max(1, round(T / sv.dt))
    avg = np.convolve(v, np.ones(w) / w, mode="valid")
    t = (np.arange(avg.size) + w) * sv.dt  # time at the end of each averaging window
    t = t - 0.5 * w * sv.dt  # ... centred
    (tau, t_d, a0, a1), _ = curve_fit(
        _first_order, t, avg, p0=[4.0, 0.2, v0, v1], bounds=([0.05, 0.0, -20.0, -20.0], [60.0, 5.0, 20.0, 20.0])
    )
    rms = float(np.sqrt(np.mean((_first_order(t, tau, t_d, a0, a1) - avg) ** 2)))
    d = xy[-1, :2] - xy[-1 - w, :2]
    heading = xy[-1, 2]
    ground = (d[0] * math.cos(heading) + d[1] * math.sin(heading)) / (w * sv.dt) * 100.0
    m_fwd = float(control.D[0])
    return {
        "tau_s": float(tau),
        "dead_time_s": float(t_d),
        "k_v": m_fwd / float(tau),
        "gain": float(avg[-1] / v1),
        "ground_gain": float(ground / v1),
        "rms": rms,
        "T": T,
        "v0": v0,
        "v1": v1,
        "M": m_fwd,
    }


def calibrate(
    *,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
    settings: MapSettings | None = None,
    T: float = 0.8,
    points: Sequence[tuple[Sequence[float], float]] | None = None,
) -> dict[str, Any]:
    """Identify ``dp`` and ``k_v`` and compare the radii of the walker and both reduced models.

    Parameters
    ----------
    T : float
        Walking cycle for the identification [s] (the shortest cycle the simulated NAO
        accepts, 0.8 s, is what (30) asks for at every delay with the default weights).
    points : sequence of (sigma_r, T), optional
        Where to compare the radii; default: the follower's operating point at zero delay
        (:func:`~bipedtele.follower.sim.poincare.operating_point`) and ``sigma_r = 0`` at
        T = 0.8 and 1.6 s.
    """
    control = control or ControlConfig()
    sim = sim or SimConfig()
    st = settings or MapSettings()
    reset = identify_dp(T, control=control, sim=sim, settings=st)
    resp = identify_speed_response(T, control=control, sim=sim, settings=st)
    dp = model_dp(reset["dp_torso"])
    loop = dataclasses.replace(
        control, hybrid_model="speed-loop", calibrated_dp=dp, calibrated_k_v=resp["k_v"]
    ).hybrid()
    if points is None:
        op = operating_point(control, sim, st.control_rate_hz, st.physics_hz(sim))
        points = [(op["sigma_r"], op["T"]), ([0.0, 0.0], 0.8), ([0.0, 0.0], 1.6)]
    rows: list[dict[str, Any]] = []
    eps = st_eps(control)
    for s_r, t in points:
        res = WalkerMap(s_r, t, eps, control=control, sim=sim, settings=st)
        with res as wm:
            r = wm.analyse()
        rows.append(
            {
                "sigma_r": [float(v) for v in s_r],
                "T": float(t),
                "eps": eps,
                "rho_walker": r.rho_walker,
                "contraction": r.contraction,
                "rho_reduced": rho_hybrid(s_r, t, eps, control.dp, control),
                "rho_reduced_speed_loop": rho_hybrid(s_r, t, eps, loop.dp, loop),
                "fixed_point_speed": r.fixed_point_speed,
            }
        )
    err_paper = [abs(r["rho_reduced"] - r["rho_walker"]) for r in rows]
    err_loop = [abs(r["rho_reduced_speed_loop"] - r["rho_walker"]) for r in rows]
    return {
        "dp": reset,
        "speed_response": resp,
        "speed_loop": {"dp": dp, "k_v": resp["k_v"]},
        "set": [
            'control.hybrid_model="speed-loop"',
            f"control.calibrated_dp={dp:.4f}",
            f"control.calibrated_k_v={resp['k_v']:.4f}",
        ],
        "points": rows,
        "max_abs_error": {"paper": max(err_paper), "speed_loop": max(err_loop)},
    }


def _run(args: argparse.Namespace) -> int:
    from bipedtele.cli import config_from_args

    cfg = config_from_args(args)
    control = cfg.get(ControlConfig)
    sim = cfg.get(SimConfig)
    settings = MapSettings(torque=walker_torque(args.robot, cfg))
    out = calibrate(control=control, sim=sim, settings=settings, T=args.T)
    text = json.dumps(out, indent=1)
    if args.json:
        try:
            Path(args.json).write_text(text + "\n", encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"--json {args.json}: cannot write ({exc.strerror})") from None
    r, s = out["dp"], out["speed_response"]
    sys.stdout.write(
        f"dp = {r['dp_torso']:.3f} (torso's speed across a touchdown, {r['touchdowns']} touchdowns; hip of eq. (8) "
        f"{r['dp']:.3f}, IQR {r['dp_iqr'][0]:.3f}-{r['dp_iqr'][1]:.3f}; half-step ratio {r['dp_step']:.3f}); "
        f"the model's dp {out['speed_loop']['dp']:.3f} (reset (22) in (0, 1])\n"
        f"speed response: tau = {s['tau_s']:.2f} s, dead time {s['dead_time_s']:.2f} s, k_v = M/tau = {s['k_v']:.3f}, "
        f"v_hip gain {s['gain']:.3f}, ground-speed gain {s['ground_gain']:.3f}, fit rms {s['rms']:.3f} cm/s\n"
    )
    for p in out["points"]:
        sys.stdout.write(
            f"  sigma_r={p['sigma_r']} T={p['T']:g}: rho_walker {p['rho_walker']:.3f} (contraction "
            f"{p['contraction']:.3f})  reduced (paper) "
            f"{p['rho_reduced']:.3f}  reduced (speed loop) {p['rho_reduced_speed_loop']:.3f}\n"
        )
    sys.stdout.write("use it: " + " ".join(f"--set {x}" for x in out["set"]) + "\n")
    return 0


def add_calibrate_parser(sub: Any) -> None:
    """``bipedtele calibrate [--json F] [--T 0.8]``: the reduced model's dp and k_v from the sim walker."""
    from bipedtele.cli import add_config_args

    p = sub.add_parser("calibrate", help="identify the reduced model's dp and k_v on the simulated walker")
    p.add_argument("--json", metavar="FILE", help="write the identification and the radius comparison as JSON")
    p.add_argument("--T", type=float, default=0.8, help="walking cycle for the identification [s] (default 0.8)")
    add_walker_arg(p)
    add_config_args(p)
    p.set_defaults(func=_run)
