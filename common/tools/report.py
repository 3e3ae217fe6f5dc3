"""The experiment's metrics (paper Table 2) and figures (Figs. 9, 11, 12) from a recording.

Definitions (also in ``docs/recording.md``); all times are the recorder's ``t_recv`` [s]:

Task window
    From the first ``events`` record ``{"event": "task_start"}`` (or ``"start"``; else the
    first command record) to the first ``{"event": "task_done"}`` (or ``"done"``) after it
    (else the last command record). ``completion_s`` is its length [s].
Delay (Fig. 9)
    Total delay h1 + h2 [ms] of the 1 s moving-average estimates inside the task window,
    from the leader's ``estimates`` records (``h1_s`` + ``h2_s``), else its ``leader/state``
    records (the cockpit sample: ``h1_ms`` + ``h2_ms``). Without either: from
    ``feedback/recv`` (the follower's ``h1_s`` + this message's own one-way delay
    ``t_recv - t``) or, in a follower's file, ``cmd/recv`` (``t_recv - t`` + the leader's
    ``h2_s``). Samples where a component is missing, zero (estimator not warm yet) or
    non-finite are left out. ``min/max/mean_delay_ms`` are over these samples.
Passes
    ``passes``: the ``pass`` (``pass_done``) events inside the task window (the leader
    records one per obstacle pass the operator completed); None in a file with neither a
    task start nor a pass (a follower's).
Speed errors (Table 2), odometry
    ``forward_error_cm_s`` [cm/s] and ``turn_error_deg_s`` [deg/s]: the error of the
    robot's speed as a walk engine reports it, per step. For each step inside the task
    window: the displacement along the mean heading and the yaw change between two
    consecutive footfalls over the step's time, against the mean of the reference applied
    over that step; the mean of ``|ref - speed|`` weighted by step time. Footfalls come from
    the ``footfall`` events the follower records (in the given recording, else in the
    ``follower`` recording passed along); two footfalls are consecutive when the second
    comes at most 1.5 of its step time after the first. Without footfalls, steps are
    approximated by consecutive windows of one step time (T/2 of the feedback's T) of the
    feedback poses, over the feedback in state ``walking``. ``odometry_source`` says which
    (``footfalls``, ``feedback``, or None).
Speed errors, instantaneous
    ``forward_error_instant_cm_s``, ``turn_error_instant_deg_s``: mean over the feedback
    messages inside the task window of ``|ref - eta|``, ``ref`` the reference the robot is
    applying (the delayed operator command k_g x_m(t - h1)) and ``eta`` the measured speed
    at that tick (v_hip, turn rate). The torso's turn rate is a pulse train (the hip yaws
    only in single support), so this turn error is large even when every step turns as
    asked. Samples are feedback messages (a constant rate): a time average.
Falls, collisions
    Over the whole recording, the largest of three counts: ``fall``/``collision`` events;
    the follower's ``falls``/``collisions`` status counters (increase during the recording,
    per follower session id); transitions of the feedback ``state`` into ``fallen``
    (falls only).
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from bipedtele.recording.format import Record, RecordingError, read_records
from bipedtele.tools.plots import require_matplotlib
from bipedtele.tools.reportdata import Run, collect, delay_source, task_window
from bipedtele.tools.reportplots import fictitious_intervals, plot_report

__all__ = ["REPORT_KEYS", "add_report_parser", "compute_report", "fictitious_intervals", "format_report", "plot_report"]

LOG = logging.getLogger("bipedtele.tools.report")

REPORT_KEYS: tuple[str, ...] = (
    "min_delay_ms",
    "max_delay_ms",
    "mean_delay_ms",
    "completion_s",
    "passes",
    "forward_error_cm_s",
    "turn_error_deg_s",
    "forward_error_instant_cm_s",
    "turn_error_instant_deg_s",
    "falls",
    "collisions",
    "odometry_source",
)


# ---------------------------------------------------------------------- metrics


def _status_increase(run: Run, key: str) -> int:
    total = 0
    for i, sid in enumerate(run.status_order):
        values = [c[key] for c in run.status[sid] if key in c]
        if not values:
            continue
        base = values[0] if i == 0 else 0  # later sessions started during the recording
        total += max(values) - base
    return total


def _delays(run: Run, window: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Return (times [s], h1 and h2 [s] as an (n, 2) array) inside the window."""
    t, d = delay_source(run)
    ta = np.asarray(t, dtype=float)
    da = np.asarray(d, dtype=float).reshape(-1, 2)
    keep = (ta >= window[0]) & (ta <= window[1])
    return ta[keep], da[keep]


