"""Cost of recording and cockpit publishing on the caller's (loop) thread.

Prints p50/p99/max per call of ``Recorder.write`` (a Command, a 30-key sample, the
leader's full ``leader/state`` sample, a video frame) and ``CockpitServer.publish_sample``
while a browser-less websocket client is connected, each next to a baseline measured side
by side in the same run (plain ``msgpack.packb`` of the same payload, what the recorder
did on the caller's thread before its channels had JSON schemas; a plain ``dict`` copy).
Then the writer thread's cost per message (JSON encoding, off the caller's thread), and a
1 kHz loop's tick lateness with and without a recorder fed at the leader's rates.
Run: ``.venv/bin/python bench/recording.py``.
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
from bipedtele.link.messages import Command, Feedback, VideoFrame
from bipedtele.recording.format import message_to_dict
from bipedtele.recording.recorder import Recorder
from bipedtele.recording.schemas import LEADER_STATE_FIELDS

N = 20_000


def sample(i: int) -> dict[str, object]:
    keys = [
        "ref_v",
        "ref_w",
        "z_e_v",
        "z_e_w",
        "eta_v",
        "eta_w",
        "force_v",
        "force_w",
        "h1_ms",
        "h2_ms",
        "alpha_m_v",
        "alpha_m_w",
        "s_r_v",
        "s_r_w",
        "T",
        "eps",
        "x_v",
        "x_w",
        "pose_x",
        "pose_y",
        "pose_yaw",
        "sonar_l",
        "sonar_r",
        "gain",
    ]
    d: dict[str, object] = {k: 0.001 * i + j for j, k in enumerate(keys)}
    d.update(t=time.time(), state="walking", link="ok", watchdog="ok", falls=0, passes_done=1)
    return d


def leader_sample(i: int) -> dict[str, object]:
    """A sample with every ``leader/state`` key, of the types a leader writes."""
    d: dict[str, object] = {}
    for j, (k, sch) in enumerate(LEADER_STATE_FIELDS.items()):
        types = sch["type"] if isinstance(sch["type"], list) else [sch["type"]]
        d[k] = 1 if "integer" in types else 0.001 * i + j if "number" in types else True if "boolean" in types else "ok"
    d["t"] = time.time()
    return d


def _as_map(obj: object) -> object:
    return message_to_dict(obj) if isinstance(obj, Command | VideoFrame) else obj


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
    print(
        f"{name:<34} p50 {p50:7.2f} us  p99 {p99:7.2f} us  max {mx:8.1f} us"
        f"   baseline p50 {b50:6.2f} p99 {b99:6.2f} us  ratio p50 {p50 / b50:5.2f}"
    )


def paced_loop(seconds: float, rec: Recorder | None) -> np.ndarray:
    """A 1 kHz loop (absolute deadlines) writing at the leader's rates: a command and a
    sample at 100 Hz, feedback at 50 Hz, a 20 kB frame at 20 Hz. Returns tick lateness [us]."""
    cmd = Command(seq=1, t=time.time(), ref=[5.0, 4.0])
    fb = Feedback(seq=1, t=time.time(), state="walking")
    frame = VideoFrame(seq=1, t=time.time(), t_capture=time.time(), jpeg=bytes(20_000))
    snaps = [leader_sample(i) for i in range(100)]
    n = int(seconds * 1000)
    late = np.empty(n)
    t_next = time.perf_counter()
    for i in range(n):
        t_next += 0.001
        while (dt := t_next - time.perf_counter()) > 0:
            time.sleep(dt)
        late[i] = (time.perf_counter() - t_next) * 1e6
        if rec is not None and i % 10 == 0:
            rec.write("cmd/sent", cmd, 1.0)
            rec.write("leader/state", snaps[i % 100], 1.0)
            if i % 20 == 0:
                rec.write("feedback/recv", fb, 1.0)
            if i % 50 == 0:
                rec.write("video/recv", frame, 1.0)
    return late


def main() -> None:
    cmd = Command(seq=1, t=time.time(), ref=[5.0, 4.0])
    frame = VideoFrame(seq=1, t=time.time(), t_capture=time.time(), jpeg=bytes(20_000))
    samples = [sample(i) for i in range(100)]
    full = [leader_sample(i) for i in range(100)]
    with tempfile.TemporaryDirectory() as tmp:
        with Recorder(Path(tmp) / "bench.mcap", jpeg_every=10) as rec:
            base = timeit(lambda i: msgpack.packb(message_to_dict(cmd), use_bin_type=True))
            row("Recorder.write(Command)", timeit(lambda i: rec.write("cmd/sent", cmd, 1.0)), base)
            base = timeit(lambda i: msgpack.packb(samples[i % 100], use_bin_type=True))
            row(
                "Recorder.write(30-key sample)", timeit(lambda i: rec.write("other/state", samples[i % 100], 1.0)), base
            )
            base = timeit(lambda i: msgpack.packb(full[i % 100], use_bin_type=True))
            row(
                f"Recorder.write({len(full[0])}-key leader/state)",
                timeit(lambda i: rec.write("leader/state", full[i % 100], 1.0)),
                base,
            )
            base = timeit(lambda i: msgpack.packb(message_to_dict(frame), use_bin_type=True))
            row("Recorder.write(VideoFrame 20 kB)", timeit(lambda i: rec.write("video/recv", frame, 1.0)), base)
        print(f"  file {(Path(tmp) / 'bench.mcap').stat().st_size / 1e6:.1f} MB, stats {rec.stats}")
        print("writer thread, per message (JSON encoding, off the caller's thread):")
        with Recorder(Path(tmp) / "encode.mcap") as idle:  # its writer thread has nothing to do
            if not hasattr(idle, "_encode"):  # an older Recorder (msgpack on the caller's thread)
                print("  (none: this Recorder encodes on the caller's thread)")
                objs_list: tuple = ()
            else:
                objs_list = (
                    ("Command", "cmd/sent", [cmd] * 100),
                    ("leader/state", "leader/state", full),
                    ("VideoFrame kept, 20 kB", "video/recv", [frame] * 100),
                )
            for name, topic, objs in objs_list:
                base = timeit(lambda i, o=objs: msgpack.packb(_as_map(o[i % 100]), use_bin_type=True))  # type: ignore[misc]
                row(f"  encode {name}", timeit(lambda i, t=topic, o=objs: idle._encode(t, o[i % 100])), base)  # type: ignore[misc]
            idle.write("events", {"event": "done"}, 1.0)

        print("1 kHz loop, tick lateness [us], 5 s each (leader rates: 100 Hz cmd + sample, 50 Hz fb, 20 Hz video):")
        no_rec = paced_loop(5.0, None)
        with Recorder(Path(tmp) / "loop.mcap", jpeg_every=10) as rec:
            with_rec = paced_loop(5.0, rec)
        for name, late in (("no recorder", no_rec), ("recorder", with_rec)):
            print(
                f"  {name:<12} p50 {np.percentile(late, 50):7.1f}  p99 {np.percentile(late, 99):7.1f}"
                f"  p99.9 {np.percentile(late, 99.9):7.1f}  max {late.max():8.1f}"
            )

    with CockpitServer(telemetry_hz=30) as server:
        stop = threading.Event()

        def client() -> None:
            async def run() -> None:
                async with (
                    aiohttp.ClientSession() as cs,
                    cs.ws_connect(
                        server.base_url + f"ws?token={server.token}", origin=server.base_url.rstrip("/")
                    ) as ws,
                ):
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
