"""Benchmark: the torque walker's joint law (15), its cost per step and what ``W_hat`` buys.

Three parts, side by side in one run:

1. Tracking with a wrong model: the torque walker squats in double support (0.7 Hz,
   +-0.15 rad at the hips, knees and ankles) with the joint law's model off by 20 %
   (``[torque] model_error``), ``W_hat = 0`` against the disturbance observer at several rates:
   the outputs' RMS after the first second and the ratio.
2. Walking on joint torques (4 cm/s, T = 1 s, 15 s): for model errors 0, 5, 10 and 20 %, with
   ``W_hat = 0`` and with the observer: how far it walked, its speed over the last cycle, the
   steps a motor limit cut, and when it fell (if it did).
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
from test_torque_walker import squat_tracking_rms


def walk(model_error: float, dob_rate_s: float, seconds: float) -> dict[str, float]:
    robot = TorqueNao(torque=TorqueConfig(model_error=model_error, dob_rate_s=dob_rate_s))
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
        robot.send_walk(WalkCommand(0.04, 0.0, 1.0, 0.05))
        t0 = time.perf_counter()
        for _ in range(round(seconds / 0.1)):
            robot.advance(0.1)
            obs = robot.observe()
            if obs.fallen:
                fell = obs.t - 0.5
                break
        wall = time.perf_counter() - t0
        return {
            "dist_m": obs.pose[0] - x0,
            "speed_cm_s": 100.0 * robot.cycle_speed(),
            "saturated": float(robot.saturated_steps),
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
    print("1. squat in double support, model off by 20 %: output RMS after 1 s")
    base = squat_tracking_rms(0.2, 0.0)
    print(f"   W_hat = 0            RMS {base:.5f}")
    for rate in (10.0, 20.0, 40.0, 60.0):
        rms = squat_tracking_rms(0.2, rate)
        print(f"   observer L = {rate:4.0f}/s  RMS {rms:.5f}  ({base / rms:6.1f}x lower)")
    print(f"\n2. walking 4 cm/s, T = 1 s, {args.walk_seconds:.0f} s on joint torques")
    print(f"   {'model error':>11s} {'W_hat':>10s} {'walked m':>8s} {'cm/s':>5s} {'sat steps':>9s} {'fell at s':>9s}")
    rows = []
    for err in (0.0, 0.05, 0.1, 0.2):
        for rate in (0.0, TorqueConfig().dob_rate_s):
            r = walk(err, rate, args.walk_seconds)
            rows.append(r)
            name = "0" if rate == 0 else f"L = {rate:.0f}/s"
            fell = "-" if math.isnan(r["fell_s"]) else f"{r['fell_s']:.1f}"
            print(
                f"   {100 * err:10.0f}% {name:>10s} {r['dist_m']:8.2f} {r['speed_cm_s']:5.1f} "
                f"{r['saturated']:9.0f} {fell:>9s}"
            )
    r = rows[0]
    print("\n3. cost (exact model, W_hat = 0 run)")
    print(f"   joint law per step p50 {r['law_p50_us']:.0f} us, p99 {r['law_p99_us']:.0f} us")
    print(f"   whole physics step {r['step_us']:.0f} us at 1 kHz: real-time factor {r['rtf']:.2f}x")


if __name__ == "__main__":
    main()