def compute_report(records: Iterable[Record], follower: Iterable[Record] | None = None) -> dict[str, Any]:
    """Return the Table 2 columns of one run.

    Parameters
    ----------
    records : iterable of Record
        A leader's or a follower's recording (see :func:`bipedtele.recording.recorder.read_records`).
    follower : iterable of Record, optional
        The follower's recording of the same run: its ``footfall`` events give the exact
        odometry speed errors when ``records`` has none (a leader's file). Its clock is
        taken to read the leader's (one machine, or synced clocks).

    Returns
    -------
    dict
        Exactly :data:`REPORT_KEYS`: ``min_delay_ms``, ``max_delay_ms``, ``mean_delay_ms``
        (h1 + h2 [ms]), ``completion_s`` [s], ``forward_error_cm_s`` [cm/s],
        ``turn_error_deg_s`` [deg/s] (odometry), ``forward_error_instant_cm_s``,
        ``turn_error_instant_deg_s`` (per feedback) (floats, None when the recording has no
        such data), ``passes`` (int, None without task events), ``falls`` and
        ``collisions`` (ints), ``odometry_source`` (``"footfalls"``, ``"feedback"`` or
        None). Definitions in the module docstring.
    """
    run = collect(records)
    if not run.footfalls and follower is not None:
        run.footfalls = collect(follower).footfalls
    out: dict[str, Any] = dict.fromkeys(REPORT_KEYS)
    window = task_window(run)
    if run.task_start is not None or run.passes:
        lo, hi = window if window is not None else (-math.inf, math.inf)
        out["passes"] = sum(1 for t in run.passes if lo <= t <= hi)
    if window is not None:
        out["completion_s"] = window[1] - window[0]
        _, d = _delays(run, window)
        if len(d):
            total_ms = 1000.0 * d.sum(axis=1)
            out["min_delay_ms"] = float(total_ms.min())
            out["max_delay_ms"] = float(total_ms.max())
            out["mean_delay_ms"] = float(total_ms.mean())
        ft = np.asarray(run.fb_t, dtype=float)
        keep = (ft >= window[0]) & (ft <= window[1])
        if keep.any():
            err = np.abs(np.asarray(run.fb_ref)[keep] - np.asarray(run.fb_eta)[keep])
            out["forward_error_instant_cm_s"] = float(err[:, 0].mean())
            out["turn_error_instant_deg_s"] = float(err[:, 1].mean())
        steps, source = _odometry_steps(run, window)
        if len(steps):
            err = np.abs(steps[:, 1:3] - steps[:, 3:5])
            w = steps[:, 0] / steps[:, 0].sum()
            out["forward_error_cm_s"] = float(err[:, 0] @ w)
            out["turn_error_deg_s"] = float(err[:, 1] @ w)
            out["odometry_source"] = source
    out["falls"] = max(run.event_counts.get("fall", 0), _status_increase(run, "falls"), run.fallen_transitions)
    out["collisions"] = max(run.event_counts.get("collision", 0), _status_increase(run, "collisions"))
    return out


# ---------------------------------------------------------------------- odometry


def _step_speed(p0: Sequence[float], p1: Sequence[float], dt: float) -> tuple[float, float]:
    """Forward speed along the mean heading [cm/s] and turn rate [deg/s] from p0 to p1."""
    dyaw = (p1[2] - p0[2] + math.pi) % (2.0 * math.pi) - math.pi
    heading = p0[2] + dyaw / 2.0
    ahead = (p1[0] - p0[0]) * math.cos(heading) + (p1[1] - p0[1]) * math.sin(heading)
    return 100.0 * ahead / dt, math.degrees(dyaw) / dt


