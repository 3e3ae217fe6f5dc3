"""Two real Zenoh sessions in separate processes, directly and through `bipedtele delay-proxy`.

The peers are ``zpeer.py`` processes (bounded run time); they write what they measured
to JSON files that the tests check.
"""

from __future__ import annotations

import itertools
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from bipedtele.delaymodels import TraceDelay, parse_delay_model

ZPEER = Path(__file__).with_name("zpeer.py")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_peer(role: str, out: Path, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(ZPEER), role, "--out", str(out), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def finish(p: subprocess.Popen[str], out: Path, timeout: float = 30.0) -> dict[str, Any]:
    try:
        log, _ = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        log, _ = p.communicate()
        raise AssertionError(f"peer did not finish: {log[-3000:]}") from None
    assert p.returncode == 0, log[-3000:]
    return json.loads(out.read_text())


@contextmanager
def delay_proxy(target: int, forward: str, backward: str, *extra: str) -> Iterator[int]:
    """Run `bipedtele delay-proxy` on a free port; yield the port; SIGINT it after."""
    port = free_port()
    p = subprocess.Popen(
        [sys.executable, "-m", "bipedtele.cli", "delay-proxy", "--listen", f"127.0.0.1:{port}",
         "--target", f"127.0.0.1:{target}", "--forward", forward, "--backward", backward, *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert p.stdout is not None
        line = p.stdout.readline()
        assert f"listening on 127.0.0.1:{port}" in line, p.stderr.read() if p.stderr else ""
        yield port
    finally:
        p.send_signal(signal.SIGINT)
        try:
            _, err = p.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            raise
    assert p.returncode == 0, err[-2000:]
    assert "forward:" in err and "backward:" in err  # shut down cleanly and logged its counters


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_commands_and_feedback_exchange(tmp_path: Path) -> None:
    port = free_port()
    f = start_peer("follower", tmp_path / "f.json", "--listen", f"tcp/127.0.0.1:{port}", "--duration", "3")
    time.sleep(0.3)
    l_ = start_peer("leader", tmp_path / "l.json", "--connect", f"tcp/127.0.0.1:{port}", "--duration", "3")
    fr, lr = finish(f, tmp_path / "f.json"), finish(l_, tmp_path / "l.json")
    assert fr["received"] > 100 and lr["received"] > 100
    assert fr["drops"] == {} and lr["drops"] == {}
    # the leader saw feedback that acknowledges its commands; delays on loopback are small
    assert lr["last_msg"]["cmd_seq"] > 0
    assert 0.0 <= lr["last_msg"]["h1_s"] < 0.05
    assert 0.0 <= fr["last_msg"]["h2_s"] < 0.05


def _settled(series: list[list[float]], t_from: float) -> list[float]:
    return [h for (t, h) in series if t >= t_from]


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_constant_delays_through_proxy(tmp_path: Path) -> None:
    port = free_port()
    f = start_peer("follower", tmp_path / "f.json", "--listen", f"tcp/127.0.0.1:{port}", "--duration", "5")
    with delay_proxy(port, "const:150ms", "const:220ms") as q:
        l_ = start_peer("leader", tmp_path / "l.json", "--connect", f"tcp/127.0.0.1:{q}", "--duration", "5")
        fr, lr = finish(f, tmp_path / "f.json"), finish(l_, tmp_path / "l.json")
    for res, want in ((fr, 0.150), (lr, 0.220)):
        assert res["first_recv"] is not None, res
        est = _settled(res["series"], res["first_recv"] + 2.0)
        assert len(est) > 50
        worst = max(abs(h - want) for h in est)
        assert worst < 0.005, f"{res['role']}: estimate off by {worst * 1e3:.1f} ms from {want * 1e3:.0f} ms"
    # each side shares its estimate: the leader knows h1 and the follower h2
    assert abs(lr["last_msg"]["h1_s"] - 0.150) < 0.005
    assert abs(fr["last_msg"]["h2_s"] - 0.220) < 0.005


def _smooth_segment(h1: TraceDelay, h2: TraceDelay, length_s: float) -> float:
    """Start time of the trace segment of ``length_s`` with the widest swing of the 1 s
    average among those without spikes (steps > 20 ms per row): on a spike the link's
    FIFO order makes chunks queue behind earlier ones, which no 1 s average of the
    trace itself describes."""
    step = h1.t[1] - h1.t[0]
    n = int(length_s / step)
    w = int(1.0 / step)
    best, best_swing = 0.0, -1.0
    for a in range(0, len(h1.t) - n, 10):
        seg1, seg2 = h1.d[a : a + n], h2.d[a : a + n]
        if any(abs(y - x) > 0.020 for s in (seg1, seg2) for x, y in itertools.pairwise(s)):
            continue
        ma = [sum(seg1[i : i + w]) / w for i in range(0, n - w)]
        swing = max(ma) - min(ma)
        if swing > best_swing:
            best, best_swing = h1.t[a], swing
    assert best_swing > 0.01, "the trace has no varying segment"
    return best


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_trace_delays_follow_moving_average(tmp_path: Path) -> None:
    h1 = parse_delay_model("trace:intercontinental:h1")
    h2 = parse_delay_model("trace:intercontinental:h2")
    assert isinstance(h1, TraceDelay) and isinstance(h2, TraceDelay)
    duration = 7.0
    a = _smooth_segment(h1, h2, duration + 3.0)
    t0 = time.time() - a  # the proxy's models start at trace time a now
    port = free_port()
    f = start_peer("follower", tmp_path / "f.json", "--listen", f"tcp/127.0.0.1:{port}", "--duration", str(duration))
    with delay_proxy(port, "trace:intercontinental:h1", "trace:intercontinental:h2", "--t0", repr(t0)) as q:
        l_ = start_peer("leader", tmp_path / "l.json", "--connect", f"tcp/127.0.0.1:{q}", "--duration", str(duration))
        fr, lr = finish(f, tmp_path / "f.json"), finish(l_, tmp_path / "l.json")
    for res, model in ((fr, h1), (lr, h2)):
        assert res["first_recv"] is not None, res
        checked = 0
        worst = 0.0
        for t, est in res["series"]:
            if t < res["first_recv"] + 1.5:
                continue
            # messages received in (t - 1, t] were sent about one delay earlier
            ref = model.window_mean(t - t0 - est, 1.0)
            worst = max(worst, abs(est - ref))
            checked += 1
        assert checked > 100
        assert worst < 0.010, f"{res['role']}: 1 s average off the trace's by {worst * 1e3:.1f} ms"


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_garbage_on_every_key_is_dropped_and_counted(tmp_path: Path) -> None:
    port = free_port()
    sink = start_peer("sink", tmp_path / "s.json", "--listen", f"tcp/127.0.0.1:{port}", "--duration", "4.5")
    time.sleep(0.3)
    fuzz = start_peer("fuzz", tmp_path / "z.json", "--connect", f"tcp/127.0.0.1:{port}", "--duration", "3")
    zr, sr = finish(fuzz, tmp_path / "z.json"), finish(sink, tmp_path / "s.json")
    bad = zr["bad_sent_per_key"]
    for key in ("cmd", "feedback", "video", "clock", "status"):
        drops = sr["drops"][key]
        assert sum(drops.values()) == bad, (key, drops)
        for reason in ("not_msgpack", "not_a_map", "bad_version", "unknown_kind", "bad_field", "missing_field"):
            assert drops.get(reason, 0) > 0, (key, reason, drops)
        # the receiver kept running: valid messages sent after the garbage got through
        assert sr["accepted"][key] >= 0.9 * zr["valid_sent_per_key"], (key, sr["accepted"], zr)


def test_zpeer_exists() -> None:
    assert ZPEER.is_file() and os.access(ZPEER, os.R_OK)
