"""Benchmark: the torque walker's joint law (15), its cost per step and what ``W_hat`` buys.

Three parts, side by side in one run:

1. Tracking with a wrong model: the torque walker walks (4 cm/s, T = 1 s, 4 s) with the joint
   law's model off by 20 % (``[torque] model_error``): ``W_hat = 0``, the disturbance observer
   alone, and the observer with the torso-mass adaptation: the RMS of the 12 outputs over the
   single supports after the first second, and the ratios.
2. Walking on joint torques (8 cm/s and 20 deg/s to the right, ramped over 4 s, 15 s) at
   T = 0.8, 1.0, 1.2 s, for model errors 0, 10 and 20 %, with ``W_hat = 0``, the observer
   alone and the observer with the adaptation: how far it walked, its speed over the last
   cycle, the steps a motor limit cut, the torso-mass estimate, and when it fell (if it did).
3. The cost: wall time per physics step of the joint law (model evaluation, allocation,
   observer) and of the whole step (with pybullet), p50/p99, and the real-time factor.

    .venv/bin/python bench/flcontrol.py [--walk-seconds 15]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from bipedtele.follower.robot import WalkCommand
from bipedtele.follower.sim.torque_config import TorqueConfig
from bipedtele.follower.sim.torque_robot import TorqueNao

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "unit"))
from test_torque_walker import walk_tracking_rms


def walk(torque: TorqueConfig, cycle_s: float, seconds: float) -> dict[str, float]:
    robot = TorqueNao(torque=torque)
    fell = math.nan
    law_s: list[float] = []
    step = robot.law.step

    def timed(*args, **kwargs):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        out = step(*args, **kwargs)
        law_s.append(time.perf_counter() - t0)
        return out

    robot.law.step = timed  # type: ignore[method-assign]
    with robot:
        robot.advance(0.5)
        x0 = robot.observe().pose[0]
        t0 = time.perf_counter()
        for k in range(round(seconds / 0.1)):
            a = min(1.0, (k + 1) / 40)
            robot.send_walk(WalkCommand(0.08 * a, -math.radians(20.0) * a, cycle_s, 0.05))
            robot.advance(0.1)
            obs = robot.observe()
            if obs.fallen:
                fell = obs.t - 0.5
                break
        wall = time.perf_counter() - t0
        return {
            "dist_m": math.hypot(obs.pose[0] - x0, obs.pose[1]),
            "speed_cm_s": 100.0 * robot.cycle_speed(),
            "saturated": float(robot.saturated_steps),
            "scale": robot._fl.torso_scale,
            "fell_s": fell,
            "rtf": (obs.t - 0.5) / wall,
            "law_p50_us": float(np.percentile(law_s, 50) * 1e6),
            "law_p99_us": float(np.percentile(law_s, 99) * 1e6),
            "step_us": wall / max(1, round((obs.t - 0.5) * robot.torque.physics_hz)) * 1e6,
        }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walk-seconds", type=float, default=15.0, help="simulated seconds per walk")
    args = ap.parse_args()
    cfg = TorqueConfig()
    print("1. walking 4 cm/s, T = 1 s, model off by 20 %: output RMS in single support after 1 s")
    base = walk_tracking_rms(0.2, 0.0, 0.0)
    print(f"   W_hat = 0                          RMS {base:.4f}")
    dob = walk_tracking_rms(0.2, cfg.dob_rate_s, 0.0)
    print(f"   observer L = {cfg.dob_rate_s:.0f}/s                  RMS {dob:.4f}  ({base / dob:5.1f}x lower)")
    both = walk_tracking_rms(0.2, cfg.dob_rate_s, cfg.mass_rate_s)
    print(f"   observer + torso mass (gamma {cfg.mass_rate_s:.0f}/s)  RMS {both:.4f}  ({base / both:5.1f}x lower)")
    print(f"\n2. walking 8 cm/s and 20 deg/s (right), ramped over 4 s, {args.walk_seconds:.0f} s on joint torques")
    print(
        f"   {'T s':>4s} {'model error':>11s} {'estimator':>16s} {'walked m':>8s} {'cm/s':>5s} "
        f"{'sat steps':>9s} {'torso':>6s} {'fell at s':>9s}"
    )
    variants = (
        ("W_hat = 0", 0.0, 0.0),
        ("observer", cfg.dob_rate_s, 0.0),
        ("observer + mass", cfg.dob_rate_s, cfg.mass_rate_s),
    )
    first = None
    for cycle in (0.8, 1.0, 1.2):
        for err in (0.0, 0.1, 0.2):
            for name, rate, gamma in variants:
                r = walk(TorqueConfig(model_error=err, dob_rate_s=rate, mass_rate_s=gamma), cycle, args.walk_seconds)
                first = first or r
                fell = "-" if math.isnan(r["fell_s"]) else f"{r['fell_s']:.1f}"
                print(
                    f"   {cycle:4.1f} {100 * err:10.0f}% {name:>16s} {r['dist_m']:8.2f} {r['speed_cm_s']:5.1f} "
                    f"{r['saturated']:9.0f} {r['scale']:6.3f} {fell:>9s}"
                )
    r = first
    print(f"\n3. cost (T = 0.8 s, exact model, W_hat = 0 run; {cfg.physics_hz:.0f} Hz physics)")
    print(f"   joint law per step p50 {r['law_p50_us']:.0f} us, p99 {r['law_p99_us']:.0f} us")
    print(f"   whole physics step {r['step_us']:.0f} us: real-time factor {r['rtf']:.2f}x")


if __name__ == "__main__":
    main()
