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
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from bipedtele.recording import Record, RecordingError, read_records
from bipedtele.telemetry import LeaderSample, sample_from_map
from bipedtele.tools.plots import require_matplotlib

if TYPE_CHECKING:
    from matplotlib.figure import Figure

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

CMD_TOPICS = ("cmd/sent", "cmd/recv")
FEEDBACK_TOPICS = ("feedback/recv", "feedback/sent")
STATUS_TOPICS = ("status/recv", "status/sent")
#: Short event names the leader program may use for the task events.
EVENT_ALIASES = {"start": "task_start", "done": "task_done", "pass": "pass_done"}


# ---------------------------------------------------------------------- extraction


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _pair(v: Any) -> tuple[float, float] | None:
    if not isinstance(v, list | tuple) or len(v) < 2:
        return None
    a, b = _num(v[0]), _num(v[1])
    return None if a is None or b is None else (a, b)


@dataclass
class _Run:
    """The signals of one recording, as arrays of (time [s], values)."""

    cmd_t: list[float] = field(default_factory=list)
    cmd_ref: list[tuple[float, float]] = field(default_factory=list)
    fb_t: list[float] = field(default_factory=list)
    fb_ref: list[tuple[float, float]] = field(default_factory=list)
    fb_eta: list[tuple[float, float]] = field(default_factory=list)
    fb_yaw: list[float] = field(default_factory=list)
    # feedback poses for the odometry fallback: t_recv, own t, x, y, yaw, ref, T, state
    pose_t: list[float] = field(default_factory=list)
    pose_tmsg: list[float] = field(default_factory=list)
    pose: list[tuple[float, float, float]] = field(default_factory=list)
    pose_ref: list[tuple[float, float]] = field(default_factory=list)
    pose_T: list[float] = field(default_factory=list)
    pose_walking: list[bool] = field(default_factory=list)
    # footfall events: t_recv, own t, pose, step_s, ref (None if not recorded)
    footfalls: list[tuple[float, float, tuple[float, float, float], float, tuple[float, float] | None]] = field(
        default_factory=list
    )
    fv_t: list[float] = field(default_factory=list)
    fv: list[tuple[float, float]] = field(default_factory=list)  # tangential, normal
    ze_t: list[float] = field(default_factory=list)
    ze: list[tuple[float, float]] = field(default_factory=list)
    state_fv_t: list[float] = field(default_factory=list)
    state_fv: list[tuple[float, float]] = field(default_factory=list)
    delay_t: list[float] = field(default_factory=list)
    delay: list[tuple[float, float]] = field(default_factory=list)  # (h1, h2) [s]
    delay_fallback_t: list[float] = field(default_factory=list)
    delay_fallback: list[tuple[float, float]] = field(default_factory=list)
    force_t: list[float] = field(default_factory=list)
    force: list[tuple[float, float]] = field(default_factory=list)
    state_delay_t: list[float] = field(default_factory=list)
    state_delay: list[tuple[float, float]] = field(default_factory=list)
    state_force_t: list[float] = field(default_factory=list)
    state_force: list[tuple[float, float]] = field(default_factory=list)
    task_start: float | None = None
    task_done: list[float] = field(default_factory=list)
    passes: list[float] = field(default_factory=list)
    event_counts: dict[str, int] = field(default_factory=dict)
    status: dict[int, list[dict[str, int]]] = field(default_factory=dict)  # sid -> counters
    status_order: list[int] = field(default_factory=list)
    fallen_transitions: int = 0
    _last_state: dict[int, str] = field(default_factory=dict)
    first_t: float | None = None
    last_t: float | None = None
    n_records: int = 0


def _positive_pair(h1: Any, h2: Any) -> tuple[float, float] | None:
    a, b = _num(h1), _num(h2)
    if a is None or b is None or a <= 0 or b <= 0:
        return None
    return a, b


