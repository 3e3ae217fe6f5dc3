"""Token bucket (the kernel's tbf) and mahimahi capacity traces (common/link/shapers.py), deterministic."""

from __future__ import annotations

from pathlib import Path

import pytest
from bipedtele.config.profile import ConfigError
from bipedtele.link.impairments import RateQueue
from bipedtele.link.shapers import (
    MTU,
    SHIPPED_MAHIMAHI,
    SHIPPED_RECIPES,
    TokenBucket,
    TraceRate,
    load_mahimahi,
    mahimahi_stats,
    synthetic_cellular,
)
from bipedtele.tools.linkemu import build_shaper

DATA = Path(__file__).resolve().parents[2] / "common" / "data"


def test_a_token_bucket_lets_its_burst_pass_at_once_then_holds_the_rate() -> None:
    """600 kbit/s, 16 kB burst, after a quiet spell: the first 10 frames of 1500 B leave at
    once (a FIFO at the same rate spreads them 20 ms apart), the 11th waits for tokens,
    and over a long run the rate is the token rate."""
    tb, fifo = TokenBucket(600_000.0, 16_000, 64_000), RateQueue(600_000.0, 64_000)
    tb_leave = [tb.enqueue(10.0, 1500) for _ in range(12)]
    fifo_leave = [fifo.enqueue(10.0, 1500) for _ in range(12)]
    assert all(x == 10.0 for x in tb_leave[:10])
    assert tb_leave[10] == pytest.approx(10.0 + (11 * 1500 - 16_000) * 8 / 600_000.0)
    assert fifo_leave[0] == pytest.approx(10.02) and fifo_leave[9] == pytest.approx(10.2)
    t, last = 20.0, None
    for _ in range(4000):  # 10 s of 2x the rate: the queue fills, the rate binds
        last = tb.enqueue(t, 1500) or last
        t += 0.0025 / 2
    assert last is not None and tb.backlog_max <= 64_000


def test_a_token_bucket_drops_at_its_limit() -> None:
    tb = TokenBucket(100_000.0, 3000, 6000)
    got = [tb.enqueue(0.0, 1500) for _ in range(8)]
    assert got[:6] == [0.0, 0.0, pytest.approx(0.12), pytest.approx(0.24), pytest.approx(0.36), pytest.approx(0.48)]
    assert got[6] is None and got[7] is None


def test_a_trace_delivers_at_its_opportunities_and_unused_ones_are_lost() -> None:
    tr = TraceRate([10, 20, 30, 1000], 10_000)
    assert tr.enqueue(0.0, 1000) == pytest.approx(0.010)
    assert tr.enqueue(0.0, 1000) == pytest.approx(0.020)  # 500 B left in the first, 500 in the second
    assert tr.enqueue(0.5, 100) == pytest.approx(1.0)  # the trace's next opportunity
    assert tr.enqueue(1.0, 3000) == pytest.approx(1.020)  # repeats with its 1 s period; two MTUs from 1.010
    assert tr.enqueue(5.0, MTU) == pytest.approx(5.010)
    full = TraceRate([1000], 3000)
    assert [full.enqueue(0.0, 1500) for _ in range(3)][2] is None  # tail drop


@pytest.mark.parametrize("name", sorted(SHIPPED_MAHIMAHI))
def test_the_shipped_traces_are_regenerated_byte_for_byte_with_their_statistics(name: str) -> None:
    trace = synthetic_cellular(*SHIPPED_RECIPES[name])
    assert (DATA / SHIPPED_MAHIMAHI[name]).read_text() == "".join(f"{x}\n" for x in trace)
    assert load_mahimahi(name) == trace
    st = mahimahi_stats(trace)
    mean, low = {"lte": (1.95e6, 4.0), "3g": (0.52e6, 9.0)}[name]
    assert st["mean_bps"] == pytest.approx(mean, rel=0.01) and st["longest_low_s"] == low and st["period_s"] == 90.0


def test_bad_shaper_specs_are_one_line_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("10\nabc\n")
    for rate, burst, what in (
        ("mahimahi:" + str(bad), None, "not an integer ms"),
        ("mahimahi:/nonexistent", None, "cannot read"),
        ("none", "16kB", "without a rate"),
        ("mahimahi:lte", "16kB", "a burst with a rate"),
    ):
        with pytest.raises(ConfigError, match=what) as err:
            build_shaper(rate, "64kB", burst)
        assert "\n" not in str(err.value) and "allowed" in str(err.value)
    assert isinstance(build_shaper("600kbit", "64kB", "16kB"), TokenBucket)
    assert isinstance(build_shaper("600kbit"), RateQueue) and build_shaper("none") is None
    assert isinstance(build_shaper("mahimahi:3g", "200kB"), TraceRate)
