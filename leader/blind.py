"""A blind operator never drives: the leader's commands stop the robot while its feedback is old.

In the paper's scheme the operator steers from what the robot's feedback shows. The
follower's watchdog stops the robot when *commands* stop arriving, but on a link whose
uplink stalls (a cellular blackout) and whose downlink is free the commands keep coming
while the operator sees nothing new: on a 3G trace the robot walked on through 12.4 s
without fresh feedback, steered by an operator whose screen said "stale".

:class:`BlindGuard` watches the age of the newest usable feedback (now minus its send
time, on the leader's clock). Once it passes ``[leader] blind_stop_s`` the commands ask
the robot to stop (``enable`` false, reference zero; the robot is not released), the
operator is told why (``no fresh feedback for N s: the robot is stopped until it
returns``), and the stop is counted and recorded (event ``blind_stop``). When fresh
feedback returns the robot stays stopped until the operator moves the handle by more
than ``move_share`` (2 %) of the device's workspace from where it rests once the force
has faded back in (``settle_s``, fade plus 0.3 s; ``fresh feedback again: move the
handle to walk on``): what the operator holds was set blind. Then walking resumes
(event ``blind_over``). Before the first feedback nothing is judged (the robot stands at
the start until commands and feedback flow).

The default of ``blind_stop_s`` (1.5 s): twice the largest age of the newest feedback on
the paper's path (h2 up to 0.644 s, feedback at 50 Hz, a burst of three lost: 0.72 s),
rounded up to half a second. On the shipped intercontinental trace with 5 % loss that
age never passed 0.33 s (300 s simulated at 50 Hz).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np

__all__ = ["BlindGuard"]

LOG = logging.getLogger("bipedtele.leader")

#: The operator's line while blind ({age} in seconds).
BLIND_LINE = "no fresh feedback for {age:.1f} s: the robot is stopped until it returns"
#: The operator's line once fresh feedback returned, until the handle moves.
REARM_LINE = "fresh feedback again: move the handle to walk on"


class BlindGuard:
    """Stops the robot while the newest feedback is older than a bound (module docstring).

    Parameters
    ----------
    stop_s : float
        The bound on the newest feedback's age [s] (``[leader] blind_stop_s``).
    workspace_m : float
        The device's workspace (half range per axis) [m].
    on_event : callable, optional
        ``on_event(name, data)`` for ``blind_stop`` and ``blind_over`` (recorded events).
    move_share : float
        A handle move that re-arms walking: this share of the workspace [-].
    settle_s : float
        After fresh feedback returns, the handle's position is taken as the reference of
        that move only after this long [s]: the force fading back in moves the handle
        (3.3 mm of a 5 cm workspace under 1 N with the sim's hand), no move of the operator.

    Attributes
    ----------
    stops : int
        How many times the robot was stopped for old feedback.
    state : str
        ``seeing``, ``blind`` or ``rearm`` (fresh again, waiting for a handle move).
    """

    def __init__(
        self,
        stop_s: float,
        workspace_m: float,
        on_event: Callable[[str, dict[str, float]], None] | None = None,
        move_share: float = 0.02,
        settle_s: float = 0.5,
    ) -> None:
        if not (math.isfinite(stop_s) and stop_s > 0):
            raise ValueError(f"blind_stop_s = {stop_s!r}: allowed: a number of seconds > 0")
        self.stop_s = float(stop_s)
        self.move_m = float(move_share) * float(workspace_m)
        self.settle_s = float(settle_s)
        self._fresh_at = 0.0  # when fresh feedback returned [s]
        self._on_event = on_event
        self.stops = 0
        self.state = "seeing"
        self._since: float | None = None  # when the current stop began [s]
        self._age: float | None = None
        self._x0: np.ndarray | None = None

    def check(self, now: float, have_feedback: bool, age_s: float | None, x_m: np.ndarray) -> bool:
        """Judge one command: True when it must ask the robot to stop.

        Parameters
        ----------
        now : float
            The loop's time [s].
        have_feedback : bool
            Any feedback was taken yet.
        age_s : float or None
            Age of the newest usable feedback [s] (None: none yet).
        x_m : numpy.ndarray
            The handle's position [m].
        """
        self._age = age_s
        if not have_feedback or age_s is None:
            return False
        old = age_s > self.stop_s
        if old and self.state == "seeing":
            self.state, self._since = "blind", now
            self.stops += 1
            LOG.warning("%s (blind stop %d)", BLIND_LINE.format(age=age_s), self.stops)
            self._event("blind_stop", {"age_s": age_s, "stops": float(self.stops)})
        elif old:
            self.state = "blind"
        elif self.state == "blind":
            self.state, self._x0, self._fresh_at = "rearm", np.array(x_m, dtype=float), now
            LOG.info("%s (newest feedback %.2f s old)", REARM_LINE, age_s)
        elif self.state == "rearm":
            if now - self._fresh_at < self.settle_s or self._x0 is None:
                self._x0 = np.array(x_m, dtype=float)  # the force fades back in: not the operator
            elif float(np.max(np.abs(np.asarray(x_m, dtype=float) - self._x0))) > self.move_m:
                self.state = "seeing"
                stopped = now - (self._since if self._since is not None else now)
                LOG.info("the handle moved with fresh feedback: walking resumes after %.1f s stopped", stopped)
                self._event("blind_over", {"stopped_s": stopped})
        return self.state != "seeing"

    def words(self) -> str | None:
        """Return the operator's line now (None: seeing)."""
        if self.state == "blind":
            return BLIND_LINE.format(age=self._age or self.stop_s)
        if self.state == "rearm":
            return REARM_LINE
        return None

    def blind_s(self, now: float) -> float | None:
        """How long the robot has been stopped for old feedback [s] (None: not stopped)."""
        return None if self.state == "seeing" or self._since is None else max(0.0, now - self._since)

    def _event(self, name: str, data: dict[str, float]) -> None:
        if self._on_event is None:
            return
        try:
            self._on_event(name, data)
        except Exception as exc:  # a recorder hiccup must not stop the haptic loop
            LOG.debug("blind guard event %s: %s", name, exc)
