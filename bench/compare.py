"""Benchmark and study of the scheme comparison (``bipedtele compare``) on the reduced model.

Prints: the wall time of the default comparison's two parts, the reduced model (every scheme
x every regime x 200 paired runs x 60 s, plus the released-handle margin runs; its simulated
periods per wall second) and the walker cells (10 paired runs x 12 s per cell, 2 processes;
``--walker-runs 0`` skips them), and their sum against the 15-minute goal; with ``--adapt``, what adapting to the delay buys: ``paper`` against
``paper-constant`` (paired) over every regime, for the default settings and for the settings
the paper leaves open where adapting could matter (``k_wt = 0.01``: (30) may choose longer
cycles; ``dp_turn = 0.7``: the impact also costs turn speed; the walker-calibrated reduced
model), each with and without the operator letting go of the handle.

Usage: ``.venv/bin/python bench/compare.py [--runs 200] [--adapt] [--json F]``
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import ci95
from bipedtele.control.schemes import scheme_class, scheme_names
from bipedtele.studies.compare import run_compare
from bipedtele.studies.compare_kernel import regime_inputs, simulate
from bipedtele.studies.regimes import REGIMES, CompareParams

SETTINGS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("defaults", {}),
    ("k_wt = 0.01", {"k_wt": 0.01}),
    ("dp_turn = 0.7", {"dp_turn": 0.7}),
    ("speed-loop model", {"hybrid_model": "speed-loop"}),
)


def _diff(a: np.ndarray, b: np.ndarray) -> str:
    mean, (lo, hi) = ci95(a - b)
    return f"{mean:+.3f} [{lo:+.3f}, {hi:+.3f}]"


def _adapt(runs: int, seed: int) -> dict[str, Any]:
    cp = CompareParams()
    out: dict[str, Any] = {}
    print("\nWhat adapting buys: paper - paper-constant, paired (negative: adapting helps)")
    print("| setting | regime | forward error | turn error | intent fwd | intent turn | released: oscillating |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for label, overrides in SETTINGS:
        cfg = dataclasses.replace(ControlConfig(), **overrides)
        chooser = OnlineChooser(cfg)
        for regime in REGIMES:
            inp = regime_inputs(regime, runs, seed, cfg, cp.study)
            worst = (float(inp.h1.max()), float(inp.h2.max()))
            res = {n: simulate(scheme_class(n)(cfg, worst), inp, cfg, cp, chooser) for n in ("paper", "paper-constant")}
            rel = {
                n: simulate(scheme_class(n)(cfg, worst), inp, cfg, cp, chooser, release=True)
                for n in ("paper", "paper-constant")
            }
            a, b = res["paper"], res["paper-constant"]
            osc = f"{100 * rel['paper']['oscillating'].mean():.0f} % / {100 * rel['paper-constant']['oscillating'].mean():.0f} %"
            row = [
                _diff(a[k], b[k]) for k in ("forward_error", "turn_error", "forward_intent_error", "turn_intent_error")
            ]
            print(f"| {label} | {regime.name} | {' | '.join(row)} | {osc} |")
            out[f"{label}/{regime.name}"] = {"diffs": row, "oscillating_paper_vs_constant": osc}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--adapt", action="store_true", help="also run the paper vs paper-constant sweep")
    ap.add_argument("--json", metavar="FILE", help="write the default comparison's result")
    ap.add_argument("--walker-runs", type=int, default=10, help="walker runs per cell (0: none)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    result = run_compare(args.runs, args.seed)
    wall = time.perf_counter() - t0
    cp = CompareParams()
    periods = round(cp.study.duration_s / cp.study.dt) * len(scheme_names())
    cells = len(REGIMES) + len(result["margin"].get("paper", {}).get("oscillating_by_scale", {}))
    print(
        f"default compare: {len(scheme_names())} schemes x {len(REGIMES)} regimes + margin, {args.runs} runs x "
        f"{cp.study.duration_s:g} s: {wall:.0f} s wall ({periods * cells / wall:.0f} periods/s of {args.runs} runs)"
    )
    if args.walker_runs > 0:
        from bipedtele.config.profile import load_config
        from bipedtele.studies.walker_compare import run_walker_compare

        t1 = time.perf_counter()
        result["walker"] = run_walker_compare(load_config("default"), runs=args.walker_runs, seed=args.seed)
        walker_s = time.perf_counter() - t1
        print(
            f"walker cells: {len(REGIMES) * len(scheme_names())} cells x {args.walker_runs} runs x 12 s: {walker_s:.0f} s"
        )
        print(f"default set: {wall + walker_s:.0f} s (goal: under 900 s)")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1)
    if args.adapt:
        _adapt(args.runs, args.seed)


if __name__ == "__main__":
    main()
