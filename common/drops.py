"""Counting dropped network messages, with rate-limited logging.

Receivers never crash on bad input: they call :meth:`DropCounter.drop` with a short
reason (``not_msgpack``, ``stale``, ...). Counts are kept per reason; a WARNING is
logged at most once per reason per ``log_interval_s`` with the number of drops since
the previous log line of that reason.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

__all__ = ["DropCounter"]

LOG = logging.getLogger("bipedtele.drops")


class DropCounter:
    """Per-reason counters of dropped messages for one receiver.

    Parameters
    ----------
    name : str
        Who drops (e.g. ``follower/cmd``); used in log lines.
    log_interval_s : float
        Minimum time between two log lines of the same reason [s].
    clock : callable, optional
        Monotonic time source [s] (injectable for tests).

    Notes
    -----
    Thread-safe: Zenoh callbacks call :meth:`drop` from the library's threads while the
    control loop reads :meth:`counts`.
    """

    def __init__(
        self,
        name: str,
        log_interval_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if log_interval_s < 0:
            raise ValueError("log_interval_s must be >= 0")
        self.name = name
        self.log_interval_s = log_interval_s
        self._clock = clock
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._unlogged: dict[str, int] = {}
        self._last_log: dict[str, float] = {}

    def drop(self, reason: str, detail: str = "") -> None:
        """Count one dropped message; log it if this reason was not logged recently.

        Parameters
        ----------
        reason : str
            Short category (used as counter name).
        detail : str
            Human-readable detail for the log line (the last one is shown).
        """
        now = self._clock()
        with self._lock:
            self._counts[reason] = self._counts.get(reason, 0) + 1
            pending = self._unlogged.get(reason, 0) + 1
            last = self._last_log.get(reason)
            if last is not None and now - last < self.log_interval_s:
                self._unlogged[reason] = pending
                return
            self._last_log[reason] = now
            self._unlogged[reason] = 0
        LOG.warning("%s: dropped %d message(s): %s%s", self.name, pending, reason, f" ({detail})" if detail else "")

    def counts(self) -> dict[str, int]:
        """Return the drops per reason since creation (a copy)."""
        with self._lock:
            return dict(self._counts)

    @property
    def total(self) -> int:
        """All drops since creation."""
        with self._lock:
            return sum(self._counts.values())

    def __repr__(self) -> str:
        return f"DropCounter({self.name!r}, {self.counts()})"
