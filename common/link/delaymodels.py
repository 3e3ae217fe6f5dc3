"""Delay models for emulation: constant, uniform jitter, normal jitter, recorded trace.

Specs (times with a unit ``ms`` or ``s``; a bare number is milliseconds)::

    const:150ms                 always 150 ms
    uniform:150ms:30ms          uniform in [120, 180] ms (mean : half-width)
    normal:150ms:20ms           normal, mean 150 ms, std 20 ms, truncated at 0
    trace:FILE.csv:h1           column h1_ms of a CSV ``t_s,h1_ms,h2_ms`` (or h2)
    trace:intercontinental:h2   the shipped trace (package data ``bipedtele.data``)

Traces are looped over their duration and linearly interpolated. Random models use a
seeded generator (reproducible runs).
"""

from __future__ import annotations

import bisect
import csv
import io
import itertools
import math
import random
import re
from abc import ABC, abstractmethod
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

from bipedtele.config.profile import ConfigError

__all__ = [
    "ALLOWED_SPECS",
    "ConstDelay",
    "DelayModel",
    "NormalDelay",
    "TraceDelay",
    "UniformDelay",
    "load_trace",
    "parse_delay_model",
    "parse_duration",
]

ALLOWED_SPECS = (
    "const:150ms, uniform:MEAN:HALFWIDTH, normal:MEAN:STD, trace:FILE.csv:h1|h2 or trace:intercontinental:h1|h2"
)
SHIPPED_TRACES = {"intercontinental": "intercontinental_delay.csv"}
MAX_DELAY_S = 60.0

_DURATION = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(ms|s|us)?\s*$")


def parse_duration(text: str) -> float:
    """Parse ``150ms``, ``0.15s``, ``150`` (milliseconds) or ``500us`` into seconds.

    Raises
    ------
    ValueError
        If the text is not a non-negative duration.
    """
    m = _DURATION.match(text)
    if not m:
        raise ValueError(f"{text!r} is not a duration like 150ms or 0.15s")
    value = float(m.group(1))
    unit = m.group(2) or "ms"
    seconds = value * {"ms": 1e-3, "s": 1.0, "us": 1e-6}[unit]
    if not math.isfinite(seconds) or seconds > MAX_DELAY_S:
        raise ValueError(f"{text!r} is out of range [0, {MAX_DELAY_S:g} s]")
    return seconds


class DelayModel(ABC):
    """A one-way delay as a function of time."""

    spec: str = ""

    @abstractmethod
    def delay_s(self, t: float) -> float:
        """Delay [s] for a message sent (or a chunk arriving) at time ``t`` [s]."""

    @property
    @abstractmethod
    def mean_s(self) -> float:
        """Mean delay of the model [s]."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.spec!r})"


class ConstDelay(DelayModel):
    """Constant delay.

    Parameters
    ----------
    delay : float
        Delay [s], >= 0.
    """

    def __init__(self, delay: float) -> None:
        if not (delay >= 0 and math.isfinite(delay)):
            raise ValueError("delay must be a finite number >= 0 s")
        self.delay = float(delay)
        self.spec = f"const:{delay * 1e3:g}ms"

    def delay_s(self, t: float) -> float:
        """Return the constant delay [s]."""
        return self.delay

    @property
    def mean_s(self) -> float:
        """Mean delay [s]."""
        return self.delay


class UniformDelay(DelayModel):
    """Uniform jitter ``mean ± half_width`` (clipped at 0).

    Parameters
    ----------
    mean, half_width : float
        [s].
    seed : int
        RNG seed.
    """

    def __init__(self, mean: float, half_width: float, seed: int = 0) -> None:
        self.mean, self.half_width = float(mean), float(half_width)
        self._rng = random.Random(seed)
        self.spec = f"uniform:{mean * 1e3:g}ms:{half_width * 1e3:g}ms"

    def delay_s(self, t: float) -> float:
        """Return a uniform draw around the mean [s], clipped at 0."""
        return max(0.0, self._rng.uniform(self.mean - self.half_width, self.mean + self.half_width))

    @property
    def mean_s(self) -> float:
        """Mean delay [s]."""
        return self.mean


class NormalDelay(DelayModel):
    """Normal jitter with mean and standard deviation, truncated at 0 (redrawn).

    Parameters
    ----------
    mean, std : float
        [s].
    seed : int
        RNG seed.
    """

    def __init__(self, mean: float, std: float, seed: int = 0) -> None:
        self.mean, self.std = float(mean), float(std)
        self._rng = random.Random(seed)
        self.spec = f"normal:{mean * 1e3:g}ms:{std * 1e3:g}ms"

    def delay_s(self, t: float) -> float:
        """Return a normal draw [s], redrawn while negative (0 after 64 tries)."""
        for _ in range(64):
            d = self._rng.gauss(self.mean, self.std)
            if d >= 0.0:
                return d
        return 0.0

    @property
    def mean_s(self) -> float:
        """Mean delay [s]."""
        return self.mean


class TraceDelay(DelayModel):
    """Recorded delay, looped and linearly interpolated.

    Parameters
    ----------
    t : sequence of float
        Strictly increasing sample times [s], starting anywhere.
    d : sequence of float
        Delays at those times [s], >= 0.
    """

    def __init__(self, t: Sequence[float], d: Sequence[float], spec: str = "trace") -> None:
        if len(t) < 2 or len(t) != len(d):
            raise ValueError("a trace needs at least two rows")
        if any(b <= a for a, b in itertools.pairwise(t)):
            raise ValueError("trace times must be strictly increasing")
        if any(not (x >= 0 and math.isfinite(x)) for x in d):
            raise ValueError("trace delays must be finite and >= 0")
        self.t = [float(x) for x in t]
        self.d = [float(x) for x in d]
        # Loop period: one sample step beyond the last row, so the last row is held one step.
        self.period = self.t[-1] - self.t[0] + (self.t[-1] - self.t[-2])
        self.spec = spec

    def delay_s(self, t: float) -> float:
        """Return the trace's delay at time ``t`` [s] (looped, interpolated)."""
        tau = self.t[0] + (t - self.t[0]) % self.period
        i = bisect.bisect_right(self.t, tau) - 1
        if i >= len(self.t) - 1:  # between the last row and the wrap to the first
            t0, t1, d0, d1 = self.t[-1], self.t[0] + self.period, self.d[-1], self.d[0]
        else:
            t0, t1, d0, d1 = self.t[i], self.t[i + 1], self.d[i], self.d[i + 1]
        w = (tau - t0) / (t1 - t0)
        return d0 + w * (d1 - d0)

    @property
    def mean_s(self) -> float:
        """Mean of the trace's delays [s]."""
        return sum(self.d) / len(self.d)

    def window_mean(self, t_end: float, window_s: float, step_s: float = 0.001) -> float:
        """Mean delay over ``(t_end - window_s, t_end]`` [s], by sampling every ``step_s``."""
        n = max(1, round(window_s / step_s))
        return sum(self.delay_s(t_end - k * step_s) for k in range(n)) / n


