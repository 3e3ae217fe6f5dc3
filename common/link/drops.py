"""Counting dropped network messages, with rate-limited logging.

Receivers never crash on bad input: they call :meth:`DropCounter.drop` with a short
reason (``not_msgpack``, ``stale``, ...). Counts are kept per reason; a WARNING is
logged at most once per reason per ``log_interval_s`` with the number of drops since
the previous log line of that reason.

Blame that fits: a message that fails authentication (:data:`UNAUTHENTIC`) while the
peer's genuine messages are being accepted (:meth:`DropCounter.authentic`, within
``ATTACK_WINDOW_S``) is not a key mismatch (two sides with different keys accept
nothing from each other): its line says "under attack?" (forged, replayed or altered
messages, or garbage on the path) instead of the receiver's guess about the keys.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

__all__ = ["ATTACK_WINDOW_S", "LIVE_REFUSED", "UNAUTHENTIC", "DropCounter"]

LOG = logging.getLogger("bipedtele.link.drops")

#: Reasons of messages that failed authentication (a MAC, a session key, a signature).
UNAUTHENTIC = frozenset({"no_mac", "bad_mac", "mac_unexpected", "no_session", "old_session", "not_msgpack"})
#: Reasons of messages refused by policy after they arrived intact (another operator holds the
#: robot, feedback of another leader's session): the link that carried them is alive.
LIVE_REFUSED = frozenset({"held", "released", "other_leader"})
#: A genuine message accepted this recently [s]: an unauthentic one is an attack, not a key mismatch.
ATTACK_WINDOW_S = 5.0


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
        self._authentic_at = -float("inf")
        #: Called for each message of :data:`LIVE_REFUSED` (the node's link watch: traffic arrives).
        self.on_live: Callable[[], None] | None = None

    def authentic(self) -> None:
        """Note one accepted, authenticated message of the peer (cheap: Zenoh callbacks call it)."""
        self._authentic_at = self._clock()

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
        if reason in LIVE_REFUSED and self.on_live is not None:
            self.on_live()
        with self._lock:
            self._counts[reason] = self._counts.get(reason, 0) + 1
            pending = self._unlogged.get(reason, 0) + 1
            last = self._last_log.get(reason)
            if last is not None and now - last < self.log_interval_s:
                self._unlogged[reason] = pending
                return
            self._last_log[reason] = now
            self._unlogged[reason] = 0
        if reason in UNAUTHENTIC and now - self._authentic_at < ATTACK_WINDOW_S:
            where = detail.partition(":")[0] if ":" in detail else detail
            detail = (
                f"under attack? {where}: messages that fail authentication arrive among the peer's genuine "
                "ones: forged, replayed or altered messages, or garbage on the path; not a key mismatch "
                "(the genuine ones pass); dropped"
            )
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
