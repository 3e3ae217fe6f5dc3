"""Benchmark: round trip of a Command leader -> follower -> leader over Zenoh (loopback,
two processes) against a bare zenoh-python ping-pong of the same payload size, unsealed and
sealed (AES-256-GCM, ``bipedtele.link.auth``), the cost of sealing one message against the HMAC
it replaced, and the accuracy of `bipedtele delay-proxy`.

    .venv/bin/python bench/transport.py [--quick] [--no-proxy]

Prints p50/p99/max of the round trips at 100 Hz and 1 kHz for each, the p50 ratios
(goal: ours within 1.3x of bare; sealed and unsealed in the same run), and the proxy's measured-minus-configured delay per
direction (goal: p50 < 2 ms). Both ping-pongs use the same QoS (express, real-time
priority, drop on congestion), reply in the subscriber callback and carry the same
payload sizes (a Command out, a Feedback back), so the ratio is the cost of bipedtele's
layer (encoding, validation, gate, estimator, stamping). The two are interleaved (half a
period apart) so that both see the same machine load.

That layer is Python run once per message: from cold caches it costs several times what
a tight loop of the same calls measures (e.g. decoding a Feedback: about 6 us in a loop,
20-50 us once per period at 1 kHz-100 Hz), which is why the gap is larger than the
in-process figures suggest.
"""

from __future__ import annotations

import argparse
import functools
import signal
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.auth import MessageAuth
from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command, Feedback, encode
from bipedtele.link.receivers import LatestReceiver, Received
from bipedtele.link.transport import Keys, Publishers, Stamper
from bipedtele.link.zenohsession import open_session

