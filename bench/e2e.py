"""Benchmark: the whole system's overhead and video latency, on this machine.

    .venv/bin/python bench/e2e.py [--seconds 15] [--rates 50,240] [--no-browser]

Processes, as in ``bipedtele demo``: router, delay proxy (``const:0ms`` both ways), the sim
follower (client of the router), the leader (scripted, client through the proxy).

1. **Stack overhead.** For every Command the follower echoed (``Feedback.cmd_seq``): the
   time from its send on the leader to the receipt of the first Feedback carrying its seq,
   from the two programs' MCAP recordings (one clock). Side by side in the same run, a bare
   zenoh-python ping-pong with payloads of the same sizes (a Command out, a Feedback back),
   same QoS, over the same path (pinger through the proxy, echo a client of the router),
   at 50 Hz. Printed: p50/p99 of command-to-feedback, of its parts (forward transport,
   wait for the follower's next control tick, the tick until the feedback is published,
   backward transport) and of the bare round trip, and overhead = ours - bare (p50, p99).
   The wait for the next tick is the follower's control period at work; it is run at each
   rate of ``--rates`` (feedback at the same rate) to show what dominates. Only the last
   command before a tick is echoed, so for echoed commands that wait is at most the
   command period (10 ms at 100 Hz) as well as the control period; the row "every command"
   (time to the first feedback reflecting that command or a newer one) has no such bias.
2. **Video glass-to-glass** at QVGA (head camera, 10 fps): ``t_capture`` (set when the
   pybullet render returns) to receipt in the leader program (JPEG encode + Zenoh), from
   the leader's recording; with headless chromium (playwright, ``/usr/bin/chromium``) on the
   cockpit page, to the browser's ``load`` event of the image (decoded) and to the next
   animation frame after it (painted). The pybullet render itself is timed separately.
   The cockpit pushes frames once per telemetry period (``leader.cockpit_rate_hz``,
   20 Hz by default), so the browser figures are given at 20 and 100 Hz.

Since issue 13 a command that arrives between two follower ticks is applied at once
(event-driven pickup: the receiver wakes the loop, which re-runs the period's update and
publishes the acknowledging feedback), so "wait for the next control tick" is the wake-up
latency. Measured on the 2-CPU dev machine, 10 s at 50 Hz (``--rates 50 --no-video``):
overhead p50 9.69 ms before, 1.34 ms after in a first copy (every command -> feedback of
it or newer: 15.8 ms -> 2.5 ms p50); in the shared tree once recording worked again, three
runs: overhead p50 0.69 / 0.84 / 0.65 ms, p99 1.71 / 1.04 / 1.23 ms (command -> first
feedback p50 1.95 / 1.88 / 1.75 ms against a bare round trip of 1.25 / 1.04 / 1.10 ms;
every command is now echoed, so the "every command" row equals the first).

Goals (issues 6, 13): overhead p50 < 2 ms; video p50 < 60 ms. Figures are what they are.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import secrets
import shutil
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.leader.app import COCKPIT_TOKEN_ENV
from bipedtele.link.messages import Command, Feedback, encode
from bipedtele.link.zenohsession import open_session
from bipedtele.recording.format import read_records

CLI = [sys.executable, "-m", "bipedtele.cli"]
PING, PONG = "benche2e/ping", "benche2e/pong"
QOS: dict[str, Any] = {
    "express": True,
    "priority": zenoh.Priority.REAL_TIME,
    "congestion_control": zenoh.CongestionControl.DROP,
}
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def pct(xs: list[float], q: float) -> float:
    ys = sorted(xs)
    return ys[min(len(ys) - 1, int(q * len(ys)))] if ys else float("nan")


def row(name: str, xs: list[float]) -> str:
    ms = [1e3 * x for x in xs]
    if not ms:
        return f"  {name:<40} (no samples)"
    return f"  {name:<40} n={len(ms):5d}  p50 {pct(ms, 0.5):7.2f} ms  p99 {pct(ms, 0.99):7.2f} ms  mean {statistics.fmean(ms):7.2f} ms"


def client_args(ep: str) -> list[str]:
    return ["--set", 'network.mode="client"', "--set", f'network.connect=["{ep}"]', "--set", "network.listen=[]"]


# --------------------------------------------------------------------------- processes


class Stack:
    """Router, 0 ms delay proxy, follower and leader processes in one folder."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.router_ep = f"tcp/127.0.0.1:{free_port()}"
        self.proxy_port = free_port()
        self.proxy_ep = f"tcp/127.0.0.1:{self.proxy_port}"

    def start(self, name: str, argv: list[str], ready: str | None = None, timeout_s: float = 60.0) -> None:
        log = self.folder / f"{name}.log"
        with open(log, "wb") as f:
            self.procs[name] = subprocess.Popen(
                argv,
                stdout=f,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                cwd=self.folder,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
        deadline = time.monotonic() + timeout_s
        while ready is not None and ready not in log.read_text(errors="replace"):
            if self.procs[name].poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"{name} did not start:\n{log.read_text(errors='replace')[-3000:]}")
            time.sleep(0.05)

    def base(self) -> None:
        self.start("router", [*CLI, "router", "--listen", self.router_ep], "listening on")
        self.start(
            "proxy",
            [
                *CLI,
                "delay-proxy",
                "--listen",
                f"127.0.0.1:{self.proxy_port}",
                "--target",
                self.router_ep.removeprefix("tcp/"),
                "--forward",
                "const:0ms",
                "--backward",
                "const:0ms",
            ],
        )
        time.sleep(0.5)

    def stop(self, name: str, timeout_s: float = 15.0) -> None:
        p = self.procs[name]
        if p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()

    def close(self) -> None:
        for name in reversed(list(self.procs)):
            self.stop(name)


