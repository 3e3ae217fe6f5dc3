"""A cellular uplink's fluid model around the follower's UplinkBudget, with a fake clock.

The follower sends feedback (380 B, at the plan's rate plus an acknowledgement per
command unless coalesced), a status (600 B, 2 Hz) and video at ``min(want, budget)``
into a drop-tail queue (``queue_bytes``) drained at ``cap(t)`` [bit/s]; what leaves it
arrives ``base_s`` later. ``video_delivered`` of the video sent arrives (TCP slowed by
loss: the publish call counts what the transport then holds back or drops). The leader
computes, as leader/linkquality.py does: ``rx_bps`` over its last 2 s, the age of its
newest feedback (``fb_age_ms``), the echo of its newest status's stamp
(``uplink_t_echo_us``) and h2, the mean delay of the feedback that arrived over the last
second (none arrived: 0 in the command); its Status (every ``status_s``, in session
``sid``) and commands (100 Hz) travel the free downlink in ``base_s``.
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Callable

from bipedtele.follower.capacity import UplinkBudget

DT = 0.01
FB, STATUS = 380, 600


class CellSim:
    def __init__(
        self,
        cap: Callable[[float], float],
        *,
        base_s: Callable[[float], float] = lambda t: 0.04,
        queue_bytes: int = 64_000,
        want_bps: float = 800_000.0,
        video_delivered: float = 1.0,
        fb_loss_ppm: int = 0,
        status_s: float = 0.5,
    ) -> None:
        self.t = 0.0
        self.cap, self.base_s, self.qmax = cap, base_s, queue_bytes
        self.want, self.video_delivered, self.fb_loss_ppm = want_bps, video_delivered, fb_loss_ppm
        self.rng = random.Random(3)
        self.status_s = status_s  # the leader's status period [s]: its acknowledgements
        self.echo = True  # the leader echoes the newest follower status's stamp
        self.sid = 1  # the leader's session (another one: a hand-over)
        self.budget = UplinkBudget(lambda: self.t)
        self.queue: deque[list[float]] = deque()  # [t_sent, bits left, is feedback, bits]
        self.queue_bits = 0.0
        self.flight: deque[tuple[float, float, float, int]] = deque()  # (arrive, t_sent, bits, 0/1/2: video/fb/status)
        self.rx: deque[tuple[float, float]] = deque()
        self.fb_arrived: deque[tuple[float, float]] = deque()  # (arrival, delay) over the last s
        self.newest_fb_sent: float | None = None
        self.newest_st_sent: float | None = None  # the newest status that arrived: its send time [s]
        self.first_fb_after: list[tuple[float, float]] = []  # (arrival, age) of every feedback
        self.to_follower: deque[tuple[float, str, object]] = deque()
        self.next_fb = self.next_st = self.next_leader_st = 0.0
        self.credit = 0.0
        self.log: list[dict[str, float]] = []

    def send(self, nbytes: int, *, video: bool = False, feedback: bool = False, status: bool = False) -> None:
        # the in-flight cap, as follower/app.py and follower/video.py apply it
        if feedback and not self.budget.inflight.admit_feedback(self.t):
            return
        if status and not self.budget.inflight.admit_probe(self.t):
            return
        if video and not self.budget.admit_video(nbytes):
            return
        stamp = round(1e6 * self.t) / 1e6  # a status is counted at its stamp (follower/app.py)
        self.budget.sent(nbytes, video, feedback=feedback, at=stamp if status else None)
        if video and self.rng.random() >= self.video_delivered:
            return
        bits = 8.0 * nbytes
        if self.queue_bits + bits > 8.0 * self.qmax:
            return  # tail drop
        self.queue.append([stamp if status else self.t, bits, 1.0 if feedback else 2.0 if status else 0.0, bits])
        self.queue_bits += bits

    def _follower(self) -> None:
        b, t = self.budget, self.t
        plan = b.feedback_plan(50.0)
        if plan.ack_each_command:
            self.send(FB, feedback=True)
        if t >= self.next_fb:
            self.next_fb = t + 1.0 / plan.rate_hz
            self.send(FB, feedback=True)
        if t >= self.next_st:
            self.next_st = t + 0.5
            self.send(STATUS, status=True)  # over the cap only as a probe, as follower/app.py does
        vb = b.video_budget_bps()
        self.credit += (self.want if vb is None else min(self.want, vb)) * DT / 8
        while self.credit >= 4000:
            self.credit -= 4000
            self.send(4000, video=True)
        b.update()

    def _path(self) -> None:
        t, serve = self.t, self.cap(self.t) * DT
        while self.queue and serve > 0:
            head = self.queue[0]
            used = min(serve, head[1])
            head[1] -= used
            serve -= used
            self.queue_bits -= used
            if head[1] <= 0:
                self.queue.popleft()
                self.flight.append((t + self.base_s(t), head[0], head[3], int(head[2])))
        while self.flight and self.flight[0][0] <= t:
            arrive, sent, bits, kind = self.flight.popleft()
            self.rx.append((arrive, bits))
            if kind == 2:
                self.newest_st_sent = max(sent, self.newest_st_sent or sent)
            if kind == 1:
                self.fb_arrived.append((arrive, arrive - sent))
                self.first_fb_after.append((arrive, arrive - sent))
                self.newest_fb_sent = max(sent, self.newest_fb_sent or sent)

    def _leader(self) -> None:
        t = self.t
        while self.rx and self.rx[0][0] < t - 2.0:
            self.rx.popleft()
        while self.fb_arrived and self.fb_arrived[0][0] < t - 1.0:
            self.fb_arrived.popleft()
        # a command every tick: h2 is the mean delay of the feedback of the last second, 0 when none arrived
        h2 = sum(d for _, d in self.fb_arrived) / len(self.fb_arrived) if self.fb_arrived else 0.0
        self.to_follower.append((t + self.base_s(t), "h2", h2))
        if t >= self.next_leader_st and self.newest_fb_sent is not None:
            self.next_leader_st = t + self.status_s
            counters = {
                "rx_bps": round(sum(b for _, b in self.rx) / 2.0),
                "fb_loss_ppm": self.fb_loss_ppm,
                "fb_age_ms": round(1000.0 * (t - self.newest_fb_sent)),
            }
            if self.echo and self.newest_st_sent is not None:
                counters["uplink_t_echo_us"] = round(1e6 * self.newest_st_sent)
            self.to_follower.append((t + self.base_s(t), "status", (counters, t, self.sid)))
        while self.to_follower and self.to_follower[0][0] <= t:
            _, kind, what = self.to_follower.popleft()
            if kind == "h2":
                self.budget.on_h2(float(what))  # type: ignore[arg-type]
            else:
                counters, ts, sid = what  # type: ignore[misc]
                self.budget.on_leader_status(counters, ts, sid)

    def run(self, seconds: float) -> list[dict[str, float]]:
        n0 = len(self.log)
        for _ in range(round(seconds / DT)):
            self._follower()
            self._path()
            self._leader()
            b = self.budget
            vb = b.video_budget_bps()
            self.log.append(
                {
                    "t": self.t,
                    "cap": b.capacity_bps,
                    "video": -1.0 if vb is None else vb,
                    "tx": b.tx_bps(),
                    "limited": float(b.limited),
                    "queue_s": self.queue_bits / 1e6,
                }
            )
            self.t += DT
        return self.log[n0:]
