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
from bipedtele.link.delaymodels import TraceDelay, parse_delay_model

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
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "delay-proxy",
            "--listen",
            f"127.0.0.1:{port}",
            "--target",
            f"127.0.0.1:{target}",
            "--forward",
            forward,
            "--backward",
            backward,
            *extra,
        ],
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


# --------------------------------------------------------------------------- MAC, send times

SENDER = r'''
"""Replays a JSON spec on a real Zenoh session (blocking congestion control: nothing lost)."""
import json, sys, time
import msgspec
import zenoh
from bipedtele.link.auth import load_message_auth
from bipedtele.link.messages import Command, encode
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.transport import Keys, Publishers, Stamper, open_session

spec = json.loads(open(sys.argv[1]).read())
net = NetworkConfig(connect=[spec["connect"]], message_key_file=spec.get("key_file", ""))
block = zenoh.CongestionControl.BLOCK
with open_session(net) as s:
    time.sleep(0.5)
    st = Stamper()
    for key, hexpayload in spec.get("raw", []):
        s.put(key, bytes.fromhex(hexpayload), congestion_control=block)
        time.sleep(0.002)
    for offset in spec.get("stamped", []):  # send time = this host's clock + offset
        msg = msgspec.structs.replace(st.make(Command), t=time.time() + offset)
        s.put("bipedtele/nao1/cmd", encode(msg), congestion_control=block)
        time.sleep(0.002)
    with Publishers(s, Keys("nao1"), auth=load_message_auth(net)) as pubs:
        for _ in range(spec.get("signed", 0)):
            pubs.cmd.put(st.make(Command, ref=[1.0, 0.0]))
            time.sleep(0.01)
    time.sleep(0.5)
'''


def run_sender(tmp_path: Path, spec: dict[str, Any]) -> None:
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    (tmp_path / "sender.py").write_text(SENDER)
    res = subprocess.run(
        [sys.executable, str(tmp_path / "sender.py"), str(tmp_path / "spec.json")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 0, res.stderr[-3000:]


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_mac_drops_unsigned_and_forged_messages_before_decoding(tmp_path: Path) -> None:
    from bipedtele.config.sections import NetworkConfig
    from bipedtele.link.auth import MessageAuth, load_message_auth, write_message_key
    from bipedtele.link.drops import DropCounter
    from bipedtele.link.messages import Command, encode
    from bipedtele.link.receivers import MessageReceiver
    from bipedtele.link.transport import Keys, Stamper
    from bipedtele.link.zenohsession import open_session

    key_file = tmp_path / "message.key"
    write_message_key(key_file)
    auth = load_message_auth(NetworkConfig(message_key_file=str(key_file)))
    assert auth is not None
    wrong = MessageAuth(os.urandom(32))
    keys, st = Keys("nao1"), Stamper()
    rounds = 10
    raw: list[tuple[str, str]] = []
    for _ in range(rounds):
        body = encode(st.make(Command, ref=[6.0, 0.0]))
        flipped = bytearray(auth.sign(body, keys.cmd))
        flipped[-3] ^= 0x01
        garbage = os.urandom(40)
        for payload in (
            body,  # unsigned: no_mac
            wrong.sign(body, keys.cmd),  # another key: bad_mac
            bytes(flipped),  # altered: bad_mac
            auth.sign(body, "bipedtele/nao2/cmd"),  # signed for another robot: bad_mac
            wrong.sign(garbage, keys.cmd),  # garbage under a wrong tag: bad_mac, never decoded
            auth.sign(garbage, keys.cmd),  # garbage under a right tag: decoded, not_msgpack
            auth.sign(encode(st.make(Command, ref=[1.0, 0.0])), keys.cmd),  # valid
        ):
            raw.append((keys.cmd, payload.hex()))
    port = free_port()
    with_key, without_key = DropCounter("with-key"), DropCounter("without-key")
    with (
        open_session(NetworkConfig(listen=[f"tcp/127.0.0.1:{port}"])) as s,
        MessageReceiver(s, keys.cmd, Command, with_key, auth=auth) as rx,
        MessageReceiver(s, keys.cmd, Command, without_key) as plain,
    ):
        run_sender(tmp_path, {"connect": f"tcp/127.0.0.1:{port}", "key_file": str(key_file), "raw": raw, "signed": 20})
        time.sleep(0.3)
        got = rx.drain()
        plain_got = plain.drain()
    counts = with_key.counts()
    assert counts == {"no_mac": rounds, "bad_mac": 4 * rounds, "not_msgpack": rounds}, counts
    # valid ones: the raw signed ones, and those Publishers(auth=...) signed (control
    # publishers drop on congestion, so at least most of the 20)
    assert all(r.msg.ref == [1.0, 0.0] for r in got)
    assert len(got) >= rounds + 10, len(got)
    # a receiver without the key takes no signed payload for a message
    assert [r.msg.ref for r in plain_got] == [[6.0, 0.0]] * rounds
    # ...and says why: the peer signs, this side has no key (not "not_msgpack")
    assert without_key.counts() == {"mac_unexpected": 6 * rounds + len(got) - rounds}, without_key.counts()


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_send_time_sanity(tmp_path: Path) -> None:
    from bipedtele.config.sections import NetworkConfig
    from bipedtele.link.clock import ClockSync
    from bipedtele.link.delayestimate import DelayEstimator
    from bipedtele.link.drops import DropCounter
    from bipedtele.link.messages import Command
    from bipedtele.link.receivers import MessageReceiver
    from bipedtele.link.transport import Keys
    from bipedtele.link.zenohsession import open_session

    keys = Keys("nao1")
    unsynced = ClockSync()
    synced = ClockSync()
    assert synced.on_pong(100.0, 110.0, 110.0, 100.0) is not None  # the peer's clock is 10 s ahead
    est_a, est_c = DelayEstimator(30.0), DelayEstimator(30.0)
    drops = {n: DropCounter(n) for n in "abc"}
    port = free_port()
    with (
        open_session(NetworkConfig(listen=[f"tcp/127.0.0.1:{port}"])) as s,
        MessageReceiver(s, keys.cmd, Command, drops["a"], estimator=est_a, max_future_s=0.25) as a,
        MessageReceiver(s, keys.cmd, Command, drops["b"], clock_sync=unsynced, max_future_s=0.25) as b,
        MessageReceiver(s, keys.cmd, Command, drops["c"], estimator=est_c, clock_sync=synced, max_future_s=0.25) as c,
    ):
        run_sender(tmp_path, {"connect": f"tcp/127.0.0.1:{port}", "stamped": [0.2, 0.2, 1.0, 10.0, 10.2, 11.0]})
        time.sleep(0.3)
        got = {"a": a.drain(), "b": b.drain(), "c": c.drain()}
        now = time.time()
        h_a, h_c = est_a.value(now), est_c.value(now)
    # a: one clock; 0.2 s ahead is within the tolerance (delay counted as 0), the rest is future
    assert len(got["a"]) == 2 and drops["a"].counts() == {"future": 4}, drops["a"].counts()
    assert h_a == 0.0  # never negative, though both messages seemed to arrive before they were sent
    # b: the peer's clock offset is unknown yet: nothing is taken
    assert got["b"] == [] and drops["b"].counts() == {"clock_not_synced": 6}
    # c: converted to the local clock first (-10 s): only the one 1 s ahead is future
    assert len(got["c"]) == 5 and drops["c"].counts() == {"future": 1}, drops["c"].counts()
    assert h_c is not None and h_c >= 0.0
