"""A leader back from a silence is not taken for a stalled uplink.

When the follower hears nothing of the leader (no command, no Status) for
``inflight_release_s``, the uplink budget releases its in-flight cap: the leader stopped,
froze, or the whole path is down. A leader back from such a silence reports its own silence
as its newest feedback's age (``fb_age_ms``): it received nothing while it was away. Judged
as it stands, that age says "stalled uplink", and the stall hold keeps the robot's
feedback behind a probe's echo (a frozen leader that resumed saw the robot walk 2.2-3.6 s
after it, against 2 s). :class:`LeaderSilence` measures the silence, from the cap's release
to the first command or Status that ends it; a feedback age that silence explains (within
``stall_s``) opens a grace of ``stall_s`` in which no stall is judged, so the first
feedback goes out at once. A path that stalls while the leader's statuses keep arriving
reports an age far past the gaps between them, and is judged stalled as before.
"""

from __future__ import annotations

import math

__all__ = ["LeaderSilence"]


class LeaderSilence:
    """The leader's silences that released the in-flight cap, and the stall grace after one.

    Parameters
    ----------
    release_s : float
        A silence this long released the cap [s] (``inflight_release_s``).
    stall_s : float
        The stall bound, and the grace's length [s] (``stall_s``).
    """

    def __init__(self, release_s: float, stall_s: float) -> None:
        self.release_s, self.stall_s = release_s, stall_s
        self._from: float | None = None  # silent since (the cap released) [s]
        self._length = 0.0  # the last silence's length, until a Status reads it [s]
        self.grace_until = -math.inf  # no stall judged before this [s]

    def released(self, last_heard: float) -> None:
        """Note the cap released for silence; the leader was last heard at ``last_heard`` [s]."""
        if self._from is None:
            self._from = last_heard

    def heard(self, now: float) -> None:
        """Note the leader heard (a command or a Status) at ``now`` [s]: a silence ends."""
        if self._from is not None:
            self._length = now - self._from
            self._from = None

    def on_status(self, now: float, age_s: float | None, floor_s: float) -> None:
        """Read a Status's feedback age ``age_s`` [s] (h2's minimum ``floor_s`` [s]): a grace if the silence explains it."""
        silent, self._length = self._length, 0.0
        if silent > self.release_s and age_s is not None and age_s - floor_s <= silent + self.stall_s:
            self.grace_until = now + self.stall_s

    def grace(self, now: float) -> bool:
        """Whether no stall is judged at ``now`` [s]."""
        return now < self.grace_until
