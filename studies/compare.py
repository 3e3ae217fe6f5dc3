"""Paired, factorial comparison of the control schemes on the reduced closed loop.

Every cell of the factorial grid (:mod:`bipedtele.control.schemes.factorial`: damping x what
is fed back x passivity controller; the named schemes are cells of it) runs the same
operators over the same delays and losses of each regime (:mod:`bipedtele.studies.regimes`),
one cell at a time through the runner (:mod:`bipedtele.studies.compare_kernel`, where the loop
and the metrics are described). This module summarises the runs and judges the differences
(:mod:`bipedtele.studies.inference`), per family (docs/schemes.md, "How the numbers are
judged"):

* **against the baseline** (``paper``, the cell ``scheduled/ze``): per regime and metric, the
  other 23 cells' paired differences, Holm within those 23, TOST within the metric's margin;
* **main effects** of the axes: per regime and metric, each level of an axis against the
  baseline's level (damping ``scheduled``, feedback ``ze``, passivity ``off``), each run's
  metric averaged over the other two axes' cells first (paired); the 6 contrasts one family;
* **released handle**: per delay scale, the 23 paired differences of the released handle's
  RMS speed against the baseline, one family.

Unstable runs are left out of the means and of every pair they are in, and counted.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import ci95
from bipedtele.control.schemes import Scheme, factorial
from bipedtele.control.schemes.factorial import DAMPINGS, FEEDBACKS, NAMED_CELLS, PASSIVITY, Cell, cell_name, grid
from bipedtele.studies.compare_kernel import regime_inputs, simulate
from bipedtele.studies.inference import judge_family, n_for_power
from bipedtele.studies.regimes import (
    ALPHA,
    EQUIVALENCE_MARGINS,
    MARGIN_SCALES,
    METRICS,
    REGIMES,
    RELEASED_MARGIN_M_S,
    CompareParams,
    Regime,
)

__all__ = [
    "BASELINE",
    "REFERENCE_LEVELS",
    "attach_power",
    "compare_steps",
    "judged_cells",
    "main_effects",
    "run_compare",
    "walker_plan",
]

LOG = logging.getLogger(__name__)

#: The cell every other is paired against: the paper's scheme.
BASELINE = cell_name(NAMED_CELLS["paper"])
#: The baseline's level on each axis (the reference of the main effects).
REFERENCE_LEVELS: dict[str, str] = NAMED_CELLS["paper"]._asdict()


def _named(name: str) -> str | None:
    return next((n for n, c in NAMED_CELLS.items() if cell_name(c) == name), None)


def _clean(runs: dict[str, np.ndarray], metric: str) -> np.ndarray:
    """Return the metric per run, NaN where the run was unstable (left out of every mean and pair)."""
    return np.where(runs["unstable"], np.nan, np.asarray(runs[metric], dtype=float))


def judged_cells(
    per_cell: dict[str, dict[str, np.ndarray]],
    baseline: str,
    metrics: tuple[str, ...] = METRICS,
    margins: dict[str, float] | None = None,
    axes: dict[str, Cell] | None = None,
) -> dict[str, dict[str, Any]]:
    """Summarise one regime's cells: mean and 95 % interval per metric, judged against ``baseline``.

    Parameters
    ----------
    per_cell : dict
        Cell name -> metric -> values per run (``unstable``: the runs left out); run ``i``
        of every cell shares its operator and delays.
    baseline : str
        The cell the others are paired against.
    metrics : tuple of str
        Metrics summarised; those with a margin in ``margins`` are judged, one family per
        metric (every cell but the baseline).
    margins : dict, optional
        Equivalence margin per metric (default :data:`~bipedtele.studies.regimes.EQUIVALENCE_MARGINS`).
    axes : dict, optional
        Cell name -> its levels, written into each cell.

    Returns
    -------
    dict
        Cell name -> ``{"damping", "feedback", "passivity", "named", "n", "unstable", metric:
        {"mean", "ci95", "vs_baseline"?}}``, ``vs_baseline`` as
        :meth:`~bipedtele.studies.inference.Verdict.to_dict` gives it (``n``, ``mean``,
        ``ci95``, ``sd``, ``p``, ``d_z``, ``p_holm``, ``margin``, ``tost_p``, ``tost_p_holm``,
        ``verdict``).
    """
    margins = EQUIVALENCE_MARGINS if margins is None else margins
    cells: dict[str, dict[str, Any]] = {}
    for name, runs in per_cell.items():
        ok = ~runs["unstable"]
        named = _named(name) or (name if name in NAMED_CELLS else None)
        cell: dict[str, Any] = {**(axes[name]._asdict() if axes else {}), "named": named}
        cell.update(n=int(ok.sum()), unstable=int(runs["unstable"].sum()))
        for m in metrics:
            mean, ci = ci95(np.asarray(runs[m])[ok])
            cell[m] = {"mean": mean, "ci95": ci}
        cells[name] = cell
    others = [n for n in per_cell if n != baseline]
    for m in metrics:
        if m not in margins or not others:
            continue
        base = _clean(per_cell[baseline], m)
        family = judge_family({n: (_clean(per_cell[n], m), base) for n in others}, margins[m], ALPHA)
        for n, verdict in family.items():
            cells[n][m]["vs_baseline"] = verdict.to_dict()
    return cells


def main_effects(
    per_cell: dict[str, dict[str, np.ndarray]], axes: dict[str, Cell], margins: dict[str, float] | None = None
) -> dict[str, dict[str, dict[str, Any]]]:
    """Return the axes' main effects per metric: each level against the reference level, paired.

    A run's value at one level of an axis is its metric averaged over every cell at that
    level (over the other two axes' levels); a run unstable in any of those cells is left
    out. Per metric, the contrasts of all three axes form one Holm family.

    Returns
    -------
    dict
        Metric -> ``"axis=level"`` -> verdict map (as in :func:`judged_cells`) with ``reference``
        the level it is taken against.
    """
    margins = EQUIVALENCE_MARGINS if margins is None else margins
    levels = {"damping": list(DAMPINGS), "feedback": list(FEEDBACKS), "passivity": list(PASSIVITY)}
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for m, margin in margins.items():
        if not all(m in r for r in per_cell.values()):
            continue
        pairs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for axis, lv in levels.items():
            mean_at = {
                level: np.mean([_clean(per_cell[n], m) for n, c in axes.items() if getattr(c, axis) == level], axis=0)
                for level in lv
            }
            ref = REFERENCE_LEVELS[axis]
            for level in lv:
                if level != ref:
                    pairs[f"{axis}={level}"] = (mean_at[level], mean_at[ref])
        family = judge_family(pairs, margin, ALPHA)
        out[m] = {k: {**v.to_dict(), "reference": REFERENCE_LEVELS[k.split("=")[0]]} for k, v in family.items()}
    return out


def compare_steps(runs_steps: int, schemes: int, regimes: int, margin_scales: int) -> int:
    """Return the control periods a comparison simulates (the progress total)."""
    return runs_steps * schemes * (regimes + margin_scales)


def _margin(oscillating_by_scale: dict[float, float]) -> float | None:
    """Largest scale >= 1 up to which at most 5 % oscillate (x0 is the no-delay reference, not counted)."""
    best: float | None = None
    for s in sorted(k for k in oscillating_by_scale if k >= 1.0):
        if oscillating_by_scale[s] > 0.05:
            break
        best = s
    return best


def _released(per_scale: dict[float, dict[str, dict[str, np.ndarray]]], baseline: str) -> dict[str, dict[str, Any]]:
    """Per cell: the margin, the oscillating share, the median released-handle speed and its test per scale."""
    names = list(next(iter(per_scale.values())))
    out: dict[str, dict[str, Any]] = {
        n: {"oscillating_by_scale": {}, "released_motion_median_m_s": {}, "vs_baseline_by_scale": {}} for n in names
    }
    for s, per in per_scale.items():
        key = f"{s:g}"
        base = per[baseline]["released_motion"]
        family = judge_family(
            {n: (per[n]["released_motion"], base) for n in names if n != baseline}, RELEASED_MARGIN_M_S, ALPHA
        )
        for n in names:
            out[n]["oscillating_by_scale"][key] = float(per[n]["oscillating"].mean())
            out[n]["released_motion_median_m_s"][key] = float(np.median(per[n]["released_motion"]))
            if n in family:
                out[n]["vs_baseline_by_scale"][key] = family[n].to_dict()
    for n in names:
        out[n]["scale"] = _margin({s: out[n]["oscillating_by_scale"][f"{s:g}"] for s in per_scale})
    return out


_CHOOSER: list[OnlineChooser] = []  # one per process: (30)'s tables are built once


def _chooser(cfg: ControlConfig) -> OnlineChooser:
    if not _CHOOSER or _CHOOSER[0].cfg != cfg:
        _CHOOSER[:] = [OnlineChooser(cfg)]
    return _CHOOSER[0]


def _cell_task(
    task: tuple[Regime, str, int, int, ControlConfig, CompareParams, bool],
    cls: type[Scheme] | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[str, str, dict[str, np.ndarray]]:
    """Simulate one cell on one regime (``cls``: its class; default the grid's cell of that name)."""
    regime, name, runs, seed, cfg, cp, release = task
    inp = regime_inputs(regime, runs, seed, cfg, cp.study)
    worst = (float(np.max(inp.h1)), float(np.max(inp.h2)))
    scheme = (cls or grid()[name])(cfg, worst)
    return regime.name, name, simulate(scheme, inp, cfg, cp, _chooser(cfg), release=release, progress=progress)


def _run_tasks(
    tasks: list[tuple[Regime, str, int, int, ControlConfig, CompareParams, bool]],
    classes: dict[str, type[Scheme]],
    jobs: int,
    k_steps: int,
    progress: Callable[[int], None] | None,
) -> dict[tuple[str, str], dict[str, np.ndarray]]:
    """Simulate every (regime, cell) task, over ``jobs`` processes when every cell is a grid cell."""
    results: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    # a worker builds a cell from its name: only grid cells (composed by factorial) travel
    if jobs > 1 and all(getattr(c, "__module__", "") == factorial.__name__ for c in classes.values()):
        # the costliest cells first (those that solve (30) anew at every impact of every run)
        tasks.sort(key=lambda t: not classes[t[1]].adapts)
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            for regime_name, name, res in pool.map(_cell_task, tasks):
                results[(regime_name, name)] = res
                if progress is not None:
                    progress(k_steps)
    else:
        for t in tasks:
            regime_name, name, res = _cell_task(t, classes[t[1]], progress)
            results[(regime_name, name)] = res
    return results


def _design(baseline: str, runs: int, seed: int) -> dict[str, Any]:
    return {
        "axes": {"damping": list(DAMPINGS), "feedback": list(FEEDBACKS), "passivity": list(PASSIVITY)},
        "named": {n: cell_name(c) for n, c in NAMED_CELLS.items()},
        "baseline": baseline,
        "reference_levels": REFERENCE_LEVELS,
        "alpha": ALPHA,
        "margins": dict(EQUIVALENCE_MARGINS),
        "released_margin_m_s": RELEASED_MARGIN_M_S,
        "families": {
            "vs_baseline": "per regime and metric: every other cell against the baseline, Holm within",
            "main_effects": "per regime and metric: each axis level against the reference level (runs averaged "
            "over the other axes' cells), the contrasts of all axes Holm within",
            "released": "per delay scale: every other cell's released-handle RMS speed against the baseline's, "
            "Holm within",
        },
        "seed": seed,
        "runs": runs,
    }


def run_compare(
    runs: int = 100,
    seed: int = 0,
    cfg: ControlConfig | None = None,
    cp: CompareParams | None = None,
    *,
    cells: dict[str, type[Scheme]] | None = None,
    regimes: tuple[Regime, ...] = REGIMES,
    margin_scales: tuple[float, ...] = MARGIN_SCALES,
    jobs: int = 1,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Run the factorial grid (or ``cells``) on every regime (reduced model), judged against the baseline.

    Parameters
    ----------
    runs : int
        Runs per cell and regime (the same operators and delays for every cell).
    cells : dict, optional
        Cell name -> scheme class (default: the whole grid,
        :func:`~bipedtele.control.schemes.factorial.grid`); the baseline is always run.
    margin_scales : tuple of float
        Delay scales of the shipped trace at which the operator lets go (``()``: none).
    jobs : int
        Processes over which the cells are spread (grid cells only; the results do not
        depend on it: each cell is one deterministic simulation of the same inputs).

    Returns
    -------
    dict
        ``{"plant": "reduced", "seed", "runs", "duration_s", "elapsed_s", "design", "schemes":
        {cell: title}, "regimes": [...], "cells": {regime: {cell: cell summary}},
        "main_effects": {regime: {metric: {"axis=level": verdict}}}, "margin": {cell: {...}}}``
        (cell summaries: :func:`judged_cells`).
    """
    if runs < 2:
        raise ValueError(f"runs = {runs}: allowed: >= 2 (a 95 % interval needs two)")
    cfg = cfg or ControlConfig()
    cp = cp or CompareParams()
    full = grid()
    classes = dict(cells) if cells else full
    classes = classes if BASELINE in classes else {BASELINE: full[BASELINE], **classes}
    axes: dict[str, Cell] = {n: getattr(c, "cell", Cell("", "", "")) for n, c in classes.items()}
    started = time.monotonic()
    out_cells: dict[str, dict[str, Any]] = {}
    effects: dict[str, Any] = {}
    released: dict[float, dict[str, dict[str, np.ndarray]]] = {}  # scale -> cell -> runs
    margin_regimes = tuple(Regime(f"margin-x{s:g}", f"shipped trace x{s:g}", scale=s) for s in margin_scales)
    tasks = [(r, n, runs, seed, cfg, cp, r in margin_regimes) for r in regimes + margin_regimes for n in classes]
    results = _run_tasks(tasks, classes, jobs, round(cp.study.duration_s / cp.study.dt), progress)
    for regime in regimes + margin_regimes:
        margin = regime in margin_regimes
        per_cell = {n: results[(regime.name, n)] for n in classes}
        if margin:
            released[regime.scale] = per_cell
            continue
        out_cells[regime.name] = judged_cells(per_cell, BASELINE, axes=axes)
        if set(classes) == set(full):
            effects[regime.name] = main_effects(per_cell, axes)
    LOG.info("compare: %d tasks done (%.0f s)", len(tasks), time.monotonic() - started)
    result: dict[str, Any] = {
        "plant": "reduced",
        "seed": seed,
        "runs": runs,
        "duration_s": cp.study.duration_s,
        "wave_window_s": cfg.wave_window_s,  # [control] wave_window_s, every runner's
        "elapsed_s": time.monotonic() - started,
        "design": _design(BASELINE, runs, seed),
        "schemes": {n: classes[n].title for n in classes},
        "regimes": [{"name": r.name, "description": r.description} for r in regimes],
        "cells": out_cells,
        "main_effects": effects,
        "margin": _released(released, BASELINE) if released else {},
    }
    if all(cell_name(c) in classes for c in NAMED_CELLS.values()):
        result["walker_plan"] = walker_plan(result)
    return result


def attach_power(reduced: dict[str, Any], walker: dict[str, Any], power: float = 0.8) -> None:
    """Write into each walker cell, per judged metric, the pairs its claim needs (``n_needed``).

    The effect size is the reduced model's ``d_z`` for the same contrast (the named scheme's
    cell against the baseline, same regime and metric); the level is the first Holm step of
    the walker's family, ``alpha / m`` for ``m`` contrasts. ``n_needed`` is None where the
    reduced model shows no effect or the regime was not run there.
    """
    for regime, per in walker["cells"].items():
        red = reduced["cells"].get(regime, {})
        m = max(1, sum(1 for n in per if n != "paper"))
        for name, cell in per.items():
            grid_name = cell_name(NAMED_CELLS[name]) if name in NAMED_CELLS else name
            for metric, v in cell.items():
                if not isinstance(v, dict) or "vs_baseline" not in v:
                    continue
                d = red.get(grid_name, {}).get(metric, {}).get("vs_baseline", {}).get("d_z", math.nan)
                v["reduced_d_z"] = d
                v["n_needed"] = n_for_power(d, ALPHA / m, power) if d is not None else None


def walker_plan(reduced: dict[str, Any], power: float = 0.8) -> dict[str, dict[str, dict[str, int | None]]]:
    """Return the walker runs each named scheme's claims need, from the reduced model's effect sizes.

    Per regime, named scheme (not ``paper``) and judged metric: the pairs a paired t-test
    needs for ``power`` at the walker family's first Holm step (``alpha / 5``: the five named
    schemes against ``paper``) to detect the reduced model's ``d_z`` of the same contrast
    (None: no effect there). The walker's own spread decides in the end: ``attach_power``
    writes the same number beside each walker difference once it is run.
    """
    named = [n for n in NAMED_CELLS if n != "paper"]
    out: dict[str, dict[str, dict[str, int | None]]] = {}
    for regime, per in reduced["cells"].items():
        out[regime] = {}
        for n in named:
            cell = per.get(cell_name(NAMED_CELLS[n]), {})
            out[regime][n] = {
                m: n_for_power(v["vs_baseline"]["d_z"], ALPHA / len(named), power)
                for m, v in cell.items()
                if isinstance(v, dict) and "vs_baseline" in v
            }
    return out