def _mean_ref(run: Run, t0: float, t1: float) -> tuple[float, float] | None:
    """Mean of the feedback references with own time in [t0, t1) (None without any)."""
    ts = np.asarray(run.pose_tmsg, dtype=float)
    keep = (ts >= t0) & (ts < t1)
    if not keep.any():
        return None
    m = np.asarray(run.pose_ref, dtype=float)[keep].mean(axis=0)
    return float(m[0]), float(m[1])


def _steps_from_footfalls(
    footfalls: Sequence[tuple[float, float, tuple[float, float, float], float, tuple[float, float] | None]],
    run: Run | None = None,
) -> list[tuple[float, float, float, float, float]]:
    """Return the steps between consecutive footfalls.

    Each row: (dt [s], speed [cm/s], turn [deg/s], ref forward, ref turn).

    ``footfalls`` are ``(t_recv, t, pose, step_s, ref)`` in time order; a pair counts when
    ``0 < t1 - t0 <= 1.5 step_s`` of the second. ``ref`` missing: the mean of ``run``'s
    feedback references over the step; a step without either is left out.
    """
    out = []
    for (_, ta, pa, _, _), (_, tb, pb, step_s, ref) in itertools.pairwise(footfalls):
        dt = tb - ta
        if not 0.0 < dt <= 1.5 * step_s:
            continue
        if ref is None and run is not None:
            ref = _mean_ref(run, ta, tb)
        if ref is None:
            continue
        v, w = _step_speed(pa, pb, dt)
        out.append((dt, v, w, ref[0], ref[1]))
    return out


def _odometry_from_feedback(run: Run, window: tuple[float, float]) -> list[tuple[float, float, float, float, float]]:
    """Return the steps approximated by windows of one step time (T/2) of the feedback poses.

    Over the feedback inside the task window in state ``walking``, on the feedback's own
    time ``t``: consecutive windows of T/2 [s] (T of the latest feedback at the window's
    start; 1 s when a feedback has none) from the start of each walking run; the pose at
    each end interpolated linearly (yaw unwrapped), the reference averaged over the window.
    A run ends at a feedback not walking or at a gap longer than T/2; its last partial
    window is left out.
    """
    tr = np.asarray(run.pose_t, dtype=float)
    if not len(tr):
        return []
    ts_all = np.asarray(run.pose_tmsg, dtype=float)
    order = np.argsort(ts_all, kind="stable")
    ts = ts_all[order]
    walking = (np.asarray(run.pose_walking, dtype=bool) & (tr >= window[0]) & (tr <= window[1]))[order]
    pose = np.asarray(run.pose, dtype=float).reshape(-1, 3)[order]
    pose[:, 2] = np.unwrap(pose[:, 2])
    refs = np.asarray(run.pose_ref, dtype=float).reshape(-1, 2)[order]
    half = 0.5 * np.nan_to_num(np.asarray(run.pose_T, dtype=float)[order], nan=1.0)
    out = []
    i, n = 0, len(ts)
    while i < n:
        if not walking[i]:
            i += 1
            continue
        j = i  # the walking run is [i, j]
        while j + 1 < n and walking[j + 1] and ts[j + 1] - ts[j] <= half[j]:
            j += 1
        seg_t, seg_p = ts[i : j + 1], pose[i : j + 1]
        t0 = ts[i]
        while True:
            k = i + int(np.searchsorted(seg_t, t0, side="right")) - 1
            t1 = t0 + half[k]
            if t1 > ts[j] + 1e-9:
                break
            keep = (seg_t >= t0) & (seg_t < t1)
            if keep.any():
                p0 = [float(np.interp(t0, seg_t, seg_p[:, c])) for c in range(3)]
                p1 = [float(np.interp(t1, seg_t, seg_p[:, c])) for c in range(3)]
                v, w = _step_speed(p0, p1, t1 - t0)
                ref = refs[i : j + 1][keep].mean(axis=0)
                out.append((t1 - t0, v, w, float(ref[0]), float(ref[1])))
            t0 = t1
        i = j + 1
    return out


def _odometry_steps(run: Run, window: tuple[float, float]) -> tuple[np.ndarray, str | None]:
    """Return (steps as an (n, 5) array, source): from footfalls if any, else from feedback windows."""
    ff = sorted((f for f in run.footfalls if window[0] <= f[0] <= window[1]), key=lambda f: f[1])
    steps, source = _steps_from_footfalls(ff, run), "footfalls"
    if not steps:
        steps, source = _odometry_from_feedback(run, window), "feedback"
    return np.asarray(steps, dtype=float).reshape(-1, 5), source if steps else None


