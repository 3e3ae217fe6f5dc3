"""The internet bench's figures of one run, from the two recordings and the leader's log.

:func:`analyse` (every figure of a row), :func:`gap_figures` (gaps of the feedback, the
first feedback after each, the blind stops, the wording), :func:`video_allowance` (the
frame rate a trace's mean capacity allows after control) and :func:`outage_figures`. Used
by ``bench/internet.py``; every namespace shares the machine's clock, so a message's
receive time minus its send stamp is its true one-way delay.
"""

from __future__ import annotations

import itertools
import math
import re
from typing import Any

import numpy as np
from bipedtele.link.delaymodels import parse_delay_model
from bipedtele.recording.format import Record

LINK_STATES = ("capacity-limited", "lossy", "lost")


# After the uplink budget's first estimate, the queue its start's overshoot built drains in
# about the budget's drain_s (1 s); the steady state is counted from twice that [s]
ESTIMATE_SETTLE_S = 2.0


def _ms(xs: list[float]) -> dict[str, float | None]:
    if not xs:
        return {"n": 0, "p50": None, "p99": None, "max": None}
    a = 1000.0 * np.asarray(xs)
    return {"n": len(xs), "p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def _passes(log: str) -> int:
    found = re.findall(r"pilot: pass (\d+)/\d+ done", log)
    return int(found[-1]) if found else 0


def analyse(
    l_rec: list[Record],
    f_rec: list[Record],
    leader_log: str,
    *,
    outage_wall: tuple[float, float] | None,
    startup_s: float = 0.0,
    emulated: tuple[str, str, float] | None = None,
) -> dict[str, Any]:
    """Every figure of one run from the two recordings and the leader's log.

    ``outage_wall``: (cut, return) in wall time; ``startup_s``: delays of messages sent in
    the first seconds after the leader's first command are left out of ``*_after_startup``;
    ``emulated``: (h1 model, h2 model, origin) of the emulator: then ``h1_excess_ms`` and
    ``h2_excess_ms`` are each message's delay beyond what the emulator applied at its send
    time (what the transport and the machine added: retransmissions, queues, scheduling).
    """
    sent = [r for r in l_rec if r.topic == "cmd/sent"]
    t_begin = sent[0].t_recv if sent else 0.0
    t_end = sent[-1].t_recv if sent else 0.0
    dur = max(1e-9, t_end - t_begin)
    res: dict[str, Any] = {"passes": _passes(leader_log), "run_s": round(dur, 1), "commands_sent": len(sent)}
    ev = [r for r in f_rec if r.topic == "events" and t_begin <= r.t_recv <= t_end]
    res["watchdog_stops"] = sum(1 for r in ev if r.data.get("event") == "watchdog_stop")
    res["operator_stops"] = sum(1 for r in ev if r.data.get("event") == "operator_stop")
    res["falls"] = sum(1 for r in ev if r.data.get("event") == "fall")
    res["collisions"] = sum(1 for r in ev if r.data.get("event") == "collision")
    st = [r for r in f_rec if r.topic == "status/sent"]
    counters = dict(st[-1].data.get("counters", {})) if st else {}
    res["follower_counters"] = counters
    for k in ("cmd_too_old", "cmd_backlog", "cmd_reordered", "cmd_accepted"):
        res[k] = counters.get(k)
    fb = [r for r in l_rec if r.topic == "feedback/recv" and r.t_recv <= t_end]
    cmd = [r for r in f_rec if r.topic == "cmd/recv" and t_begin <= r.data["t"] <= t_end]
    h2 = [(r.data["t"], r.t_recv - r.data["t"]) for r in fb]
    h1 = [(r.data["t"], r.t_recv - r.data["t"]) for r in cmd]
    res["h1_ms"] = _ms([d for _, d in h1])
    res["h2_ms"] = _ms([d for _, d in h2])
    res["h1_ms_after_startup"] = _ms([d for t, d in h1 if t >= t_begin + startup_s])
    res["h2_ms_after_startup"] = _ms([d for t, d in h2 if t >= t_begin + startup_s])
    # the follower's uplink budget: its first estimate of the path ends its start (a cut, or
    # start_s of clear path); the start's growth overshoots a cap once before it
    est = [r.t_recv for r in st if int(r.data.get("counters", {}).get("uplink_capacity_bps", 0) or 0) > 0]
    settled = est[0] + ESTIMATE_SETTLE_S if est else math.inf
    res["first_estimate_s"] = round(est[0] - t_begin, 1) if est else None
    res["h2_ms_start"] = _ms([d for t, d in h2 if t_begin + startup_s <= t < settled])
    res["h2_ms_after_estimate"] = _ms([d for t, d in h2 if t >= settled])
    if emulated is not None:
        m1, m2 = parse_delay_model(emulated[0]), parse_delay_model(emulated[1])
        t0 = emulated[2]
        res["h1_excess_ms"] = _ms([d - m1.delay_s(t - t0) for t, d in h1 if t >= t_begin + startup_s])
        res["h2_excess_ms"] = _ms([d - m2.delay_s(t - t0) for t, d in h2 if t >= t_begin + startup_s])
    res["h_source"] = "true one-way: follower cmd/recv and leader feedback/recv, receive time - send stamp t"
    video = [r for r in l_rec if r.topic == "video/recv" and t_begin <= r.t_recv <= t_end]
    res["video_fps"] = round(len(video) / dur, 2)
    states = [r.data.get("link") for r in l_rec if r.topic == "leader/state" and t_begin <= r.t_recv <= t_end]
    res["link_samples"] = len(states)
    res["link_fraction"] = {
        s: (sum(1 for x in states if x == s) / len(states) if states else None) for s in LINK_STATES
    }
    res["link_states_seen"] = sorted({str(x) for x in states})
    fb_sent = [r for r in f_rec if r.topic == "feedback/sent"]
    moved = [r.data["pose"] for r in fb_sent if r.data.get("pose")]
    res["distance_m"] = (
        round(float(np.sum(np.hypot(*np.diff(np.asarray(moved)[:, :2], axis=0).T))), 2) if len(moved) > 1 else 0.0
    )
    res["walking_fraction"] = (
        sum(1 for r in fb_sent if r.data.get("state") == "walking") / len(fb_sent) if fb_sent else None
    )
    res["gap"] = gap_figures(l_rec, f_rec, leader_log)
    if outage_wall is not None:
        moved = [r.t_recv for r in l_rec if r.topic == "events" and r.data.get("event") == "blind_over"]
        res["outage"] = outage_figures(fb_sent, cmd, *outage_wall, moved=moved)
        res["outage"]["cut_after_first_command_s"] = round(outage_wall[0] - t_begin, 1)
    return res


_STOP_EVENTS = ("operator_stop", "watchdog_stop")


def gap_figures(l_rec: list[Record], f_rec: list[Record], leader_log: str, blind_stop_s: float = 1.5) -> dict[str, Any]:
    """Gaps of the feedback at the leader, the first feedback after each, the blind stops, the wording.

    A gap: more than 1 s between two feedback the leader received. ``first_age_s``: how old
    the first one after it was (receive time - send stamp); ``fresh_after_s``: from the gap's
    end to the first one at most 0.5 s old. Blind stops (leader events): the robot's stop
    (its ``operator_stop`` / ``watchdog_stop`` event, or its first feedback sent in a state
    other than ``walking``, whichever came first) after the send time of the
    newest feedback the operator had, and its first ``walking`` feedback after the
    ``blind_over`` event.
    """
    fb = sorted((r.t_recv, r.t_recv - r.data["t"], r.data["t"]) for r in l_rec if r.topic == "feedback/recv")
    f_st = [(r.t_recv, r.data.get("counters", {})) for r in f_rec if r.topic == "status/sent"]
    f_fb = sorted(r.data["t"] for r in f_rec if r.topic == "feedback/sent")
    gaps = []
    for (a, _, _), (b, age, _) in itertools.pairwise(fb):
        if b - a > 1.0:
            fresh = next((t - b for t, ag, _ in fb if t >= b and ag <= 0.5), None)
            gaps.append(
                {
                    "at": round(a, 2),
                    "length_s": round(b - a, 2),
                    "first_age_s": round(age, 3),
                    "fresh_after_s": None if fresh is None else round(fresh, 3),
                    **_gap_split(fb, f_st, f_fb, a, b),
                }
            )
    sent = [(r.t_recv, r.data.get("state")) for r in f_rec if r.topic == "feedback/sent"]
    # the robot's stop: its stop event, or its first feedback not walking (the feedback may
    # be held by the uplink's in-flight cap, so the event comes first)
    halts = sorted(
        [r.t_recv for r in f_rec if r.topic == "events" and r.data.get("event") in _STOP_EVENTS]
        + [ts for ts, st in sent if st != "walking"]
    )
    ev = [(r.t_recv, r.data) for r in l_rec if r.topic == "events"]
    stops, walks = [], []
    for t, d in ev:
        if d.get("event") == "blind_stop":
            newest = max((ts for tr, _, ts in fb if tr <= t), default=None)
            t_stop = next((ts for ts in halts if ts >= t), None)
            if newest is not None and t_stop is not None:
                stops.append(round(t_stop - newest, 3))
        elif d.get("event") == "blind_over":
            t_walk = next((ts for ts, st in sent if ts >= t and st == "walking"), None)
            walks.append(None if t_walk is None else round(t_walk - t, 3))
    return {
        "gaps": gaps,
        "blind_stops": len(stops),
        "stop_after_newest_fb_s": stops,
        "walk_after_handle_s": walks,
        "acl_lines": sum(1 for ln in leader_log.splitlines() if "ACL" in ln and "WARNING" in ln),
        "stall_lines": leader_log.count("uplink stalled for"),
        "blind_stop_s": blind_stop_s,
    }


def _gap_split(
    fb: list[tuple[float, float, float]],
    f_st: list[tuple[float, dict[str, Any]]],
    f_fb: list[float],
    a: float,
    b: float,
) -> dict[str, Any]:
    """The feedback that arrived after a gap ``(a, b)``, split by when it was sent.

    (a) in flight when the gap began: sent after the last one that arrived before it and
    before ``a`` (the last arrival before the gap): how many the follower sent
    (``inflight_sent``, from its ``feedback/sent``), how many of them the leader took after
    the gap (``inflight_n``; the others were refused as too old, or lost) and the oldest
    of those's age, and the follower's bytes in flight in its last Status before ``a``
    (``uplink_inflight_bytes``; None: not reported). (b) sent during the gap or after: the
    age of the first of it to arrive, and when it arrived after the gap's end; of what was
    sent 0.5 s or more into the gap (once the follower could know: a round trip and a
    status period), the age of the first to arrive (``first_late_age_s``: a probe, or the
    first fresh one).
    """
    last = max((ts for t, _, ts in fb if t <= a), default=-math.inf)
    after = [(t, ag, ts) for t, ag, ts in fb if t >= b]
    old = [(t, ag) for t, ag, ts in after if ts < a]
    new = next(((t, ag) for t, ag, ts in after if ts >= a), None)
    late = next(((t, ag) for t, ag, ts in after if ts >= a + 0.5), None)
    st = [c for t, c in f_st if t <= a]
    return {
        "inflight_sent": sum(1 for ts in f_fb if last < ts < a),
        "inflight_n": len(old),
        "inflight_age_s": round(max((ag for _, ag in old), default=0.0), 3),
        "inflight_bytes": st[-1].get("uplink_inflight_bytes") if st else None,
        "first_new_age_s": None if new is None else round(new[1], 3),
        "first_new_after_s": None if new is None else round(new[0] - b, 3),
        "first_late_age_s": None if late is None else round(late[1], 3),
    }


def video_allowance(
    l_rec: list[Record], f_rec: list[Record], mean_bps: float, t0: float, t1: float, most_fps: float | None = None
) -> dict[str, Any]:
    """The frame rate the trace's mean capacity allows after control, from the frames actually sent.

    ``frame_bytes``: mean size of the frames the leader received (JPEG + 120 bytes of
    fields and MAC); ``control_bps``: the follower's control rate (``uplink_tx_control_bps``,
    mean of its Status over the run); allowance = (mean - control) / (8 frame_bytes).
    ``most_fps``: the follower's configured video rate, every camera [frames/s]; no path
    lets video send more, so ``within_fps`` = min(allowance, most_fps) is what the path
    allows of the video asked for (None without it).
    """
    sizes = [
        len(r.data["jpeg"]) + 120
        for r in l_rec
        if r.topic == "video/recv" and t0 <= r.t_recv <= t1 and r.data.get("jpeg") and not r.data.get("jpeg_skipped")
    ]
    ctl = [
        float(r.data.get("counters", {}).get("uplink_tx_control_bps", 0) or 0)
        for r in f_rec
        if r.topic == "status/sent" and t0 <= r.t_recv <= t1
    ]
    if not sizes or not ctl:
        return {"mean_bps": mean_bps, "frame_bytes": None, "control_bps": None, "allowed_fps": None}
    fb = sum(sizes) / len(sizes)
    c = sum(ctl) / len(ctl)
    allowed = round(max(0.0, mean_bps - c) / (8.0 * fb), 2)
    return {
        "mean_bps": round(mean_bps),
        "frame_bytes": round(fb),
        "control_bps": round(c),
        "allowed_fps": allowed,
        "most_fps": most_fps,
        "within_fps": None if most_fps is None else min(allowed, most_fps),
    }


def outage_figures(
    fb_sent: list[Record], cmd: list[Record], cut: float, back: float, moved: list[float] | None = None
) -> dict[str, Any]:
    """Stop and restart latencies around an outage, and what of the backlog was applied after it.

    ``moved``: when the leader's blind stops ended (fresh feedback and a handle move,
    ``blind_over`` events): the restart after the first one past the path's return is
    ``restart_after_move_s`` (the robot waits for the operator's move then).
    """
    move = min((t for t in moved or [] if t >= back), default=None)
    after_move = (
        None
        if move is None
        else next((r.t_recv - move for r in fb_sent if r.t_recv >= move and r.data.get("state") == "walking"), None)
    )
    before = [r for r in fb_sent if r.t_recv < cut]
    walking_at_cut = bool(before) and before[-1].data.get("state") == "walking"
    stop = next((r.t_recv - cut for r in fb_sent if r.t_recv >= cut and r.data.get("state") != "walking"), None)
    restart = next((r.t_recv - back for r in fb_sent if r.t_recv >= back and r.data.get("state") == "walking"), None)
    last_cmd = max((r.t_recv for r in cmd if r.t_recv < cut + 3.0 and r.t_recv <= back), default=None)
    # Sent before the path returned (5 ms margin: the operator's hop to the emulator), applied after.
    stale = [r for r in cmd if r.data["t"] < back - 0.005 and r.t_recv >= back]
    first_after = next((r for r in cmd if r.t_recv >= back), None)
    return {
        "cut_wall": cut,
        "back_wall": back,
        "walking_at_cut": walking_at_cut,
        "stop_latency_s": None if stop is None else round(stop, 3),
        "stop_after_last_command_s": (None if stop is None or last_cmd is None else round(cut + stop - last_cmd, 3)),
        "restart_latency_s": None if restart is None else round(restart, 3),
        "restart_after_move_s": None if after_move is None else round(after_move, 3),
        "move_after_return_s": None if move is None else round(move - back, 3),
        "first_command_after_s": None if first_after is None else round(first_after.t_recv - back, 3),
        "stale_applied": len(stale),
        "stale_oldest_age_s": round(max((r.t_recv - r.data["t"] for r in stale), default=0.0), 3),
    }
