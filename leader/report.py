"""What the leader program reports: the link's figures in its Status and samples, its result line.

:func:`link_counters` puts the link's figures (:class:`~bipedtele.leader.linkquality.LinkReport`)
into the leader's Status for the follower to adapt its rates (docs/follower.md, Capacity);
:func:`fill_link` sets a telemetry sample's link fields; :func:`summary` is the program's
one-line result (docs/leader.md).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from bipedtele.leader.linkquality import LinkQuality, LinkReport
from bipedtele.leader.loop import LeaderLoop
from bipedtele.leader.operator import Operator
from bipedtele.leader.reach import KEY_MISMATCH, CommandReach
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import MAX_SEQ
from bipedtele.telemetry import LeaderSample

__all__ = ["fill_link", "link_counters", "summary"]


#: Largest value of a Status counter.
_COUNTER_MAX = MAX_SEQ


def _counter(value: float) -> int:
    """Return ``value`` as a Status counter: rounded, clamped to ``0 .. MAX_SEQ``."""
    if not math.isfinite(value):
        return _COUNTER_MAX if value > 0 else 0
    return min(max(round(value), 0), _COUNTER_MAX)


def link_counters(rep: LinkReport) -> dict[str, int]:
    """Return the leader's link figures as Status counters (the follower adapts to them).

    ``rx_bps`` (payload received over the last 2 s [bit/s]), ``fb_loss_ppm`` (feedback
    loss over the last 2 s [ppm]), ``fb_age_ms`` (age of the newest feedback now [ms]) and
    ``uplink_t_echo_us`` (the newest follower Status's send stamp, echoed [us]);
    a figure that is not known yet is left out.
    """
    out: dict[str, int] = {}
    if rep.rx_bps is not None:
        out["rx_bps"] = _counter(rep.rx_bps)
    if rep.loss_ppm is not None:
        out["fb_loss_ppm"] = _counter(rep.loss_ppm)
    if rep.fb_age_s is not None:
        out["fb_age_ms"] = _counter(1000.0 * rep.fb_age_s)
    if rep.status_echo_us is not None:  # the newest follower Status's stamp: its acknowledgement
        out["uplink_t_echo_us"] = _counter(rep.status_echo_us)
    return out


def fill_link(sample: LeaderSample, rep: LinkReport, counters: dict[str, int]) -> None:
    """Set the sample's link fields from a link report and the follower's Status counters.

    A follower counter that is missing leaves its field unset (unknown).
    """
    sample.link = rep.state
    sample.link_lost_s = rep.lost_s
    sample.fb_age_ms = None if rep.fb_age_s is None else 1000.0 * rep.fb_age_s
    sample.loss_pct = None if rep.loss_ppm is None else rep.loss_ppm / 1e4
    sample.rx_kbps = None if rep.rx_bps is None else rep.rx_bps / 1000.0
    sample.video_fps = rep.video_fps
    sample.video_bytes = rep.video_bytes
    sample.video_width = rep.video_width
    sample.video_height = rep.video_height
    sample.fb_arrived = rep.fb_arrived
    sample.fb_too_old = rep.fb_too_old
    tx = counters.get("tx_bps")
    sample.tx_kbps = None if tx is None else tx / 1000.0
    sample.video_quality = counters.get("video_quality")
    cap = counters.get("capacity_limited")
    sample.capacity_limited = None if cap is None else cap == 1


def summary(
    loop: LeaderLoop,
    op_name: str,
    operator: Operator | None,
    elapsed: float,
    drops: DropCounter,
    record: Path | None,
    rt: bool,
    reach: CommandReach | None = None,
    link: LinkQuality | None = None,
) -> str:
    """Return the program's one-line result.

    ``N feedback received`` counts the feedback that arrived (accepted by the receiver:
    MAC, decoding, send-time checks, gate), then in brackets how many the loop took (it
    takes the newest at each 1 kHz tick) and how many were refused as too old.
    """
    parts = [f"leader: operator {op_name}"]
    prog = operator.progress() if operator is not None else {}
    if "passes_done" in prog:
        parts.append(f"{prog['passes_done']}/{prog['passes']} passes")
    parts.append("done" if loop.done else "stopped")
    parts.append(f"{elapsed:.1f} s")
    if link is not None:
        received = (
            f"{link.fb_arrived} feedback received ({loop.feedback_count} used by the loop, {link.fb_too_old} too old)"
        )
    else:
        received = f"{loop.feedback_count} feedback received"
    parts.append(f"{loop.seq} commands sent, {received}, {drops.total} dropped")
    if loop.blind.stops:
        parts.append(f"{loop.blind.stops} blind stops (no fresh feedback for {loop.blind.stop_s:g} s)")
    if loop.h1 is not None and loop.h2 is not None:
        parts.append(f"last delay h1+h2 {1000 * (loop.h1 + loop.h2):.0f} ms")
    parts.append(f"max |f_m| now {float(np.abs(loop.force).max()):.2f} N")
    if rt:
        st = loop.period_stats.summary(loop.dt)
        if "rate_hz" in st:
            parts.append(f"loop {st['rate_hz']:.1f} Hz, p99 period error {1000 * st['err_p99_s']:.2f} ms")
    if record is not None:
        parts.append(f"recording {record}")
    if reach is not None and reach.never_reached and reach.key_reason is not None:
        parts.append(f"NO COMMAND REACHED THE ROBOT ({KEY_MISMATCH} {reach.key_line})")
    elif reach is not None and reach.never_reached:
        parts.append("NO COMMAND REACHED THE ROBOT (refused by the router's ACL? log in as a leader user)")
    elif reach is not None and reach.never_acknowledged:
        parts.append(
            "NO COMMAND ACKNOWLEDGED BY THE ROBOT (link lost: nothing heard from the follower; path or router down?)"
        )
    return ", ".join(parts)
