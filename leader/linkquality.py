"""The link as the leader measures it: feedback age, loss, goodput, video rate, link state.

Everything here is measured at the leader from what arrives (no clock but the one given):

- **feedback age**: receive time minus the feedback's send time converted to the local
  clock (in ``[clock] mode = "ntp"`` the node's clock offset, as for h2), and, at any
  moment, the age of the newest *accepted* feedback (now minus its send time) [s];
- **feedback age bound**: a feedback older than :attr:`LinkQuality.max_age_s` when it
  arrives is refused (``fb_too_old``) and never shown as live. The bound is
  ``max(max_age_floor_s, recent minimum delay + max_age_margin_s)``: 2 s, or, on a path
  whose one-way delay stays above 1 s, the smallest age of the feedback accepted in the
  last ``baseline_s`` (10 s) plus 1 s. With no accepted feedback in that time (a leader
  that just started) the bound is 2 s, so a burst of feedback captured 100 s ago (a
  restarted leader fed from a queue) is refused;
- **loss**: sequence gaps of the feedback that arrived over the last ``window_s`` (2 s),
  in parts per million of the messages sent in that time (a new follower session starts
  counting afresh); the gap of an outage (a feedback arriving after ``lost_after_s`` of
  silence, or more than ``lost_after_s`` older than the recent minimum delay: the backlog
  of a stalled path) is no loss: it is counted apart (``outage_gaps``), or the link read
  "lossy" for 2 s after every gap of a cellular uplink;
- **goodput**: payload bytes received over the last ``window_s`` on feedback, video and
  status [bit/s]; unknown (None) until ``window_s`` has passed since the first byte;
- **video**: frames received per second over ``window_s`` (all cameras) and the newest
  frame's size [bytes, px].

The link state (:meth:`LinkQuality.report`) is one of :data:`LINK_STATES`:

``no-follower``
    The follower's presence is not seen.
``waiting``
    Present, but no feedback has arrived yet.
``lost``
    No feedback at all (not even a too-old one) for ``lost_after_s`` (1 s);
    :attr:`LinkReport.lost_s` says for how long.
``stale``
    Feedback arrives but none usable for ``feedback_timeout_s``: the newest accepted one
    was received longer ago than that (the leader loop fades the force out then), or what
    arrives is refused as too old.
``capacity-limited``
    The follower says so (Status counter ``capacity_limited`` = 1), or the goodput
    received is below ``capacity_ratio`` (0.85) of what the follower says it sends
    (Status counter ``tx_bps``).
``lossy``
    Feedback loss above ``lossy_ppm`` (2 %).
``ok``
    None of the above.

The checks run in that order: the first that holds names the state. A follower counter
that is missing is unknown and never used.

Thread safety: the ``on_*`` methods run on Zenoh's callback threads, :meth:`report` and
:meth:`feedback_age` on others; a lock guards the state (every call is O(1) amortised).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from bipedtele.telemetry import LINK_STATES, link_words

__all__ = ["LINK_STATES", "LinkQuality", "LinkReport", "link_words"]


#: Largest sequence gap counted as lost messages (a larger jump is a restart, not loss).
_MAX_GAP = 10_000

#: ``rx_bps`` is reported this long after the first byte [s] (over the part of the window
#: that has passed): the follower's uplink budget needs it early, while its first queue builds.
_RX_WARM_S = 0.5


@dataclass(frozen=True)
class LinkReport:
    """The link at one moment (see the module docstring).

    Attributes
    ----------
    state : str
        One of :data:`LINK_STATES`.
    lost_s : float or None
        State ``lost``: time since the last feedback arrived [s]; else None.
    fb_age_s : float or None
        Age of the newest accepted feedback: now minus its send time on the local clock [s].
    loss_ppm : int or None
        Feedback lost over the window [parts per million]; None with nothing in the window.
    rx_bps : float or None
        Payload received over the window [bit/s] (over the time since the first byte while
        that is shorter); None until 0.5 s after the first byte.
    video_fps : float or None
        Video frames received per second over the window (all cameras); None before the first.
    video_bytes, video_width, video_height : int or None
        The newest frame's JPEG size [bytes] and image size [px].
    fb_arrived : int
        Feedback that arrived (accepted by the receiver, too old or not).
    fb_too_old : int
        Feedback refused as older than the bound.
    max_age_s : float
        The feedback age bound in force [s].
    status_echo_us : int or None
        The send stamp of the newest follower Status received (its counter ``uplink_t_us``,
        on the follower's clock) [us], echoed back in the leader's Status: it tells the
        follower that everything it sent before that Status arrived (TCP's timestamp echo);
        None: no follower Status with a stamp.
    """

    state: str
    lost_s: float | None
    fb_age_s: float | None
    loss_ppm: int | None
    rx_bps: float | None
    video_fps: float | None
    video_bytes: int | None
    video_width: int | None
    video_height: int | None
    fb_arrived: int
    fb_too_old: int
    max_age_s: float
    status_echo_us: int | None = None


class LinkQuality:
    """Measures the link from what the leader receives (module docstring).

    Parameters
    ----------
    feedback_timeout_s : float
        No accepted feedback received for this long -> ``stale`` [s] (``[leader]
        feedback_timeout_s``, as the loop's force fade).
    lost_after_s : float
        No feedback arrived at all for this long -> ``lost`` [s].
    window_s : float
        Window of the loss, goodput and video rate [s].
    max_age_floor_s : float
        Feedback older than this when it arrives is refused, unless the path's recent
        minimum delay plus ``max_age_margin_s`` is larger [s].
    max_age_margin_s : float
        Margin above the recent minimum delay [s].
    baseline_s : float
        How far back the recent minimum delay looks [s].
    lossy_ppm : int
        Loss above this -> ``lossy`` [ppm] (2 %).
    capacity_ratio : float
        Goodput below this fraction of the follower's ``tx_bps`` -> ``capacity-limited``.
    clock : callable
        Local time [s], the clock of the receive times (``time.time``).
    """

    def __init__(
        self,
        *,
        feedback_timeout_s: float = 0.5,
        lost_after_s: float = 1.0,
        window_s: float = 2.0,
        max_age_floor_s: float = 2.0,
        max_age_margin_s: float = 1.0,
        baseline_s: float = 10.0,
        lossy_ppm: int = 20_000,
        capacity_ratio: float = 0.85,
        clock: Callable[[], float] = time.time,
    ) -> None:
        for name, value in (
            ("feedback_timeout_s", feedback_timeout_s),
            ("lost_after_s", lost_after_s),
            ("window_s", window_s),
            ("max_age_floor_s", max_age_floor_s),
            ("baseline_s", baseline_s),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: allowed: a number > 0")
        self.feedback_timeout_s = float(feedback_timeout_s)
        self.lost_after_s = float(lost_after_s)
        self.window_s = float(window_s)
        self.max_age_floor_s = float(max_age_floor_s)
        self.max_age_margin_s = float(max_age_margin_s)
        self.baseline_s = float(baseline_s)
        self.lossy_ppm = int(lossy_ppm)
        self.capacity_ratio = float(capacity_ratio)
        self._clock = clock
        self._lock = threading.Lock()
        # feedback
        self.fb_arrived = 0
        self.fb_too_old = 0
        #: Sequence gaps after an outage (not counted as loss).
        self.outage_gaps = 0
        self._fb_sid: int | None = None
        self._fb_seq = 0
        self._last_arrival: float | None = None  # receive time of the newest feedback that arrived
        self._last_accepted: float | None = None  # receive time of the newest accepted one
        self._newest_sent: float | None = None  # its send time, local clock
        self._seq_events: deque[tuple[float, int]] = deque()  # (t_recv, lost before it)
        self._lost_sum = 0
        self._mins: deque[tuple[float, float]] = deque()  # ascending ages of accepted feedback
        # bytes and video
        self._bytes: deque[tuple[float, int]] = deque()
        self._bytes_sum = 0
        self._first_byte: float | None = None
        self._frames: deque[float] = deque()
        self._frame: tuple[int, int, int] | None = None  # bytes, width, height

    # ------------------------------------------------------------------ what arrives

    def max_age_s(self, now: float | None = None) -> float:
        """Return the feedback age bound in force [s] (module docstring)."""
        now = self._clock() if now is None else now
        with self._lock:
            return self._bound(now)

    def _bound(self, now: float) -> float:
        mins = self._mins
        while mins and mins[0][0] < now - self.baseline_s:
            mins.popleft()
        base = mins[0][1] if mins else None
        return self.max_age_floor_s if base is None else max(self.max_age_floor_s, base + self.max_age_margin_s)

    def on_feedback(self, sid: int, seq: int, t_sent: float, t_recv: float, nbytes: int) -> bool:
        """Take one feedback that the receiver accepted; return whether it is young enough to use.

        Parameters
        ----------
        sid, seq : int
            The feedback's session and sequence number (gaps count as loss).
        t_sent : float
            Its send time on the local clock [s] (converted in ntp mode).
        t_recv : float
            Its receive time [s].
        nbytes : int
            Its payload size [bytes].

        Returns
        -------
        bool
            False when it is older than :meth:`max_age_s` (counted in ``fb_too_old``).
        """
        age = max(t_recv - t_sent, 0.0) if math.isfinite(t_sent) else math.inf
        with self._lock:
            self.fb_arrived += 1
            self._add_bytes(t_recv, nbytes)
            lost = 0
            base = self._mins[0][1] if self._mins else 0.0
            # after a silence, or part of the backlog a stalled path delivers late
            outage = (self._last_arrival is not None and t_recv - self._last_arrival > self.lost_after_s) or (
                age > base + self.lost_after_s
            )
            self._last_arrival = t_recv
            if sid != self._fb_sid:  # a new follower session: its numbers start afresh
                self._fb_sid, self._fb_seq = sid, seq
            else:
                if seq > self._fb_seq + 1 and outage:
                    self.outage_gaps += 1  # what the follower sent into a dead path: not the path's loss
                elif seq > self._fb_seq + 1:
                    lost = min(seq - self._fb_seq - 1, _MAX_GAP)
                self._fb_seq = max(seq, self._fb_seq)
            self._seq_events.append((t_recv, lost))
            self._lost_sum += lost
            if age > self._bound(t_recv):
                self.fb_too_old += 1
                return False
            mins = self._mins
            while mins and mins[-1][1] >= age:
                mins.pop()
            mins.append((t_recv, age))
            self._last_accepted = t_recv
            self._newest_sent = t_sent  # the receiver's gate lets only newer ones through
            return True

    def on_video(self, t_recv: float, nbytes: int, width: int, height: int, *, counted: bool = False) -> None:
        """Take one video frame received [s, bytes, px].

        ``counted``: its bytes were taken already, part by part (:meth:`on_video_part`).
        """
        with self._lock:
            if not counted:
                self._add_bytes(t_recv, nbytes)
            self._frames.append(t_recv)
            self._frame = (int(nbytes), int(width), int(height))

    def on_video_part(self, t_recv: float, nbytes: int) -> None:
        """Take the bytes of one message of a frame sent in parts [s, bytes] (goodput only)."""
        with self._lock:
            self._add_bytes(t_recv, nbytes)

    def on_status(self, t_recv: float, nbytes: int) -> None:
        """Take one status message of the follower received [s, bytes]."""
        with self._lock:
            self._add_bytes(t_recv, nbytes)

    def _add_bytes(self, t: float, nbytes: int) -> None:
        n = max(int(nbytes), 0)
        if self._first_byte is None:
            self._first_byte = t
        self._bytes.append((t, n))
        self._bytes_sum += n

    def _prune(self, now: float) -> None:
        start = now - self.window_s
        b, ev, fr = self._bytes, self._seq_events, self._frames
        while b and b[0][0] < start:
            self._bytes_sum -= b.popleft()[1]
        while ev and ev[0][0] < start:
            self._lost_sum -= ev.popleft()[1]
        while fr and fr[0] < start:
            fr.popleft()

    # ------------------------------------------------------------------ what it says

    def feedback_age(self, now: float | None = None) -> float | None:
        """Age of the newest accepted feedback: now minus its send time [s] (>= 0); None before one."""
        now = self._clock() if now is None else now
        sent = self._newest_sent
        return None if sent is None else max(now - sent, 0.0)

    def report(
        self,
        now: float | None = None,
        *,
        follower_present: bool = True,
        follower_counters: Mapping[str, int] | None = None,
    ) -> LinkReport:
        """Return the link's figures and state at ``now`` (module docstring).

        Parameters
        ----------
        now : float, optional
            Local time [s] (read from the clock when omitted).
        follower_present : bool
            Whether the follower's presence is seen.
        follower_counters : Mapping, optional
            The follower's latest Status counters (``tx_bps``, ``capacity_limited``; a
            missing one is unknown).
        """
        now = self._clock() if now is None else now
        with self._lock:
            self._prune(now)
            n_ev = len(self._seq_events)
            sent = n_ev + self._lost_sum
            loss_ppm = None if sent == 0 else round(1e6 * self._lost_sum / sent)
            rx_bps = None
            if self._first_byte is not None and now - self._first_byte >= _RX_WARM_S:
                # over the window, or over what has passed of it since the first byte
                rx_bps = 8.0 * self._bytes_sum / min(self.window_s, now - self._first_byte)
            video_fps = None if self._frame is None else len(self._frames) / self.window_s
            frame = self._frame
            last_arrival, last_accepted = self._last_arrival, self._last_accepted
            arrived, too_old, bound = self.fb_arrived, self.fb_too_old, self._bound(now)
        age = self.feedback_age(now)
        lost_s = None
        if not follower_present:
            state = "no-follower"
        elif last_arrival is None:
            state = "waiting"
        elif now - last_arrival > self.lost_after_s:
            state, lost_s = "lost", now - last_arrival
        elif last_accepted is None or now - last_accepted > self.feedback_timeout_s:
            state = "stale"
        elif _capacity_limited(rx_bps, follower_counters, self.capacity_ratio):
            state = "capacity-limited"
        elif loss_ppm is not None and loss_ppm > self.lossy_ppm:
            state = "lossy"
        else:
            state = "ok"
        return LinkReport(
            state=state,
            lost_s=lost_s,
            fb_age_s=age,
            loss_ppm=loss_ppm,
            rx_bps=rx_bps,
            video_fps=video_fps,
            video_bytes=frame[0] if frame else None,
            video_width=frame[1] if frame else None,
            video_height=frame[2] if frame else None,
            fb_arrived=arrived,
            fb_too_old=too_old,
            max_age_s=bound,
            status_echo_us=_stamp(follower_counters),
        )


def _stamp(counters: Mapping[str, int] | None) -> int | None:
    """Return the follower Status's send stamp ``uplink_t_us`` [us] (None: missing or not an int)."""
    v = None if counters is None else counters.get("uplink_t_us")
    return v if isinstance(v, int) and not isinstance(v, bool) and v >= 0 else None


def _capacity_limited(rx_bps: float | None, counters: Mapping[str, int] | None, ratio: float) -> bool:
    if not counters:
        return False
    if "capacity_limited" in counters:
        # the follower's verdict: it aligns the windows by h2 and asks for a queue; the
        # leader's rx against the follower's tx (windows apart by h2 and a status period)
        # said "capacity-limited" on uncapped paths after each step of the video rate
        return counters.get("capacity_limited") == 1
    tx = counters.get("tx_bps")
    return rx_bps is not None and isinstance(tx, int) and tx > 0 and rx_bps < ratio * tx
