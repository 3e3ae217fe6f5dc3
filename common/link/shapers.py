"""Bottlenecks beside the rate FIFO: a token bucket with a burst, and mahimahi capacity traces.

Pure models, no sockets and no clock, with the interface of
:class:`bipedtele.link.impairments.RateQueue`: ``enqueue(t, size)`` returns when the frame's
last bit leaves [s], or None when the queue is full (tail drop); ``backlog_max`` is the
largest backlog seen [bytes].

- :class:`TokenBucket` is the kernel's ``tbf`` (and what modems and policers do): tokens
  accrue at ``rate`` up to ``burst`` bytes; a frame leaves as soon as the bucket holds its
  size, so after a quiet spell up to ``burst`` bytes pass at once (line rate), and only
  then does the rate bind. The plain FIFO (:class:`~bipedtele.link.impairments.RateQueue`)
  serialises every frame at ``rate``: a fixed-rate line (a DSL or a serial modem).
- :class:`TraceRate` replays a capacity trace in mahimahi's format (Netravali et al.,
  "Mahimahi: accurate record-and-replay for HTTP", USENIX ATC 2015): one line per
  delivery opportunity, its time in integer milliseconds; each opportunity carries up to
  ``MTU`` (1500) bytes; the trace repeats with the period of its last line. A frame
  waits in a drop-tail queue for opportunities after its arrival; an opportunity nothing
  waits for is lost, as on a cellular link (the cell's scheduler gives the slot away).

Shipped traces (package data, ``mahimahi:lte`` and ``mahimahi:3g``) are synthetic, made
by :func:`synthetic_cellular` with a fixed seed and the statistics of the public LTE and
3G traces they stand for (mean 1.95 Mbit/s with one 4 s gap; mean 0.52 Mbit/s with a
9 s near-zero stretch); ``tests/unit/test_shapers.py`` regenerates them byte for byte and
checks their statistics.
"""

from __future__ import annotations

import bisect
import math
import random
from collections import deque
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

from bipedtele.config.profile import ConfigError

__all__ = [
    "ALLOWED_TRACE",
    "MTU",
    "SHIPPED_MAHIMAHI",
    "SHIPPED_RECIPES",
    "TokenBucket",
    "TraceRate",
    "load_mahimahi",
    "mahimahi_stats",
    "synthetic_cellular",
]

MTU = 1500  # bytes one opportunity carries
SHIPPED_MAHIMAHI = {"lte": "mahimahi_lte.csv", "3g": "mahimahi_3g.csv"}
#: How the shipped traces were made (:func:`synthetic_cellular` arguments): 90 s each, the
#: mean over the whole trace 1.95 and 0.52 Mbit/s, an LTE gap of 4 s at 40 s, a 3G stretch
#: of 9 s at 2 % of its mean from 35 s.
SHIPPED_RECIPES: dict[str, tuple[float, int, tuple[float, float, float], int]] = {
    "lte": (1.95e6 * 90 / 86, 90, (40.0, 4.0, 0.0), 1),
    "3g": (0.52e6 * 90 / 81.18, 90, (35.0, 9.0, 0.02), 2),
}
ALLOWED_TRACE = "mahimahi:lte, mahimahi:3g or mahimahi:FILE (one delivery opportunity per line, in integer ms)"


