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
Speed errors (Table 2)
    Mean over the feedback messages inside the task window of ``|ref - eta|``, where ``ref``
    is the reference the robot is applying (the delayed operator command k_g x_m(t - h1))
    and ``eta`` the measured speed (v_hip, turn rate): the tracking error "according to the
    values received in the robot" (Sec. 5, Fig. 12). ``forward_error_cm_s`` uses the first
    component [cm/s], ``turn_error_deg_s`` the second [deg/s]. Samples are feedback
    messages (a constant rate), so the mean is a time average.
Falls, collisions
    Over the whole recording, the largest of three counts: ``fall``/``collision`` events;
    the follower's ``falls``/``collisions`` status counters (increase during the recording,
    per follower session id); transitions of the feedback ``state`` into ``fallen``
    (falls only).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from bipedtele.recording import Record, RecordingError, read_records
from matplotlib.figure import Figure

__all__ = ["REPORT_KEYS", "add_report_parser", "compute_report", "fictitious_intervals", "format_report", "plot_report"]

LOG = logging.getLogger("bipedtele.report")

REPORT_KEYS: tuple[str, ...] = (
    "min_delay_ms",
    "max_delay_ms",
    "mean_delay_ms",
    "completion_s",
    "forward_error_cm_s",
    "turn_error_deg_s",
    "falls",
    "collisions",
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
        elif topic == "leader/state":  # the leader loop's cockpit sample (ms, N)
            h1, h2 = _num(d.get("h1_ms")), _num(d.get("h2_ms"))
            pair = _positive_pair(h1, h2)
            if pair is not None:
                run.state_delay_t.append(t)
                run.state_delay.append((pair[0] / 1000.0, pair[1] / 1000.0))
            fv, fw = _num(d.get("force_v")), _num(d.get("force_w"))
            if fv is not None and fw is not None:
                run.state_force_t.append(t)
                run.state_force.append((fv, fw))
            ft, fn = _num(d.get("f_v_t")), _num(d.get("f_v_n"))
            if ft is not None and fn is not None:
                run.state_fv_t.append(t)
                run.state_fv.append((ft, fn))
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
        elif topic in STATUS_TOPICS:
            counters = d.get("counters")
            sid = d.get("sid", 0)
            if d.get("role", "follower") == "follower" and isinstance(counters, dict):
                if isinstance(sid, int) and sid not in run.status:
                    run.status[sid] = []
                    run.status_order.append(sid)
                if isinstance(sid, int):
                    run.status[sid].append(
                        {k: v for k, v in counters.items() if isinstance(v, int)}
                    )
    return run


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
    """The best delay signal: ``estimates``, else ``leader/state``, else per-message."""
    if run.delay:
        return run.delay_t, run.delay
    if run.state_delay:
        return run.state_delay_t, run.state_delay
    return run.delay_fallback_t, run.delay_fallback


def _delays(run: _Run, window: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(times [s], h1 and h2 [s] as an (n, 2) array) inside the window."""
    t, d = _delay_source(run)
    ta = np.asarray(t, dtype=float)
    da = np.asarray(d, dtype=float).reshape(-1, 2)
    keep = (ta >= window[0]) & (ta <= window[1])
    return ta[keep], da[keep]


def compute_report(records: Iterable[Record]) -> dict[str, Any]:
    """The Table 2 columns of one run.

    Parameters
    ----------
    records : iterable of Record
        A leader's or a follower's recording (see :func:`bipedtele.recording.read_records`).

    Returns
    -------
    dict
        Exactly :data:`REPORT_KEYS`: ``min_delay_ms``, ``max_delay_ms``, ``mean_delay_ms``
        (h1 + h2 [ms]), ``completion_s`` [s], ``forward_error_cm_s`` [cm/s],
        ``turn_error_deg_s`` [deg/s] (floats, None when the recording has no such data),
        ``falls`` and ``collisions`` (ints). Definitions in the module docstring.
    """
    run = _collect(records)
    out: dict[str, Any] = dict.fromkeys(REPORT_KEYS)
    window = _window(run)
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
            out["forward_error_cm_s"] = float(err[:, 0].mean())
            out["turn_error_deg_s"] = float(err[:, 1].mean())
    out["falls"] = max(
        run.event_counts.get("fall", 0), _status_increase(run, "falls"), run.fallen_transitions
    )
    out["collisions"] = max(run.event_counts.get("collision", 0), _status_increase(run, "collisions"))
    return out


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
    ("forward_error_cm_s", "Forward speed average error", "cm/s"),
    ("turn_error_deg_s", "Turning speed average error", "deg/s"),
    ("falls", "Falls", ""),
    ("collisions", "Obstacle contacts", ""),
)


def format_report(report: dict[str, Any], title: str = "") -> str:
    """The report as a small two-column table (the paper's Table 2 plus falls/contacts)."""
    lines = [title] if title else []
    for key, label, unit in _ROWS:
        v = report.get(key)
        if v is None:
            text = "-"
        elif isinstance(v, int):
            text = str(v)
        else:
            text = f"{v:.2f} {unit}"
        lines.append(f"  {label:<30} {text}")
    return "\n".join(lines)


def _run_report(args: argparse.Namespace) -> int:
    path = Path(args.recording)
    try:
        records = list(read_records(path))
    except RecordingError as exc:
        sys.stderr.write(f"bipedtele report: {exc}\n")
        return 2
    if not records:
        sys.stderr.write(f"bipedtele report: {path} holds no messages (empty or cut at the start)\n")
        return 2
    report = compute_report(records)
    sys.stdout.write(format_report(report, title=f"Table 2: {path}") + "\n")
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
    """``bipedtele report RUN.mcap [--json F] [--plots DIR]``: Table 2 of a recorded run."""
    p = sub.add_parser(
        "report",
        help="Table 2 metrics (delay, completion time, speed errors, falls) of a recording",
        description="Print the paper's Table 2 columns for a recorded run (MCAP) and "
        "optionally write them as JSON and the Fig. 9/11/12-like figures as PNG.",
    )
    p.add_argument("recording", metavar="RUN.mcap", help="a leader or follower recording")
    p.add_argument("--json", metavar="F", help="write the report as JSON to this file")
    p.add_argument("--plots", metavar="DIR", help="write fig9/fig11/fig12 PNGs into this folder")
    p.set_defaults(func=_run_report)
