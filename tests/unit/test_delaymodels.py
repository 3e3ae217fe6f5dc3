"""Delay model specs, traces (shipped and from a file), and the in-process delay line."""

from __future__ import annotations

import statistics
from pathlib import Path

import pytest
from bipedtele.config.profile import ConfigError
from bipedtele.link.delaymodels import (
    ConstDelay,
    NormalDelay,
    TraceDelay,
    UniformDelay,
    parse_delay_model,
    parse_duration,
)
from delayline import DelayLine


def test_durations() -> None:
    assert parse_duration("150ms") == pytest.approx(0.15)
    assert parse_duration("0.2s") == pytest.approx(0.2)
    assert parse_duration("150") == pytest.approx(0.15)
    assert parse_duration("500us") == pytest.approx(0.0005)
    for bad in ("", "-1ms", "abc", "1h", "120s"):
        with pytest.raises(ValueError):
            parse_duration(bad)


def test_const() -> None:
    m = parse_delay_model("const:150ms")
    assert isinstance(m, ConstDelay)
    assert m.delay_s(0.0) == m.delay_s(123.4) == pytest.approx(0.15)


def test_uniform_and_normal_statistics_and_seed() -> None:
    u = parse_delay_model("uniform:150ms:30ms", seed=4)
    assert isinstance(u, UniformDelay)
    xs = [u.delay_s(k * 0.01) for k in range(20000)]
    assert min(xs) >= 0.12 and max(xs) <= 0.18
    assert statistics.fmean(xs) == pytest.approx(0.15, abs=0.002)
    n = parse_delay_model("normal:150ms:20ms", seed=4)
    assert isinstance(n, NormalDelay)
    ys = [n.delay_s(0.0) for _ in range(20000)]
    assert statistics.fmean(ys) == pytest.approx(0.15, abs=0.002)
    assert statistics.stdev(ys) == pytest.approx(0.02, abs=0.002)
    # truncated at zero
    z = parse_delay_model("normal:5ms:50ms")
    assert min(z.delay_s(0.0) for _ in range(5000)) >= 0.0
    # same seed, same sequence
    a, b = parse_delay_model("normal:150ms:20ms", 9), parse_delay_model("normal:150ms:20ms", 9)
    assert [a.delay_s(0) for _ in range(5)] == [b.delay_s(0) for _ in range(5)]


def test_trace_interpolates_and_loops(tmp_path: Path) -> None:
    f = tmp_path / "tr.csv"
    f.write_text("t_s,h1_ms,h2_ms\n0,100,200\n1,200,200\n2,100,300\n")
    m = parse_delay_model(f"trace:{f}:h1")
    assert isinstance(m, TraceDelay)
    assert m.delay_s(0.0) == pytest.approx(0.1)
    assert m.delay_s(0.5) == pytest.approx(0.15)
    assert m.delay_s(1.0) == pytest.approx(0.2)
    # period 3 s: between the last row (t=2) and the wrap to the first (t=3)
    assert m.delay_s(2.5) == pytest.approx(0.1)
    assert m.delay_s(3.5) == pytest.approx(0.15)
    assert m.delay_s(-2.5) == pytest.approx(0.15)
    h2 = parse_delay_model(f"trace:{f}:h2")
    assert h2.delay_s(1.5) == pytest.approx(0.25)
    assert m.window_mean(1.0, 1.0) == pytest.approx(0.15, abs=1e-3)


def test_shipped_intercontinental_trace() -> None:
    h1 = parse_delay_model("trace:intercontinental:h1")
    h2 = parse_delay_model("trace:intercontinental:h2")
    assert isinstance(h1, TraceDelay) and isinstance(h2, TraceDelay)
    totals = [a + b for a, b in zip(h1.d, h2.d, strict=True)]
    # the paper's Table 2 figures that the shipped trace reproduces: 262/361/644 ms
    assert min(totals) == pytest.approx(0.262, abs=0.002)
    assert statistics.fmean(totals) == pytest.approx(0.361, abs=0.002)
    assert max(totals) == pytest.approx(0.644, abs=0.002)


@pytest.mark.parametrize(
    "spec",
    [
        "",
        "const",
        "const:abc",
        "const:-5ms",
        "uniform:150ms",
        "uniform:10ms:30ms",
        "normal:1:2:3",
        "gamma:1ms",
        "trace:/nonexistent.csv:h1",
        "trace:intercontinental:h3",
        "trace:intercontinental",
    ],
)
def test_bad_specs_one_line(spec: str) -> None:
    with pytest.raises(ConfigError) as exc:
        parse_delay_model(spec)
    msg = str(exc.value)
    assert "\n" not in msg and "allowed:" in msg and repr(spec) in msg


def test_bad_trace_file(tmp_path: Path) -> None:
    f = tmp_path / "bad.csv"
    f.write_text("a,b\n1,2\n")
    with pytest.raises(ConfigError, match="t_s,h1_ms,h2_ms"):
        parse_delay_model(f"trace:{f}:h1")
    f.write_text("t_s,h1_ms,h2_ms\n0,1,1\n0,2,2\n")
    with pytest.raises(ConfigError, match="increasing"):
        parse_delay_model(f"trace:{f}:h1")


def test_delay_line_constant() -> None:
    dl: DelayLine[int] = DelayLine(0.15)
    dl.push(0.0, 1)
    dl.push(0.05, 2)
    assert dl.pop_ready(0.149) == []
    assert dl.next_release() == pytest.approx(0.15)
    assert dl.pop_ready(0.15) == [1]
    assert dl.pop_ready(1.0) == [2]
    assert len(dl) == 0 and dl.next_release() is None


def test_delay_line_keeps_fifo_when_delay_falls(tmp_path: Path) -> None:
    f = tmp_path / "fall.csv"
    f.write_text("t_s,h1_ms,h2_ms\n0,500,0\n0.1,100,0\n10,100,0\n")
    dl: DelayLine[str] = DelayLine(parse_delay_model(f"trace:{f}:h1"))
    r_a = dl.push(0.0, "a")  # released at 0.5
    r_b = dl.push(0.1, "b")  # would be 0.2, waits behind a
    assert r_a == pytest.approx(0.5) and r_b == pytest.approx(0.5)
    assert dl.pop_ready(0.3) == []
    assert dl.pop_ready(0.5) == ["a", "b"]
    dl.push(1.0, "c")
    dl.clear()
    assert dl.pop_ready(5.0) == []
