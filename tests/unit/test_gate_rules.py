"""The trimmed per-message checks decide exactly as the rules they implement say.

SequenceGate.accept and DelayEstimator.update run once per received message and were
rewritten for speed; these tests drive them with random sequences (other sessions,
duplicates, stale and far-jumping seqs, clocks that stall, jump back or return NaN,
non-finite and out-of-order times) next to a plain statement of each rule.
"""

from __future__ import annotations

import math
import random

import pytest
from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command
from bipedtele.link.transport import Stamper

pytestmark = pytest.mark.timeout(60)


class _Rules:
    """The gate's rules, one per line (module docstring of bipedtele.link.gate)."""

    def __init__(self, takeover: float, rate: float, margin: int) -> None:
        self.takeover, self.rate, self.margin = takeover, rate, margin
        self.sid: int | None = None
        self.seq = -1
        self.t = -math.inf

    def accept(self, sid: int, seq: int, now: float) -> str | None:
        elapsed = now - self.t
        silent = not elapsed <= self.takeover  # NaN: silent
        if sid != self.sid and self.sid is not None and not silent:
            return "foreign_session"
        if sid == self.sid and seq == self.seq:
            return "duplicate"
        if sid == self.sid and seq < self.seq:
            return "stale"
        if sid == self.sid and not silent and seq - self.seq > max(elapsed, 0.0) * self.rate + self.margin:
            return "seq_jump"
        self.sid, self.seq, self.t = sid, seq, now
        return None


@pytest.mark.parametrize("seed", range(20))
def test_gate_decides_as_its_rules(seed: int) -> None:
    rng = random.Random(seed)
    now = [100.0]
    gate = SequenceGate(takeover_after_s=0.5, clock=lambda: now[0], max_rate_hz=1000.0, seq_margin=10)
    rules = _Rules(0.5, 1000.0, 10)
    sids = [1, 2, 3]
    seqs = dict.fromkeys(sids, 0)
    reasons = set()
    for _ in range(3000):
        step = rng.choice([0.0, 0.0005, 0.002, 0.01, 0.3, 0.7, -0.2, math.nan])
        now[0] = 100.0 if math.isnan(now[0]) else now[0]
        now[0] = now[0] + step if not math.isnan(step) else math.nan
        sid = rng.choice(sids) if rng.random() < 0.3 else sids[0]
        seqs[sid] += rng.choice([1, 1, 1, 0, -1, -5, 20, 2000, 2**62])
        msg = Stamper(sid=sid).make(Command)
        msg = type(msg)(**{**{f: getattr(msg, f) for f in msg.__struct_fields__}, "seq": max(seqs[sid], 0)})
        got = gate.accept(msg)
        assert got == rules.accept(sid, msg.seq, now[0])
        reasons.add(got)
        if rng.random() < 0.01:
            gate.release()
            rules.t = -math.inf
    assert reasons == {None, "foreign_session", "duplicate", "stale", "seq_jump"}


def _window_mean(samples: list[tuple[float, float]], now: float, window: float) -> float | None:
    inside = [d for t, d in samples if now - window < t <= now]
    return max(sum(inside) / len(inside), 0.0) if inside else None


@pytest.mark.parametrize("seed", range(10))
def test_estimator_is_the_mean_of_clamped_delays_in_the_window(seed: int) -> None:
    rng = random.Random(seed)
    est = DelayEstimator(window_s=0.05, max_samples=40)
    kept: list[tuple[float, float]] = []
    last = -math.inf
    t = 1000.0
    for _ in range(2000):
        t += rng.choice([0.0, 0.001, 0.003, 0.02, -0.002])
        sent = t - rng.choice([0.01, 0.0, -0.005, 2e9, 0.2])
        recv = t
        if rng.random() < 0.02:
            sent = rng.choice([math.nan, math.inf, -math.inf])
        if rng.random() < 0.02:
            recv = rng.choice([math.nan, math.inf])
        est.update(sent, recv)
        if math.isfinite(sent) and math.isfinite(recv):
            last = max(last, recv)
            kept.append((last, min(max(last - sent, 0.0), DelayEstimator.MAX_SAMPLE_S)))
            kept = kept[-40:]
        got, want = est.value(last), _window_mean(kept, last, 0.05)
        assert (got is None) == (want is None)
        if got is not None and want is not None:
            assert got >= 0.0 and math.isclose(
                got, want, rel_tol=1e-9, abs_tol=1e-4
            )  # running sum of up to 1e9 s samples
