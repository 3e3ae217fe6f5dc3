"""Publish invalid payloads on every key of one robot (an e2e test's hostile peer).

    python tests/e2e/garbage.py --connect tcp/127.0.0.1:7447 --count 200 [--user U --password P]

Publishes ``--count`` payloads on each of ``cmd``, ``feedback``, ``video``, ``clock`` and
``status`` (bounded count, paced over at most ``--seconds``), cycling through kinds of
garbage that no receiver may accept: random bytes, msgpack that is not a map, maps
without the envelope, a wrong schema version, an unknown or wrong kind for the key,
fields of the wrong type, out-of-range and non-finite values, and truncated valid
messages. Prints one JSON line ``{"sent": {key: n}, "kinds": {kind: n}}``.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from collections import Counter
from collections.abc import Callable

import msgpack
import zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.messages import (
    SCHEMA_VERSION,
    ClockPing,
    Command,
    Feedback,
    Message,
    Status,
    VideoFrame,
    encode,
)
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session

# What each receiver expects on each key; a *valid* message of another kind is garbage there.
WRONG_KIND: dict[str, type[Message]] = {
    "cmd": Feedback,
    "feedback": Command,
    "video": Status,
    "clock": Command,
    "status": Command,
}
RIGHT_KIND: dict[str, type[Message]] = {
    "cmd": Command,
    "feedback": Feedback,
    "video": VideoFrame,
    "clock": ClockPing,
    "status": Status,
}


def _pack(obj: object) -> bytes:
    return bytes(msgpack.packb(obj, use_bin_type=True))


def _valid_dict(cls: type[Message], rng: random.Random) -> dict[str, object]:
    data: dict[str, object] = msgpack.unpackb(encode(cls(sid=rng.randrange(1, 2**32), seq=1, t=time.time())))
    return data


def _generators(key: str, rng: random.Random) -> list[tuple[str, Callable[[], bytes]]]:
    right = RIGHT_KIND[key]

    def bad_field(value: object, name: str) -> Callable[[], bytes]:
        def make() -> bytes:
            d = _valid_dict(right, rng)
            d[name] = value
            return _pack(d)

        return make

    # a field of the right kind that is a number list on Command/Feedback, "t" elsewhere
    list_field = "ref" if right in (Command, Feedback) else "t"
    gens: list[tuple[str, Callable[[], bytes]]] = [
        ("random_bytes", lambda: rng.randbytes(rng.randrange(0, 300))),
        ("empty", lambda: b""),
        ("not_a_map", lambda: _pack(rng.choice([42, "cmd", [1, 2, 3], None, 3.5, b"\x00"]))),
        ("no_envelope", lambda: _pack({"ref": [1.0, 2.0], "seq": 3})),
        ("bad_version", lambda: _pack({**_valid_dict(right, rng), "v": SCHEMA_VERSION + 7})),
        ("unknown_kind", lambda: _pack({**_valid_dict(right, rng), "k": "launch"})),
        ("wrong_kind", lambda: encode(WRONG_KIND[key](sid=rng.randrange(1, 2**32), seq=1, t=time.time()))),
        ("wrong_type", bad_field("fast", list_field)),
        ("nan_time", bad_field(float("nan"), "t")),
        ("inf_value", bad_field([float("inf"), 0.0] if list_field == "ref" else float("inf"), list_field)),
        ("huge_value", bad_field([1e12, 0.0] if list_field == "ref" else 1e300, list_field)),
        ("negative_seq", bad_field(-5, "seq")),
        ("missing_field", lambda: _pack({k: v for k, v in _valid_dict(right, rng).items() if k != "seq"})),
        ("truncated", lambda: encode(right(sid=rng.randrange(1, 2**32), seq=9, t=time.time()))[:-3]),
        ("deep_nesting", lambda: b"\x91" * 2000 + b"\xc0"),
        ("bad_utf8", lambda: b"\x81\xa1k\xa3\xff\xfe\xfd"),
    ]
    return gens


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", required=True, help="router endpoint, e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--robot-id", default="nao1")
    ap.add_argument("--count", type=int, default=200, help="payloads per key (1-10000)")
    ap.add_argument("--seconds", type=float, default=2.0, help="spread them over this long (at most, 0-60)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keys", default="cmd,feedback,video,clock,status")
    ap.add_argument("--user", default="", help="log in as this user (routers with authentication)")
    ap.add_argument("--password", default="")
    args = ap.parse_args(argv)
    if not 1 <= args.count <= 10_000 or not 0 <= args.seconds <= 60:
        ap.error("--count: 1-10000, --seconds: 0-60")
    rng = random.Random(args.seed)
    keys = Keys(args.robot_id)
    names = args.keys.split(",")
    sent: Counter[str] = Counter()
    kinds: Counter[str] = Counter()
    net = NetworkConfig(mode="client", connect=[args.connect], timeout_s=10.0, user=args.user, password=args.password)
    with open_session(net) as session:
        # Block rather than drop on congestion: every payload must reach the receivers
        # so that the test can compare counts.
        pubs = {
            n: session.declare_publisher(getattr(keys, n), congestion_control=zenoh.CongestionControl.BLOCK)
            for n in names
        }
        gens = {n: _generators(n, rng) for n in names}
        pause = args.seconds / args.count
        for i in range(args.count):
            for n in names:
                kind, make = gens[n][i % len(gens[n])]
                pubs[n].put(make())
                sent[n] += 1
                kinds[kind] += 1
            time.sleep(pause)
        time.sleep(0.5)  # let the last ones leave before the session closes
        for p in pubs.values():
            p.undeclare()
    sys.stdout.write(json.dumps({"sent": dict(sent), "kinds": dict(kinds)}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
