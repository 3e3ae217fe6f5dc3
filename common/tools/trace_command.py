"""``bipedtele trace``: a run's recording turned into a trace of its path, to replay it.

From a leader recording (``leader-*.mcap``; optionally the follower's of the same run):

- **h2**: each feedback the leader received, its receive time minus its send stamp
  (``feedback/recv``; a true one-way delay with ``synced`` clocks, in ``ntp`` mode the
  leader's converted one);
- **h1**: each command the follower took, the same way (``cmd/recv`` of the follower's
  recording), or else the follower's own estimate carried in each feedback (``h1_s``);
- **loss**: the feedback's sequence gaps over the last second [%];
- **delivered rate**: what the leader received, the ``rx_kbps`` of its samples
  (``leader/state``) [kbit/s].

Each is taken per ``--step`` (50 ms) of send time, the median of the delays sent in that
step (a step without one holds the step before), and written as CSV
``t_s,h1_ms,h2_ms,loss_pct,rx_kbps`` from t = 0 at the first feedback: the format of
the shipped delay trace, so ``trace:FILE.csv:h1`` and ``trace:FILE.csv:h2`` replay the
path in the delay proxy, ``bipedtele link-emu`` and ``bipedtele netem`` (which read the
first three columns). ``--mahimahi FILE`` also writes the delivered rate as a mahimahi
capacity trace (``link-emu --rate-forward mahimahi:FILE``: a lower bound of the uplink's
capacity, what it carried). Loss is written for reading; replay it with ``--loss``.
"""

from __future__ import annotations

import argparse
import bisect
import itertools
import logging
import math
import statistics
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.link.shapers import MTU
from bipedtele.recording.format import Record, read_records

__all__ = ["add_trace_parser", "path_trace", "write_mahimahi"]

LOG = logging.getLogger("bipedtele.tools.trace")


def _binned(samples: Iterable[tuple[float, float]], t0: float, step: float, n: int) -> list[float | None]:
    """Median of the ``(send time, value)`` samples per step from ``t0``; None where a step has none."""
    bins: list[list[float]] = [[] for _ in range(n)]
    for t, v in samples:
        k = int((t - t0) / step)
        if 0 <= k < n and math.isfinite(v):
            bins[k].append(v)
    return [statistics.median(b) if b else None for b in bins]


def _held(values: list[float | None], default: float = 0.0) -> list[float]:
    """Fill each None with the value before it (the first ones with the first value known)."""
    first = next((v for v in values if v is not None), default)
    out, last = [], first
    for v in values:
        last = v if v is not None else last
        out.append(last)
    return out


def _loss(fb: list[Record], times: list[float]) -> list[float]:
    """Feedback lost over the last second at each time [%] (sequence gaps within one session)."""
    events: list[tuple[float, int]] = []  # (receive time, lost before it)
    last: tuple[int, int] | None = None
    for r in fb:
        sid, seq = int(r.data.get("sid", 0)), int(r.data.get("seq", 0))
        lost = seq - last[1] - 1 if last is not None and last[0] == sid and seq > last[1] + 1 else 0
        last = (sid, seq) if last is None or last[0] != sid or seq > last[1] else last
        events.append((r.t_recv, lost))
    ev_t = [t for t, _ in events]
    out = []
    for t in times:
        a, b = bisect.bisect_left(ev_t, t - 1.0), bisect.bisect_right(ev_t, t)
        got = b - a
        lost = sum(x for _, x in events[a:b])
        out.append(100.0 * lost / (got + lost) if got + lost else 0.0)
    return out


