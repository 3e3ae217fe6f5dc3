"""Per-packet link impairments: loss, rate cap with a bounded queue, outages, delay.

Pure model, no sockets and no clock: :meth:`Direction.admit` takes a frame's arrival time
[s, since the emulator's origin] and size [bytes] and returns when to release it, or why
it is dropped. The packet emulator (:mod:`bipedtele.tools.linkemu`) calls it once per
frame; tests call it with made-up times.

Order of the stages of one direction::

    outage (at arrival) -> rate queue (tail drop, serialisation) -> loss -> delay

A frame's delay is the direction's delay model evaluated when the frame leaves the queue,
and a frame is never released before the one admitted before it (no reordering).

Specs (one-line :class:`~bipedtele.config.profile.ConfigError` naming what is wrong otherwise)::

    loss     none | 1% | 0.01 | ge:p=1%,r=30%[,bad=100%][,good=0%]
    rate     none | 600kbit | 1.5mbit | 2gbit | 800bit (bits per second)
    queue    64kB | 1MB | 1500B | 1500 (bytes; KB, MB too; 1k = 1000)
    outage   at=30s,for=3s[,every=60s]
"""

from __future__ import annotations

import math
import random
import re
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

from bipedtele.config.profile import ConfigError
from bipedtele.link.delaymodels import DelayModel

__all__ = [
    "ALLOWED_LOSS",
    "ALLOWED_OUTAGE",
    "ALLOWED_QUEUE",
    "ALLOWED_RATE",
    "DROP_REASONS",
    "Direction",
    "DirectionCounters",
    "GilbertElliott",
    "LossModel",
    "NoLoss",
    "Outage",
    "RandomLoss",
    "RateQueue",
    "Shaper",
    "Verdict",
    "parse_loss",
    "parse_outage",
    "parse_queue",
    "parse_rate",
]

ALLOWED_LOSS = "none, a probability like 1% or 0.01, or ge:p=P,r=R[,bad=B][,good=G] (Gilbert-Elliott)"
ALLOWED_RATE = "none or bits per second like 600kbit, 1.5mbit, 1gbit, 9600bit"
ALLOWED_QUEUE = "bytes like 64kB, 1MB, 1500B or 1500 (at least 1500)"
ALLOWED_OUTAGE = "at=T,for=D[,every=P] with durations like 30s or 500ms (P > D)"
DROP_REASONS = ("loss", "queue", "outage")
MIN_QUEUE_BYTES = 1500
MAX_OUTAGE_S = 86400.0

_PROB = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(%?)\s*$")
_RATE = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([kmg]?)(bit|bps)\s*$", re.IGNORECASE)
_BYTES = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*([kKmM]?)(B?)\s*$")


def _prob(text: str) -> float:
    """Parse ``1%`` or ``0.01`` into a probability in [0, 1] (ValueError otherwise)."""
    m = _PROB.match(text)
    if not m:
        raise ValueError(f"{text!r} is not a probability like 1% or 0.01")
    p = float(m.group(1)) / (100.0 if m.group(2) else 1.0)
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"{text!r} is outside [0, 1] (0% to 100%)")
    return p


class LossModel(ABC):
    """Decides, frame by frame, whether the wire loses it."""

    spec: str = "none"

    @abstractmethod
    def lost(self) -> bool:
        """Return True when the next frame is lost."""


class NoLoss(LossModel):
    """No frame is lost."""

    def lost(self) -> bool:
        """Return False."""
        return False


class RandomLoss(LossModel):
    """Independent (Bernoulli) loss.

    Parameters
    ----------
    p : float
        Loss probability of each frame, in [0, 1].
    seed : int
        RNG seed.
    """

    def __init__(self, p: float, seed: int = 0) -> None:
        self.p = p
        self._rng = random.Random(seed)
        self.spec = f"{100 * p:g}%"

    def lost(self) -> bool:
        """Return True with probability ``p``."""
        return self._rng.random() < self.p


class GilbertElliott(LossModel):
    """Two-state bursty loss (Gilbert-Elliott).

    Before each frame the state moves good -> bad with probability ``p`` and bad -> good
    with probability ``r``; the frame is then lost with probability ``loss_bad`` in the bad
    state and ``loss_good`` in the good state. Bad runs last ``1/r`` frames on average; the
    long-run loss fraction is ``(p * loss_bad + r * loss_good) / (p + r)``.

    Parameters
    ----------
    p, r : float
        Transition probabilities per frame, in [0, 1] (``p + r > 0``).
    loss_bad, loss_good : float
        Loss probability in each state, in [0, 1].
    seed : int
        RNG seed.
    """

    def __init__(self, p: float, r: float, loss_bad: float = 1.0, loss_good: float = 0.0, seed: int = 0) -> None:
        if p + r <= 0.0:
            raise ValueError("p + r must be > 0")
        self.p, self.r, self.loss_bad, self.loss_good = p, r, loss_bad, loss_good
        self.bad = False
        self._rng = random.Random(seed)
        self.spec = f"ge:p={100 * p:g}%,r={100 * r:g}%,bad={100 * loss_bad:g}%,good={100 * loss_good:g}%"

    @property
    def mean_loss(self) -> float:
        """Long-run loss fraction (stationary distribution of the two states)."""
        return (self.p * self.loss_bad + self.r * self.loss_good) / (self.p + self.r)

    def lost(self) -> bool:
        """Step the state, then draw the loss of one frame."""
        u = self._rng.random()
        self.bad = (u >= self.r) if self.bad else (u < self.p)
        return self._rng.random() < (self.loss_bad if self.bad else self.loss_good)


