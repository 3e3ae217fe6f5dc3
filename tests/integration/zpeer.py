"""A small leader/follower/sink/fuzz peer for the transport integration tests.

Run as a separate process (``python zpeer.py ROLE ...``); it opens a real Zenoh session,
runs for a bounded ``--duration`` and writes what it saw as JSON to ``--out``.

Roles
-----
leader
    Publishes Commands at ``--rate`` carrying its h2 estimate; estimates h2 from the
    feedback it receives.
follower
    Publishes Feedback at ``--rate`` carrying its h1 estimate; estimates h1 from the
    commands it receives.
sink
    Subscribes to every key with the right message type and counts what it accepts
    and drops.
fuzz
    Publishes random bytes, random msgpack and malformed messages on every key, then
    valid messages, then keeps publishing valid messages.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from typing import Any

import msgpack
import zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import (
    ClockPing,
    ClockPong,
    Command,
    Feedback,
    Message,
    Status,
    VideoFrame,
    encode,
)
from bipedtele.link.receivers import LatestReceiver, MessageReceiver
from bipedtele.link.transport import Keys, MessagePublisher, Publishers, Stamper, declare_presence
from bipedtele.link.zenohsession import open_session

KEY_TYPES: dict[str, Any] = {
    "cmd": Command,
    "feedback": Feedback,
    "video": VideoFrame,
    "clock": (ClockPing, ClockPong),
    "status": Status,
}


def _valid(name: str, st: Stamper) -> Message:
    if name == "cmd":
        return st.make(Command, ref=[1.0, 0.5])
    if name == "feedback":
        return st.make(Feedback, z_e=[1.0, 0.0])
    if name == "video":
        return st.make(VideoFrame, jpeg=b"\xff\xd8\xff\xd9")
    if name == "clock":
        return st.make(ClockPing)
    return st.make(Status, role="leader", state="running")


def _malformed(rng: random.Random, name: str, st: Stamper) -> list[bytes]:
    """Bad payloads for one key, built on a valid message of that key's type."""
    good = encode(_valid(name, st))
    base = msgpack.unpackb(good)
    out = [
        rng.randbytes(rng.randint(0, 64)),
        b"",
        msgpack.packb([1, 2, 3]),
        msgpack.packb({**base, "v": 99}),
        msgpack.packb({**base, "k": "nope"}),
        msgpack.packb({**base, "t": float("nan")}),
        msgpack.packb({**base, "t": -5.0}),
        msgpack.packb({k: v for k, v in base.items() if k != "seq"}),
        msgpack.packb({**base, "seq": -1}),
        msgpack.packb({**base, "sid": "me"}),
        good[:-3],
    ]
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("role", choices=["leader", "follower", "sink", "fuzz"])
    ap.add_argument("--listen", action="append", default=[])
    ap.add_argument("--connect", action="append", default=[])
    ap.add_argument("--mode", default="peer")
    ap.add_argument("--robot", default="nao1")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--window", type=float, default=1.0)
    ap.add_argument("--out", required=True)
    ap.add_argument("--user", default="")
    ap.add_argument("--password", default="")
    args = ap.parse_args()

    net = NetworkConfig(
        mode=args.mode, listen=args.listen, connect=args.connect, user=args.user, password=args.password
    )
    keys = Keys(args.robot)
    st = Stamper()
    result: dict[str, Any] = {"role": args.role, "series": [], "sent": 0}
    t_end = time.monotonic() + args.duration
    period = 1.0 / args.rate
    with (
        open_session(net) as session,
        Publishers(session, keys) as pubs,
        declare_presence(session, keys, "leader" if args.role in ("leader", "fuzz") else "follower"),
    ):
        if args.role in ("leader", "follower"):
            rx_key, rx_type = ("feedback", Feedback) if args.role == "leader" else ("cmd", Command)
            est = DelayEstimator(args.window)
            drops = DropCounter(f"{args.role}/{rx_key}")
            with LatestReceiver(session, getattr(keys, rx_key), rx_type, drops, SequenceGate(), estimator=est) as rx:
                first = None
                while time.monotonic() < t_end:
                    now = time.time()
                    h = est.value(now)
                    if rx.count and first is None:
                        first = rx.latest().t_recv
                    if h is not None:
                        result["series"].append([now, h])
                    if args.role == "leader":
                        pubs.cmd.put(st.make(Command, ref=[2.0, 1.0], h2_s=h or 0.0))
                    else:
                        got = rx.latest()
                        pubs.feedback.put(
                            st.make(
                                Feedback,
                                z_e=[1.0, 0.0],
                                h1_s=h or 0.0,
                                cmd_seq=got.msg.seq if got else 0,
                            )
                        )
                    result["sent"] += 1
                    time.sleep(max(0.0, period - (time.time() - now)))
                result.update(first_recv=first, received=rx.count, drops=drops.counts())
                last = rx.latest()
                if last is not None:
                    result["last_msg"] = {
                        k: getattr(last.msg, k) for k in ("seq", "h2_s", "h1_s", "cmd_seq") if hasattr(last.msg, k)
                    }
        elif args.role == "sink":
            counters = {k: DropCounter(f"sink/{k}", log_interval_s=60.0) for k in KEY_TYPES}
            rxs = {
                k: MessageReceiver(session, getattr(keys, k), t, counters[k], SequenceGate(), maxlen=100000)
                for k, t in KEY_TYPES.items()
            }
            try:
                while time.monotonic() < t_end:
                    time.sleep(0.05)
                result["accepted"] = {k: r.count for k, r in rxs.items()}
                result["drops"] = {k: c.counts() for k, c in counters.items()}
            finally:
                for r in rxs.values():
                    r.close()
        else:  # fuzz
            rng = random.Random(1)
            time.sleep(0.5)  # let the subscriptions propagate
            bad = 0
            # Block rather than drop on congestion (unlike the control publishers): a burst
            # of garbage must reach the receivers for the counts to be checked exactly.
            blocking = {
                n: session.declare_publisher(getattr(keys, n), congestion_control=zenoh.CongestionControl.BLOCK)
                for n in KEY_TYPES
            }
            for name in KEY_TYPES:
                pub = MessagePublisher(blocking[name], getattr(keys, name))
                for payload in _malformed(rng, name, st):
                    pub.put_bytes(payload)
                    bad += 1
                for _ in range(20):
                    pub.put_bytes(rng.randbytes(rng.randint(1, 200)))
                    bad += 1
                # valid kind on the wrong key
                pub.put(st.make(Status if name != "status" else Command))
                bad += 1
            result["bad_sent_per_key"] = bad // len(KEY_TYPES)
            valid = 0
            while time.monotonic() < t_end:
                for name in KEY_TYPES:
                    getattr(pubs, name).put(_valid(name, st))
                valid += 1
                time.sleep(0.02)
            result["valid_sent_per_key"] = valid
    with open(args.out, "w") as f:
        json.dump(result, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
