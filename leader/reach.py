"""Do the leader's commands reach the robot? Told from the follower's own feedback.

A router whose access control refuses this leader's commands (logged in as a user that is
not in ``network.publishers_allowed``, a wrong key in the command ACL) lets the session
open and may even forward feedback: nothing fails, the robot simply never moves. The
follower says in every :class:`~bipedtele.messages.Feedback` which command it applies
(``cmd_seq``); this module watches that.

A feedback *acknowledges* this leader when its ``cmd_seq`` is one of the sequence numbers
this leader has sent (``1 .. seq``) and differs from the ``cmd_seq`` of the first feedback
heard from that follower session (so the last command of an earlier leader, still shown
by a follower that hears nobody now, does not count once our own numbers pass it). A
follower that does not fill ``cmd_seq`` (0: none applied) acknowledges only by walking.

While the follower is present (liveliness) and this leader sends commands, no
acknowledgement for ``window_s`` gives one WARNING line, ``commands not reaching the
robot: refused by the router's ACL? ...``; an acknowledgement after it gives one INFO line.
At the end, :attr:`CommandReach.never_reached` tells whether a run that had the follower
there for a whole window got no command through at all (the leader then exits non-zero).

Why not also "the follower stands while we command motion": a follower legitimately stands
under commanded motion (a fall waiting for the operator to re-arm, a robot without its
guard, the start of a walk); ``cmd_seq`` says what it applies whatever it does with it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from bipedtele.messages import Feedback

__all__ = ["CommandReach"]

LOG = logging.getLogger("bipedtele.leader")


class CommandReach:
    """Watches whether the follower applies this leader's commands.

    Parameters
    ----------
    sent_seq : callable
        ``() -> int``: the sequence number of the last command sent (0: none yet).
    window_s : float
        How long the follower may be present while commands go out unacknowledged
        before the warning [s] (1.5 s: said within 2 s, well above a round trip).
    clock : callable
        Monotonic time [s].

    Notes
    -----
    :meth:`on_feedback` runs on the receiver's thread, :meth:`check` on a slow side thread
    (about 20 Hz); both are cheap.
    """

    def __init__(
        self,
        sent_seq: Callable[[], int],
        window_s: float = 1.5,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not window_s > 0:
            raise ValueError(f"window_s must be > 0, got {window_s!r}")
        self._sent_seq = sent_seq
        self.window_s = float(window_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._baseline: dict[int, int] = {}  # follower sid -> cmd_seq of its first feedback
        self.feedback = 0
        self.acknowledged = 0
        self._last_ack: float | None = None
        self._since: float | None = None  # follower present and commands going out since
        self._warned = False
        self.warnings = 0
        self.exposed = False  # the follower was there for a whole window of commands

    def on_feedback(self, fb: Feedback) -> None:
        """Take one received feedback (any thread)."""
        sent = self._sent_seq()
        with self._lock:
            self.feedback += 1
            base = self._baseline.setdefault(fb.sid, fb.cmd_seq)
            if fb.cmd_seq:
                ok = 1 <= fb.cmd_seq <= sent and fb.cmd_seq != base
            else:
                ok = fb.state == "walking" and sent > 0
            if ok:
                self.acknowledged += 1
                self._last_ack = self._clock()

    @property
    def ever_reached(self) -> bool:
        """True once any feedback acknowledged one of our commands."""
        return self.acknowledged > 0

    @property
    def never_reached(self) -> bool:
        """Whether the commands never reached the follower.

        True when the follower was present for a whole window while we sent commands, and
        not one of them was acknowledged.
        """
        return self.exposed and not self.ever_reached

    def check(self, follower_present: bool) -> None:
        """Update the verdict; log when it changes (call it a few times per second)."""
        now = self._clock()
        if not follower_present or self._sent_seq() == 0:
            self._since = None
            return
        if self._since is None:
            self._since = now
        with self._lock:
            last_ack, feedback = self._last_ack, self.feedback
        recent = last_ack is not None and now - last_ack < self.window_s
        if recent:
            if self._warned:
                LOG.info("commands reach the robot again (the follower's feedback acknowledges them)")
                self._warned = False
            return
        if now - self._since < self.window_s:
            return
        self.exposed = True
        if not self._warned:
            self._warned = True
            self.warnings += 1
            why = (
                f"the follower is present but its feedback acknowledges none of our commands ({feedback} heard)"
                if feedback
                else "the follower is present but no feedback arrives"
            )
            LOG.warning(
                "commands not reaching the robot: refused by the router's ACL? (%s for %.1f s; "
                "the leader must log in as a user of network.publishers_allowed)", why, self.window_s,
            )  # fmt: skip
