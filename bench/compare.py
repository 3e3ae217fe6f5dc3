"""Benchmark and side studies of the scheme comparison (``bipedtele compare``).

Prints: the wall time of the default comparison's two parts, the reduced model (the
factorial grid x every regime x 100 paired runs x 60 s, plus the released-handle runs) and
the walker cells (the named schemes, 10 paired runs x 12 s per cell, 2 processes;
``--walker-runs 0`` skips them), and their sum against the 20-minute goal. Side studies:

* ``--wave-window``: the received-wave gain ``sqrt(1 - dh/dt)`` measured over windows of
  0.1, 0.25, 0.5 and 1 s, its mean over every regime's delays (a stationary delay has no
  mean rate: a mean below 1 is bias from the jitter and the clip at 1), and its mean during
  a sustained ramp of 0.2 s/s (the true gain ``sqrt(0.8)``) with the time it takes to get
  there (docs/schemes.md, "The wave gain's window");
* ``--merge``: whether two regimes duplicate each other: the paired difference of the same
  cell on two regimes that share their operators (the lossless shipped trace against the
  same trace with 5 % loss), judged with TOST within the comparison's margins.

Usage: ``.venv/bin/python bench/compare.py [--runs 100] [--walker-runs 10] [--wave-window] [--merge]``
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import StudyParams, channel
from bipedtele.control.schemes.factorial import grid
from bipedtele.control.schemes.ports import wave_gain
from bipedtele.studies.compare import run_compare
from bipedtele.studies.compare_kernel import regime_inputs, simulate
from bipedtele.studies.inference import judge_family
from bipedtele.studies.regimes import EQUIVALENCE_MARGINS, REGIMES, CompareParams

LOG = logging.getLogger("bench.compare")

WINDOWS_S = (0.1, 0.25, 0.5, 1.0)


def wave_windows(seed: int = 1, runs: int = 20) -> dict[str, Any]:
    """Mean received-wave gain per regime and window, and on a sustained ramp (module docstring)."""
    cfg, p = ControlConfig(), StudyParams()
    out: dict[str, Any] = {}
    for regime in REGIMES:
        inp = regime_inputs(regime, runs, seed, cfg, p)
        h1 = np.broadcast_to(inp.h1, (runs, np.shape(inp.h1)[-1]))
        lost = np.broadcast_to(inp.lost1, h1.shape)
        gains = {f"{w:g}": [] for w in WINDOWS_S}  # type: dict[str, list[float]]
        for i in range(runs):
            ch = channel(np.asarray(h1[i]), p.dt, p.window_s, np.asarray(lost[i]))
            for w in WINDOWS_S:
                gains[f"{w:g}"].append(float(wave_gain(ch.idx, round(w / p.dt))[round(5.0 / p.dt) :].mean()))
        out[regime.name] = {w: float(np.mean(v)) for w, v in gains.items()}
    k = np.arange(round(60.0 / p.dt))
    ramp = 0.3 + 0.2 * np.clip(k * p.dt - 10.0, 0.0, 10.0)  # 0.2 s/s from 10 s to 20 s
    ch = channel(ramp, p.dt, p.window_s)
    on = (k * p.dt >= 12.0) & (k * p.dt < 19.0)
    out["ramp 0.2 s/s"] = {}
    for w in WINDOWS_S:
        g = wave_gain(ch.idx, round(w / p.dt))
        start = int(np.flatnonzero(ch.idx >= round(10.0 / p.dt))[0])  # the ramp's first message arrives
        reached = int(np.flatnonzero(g[start:] <= 0.95)[0]) * p.dt
        out["ramp 0.2 s/s"][f"{w:g}"] = {"mean_gain": float(g[on].mean()), "time_to_0.95_s": reached}
    return out


def merge_check(runs: int, seed: int) -> dict[str, Any]:
    """The lossless shipped trace against the same trace with 5 % loss, paired, every cell (TOST)."""
    cfg, cp = ControlConfig(), CompareParams()
    trace = next(r for r in REGIMES if r.name == "trace")
    lossless = dataclasses.replace(trace, name="trace-lossless", loss=0.0)
    chooser = OnlineChooser(cfg)
    a_in, b_in = regime_inputs(trace, runs, seed, cfg, cp.study), regime_inputs(lossless, runs, seed, cfg, cp.study)
    if not (np.array_equal(a_in.h1, b_in.h1) and np.array_equal(a_in.intent, b_in.intent)):
        raise RuntimeError("the two regimes do not share their delays and operators: not paired")
    worst = (float(np.max(a_in.h1)), float(np.max(a_in.h2)))
    out: dict[str, Any] = {}
    for name, cls in grid().items():
        a = simulate(cls(cfg, worst), a_in, cfg, cp, chooser)
        b = simulate(cls(cfg, worst), b_in, cfg, cp, chooser)
        out[name] = {}
        for metric, margin in EQUIVALENCE_MARGINS.items():
            v = judge_family({metric: (a[metric], b[metric])}, margin)[metric]
            out[name][metric] = {"mean": v.diff.mean, "ci95": list(v.diff.ci95), "tost_p": v.tost_p}
    worst_abs = max(abs(v["mean"]) for c in out.values() for v in c.values())
    worst_tost = max(v["tost_p"] for c in out.values() for v in c.values())
    print(
        f"trace with 5 % loss - lossless, every cell and metric: |mean| <= {worst_abs:.4f}, TOST p <= {worst_tost:.2g}"
    )
    return {"cells": out, "max_abs_mean": worst_abs, "max_tost_p": worst_tost}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", metavar="FILE", help="write what was measured")
    ap.add_argument("--walker-runs", type=int, default=10, help="walker runs per cell (0: none)")
    ap.add_argument("--no-default", action="store_true", help="skip the default set's timing")
    ap.add_argument("--wave-window", action="store_true", help="measure the wave gain's bias per window")
    ap.add_argument("--merge", action="store_true", help="test whether loss changes the trace regime")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO)
    result: dict[str, Any] = {}
    if not args.no_default:
        t0 = time.perf_counter()
        result["default"] = run_compare(args.runs, args.seed)
        wall = time.perf_counter() - t0
        print(
            f"reduced: {len(grid())} cells x {len(REGIMES)} regimes + released, {args.runs} runs x 60 s: {wall:.0f} s"
        )
        if args.walker_runs > 0:
            from bipedtele.config.profile import load_config
            from bipedtele.studies.walker_compare import run_walker_compare

            t1 = time.perf_counter()
            result["walker"] = run_walker_compare(load_config("default"), runs=args.walker_runs, seed=args.seed)
            walker_s = time.perf_counter() - t1
            print(f"walker: {walker_s:.0f} s; default set: {wall + walker_s:.0f} s (goal: under 1200 s)")
    if args.wave_window:
        result["wave_window"] = ww = wave_windows(args.seed)
        for name, row in ww.items():
            print(name, json.dumps(row))
    if args.merge:
        result["merge"] = merge_check(args.runs, args.seed)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