def path_trace(
    leader: list[Record], follower: list[Record] | None = None, step_s: float = 0.05
) -> list[dict[str, float]]:
    """Return the path's trace rows (``t_s``, ``h1_ms``, ``h2_ms``, ``loss_pct``, ``rx_kbps``; module docstring).

    Raises
    ------
    ConfigError
        The recording holds fewer than two feedback received (one line).
    """
    if not (math.isfinite(step_s) and 0.001 <= step_s <= 10.0):
        raise ConfigError(f"--step {step_s!r}: allowed: 0.001 to 10 s")
    fb = sorted((r for r in leader if r.topic == "feedback/recv" and "t" in r.data), key=lambda r: r.t_recv)
    if len(fb) < 2:
        raise ConfigError(
            "the recording holds fewer than two feedback received; allowed: a leader recording (leader-*.mcap)"
        )
    t0 = min(float(r.data["t"]) for r in fb)
    n = max(2, math.ceil((max(float(r.data["t"]) for r in fb) - t0) / step_s) + 1)
    h2 = _held(_binned(((float(r.data["t"]), r.t_recv - float(r.data["t"])) for r in fb), t0, step_s, n))
    cmds = [r for r in follower or [] if r.topic == "cmd/recv" and "t" in r.data]
    if cmds:
        h1_src = ((float(r.data["t"]), r.t_recv - float(r.data["t"])) for r in cmds)
    else:  # the follower's estimate, as it sent it
        h1_src = ((float(r.data["t"]), float(r.data.get("h1_s") or math.nan)) for r in fb)
    h1 = _held(_binned(h1_src, t0, step_s, n))
    times = [t0 + k * step_s for k in range(n)]
    loss = _loss(fb, times)
    states = sorted((r.t_recv, r.data.get("rx_kbps")) for r in leader if r.topic == "leader/state")
    st_t = [t for t, _ in states]
    rx = []
    for t in times:
        i = bisect.bisect_right(st_t, t) - 1
        v = states[i][1] if i >= 0 else None
        rx.append(float(v) if isinstance(v, (int, float)) and math.isfinite(v) else 0.0)
    return [
        {
            "t_s": k * step_s,
            "h1_ms": 1000.0 * max(0.0, h1[k]),
            "h2_ms": 1000.0 * max(0.0, h2[k]),
            "loss_pct": loss[k],
            "rx_kbps": rx[k],
        }
        for k in range(n)
    ]


def write_csv(rows: list[dict[str, float]], path: Path) -> None:
    """Write the rows as ``t_s,h1_ms,h2_ms,loss_pct,rx_kbps``."""
    lines = ["t_s,h1_ms,h2_ms,loss_pct,rx_kbps"]
    lines += [f"{r['t_s']:.3f},{r['h1_ms']:.2f},{r['h2_ms']:.2f},{r['loss_pct']:.2f},{r['rx_kbps']:.1f}" for r in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_mahimahi(rows: list[dict[str, float]], path: Path) -> int:
    """Write the delivered rate as mahimahi delivery opportunities; return how many."""
    out: list[int] = []
    carry = 0.0
    for a, b in itertools.pairwise(rows):
        dt = b["t_s"] - a["t_s"]
        carry += 1000.0 * a["rx_kbps"] * dt / (8.0 * MTU)
        k = int(carry)
        carry -= k
        out.extend(round(1000.0 * a["t_s"] + 1000.0 * dt * (j + 0.5) / k) for j in range(k))
    out.append(max(1, round(1000.0 * rows[-1]["t_s"])))  # the period
    path.write_text("".join(f"{ms}\n" for ms in out), encoding="utf-8")
    return len(out) - 1


def _read(path: str, what: str) -> list[Record]:
    try:
        return list(read_records(Path(path)))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{what} {path!r}: cannot read it as a recording ({exc}); allowed: an .mcap file") from None


def run(args: argparse.Namespace) -> int:
    """``bipedtele trace``: write the path's trace of a recording."""
    leader = _read(args.recording, "RECORDING")
    follower = _read(args.follower, "--follower") if args.follower else None
    rows = path_trace(leader, follower, args.step)
    out = Path(args.out)
    write_csv(rows, out)
    h1 = sorted(r["h1_ms"] for r in rows)
    h2 = sorted(r["h2_ms"] for r in rows)
    sys.stdout.write(
        f"trace: {out}: {len(rows)} rows over {rows[-1]['t_s']:.1f} s; h1 median {h1[len(h1) // 2]:.0f} ms, "
        f"h2 median {h2[len(h2) // 2]:.0f} ms; replay: trace:{out}:h1 / trace:{out}:h2\n"
    )
    if args.mahimahi:
        n = write_mahimahi(rows, Path(args.mahimahi))
        sys.stdout.write(
            f"trace: {args.mahimahi}: {n} delivery opportunities (link-emu --rate-forward mahimahi:FILE)\n"
        )
    return 0


def add_trace_parser(sub: Any) -> None:
    """Register ``bipedtele trace``."""
    p = sub.add_parser(
        "trace",
        help="turn a run's recording into a trace of its path (delays, loss, rate)",
        description="Turn a run's recording into a trace of its path that the delay proxy, "
        "link-emu and netem replay (trace:FILE.csv:h1|h2).",
    )
    p.add_argument("recording", metavar="RECORDING", help="the leader's recording (leader-*.mcap)")
    p.add_argument("--follower", metavar="FILE", help="the follower's recording of the same run (true h1)")
    p.add_argument("--out", required=True, metavar="FILE", help="the trace to write (CSV t_s,h1_ms,h2_ms,...)")
    p.add_argument("--step", type=float, default=0.05, metavar="S", help="row spacing [s] (default 0.05)")
    p.add_argument("--mahimahi", metavar="FILE", help="also write the delivered rate as a mahimahi trace")
    p.set_defaults(func=run)
