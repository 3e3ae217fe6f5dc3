"""Benchmark: issue 19's table, the README's two hosts on an emulated internet path.

    .venv/bin/python bench/internet.py [--seconds 90] [--links split|single|single,split]
        [--only trace,loss1,loss5,outage,lan600-video,lan600-novideo,lan300-video,lan300-novideo,
                tbf600-video,tbf600-novideo,tbf300-video,lte,3g]
        [--json F] [--workdir DIR] [--seed N] [--leader-status-hz HZ]

What a field engineer would do: ``bipedtele setup two-hosts --router-name router.bt.test``
once, each of its three folders copied into the working folder of its own "host" (a network
namespace), and on each host exactly the README's command from that folder::

    bipedtele router   --config router/bipedtele.toml      # router host
    bipedtele follower --config robot/bipedtele.toml       # robot host (+ --set follower.camera_fps=0: video off)
    bipedtele leader   --config operator/bipedtele.toml --duration S   # operator host, the pilot

TLS, logins, the deny-by-default ACL and the end-to-end message key as written. The
per-packet link emulator (``bipedtele link-emu`` in ``EmulatedLink``'s middle namespace)
sits between one host and the other two, which share a bridge behind side B
(``EmulatedLink.add_host``); ``router.bt.test`` resolves to the router's address in every
namespace (``/etc/netns/NS/hosts``):

- intercontinental rows: operator | emulator | router + robot. Forward (operator -> router)
  ``trace:intercontinental:h1``, backward ``h2``; loss both directions (independent);
  the outage both directions at ``--outage-at`` s (default 40) of the emulator's origin,
  which is set just before the leader starts;
- LAN rows: robot | emulator | router + operator. No delay; the robot -> router direction
  capped (``--rate-forward``) with a 64 kB queue;
- kernel tbf rows: the same hosts, the emulator transparent, the robot's interface shaped by
  the kernel's token bucket (``tc qdisc add dev D root tbf rate R burst 16kb limit 64kb``:
  a modem's or a policer's shaper, whose burst lets a start or a probe overshoot);
- cellular rows: the same hosts, 40 ms each way, the robot -> router direction replaying a
  mahimahi capacity trace (``--rate-forward mahimahi:lte|3g``, the shipped synthetic ones)
  through a 256 kB drop-tail queue.

``--links single|split`` rewrites ``links`` in the three profiles (setup writes ``split``),
so the same bench shows the old single-connection transport beside the split one.

Per run (from the programs' logs and MCAP recordings; every namespace shares this
machine's clock, so a message's receive time minus its send stamp ``t`` is its **true**
one-way delay):

- passes (``pilot: pass N/10 done`` in the leader's log), falls;
- the follower's ``watchdog_stop`` / ``operator_stop`` events while the leader ran;
- commands dropped by the follower as too old / backlog / reordered (its last Status);
- h1 per command the follower's loop took (``cmd/recv``: receive time - ``t``; commands
  superseded between two ticks are not recorded), h2 per feedback the leader received
  (``feedback/recv``); p50/p99/max in ms;
- video frames/s received by the leader; the fraction of the leader's samples (``leader/state``)
  whose ``link`` is ``capacity-limited`` / ``lossy`` / ``lost``;
- outage rows: the robot's stop latency (path cut to the first feedback the follower sent
  in a state other than ``walking``), its restart latency (path back to the first feedback
  in ``walking``), and the commands sent before the path returned that the follower applied
  after it (count, oldest age);
- gaps of the feedback at the leader (over 1 s): the first feedback after each, split into
  (a) what was in flight when the gap began (sent before it; the leader refuses what is
  older than about 2 s) and (b) the first one sent during it, and when the first fresh one
  (at most 0.5 s old) arrived;
- cellular rows: the frame rate the trace's mean capacity allows after control, from the
  mean size of the frames the leader received (``allowance``), beside the frame rate;
- the emulator's counters (``--stats-json``);
- the paper's Table 2 of the run (``bipedtele report``: completion time of the pilot's
  passes, speed errors, delays): with ``--only trace --seconds 220`` the pilot finishes
  its 10 passes, the two-host figures to set beside the demo's.

A markdown table at the end; ``--json F`` writes every figure. Everything is torn down
(processes, namespaces, ``/etc/netns`` entries) also on Ctrl-C. This script prints
figures; it asserts nothing (tests/e2e/test_internet.py asserts).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from bipedtele.link.delaymodels import parse_delay_model
from bipedtele.link.shapers import load_mahimahi, mahimahi_stats
from bipedtele.recording.format import Record, read_records
from bipedtele.tools.netns import SIDE_A, SIDE_B, EmulatedLink, NetnsError
from bipedtele.tools.report import compute_report

REPO = Path(__file__).resolve().parent.parent
CLI = [sys.executable, "-m", "bipedtele.cli"]
ROUTER_NAME = "router.bt.test"
PORT = 7447
HOSTS = ("router", "robot", "operator")
LINK_STATES = ("capacity-limited", "lossy", "lost")
# After the uplink budget's first estimate, the queue its start's overshoot built drains in
# about the budget's drain_s (1 s); the steady state is counted from twice that [s]
ESTIMATE_SETTLE_S = 2.0


@dataclass(frozen=True)
class Condition:
    """One row: where the emulator sits and what it does."""

    name: str
    label: str
    topology: str  # "intercontinental": operator | emu | router+robot; "lan": robot | emu | router+operator
    emulator: tuple[str, ...] = ()  # impairments besides the delays
    video: bool = True
    outage: tuple[float, float] | None = None  # (at, for) [s] of the emulator's origin, both directions
    tbf: tuple[str, ...] = ()  # the kernel's tbf on the robot's interface (`tc qdisc add ... root tbf` ARGS)


def conditions(outage_at: float = 40.0) -> dict[str, Condition]:
    """The issue's rows, by name."""
    both = lambda opt, v: (f"--{opt}-forward", v, f"--{opt}-backward", v)  # noqa: E731
    out = f"at={outage_at:g}s,for=3s"
    lan = lambda rate: ("--rate-forward", rate, "--queue-forward", "64kB")  # noqa: E731
    # the kernel's token bucket as a modem or a policer has it: 16 kB burst, 64 kB queue
    tbf = lambda rate: ("rate", rate, "burst", "16kb", "limit", "64kb")  # noqa: E731

    # a cellular uplink: a mahimahi capacity trace with a deep drop-tail queue, 40 ms each way
    def cell(name: str) -> tuple[str, ...]:
        return (
            "--forward",
            "const:40ms",
            "--backward",
            "const:40ms",
            "--rate-forward",
            f"mahimahi:{name}",
            "--queue-forward",
            "256kB",
        )

    rows = [
        Condition("trace", "shipped trace", "intercontinental"),
        Condition("loss1", "+ 1 % loss", "intercontinental", both("loss", "1%")),
        Condition("loss5", "+ 5 % loss", "intercontinental", both("loss", "5%")),
        Condition("outage", "+ 3 s outage", "intercontinental", both("outage", out), outage=(outage_at, 3.0)),
        Condition("lan600-video", "LAN 600 kbit/s uplink, video on", "lan", lan("600kbit")),
        Condition("lan600-novideo", "LAN 600 kbit/s uplink, video off", "lan", lan("600kbit"), video=False),
        Condition("lan300-video", "LAN 300 kbit/s uplink, video on", "lan", lan("300kbit")),
        Condition("lan300-novideo", "LAN 300 kbit/s uplink, video off", "lan", lan("300kbit"), video=False),
        Condition("tbf600-video", "kernel tbf 600 kbit/s (16 kB burst), video on", "lan", tbf=tbf("600kbit")),
        Condition(
            "tbf600-novideo", "kernel tbf 600 kbit/s (16 kB burst), video off", "lan", tbf=tbf("600kbit"), video=False
        ),
        Condition("tbf300-video", "kernel tbf 300 kbit/s (16 kB burst), video on", "lan", tbf=tbf("300kbit")),
        Condition("lte", "LTE trace (synthetic, 1.95 Mbit/s, 4 s gap), 40 ms", "lan", cell("lte")),
        Condition("3g", "3G trace (synthetic, 0.52 Mbit/s, 9 s near zero), 40 ms", "lan", cell("3g")),
    ]
    return {c.name: c for c in rows}