@contextlib.contextmanager
def stack(keep: bool) -> Iterator[Stack]:
    folder = Path(tempfile.mkdtemp(prefix="bench-e2e-"))
    s = Stack(folder)
    try:
        s.base()
        yield s
    finally:
        s.close()
        if keep:
            print(f"  (logs and recordings kept in {folder})")
        else:
            shutil.rmtree(folder, ignore_errors=True)


# --------------------------------------------------------------------------- bare ping-pong


def echo_main(ep: str, fb_size: int, seconds: float) -> None:
    """Bare echo (a client of the router, like the follower): answers pings with pongs of
    the Feedback's size."""
    with open_session(NetworkConfig(mode="client", connect=[ep])) as s:
        pong = s.declare_publisher(PONG, **QOS)
        pad = b"\0" * (fb_size - 8)
        sub = s.declare_subscriber(PING, lambda sample: pong.put(sample.payload.to_bytes()[:8] + pad))
        print("ready", flush=True)
        time.sleep(seconds)
        sub.undeclare()
        pong.undeclare()


def bare_pingpong(ep: str, cmd_size: int, rate: float, stop: threading.Event, out: list[float]) -> None:
    """Pinger through ``ep`` (the proxy, like the leader) at ``rate`` until ``stop``."""
    sent: dict[int, float] = {}

    def got(sample: zenoh.Sample) -> None:
        t = time.time()
        t0 = sent.pop(struct.unpack_from("<Q", sample.payload.to_bytes())[0], None)
        if t0 is not None:
            out.append(t - t0)

    with open_session(NetworkConfig(mode="client", connect=[ep])) as s:
        pub = s.declare_publisher(PING, **QOS)
        sub = s.declare_subscriber(PONG, got)
        time.sleep(0.5)
        pad, i, t_next = b"\0" * (cmd_size - 8), 0, time.monotonic()
        while not stop.is_set():
            i += 1
            sent[i] = time.time()
            pub.put(struct.pack("<Q", i) + pad)
            t_next += 1.0 / rate
            time.sleep(max(0.0, t_next - time.monotonic()))
        time.sleep(0.3)
        sub.undeclare()
        pub.undeclare()


def message_sizes() -> tuple[int, int]:
    """Encoded sizes [bytes] of a typical Command and Feedback."""
    t = time.time()
    cmd = Command(
        sid=123456789,
        seq=123456,
        t=t,
        ref=[5.0, 0.1],
        x_m=[0.01, 0.001],
        dx_m=[0.001, 0.0],
        h2_s=0.004,
        alpha_m=[2.5, 1.2],
    )
    fb = Feedback(
        sid=123456789,
        seq=123456,
        t=t,
        z_e=[4.9, 0.1],
        z_r=[4.8, 0.1],
        eta=[5.1, 0.2],
        ref=[5.0, 0.1],
        pose=[1.2, 0.01, 0.02],
        sonar=[2.5, 2.5],
        f_v=[0.0, 0.0],
        h1_s=0.002,
        s_e=[1.0, 1.0],
        s_r=[0.8, 0.6],
        T=0.8,
        eps=0.1,
        state="walking",
        cmd_seq=123456,
    )
    return len(encode(cmd)), len(encode(fb))


