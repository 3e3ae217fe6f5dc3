"""Cost of recording and cockpit publishing on the caller's (loop) thread.

Prints p50/p99/max per call of ``Recorder.write`` (a Command, a 30-key leader sample) and
``CockpitServer.publish_sample`` while a browser-less websocket client is connected, each
next to a baseline measured side by side in the same run (plain ``msgpack.packb`` of the
same payload; a plain ``dict`` copy). Run: ``.venv/bin/python bench/recording.py``.
"""

from __future__ import annotations

import asyncio
import contextlib
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import aiohttp
import msgpack
import numpy as np
from bipedtele.leader.cockpit import CockpitServer
from bipedtele.messages import Command
from bipedtele.recording import Recorder, message_to_dict

N = 20_000


def sample(i: int) -> dict[str, object]:
    keys = ["ref_v", "ref_w", "z_e_v", "z_e_w", "eta_v", "eta_w", "force_v", "force_w",
            "h1_ms", "h2_ms", "alpha_m_v", "alpha_m_w", "s_r_v", "s_r_w", "T", "eps",
            "x_v", "x_w", "pose_x", "pose_y", "pose_yaw", "sonar_l", "sonar_r", "gain"]  # fmt: skip
    d: dict[str, object] = {k: 0.001 * i + j for j, k in enumerate(keys)}
    d.update(t=time.time(), state="walking", link="ok", watchdog="ok", falls=0, passes_done=1)
    return d


def timeit(fn: Callable[[int], object]) -> np.ndarray:
    out = np.empty(N)
    for i in range(N):
        t0 = time.perf_counter_ns()
        fn(i)
        out[i] = time.perf_counter_ns() - t0
        if i % 10 == 0:
            time.sleep(0.0005)  # about the loop's pace, so background threads run too
    return out / 1000.0  # us


def row(name: str, us: np.ndarray, base: np.ndarray) -> None:
    p50, p99, mx = np.percentile(us, 50), np.percentile(us, 99), us.max()
    b50, b99 = np.percentile(base, 50), np.percentile(base, 99)
    print(f"{name:<34} p50 {p50:7.2f} us  p99 {p99:7.2f} us  max {mx:8.1f} us"
          f"   baseline p50 {b50:6.2f} p99 {b99:6.2f} us  ratio p50 {p50 / b50:5.2f}")  # fmt: skip


def main() -> None:
    cmd = Command(seq=1, t=time.time(), ref=[5.0, 4.0])
    samples = [sample(i) for i in range(100)]
    with tempfile.TemporaryDirectory() as tmp:
        with Recorder(Path(tmp) / "bench.mcap") as rec:
            base = timeit(lambda i: msgpack.packb(message_to_dict(cmd), use_bin_type=True))
            row("Recorder.write(Command)", timeit(lambda i: rec.write("cmd/sent", cmd, 1.0)), base)
            base = timeit(lambda i: msgpack.packb(samples[i % 100], use_bin_type=True))
            row("Recorder.write(30-key sample)",
                timeit(lambda i: rec.write("leader/state", samples[i % 100], 1.0)), base)  # fmt: skip
        print(f"  file {(Path(tmp) / 'bench.mcap').stat().st_size / 1e6:.1f} MB, stats {rec.stats}")

    with CockpitServer(telemetry_hz=30) as server:
        stop = threading.Event()

        def client() -> None:
            async def run() -> None:
                async with aiohttp.ClientSession() as cs, cs.ws_connect(
                    server.base_url + f"ws?token={server.token}", origin=server.base_url.rstrip("/")
                ) as ws:
                    while not stop.is_set():
                        with contextlib.suppress(TimeoutError):
                            await asyncio.wait_for(ws.receive(), 0.2)

            asyncio.run(run())

        th = threading.Thread(target=client)
        th.start()
        time.sleep(0.3)
        base = timeit(lambda i: dict(samples[i % 100]))
        row("CockpitServer.publish_sample", timeit(lambda i: server.publish_sample(samples[i % 100])), base)
        stop.set()
        th.join()
        print(f"  cockpit stats {server.stats}")


if __name__ == "__main__":
    main()