def parse_loss(spec: str, seed: int = 0) -> LossModel:
    """Build a loss model from ``none``, ``1%``, ``0.01`` or ``ge:p=..,r=..[,bad=..][,good=..]``.

    Raises
    ------
    ConfigError
        One line naming the spec and what is allowed.
    """

    def bad(why: str) -> ConfigError:
        return ConfigError(f"loss {spec!r}: {why}; allowed: {ALLOWED_LOSS}")

    text = spec.strip()
    try:
        if text in ("", "none", "0", "0%"):
            return NoLoss()
        if not text.startswith("ge:"):
            return RandomLoss(_prob(text), seed)
        fields: dict[str, float] = {}
        for item in text[3:].split(","):
            key, eq, value = item.partition("=")
            key = key.strip()
            if not eq or key not in ("p", "r", "bad", "good"):
                raise bad(f"unknown field {item.strip()!r} (fields: p, r, bad, good)")
            if key in fields:
                raise bad(f"{key} given twice")
            fields[key] = _prob(value)
        if "p" not in fields or "r" not in fields:
            raise bad("ge needs p (good->bad) and r (bad->good)")
        if fields["p"] + fields["r"] <= 0.0:
            raise bad("p and r are both 0")
        return GilbertElliott(fields["p"], fields["r"], fields.get("bad", 1.0), fields.get("good", 0.0), seed)
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise bad(str(exc)) from None


def parse_rate(spec: str) -> float | None:
    """Parse ``600kbit``, ``1.5mbit``, ``1gbit`` or ``none`` into bits per second (None: no cap).

    Raises
    ------
    ConfigError
        One line naming the spec and what is allowed.
    """
    if spec.strip().lower() in ("", "none"):
        return None
    m = _RATE.match(spec)
    if not m:
        raise ConfigError(f"rate {spec!r}: not a rate; allowed: {ALLOWED_RATE}")
    bps = float(m.group(1)) * {"": 1.0, "k": 1e3, "m": 1e6, "g": 1e9}[m.group(2).lower()]
    if not (math.isfinite(bps) and 1e3 <= bps <= 1e11):
        raise ConfigError(f"rate {spec!r}: out of range [1kbit, 100gbit]; allowed: {ALLOWED_RATE}")
    return bps


def parse_queue(spec: str) -> int:
    """Parse a queue size ``64kB``, ``1MB``, ``1500B`` or ``1500`` into bytes (k = 1000).

    Raises
    ------
    ConfigError
        One line naming the spec and what is allowed.
    """
    m = _BYTES.match(spec)
    if not m:
        raise ConfigError(f"queue {spec!r}: not a size; allowed: {ALLOWED_QUEUE}")
    n = float(m.group(1)) * {"": 1, "k": 1000, "m": 1000_000}[m.group(2).lower()]
    if not MIN_QUEUE_BYTES <= n <= 1e9:
        raise ConfigError(
            f"queue {spec!r}: out of range [1500 B, 1 GB] (a queue holds at least one frame); allowed: {ALLOWED_QUEUE}"
        )
    return int(n)


@dataclass(frozen=True)
class Outage:
    """Window(s) during which a direction drops every frame.

    Parameters
    ----------
    at_s : float
        Start of the first window [s since the origin].
    for_s : float
        Length of each window [s].
    every_s : float or None
        Period of the windows [s] (> ``for_s``); None: one window.
    """

    at_s: float
    for_s: float
    every_s: float | None = None

    def active(self, t: float) -> bool:
        """Return True when time ``t`` [s] lies in a window (start included, end not)."""
        if t < self.at_s:
            return False
        dt = t - self.at_s
        if self.every_s is not None:
            dt %= self.every_s
        return dt < self.for_s


def parse_outage(spec: str) -> Outage:
    """Parse ``at=30s,for=3s[,every=60s]`` (bare numbers are milliseconds, as for delays).

    Raises
    ------
    ConfigError
        One line naming the spec and what is allowed.
    """

    def bad(why: str) -> ConfigError:
        return ConfigError(f"outage {spec!r}: {why}; allowed: {ALLOWED_OUTAGE}")

    fields: dict[str, float] = {}
    for item in spec.split(","):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or key not in ("at", "for", "every"):
            raise bad(f"unknown field {item.strip()!r} (fields: at, for, every)")
        if key in fields:
            raise bad(f"{key} given twice")
        try:
            fields[key] = _long_duration(value)
        except ValueError as exc:
            raise bad(str(exc)) from None
    if "at" not in fields or "for" not in fields:
        raise bad("needs at= and for=")
    if fields["for"] <= 0.0:
        raise bad("for= must be > 0")
    every = fields.get("every")
    if every is not None and every <= fields["for"]:
        raise bad("every= must be longer than for=")
    return Outage(fields["at"], fields["for"], every)