def _add_state(run: _Run, t: float, sample: LeaderSample) -> None:
    """Fold one ``leader/state`` sample in: delay estimates, handle and fictitious forces."""
    pair = _positive_pair(sample.h1_ms, sample.h2_ms)
    if pair is not None:
        run.state_delay_t.append(t)
        run.state_delay.append((pair[0] / 1000.0, pair[1] / 1000.0))
    fv, fw = _num(sample.force_v), _num(sample.force_w)
    if fv is not None and fw is not None:
        run.state_force_t.append(t)
        run.state_force.append((fv, fw))
    ft, fn = _num(sample.f_v_t), _num(sample.f_v_n)
    if ft is not None and fn is not None:
        run.state_fv_t.append(t)
        run.state_fv.append((ft, fn))


def _collect(records: Iterable[Record]) -> _Run:
    run = _Run()
    for rec in records:
        t, d, topic = rec.t_recv, rec.data, rec.topic
        run.n_records += 1
        run.first_t = t if run.first_t is None else min(run.first_t, t)
        run.last_t = t if run.last_t is None else max(run.last_t, t)
        if topic in CMD_TOPICS:
            ref = _pair(d.get("ref"))
            if ref is not None:
                run.cmd_t.append(t)
                run.cmd_ref.append(ref)
            if topic == "cmd/recv":
                sent = _num(d.get("t"))
                pair = _positive_pair(t - sent if sent is not None else None, d.get("h2_s"))
                if pair is not None:
                    run.delay_fallback_t.append(t)
                    run.delay_fallback.append(pair)
        elif topic in FEEDBACK_TOPICS:
            ref, eta = _pair(d.get("ref")), _pair(d.get("eta"))
            pose = d.get("pose")
            yaw = _num(pose[2]) if isinstance(pose, list | tuple) and len(pose) >= 3 else None
            if ref is not None and eta is not None:
                run.fb_t.append(t)
                run.fb_ref.append(ref)
                run.fb_eta.append(eta)
                run.fb_yaw.append(math.nan if yaw is None else yaw)
                xy = _pair(pose)
                t_msg = _num(d.get("t"))
                if xy is not None and yaw is not None and t_msg is not None:
                    run.pose_t.append(t)
                    run.pose_tmsg.append(t_msg)
                    run.pose.append((xy[0], xy[1], yaw))
                    run.pose_ref.append(ref)
                    period = _num(d.get("T"))
                    run.pose_T.append(period if period is not None and period > 0 else math.nan)
                    run.pose_walking.append(d.get("state", "walking") == "walking")
            fv_pair, ze_pair = _pair(d.get("f_v")), _pair(d.get("z_e"))
            if fv_pair is not None:
                run.fv_t.append(t)
                run.fv.append(fv_pair)
            if ze_pair is not None:
                run.ze_t.append(t)
                run.ze.append(ze_pair)
            if topic == "feedback/recv":
                sent = _num(d.get("t"))
                pair = _positive_pair(d.get("h1_s"), t - sent if sent is not None else None)
                if pair is not None:
                    run.delay_fallback_t.append(t)
                    run.delay_fallback.append(pair)
            sid = d.get("sid", 0)
            state = d.get("state")
            if isinstance(state, str) and isinstance(sid, int):
                if state == "fallen" and run._last_state.get(sid) != "fallen":
                    run.fallen_transitions += 1
                run._last_state[sid] = state
        elif topic == "estimates":
            pair = _positive_pair(d.get("h1_s"), d.get("h2_s"))
            if pair is not None:
                run.delay_t.append(t)
                run.delay.append(pair)
            f = _pair(d.get("f_m"))
            if f is not None:
                run.force_t.append(t)
                run.force.append(f)
        elif topic == "leader/state":  # the leader loop's sample (ms, N)
            sample = sample_from_map(d)
            if sample is not None:
                _add_state(run, t, sample)
        elif topic == "events":
            ev = d.get("event")
            if not isinstance(ev, str):
                continue
            ev = EVENT_ALIASES.get(ev, ev)
            run.event_counts[ev] = run.event_counts.get(ev, 0) + 1
            if ev == "task_start" and run.task_start is None:
                run.task_start = t
            elif ev == "task_done":
                run.task_done.append(t)
            elif ev == "pass_done":
                run.passes.append(t)
            elif ev == "footfall":
                _add_footfall(run, t, d)
        elif topic in STATUS_TOPICS:
            counters = d.get("counters")
            sid = d.get("sid", 0)
            if d.get("role", "follower") == "follower" and isinstance(counters, dict):
                if isinstance(sid, int) and sid not in run.status:
                    run.status[sid] = []
                    run.status_order.append(sid)
                if isinstance(sid, int):
                    run.status[sid].append({k: v for k, v in counters.items() if isinstance(v, int)})
    return run


