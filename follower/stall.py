"""Whether the robot's uplink is stalled, judged on each word of the leader (:class:`StallJudge`).

The path failed to deliver when the newest feedback the leader had (its Status's
``fb_age_ms``, or a command's echo of it) is older than h2's floor by more than
``stall_s`` and something of ours sent after it, long enough ago to have arrived, is still
undelivered (an old feedback with nothing after it is our own pacing). A leader back from a
silence reports that silence as the age: :class:`~bipedtele.follower.leadersilence.LeaderSilence`
grants a grace. A word of the leader sent before the stall began (a Status that waited
behind the gap) does not end it. Each word also feeds the delivery rate
(:class:`~bipedtele.follower.delivery.DeliveryRate`), whose best before the stall the
capacity restarts from (:class:`~bipedtele.follower.capacity.UplinkBudget`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from bipedtele.follower.delivery import DeliveryRate, InFlight
from bipedtele.follower.leadersilence import LeaderSilence

__all__ = ["StallJudge", "StallVerdict"]


class StallVerdict(NamedTuple):
    """One judgement: stalled now, and whether a stall began or ended with it."""

    stalled: bool
    began: bool
    ended: bool


class StallJudge:
    """The uplink's stall, judged on the leader's Status and on each command's echo.

    Parameters
    ----------
    stall_s : float
        The newest feedback older than h2's floor by more than this is a stall [s].
    timeout_s : float
        A stall is current only while the leader was heard within this [s] (its Status, or
        a command whose echo judged it).
    delivery : DeliveryRate
        The delivery rate each judgement feeds (its ``stalled`` flag is the stall's state).
    silence : LeaderSilence
        The leader's silences (a grace after one).
    inflight : InFlight
        What is in flight (undelivered data; held to one message while stalled).
    """

    def __init__(
        self, stall_s: float, timeout_s: float, delivery: DeliveryRate, silence: LeaderSilence, inflight: InFlight
    ) -> None:
        self.stall_s, self.timeout_s = float(stall_s), float(timeout_s)
        self.delivery, self.silence, self.inflight = delivery, silence, inflight
        self.heard = -math.inf  # the leader's last word that judged [s]

    def judge(self, now: float, ts: float, rx: int | None, t_fb: float | None, floor_s: float) -> StallVerdict:
        """Judge a word of the leader heard at ``now`` [s].

        Parameters
        ----------
        now, ts : float
            Now, and when the leader sent its word (a Status or a command) [s].
        rx : int or None
            What the leader received over its window [bit/s] (a Status's; None: a command's).
        t_fb : float or None
            Send time of the newest feedback the leader had then [s] (None: none).
        floor_s : float
            h2's floor: the path's own delay [s].
        """
        self.heard = now
        d = self.delivery
        stall = t_fb is not None and ts - t_fb - floor_s > self.stall_s and not self.silence.grace(now)
        stall = stall and self.inflight.undelivered(t_fb or 0.0, ts - floor_s - self.stall_s)
        was = d.stalled
        stall = stall or (was and ts < (d.stall_since or -math.inf))  # sent before the stall began
        d.sample(ts, 0.0 if rx is None else float(rx), stall)
        self.inflight.hold = stall  # a path that does not deliver: one message of ours in it at most
        return StallVerdict(stall, stall and not was, was and not stall)

    def current(self, now: float, heard: float = -math.inf) -> bool:
        """Say whether the path is stalled at ``now`` [s]: the last judgement said so, and the leader was heard within ``timeout_s``.

        ``heard``: the leader's last word [s] that judged nothing (a Status without ``rx_bps``).
        """
        return self.delivery.stalled and now - max(self.heard, heard) <= self.timeout_s