def load_trace(text: str, column: str, label: str = "trace") -> TraceDelay:
    """Parse a CSV trace ``t_s,h1_ms,h2_ms`` and return one column as a model.

    Parameters
    ----------
    text : str
        CSV text with a header row.
    column : str
        ``h1`` or ``h2``.
    """
    reader = csv.DictReader(io.StringIO(text))
    key = f"{column}_ms"
    if reader.fieldnames is None or "t_s" not in reader.fieldnames or key not in reader.fieldnames:
        raise ValueError(f"expected CSV columns t_s,h1_ms,h2_ms, got {reader.fieldnames}")
    ts, ds = [], []
    for row in reader:
        try:
            ts.append(float(row["t_s"]))
            ds.append(float(row[key]) * 1e-3)
        except (TypeError, ValueError):
            raise ValueError(f"bad row {row!r}") from None
    return TraceDelay(ts, ds, spec=label)


def _trace_text(source: str) -> str:
    if source in SHIPPED_TRACES:
        return resources.files("bipedtele.data").joinpath(SHIPPED_TRACES[source]).read_text("utf-8")
    return Path(source).read_text(encoding="utf-8")


def parse_delay_model(spec: str, seed: int = 0) -> DelayModel:
    """Build a delay model from a spec string (see the module docstring).

    Parameters
    ----------
    spec : str
        ``const:150ms``, ``uniform:150ms:30ms``, ``normal:150ms:20ms``,
        ``trace:FILE.csv:h1`` or ``trace:intercontinental:h2``.
    seed : int
        Seed of the random models.

    Raises
    ------
    ConfigError
        One line naming the spec and what is allowed.
    """

    def bad(why: str) -> ConfigError:
        return ConfigError(f"delay model {spec!r}: {why}; allowed: {ALLOWED_SPECS}")

    kind, _, rest = spec.strip().partition(":")
    try:
        if kind == "const":
            return ConstDelay(parse_duration(rest))
        if kind in ("uniform", "normal"):
            parts = rest.split(":")
            if len(parts) != 2:
                raise bad(f"{kind} needs two durations")
            a, b = parse_duration(parts[0]), parse_duration(parts[1])
            if kind == "uniform":
                if b > a:
                    raise bad("half-width larger than the mean")
                return UniformDelay(a, b, seed)
            return NormalDelay(a, b, seed)
        if kind == "trace":
            source, sep, column = rest.rpartition(":")
            if not sep or column not in ("h1", "h2") or not source:
                raise bad("trace needs a file and a column h1 or h2")
            try:
                text = _trace_text(source)
            except OSError as exc:
                raise bad(f"cannot read {source} ({exc.strerror})") from None
            return load_trace(text, column, label=spec.strip())
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise bad(str(exc)) from None
    raise bad(f"unknown kind {kind!r}")
