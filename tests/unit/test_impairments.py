"""The per-packet impairment model, with made-up arrival times (no sockets, no clock)."""

from __future__ import annotations

import itertools
import math

import pytest
from bipedtele.config.profile import ConfigError
from bipedtele.link.delaymodels import ConstDelay, TraceDelay, parse_delay_model
from bipedtele.link.impairments import (
    Direction,
    GilbertElliott,
    NoLoss,
    Outage,
    RandomLoss,
    RateQueue,
    parse_loss,
    parse_outage,
    parse_queue,
    parse_rate,
)


def _binomial_bounds(n: int, p: float, z: float = 5.0) -> tuple[float, float]:
    """Fraction bounds: mean +- z standard deviations of a binomial(n, p) fraction."""
    sd = math.sqrt(p * (1 - p) / n)
    return p - z * sd, p + z * sd


def test_random_loss_fraction_within_binomial_bounds_and_seeded() -> None:
    n = 20000
    d = Direction(ConstDelay(0.0), RandomLoss(0.2, seed=7))
    lost = sum(d.admit(k * 1e-3, 100).release_s is None for k in range(n))
    lo, hi = _binomial_bounds(n, 0.2)
    assert lo <= lost / n <= hi
    assert d.counters.dropped["loss"] == lost and d.counters.forwarded == n - lost
    again = RandomLoss(0.2, seed=7)
    first = RandomLoss(0.2, seed=7)
    assert [again.lost() for _ in range(500)] == [first.lost() for _ in range(500)]


def test_gilbert_elliott_bursts_and_mean_loss() -> None:
    ge = GilbertElliott(p=0.01, r=0.25, loss_bad=1.0, loss_good=0.0, seed=3)
    seq = [ge.lost() for _ in range(200_000)]
    frac = sum(seq) / len(seq)
    assert ge.mean_loss == pytest.approx(0.01 / 0.26)
    assert frac == pytest.approx(ge.mean_loss, rel=0.1)
    bursts, run = [], 0
    for x in seq:
        if x:
            run += 1
        elif run:
            bursts.append(run)
            run = 0
    mean_burst = sum(bursts) / len(bursts)
    assert mean_burst == pytest.approx(1 / 0.25, rel=0.1)  # geometric runs, mean 1/r
    # Random loss at the same mean has runs of about 1 / (1 - p) ~ 1.04 frames.
    assert mean_burst > 3.0


def test_gilbert_elliott_good_state_loss() -> None:
    ge = GilbertElliott(p=0.0, r=1.0, loss_bad=1.0, loss_good=0.1, seed=1)  # always good
    frac = sum(ge.lost() for _ in range(20000)) / 20000
    lo, hi = _binomial_bounds(20000, 0.1)
    assert lo <= frac <= hi


def test_rate_cap_serialisation_times() -> None:
    q = RateQueue(rate_bps=1e6, capacity=100_000)
    # 1250 bytes at 1 Mbit/s: 10 ms each; back-to-back arrivals queue up.
    finishes = [q.enqueue(0.0, 1250) for _ in range(3)]
    assert finishes == pytest.approx([0.010, 0.020, 0.030])
    assert q.backlog == 3750 and q.backlog_max == 3750
    # After an idle gap serialisation starts at the arrival.
    assert q.enqueue(1.0, 125) == pytest.approx(1.001)
    assert q.backlog == 125


def test_queue_overflow_tail_drops_and_counts() -> None:
    d = Direction(ConstDelay(0.05), rate=RateQueue(rate_bps=8e5, capacity=4500))  # 1500 B = 15 ms
    verdicts = [d.admit(0.0, 1500) for _ in range(5)]
    assert [v.reason for v in verdicts] == [None, None, None, "queue", "queue"]
    assert [v.release_s for v in verdicts[:3]] == pytest.approx([0.065, 0.080, 0.095])
    assert d.counters.dropped == {"loss": 0, "queue": 2, "outage": 0}
    assert d.counters.queue_bytes_max == 4500
    # Once the first frame is out, there is room for one more.
    assert d.admit(0.0151, 1500).release_s == pytest.approx(0.110)