def _add_footfall(run: _Run, t: float, d: dict[str, Any]) -> None:
    pose = d.get("pose")
    t_ff, step_s = _num(d.get("t")), _num(d.get("step_s"))
    xy = _pair(pose)
    yaw = _num(pose[2]) if isinstance(pose, list | tuple) and len(pose) >= 3 else None
    if t_ff is None or step_s is None or step_s <= 0 or xy is None or yaw is None:
        return
    run.footfalls.append((t, t_ff, (xy[0], xy[1], yaw), step_s, _pair(d.get("ref"))))


def _window(run: _Run) -> tuple[float, float] | None:
    t0 = run.task_start
    if t0 is None:
        t0 = min(run.cmd_t) if run.cmd_t else run.first_t
    if t0 is None:
        return None
    done = [t for t in run.task_done if t >= t0]
    if done:
        t1 = min(done)
    elif run.cmd_t:
        t1 = max(run.cmd_t)
    else:
        t1 = run.last_t if run.last_t is not None else t0
    return t0, max(t0, t1)


def _status_increase(run: _Run, key: str) -> int:
    total = 0
    for i, sid in enumerate(run.status_order):
        values = [c[key] for c in run.status[sid] if key in c]
        if not values:
            continue
        base = values[0] if i == 0 else 0  # later sessions started during the recording
        total += max(values) - base
    return total


def _delay_source(run: _Run) -> tuple[list[float], list[tuple[float, float]]]:
    """Return the best delay signal: ``estimates``, else ``leader/state``, else per-message."""
    if run.delay:
        return run.delay_t, run.delay
    if run.state_delay:
        return run.state_delay_t, run.state_delay
    return run.delay_fallback_t, run.delay_fallback