# --------------------------------------------------------------------------- processes


@dataclass
class Proc:
    name: str
    popen: subprocess.Popen[bytes]
    log_path: Path

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def tail(self, n: int = 15) -> str:
        return "\n".join(self.log().splitlines()[-n:])

    def wait_log(self, pattern: str, timeout_s: float) -> None:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while not rx.search(self.log()):
            if not self.alive():
                raise RuntimeError(
                    f"{self.name} exited (rc {self.popen.returncode}) before {pattern!r}:\n{self.tail()}"
                )
            if time.monotonic() > deadline:
                raise RuntimeError(f"{self.name}: no {pattern!r} within {timeout_s:g} s:\n{self.tail()}")
            time.sleep(0.1)

    def stop(self, timeout_s: float = 10.0) -> int | None:
        if self.alive():
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.popen.pid, signal.SIGTERM)
            try:
                return self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.popen.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            return self.popen.wait(timeout=5.0)
        return None


def start(name: str, args: list[str], *, netns: str, cwd: Path, log_dir: Path) -> Proc:
    """``ip netns exec NS python -m bipedtele.cli ARGS`` in ``cwd``, output to ``log_dir/NAME.log``."""
    log_path = log_dir / f"{name}.log"
    with open(log_path, "wb") as log:
        popen = subprocess.Popen(
            ["ip", "netns", "exec", netns, *CLI, *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            cwd=cwd,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    return Proc(name, popen, log_path)


# --------------------------------------------------------------------------- setup


def setup_two_hosts(out: Path) -> dict[str, list[str]]:
    """Run ``bipedtele setup two-hosts`` once; return host -> the printed command (after ``bipedtele``)."""
    r = subprocess.run(
        [*CLI, "setup", "two-hosts", "--router-name", ROUTER_NAME, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    if r.returncode != 0:
        raise RuntimeError(f"setup two-hosts failed: {r.stderr.strip()}")
    commands = {}
    for host in HOSTS:
        m = re.search(rf"^\s*{host}:\s+bipedtele (.+)$", r.stdout, re.MULTILINE)
        if not m:
            raise RuntimeError(f"setup did not print the {host}'s command:\n{r.stdout}")
        commands[host] = m.group(1).split()
    return commands


def copy_hosts(setup_out: Path, run_dir: Path, links: str | None) -> dict[str, Path]:
    """Copy each host folder into ``run_dir/host-H/`` (modes kept); set ``links`` if given."""
    homes = {}
    for host in HOSTS:
        home = run_dir / f"host-{host}"
        home.mkdir(parents=True)
        shutil.copytree(setup_out / host, home / host)
        if links is not None:
            prof = home / host / "bipedtele.toml"
            text, n = re.subn(r'^links = "[a-z-]+"', f'links = "{links}"', prof.read_text(), flags=re.MULTILINE)
            if n != 1:
                raise RuntimeError(f"{prof}: no `links = ...` line to rewrite")
            prof.write_text(text)
        homes[host] = home
    return homes


@dataclass
class Topology:
    link: EmulatedLink
    ns: dict[str, str]  # host -> namespace
    ip: dict[str, str]
    etc: list[Path] = field(default_factory=list)

    def remove(self) -> None:
        self.link.remove()
        for d in self.etc:
            shutil.rmtree(d, ignore_errors=True)


@contextlib.contextmanager
def topology(kind: str, emulator_log: Path, tag: str | None = None) -> Iterator[Topology]:
    """The three hosts around the emulator (not started yet); torn down on exit (``tag``: 4 characters of the names)."""
    tag = tag or secrets.token_hex(2)
    n = secrets.randbelow(250) + 2
    a_ip, b_ip, c_ip = f"10.235.{n}.1", f"10.235.{n}.2", f"10.235.{n}.3"
    link = EmulatedLink([], tag=tag, a_ip=a_ip, b_ip=b_ip, log_path=emulator_log, autostart=False)
    top = Topology(link, {}, {})
    try:
        link.create()
        link.pin_neighbours()  # no ARP request crosses a lossy wire
        third = link.add_host(SIDE_B, c_ip)
        alone = "operator" if kind == "intercontinental" else "robot"
        other = "robot" if kind == "intercontinental" else "operator"
        top.ns = {alone: link.ns[SIDE_A], "router": link.ns[SIDE_B], other: third}
        top.ip = {alone: a_ip, "router": b_ip, other: c_ip}
        for ns in top.ns.values():
            d = Path("/etc/netns") / ns  # `ip netns exec` mounts d/hosts over /etc/hosts
            d.mkdir(parents=True, exist_ok=True)
            top.etc.append(d)
            (d / "hosts").write_text(f"127.0.0.1 localhost\n{top.ip['router']} {ROUTER_NAME}\n")
        yield top
    finally:
        top.remove()


# --------------------------------------------------------------------------- one run


def _ms(xs: list[float]) -> dict[str, float | None]:
    if not xs:
        return {"n": 0, "p50": None, "p99": None, "max": None}
    a = 1000.0 * np.asarray(xs)
    return {"n": len(xs), "p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def _recording(home: Path, role: str) -> Path | None:
    files = sorted((home / "runs").glob(f"{role}-*.mcap"))
    return files[-1] if files else None


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


def video_allowance(l_rec: list[Record], f_rec: list[Record], mean_bps: float, t0: float, t1: float) -> dict[str, Any]:
    """The frame rate the trace's mean capacity allows after control, from the frames actually sent.

    ``frame_bytes``: mean size of the frames the leader received (JPEG + 120 bytes of
    fields and MAC); ``control_bps``: the follower's control rate (``uplink_tx_control_bps``,
    mean of its Status over the run); allowance = (mean - control) / (8 frame_bytes).
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
    return {
        "mean_bps": round(mean_bps),
        "frame_bytes": round(fb),
        "control_bps": round(c),
        "allowed_fps": round(max(0.0, mean_bps - c) / (8.0 * fb), 2),
    }


def _cellular_allowance(cond: Condition, l_rec: list[Record], f_rec: list[Record]) -> dict[str, Any] | None:
    """A cellular row's video allowance (:func:`video_allowance` over the pilot's run); None for other rows."""
    trace = next((x.split(":", 1)[1] for x in cond.emulator if x.startswith("mahimahi:")), None)
    sent = [r.t_recv for r in l_rec if r.topic == "cmd/sent"]
    if trace is None or not sent:
        return None
    return video_allowance(l_rec, f_rec, mahimahi_stats(load_mahimahi(trace))["mean_bps"], sent[0], sent[-1])


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


def operator_sockets(ns: str, out: Path) -> dict[str, int]:
    """Count the operator host's TCP and UDP sockets to the router's port (``ss``), saved to ``out``."""
    r = subprocess.run(["ip", "netns", "exec", ns, "ss", "-tuanp"], capture_output=True, text=True, timeout=20)
    out.write_text(r.stdout + r.stderr)
    mine = [ln.split() for ln in r.stdout.splitlines() if f":{PORT} " in ln + " "]
    return {
        "tcp": sum(1 for w in mine if w and w[0] == "tcp" and w[1] == "ESTAB"),
        "udp": sum(1 for w in mine if w and w[0] == "udp"),
    }


def _summary_line(leader: Proc) -> str:
    summary = [ln for ln in leader.log().splitlines() if ln.startswith("leader:")]
    return summary[-1] if summary else leader.tail(3)


def shape_robot(top: Topology, tbf: tuple[str, ...]) -> None:
    """The kernel's tbf on the robot's egress, before the (then transparent) emulator."""
    dev = top.link.dev[SIDE_A]
    tc = ["ip", "netns", "exec", top.ns["robot"], "tc", "qdisc", "add", "dev", dev, "root", "tbf", *tbf]
    r = subprocess.run(tc, capture_output=True, text=True, timeout=20)
    if r.returncode != 0:
        raise RuntimeError(f"tc tbf: {r.stderr.strip()}")


def run_condition(
    cond: Condition,
    links: str | None,
    seconds: float,
    setup_out: Path,
    commands: dict[str, list[str]],
    run_dir: Path,
    *,
    seed: int = 1,
    startup_s: float = 5.0,
    say: Any = print,
    tag: str | None = None,
    leader_extra: tuple[str, ...] = (),
) -> dict[str, Any]:
    """One run of ``cond`` with ``links`` (None: as setup wrote); return its figures (``leader_extra``: more leader arguments)."""
    run_dir.mkdir(parents=True)
    homes = copy_hosts(setup_out, run_dir, links)
    stats = run_dir / "linkemu.json"
    procs: list[Proc] = []
    sockets: dict[str, int] | None = None
    with topology(cond.topology, run_dir / "linkemu.log", tag) as top:
        models = ("const:0ms", "const:0ms")
        if cond.topology == "intercontinental":
            models = ("trace:intercontinental:h1", "trace:intercontinental:h2")
        base = ["--forward", models[0], "--backward", models[1]]
        try:

            def go(host: str, name: str, extra: list[str]) -> Proc:
                p = start(name, [*commands[host], *extra], netns=top.ns[host], cwd=homes[host], log_dir=run_dir)
                procs.append(p)
                return p

            def emulate() -> float:
                t0 = time.time()
                top.link.start_emulator(
                    [
                        *base,
                        *cond.emulator,
                        "--t0",
                        f"{t0:.6f}",
                        "--seed",
                        str(seed),
                        "--stats-every",
                        "10",
                        "--stats-json",
                        str(stats),
                    ]
                )
                return t0

            if cond.tbf:
                shape_robot(top, cond.tbf)
            router = go("router", "router", [])
            router.wait_log(r"router: \S+ listening on", 60.0)
            t0 = emulate() if cond.topology == "lan" else None  # the robot's path crosses it
            follower = go("robot", "follower", [] if cond.video else ["--set", "follower.camera_fps=0"])
            follower.wait_log(r"follower \S+ ready", 120.0)
            if t0 is None:  # the origin of the trace and the outage: just before the leader starts
                t0 = emulate()
            leader = go("operator", "leader", ["--duration", f"{seconds:g}", *leader_extra])
            deadline = time.monotonic() + seconds + 180.0  # bounded: start-up through the path, then S
            t_ss: float | None = time.monotonic() + min(10.0, seconds / 2)
            while leader.alive() and time.monotonic() < deadline:
                if t_ss is not None and time.monotonic() > t_ss:  # which links the operator's host holds
                    t_ss, sockets = None, operator_sockets(top.ns["operator"], run_dir / "ss-operator.txt")
                if not follower.alive():
                    say(f"  follower exited early:\n{follower.tail()}")
                    break
                time.sleep(0.5)
            leader_rc = leader.stop(15.0)
            follower.stop(15.0)
            router.stop(10.0)
        finally:
            for p in procs:
                p.stop(5.0)
            top.link.stop_emulator()
    res: dict[str, Any] = {
        "condition": cond.name,
        "label": cond.label,
        "links": links or "as written",
        "leader_rc": leader_rc,
        "run_dir": str(run_dir),
        "operator_sockets": sockets,
        "leader_summary": _summary_line(leader),
    }
    l_path, f_path = _recording(homes["operator"], "leader"), _recording(homes["robot"], "follower")
    if l_path is None or f_path is None:
        res["error"] = f"no recording (leader {l_path}, follower {f_path}); leader log:\n{leader.tail()}"
        return res
    # forward is operator -> router (h1) across the ocean, robot -> router (h2) on the LAN
    h_models = models if cond.topology == "intercontinental" else models[::-1]
    outage = (t0 + cond.outage[0], t0 + cond.outage[0] + cond.outage[1]) if cond.outage else None
    l_rec, f_rec = list(read_records(l_path)), list(read_records(f_path))
    res.update(analyse(l_rec, f_rec, leader.log(), outage_wall=outage, startup_s=startup_s, emulated=(*h_models, t0)))
    # Table 2 of the run (`bipedtele report`): completion time and speed errors, as the demo prints
    res["table2"] = compute_report(l_rec, f_rec)
    res["allowance"] = _cellular_allowance(cond, l_rec, f_rec)
    try:
        res["linkemu"] = json.loads(stats.read_text())
    except (OSError, ValueError):
        res["linkemu"] = None
    res["emulator_t0"] = t0
    (run_dir / "result.json").write_text(json.dumps(res, indent=2, default=str) + "\n")
    return res


# --------------------------------------------------------------------------- printing


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


# --------------------------------------------------------------------------- main


def _leader_extra(p: argparse.ArgumentParser, hz: float | None) -> tuple[str, ...]:
    """The leader's extra arguments for ``--leader-status-hz`` (exits 2 naming the range when out of it)."""
    if hz is not None and not (math.isfinite(hz) and 0.1 <= hz <= 50.0):
        p.error(f"--leader-status-hz {hz!r}: allowed: 0.1 to 50")
    return () if hz is None else ("--set", f"leader.status_rate_hz={hz:g}")


def main(argv: list[str] | None = None) -> int:
    all_conds = conditions()
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--seconds", type=float, default=90.0, help="the pilot's run per condition (leader --duration)")
    p.add_argument("--only", default=",".join(all_conds), help=f"conditions, comma-separated: {','.join(all_conds)}")
    p.add_argument(
        "--links", default="split", help="single, split, or both as 'single,split' (profiles' [network] links)"
    )
    p.add_argument(
        "--outage-at", type=float, default=40.0, help="outage start [s] of the emulator's origin (leader start)"
    )
    p.add_argument("--seed", type=int, default=1, help="the emulator's seed")
    p.add_argument("--leader-status-hz", type=float, default=None, help="[leader] status_rate_hz (default: setup's)")
    p.add_argument("--tag", default="", help="prefix of the namespaces' 4-character tag (random hex after it)")
    p.add_argument("--json", default=None, metavar="F", help="write every figure to F")
    p.add_argument(
        "--workdir", default=None, metavar="DIR", help="keep logs and recordings here (default: a temp dir, removed)"
    )
    args = p.parse_args(argv)
    conds = conditions(args.outage_at)
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    bad = [n for n in names if n not in conds]
    links = [x.strip() for x in args.links.split(",") if x.strip()]
    if bad or not names or any(x not in ("single", "split", "split-tcp") for x in links):
        p.error(f"--only {args.only!r} / --links {args.links!r}: allowed: {', '.join(conds)}; single, split, split-tcp")
    if os.geteuid() != 0 or shutil.which("ip") is None:
        sys.stderr.write("bench/internet.py: needs root and iproute2 (network namespaces, raw sockets)\n")
        return 2

    def on_term(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    for sig in (signal.SIGTERM, signal.SIGINT):  # SIGINT too: a background job may have it ignored
        signal.signal(sig, on_term)
    leader_extra = _leader_extra(p, args.leader_status_hz)
    work = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="bt-internet-"))
    work.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    try:
        setup_out = work / f"setup-{secrets.token_hex(2)}"
        commands = setup_two_hosts(setup_out)
        print(
            f"setup two-hosts: {setup_out}; commands: "
            + "; ".join(f"{h}: bipedtele {' '.join(c)}" for h, c in commands.items())
        )
        for name in names:
            for lk in links:
                cond = conds[name]
                t_start = time.monotonic()
                print(f"--- {cond.label} [{lk}] ({args.seconds:g} s) ...", flush=True)
                try:
                    r = run_condition(
                        cond,
                        lk,
                        args.seconds,
                        setup_out,
                        commands,
                        work / f"{name}-{lk}-{secrets.token_hex(2)}",
                        seed=args.seed,
                        tag=args.tag + secrets.token_hex(2)[: 4 - len(args.tag)],
                        leader_extra=leader_extra,
                    )
                except (RuntimeError, NetnsError) as exc:
                    r = {"condition": name, "label": cond.label, "links": lk, "error": str(exc)}
                r["wall_s"] = round(time.monotonic() - t_start, 1)
                rows.append(r)
                print(row_line(r))
                print("  " + emu_line(r.get("linkemu")))
                if "leader_summary" in r:
                    print("  " + r["leader_summary"])
                sys.stdout.flush()
    except KeyboardInterrupt:
        print("interrupted: torn down", file=sys.stderr)
    finally:
        if rows:
            print()
            print(table(rows))
        if args.json:
            Path(args.json).write_text(
                json.dumps({"seconds": args.seconds, "rows": rows}, indent=2, default=str) + "\n"
            )
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