_LONG = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*(ms|s|min)?\s*$")


def _long_duration(text: str) -> float:
    """Parse ``30s``, ``500ms``, ``2min`` or ``500`` (milliseconds) into seconds, up to a day."""
    m = _LONG.match(text)
    if not m:
        raise ValueError(f"{text.strip()!r} is not a duration like 30s or 500ms")
    value = float(m.group(1)) * {"ms": 1e-3, "s": 1.0, "min": 60.0, None: 1e-3}[m.group(2)]
    if value > MAX_OUTAGE_S:
        raise ValueError(f"{text.strip()!r} is longer than a day")
    return value


class Shaper(Protocol):
    """A bottleneck: :class:`RateQueue`, or :class:`~bipedtele.link.shapers.TokenBucket` / :class:`~bipedtele.link.shapers.TraceRate`."""

    backlog_max: int

    def enqueue(self, t: float, size: int) -> float | None:
        """Offer a frame of ``size`` bytes at ``t`` [s]; return when it leaves [s], or None (queue full)."""
        ...


class RateQueue:
    """A bottleneck: a FIFO of ``capacity`` bytes drained at ``rate_bps`` bits per second.

    Parameters
    ----------
    rate_bps : float
        Line rate [bit/s]; a frame of ``n`` bytes takes ``8 n / rate_bps`` seconds.
    capacity : int
        Queue size [bytes], the frame being serialised included; a frame that does not fit
        is dropped (tail drop).
    """

    def __init__(self, rate_bps: float, capacity: int) -> None:
        self.rate_bps, self.capacity = rate_bps, capacity
        self._busy: deque[tuple[float, int]] = deque()  # (finish time [s], size [bytes])
        self.backlog = 0
        self.backlog_max = 0

    def enqueue(self, t: float, size: int) -> float | None:
        """Offer a frame at time ``t`` [s]; return when its last bit leaves [s], or None (full)."""
        while self._busy and self._busy[0][0] <= t:
            self.backlog -= self._busy.popleft()[1]
        if self.backlog + size > self.capacity:
            return None
        start = self._busy[-1][0] if self._busy else t
        finish = max(start, t) + 8.0 * size / self.rate_bps
        self._busy.append((finish, size))
        self.backlog += size
        self.backlog_max = max(self.backlog_max, self.backlog)
        return finish


@dataclass(frozen=True)
class Verdict:
    """What happens to one frame: released at ``release_s`` [s], or dropped for ``reason``."""

    release_s: float | None
    reason: str | None = None


@dataclass
class DirectionCounters:
    """Counters of one direction (frames and bytes; drops by reason; largest queue [bytes])."""

    forwarded: int = 0
    forwarded_bytes: int = 0
    dropped: dict[str, int] = field(default_factory=lambda: dict.fromkeys(DROP_REASONS, 0))
    queue_bytes_max: int = 0

    def as_dict(self) -> dict[str, object]:
        """Return the counters as a JSON-ready dict."""
        return {
            "forwarded": self.forwarded,
            "forwarded_bytes": self.forwarded_bytes,
            "dropped": dict(self.dropped),
            "queue_bytes_max": self.queue_bytes_max,
        }


class Direction:
    """The impairments of one direction of a link.

    Parameters
    ----------
    delay : DelayModel
        Propagation delay, evaluated when a frame leaves the rate queue.
    loss : LossModel, optional
        Default: no loss.
    rate : Shaper, optional
        Bottleneck (a rate FIFO, a token bucket, a capacity trace); default none (infinite
        rate, no queue).
    outages : sequence of Outage
        Windows that drop everything arriving in them.
    """

    def __init__(
        self,
        delay: DelayModel,
        loss: LossModel | None = None,
        rate: Shaper | None = None,
        outages: Sequence[Outage] = (),
    ) -> None:
        self.delay, self.loss, self.rate = delay, loss or NoLoss(), rate
        self.outages = tuple(outages)
        self.counters = DirectionCounters()
        self._last_release = -math.inf

    def admit(self, t: float, size: int) -> Verdict:
        """Decide the fate of a frame of ``size`` bytes arriving at ``t`` [s].

        Arrival times must not decrease from call to call.
        """
        if any(o.active(t) for o in self.outages):
            return self._drop("outage")
        leave = t
        if self.rate is not None:
            finish = self.rate.enqueue(t, size)
            self.counters.queue_bytes_max = self.rate.backlog_max
            if finish is None:
                return self._drop("queue")
            leave = finish
        if self.loss.lost():
            return self._drop("loss")
        release = max(leave + self.delay.delay_s(leave), self._last_release)
        self._last_release = release
        self.counters.forwarded += 1
        self.counters.forwarded_bytes += size
        return Verdict(release)

    def _drop(self, reason: str) -> Verdict:
        self.counters.dropped[reason] += 1
        return Verdict(None, reason)
