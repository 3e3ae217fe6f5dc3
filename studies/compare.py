"""Paired comparison of the control schemes on the reduced closed loop, over delay regimes.

Every registered scheme runs the same operators over the same delays and losses of each
regime (:mod:`bipedtele.studies.regimes`), one scheme at a time through the runner
(:mod:`bipedtele.studies.compare_kernel`, where the loop and the metrics are described);
this module summarises the runs into paired cells, finds each scheme's stability margin and
writes the tables (docs/schemes.md).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import ci95
from bipedtele.control.schemes import scheme_class, scheme_names
from bipedtele.studies.compare_kernel import regime_inputs, simulate
from bipedtele.studies.regimes import MARGIN_SCALES, METRICS, REGIMES, CompareParams, Regime

__all__ = ["compare_markdown", "compare_steps", "paired_cell", "run_compare"]

LOG = logging.getLogger(__name__)


def paired_cell(
    runs: dict[str, np.ndarray], base: dict[str, np.ndarray] | None, metrics: tuple[str, ...] = METRICS
) -> dict[str, Any]:
    """Summarise one scheme's runs of one regime: mean and 95 % interval per metric, paired against ``base``.

    ``runs[m]`` holds metric ``m`` per run, ``runs["unstable"]`` the runs left out (diverged,
    fell); run ``i`` of ``runs`` and of ``base`` share their operator and delays.
    """
    ok = ~runs["unstable"]
    cell: dict[str, Any] = {"n": int(ok.sum()), "unstable": int(runs["unstable"].sum())}
    both = ok if base is None else ok & ~base["unstable"]
    for m in metrics:
        mean, ci = ci95(runs[m][ok])
        cell[m] = {"mean": mean, "ci95": ci}
        if base is not None:
            d_mean, d_ci = ci95(runs[m][both] - base[m][both])
            cell[m]["diff"] = {"mean": d_mean, "ci95": d_ci, "n": int(both.sum())}
    return cell


def compare_steps(runs_steps: int, schemes: int, regimes: int, margin_scales: int) -> int:
    """Return the control periods a comparison simulates (the progress total)."""
    return runs_steps * schemes * (regimes + margin_scales)


def _margin(unstable_by_scale: dict[float, float]) -> float | None:
    """Largest scale >= 1 up to which at most 5 % oscillate (x0 is the no-delay reference, not counted)."""
    best: float | None = None
    for s in sorted(k for k in unstable_by_scale if k >= 1.0):
        if unstable_by_scale[s] > 0.05:
            break
        best = s
    return best


def run_compare(
    runs: int = 200,
    seed: int = 0,
    cfg: ControlConfig | None = None,
    cp: CompareParams | None = None,
    *,
    schemes: tuple[str, ...] | None = None,
    regimes: tuple[Regime, ...] = REGIMES,
    margin_scales: tuple[float, ...] = MARGIN_SCALES,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Compare every scheme on every regime (reduced model), paired against ``paper``.

    Parameters
    ----------
    runs : int
        Runs per scheme and regime (the same operators for every scheme).
    schemes : tuple of str, optional
        Registered names (default: all; ``paper`` is always run, as the reference).
    margin_scales : tuple of float
        Delay scales of the shipped trace for the stability margin (``()``: none).

    Returns
    -------
    dict
        ``{"plant": "reduced", "seed", "runs", "duration_s", "elapsed_s", "schemes": {name:
        title}, "regimes": [...], "cells": {regime: {scheme: cell}}, "margin": {scheme:
        {"scale", "oscillating_by_scale", "released_motion_median_m_s"}}}``; a cell holds ``n``,
        ``unstable`` and, per metric, ``mean``, ``ci95`` and (except for ``paper``) the paired
        ``diff`` against ``paper``.
    """
    if runs < 2:
        raise ValueError(f"runs = {runs}: allowed: >= 2 (a 95 % interval needs two)")
    cfg = cfg or ControlConfig()
    cp = cp or CompareParams()
    names = list(schemes) if schemes else scheme_names()
    if "paper" not in names:
        names.insert(0, "paper")
    classes = {n: scheme_class(n) for n in names}
    chooser = OnlineChooser(cfg)
    started = time.monotonic()
    cells: dict[str, dict[str, Any]] = {}
    unstable: dict[str, dict[float, float]] = {n: {} for n in names}
    motion: dict[str, dict[float, float]] = {n: {} for n in names}
    margin_regimes = tuple(Regime(f"margin-x{s:g}", f"shipped trace x{s:g}", scale=s) for s in margin_scales)
    for regime in regimes + margin_regimes:
        inp = regime_inputs(regime, runs, seed, cfg, cp.study)
        worst = (float(inp.h1.max()), float(inp.h2.max()))
        margin = regime in margin_regimes
        per_scheme = {
            n: simulate(cls(cfg, worst), inp, cfg, cp, chooser, release=margin, progress=progress)
            for n, cls in classes.items()
        }
        if margin:
            for n, r in per_scheme.items():
                unstable[n][regime.scale] = float(r["oscillating"].mean())
                motion[n][regime.scale] = float(np.median(r["released_motion"]))
            continue
        cells[regime.name] = {
            n: paired_cell(r, None if n == "paper" else per_scheme["paper"]) for n, r in per_scheme.items()
        }
        LOG.info("compare: %s done (%.0f s)", regime.name, time.monotonic() - started)
    return {
        "plant": "reduced",
        "seed": seed,
        "runs": runs,
        "duration_s": cp.study.duration_s,
        "elapsed_s": time.monotonic() - started,
        "schemes": {n: classes[n].title for n in names},
        "regimes": [{"name": r.name, "description": r.description} for r in regimes],
        "cells": cells,
        "margin": _margins(unstable, motion) if margin_scales else {},
    }