# ---------------------------------------------------------------------- command

_ROWS = (
    ("min_delay_ms", "Min delay", "ms"),
    ("max_delay_ms", "Max delay", "ms"),
    ("mean_delay_ms", "Average delay", "ms"),
    ("completion_s", "Task completion time", "s"),
    ("passes", "Task passes", ""),
    ("forward_error_cm_s", "Forward speed average error", "cm/s"),
    ("turn_error_deg_s", "Turning speed average error", "deg/s"),
    ("forward_error_instant_cm_s", "Forward speed error per tick", "cm/s"),
    ("turn_error_instant_deg_s", "Turning speed error per tick", "deg/s"),
    ("falls", "Falls", ""),
    ("collisions", "Obstacle contacts", ""),
    ("odometry_source", "Speeds per step from", ""),
)


def format_report(report: dict[str, Any], title: str = "") -> str:
    """Return the report as a small two-column table (the paper's Table 2 plus falls/contacts)."""
    lines = [title] if title else []
    for key, label, unit in _ROWS:
        v = report.get(key)
        if v is None:
            text = "-"
        elif isinstance(v, int | str):
            text = str(v)
        else:
            text = f"{v:.2f} {unit}"
        lines.append(f"  {label:<30} {text}")
    return "\n".join(lines)


def _inputs(args: argparse.Namespace) -> tuple[Path, Path | None]:
    """(leader or single recording, follower recording or None) from the arguments.

    A folder (a demo's run folder) stands for its ``leader.mcap`` and, when present, its
    ``follower.mcap``.
    """
    path = Path(args.recording)
    follower = Path(args.follower) if args.follower else None
    if path.is_dir():
        folder = path
        path = folder / "leader.mcap"
        if follower is None and (folder / "follower.mcap").is_file():
            follower = folder / "follower.mcap"
    return path, follower


def _run_report(args: argparse.Namespace) -> int:
    if args.plots:
        require_matplotlib("--plots")
    path, follower_path = _inputs(args)
    try:
        records = list(read_records(path))
        follower = list(read_records(follower_path)) if follower_path is not None else None
    except RecordingError as exc:
        sys.stderr.write(f"bipedtele report: {exc}\n")
        return 2
    if not records:
        sys.stderr.write(f"bipedtele report: {path} holds no messages (empty or cut at the start)\n")
        return 2
    report = compute_report(records, follower=follower)
    title = f"Table 2: {path}" + (f" (footfalls from {follower_path})" if follower_path is not None else "")
    sys.stdout.write(format_report(report, title=title) + "\n")
    try:
        if args.json:
            Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
        if args.plots:
            out = Path(args.plots)
            out.mkdir(parents=True, exist_ok=True)
            for name, fig in plot_report(records).items():
                fig.savefig(out / f"{name}.png", dpi=110)
            sys.stdout.write(f"  figures written to {out}/\n")
    except OSError as exc:
        sys.stderr.write(f"bipedtele report: cannot write output: {exc}\n")
        return 2
    return 0


def add_report_parser(sub: Any) -> None:
    """``bipedtele report RUN.mcap [--follower F.mcap] [--json F] [--plots DIR]``: Table 2 of a recorded run."""
    p = sub.add_parser(
        "report",
        help="Table 2 metrics (delay, completion time, speed errors, falls) of a recording",
        description="Print the paper's Table 2 columns for a recorded run (MCAP) and "
        "optionally write them as JSON and the Fig. 9/11/12-like figures as PNG.",
    )
    p.add_argument(
        "recording",
        metavar="RUN.mcap",
        help="a leader or follower recording, or a run folder holding leader.mcap (and follower.mcap)",
    )
    p.add_argument(
        "--follower",
        metavar="F.mcap",
        help="the follower's recording of the same run: exact per-step speeds from its footfalls",
    )
    p.add_argument("--json", metavar="F", help="write the report as JSON to this file")
    p.add_argument("--plots", metavar="DIR", help="write fig9/fig11/fig12 PNGs into this folder")
    p.set_defaults(func=_run_report)