def test_outage_windows_single_and_periodic() -> None:
    once = Outage(at_s=30.0, for_s=3.0)
    assert [once.active(t) for t in (29.99, 30.0, 32.99, 33.0, 90.0)] == [False, True, True, False, False]
    every = parse_outage("at=10s,for=1s,every=5s")
    assert [every.active(t) for t in (9.9, 10.5, 11.5, 15.2, 16.1, 20.0)] == [False, True, False, True, False, True]
    d = Direction(ConstDelay(0.1), outages=[once])
    fates = [d.admit(t, 100).reason for t in (29.0, 30.0, 31.0, 33.5)]
    assert fates == [None, "outage", "outage", None]
    assert d.counters.dropped["outage"] == 2 and d.counters.forwarded == 2


def test_no_reordering_when_the_delay_falls() -> None:
    # The delay falls 500 ms -> 100 ms within 0.1 s: later frames wait behind earlier ones.
    trace = TraceDelay([0.0, 0.1, 10.0], [0.5, 0.1, 0.1])
    d = Direction(trace)
    times = [k * 0.005 for k in range(100)]
    releases = [d.admit(t, 100).release_s for t in times]
    assert all(r is not None for r in releases)
    rel = [r for r in releases if r is not None]
    assert all(b >= a for a, b in itertools.pairwise(rel))
    assert rel[0] == pytest.approx(0.5)
    assert rel[-1] == pytest.approx(times[-1] + 0.1)


def test_const_delay_release_and_delay_models_from_specs() -> None:
    d = Direction(parse_delay_model("const:150ms"), NoLoss())
    assert d.admit(2.0, 60).release_s == pytest.approx(2.15)
    assert d.counters.forwarded_bytes == 60


def test_loss_specs() -> None:
    assert isinstance(parse_loss("none"), NoLoss)
    m = parse_loss("1%")
    assert isinstance(m, RandomLoss) and m.p == pytest.approx(0.01)
    assert isinstance(parse_loss("0.2"), RandomLoss)
    ge = parse_loss("ge:p=1%,r=30%,bad=80%,good=0.1%")
    assert isinstance(ge, GilbertElliott)
    assert (ge.p, ge.r, ge.loss_bad, ge.loss_good) == pytest.approx((0.01, 0.3, 0.8, 0.001))


def test_rate_and_queue_specs() -> None:
    assert parse_rate("600kbit") == pytest.approx(6e5)
    assert parse_rate("1.5mbit") == pytest.approx(1.5e6)
    assert parse_rate("1Gbit") == pytest.approx(1e9)
    assert parse_rate("none") is None
    assert parse_queue("64kB") == 64000
    assert parse_queue("1MB") == 1_000_000
    assert parse_queue("1500") == 1500


@pytest.mark.parametrize(
    ("parse", "spec", "words"),
    [
        (parse_loss, "120%", "outside [0, 1]"),
        (parse_loss, "lots", "not a probability"),
        (parse_loss, "ge:p=1%", "needs p"),
        (parse_loss, "ge:p=1%,r=2%,x=3%", "unknown field"),
        (parse_loss, "ge:p=0,r=0", "both 0"),
        (parse_rate, "fast", "not a rate"),
        (parse_rate, "10bit", "out of range"),
        (parse_queue, "10", "at least one frame"),
        (parse_queue, "big", "not a size"),
        (parse_outage, "at=30s", "needs at= and for="),
        (parse_outage, "at=30s,for=0s", "for= must be > 0"),
        (parse_outage, "at=1s,for=5s,every=2s", "every= must be longer"),
        (parse_outage, "at=xs,for=1s", "not a duration"),
        (parse_outage, "start=1s,for=1s", "unknown field"),
    ],
)
def test_bad_specs_are_one_line_config_errors(parse: object, spec: str, words: str) -> None:
    assert callable(parse)
    with pytest.raises(ConfigError) as err:
        parse(spec)
    msg = str(err.value)
    assert "\n" not in msg and words in msg and "allowed:" in msg and repr(spec) in msg
