"""Drift-free periodic pacing for both nodes' loops (the 1 kHz haptic loop, the follower).

:class:`Pacer` waits for deadlines on a fixed grid ``start + k * period_s``. It sleeps on an
event until ``spin_s`` before the deadline, then yields (``sleep(0)``, which releases the
GIL so Zenoh, cockpit and recorder threads keep running) until the deadline. A late tick
does not shift the grid; when the loop falls more than one period behind, the missed
deadlines are skipped and counted (no burst of catch-up ticks), so the rate never drifts.

The sleep can be cut short: :meth:`Pacer.notify` (a receiver thread: a fresh command
arrived) makes the current :meth:`Pacer.wait` return ``False`` at once without using up
the deadline, and :meth:`Pacer.stop` (a signal handler, another thread) ends every wait
for good. Clock and sleep are injectable, so the pacer is tested on a fake clock.

:class:`PeriodStats` keeps tick times for rate and jitter figures; on Linux
:func:`set_timer_slack` trims the default 50 us oversleep of a timed wait and
:func:`realtime_scheduling` runs a block under ``SCHED_FIFO`` where allowed.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import numpy.typing as npt

__all__ = ["Pacer", "PeriodStats", "Sleeper", "realtime_scheduling", "set_timer_slack"]

LOG = logging.getLogger(__name__)

_PR_SET_TIMERSLACK = 29

#: ``sleep(timeout_s, wake) -> woken``: wait at most ``timeout_s`` [s] or until ``wake`` is set.
Sleeper = Callable[[float, threading.Event], bool]


def _event_sleep(timeout_s: float, wake: threading.Event) -> bool:
    if timeout_s <= 0.0:
        time.sleep(0)  # yield the GIL
        return wake.is_set()
    return wake.wait(timeout_s)


class Pacer:
    """Waits for the deadlines ``start + k * period_s`` (see the module docstring).

    Parameters
    ----------
    period_s : float
        Period [s], > 0.
    spin_s : float
        Time before each deadline spent yielding instead of sleeping [s].
    clock : callable
        Monotonic clock [s].
    sleep : callable
        ``sleep(timeout_s, wake) -> woken``: the timed wait (an event wait by default; a
        fake one in tests advances a fake clock).

    Raises
    ------
    ValueError
        ``period_s`` not a number > 0.
    """

    def __init__(
        self,
        period_s: float,
        *,
        spin_s: float = 0.0,
        clock: Callable[[], float] = time.perf_counter,
        sleep: Sleeper = _event_sleep,
    ) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s = {period_s!r}: allowed: a number > 0 s")
        self.period_s = float(period_s)
        self.spin_s = max(0.0, float(spin_s))
        self.clock = clock
        self._sleep = sleep
        self._wake = threading.Event()
        self._stopped = False
        self.start = clock()
        self.k = 0
        self.missed = 0
        self.late_ticks = 0

    @property
    def deadline(self) -> float:
        """Next deadline on the grid [s, clock time]."""
        return self.start + (self.k + 1) * self.period_s

    def passed(self) -> int:
        """Return how many grid deadlines have passed since :attr:`start` (the clock's now)."""
        return math.floor((self.clock() - self.start) / self.period_s)

    @property
    def stopped(self) -> bool:
        """True once :meth:`stop` was called."""
        return self._stopped

    def reset(self) -> None:
        """Restart the grid now."""
        self.start = self.clock()
        self.k = 0

    def notify(self) -> None:
        """Cut the current (or next) :meth:`wait` short; thread-safe."""
        self._wake.set()

    def stop(self) -> None:
        """End this and every later :meth:`wait` at once; thread-safe."""
        self._stopped = True
        self._wake.set()

    def wait(self) -> bool:
        """Wait for the next deadline.

        Returns
        -------
        bool
            True when the deadline was reached (it is used up; deadlines more than one
            period in the past are skipped and counted in ``missed``); False when
            :meth:`notify` or :meth:`stop` cut the wait short (the deadline stays).
        """
        deadline = self.deadline
        now = self.clock()
        if now > deadline:
            self.late_ticks += 1
            if now > deadline + self.period_s:
                skipped = int((now - deadline) // self.period_s)
                self.k += skipped
                self.missed += skipped
            self.k += 1
            return True
        while True:
            if self._wake.is_set():
                if not self._stopped:
                    self._wake.clear()
                return False
            remaining = deadline - self.clock()
            if remaining <= 0.0:
                self.k += 1
                return True
            self._sleep(remaining - self.spin_s if remaining > self.spin_s else 0.0, self._wake)


class PeriodStats:
    """Ring buffer of tick start times (monotonic clock) for rate and jitter figures.

    Parameters
    ----------
    capacity : int
        Ticks kept (the newest ones).
    """

    def __init__(self, capacity: int = 1 << 16) -> None:
        self._buf: npt.NDArray[np.float64] = np.zeros(capacity)
        self._n = 0

    def add(self, t: float) -> None:
        """Record one tick start time [s]."""
        self._buf[self._n % len(self._buf)] = t
        self._n += 1

    def times(self) -> npt.NDArray[np.float64]:
        """Return the recorded tick start times [s], oldest first."""
        n, cap = self._n, len(self._buf)
        if n <= cap:
            return self._buf[:n].copy()
        i = n % cap
        return np.concatenate([self._buf[i:], self._buf[:i]])

    def summary(self, period_s: float) -> dict[str, float]:
        """Return the mean rate [Hz] and period-error percentiles [s] (|period - nominal|)."""
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


def set_timer_slack(ns: int = 1000) -> bool:
    """Set the calling thread's timer slack [ns] (Linux only); return whether it worked."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return int(libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(ns), 0, 0, 0)) == 0
    except (OSError, AttributeError):  # pragma: no cover - exotic libc
        return False


@contextlib.contextmanager
def realtime_scheduling(priority: int) -> Iterator[bool]:
    """Run the calling thread with ``SCHED_FIFO`` at ``priority`` (1-99) inside the block.

    Yields whether it worked (0 or no permission: False); the old policy is restored after.
    """
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
