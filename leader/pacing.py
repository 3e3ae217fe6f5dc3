"""Drift-free periodic pacing for the 1 kHz haptic loop.

:class:`Pacer` waits for deadlines on a fixed grid ``start + k * period``: it sleeps until
``spin_s`` before the deadline, then yields (``time.sleep(0)``, which releases the GIL so
the cockpit, recorder and Zenoh threads keep running) until the deadline. A late tick does
not shift the grid; when the loop falls more than one period behind, the missed deadlines
are skipped and counted (no burst of catch-up ticks), so the rate never drifts.

On Linux the thread's timer slack is set to 1 us (``prctl(PR_SET_TIMERSLACK)``) where
allowed, which trims the default 50 us oversleep of ``time.sleep``.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import sys
import time
from collections.abc import Callable, Iterator

import numpy as np

__all__ = ["Pacer", "PeriodStats", "realtime_scheduling", "set_timer_slack"]

LOG = logging.getLogger(__name__)

_PR_SET_TIMERSLACK = 29


def set_timer_slack(ns: int = 1000) -> bool:
    """Set the calling thread's timer slack [ns] (Linux only). True if it worked."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return int(libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(ns), 0, 0, 0)) == 0
    except (OSError, AttributeError):  # pragma: no cover - exotic libc
        return False


@contextlib.contextmanager
def realtime_scheduling(priority: int) -> Iterator[bool]:
    """Run the calling thread with ``SCHED_FIFO`` at ``priority`` (1-99) inside the block,
    restoring its policy after; yields whether it worked (0 or no permission: False)."""
    if priority <= 0 or not hasattr(os, "sched_setscheduler"):
        yield False
        return
    try:
        old_policy = os.sched_getscheduler(0)
        old_param = os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        LOG.warning("real-time scheduling (SCHED_FIFO %d) refused: %s; running at normal priority", priority, exc)
        yield False
        return
    try:
        yield True
    finally:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, old_policy, old_param)


class PeriodStats:
    """Ring buffer of tick start times (monotonic clock) for rate and jitter figures.

    Parameters
    ----------
    capacity : int
        Ticks kept (the newest ones).
    """

    def __init__(self, capacity: int = 1 << 16) -> None:
        self._buf = np.zeros(capacity)
        self._n = 0

    def add(self, t: float) -> None:
        """Record one tick start time [s]."""
        self._buf[self._n % len(self._buf)] = t
        self._n += 1

    def times(self) -> np.ndarray:
        """The recorded tick start times [s], oldest first."""
        n, cap = self._n, len(self._buf)
        if n <= cap:
            return self._buf[:n].copy()
        i = n % cap
        return np.concatenate([self._buf[i:], self._buf[:i]])

    def summary(self, period_s: float) -> dict[str, float]:
        """Mean rate [Hz] and period-error percentiles [s] (|period - nominal|)."""
        t = self.times()
        if len(t) < 3:
            return {"ticks": float(len(t))}
        p = np.diff(t)
        err = np.abs(p - period_s)
        return {
            "ticks": float(len(t)),
            "rate_hz": float((len(t) - 1) / (t[-1] - t[0])),
            "period_p50_s": float(np.percentile(p, 50)),
            "err_p50_s": float(np.percentile(err, 50)),
            "err_p99_s": float(np.percentile(err, 99)),
            "err_max_s": float(err.max()),
        }


class Pacer:
    """Waits for the deadlines ``start + k * period_s`` (see the module docstring).

    Parameters
    ----------
    period_s : float
        Period [s].
    spin_s : float
        Time before each deadline spent yielding instead of sleeping [s].
    clock : callable
        Monotonic clock [s].
    """

    def __init__(
        self, period_s: float, spin_s: float = 0.0003, clock: Callable[[], float] = time.perf_counter
    ) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s = {period_s!r}: allowed: a number > 0 s")
        self.period_s = float(period_s)
        self.spin_s = max(0.0, float(spin_s))
        self.clock = clock
        self.start = clock()
        self.k = 0
        self.missed = 0
        self.late_ticks = 0

    def reset(self) -> None:
        """Restart the grid now."""
        self.start = self.clock()
        self.k = 0

    def wait(self) -> int:
        """Wait for the next deadline; return how many deadlines were skipped (0 normally)."""
        self.k += 1
        deadline = self.start + self.k * self.period_s
        now = self.clock()
        skipped = 0
        if now > deadline:
            self.late_ticks += 1
            if now > deadline + self.period_s:
                skipped = int((now - deadline) // self.period_s)
                self.k += skipped
                self.missed += skipped
                deadline = self.start + self.k * self.period_s
        remaining = deadline - now
        if remaining > self.spin_s:
            time.sleep(remaining - self.spin_s)
        while self.clock() < deadline:
            time.sleep(0)
        return skipped