class _Backlog:
    """Bytes in the queue: frames admitted whose last bit has not left yet."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self._busy: deque[tuple[float, int]] = deque()  # (finish time [s], size [bytes])
        self.backlog = 0
        self.backlog_max = 0

    def fits(self, t: float, size: int) -> bool:
        while self._busy and self._busy[0][0] <= t:
            self.backlog -= self._busy.popleft()[1]
        return self.backlog + size <= self.capacity

    def add(self, finish: float, size: int) -> None:
        self._busy.append((finish, size))
        self.backlog += size
        self.backlog_max = max(self.backlog_max, self.backlog)


class TokenBucket(_Backlog):
    """The kernel's ``tbf``: ``rate_bps`` with a bucket of ``burst`` bytes and a queue of ``capacity`` bytes.

    Parameters
    ----------
    rate_bps : float
        Token rate [bit/s].
    burst : int
        Bucket size [bytes] (at least one frame: 1514).
    capacity : int
        Queue size [bytes] (``limit``), the frames waiting for tokens.
    """

    def __init__(self, rate_bps: float, burst: int, capacity: int) -> None:
        super().__init__(capacity)
        self.rate_bps, self.burst = float(rate_bps), int(burst)
        self._tokens = float(burst)  # bytes, at ``_t``
        self._t = -math.inf

    def enqueue(self, t: float, size: int) -> float | None:
        """Offer a frame at ``t`` [s]; return when it leaves [s], or None (queue full)."""
        if not self.fits(t, size):
            return None
        start = max(t, self._t)
        tokens = min(float(self.burst), self._tokens + (start - self._t) * self.rate_bps / 8.0)
        leave = start if tokens >= size else start + (size - tokens) * 8.0 / self.rate_bps
        self._tokens = min(float(self.burst), tokens + (leave - start) * self.rate_bps / 8.0) - size
        self._t = leave
        self.add(leave, size)
        return leave


class TraceRate(_Backlog):
    """A mahimahi capacity trace with a drop-tail queue of ``capacity`` bytes.

    Parameters
    ----------
    opportunities_ms : sequence of int
        Delivery opportunities [ms], non-decreasing, the last > 0 (the trace's period).
    capacity : int
        Queue size [bytes].
    """

    def __init__(self, opportunities_ms: Sequence[int], capacity: int) -> None:
        super().__init__(capacity)
        if not opportunities_ms or opportunities_ms[-1] <= 0:
            raise ValueError("a mahimahi trace needs at least one opportunity after 0 ms")
        self._ts = [x / 1000.0 for x in opportunities_ms]
        self.period = opportunities_ms[-1] / 1000.0
        self._n = -1  # the current opportunity (a global index over the repeats)
        self._left = 0  # bytes left in it

    def _time(self, n: int) -> float:
        k, i = divmod(n, len(self._ts))
        return k * self.period + self._ts[i]

    def _first_at(self, t: float) -> int:
        """Index of the first opportunity at or after ``t`` [s]."""
        k = math.floor(t / self.period)
        i = bisect.bisect_left(self._ts, t - k * self.period)
        if i == len(self._ts):
            k, i = k + 1, 0
        return k * len(self._ts) + i

    def enqueue(self, t: float, size: int) -> float | None:
        """Offer a frame at ``t`` [s]; return when its last byte leaves [s], or None (queue full)."""
        if not self.fits(t, size):
            return None
        if self._n < 0 or self._time(self._n) < t:
            self._n, self._left = self._first_at(t), MTU  # opportunities before t went unused
        need = size
        while need > self._left:
            need -= self._left
            self._n, self._left = self._n + 1, MTU
        self._left -= need
        leave = self._time(self._n)
        self.add(leave, size)
        return leave


def load_mahimahi(source: str) -> list[int]:
    """Read a mahimahi trace: a shipped name (``lte``, ``3g``) or a file (ConfigError, one line, when bad)."""
    try:
        if source in SHIPPED_MAHIMAHI:
            text = resources.files("bipedtele.data").joinpath(SHIPPED_MAHIMAHI[source]).read_text("utf-8")
        else:
            text = Path(source).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"mahimahi:{source}: cannot read it ({exc.strerror}); allowed: {ALLOWED_TRACE}") from None
    out: list[int] = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            ms = int(line.strip())
        except ValueError:
            raise ConfigError(
                f"mahimahi:{source}: line {n} {line.strip()!r} is not an integer ms; allowed: {ALLOWED_TRACE}"
            ) from None
        if ms < 0 or (out and ms < out[-1]):
            raise ConfigError(
                f"mahimahi:{source}: line {n}: times must be >= 0 and non-decreasing; allowed: {ALLOWED_TRACE}"
            )
        out.append(ms)
    if not out or out[-1] <= 0:
        raise ConfigError(f"mahimahi:{source}: no opportunity after 0 ms; allowed: {ALLOWED_TRACE}")
    return out


def mahimahi_stats(opportunities_ms: Sequence[int], bin_s: float = 1.0) -> dict[str, float]:
    """Mean capacity [bit/s], the longest run of bins under 5 % of it [s] and the period [s]."""
    period = opportunities_ms[-1] / 1000.0
    bins = [0] * max(1, math.ceil(period / bin_s))
    for ms in opportunities_ms:
        bins[min(len(bins) - 1, int(ms / 1000.0 / bin_s))] += 1
    mean = 8.0 * MTU * len(opportunities_ms) / period
    longest = run = 0
    for b in bins:
        run = run + 1 if 8.0 * MTU * b / bin_s < 0.05 * mean else 0
        longest = max(longest, run)
    return {"mean_bps": mean, "longest_low_s": longest * bin_s, "period_s": period}


def synthetic_cellular(mean_bps: float, seconds: int, low: tuple[float, float, float], seed: int) -> list[int]:
    """Make a synthetic cellular trace: per 100 ms a capacity drawn lognormal (sigma 0.6) around the mean.

    Parameters
    ----------
    mean_bps : float
        Mean capacity outside the low stretch [bit/s] (the draws are scaled to it).
    seconds : int
        Length [s] (the trace's period).
    low : tuple of float
        ``(at, for, share)``: from ``at`` s, for ``for`` s, the capacity is ``share`` of the
        mean (0: a gap) [s, s, -].
    seed : int
        Seed of the draws.
    """
    rng = random.Random(seed)
    steps = seconds * 10
    draws = [rng.lognormvariate(0.0, 0.6) for _ in range(steps)]
    scale = sum(draws) / steps
    at, length, share = low
    out: list[int] = []
    carry = 0.0
    for k in range(steps):
        t = k / 10.0
        rate = mean_bps * draws[k] / scale
        if at <= t < at + length:
            rate = mean_bps * share
        carry += rate * 0.1 / (8.0 * MTU)  # opportunities in this 100 ms
        n = int(carry)
        carry -= n
        out.extend(round(1000.0 * t + 100.0 * (j + 0.5) / n) for j in range(n))
    out.append(1000 * seconds)  # the period: one opportunity at its end
    return out
