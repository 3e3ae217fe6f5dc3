"""``bipedtele trace``: a recording's path replayed through ``bipedtele delay-proxy`` (real processes, loopback).

A leader recording as the demo writes it (``feedback/recv`` every 20 ms with its send
stamp and the follower's h1 estimate, ``leader/state`` with ``rx_kbps``) of a path whose
delays swing (h2 80 +- 40 ms over 8 s, h1 60 +- 30 ms over 5 s, one 1 s step of +100 ms
on h2). ``bipedtele trace`` makes its CSV; the delay proxy replays it (``--t0`` lines the
trace's origin up with the test's clock); messages sent both ways through the proxy
every 40 ms for 9 s arrive with the recorded delays: the median error is under 5 ms.
"""

from __future__ import annotations

import math
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from bipedtele.link.messages import Feedback
from bipedtele.recording.recorder import Recorder

pytestmark = [pytest.mark.slow, pytest.mark.timeout(90)]

T_REC = 1_700_000_000.0


def h2_s(tau: float) -> float:
    step = 0.1 if 6.0 <= tau % 12.0 < 7.0 else 0.0
    return 0.08 + 0.04 * math.sin(2 * math.pi * tau / 8.0) + step


def h1_s(tau: float) -> float:
    return 0.06 + 0.03 * math.sin(2 * math.pi * tau / 5.0)


def _recording(path: Path, seconds: float = 12.0) -> None:
    with Recorder(path, metadata={"role": "leader"}) as rec:
        for k in range(round(seconds / 0.02)):
            tau = 0.02 * k
            t = T_REC + tau
            fb = Feedback(sid=5, seq=k + 1, t=t, h1_s=h1_s(tau), z_e=[0.0, 0.0], eta=[0.0, 0.0])
            rec.write("feedback/recv", fb, t + h2_s(tau))
            if k % 10 == 0:
                rec.write("leader/state", {"t": t, "rx_kbps": 300.0}, t)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _reader(conn: socket.socket, out: list[tuple[float, float]]) -> None:
    buf = b""
    while True:
        try:
            data = conn.recv(4096)
        except OSError:
            return
        if not data:
            return
        now = time.time()
        buf += data
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            out.append((float(line), now))


def _send(sock: socket.socket, n: int, every: float) -> None:
    for _ in range(n):
        sock.sendall(f"{time.time():.6f}\n".encode())
        time.sleep(every)


def test_a_recordings_trace_replays_through_the_delay_proxy_within_5_ms(tmp_path: Path) -> None:
    rec = tmp_path / "leader-demo.mcap"
    _recording(rec)
    csv = tmp_path / "path.csv"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "trace",
            str(rec),
            "--out",
            str(csv),
            "--mahimahi",
            str(tmp_path / "rate.mahi"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert csv.read_text().splitlines()[0] == "t_s,h1_ms,h2_ms,loss_pct,rx_kbps"
    target = socket.socket()
    target.bind(("127.0.0.1", 0))
    target.listen(1)
    port = _free_port()
    t0 = time.time() + 1.0  # the trace's origin: a second after now (the proxy starts meanwhile)
    proxy = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "delay-proxy",
            "--listen",
            f"127.0.0.1:{port}",
            "--target",
            f"127.0.0.1:{target.getsockname()[1]}",
            "--forward",
            f"trace:{csv}:h1",
            "--backward",
            f"trace:{csv}:h2",
            "--t0",
            f"{t0:.6f}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    fwd: list[tuple[float, float]] = []
    bwd: list[tuple[float, float]] = []
    try:
        assert proxy.stdout is not None and f"listening on 127.0.0.1:{port}" in proxy.stdout.readline()
        client = socket.create_connection(("127.0.0.1", port), timeout=10)
        server, _ = target.accept()
        for s in (client, server):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        readers = [
            threading.Thread(target=_reader, args=(server, fwd), daemon=True),
            threading.Thread(target=_reader, args=(client, bwd), daemon=True),
        ]
        for th in readers:
            th.start()
        time.sleep(max(0.0, t0 - time.time()))
        senders = [
            threading.Thread(target=_send, args=(client, 225, 0.04)),
            threading.Thread(target=_send, args=(server, 225, 0.04)),
        ]
        for th in senders:
            th.start()
        for th in senders:
            th.join(30)
        time.sleep(0.6)
        client.close()
        server.close()
    finally:
        proxy.send_signal(signal.SIGINT)
        proxy.wait(timeout=10)
        target.close()
    for got, model in ((fwd, h1_s), (bwd, h2_s)):
        assert len(got) > 200, len(got)
        errors = [abs((recv - sent) - model(sent - t0)) * 1000.0 for sent, recv in got]
        assert statistics.median(errors) < 5.0, (model.__name__, statistics.median(errors), max(errors))
