"""Benchmark: real-time factor of the simulated NAO (physics + control), with and without cameras.

Runs the same scripted walk (5 cm/s straight, then 5 cm/s turning at 4 deg/s) three ways,
side by side in one process:

1. physics + control only (50 Hz control: send_walk, advance, observe with sonar);
2. the same plus one QVGA camera rendered at 10 fps (TinyRenderer, CPU);
3. the same plus both cameras (head and scene) at 10 fps each.

Then the torque walker (``--robot sim-torque``: the joint law (15) on a 20 % wrong model every
500 Hz physics step) the same way, without and with the head camera.

Prints the real-time factor (simulated seconds per wall second; goals >= 4x physics+control,
>= 1.5x with the camera at 10 fps, >= 1x for the torque walker), the camera's cost per frame (p50/p99), the RMS joint
tracking error and the forward (eq. 8) and turn tracking errors after the first 5 s.

Then the walker's speed range: per cycle time T (0.6, 0.8, 1.0, 1.2 s asked; the robot
clamps T to its limits and says so), the steady speed reached, measured per step between
footfalls (odometry, as the report does) after the first 4 s of a 12 s walk, for the
fastest command (10 cm/s straight; 25 deg/s turning in place; 25 deg/s while walking at
5 cm/s). "sent" is what ``send_walk`` returned (its clamp), "reached" the mean per-step
speed, "+-" the standard deviation over the steps.

    .venv/bin/python bench/follower.py [--seconds 30] [--range-only | --no-range]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import time

import numpy as np
from bipedtele.follower.robot import WalkCommand
from bipedtele.follower.sim.robot import SimNao
from bipedtele.follower.sim.torque_robot import TorqueNao
from bipedtele.follower.sim.world import TASK_COURSE, WorldConfig

DT = 0.02
V = 0.05
TURN = math.radians(4.0)


def run(seconds: float, cameras: tuple[str, ...], fps: float, torque: bool = False) -> dict[str, float]:
    # the task course, moved 1.5 m further so the walk (about 1.3 m) does not reach it
    course = [dataclasses.replace(o, position=[o.position[0] + 1.5, *o.position[1:]]) for o in TASK_COURSE]
    world = WorldConfig(obstacles=course)
    frame_s: list[float] = []
    v_err, w_err, j_err = [], [], []
    every = round(1.0 / (fps * DT)) if cameras else 0
    with TorqueNao(world=world) if torque else SimNao(world=world) as robot:
        t0 = time.perf_counter()
        for i in range(round(seconds / DT)):
            turn = TURN if i * DT > seconds / 2 else 0.0
            robot.send_walk(WalkCommand(V, turn, 1.0, 0.1))
            robot.advance(DT)
            obs = robot.observe()
            if every and i % every == 0:
                for cam in cameras:
                    f0 = time.perf_counter()
                    robot.capture(cam)
                    frame_s.append(time.perf_counter() - f0)
            if obs.t > 5.0:
                v_err.append(abs(obs.v_hip_m_s - V))
                j_err.append(obs.joint_error_rad)
                if obs.t > seconds / 2 + 5.0:
                    w_err.append(obs.turn_rate_rad_s - TURN)
            if obs.fallen:
                raise SystemExit(f"the robot fell at t = {obs.t:.1f} s")
        wall = time.perf_counter() - t0
    # turn error per walking cycle (the yaw moves only in single support)
    w = np.array(w_err[: len(w_err) // 50 * 50]).reshape(-1, 50).mean(axis=1) if len(w_err) >= 50 else np.zeros(1)
    return {
        "rtf": seconds / wall,
        "frame_p50_ms": float(np.percentile(frame_s, 50) * 1e3) if frame_s else 0.0,
        "frame_p99_ms": float(np.percentile(frame_s, 99) * 1e3) if frame_s else 0.0,
        "joint_rms_deg": math.degrees(float(np.sqrt(np.mean(np.square(j_err))))),
        "v_err_cm_s": 100.0 * float(np.mean(v_err)),
        "turn_err_deg_s": math.degrees(float(np.mean(np.abs(w)))),
    }


RANGE_T = (0.6, 0.8, 1.0, 1.2)
RANGE_V = 0.10  # fastest forward command [m/s]
RANGE_W = math.radians(25.0)  # fastest turn command [rad/s]
RANGE_S = 12.0  # simulated seconds per walk
STEADY_S = 4.0  # steps before this time are left out


def walk_range(v: float, w: float, cycle_s: float) -> dict[str, float]:
    """Walk ``RANGE_S`` s at (v [m/s], w [rad/s], T [s]); per-step speeds from the footfalls."""
    with SimNao() as robot:
        sent = robot.send_walk(WalkCommand(v, w, cycle_s, 0.1))
        feet = []
        fell = False
        for _ in range(round(RANGE_S / DT)):
            robot.send_walk(WalkCommand(v, w, cycle_s, 0.1))
            robot.advance(DT)
            obs = robot.observe()
            fell = fell or obs.fallen
            ff = robot.footfall()
            if ff is not None and (not feet or feet[-1].n != ff.n):
                feet.append(ff)
    speeds, turns = [], []
    for a, b in itertools.pairwise(feet):
        dt = b.t - a.t
        if a.t < STEADY_S or not 0 < dt <= 1.5 * b.step_s:
            continue
        dyaw = (b.pose[2] - a.pose[2] + math.pi) % (2 * math.pi) - math.pi
        head = a.pose[2] + dyaw / 2
        speeds.append(((b.pose[0] - a.pose[0]) * math.cos(head) + (b.pose[1] - a.pose[1]) * math.sin(head)) / dt)
        turns.append(dyaw / dt)
    return {
        "T": sent.cycle_s,
        "v_sent": sent.forward_m_s,
        "w_sent": sent.turn_rad_s,
        "fell": float(fell),
        "v": float(np.mean(speeds)) if speeds else math.nan,
        "v_sd": float(np.std(speeds)) if speeds else math.nan,
        "w": float(np.mean(turns)) if turns else math.nan,
        "w_sd": float(np.std(turns)) if turns else math.nan,
    }


def print_range() -> None:
    print(
        f"\nwalker speed range: per-step odometry after {STEADY_S:.0f} s of a {RANGE_S:.0f} s walk "
        f"(commands {100 * RANGE_V:.0f} cm/s, {math.degrees(RANGE_W):.0f} deg/s)"
    )
    print(
        f"{'T asked':>7s} {'T':>5s} | {'straight: sent':>14s} {'reached cm/s':>14s} | "
        f"{'in place: sent':>14s} {'reached deg/s':>14s} | {'walk+turn: sent':>15s} {'reached':>17s}"
    )
    for cycle in RANGE_T:
        f = walk_range(RANGE_V, 0.0, cycle)
        t = walk_range(0.0, RANGE_W, cycle)
        b = walk_range(RANGE_V / 2, RANGE_W, cycle)
        fell = " FELL" if f["fell"] or t["fell"] or b["fell"] else ""
        print(
            f"{cycle:7.1f} {f['T']:5.2f} | {100 * f['v_sent']:14.1f} {100 * f['v']:8.2f} +-{100 * f['v_sd']:4.2f} | "
            f"{math.degrees(t['w_sent']):14.1f} {math.degrees(t['w']):8.2f} +-{math.degrees(t['w_sd']):4.2f} | "
            f"{100 * b['v_sent']:5.1f} cm/s {math.degrees(b['w_sent']):4.1f} d/s "
            f"{100 * b['v']:5.2f} cm/s {math.degrees(b['w']):5.2f} d/s{fell}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per run")
    group = ap.add_mutually_exclusive_group()
    group.add_argument("--range-only", action="store_true", help="only the walker's speed range")
    group.add_argument("--no-range", action="store_true", help="skip the walker's speed range")
    args = ap.parse_args()
    if not args.range_only:
        print_rtf(args.seconds)
    if not args.no_range:
        print_range()


def print_rtf(seconds: float) -> None:
    rows = [
        ("physics + control", (), 0.0, 4.0, False),
        ("+ head camera 10 fps", ("head",), 10.0, 1.5, False),
        ("+ head & scene 10 fps", ("head", "scene"), 10.0, 1.5, False),
        ("torque walker", (), 0.0, 1.0, True),
        ("torque + head camera", ("head",), 10.0, 1.0, True),
    ]
    print(
        f"sim NAO, {seconds:.0f} s simulated per run, 50 Hz control, QVGA TinyRenderer; the torque walker "
        "(--robot sim-torque): the joint law (15) every 500 Hz physics step, model 20 % wrong"
    )
    print(
        f"{'run':24s} {'RTF':>6s} {'goal':>5s} {'frame p50/p99 ms':>17s} {'joint RMS deg':>13s} "
        f"{'|v err| cm/s':>12s} {'|turn err| deg/s':>16s}"
    )
    for name, cams, fps, goal, torque in rows:
        r = run(seconds, cams, fps, torque)
        frame = f"{r['frame_p50_ms']:.1f}/{r['frame_p99_ms']:.1f}" if cams else "-"
        print(
            f"{name:24s} {r['rtf']:5.1f}x {goal:4.1f}x {frame:>17s} {r['joint_rms_deg']:13.2f} "
            f"{r['v_err_cm_s']:12.2f} {r['turn_err_deg_s']:16.2f}"
        )


if __name__ == "__main__":
    main()