def _margins(oscillating: dict[str, dict[float, float]], motion: dict[str, dict[float, float]]) -> dict[str, Any]:
    """Per scheme: the margin, the share of oscillating runs and the median released-handle speed per scale."""
    return {
        n: {
            "scale": _margin(u),
            "oscillating_by_scale": {f"{s:g}": v for s, v in u.items()},
            "released_motion_median_m_s": {f"{s:g}": v for s, v in motion[n].items()},
        }
        for n, u in oscillating.items()
    }


def _fmt(v: dict[str, Any], key: str = "") -> str:
    d = v[key] if key else v
    if not math.isfinite(d["mean"]):
        return "-"
    lo, hi = d["ci95"]
    return f"{d['mean']:.2f} [{lo:.2f}, {hi:.2f}]"


def _walker_lines(walker: dict[str, Any]) -> list[str]:
    """Return the walker cells as markdown: errors, paired differences against the paper, falls."""
    lines = [
        f"The pybullet walker (the real follower loop), {walker['runs']} paired runs per cell, "
        f"{walker['duration_s']:g} s each, {walker['wall_s']:.0f} s wall. Coordination error per follower tick "
        "|ref - eta| and intent error [cm/s, deg/s], mean [95 % CI] and paired difference against `paper`; "
        "fallen runs are left out and counted.",
        "",
        "| regime | scheme | forward | - paper | turn | - paper | intent fwd - paper | intent turn - paper | falls |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for regime, per in walker["cells"].items():
        for name, c in per.items():
            diffs = [
                _fmt(c[m], "diff") if "diff" in c[m] else ""
                for m in ("forward_error", "turn_error", "forward_intent_error", "turn_intent_error")
            ]
            lines.append(
                f"| {regime} | {name} | {_fmt(c['forward_error'])} | {diffs[0]} | {_fmt(c['turn_error'])} | "
                f"{diffs[1]} | {diffs[2]} | {diffs[3]} | {c['unstable']} |"
            )
    return lines


_WINNER_METRICS = (
    ("forward_error", "coordination fwd"),
    ("turn_error", "coordination turn"),
    ("forward_intent_error", "intent fwd"),
    ("turn_intent_error", "intent turn"),
    ("forward_force_error", "force error fwd"),
)


def _winners(result: dict[str, Any]) -> list[str]:
    """Per regime and metric: the scheme with the lowest mean, and whether it beats the paper for sure."""
    head = " | ".join(label for _, label in _WINNER_METRICS)
    lines = [
        "Lowest mean per regime and metric (a `*`: its paired 95 % interval against `paper` lies below zero; "
        "`paper` itself: no other scheme's lies below zero).",
        "",
        f"| regime | {head} |",
        "| --- |" + " --- |" * len(_WINNER_METRICS),
    ]
    for regime, per in result["cells"].items():
        row = []
        for metric, _ in _WINNER_METRICS:
            name = min(per, key=lambda n: per[n][metric]["mean"] if math.isfinite(per[n][metric]["mean"]) else math.inf)
            diff = per[name][metric].get("diff")
            sure = name == "paper" or (diff is not None and diff["ci95"][1] < 0.0)
            row.append(f"{name}{'*' if sure and name != 'paper' else ''}")
        lines.append(f"| {regime} | {' | '.join(row)} |")
    return lines


def compare_markdown(result: dict[str, Any]) -> str:
    """Return the comparison as markdown: per regime, each scheme's errors and the paired differences."""
    lines = [
        f"Reduced model, {result['runs']} paired runs per scheme and regime, {result['duration_s']:g} s each, "
        f"seed {result['seed']}. Mean [95 % CI] of the time-mean coordination error |eq. (6)| [cm/s] and "
        "|eq. (10)| [deg/s], the paired difference against `paper` (negative: better than the paper), the "
        "paired difference of the intent error (intended speed against the robot's), the "
        "force error against the delay-free coupling [N, forward], and the least passivity observer at the "
        "leader and follower ports [N cm, forward]; unstable runs are left out and counted.",
        "",
        "| regime | scheme | forward | - paper | turn | - paper | intent fwd - paper | intent turn - paper "
        "| force error | PO leader / follower | unstable |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for regime, per in result["cells"].items():
        for name, c in per.items():
            dfw = _fmt(c["forward_error"], "diff") if "diff" in c["forward_error"] else ""
            dtu = _fmt(c["turn_error"], "diff") if "diff" in c["turn_error"] else ""
            ifw = _fmt(c["forward_intent_error"], "diff") if "diff" in c["forward_intent_error"] else ""
            itu = _fmt(c["turn_intent_error"], "diff") if "diff" in c["turn_intent_error"] else ""
            po = f"{c['forward_po_leader']['mean']:.1f} / {c['forward_po_follower']['mean']:.1f}"
            lines.append(
                f"| {regime} | {name} | {_fmt(c['forward_error'])} | {dfw} | {_fmt(c['turn_error'])} | {dtu} | {ifw} | {itu} | "
                f"{_fmt(c['forward_force_error'])} | {po} | {c['unstable']} |"
            )
    lines += ["", *_winners(result)]
    if result.get("walker"):
        lines += ["", *_walker_lines(result["walker"])]
    if result.get("margin"):
        lines += [
            "",
            "Handle released mid-run: share of runs still oscillating over the last quarter (released handle's "
            "RMS speed above the threshold) per delay scale of the shipped trace (x0: no delay, the reference), "
            "and the median RMS [mm/s].",
            "",
            "| scheme | stability margin (largest scale, <= 5 % oscillating) | oscillating share by scale "
            "| median released-handle speed by scale [mm/s] |",
            "| --- | --- | --- | --- |",
        ]
        for name, m in result["margin"].items():
            share = ", ".join(f"x{s}: {100 * v:.0f} %" for s, v in m["oscillating_by_scale"].items())
            med = ", ".join(f"x{s}: {1e3 * v:.1f}" for s, v in m["released_motion_median_m_s"].items())
            margin = f"x{m['scale']:g}" if m["scale"] is not None else "none (oscillates at x1)"
            lines.append(f"| {name} | {margin} | {share} | {med} |")
    return "\n".join(lines) + "\n"
