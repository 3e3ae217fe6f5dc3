"""Do the leader's commands reach the robot? Told from the follower's own feedback.

A router whose access control refuses this leader's commands (logged in as a user that is
not in ``network.publishers_allowed``, a wrong key in the command ACL) lets the session
open and may even forward feedback: nothing fails, the robot simply never moves. The
follower says in every :class:`~bipedtele.link.messages.Feedback` which command it applies
(``cmd_seq``); this module watches that.

A feedback *acknowledges* this leader when its ``cmd_seq`` is one of the sequence numbers
this leader has sent (``1 .. seq``) and differs from the ``cmd_seq`` of the first feedback
heard from that follower session (so the last command of an earlier leader, still shown
by a follower that hears nobody now, does not count once our own numbers pass it). A
follower that does not fill ``cmd_seq`` (0: none applied) acknowledges only by walking.

While the follower is present (liveliness) and this leader sends commands, no
acknowledgement for ``window_s`` gives one WARNING line naming the cause the evidence
points to:

- the follower is *heard fresh* for a whole window (its feedback, status or video,
  each sent less than ``fresh_s`` before it arrived, with no pause longer than the window
  between them, or a message of its dropped only because our clock is not synced to its
  yet): the path and the router work, so the commands are refused on the way,
  ``commands not reaching the robot: refused by the router's ACL? ...`` (a leader logged
  in as the follower's user receives the follower's status but no feedback);
- the follower is heard, but nothing fresh arrived within the window (what arrives was
  sent ``fresh_s`` or more before): its uplink is stalled or draining a backlog (a
  cellular blackout), ``uplink stalled for N s: ...``, N the time since the last
  acknowledgement; the ACL is not named (and while fresh messages have come for less
  than a window, no verdict) (before, every gap of a cellular uplink
  ended in "refused by the router's ACL?": the old status and video arrived first, the
  feedback after them); a refusal keeps the follower heard fresh, three messages at least
  since the last acknowledgement (two trickling through a near-zero stretch are no verdict);
- nothing is heard from the follower (a stalled or cut path, a router down: its presence
  may still linger): ``link lost: no feedback for N s (path or router down?)``; the ACL
  is not named, nothing says our commands were refused.

- the follower's messages arrive but are refused for their MAC (``no_mac``: it has no
  key; ``mac_unexpected``: it has one and we do not; ``bad_mac``: the keys differ):
  ``commands not reaching the robot: message keys do not match: ...`` with the line that
  says which; the ACL is not named.

- the follower's status says another operator holds the robot (hand-over, docs/fleet.md):
  ``robot <id> is held by <operator>``: our commands are refused until that operator
  releases it; the ACL is not named.

- the follower is never present while this leader sends commands for ``absent_s`` (10 s):
  ``no robot <id> on the router``: it is not running, or the router's ACL does not let this
  login reach it (an operator bound to other robots, ``user@robot_id`` in
  ``publishers_allowed``, sees neither the robot's presence nor anything of it, and the
  robot nothing of the operator: docs/fleet.md).

An acknowledgement after it gives one INFO line; a change of cause gives a new WARNING.
At the end, :attr:`CommandReach.never_reached` tells whether a run that had the follower
heard for a whole window got no command through at all (refused: the leader then exits
non-zero), :attr:`CommandReach.never_acknowledged` whether a run that had the follower
present for a whole window saw no acknowledgement whatever the cause.

Why not also "the follower stands while we command motion": a follower legitimately stands
under commanded motion (a fall waiting for the operator to re-arm, a robot without its
guard, the start of a walk); ``cmd_seq`` says what it applies whatever it does with it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from bipedtele.link.auth import BAD_MAC_LINE, KEY_REASONS, NO_MAC_LINE, UNEXPECTED_MAC_LINE
from bipedtele.link.messages import Feedback

__all__ = ["ABSENT", "HELD", "KEY_MISMATCH", "LOST", "REFUSED", "STALLED", "CommandReach"]

LOG = logging.getLogger("bipedtele.leader")


#: The WARNING of the refused case (tests and launchers grep for it).
REFUSED = "commands not reaching the robot: refused by the router's ACL?"
#: The WARNING of a key problem starts with this; the line for the drop reason follows.
KEY_MISMATCH = "commands not reaching the robot: message keys do not match:"
_KEY_LINES: dict[str, str] = {"no_mac": NO_MAC_LINE, "bad_mac": BAD_MAC_LINE, "mac_unexpected": UNEXPECTED_MAC_LINE}
#: The WARNING of the lost case starts with this.
LOST = "link lost: no feedback for"
#: The WARNING of a stalled uplink (the follower heard, late) starts with this.
STALLED = "uplink stalled for"
#: The WARNING of a robot never present starts with this.
ABSENT = "no robot"
#: The WARNING of a robot held by another operator starts with this.
HELD = "commands not reaching the robot: held by another operator:"


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
    key_drops : callable, optional
        ``() -> {reason: count}``: the node's drop counts. Messages refused for their MAC
        (``no_mac``, ``bad_mac``, ``mac_unexpected``) within the window make the verdict a
        key problem, named in one line (:data:`KEY_MISMATCH`), instead of the ACL.
    robot_id, user : str
        Named in the line of a robot never present (:data:`ABSENT`).
    absent_s : float
        How long commands go out with the follower never present before that line [s].
    holder : callable, optional
        ``() -> str | None``: who holds the robot, from the follower's status (``""``:
        free or unnamed; None: not known). Another operator than ``user`` makes the
        verdict :data:`HELD`.
    released : callable, optional
        ``() -> bool``: this leader gave the robot up (cockpit Release): no verdicts then.
    fresh_s : float, optional
        A message of the follower's heard this long or longer after it was sent is old
        [s] (default: ``window_s``).

    Notes
    -----
    :meth:`on_feedback` and :meth:`on_heard` run on the receivers' threads, :meth:`check`
    on a slow side thread (about 20 Hz); all are cheap.
    """

    def __init__(
        self,
        sent_seq: Callable[[], int],
        window_s: float = 1.5,
        clock: Callable[[], float] = time.monotonic,
        key_drops: Callable[[], dict[str, int]] | None = None,
        robot_id: str = "",
        user: str = "",
        absent_s: float = 10.0,
        holder: Callable[[], str | None] | None = None,
        released: Callable[[], bool] | None = None,
        fresh_s: float | None = None,
    ) -> None:
        if not window_s > 0:
            raise ValueError(f"window_s must be > 0, got {window_s!r}")
        self.fresh_s = float(window_s if fresh_s is None else fresh_s)
        self._fresh_since: float | None = None  # fresh messages heard without a window's pause since
        self._fresh_unacked: float | None = None  # the first fresh message after the last acknowledgement
        self._fresh_count = 0  # fresh messages since the last acknowledgement
        self._last_fresh: float | None = None
        self.stall_warnings = 0
        self._sent_seq = sent_seq
        self._key_counts = key_drops
        self._key_seen_counts: dict[str, int] = {}
        self._key_last: tuple[float, str] | None = None
        #: The drop reason of the last key problem (``no_mac``, ``bad_mac``, ``mac_unexpected``), or None.
        self.key_reason: str | None = None
        self.window_s = float(window_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._baseline: dict[int, int] = {}  # follower sid -> cmd_seq of its first feedback
        self.feedback = 0
        self.acknowledged = 0
        self._last_ack: float | None = None
        self._last_fb: float | None = None  # the newest feedback arrived (monotonic)
        self._last_heard: float | None = None  # anything of the follower's arrived
        self._since: float | None = None  # follower present and commands going out since
        self._warned: str | None = None  # the cause last warned about: "refused", "lost"
        self.warnings = 0
        self.lost_warnings = 0
        self.exposed = False  # the follower was heard for a whole window of commands, none acknowledged
        self.present_window = False  # the follower was present for a whole window of commands
        self.robot_id, self.user, self.absent_s = robot_id, user, float(absent_s)
        self._absent_since: float | None = None  # commands going out, the follower never present, since
        self._ever_present = False
        self.absent_warnings = 0
        self._holder, self._released = holder, released
        self._held_over: float | None = None  # when the robot stopped being held by another
        self.held_warnings = 0

    def _absent(self, now: float) -> None:
        if self._absent_since is None:
            self._absent_since = now
        if now - self._absent_since < self.absent_s or self.absent_warnings:
            return
        self.absent_warnings += 1
        who = f"user {self.user!r}" if self.user else "this login"
        LOG.warning(
            "%s %s on the router after %.0f s of commands: it is not running, or the router's ACL does not let "
            "%s reach it (an operator drives only the robots named for it: publishers_allowed 'user@robot_id', "
            "bipedtele setup fleet --operator USER=ROBOT)",
            ABSENT,
            self.robot_id or "(this id)",
            self.absent_s,
            who,
        )

    def _heard(self, now: float, age_s: float | None) -> None:
        """Something of the follower's arrived ``age_s`` after it was sent (None: unknown); lock held."""
        self._last_heard = now
        if age_s is not None and not age_s < self.fresh_s:
            return
        if self._last_fresh is None or now - self._last_fresh > self.window_s:
            self._fresh_since = now
        self._last_fresh = now
        if self._fresh_unacked is None:
            self._fresh_unacked = now  # the first fresh message since the last acknowledgement
        self._fresh_count += 1

    def on_feedback(self, fb: Feedback, age_s: float | None = None) -> None:
        """Take one received feedback (any thread), ``age_s`` after it was sent [s] (None: unknown)."""
        sent = self._sent_seq()
        now = self._clock()
        with self._lock:
            self.feedback += 1
            self._last_fb = now
            self._heard(now, age_s)
            base = self._baseline.setdefault(fb.sid, fb.cmd_seq)
            if fb.cmd_seq:  # noqa: SIM108 (two rules, clearer apart than in one ternary)
                ok = 1 <= fb.cmd_seq <= sent and fb.cmd_seq != base
            else:
                ok = fb.state == "walking" and sent > 0
            if ok:
                self.acknowledged += 1
                self._last_ack = now
                self._fresh_unacked, self._fresh_count = None, 0

    def _key_problem(self, now: float) -> str | None:
        """Return the key line when messages were refused for their MAC within the window, else None."""
        if self._key_counts is None:
            return None
        counts = self._key_counts()
        grew = {r: counts.get(r, 0) - self._key_seen_counts.get(r, 0) for r in KEY_REASONS}
        self._key_seen_counts = {r: counts.get(r, 0) for r in KEY_REASONS}
        worst = max(grew, key=lambda r: grew[r])
        if grew[worst] > 0:
            self._key_last = (now, worst)
        if self._key_last is None or now - self._key_last[0] >= self.window_s:
            return None
        self.key_reason = self._key_last[1]
        return _KEY_LINES[self._key_last[1]]

    @property
    def key_line(self) -> str:
        """The line naming the last key problem (empty when there was none)."""
        return _KEY_LINES.get(self.key_reason or "", "")

    def on_heard(self, age_s: float | None = None) -> None:
        """Something of the follower's arrived other than feedback (status, video; any thread).

        Evidence that the path and the router work; of a timely path only when it is fresh
        (``age_s``: how long after it was sent it arrived [s]; None: unknown, taken as fresh).
        """
        now = self._clock()
        with self._lock:
            self._heard(now, age_s)

    @property
    def ever_reached(self) -> bool:
        """True once any feedback acknowledged one of our commands."""
        return self.acknowledged > 0

    @property
    def never_reached(self) -> bool:
        """Whether the commands were refused on the way for the whole run.

        True when the follower was heard (the link worked) for a whole window while we
        sent commands, and not one of them was acknowledged.
        """
        return self.exposed and not self.ever_reached

    @property
    def never_acknowledged(self) -> bool:
        """True when the follower was present for a whole window of commands and none was acknowledged.

        Refused (:attr:`never_reached`) or lost: the run reached nothing that we know of.
        """
        return self.present_window and not self.ever_reached

    def check(self, follower_present: bool) -> None:
        """Update the verdict; log when it changes (call it a few times per second)."""
        now = self._clock()
        if follower_present:
            self._ever_present = True
        elif not self._ever_present and self._sent_seq() > 0:
            self._absent(now)
        if not follower_present or self._sent_seq() == 0 or (self._released is not None and self._released()):
            self._since = None
            return
        if self._since is None:
            self._since = now
        with self._lock:
            last_ack, last_fb, last_heard, feedback = self._last_ack, self._last_fb, self._last_heard, self.feedback
            last_fresh, fresh_since, unacked = self._last_fresh, self._fresh_since, self._fresh_unacked
            fresh_count = self._fresh_count
        recent = last_ack is not None and now - last_ack < self.window_s
        if recent:
            if self._warned is not None:
                LOG.info("commands reach the robot again (the follower's feedback acknowledges them)")
                self._warned = None
            return
        held = self._holder() if self._holder is not None else None
        held_by_other = bool(held) and held != self.user
        if self._warned == "held" and not held_by_other and self._held_over is None:
            self._held_over = self._since = now  # released to us: a fresh window for the take
        if now - self._since < self.window_s:
            return
        self.present_window = True
        heard = last_heard is not None and now - last_heard < self.window_s
        key = self._key_problem(now)
        if key is not None:  # the follower's messages arrive but fail the MAC check
            self.exposed = True
            if self._warned != "key":
                self._warned = "key"
                self.warnings += 1
                LOG.warning("%s %s", KEY_MISMATCH, key)
            return
        if held_by_other:
            self._warn_held(str(held))
            return
        fresh = last_fresh is not None and now - last_fresh < self.window_s
        if heard and not fresh:
            self._stalled(now, last_ack if last_ack is not None else self._since)
            return
        if heard and fresh_since is not None and now - fresh_since < self.window_s:
            return  # timely again only just now (a backlog drained): its feedback may follow
        if heard and (
            unacked is None or last_fresh is None or last_fresh - unacked < 0.5 * self.window_s or fresh_count < 3
        ):
            # the follower's messages stopped with its acknowledgements (a gap's start: a video
            # frame 0.05 s after the last feedback was still "heard" 1.49 s later; on a cellular
            # uplink's near-zero stretch one frame trickled in 0.86 s after it, 0.85 s old, and
            # in another a frame then a status 1.49 s apart, and the ACL was named); a refusal
            # shows the follower heard on, unacknowledged, for half a window at least, and
            # three times at least (its status at 2 Hz, its video)
            return
        self._warn_unacknowledged(now, heard, last_fb, feedback)

    def _warn_held(self, held: str) -> None:
        """Say once that another operator holds the robot (our commands are refused until a release)."""
        self._held_over = None
        if self._warned != "held":
            self._warned = "held"
            self.held_warnings += 1
            LOG.warning(
                "%s robot %s is held by %s: our commands are refused until %s releases it (cockpit: Release); "
                "we take it then",
                HELD,
                self.robot_id or "(this id)",
                held,
                held,
            )

    def _warn_unacknowledged(self, now: float, heard: bool, last_fb: float | None, feedback: int) -> None:
        """Say once why no feedback acknowledges our commands: refused (the follower is heard, fresh), or lost.

        Parameters
        ----------
        now : float
            Now [s].
        heard : bool
            The follower's messages arrived within the window (fresh: the checks before
            this one left out a stalled uplink).
        last_fb : float or None
            When its last feedback arrived [s].
        feedback : int
            Feedback heard so far.
        """
        if heard:
            self.exposed = True
            if self._warned != "refused":
                self._warned = "refused"
                self.warnings += 1
                fb_fresh = last_fb is not None and now - last_fb < self.window_s
                why = (
                    f"the follower is present but its feedback acknowledges none of our commands ({feedback} heard)"
                    if fb_fresh
                    else "the follower is present and heard but no feedback arrives"
                )
                LOG.warning(
                    "%s (%s for %.1f s; the leader must log in as a user of network.publishers_allowed)",
                    REFUSED,
                    why,
                    self.window_s,
                )
            return
        if self._warned not in ("lost", "stalled"):
            self._warned = "lost"
            self.lost_warnings += 1
            since = self._since if self._since is not None else now
            silent = now - (last_fb if last_fb is not None else since)
            LOG.warning(
                "%s %.1f s (path or router down?): nothing heard from the follower while its presence is "
                "still seen; commands may or may not reach it",
                LOST,
                silent,
            )

    def _stalled(self, now: float, since: float) -> None:
        """Tell (once per episode) that the follower is heard, but late: its uplink is stalled."""
        if self._warned == "stalled":
            return
        self._warned = "stalled"
        self.stall_warnings += 1
        LOG.warning(
            "%s %.1f s: the follower's messages arrive %.1f s late or older (its uplink is stalled or "
            "draining a backlog); commands may still reach the robot",
            STALLED,
            now - since,
            self.fresh_s,
        )