def _delays(run: _Run, window: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Return (times [s], h1 and h2 [s] as an (n, 2) array) inside the window."""
    t, d = _delay_source(run)
    ta = np.asarray(t, dtype=float)
    da = np.asarray(d, dtype=float).reshape(-1, 2)
    keep = (ta >= window[0]) & (ta <= window[1])
    return ta[keep], da[keep]


def compute_report(records: Iterable[Record], follower: Iterable[Record] | None = None) -> dict[str, Any]:
    """Return the Table 2 columns of one run.

    Parameters
    ----------
    records : iterable of Record
        A leader's or a follower's recording (see :func:`bipedtele.recording.read_records`).
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
    run = _collect(records)
    if not run.footfalls and follower is not None:
        run.footfalls = _collect(follower).footfalls
    out: dict[str, Any] = dict.fromkeys(REPORT_KEYS)
    window = _window(run)
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


def _mean_ref(run: _Run, t0: float, t1: float) -> tuple[float, float] | None:
    """Mean of the feedback references with own time in [t0, t1) (None without any)."""
    ts = np.asarray(run.pose_tmsg, dtype=float)
    keep = (ts >= t0) & (ts < t1)
    if not keep.any():
        return None
    m = np.asarray(run.pose_ref, dtype=float)[keep].mean(axis=0)
    return float(m[0]), float(m[1])


def _steps_from_footfalls(
    footfalls: Sequence[tuple[float, float, tuple[float, float, float], float, tuple[float, float] | None]],
    run: _Run | None = None,
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


def _odometry_from_feedback(run: _Run, window: tuple[float, float]) -> list[tuple[float, float, float, float, float]]:
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


def _odometry_steps(run: _Run, window: tuple[float, float]) -> tuple[np.ndarray, str | None]:
    """Return (steps as an (n, 5) array, source): from footfalls if any, else from feedback windows."""
    ff = sorted((f for f in run.footfalls if window[0] <= f[0] <= window[1]), key=lambda f: f[1])
    steps, source = _steps_from_footfalls(ff, run), "footfalls"
    if not steps:
        steps, source = _odometry_from_feedback(run, window), "feedback"
    return np.asarray(steps, dtype=float).reshape(-1, 5), source if steps else None


# ---------------------------------------------------------------------- figures


def fictitious_intervals(t: np.ndarray, f_t: np.ndarray, threshold: float = 1e-6) -> list[tuple[float, float]]:
    """Time intervals [s] where the tangential fictitious force acts (``|f_t| > threshold``).

    An interval runs from its first active sample to the first inactive one after it (to
    the last sample if it lasts to the end).
    """
    t = np.asarray(t, dtype=float)
    on = np.abs(np.asarray(f_t, dtype=float)) > threshold
    out: list[tuple[float, float]] = []
    start: float | None = None
    for ti, o in zip(t, on, strict=True):
        if o and start is None:
            start = float(ti)
        elif not o and start is not None:
            out.append((start, float(ti)))
            start = None
    if start is not None:
        out.append((start, float(t[-1])))
    return out


def _rel(t: Sequence[float], t0: float) -> np.ndarray:
    return np.asarray(t, dtype=float) - t0


def plot_report(records: Iterable[Record]) -> dict[str, Figure]:
    """Figures like the paper's: ``fig9_delay``, ``fig11_coordination``, ``fig12_tracking``.

    Parameters
    ----------
    records : iterable of Record
        A recording (read once).

    Returns
    -------
    dict of str to matplotlib Figure
        Time axes in seconds from the task start; the task window is shaded.
        ``fig9_delay``: h1, h2 and h1 + h2 [ms]. ``fig11_coordination``: (a) commanded
        (sent) vs robot forward speed and the equivalent speed z_e the operator feels
        [cm/s], (b) the same for the turn speed [deg/s], (c) the fictitious force f_v
        (tangential, normal; from the feedback, else the leader's state samples), (d) the
        handle force f_m [N] (when recorded); the intervals where the tangential f_v acts
        (:func:`fictitious_intervals`) are shaded on every panel. ``fig12_tracking``: (a) the reference
        applied on the robot vs its forward speed [cm/s], (b) the turn angle commanded
        (integral of the applied turn-speed reference) vs the robot's yaw [deg].
    """
    run = _collect(records)
    window = _window(run) or (0.0, 0.0)
    t0 = window[0]
    from matplotlib.figure import Figure  # the ``plots`` extra: only the figures need it

    figs: dict[str, Figure] = {}

    def shade(ax: Any) -> None:
        ax.axvspan(0.0, window[1] - t0, color="0.9", zorder=0)
        ax.grid(True, alpha=0.3)

    # Fig. 9: total delay.
    fig = Figure(figsize=(8, 3.2), layout="constrained")
    ax = fig.add_subplot()
    t, d = _delay_source(run)
    if d:
        da = 1000.0 * np.asarray(d)
        tr = _rel(t, t0)
        ax.plot(tr, da.sum(axis=1), color="C3", label="h1 + h2")
        ax.plot(tr, da[:, 0], color="C0", lw=0.8, ls="--", label="h1 (forward)")
        ax.plot(tr, da[:, 1], color="C1", lw=0.8, ls="--", label="h2 (backward)")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("delay [ms]")
    ax.set_title("Total delay h1 + h2 (1 s moving average)")
    shade(ax)
    figs["fig9_delay"] = fig

    # Fig. 11: commanded vs robot speeds, the fictitious force and the handle force; the
    # intervals where f_v acts are shaded (the paper's rectangles).
    fig = Figure(figsize=(8, 9), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    cmd = np.asarray(run.cmd_ref, dtype=float).reshape(-1, 2)
    eta = np.asarray(run.fb_eta, dtype=float).reshape(-1, 2)
    ze = np.asarray(run.ze, dtype=float).reshape(-1, 2)
    fv_t, fv = (run.fv_t, run.fv) if run.fv else (run.state_fv_t, run.state_fv)
    fva = np.asarray(fv, dtype=float).reshape(-1, 2)
    acts = fictitious_intervals(_rel(fv_t, t0), fva[:, 0]) if len(fva) else []

    def shade_fv(ax: Any) -> None:
        for i, (a0, a1) in enumerate(acts):
            ax.axvspan(a0, a1, color="tab:orange", alpha=0.18, zorder=0, label="f_v acts" if i == 0 else None)

    for i, (unit, name) in enumerate((("cm/s", "forward speed"), ("deg/s", "turn speed"))):
        a = axes[i]
        if len(cmd):
            a.plot(_rel(run.cmd_t, t0), cmd[:, i], color="C1", label="command (sent)")
        if len(eta):
            a.plot(_rel(run.fb_t, t0), eta[:, i], color="C0", lw=0.8, label="NAO (measured)")
        if len(ze):
            a.plot(_rel(run.ze_t, t0), ze[:, i], color="C2", lw=1.0, ls="--", label="z_e (felt, eq. 29)")
        a.set_ylabel(f"{name} [{unit}]")
        shade(a)
        shade_fv(a)
        a.legend(loc="upper right", fontsize=8)
    a = axes[2]
    if len(fva):
        a.plot(_rel(fv_t, t0), fva[:, 0], color="C3", label="f_v tangential")
        a.plot(_rel(fv_t, t0), fva[:, 1], color="C7", lw=0.8, label="f_v normal")
    a.set_ylabel("fictitious force f_v")
    shade(a)
    shade_fv(a)
    a.legend(loc="upper right", fontsize=8)
    a = axes[3]
    force_t, force = (run.force_t, run.force) if run.force else (run.state_force_t, run.state_force)
    if force:
        f = np.asarray(force)
        a.plot(_rel(force_t, t0), f[:, 0], color="C4", label="f_m forward axis")
        a.plot(_rel(force_t, t0), f[:, 1], color="C5", label="f_m turn axis")
    a.set_ylabel("handle force [N]")
    a.set_xlabel("time [s]")
    shade(a)
    shade_fv(a)
    a.legend(loc="upper right", fontsize=8)
    axes[0].set_title("Coordination: (a) forward, (b) turn, (c) fictitious force, (d) handle force")
    figs["fig11_coordination"] = fig

    # Fig. 12: applied reference vs robot, forward speed and turn angle.
    fig = Figure(figsize=(8, 5.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    if run.fb_t:
        tr = _rel(run.fb_t, t0)
        ref = np.asarray(run.fb_ref)
        axes[0].plot(tr, ref[:, 0], color="C1", label="reference (on the robot)")
        axes[0].plot(tr, eta[:, 0], color="C0", lw=0.8, label="NAO")
        dt = np.diff(tr, prepend=tr[0])
        ref_angle = np.cumsum(ref[:, 1] * dt)
        axes[1].plot(tr, ref_angle, color="C1", label="reference angle (integral)")
        yaw = np.asarray(run.fb_yaw, dtype=float)
        ok = np.isfinite(yaw)
        if ok.any():
            yaw_deg = np.degrees(np.unwrap(yaw[ok]))
            axes[1].plot(tr[ok], yaw_deg - yaw_deg[0], color="C0", lw=0.8, label="NAO yaw")
        for a in axes:
            a.legend(loc="upper right", fontsize=8)
    axes[0].set_ylabel("forward speed [cm/s]")
    axes[1].set_ylabel("turn angle [deg]")
    axes[1].set_xlabel("time [s]")
    for a in axes:
        shade(a)
    axes[0].set_title("Tracking: (a) forward speed, (b) turn angle")
    figs["fig12_tracking"] = fig
    return figs


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