BARE_PING, BARE_PONG = "benchbare/ping", "benchbare/pong"
#: The sealed runs' key (a benchmark's, not a secret) and robot id.
SEAL_KEY, SEALED = bytes(range(32)), "benchsealed"
QOS: dict[str, Any] = {
    "express": True,
    "priority": zenoh.Priority.REAL_TIME,
    "congestion_control": zenoh.CongestionControl.DROP,
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def pct(xs: list[float], q: float) -> float:
    ys = sorted(xs)
    return ys[min(len(ys) - 1, int(q * len(ys)))]


# --------------------------------------------------------------------------- echo process


def echo(listen: str, seconds: float) -> None:
    """Follower side: answers bipedtele Commands with Feedback and bare pings with pongs."""
    keys = Keys("bench")
    st = Stamper()
    with open_session(NetworkConfig(listen=[listen])) as s, Publishers(s, keys) as pubs:
        # The bare pong carries as many bytes as our Feedback (the ping's 8-byte counter,
        # then padding), so both ping-pongs move the same payload sizes each way.
        pad = b"\0" * (len(encode(st.make(Feedback, cmd_seq=1, h1_s=0.0))) - 8)
        pong = s.declare_publisher(BARE_PONG, **QOS)
        bare = s.declare_subscriber(BARE_PING, lambda sample: pong.put(sample.payload.to_bytes()[:8] + pad))

        def answer(rec: Received[Command]) -> None:
            pubs.feedback.put(st.make(Feedback, cmd_seq=rec.msg.seq, h1_s=0.0))

        auth, skeys = MessageAuth(SEAL_KEY), Keys(SEALED)
        sealed_pubs = Publishers(s, skeys, auth=auth)

        def answer_sealed(rec: Received[Command]) -> None:
            sealed_pubs.feedback.put(st.make(Feedback, cmd_seq=rec.msg.seq, h1_s=0.0))

        est = DelayEstimator(1.0)
        with (
            LatestReceiver(
                s, keys.cmd, Command, DropCounter("bench/cmd"), SequenceGate(), estimator=est, on_message=answer
            ),
            LatestReceiver(
                s,
                skeys.cmd,
                Command,
                DropCounter("bench/scmd"),
                SequenceGate(),
                estimator=est,
                on_message=answer_sealed,
                auth=auth,
            ),
            sealed_pubs,
        ):
            print("ready", flush=True)
            time.sleep(seconds)
        bare.undeclare()
        pong.undeclare()


# --------------------------------------------------------------------------- leader side


def run_pair(s: zenoh.Session, rate: float, n: int, sealed: bool) -> tuple[list[float], list[float], int]:
    """Interleaved ping-pongs: a bipedtele Command at each tick, a bare ping of the same
    size half a period later, so both see the same machine load (``sealed``: under a key)."""
    auth = MessageAuth(SEAL_KEY) if sealed else None
    keys = Keys(SEALED if sealed else "bench")
    st = Stamper()
    sent_ours: dict[int, float] = {}
    sent_bare: dict[int, float] = {}
    ours: list[float] = []
    bare: list[float] = []

    def got_ours(rec: Received[Feedback]) -> None:
        t = time.perf_counter()
        t0 = sent_ours.pop(rec.msg.cmd_seq, None)
        if t0 is not None:
            ours.append(t - t0)

    def got_bare(sample: zenoh.Sample) -> None:
        t = time.perf_counter()
        seq = struct.unpack_from("<Q", sample.payload.to_bytes())[0]
        t0 = sent_bare.pop(seq, None)
        if t0 is not None:
            bare.append(t - t0)

    def command() -> Command:
        return st.make(Command, ref=[3.0, 1.5], x_m=[0.01, 0.002], dx_m=[0.0, 0.0], h2_s=0.05, alpha_m=[2.0, 2.0])

    size = len(encode(command())) + (36 if sealed else 0)
    pad = b"\0" * (size - 8)
    est = DelayEstimator(1.0)
    pub = s.declare_publisher(BARE_PING, **QOS)
    sub = s.declare_subscriber(BARE_PONG, got_bare)
    with (
        Publishers(s, keys, auth=auth) as pubs,
        LatestReceiver(
            s,
            keys.feedback,
            Feedback,
            DropCounter("bench/fb"),
            SequenceGate(),
            estimator=est,
            on_message=got_ours,
            auth=auth,
        ),
    ):
        time.sleep(0.3)
        period, t_next = 1.0 / rate, time.perf_counter()
        for i in range(n):
            msg = command()
            sent_ours[msg.seq] = time.perf_counter()
            pubs.cmd.put(msg)
            time.sleep(max(0.0, t_next + period / 2 - time.perf_counter()))
            sent_bare[i] = time.perf_counter()
            pub.put(struct.pack("<Q", i) + pad)
            t_next += period
            time.sleep(max(0.0, t_next - time.perf_counter()))
        time.sleep(0.3)
    sub.undeclare()
    pub.undeclare()
    return ours, bare, size


def line(name: str, xs: list[float], n: int) -> str:
    ms = [x * 1e3 for x in xs]
    return f"  {name:<26} n={len(xs):5d}/{n:<5d} p50 {pct(ms, 0.5):7.3f} ms  p99 {pct(ms, 0.99):7.3f} ms  max {max(ms):7.3f} ms"


def bench_roundtrip(quick: bool) -> None:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    fb_size = len(encode(Stamper().make(Feedback, cmd_seq=1, h1_s=0.0)))
    runs = [(100.0, 300 if quick else 1000), (1000.0, 1000 if quick else 5000)]
    total = sum(n / r for r, n in runs) * 4 + 20
    child = subprocess.Popen(
        [sys.executable, __file__, "--echo", ep, "--seconds", str(total)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        print("Round trip leader -> follower -> leader, Zenoh over loopback TCP, two processes")
        with open_session(NetworkConfig(connect=[ep])) as s:
            time.sleep(0.5)
            for rate, n in runs:
                for sealed in (False, True):
                    ours, bare, size = run_pair(s, rate, n, sealed)
                    what = "sealed (AES-256-GCM)" if sealed else "unsealed"
                    back = fb_size + (36 if sealed else 0)
                    print(f" {rate:.0f} Hz, {what}, payload {size} bytes out, {back} bytes back:")
                    print(line("bare zenoh ping-pong", bare, n))
                    print(line("bipedtele Command/Feedback", ours, n))
                    ratio = statistics.median(ours) / statistics.median(bare)
                    print(f"  ratio p50 ours/bare = {ratio:.2f} (goal <= 1.3)")
    finally:
        child.send_signal(signal.SIGTERM)
        child.wait(10)


# --------------------------------------------------------------------------- sealing, per message


def _hmac_sign(key: bytes, topic: str) -> Any:
    """The HMAC-SHA256 framing sealing replaced (its precomputed inner and outer states)."""
    import hashlib

    block = key.ljust(64, b"\0")
    inner = hashlib.sha256(bytes(b ^ 0x36 for b in block))
    inner.update(b"\xc1BT\x01" + topic.encode() + b"\0")
    outer = hashlib.sha256(bytes(b ^ 0x5C for b in block))

    def sign(body: bytes) -> bytes:
        i = inner.copy()
        i.update(body)
        o = outer.copy()
        o.update(i.digest())
        return b"\xc1BT\x01" + o.digest() + body

    return sign


def bench_seal(quick: bool) -> None:
    """Per-message cost of sealing and opening a Command, a Feedback and a video frame, side by side."""
    import hmac as _hmac

    st, topic, n = Stamper(), "bipedtele/nao1/cmd", 2000 if quick else 20000
    auth, sign = MessageAuth(SEAL_KEY), _hmac_sign(SEAL_KEY, topic)
    bodies = {
        "Command": encode(st.make(Command, ref=[3.0, 1.5], x_m=[0.01, 0.002], alpha_m=[2.0, 2.0])),
        "Feedback": encode(st.make(Feedback, cmd_seq=1, h1_s=0.0)),
        "video 40 kB": bytes(40_000),
    }
    print(f"Per message, in a loop of {n} (us): HMAC-SHA256 sign / verify  vs  AES-256-GCM seal / open")
    for name, body in bodies.items():
        signed, sealed = sign(body), auth.sign(body, topic)

        def verify(p: bytes = signed, b: bytes = body) -> bool:
            return _hmac.compare_digest(sign(b)[4:36], p[4:36])

        fns = (
            functools.partial(sign, body),
            verify,
            functools.partial(auth.sign, body, topic),
            functools.partial(auth.verify, sealed, topic),
        )
        t = []
        for fn in fns:
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            t.append((time.perf_counter() - t0) / n * 1e6)
        print(f"  {name:<12} {len(body):6d} bytes:  HMAC {t[0]:6.2f} / {t[1]:6.2f}   AES-GCM {t[2]:6.2f} / {t[3]:6.2f}")


# --------------------------------------------------------------------------- proxy accuracy

FRAME = struct.Struct("<dI")


def _read_frames(sock: socket.socket, out: list[float], n: int, expected: float) -> None:
    buf = b""
    while len(out) < n:
        data = sock.recv(65536)
        t = time.time()
        if not data:
            return
        buf += data
        while len(buf) >= FRAME.size:
            t_sent, _ = FRAME.unpack_from(buf)
            buf = buf[FRAME.size :]
            out.append(t - t_sent - expected)


def _send_frames(sock: socket.socket, rate: float, n: int) -> None:
    period, t_next = 1.0 / rate, time.perf_counter()
    for i in range(n):
        sock.sendall(FRAME.pack(time.time(), i))
        t_next += period
        time.sleep(max(0.0, t_next - time.perf_counter()))


def bench_proxy(quick: bool) -> None:
    fwd, bwd = 0.050, 0.080
    server = socket.create_server(("127.0.0.1", 0))
    target = server.getsockname()[1]
    port = free_port()
    proxy = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "--log-level",
            "WARNING",
            "delay-proxy",
            "--listen",
            f"127.0.0.1:{port}",
            "--target",
            f"127.0.0.1:{target}",
            "--forward",
            f"const:{fwd * 1e3:g}ms",
            "--backward",
            f"const:{bwd * 1e3:g}ms",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proxy.stdout is not None and "listening" in proxy.stdout.readline()
        print(
            f"\ndelay-proxy accuracy: measured minus configured one-way delay (forward {fwd * 1e3:g} ms, backward {bwd * 1e3:g} ms)"
        )
        for rate, n in ((100.0, 300 if quick else 1000), (1000.0, 1000 if quick else 5000)):
            client = socket.create_connection(("127.0.0.1", port))
            conn, _ = server.accept()
            for s in (client, conn):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            f_err: list[float] = []
            b_err: list[float] = []
            readers = [
                threading.Thread(target=_read_frames, args=(conn, f_err, n, fwd)),
                threading.Thread(target=_read_frames, args=(client, b_err, n, bwd)),
            ]
            writers = [
                threading.Thread(target=_send_frames, args=(client, rate, n)),
                threading.Thread(target=_send_frames, args=(conn, rate, n)),
            ]
            for t in readers + writers:
                t.start()
            for t in readers + writers:
                t.join(timeout=n / rate + 10)
            client.close()
            conn.close()
            for name, err in (("forward", f_err), ("backward", b_err)):
                ms = [e * 1e3 for e in err]
                print(
                    f"  {rate:5.0f} Hz {name:<8} n={len(ms):5d}  error p50 {pct(ms, 0.5):6.3f} ms  p99 {pct(ms, 0.99):6.3f} ms  "
                    f"min {min(ms):6.3f} ms  max {max(ms):6.3f} ms  (goal p50 < 2 ms)"
                )
    finally:
        proxy.send_signal(signal.SIGINT)
        proxy.wait(10)
        server.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer samples")
    ap.add_argument("--no-proxy", action="store_true", help="the round trips only (skip the delay-proxy accuracy)")
    ap.add_argument("--echo", metavar="ENDPOINT", help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=60.0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.echo:
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
        echo(args.echo, args.seconds)
        return 0
    print(f"bench/transport.py  (python {sys.version.split()[0]}, zenoh {Path(zenoh.__file__).parent.name})")
    bench_seal(args.quick)
    bench_roundtrip(args.quick)
    if not args.no_proxy:
        bench_proxy(args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