# --------------------------------------------------------------------------- 1. overhead


def _overhead_run(
    st: Stack, rate_hz: float, seconds: float, sizes: tuple[int, int]
) -> tuple[list[Any], list[Any], list[float]]:
    """Echo, follower and a walking leader on ``st``'s stack; the recordings' records and the bare ping-pong's round trips."""
    cmd_size, fb_size = sizes
    f_rec, l_rec = st.folder / "follower.mcap", st.folder / "leader.mcap"
    echo = ["--echo", st.router_ep, "--fb-size", str(fb_size), "--seconds", str(seconds + 120)]
    st.start("echo", [sys.executable, __file__, *echo], "ready")
    rates = ["--set", f"follower.control_rate_hz={rate_hz:g}", "--set", f"follower.feedback_rate_hz={rate_hz:g}"]
    follower = [
        "follower",
        *client_args(st.router_ep),
        "--set",
        "follower.camera_fps=0",
        *rates,
        "--record",
        str(f_rec),
    ]
    st.start("follower", [*CLI, *follower], "ready")
    stop = threading.Event()
    bare: list[float] = []
    pinger = threading.Thread(target=bare_pingpong, args=(st.proxy_ep, cmd_size, 50.0, stop, bare))
    pinger.start()
    try:
        script = [
            "--operator",
            "scripted",
            "--set",
            "leader.script=[[0, 5, 0], [600, 5, 0]]",
            "--set",
            "leader.cockpit=false",
        ]
        leader = ["leader", *client_args(st.proxy_ep), *script, "--duration", f"{seconds:g}", "--record", str(l_rec)]
        st.start("leader", [*CLI, *leader], "leader ready")
        st.procs["leader"].wait(timeout=seconds + 60)
    finally:
        stop.set()
        pinger.join()
    st.stop("follower")
    return list(read_records(l_rec)), list(read_records(f_rec)), bare


def overhead(rate_hz: float, seconds: float, keep: bool) -> dict[str, list[float]]:
    """Command to feedback through a real router and the delay proxy at 0 ms: the overhead's parts [s]."""
    cmd_size, fb_size = message_sizes()
    with stack(keep) as st:
        leader_recs, follower_recs, bare = _overhead_run(st, rate_hz, seconds, (cmd_size, fb_size))
    return _overhead_parts(leader_recs, follower_recs, bare, (cmd_size, fb_size))


