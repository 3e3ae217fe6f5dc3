"""The scheme comparison on the pybullet walker (``bipedtele compare``'s walker cells).

Every scheme drives the real follower loop and the pybullet NAO in simulated time
(:func:`~bipedtele.studies.walker_study.walker_run`: the leader side and the operator
are the reduced comparison's, acting as the scheme does), over the same regimes, operators,
delays and losses as the reduced model (:func:`~bipedtele.studies.compare_kernel.regime_inputs`,
equal seeds), so run ``i`` of every scheme is paired. Runs go to ``jobs`` processes.

Metrics per run: the coordination errors per follower tick (``|ref - eta|``, eqs. 6 and 10,
with the reference the robot applies and its measured speeds), the intent errors
(``|intended speed - eta|``), and whether the robot fell (a fallen run is left out of the
means and counted).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np
from bipedtele.config.profile import Config
from bipedtele.control.config import ControlConfig
from bipedtele.control.reduced import StudyParams
from bipedtele.control.schemes import scheme_names
from bipedtele.control.schemes.factorial import NAMED_CELLS
from bipedtele.follower.config import FollowerConfig
from bipedtele.follower.sim.config import SimConfig
from bipedtele.studies.compare import judged_cells
from bipedtele.studies.compare_kernel import regime_inputs
from bipedtele.studies.regimes import REGIMES, Regime
from bipedtele.studies.walker_study import WalkerRun, walker_run

__all__ = ["WALKER_METRICS", "run_walker_compare"]

LOG = logging.getLogger(__name__)

#: Metrics of a walker cell.
WALKER_METRICS: tuple[str, ...] = ("forward_error", "turn_error", "forward_intent_error", "turn_intent_error")


def _row(x: np.ndarray, i: int) -> np.ndarray:
    """Return run ``i``'s series: its row of a ``(runs, steps)`` array, or the one series every run shares."""
    return np.asarray(x[i]) if np.ndim(x) == 2 else np.asarray(x)


def _one(task: tuple[str, str, int, dict[str, Any]]) -> tuple[str, str, int, WalkerRun]:
    regime, scheme, i, kwargs = task
    control = dataclasses.replace(kwargs.pop("control"), scheme=scheme)
    return regime, scheme, i, walker_run(control=control, cp=None, **kwargs)


def run_walker_compare(
    cfg: Config,
    *,
    runs: int = 10,
    seed: int = 0,
    duration_s: float = 12.0,
    schemes: tuple[str, ...] | None = None,
    regimes: tuple[Regime, ...] = REGIMES,
    jobs: int = 2,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Run every scheme ``runs`` times per regime on the walker; cells paired against ``paper``.

    Parameters
    ----------
    cfg : Config
        The profile (``[control]``, ``[follower]``, ``[sim]``).
    runs : int
        Runs per scheme and regime.
    duration_s : float
        Simulated time per run [s].
    jobs : int
        Processes.
    progress : callable, optional
        Called with 1 per run done.

    Returns
    -------
    dict
        ``{"plant": "walker", "runs", "duration_s", "wall_s", "cells": {regime: {scheme: cell}}}``
        with cells as :func:`~bipedtele.studies.compare.judged_cells` makes them (``unstable``:
        the falls; one family per regime and metric, every scheme against ``paper``).
    """
    control = cfg.get(ControlConfig)
    params = StudyParams(duration_s=duration_s)
    names = list(schemes) if schemes else scheme_names()
    if "paper" not in names:
        names.insert(0, "paper")
    tasks = []
    for regime in regimes:
        inp = regime_inputs(regime, runs, seed, control, params)
        for scheme in names:
            for i in range(runs):
                kwargs = {
                    "switch": inp.switch[i : i + 1],
                    "intent": inp.intent[i : i + 1],
                    "h1": _row(inp.h1, i),
                    "h2": _row(inp.h2, i),
                    "lost": (_row(inp.lost1, i), _row(inp.lost2, i)),
                    "control": control,
                    "follower": cfg.get(FollowerConfig),
                    "sim": cfg.get(SimConfig),
                    "params": params,
                }
                tasks.append((regime.name, scheme, i, kwargs))
    started = time.monotonic()
    done: dict[tuple[str, str], list[WalkerRun | None]] = {(r.name, n): [None] * runs for r in regimes for n in names}
    with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        for regime_name, scheme, i, run in pool.map(_one, tasks):
            done[(regime_name, scheme)][i] = run
            if progress is not None:
                progress(1)
    cells: dict[str, dict[str, Any]] = {}
    for regime in regimes:
        per = {}
        for scheme in names:
            rs = [r for r in done[(regime.name, scheme)] if r is not None]
            per[scheme] = {m: np.array([getattr(r, m) for r in rs]) for m in WALKER_METRICS}
            per[scheme]["unstable"] = np.array([r.fell for r in rs], dtype=bool)
        axes = {n: NAMED_CELLS[n] for n in per if n in NAMED_CELLS}
        cells[regime.name] = judged_cells(per, "paper", WALKER_METRICS, axes=axes if len(axes) == len(per) else None)
        LOG.info("walker compare: %s done (%.0f s)", regime.name, time.monotonic() - started)
    return {
        "plant": "walker",
        "runs": runs,
        "duration_s": duration_s,
        "wall_s": time.monotonic() - started,
        "cells": cells,
    }
