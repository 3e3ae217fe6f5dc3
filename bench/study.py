"""Benchmark of the control core: the full default study and one online (30) call.

Prints: wall time of the full default study (every delay case x (500 CP + 500 VP) runs x 60 s),
runs per second, simulated seconds per wall second; the cost of one
``OnlineChooser.choose`` call (p50/p99, fresh s_e each call and memoised), side by side with
the exact offline solver as the baseline.

Usage: ``.venv/bin/python bench/study.py [--runs 500] [--calls 2000]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser, solve_exact
from bipedtele.studies.study import CASES, StudyParams, run_study


def _pcts(samples: list[float]) -> str:
    p50, p99 = np.percentile(np.asarray(samples) * 1e6, [50, 99])
    return f"p50 {p50:8.1f} us  p99 {p99:8.1f} us"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=500)
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    cfg = ControlConfig()
    params = StudyParams()

    t0 = time.perf_counter()
    chooser = OnlineChooser(cfg)
    build = time.perf_counter() - t0
    print(f"OnlineChooser build: {build * 1e3:.1f} ms (table {chooser.sigma.size} x {chooser.T.size})")

    rng = np.random.default_rng(args.seed)
    fresh, memo = [], []
    for _ in range(args.calls):
        s_e = rng.uniform(0.0, 3.0, size=2)
        t = time.perf_counter()
        chooser.choose(s_e)
        fresh.append(time.perf_counter() - t)
        t = time.perf_counter()
        chooser.choose(s_e)
        memo.append(time.perf_counter() - t)
    exact = []
    for _ in range(10):
        s_e = rng.uniform(0.0, 3.0, size=2)
        t = time.perf_counter()
        solve_exact(s_e, cfg)
        exact.append(time.perf_counter() - t)
    print(f"choose(), new s_e   : {_pcts(fresh)}  ({args.calls} calls)")
    print(f"choose(), memoised  : {_pcts(memo)}")
    print(
        f"solve_exact baseline: {_pcts(exact)}  (10 calls; ratio p50 exact/online {np.median(exact) / np.median(fresh):.0f}x)"
    )

    t0 = time.perf_counter()
    result = run_study(args.runs, args.seed, cfg, params)
    wall = time.perf_counter() - t0
    n_runs = len(CASES) * 2 * args.runs
    sim_s = n_runs * params.duration_s
    print(
        f"study: {len(CASES)} cases x ({args.runs} CP + {args.runs} VP) runs x {params.duration_s:g} s "
        f"at dt {params.dt} s: {wall:.2f} s wall, {n_runs / wall:.0f} runs/s, "
        f"{sim_s / wall:.0f} simulated s per wall s"
    )
    for c in result["cases"]:
        print(
            f"  {c['name']:<16} CP fwd {c['cp']['forward_error']:.3f} turn {c['cp']['turn_error']:.3f} | "
            f"VP fwd {c['vp']['forward_error']:.3f} turn {c['vp']['turn_error']:.3f}"
        )


if __name__ == "__main__":
    main()