def _overhead_parts(
    leader_recs: list[Any], follower_recs: list[Any], bare: list[float], sizes: tuple[int, int]
) -> dict[str, list[float]]:
    """Each command's path split into its parts, from both recordings [s]."""
    cmd_size, fb_size = sizes
    sent = {r.data["seq"]: r.t_recv for r in leader_recs if r.topic == "cmd/sent"}
    first_fb: dict[int, float] = {}
    for r in leader_recs:
        if r.topic == "feedback/recv":
            first_fb.setdefault(r.data["cmd_seq"], r.t_recv)
    f_cmd = {r.data["seq"]: r.t_recv for r in follower_recs if r.topic == "cmd/recv"}
    f_fb: dict[int, tuple[float, float]] = {}
    for r in follower_recs:
        if r.topic == "feedback/sent":
            f_fb.setdefault(r.data["cmd_seq"], (r.data["t"], r.t_recv))
    parts: dict[str, list[float]] = {k: [] for k in ("total", "forward", "tick_wait", "tick", "backward", "transport")}
    warm = sorted(sent)[len(sent) // 10 :]  # skip the first 10 % (start-up)
    for seq in warm:
        if seq in first_fb and seq in f_cmd and seq in f_fb:
            t0, t_f, (t_tick, t_pub), t1 = sent[seq], f_cmd[seq], f_fb[seq], first_fb[seq]
            parts["total"].append(t1 - t0)
            parts["forward"].append(t_f - t0)
            parts["tick_wait"].append(t_tick - t_f)
            parts["tick"].append(t_pub - t_tick)
            parts["backward"].append(t1 - t_pub)
            parts["transport"].append((t_f - t0) + (t1 - t_pub))
    # Every command, echoed or not: until the first feedback reflecting it or a newer one
    # (what an operator's command waits for; includes the whole control period).
    fb_times = sorted((t, cs) for cs, t in first_fb.items())
    parts["any"] = []
    j = 0
    for seq in warm:
        while j < len(fb_times) and (fb_times[j][1] < seq or fb_times[j][0] < sent[seq]):
            j += 1
        if j == len(fb_times):
            break
        parts["any"].append(fb_times[j][0] - sent[seq])
    parts["bare"] = bare[len(bare) // 10 :]
    parts["_sizes"] = [float(cmd_size), float(fb_size)]
    return parts


def print_overhead(rate_hz: float, p: dict[str, list[float]]) -> None:
    print(
        f"\ncommand -> feedback, follower control and feedback at {rate_hz:g} Hz, proxy 0 ms "
        f"(Command {p['_sizes'][0]:.0f} B, Feedback {p['_sizes'][1]:.0f} B)"
    )
    print(row("ours: command sent -> first feedback", p["total"]))
    print(row("  forward: leader -> follower receipt", p["forward"]))
    print(row("  wait for the next control tick", p["tick_wait"]))
    print(row("  tick: start -> feedback published", p["tick"]))
    print(row("  backward: published -> leader receipt", p["backward"]))
    print(row("  transport only (forward + backward)", p["transport"]))
    print(row("bare zenoh ping-pong, same path/sizes", p["bare"]))
    print(row("every command -> feedback of it or newer", p["any"]))
    for q, name in ((0.5, "p50"), (0.99, "p99")):
        tot = 1e3 * (pct(p["total"], q) - pct(p["bare"], q))
        tr = 1e3 * (pct(p["transport"], q) - pct(p["bare"], q))
        print(f"  overhead {name}: ours - bare = {tot:6.2f} ms (all); transport only - bare = {tr:6.2f} ms")


# --------------------------------------------------------------------------- 2. video

# Installed before the page's own script: remembers the capture time of each frame the
# cockpit pushes (same header as leader/cockpit/static/app.js) and, for every <img> that
# loads a frame, the age at the load event and at the next animation frame.
INIT_JS = r"""
window.__g2g = {load: [], paint: [], recv: []};
(() => {
  const urlT = new Map(); let lastT = null;
  const Orig = window.WebSocket;
  window.WebSocket = class extends Orig {
    constructor(...a) {
      super(...a);
      this.addEventListener("message", (ev) => {
        if (typeof ev.data === "string") return;
        const dv = new DataView(ev.data);
        if (ev.data.byteLength < 15 || dv.getUint8(0) !== 0x56 || dv.getUint8(1) !== 0x46) return;
        const len = dv.getUint8(2);
        lastT = dv.getFloat64(3 + len, true);
        window.__g2g.recv.push(Date.now() / 1000 - lastT);
      });
    }
  };
  const create = URL.createObjectURL.bind(URL);
  URL.createObjectURL = (obj) => {
    const u = create(obj);
    if (obj && obj.type === "image/jpeg" && lastT !== null) urlT.set(u, lastT);
    return u;
  };
  document.addEventListener("load", (ev) => {
    const el = ev.target;
    if (!el || el.tagName !== "IMG" || !urlT.has(el.src)) return;
    const t = urlT.get(el.src); urlT.delete(el.src);
    window.__g2g.load.push(Date.now() / 1000 - t);
    requestAnimationFrame(() => window.__g2g.paint.push(Date.now() / 1000 - t));
  }, true);
})();
"""


def render_time(n: int = 30) -> list[float]:
    """Seconds per head-camera render of the sim NAO (pybullet, QVGA), in this process."""
    from bipedtele.config.profile import load_config
    from bipedtele.follower.robot import make_robot

    out = []
    with make_robot("sim", config=load_config("default")) as robot:
        for _ in range(n):
            robot.advance(0.02)
            t0 = time.perf_counter()
            robot.capture("head")
            out.append(time.perf_counter() - t0)
    return out


def video(seconds: float, cockpit_hz: float, browser: bool, keep: bool) -> dict[str, list[float]]:
    with stack(keep) as st:
        l_rec = st.folder / "leader.mcap"
        port = free_port()
        token = secrets.token_urlsafe(24)
        os.environ[COCKPIT_TOKEN_ENV] = token  # inherited by the leader started below
        st.start(
            "follower",
            [
                *CLI,
                "follower",
                *client_args(st.router_ep),
                "--set",
                "follower.camera_fps=10",
                "--set",
                'follower.cameras=["head"]',
                "--record",
                str(st.folder / "follower.mcap"),
            ],
            "ready",
        )
        st.start(
            "leader",
            [
                *CLI,
                "leader",
                *client_args(st.proxy_ep),
                "--operator",
                "scripted",
                "--set",
                "leader.script=[[0, 5, 0], [600, 5, 0]]",
                "--set",
                "leader.cockpit=true",
                "--set",
                f"leader.cockpit_port={port}",
                "--set",
                f"leader.cockpit_rate_hz={cockpit_hz:g}",
                "--duration",
                f"{seconds + 30:g}",
                "--record",
                str(l_rec),
            ],
            "leader ready",
        )
        res: dict[str, list[float]] = {}
        if browser and Path(CHROMIUM).exists():
            from playwright.sync_api import sync_playwright

            with sync_playwright() as pw:
                b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
                page = b.new_page(viewport={"width": 1280, "height": 900})
                page.add_init_script(INIT_JS)
                page.goto(f"http://127.0.0.1:{port}/?token={token}")
                time.sleep(seconds)
                g = page.evaluate("window.__g2g")
                b.close()
            n = len(g["load"])
            res = {k: [float(x) for x in g[k][max(1, n // 10) :]] for k in ("recv", "load", "paint")}
        else:
            time.sleep(seconds)
        st.stop("leader")
        st.stop("follower")
        frames = [r for r in read_records(l_rec) if r.topic == "video/recv"]
    res["leader"] = [r.t_recv - r.data["t_capture"] for r in frames[len(frames) // 10 :]]
    res["_kb"] = [statistics.fmean(len(r.data["jpeg"]) for r in frames if r.data["jpeg"]) / 1024] if frames else []
    return res


# --------------------------------------------------------------------------- main


def main() -> None:
    ap = argparse.ArgumentParser(description="whole-system overhead and video latency")
    ap.add_argument("--seconds", type=float, default=15.0, help="length of each run [s]")
    ap.add_argument("--rates", default="50,240", help="follower control rates to run [Hz]")
    ap.add_argument("--no-browser", action="store_true", help="skip the headless chromium part")
    ap.add_argument("--no-video", action="store_true", help="skip the video part (overhead only)")
    ap.add_argument("--keep", action="store_true", help="keep the run folders")
    ap.add_argument("--echo", help=argparse.SUPPRESS)
    ap.add_argument("--fb-size", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.echo:
        echo_main(args.echo, args.fb_size, args.seconds)
        return
    print(f"bench/e2e.py on {os.cpu_count()} CPUs; runs of {args.seconds:g} s")
    summary: dict[str, Any] = {}
    for rate in [float(r) for r in args.rates.split(",")]:
        p = overhead(rate, args.seconds, args.keep)
        print_overhead(rate, p)
        summary[f"overhead_p50_ms@{rate:g}Hz"] = round(1e3 * (pct(p["total"], 0.5) - pct(p["bare"], 0.5)), 2)
        summary[f"transport_overhead_p50_ms@{rate:g}Hz"] = round(
            1e3 * (pct(p["transport"], 0.5) - pct(p["bare"], 0.5)), 2
        )
    if args.no_video:
        print("\nsummary " + json.dumps(summary))
        return
    rt = render_time()
    print("\nvideo, head camera QVGA 10 fps, proxy 0 ms")
    print(row("pybullet render (not in the figures below)", rt))
    for hz in (20.0, 100.0):
        v = video(args.seconds, hz, not args.no_browser, args.keep)
        if hz == 20.0:
            print(f"  mean JPEG size {v['_kb'][0]:.1f} KiB" if v["_kb"] else "  no frames")
            print(row("render done -> leader program receipt", v["leader"]))
            summary["video_leader_p50_ms"] = round(1e3 * pct(v["leader"], 0.5), 1)
        if "load" in v:
            print(f"  browser, cockpit pushing at {hz:g} Hz:")
            print(row("  render done -> browser websocket receipt", v["recv"]))
            print(row("  render done -> browser decoded (img load)", v["load"]))
            print(row("  render done -> next animation frame", v["paint"]))
            summary[f"video_browser_load_p50_ms@{hz:g}Hz"] = round(1e3 * pct(v["load"], 0.5), 1)
    print("\nsummary " + json.dumps(summary))
    print("goals: overhead p50 < 2 ms; video p50 < 60 ms")


if __name__ == "__main__":
    main()
