"""The internet bench's printing: one line per row (:func:`row_line`), the emulator's counters, the table."""

from __future__ import annotations

from typing import Any


def _d(m: dict[str, Any]) -> str:
    if not m or m.get("p50") is None:
        return "-"
    return f"{m['p50']:.0f}/{m['p99']:.0f}/{m['max']:.0f}"


def _p99(m: dict[str, Any] | None) -> str:
    return "-" if not m or m.get("p99") is None else f"{m['p99']:.0f}"


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f}"


def emu_line(e: dict[str, Any] | None) -> str:
    if not e:
        return "emulator: no counters"
    parts = []
    for d in ("forward", "backward"):
        c = e.get(d, {})
        drop = c.get("dropped", {})
        parts.append(
            f"{d} {c.get('forwarded', '?')} fr, drop loss/queue/outage {drop.get('loss', 0)}/{drop.get('queue', 0)}/"
            f"{drop.get('outage', 0)}, queue max {c.get('queue_bytes_max', 0)} B"
        )
    return "emulator: " + "; ".join(parts)


def _f(x: float | None, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def row_line(r: dict[str, Any]) -> str:
    if "error" in r:
        return f"{r['label']} [{r['links']}]: ERROR {r['error']}"
    lf = r["link_fraction"]
    s = (
        f"{r['label']} [{r['links']}]: {r['passes']} passes in {r['run_s']} s, dist {r['distance_m']} m, "
        f"watchdog {r['watchdog_stops']}, operator stops {r['operator_stops']}, falls {r['falls']}, "
        f"too old {r['cmd_too_old']}, backlog {r['cmd_backlog']}, h1 {_d(r['h1_ms'])} ms, h2 {_d(r['h2_ms'])} ms, "
        f"excess over the emulator p99 h1/h2 {_p99(r.get('h1_excess_ms'))}/{_p99(r.get('h2_excess_ms'))} ms, "
        f"video {r['video_fps']:.1f} fps, link cap/lossy/lost {_pct(lf['capacity-limited'])}/{_pct(lf['lossy'])}/"
        f"{_pct(lf['lost'])} %"
    )
    t2 = r.get("table2") or {}
    if t2.get("completion_s") is not None:
        s += (
            f"; Table 2: {t2['passes']} passes, completion {t2['completion_s']:.1f} s, speed errors "
            f"{_f(t2['forward_error_cm_s'])} cm/s, {_f(t2['turn_error_deg_s'])} deg/s, "
            f"delay min/mean/max {_f(t2['min_delay_ms'], 0)}/{_f(t2['mean_delay_ms'], 0)}/{_f(t2['max_delay_ms'], 0)} ms"
        )
    g = r.get("gap") or {}
    if g.get("gaps") or g.get("blind_stops") or g.get("acl_lines"):
        s += (
            f"; gaps {[(x['length_s'], x['first_age_s'], x['fresh_after_s']) for x in g['gaps']]} (length, first "
            f"feedback's age, fresh after s); split {[_split(x) for x in g['gaps']]}, blind stops {g['blind_stops']} (stopped {g['stop_after_newest_fb_s']} s "
            f"after the newest feedback's send, walking {g['walk_after_handle_s']} s after the move), "
            f"ACL lines {g['acl_lines']}, stall lines {g['stall_lines']}"
        )
    al = r.get("allowance")
    if al and al.get("allowed_fps"):
        s += (
            f"; video allowance {al['allowed_fps']} fps (mean {al['mean_bps'] / 1e6:.2f} Mbit/s, control "
            f"{al['control_bps'] / 1e3:.0f} kbit/s, frames {al['frame_bytes']} B): {r['video_fps'] / al['allowed_fps']:.0%}"
        )
        if al.get("within_fps"):
            s += f"; of min(allowance, the {al['most_fps']:g} fps configured): {r['video_fps'] / al['within_fps']:.0%}"
    if "outage" in r:
        o = r["outage"]
        s += (
            f"; outage at +{o['cut_after_first_command_s']} s: stop {o['stop_latency_s']} s "
            f"({o['stop_after_last_command_s']} s after the last command), restart {o['restart_latency_s']} s, "
            f"stale applied {o['stale_applied']}"
        )
    return s


def _split(x: dict[str, Any]) -> str:
    """One gap's split: (a) in flight when it began, (b) sent in it."""
    return (
        f"(a) {x.get('inflight_sent')} fb in flight ({x.get('inflight_bytes')} B), {x.get('inflight_n')} taken after "
        f"it, up to {x.get('inflight_age_s')} s old; "
        f"(b) first {x.get('first_new_age_s')} s old at +{x.get('first_new_after_s')} s, of what was sent 0.5 s "
        f"into it {x.get('first_late_age_s')} s old"
    )


def table(rows: list[dict[str, Any]]) -> str:
    head = (
        "| condition | links | passes | watchdog / operator stops | too old / backlog | h1 ms p50/p99/max | "
        "h2 ms p50/p99/max | video fps | capacity-limited / lossy / lost % | outage stop / restart s, stale |\n"
        "|---|---|---|---|---|---|---|---|---|---|"
    )
    out = [head]
    for r in rows:
        if "error" in r:
            out.append(f"| {r['label']} | {r['links']} | error | | | | | | | |")
            continue
        lf = r["link_fraction"]
        o = r.get("outage")
        ot = "-" if o is None else f"{o['stop_latency_s']} / {o['restart_latency_s']}, {o['stale_applied']}"
        out.append(
            f"| {r['label']} | {r['links']} | {r['passes']} | {r['watchdog_stops']} / {r['operator_stops']} | "
            f"{r['cmd_too_old']} / {r['cmd_backlog']} | {_d(r['h1_ms'])} | {_d(r['h2_ms'])} | {r['video_fps']:.1f} | "
            f"{_pct(lf['capacity-limited'])} / {_pct(lf['lossy'])} / {_pct(lf['lost'])} | {ot} |"
        )
    return "\n".join(out)
