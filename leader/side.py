"""The leader program's slow duties, in a side thread (about 20 Hz).

Status out (the leader's counters and the link's figures, for the follower to adapt its
rates), the follower's status in, the operator's progress as events, the cockpit's hand
logged, and the command-reach check (:class:`~bipedtele.leader.reach.CommandReach`).
:class:`~bipedtele.leader.app.LeaderApp` starts it once the loop is built.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from bipedtele.config.profile import Config
from bipedtele.config.sections import ClockConfig, NetworkConfig, RobotConfig
from bipedtele.leader.config import LeaderConfig
from bipedtele.leader.linkquality import LinkQuality, LinkReport
from bipedtele.leader.loop import LeaderLoop
from bipedtele.leader.reach import CommandReach
from bipedtele.leader.report import fill_link, link_counters
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import Status, fit_counters
from bipedtele.link.receivers import LatestReceiver
from bipedtele.link.transport import PresenceWatcher, Publishers
from bipedtele.telemetry import LeaderSample

__all__ = ["LeaderSide"]

LOG = logging.getLogger(__name__)


class LeaderSide:
    """The leader's slow duties in a side thread (about 20 Hz).

    Status out, follower status in, presence, events of the operator's progress, the
    command-reach check. (Clock pings run in their own
    :class:`~bipedtele.link.clocklink.ClockLink` thread.)
    """

    def __init__(
        self,
        loop: LeaderLoop,
        pubs: Publishers,
        cfg: Config,
        status_rx: LatestReceiver[Status],
        presence: PresenceWatcher,
        drops: DropCounter,
        record: Callable[[str, Any, float], None],
        reach: CommandReach | None = None,
        link: LinkQuality | None = None,
        hand: Callable[[], bool] | None = None,
    ) -> None:
        self.reach = reach
        self.hand = hand
        self.link = link or LinkQuality(feedback_timeout_s=cfg.get(LeaderConfig).feedback_timeout_s)
        self._not_synced = 0  # drops counted as clock_not_synced so far
        self.loop, self.pubs, self.cfg = loop, pubs, cfg
        self.status_rx, self.presence = status_rx, presence
        self.drops, self.record = drops, record
        self.follower_status: Status | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="leader-aux", daemon=True)
        self._status_seq = 0
        self._passes = 0
        self._progress_lock = threading.Lock()
        self._released = False  # the hand last logged

    def record_progress(self, now: float) -> None:
        """Record a ``pass`` event for every pass the operator completed since the last call."""
        op = self.loop.operator
        if op is None:
            return
        with self._progress_lock:
            prog = op.progress()
            n = int(prog.get("passes_done", 0))
            sides = list(prog.get("sides", []))
            while self._passes < n:
                self._passes += 1
                side = sides[self._passes - 1] if len(sides) >= self._passes else ""
                self.record("events", {"event": "pass", "n": self._passes, "side": side}, now)

    def __enter__(self) -> LeaderSide:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def report(self, now: float | None = None) -> LinkReport:
        """Return the link's figures and state now (presence and the follower's counters)."""
        st = self.follower_status
        return self.link.report(
            now, follower_present=self.presence.alive, follower_counters=st.counters if st is not None else None
        )

    def fill(self, sample: LeaderSample) -> None:
        """Fill the sample's fields from the follower's status, presence and the link's figures."""
        st = self.follower_status
        sample.follower_present = self.presence.alive
        counters = st.counters if st is not None else {}
        if st is not None:
            sample.watchdog = counters.get("watchdog_stops", counters.get("watchdog", 0))
            sample.falls = counters.get("falls", 0)
            sample.collisions = counters.get("collisions", 0)
            sample.follower_text = st.text
            sample.held_by = st.held_by
        fill_link(sample, self.report(), counters)

    def _take_hand(self) -> None:
        """Log the cockpit's Release / Take (the loop reads the hand itself; docs/fleet.md, Hand-over)."""
        if self.hand is None:
            return
        released = self.hand()
        if released != self._released:
            self._released = released
            robot = self.cfg.get(RobotConfig).id
            if released:
                LOG.info("robot %s released (cockpit): the robot stops; another operator may take it", robot)
            else:
                LOG.info("robot %s: Take (cockpit): driving it again once it is free", robot)

    def _run(self) -> None:
        lc, ck = self.cfg.get(LeaderConfig), self.cfg.get(ClockConfig)
        next_status = time.monotonic()
        text = "clock: synced" if ck.mode == "synced" else "clock: ntp (h1+h2 exact, split estimated)"
        user = self.cfg.get(NetworkConfig).user  # who drives, for the fleet view (bipedtele status)
        while not self._stop.wait(0.05):
            now_m, now = time.monotonic(), time.time()
            try:
                got = self.status_rx.take()
                if got is not None and got.msg.role == "follower":
                    self.follower_status = got.msg
                self._heard_unsynced()
                if now_m >= next_status:
                    next_status = now_m + 1.0 / lc.status_rate_hz
                    counters = {f"drop_{k}": v for k, v in self.drops.counts().items()}
                    counters.update(
                        commands=self.loop.seq,
                        feedback=self.loop.feedback_count,
                        missed_ticks=self.loop.missed_ticks,
                        blind_stops=self.loop.blind.stops,
                    )
                    counters.update(link_counters(self.report(now)))
                    self._status_seq += 1
                    blind = self.loop.blind.words()
                    st = Status(
                        sid=self.loop.sid,
                        seq=self._status_seq,
                        t=now,
                        role="leader",
                        state=self.loop.state,
                        counters=fit_counters(counters),
                        text=f"{text}; {blind}" if blind else text,
                        operator=user,
                    )
                    self.pubs.status.put(st)
                    self.record("status/sent", st, now)
                self.record_progress(now)
                self._take_hand()
                if self.reach is not None:
                    self.reach.check(self.presence.alive)
            except Exception as exc:  # a bad moment on the network must not end the program
                LOG.warning("leader side thread: %s", exc)

    def _heard_unsynced(self) -> None:
        """Messages dropped only because our clock is not synced to the peer's yet: the path works."""
        n = self.drops.counts().get("clock_not_synced", 0)
        if n > self._not_synced and self.reach is not None:
            self.reach.on_heard()
        self._not_synced = n
