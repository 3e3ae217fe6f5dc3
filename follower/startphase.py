"""The uplink budget's start, before the path said what it carries (:class:`StartPhase`).

Video's budget starts at ``start_bps`` (64 kbit/s) and grows by ``start_growth`` (x1.3) a
second while the path is clear (the budget judges that) and the budget is under twice what
is sent (a budget far above the sending rate was never tested). Past ``start_max_bps`` the
path is taken as unlimited; after ``start_s`` of clear path the capacity is taken as 1.2 x
the most that was sent with the path clear (not what is sent at that moment: TCP's video
slowed by loss dips it), and probed from there (twice it overshot a 600 kbit/s uplink by
200 ms at once), once video has sent what the start offers it or all it wants (BBR's rule
for an application-limited sender: a rate the sender did not use is no measure of the
path), after twice ``start_s`` at the latest. See :mod:`bipedtele.follower.capacity`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from bipedtele.follower.uplinktuning import UplinkTuning

__all__ = ["StartPhase"]


@dataclass
class StartPhase:
    """What the start counted so far.

    Attributes
    ----------
    clear_s : float
        Time of clear path in the start [s].
    peak_bps : float
        The most sent in it with the path clear [bit/s].
    """

    clear_s: float = 0.0
    peak_bps: float = 0.0

    def step(
        self,
        tuning: UplinkTuning,
        budget_bps: float,
        dt: float,
        tx: float,
        video_most_bps: float = 0.0,
        video_sent: Callable[[], float] | None = None,
    ) -> tuple[float | None, float | None]:
        """Count ``dt`` [s] more of clear path, ``tx`` [bit/s] sent now, from video's start budget ``budget_bps`` [bit/s].

        ``video_most_bps`` [bit/s]: what video sends at its most (0: not known, or no video);
        ``video_sent()``: what video sends now [bit/s], read only when the take is due. Until
        video sends 0.8 of what the start offers it (or of its most) the capacity is not
        taken before twice ``start_s``: on the 5 % loss row video, climbing its levels, sent
        270 of the 524 kbit/s offered when the start ended, the capacity taken from that
        peak left video 344 kbit/s, and it sent 9.5-14 frames/s for 30 s against 17-20 in
        the loss-free run, whose start had ended 1.5 s later in video's climb.

        Returns
        -------
        tuple of (float or None, float or None)
            Video's start budget [bit/s] (None: the start is over), and the capacity taken
            [bit/s] (None: none, unlimited past ``start_max_bps`` or still in the start).
        """
        tu = tuning
        want = min(budget_bps, video_most_bps)  # what video is offered (before this step's growth)
        self.clear_s += dt
        self.peak_bps = max(self.peak_bps, tx)
        if budget_bps < 2.0 * tx + tu.floor_bps:
            budget_bps *= tu.start_growth**dt
        if budget_bps > tu.start_max_bps:
            return None, None
        if self.clear_s >= tu.start_s:
            tested = not want or video_sent is None or video_sent() >= 0.8 * want
            if tested or self.clear_s >= 2.0 * tu.start_s:
                return None, 1.2 * self.peak_bps + tu.floor_bps
        return budget_bps, None
