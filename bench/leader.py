"""Benchmark: the leader's 1 kHz haptic loop rate and period jitter.

Scenarios, measured side by side in one run:

``alone``
    The loop with the simulated Falcon and the scripted operator, feedback from a local
    function (no network, no cockpit, no recording).
``full``
    The ``bipedtele leader`` program in this process (Zenoh session, receivers, MCAP
    recording, cockpit) while a peer process publishes feedback at 50 Hz and 15 fps QVGA
    JPEG video, and a browser-like websocket client pulls the cockpit's samples and video.
``full+fifo``
    As ``full`` with the loop thread at SCHED_FIFO priority 50 (where permitted).

Prints the achieved mean rate [Hz] and the period error |period - 1 ms| p50/p99/max [ms].
Goal: mean rate >= 995 Hz, p99 period error < 1 ms.

Usage: ``python bench/leader.py [--seconds 10]``
"""

from __future__ import annotations

import argparse
import os
import secrets
import socket
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
from bipedtele.config.profile import load_config
from bipedtele.leader.app import COCKPIT_TOKEN_ENV, LeaderApp
from bipedtele.leader.devices.sim_falcon import SimFalcon
from bipedtele.leader.loop import LeaderLoop
from bipedtele.leader.operator import make_operator
from bipedtele.link.inbox import FeedbackInbox
from bipedtele.link.messages import Feedback

PEER = textwrap.dedent(
    """
    import sys, time, numpy as np, cv2
    from bipedtele.config.sections import NetworkConfig
    from bipedtele.link.transport import Keys, Publishers, open_session, declare_presence
    from bipedtele.link.messages import Feedback, VideoFrame
    port, robot, seconds = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
    net = NetworkConfig(connect=[f"tcp/127.0.0.1:{port}"])
    keys = Keys(robot)
    yy, xx = np.mgrid[0:240, 0:320]
    with open_session(net) as s, Publishers(s, keys) as pubs, declare_presence(s, keys, "follower"):
        t0 = time.time(); k = 0; next_fb = next_vid = t0; seq = 0; vseq = 0
        while time.time() - t0 < seconds:
            now = time.time()
            if now >= next_fb:
                seq += 1; next_fb += 0.02
                pubs.feedback.put(Feedback(sid=99, seq=seq, t=now, z_e=[2.0, 1.0], h1_s=0.05,
                                           pose=[0.01 * seq, 0.0, 0.0], sonar=[2.5, 2.5], state="walking"))
            if now >= next_vid:
                vseq += 1; next_vid += 1 / 15
                img = ((xx + 4 * vseq) % 256 ^ (yy + 2 * vseq) % 256).astype(np.uint8)
                img = cv2.merge([img, np.roll(img, 17, 1), np.roll(img, 31, 0)])
                ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
                pubs.video.put(VideoFrame(sid=99, seq=vseq, t=time.time(), camera="head", width=320,
                                          height=240, t_capture=now, jpeg=jpg.tobytes()))
            time.sleep(0.002)
    """
)

BROWSER = textwrap.dedent(
    """
    import asyncio, sys, time, aiohttp
    port, seconds, token = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
    async def main():
        url = f"http://127.0.0.1:{port}"
        n_text = n_bin = 0
        for _ in range(100):
            try:
                async with aiohttp.ClientSession() as s:
                    async with s.ws_connect(url + "/ws?token=" + token, origin=url) as ws:
                        t0 = time.time()
                        while time.time() - t0 < seconds:
                            try:
                                msg = await asyncio.wait_for(ws.receive(), 0.5)
                            except asyncio.TimeoutError:
                                continue
                            if msg.type == aiohttp.WSMsgType.TEXT: n_text += 1
                            elif msg.type == aiohttp.WSMsgType.BINARY: n_bin += 1
                            else: break
                        print(f"browser: {n_text} text, {n_bin} video messages", file=sys.stderr)
                        return
            except aiohttp.ClientError:
                await asyncio.sleep(0.1)
    asyncio.run(main())
    """
)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def fmt(name: str, st: dict) -> str:
    if "rate_hz" not in st:
        return f"{name:<11} (no figures)"
    return (
        f"{name:<11} {st['rate_hz']:8.1f} Hz   err p50 {1e3 * st['err_p50_s']:6.3f} ms   "
        f"p99 {1e3 * st['err_p99_s']:6.3f} ms   max {1e3 * st['err_max_s']:7.3f} ms   "
        f"missed {st.get('missed_ticks', 0)}"
    )


def run_alone(seconds: float) -> dict:
    cfg = load_config("default", ["leader.script=[[0, 4, 2], [1000, 4, 2]]"])
    dev = SimFalcon()
    dev.connect()
    op = make_operator("scripted", cfg)
    z = np.zeros(2)

    def latest():
        now = time.time()
        return Feedback(t=now - 0.05, z_e=list(z), h1_s=0.05), now

    loop = LeaderLoop(dev, op, cfg.control, lambda c: None, FeedbackInbox(source=latest), cfg=cfg.leader)
    loop.run(duration_s=seconds)
    dev.disconnect()
    return {**loop.period_stats.summary(loop.dt), "missed_ticks": loop.missed_ticks}


def run_full(seconds: float, rt_priority: int) -> dict:
    zport, cport = free_port(), free_port()
    robot = f"bench{os.getpid()}"
    token = secrets.token_urlsafe(24)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    os.environ[COCKPIT_TOKEN_ENV] = token  # the leader below runs in this process
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(
            "default",
            [
                f"robot.id={robot!r}".replace("'", '"'),
                f'network.listen=["tcp/127.0.0.1:{zport}"]',
                f"leader.cockpit_port={cport}",
                f"leader.rt_priority={rt_priority}",
                "leader.script=[[0, 4, 2], [1000, 4, 2]]",
                f'record.dir="{tmp}"',
            ],
        )
        peer = subprocess.Popen([sys.executable, "-c", PEER, str(zport), robot, str(seconds + 3)], env=env)
        browser = subprocess.Popen([sys.executable, "-c", BROWSER, str(cport), str(seconds + 2), token], env=env)
        stats: dict = {}
        try:
            LeaderApp(
                cfg, operator_name="scripted", duration_s=seconds, realtime=True, record=Path(tmp) / "bench.mcap"
            ).run(stats)
        finally:
            for p in (peer, browser):
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
    return stats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="duration of each scenario [s]")
    args = ap.parse_args()
    print(
        f"leader loop benchmark: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}, "
        f"{args.seconds:.0f} s per scenario, goal >= 995 Hz and p99 error < 1 ms"
    )
    alone = run_alone(args.seconds)
    print(fmt("alone", alone), flush=True)
    full = run_full(args.seconds, 0)
    print(
        fmt("full", full),
        f"  feedback {full.get('feedback')}  cockpit frames {full.get('cockpit', {}).get('frames_pushed')}",
        flush=True,
    )
    fifo = run_full(args.seconds, 50)
    print(fmt("full+fifo", fifo), flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
