"""The bridge's side of the NAO guard: heartbeats to the ``BipedteleGuard`` qi service.

The guard (``follower/naoqi/nao_guard.py``, run on the robot or as
``bipedtele nao-guard``) calls ``ALMotion.stopMove`` when heartbeats stop for its lapse
time (0.5 s by default). Protocol, over the NAOqi session the bridge already holds:

- ``version() -> str``: ``"bipedtele-guard <protocol>"``; this side speaks protocol 1.
- ``heartbeat(owner: str) -> float``: "I am alive and may be moving the robot"; the
  answer is the guard's lapse time [s]. Sent every ``period_s`` (>= 10 Hz, 20 Hz by
  default) from a thread of its own, *only while the follower's loop is alive* (a robot
  call started within :data:`ACTIVITY_WINDOW_S`): a loop that hangs lets the guard fire.
- ``release(owner: str) -> bool``: sent on a clean disconnect, after the bridge stopped
  the robot itself: the guard disarms without a stop.
- ``status() -> str``: JSON for people and tests (armed, owner, seconds since the last
  heartbeat, stops so far, lapse).

:attr:`GuardLink.answered` is true while the last acknowledged heartbeat is younger than
the guard's lapse time; the bridge refuses to walk otherwise (unless the user opted out).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["ACTIVITY_WINDOW_S", "GUARD_SERVICE", "PROTOCOL", "GuardLink"]

LOG = logging.getLogger(__name__)

#: The qi service name the guard registers.
GUARD_SERVICE = "BipedteleGuard"
#: The heartbeat protocol this bridge speaks.
PROTOCOL = 1
#: Heartbeats stop when no robot call started for this long [s] (the loop is stuck).
ACTIVITY_WINDOW_S = 0.3
#: How often a missing guard is looked up again [s].
LOOKUP_EVERY_S = 1.0


class GuardLink:
    """Heartbeats the guard from a daemon thread while the session is open.

    Parameters
    ----------
    session : qi.Session
        The bridge's connected session to NAOqi.
    owner : str
        Who heartbeats (host:pid), shown by the guard.
    period_s : float
        Heartbeat period [s] (<= 0.1).
    call_timeout_s : float
        Longest wait for one guard call [s].
    last_activity : callable
        Monotonic time [s] of the bridge's latest robot call.
    monotonic : callable
        Clock [s].
    """

    def __init__(
        self,
        session: Any,
        owner: str,
        period_s: float,
        call_timeout_s: float,
        last_activity: Callable[[], float],
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self._session = session
        self.owner = owner
        self.period_s = period_s
        self._ms = max(1, int(call_timeout_s * 1000))
        self._activity = last_activity
        self._mono = monotonic
        self._proxy: Any = None
        self._ok_until = -math.inf
        self._next_lookup = -math.inf
        self.lapse_s: float | None = None
        self.version: str | None = None
        self.beats = 0
        self._stop = threading.Event()
        self._beat_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._lost_logged = False

    @property
    def answered(self) -> bool:
        """True while the guard acknowledged a heartbeat within its lapse time."""
        return self._mono() < self._ok_until

    def probe(self) -> bool:
        """Look the guard up and heartbeat once, now (at connect). True if it answered."""
        self._next_lookup = -math.inf
        self._beat()
        return self.answered

    def beat_now(self) -> bool:
        """Heartbeat once now (the loop just came back from a stall). True if it answered."""
        self._beat()
        return self.answered

    def start(self) -> None:
        """Start the heartbeat thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="nao-guard-heartbeat", daemon=True)
            self._thread.start()

    def close(self, release: bool) -> None:
        """Stop heartbeating; with ``release`` tell the guard the robot was stopped by us."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        proxy, self._proxy = self._proxy, None
        self._ok_until = -math.inf
        if release and proxy is not None:
            try:
                proxy.release(self.owner, _async=True).value(self._ms)
            except RuntimeError as exc:
                LOG.debug("releasing the guard: %s", exc)

    # ------------------------------------------------------------------ thread

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            if self._mono() - self._activity() > ACTIVITY_WINDOW_S:
                continue  # the follower's loop is stuck: let the guard stop the robot
            self._beat()

    def _beat(self) -> None:
        with self._beat_lock:
            self._beat_locked()

    def _beat_locked(self) -> None:
        now = self._mono()
        if self._proxy is None:
            if now < self._next_lookup:
                return
            self._next_lookup = now + LOOKUP_EVERY_S
            try:
                proxy = self._session.service(GUARD_SERVICE, _async=True).value(self._ms)
                version = str(proxy.version(_async=True).value(self._ms))
            except (RuntimeError, AttributeError) as exc:
                LOG.debug("no %s yet: %s", GUARD_SERVICE, exc)
                return
            if not version.startswith("bipedtele-guard "):
                LOG.error(
                    "%s answered version %r: expected 'bipedtele-guard %d'; not a guard this bridge can use",
                    GUARD_SERVICE,
                    version,
                    PROTOCOL,
                )
                return
            self._proxy, self.version = proxy, version
            LOG.info("NAO guard found (%s): heartbeats every %.0f ms", version, 1000 * self.period_s)
        try:
            lapse = float(self._proxy.heartbeat(self.owner, _async=True).value(self._ms))
        except (RuntimeError, TypeError, ValueError) as exc:
            self._proxy = None
            if not self._lost_logged:
                self._lost_logged = True
                LOG.error("the NAO guard stopped answering (%s): the robot will stand until it answers again", exc)
            return
        if not (math.isfinite(lapse) and lapse > 0):
            lapse = 0.5
        self.lapse_s = lapse
        self._ok_until = now + lapse
        self.beats += 1
        if self._lost_logged:
            self._lost_logged = False
            LOG.warning("the NAO guard answers again")
