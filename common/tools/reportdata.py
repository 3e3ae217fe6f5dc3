"""The signals of one recording, read for ``bipedtele report``: commands, feedback, delays, forces, events.

:func:`collect` reads a recording once into a :class:`Run` (lists of times and values per
signal, the task events, the follower's status counters); :func:`task_window` and
:func:`delay_source` pick the task window and the best delay signal from it. The metrics
(:mod:`bipedtele.tools.report`) and the figures (:mod:`bipedtele.tools.reportplots`) are
computed from a :class:`Run`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from bipedtele.recording.format import Record
from bipedtele.telemetry import LeaderSample, sample_from_map

__all__ = ["EVENT_ALIASES", "Run", "collect", "delay_source", "task_window"]

CMD_TOPICS = ("cmd/sent", "cmd/recv")
FEEDBACK_TOPICS = ("feedback/recv", "feedback/sent")
STATUS_TOPICS = ("status/recv", "status/sent")
#: Short event names the leader program may use for the task events.
EVENT_ALIASES = {"start": "task_start", "done": "task_done", "pass": "pass_done"}


def _num(v: Any) -> float | None:
    """Return ``v`` as a finite float, else None (booleans and non-numbers too)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _pair(v: Any) -> tuple[float, float] | None:
    """Return the first two items of a list as finite floats, else None."""
    if not isinstance(v, list | tuple) or len(v) < 2:
        return None
    a, b = _num(v[0]), _num(v[1])
    return None if a is None or b is None else (a, b)


@dataclass
class Run:
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


def _add_state(run: Run, t: float, sample: LeaderSample) -> None:
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


def collect(records: Iterable[Record]) -> Run:
    """Read a recording (once) into its signals."""
    run = Run()
    for rec in records:
        t, d, topic = rec.t_recv, rec.data, rec.topic
        run.n_records += 1
        run.first_t = t if run.first_t is None else min(run.first_t, t)
        run.last_t = t if run.last_t is None else max(run.last_t, t)
        if topic in CMD_TOPICS:
            _add_command(run, topic, t, d)
        elif topic in FEEDBACK_TOPICS:
            _add_feedback(run, topic, t, d)
        elif topic == "estimates":
            _add_estimates(run, t, d)
        elif topic == "leader/state":  # the leader loop's sample (ms, N)
            sample = sample_from_map(d)
            if sample is not None:
                _add_state(run, t, sample)
        elif topic == "events":
            _add_event(run, t, d)
        elif topic in STATUS_TOPICS:
            _add_status(run, d)
    return run


def _add_command(run: Run, topic: str, t: float, d: dict[str, Any]) -> None:
    """Fold one command in: its reference and, received, its one-way delay with the leader's h2."""
    ref = _pair(d.get("ref"))
    if ref is not None:
        run.cmd_t.append(t)
        run.cmd_ref.append(ref)
    if topic == "cmd/recv":
        sent = _num(d.get("t"))
        delays = _positive_pair(t - sent if sent is not None else None, d.get("h2_s"))
        if delays is not None:
            run.delay_fallback_t.append(t)
            run.delay_fallback.append(delays)


def _add_feedback(run: Run, topic: str, t: float, d: dict[str, Any]) -> None:
    """Fold one feedback in: speeds, pose, forces, the delays (received) and falls."""
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
        delays = _positive_pair(d.get("h1_s"), t - sent if sent is not None else None)
        if delays is not None:
            run.delay_fallback_t.append(t)
            run.delay_fallback.append(delays)
    sid = d.get("sid", 0)
    state = d.get("state")
    if isinstance(state, str) and isinstance(sid, int):
        if state == "fallen" and run._last_state.get(sid) != "fallen":
            run.fallen_transitions += 1
        run._last_state[sid] = state


def _add_estimates(run: Run, t: float, d: dict[str, Any]) -> None:
    """Fold one ``estimates`` record in: the leader's delay estimates and handle force."""
    delays = _positive_pair(d.get("h1_s"), d.get("h2_s"))
    if delays is not None:
        run.delay_t.append(t)
        run.delay.append(delays)
    f = _pair(d.get("f_m"))
    if f is not None:
        run.force_t.append(t)
        run.force.append(f)


def _add_event(run: Run, t: float, d: dict[str, Any]) -> None:
    """Fold one event in: task start and done, passes, footfalls; every kind counted."""
    ev = d.get("event")
    if not isinstance(ev, str):
        return
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


def _add_status(run: Run, d: dict[str, Any]) -> None:
    """Fold one status in: a follower's counters, per session id."""
    counters = d.get("counters")
    sid = d.get("sid", 0)
    if d.get("role", "follower") == "follower" and isinstance(counters, dict):
        if isinstance(sid, int) and sid not in run.status:
            run.status[sid] = []
            run.status_order.append(sid)
        if isinstance(sid, int):
            run.status[sid].append({k: v for k, v in counters.items() if isinstance(v, int)})


def _add_footfall(run: Run, t: float, d: dict[str, Any]) -> None:
    pose = d.get("pose")
    t_ff, step_s = _num(d.get("t")), _num(d.get("step_s"))
    xy = _pair(pose)
    yaw = _num(pose[2]) if isinstance(pose, list | tuple) and len(pose) >= 3 else None
    if t_ff is None or step_s is None or step_s <= 0 or xy is None or yaw is None:
        return
    run.footfalls.append((t, t_ff, (xy[0], xy[1], yaw), step_s, _pair(d.get("ref"))))


def task_window(run: Run) -> tuple[float, float] | None:
    """Return the task window [s]: task start (else the first command) to the first task done after it."""
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


def delay_source(run: Run) -> tuple[list[float], list[tuple[float, float]]]:
    """Return the best delay signal: ``estimates``, else ``leader/state``, else per-message."""
    if run.delay:
        return run.delay_t, run.delay
    if run.state_delay:
        return run.state_delay_t, run.state_delay
    return run.delay_fallback_t, run.delay_fallback
