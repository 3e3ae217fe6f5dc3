"""Benchmark: per-message cost of SequenceGate.accept and DelayEstimator.update.

    .venv/bin/python bench/gate_clock.py [--n 200000]

Prints the mean cost per call [us] in a tight loop (warm caches) and when each call is
separated by a sweep over a few MB of memory (cold caches, closer to one call per
Zenoh callback at 100 Hz). These are the two checks a receiver runs per message after
decoding; bench/transport.py measures the whole round trip.
"""

from __future__ import annotations

import argparse
import time

from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command
from bipedtele.link.transport import Stamper


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200_000, help="calls in the warm loop")
    ap.add_argument("--cold", type=int, default=2_000, help="calls in the cold loop")
    args = ap.parse_args()
    st = Stamper()
    msgs = [st.make(Command) for _ in range(args.n)]
    gate = SequenceGate()
    t0 = time.perf_counter()
    for m in msgs:
        gate.accept(m)
    gate_warm = (time.perf_counter() - t0) / args.n * 1e6
    est = DelayEstimator(1.0)
    now = time.time()
    t0 = time.perf_counter()
    for i in range(args.n):
        est.update(now + i * 1e-5 - 0.001, now + i * 1e-5)
    est_warm = (time.perf_counter() - t0) / args.n * 1e6

    junk = bytearray(8 << 20)
    gate, est = SequenceGate(), DelayEstimator(1.0)
    g_total = e_total = 0.0
    for i in range(args.cold):
        junk[::64] = bytes(len(junk[::64]))  # evict the caches
        m = msgs[i]
        t0 = time.perf_counter()
        gate.accept(m)
        t1 = time.perf_counter()
        est.update(now + i * 1e-3 - 0.001, now + i * 1e-3)
        t2 = time.perf_counter()
        g_total += t1 - t0
        e_total += t2 - t1
    print(f"SequenceGate.accept     warm {gate_warm:6.3f} us   cold {g_total / args.cold * 1e6:6.3f} us")
    print(f"DelayEstimator.update   warm {est_warm:6.3f} us   cold {e_total / args.cold * 1e6:6.3f} us")


if __name__ == "__main__":
    main()
