"""Predictor for delayed teleoperation: where the robot is now, and where it will be.

The leader sees the robot as it was when its feedback left, ``h2`` ago (a little more: the
feedback also waited here). Every command it sent since reaches the robot ``h1`` after it
left. Both are known on the leader, so the classic predictive display for delayed
teleoperation applies: start from the last reported pose and speeds (stamped with the
feedback's send time ``t_fb``) and dead-reckon a unicycle forward, with the speeds the
robot will realise from the commands still in flight.

Model
-----
- The robot applies at time ``tau`` the reference of the command sent at ``tau - h1``
  (the latest one sent before; zero-order hold). For ``tau <= now + h1`` that command is
  already sent, so the pose ``h1`` ahead depends only on commands the leader knows.
- Its speeds ``[v cm/s, w deg/s]`` follow the applied reference through a first-order lag
  of time constant ``tau_s`` (the follower's reference model, (28), and the gait change the
  step once per step; half a walking cycle is a fair default), starting from the reported
  speeds at ``t_fb``.
- The pose integrates ``dx = v cos(yaw)``, ``dy = v sin(yaw)``, ``dyaw = w`` (metres,
  radians) on a grid of ``step_s`` with the heading taken at mid-step.

The whole horizon is computed with numpy in a few tens of microseconds, so the pilot may
call it at every command inside the 1 kHz loop.

Not modelled: the fictitious force near obstacles (it slows the robot), the commands'
enable flag other than as a zero reference, and the delay's variation inside the horizon
(the current estimates ``h1`` are used throughout).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from bipedtele.telemetry import LeaderSample

__all__ = ["CommandLog", "DelayPredictor", "LivePredictor", "PredictedPose"]


@dataclass(frozen=True)
class PredictedPose:
    """A predicted robot state.

    Attributes
    ----------
    t : float
        Time the prediction is for [s, message clock].
    x, y : float
        Position [m] in the frame of ``Feedback.pose``.
    yaw : float
        Heading [rad], wrapped to (-pi, pi].
    v : float
        Forward speed [cm/s].
    w : float
        Turn speed [deg/s].
    """

    t: float
    x: float
    y: float
    yaw: float
    v: float
    w: float

    @property
    def pose(self) -> tuple[float, float, float]:
        """``(x [m], y [m], yaw [rad])``."""
        return (self.x, self.y, self.yaw)


class CommandLog:
    """The commands sent, as ``(send time [s], reference [cm/s, deg/s])``, oldest first.

    Parameters
    ----------
    keep_s : float
        Commands older than this before the newest are forgotten [s] (keep more than the
        largest ``h1 + h2`` expected).
    """

    def __init__(self, keep_s: float = 10.0) -> None:
        if not (keep_s > 0 and math.isfinite(keep_s)):
            raise ValueError(f"keep_s = {keep_s!r}: allowed: a finite number of seconds > 0")
        self.keep_s = float(keep_s)
        self._t: list[float] = []
        self._ref: list[tuple[float, float]] = []

    def __len__(self) -> int:
        return len(self._t)

    def add(self, t: float, ref: Sequence[float]) -> None:
        """Log a command sent at ``t`` [s] with reference ``ref`` [cm/s, deg/s].

        A command stamped before the newest one replaces nothing and is ignored (time
        never runs backwards on one sender).
        """
        if not math.isfinite(t) or (self._t and t < self._t[-1]):
            return
        v, w = float(ref[0]), float(ref[1])
        if not (math.isfinite(v) and math.isfinite(w)):
            v = w = 0.0
        self._t.append(float(t))
        self._ref.append((v, w))
        if self._t[0] < t - 1.5 * self.keep_s:  # forget in batches (amortised O(1) per command)
            i = bisect.bisect_left(self._t, t - self.keep_s)
            del self._t[:i], self._ref[:i]

    def refs_at(self, t_send: np.ndarray) -> np.ndarray:
        """Return the reference in force at each send time, shape ``(n, 2)`` [cm/s, deg/s].

        That is the latest command sent at or before it; zero before the first logged
        command.
        """
        t_send = np.asarray(t_send, dtype=float)
        if not self._t or len(t_send) == 0:
            return np.zeros((len(t_send), 2))
        # Only the commands that matter: the one in force at the first time, and later ones.
        lo = max(0, bisect.bisect_right(self._t, float(t_send.min())) - 1)
        hi = bisect.bisect_right(self._t, float(t_send.max()))
        if lo == 0 and self._t[0] > t_send.min():
            ts, refs = (
                np.asarray(self._t[:hi]),
                np.vstack([np.zeros((1, 2)), np.asarray(self._ref[:hi]).reshape(-1, 2)]),
            )
            return refs[np.searchsorted(ts, t_send, side="right")]  # 0: before the first command
        ts, refs = np.asarray(self._t[lo:hi]), np.asarray(self._ref[lo:hi]).reshape(-1, 2)
        return refs[np.searchsorted(ts, t_send, side="right") - 1]


class DelayPredictor:
    """Dead reckoning from delayed feedback plus the commands in flight (module docstring).

    Parameters
    ----------
    tau_s : float
        Time constant of the robot's speed response to its reference [s] (0: the speeds
        jump to the reference).
    step_s : float
        Integration step [s].
    max_horizon_s : float
        Longest prediction from the feedback's send time [s]; a feedback older than this
        (the link is down) is extrapolated only this far.
    keep_s : float
        How long commands are kept [s] (see :class:`CommandLog`).
    """

    def __init__(
        self, tau_s: float = 0.5, step_s: float = 0.02, max_horizon_s: float = 5.0, keep_s: float = 10.0
    ) -> None:
        if not (tau_s >= 0 and math.isfinite(tau_s)):
            raise ValueError(f"tau_s = {tau_s!r}: allowed: a finite number of seconds >= 0")
        if not (step_s > 0 and math.isfinite(step_s)):
            raise ValueError(f"step_s = {step_s!r}: allowed: a finite number of seconds > 0")
        if not (max_horizon_s > 0 and math.isfinite(max_horizon_s)):
            raise ValueError(f"max_horizon_s = {max_horizon_s!r}: allowed: a finite number of seconds > 0")
        self.tau_s = float(tau_s)
        self.step_s = float(step_s)
        self.max_horizon_s = float(max_horizon_s)
        self.commands = CommandLog(keep_s)

    def add_command(self, t: float, ref: Sequence[float]) -> None:
        """Log a command sent at ``t`` [s, message clock] with ``ref`` [cm/s, deg/s]."""
        self.commands.add(t, ref)

    def trajectory(
        self,
        pose: Sequence[float],
        speed: Sequence[float],
        t_fb: float,
        t_end: float,
        h1_s: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predict the states from ``t_fb`` to ``t_end``.

        Parameters
        ----------
        pose : sequence of float
            Reported ``(x [m], y [m], yaw [rad])`` at ``t_fb``.
        speed : sequence of float
            Reported ``(v [cm/s], w [deg/s])`` at ``t_fb``.
        t_fb : float
            When the feedback left the robot [s, message clock].
        t_end : float
            Last time to predict [s]; clipped to ``t_fb + max_horizon_s``.
        h1_s : float
            Forward delay estimate [s] (commands act ``h1_s`` after they were sent).

        Returns
        -------
        t : ndarray, shape (n + 1,)
            Times [s], ``t[0] = t_fb``.
        state : ndarray, shape (n + 1, 5)
            ``x [m], y [m], yaw [rad] (unwrapped), v [cm/s], w [deg/s]`` at each time.
        """
        h1 = max(0.0, float(h1_s)) if math.isfinite(h1_s) else 0.0
        span = min(max(0.0, t_end - t_fb), self.max_horizon_s)
        n = max(0, math.ceil(span / self.step_s - 1e-9))
        x0, y0, yaw0 = (float(pose[0]), float(pose[1]), float(pose[2]))
        v0, w0 = float(speed[0]), float(speed[1])
        if n == 0:
            return np.array([t_fb]), np.array([[x0, y0, yaw0, v0, w0]])
        dt = span / n
        t = t_fb + dt * np.arange(n + 1)
        # Reference acting over each step: the command sent h1 before the step's start.
        ref = self.commands.refs_at(t[:-1] - h1)
        if self.tau_s > 0.0:
            a = math.exp(-dt / self.tau_s)
            nxt = _first_order(a, np.array([v0, w0]), ref)
        else:
            nxt = ref
        sp = np.vstack([[v0, w0], nxt])  # (n + 1, 2): v [cm/s], w [deg/s]
        mid = 0.5 * (sp[:-1] + sp[1:]) * dt  # per step: metres * 100, degrees
        yaw = yaw0 + np.concatenate([[0.0], np.cumsum(np.radians(mid[:, 1]))])
        yaw_mid = 0.5 * (yaw[:-1] + yaw[1:])
        step = mid[:, 0] / 100.0
        xy = np.vstack([[x0, y0], np.column_stack([step * np.cos(yaw_mid), step * np.sin(yaw_mid)])]).cumsum(axis=0)
        x, y, vs, ws = xy[:, 0], xy[:, 1], sp[:, 0], sp[:, 1]
        return t, np.column_stack([x, y, yaw, vs, ws])

    def predict(
        self,
        pose: Sequence[float],
        speed: Sequence[float],
        t_fb: float,
        t: float,
        h1_s: float,
    ) -> PredictedPose:
        """Predict the state at time ``t`` [s] (see :meth:`trajectory` for the rest).

        ``t = now`` gives the present pose; ``t = now + h1_s`` the pose when a command sent
        now starts to act. A ``t`` before ``t_fb`` gives the reported state.
        """
        ts, st = self.trajectory(pose, speed, t_fb, t, h1_s)
        x, y, yaw, v, w = st[-1]
        return PredictedPose(float(ts[-1]), float(x), float(y), _wrap(float(yaw)), float(v), float(w))

    def predict_now_and_ahead(
        self,
        pose: Sequence[float],
        speed: Sequence[float],
        t_fb: float,
        now: float,
        h1_s: float,
    ) -> tuple[PredictedPose, PredictedPose]:
        """Predict the present state (at ``now``) and the state ``h1_s`` later.

        Both come from one integration (units as in :meth:`trajectory`).
        """
        ts, st = self.trajectory(pose, speed, t_fb, now + max(0.0, h1_s), h1_s)
        k = int(np.searchsorted(ts, now, side="right")) - 1
        k = min(max(k, 0), len(ts) - 1)
        out = []
        for i in (k, len(ts) - 1):
            x, y, yaw, v, w = st[i]
            out.append(PredictedPose(float(ts[i]), float(x), float(y), _wrap(float(yaw)), float(v), float(w)))
        return out[0], out[1]


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class LivePredictor:
    """A :class:`DelayPredictor` fed from the leader loop's telemetry samples.

    After each command the loop makes a sample (``leader/loop.py``: ``t``, ``t_device``,
    ``ref_v``, ``ref_w``, ``enable``, ``h2_ms``, ``feedback_age_ms``); :meth:`observe`
    logs the command and keeps two clock relations:

    - device time -> message clock (``t - t_device``), so an operator model that only
      sees its device's time can ask for the present;
    - the feedback's send time on this host's clock: ``t - feedback_age - h2`` minus the
      feedback's own stamp ``Feedback.t`` (the median of the last ``window`` samples).
      With one clock (``[clock] mode = "synced"``) it is about zero; in ntp mode it is the
      offset between the two hosts' clocks, which the stamps do not include.

    Parameters
    ----------
    predictor : DelayPredictor
        The model (its command log is filled here).
    window : int
        Samples in the median of the feedback clock offset.
    """

    def __init__(self, predictor: DelayPredictor, window: int = 100) -> None:
        self.predictor = predictor
        self.dev_offset: float | None = None
        self._fb_offsets: deque[float] = deque(maxlen=max(1, int(window)))
        self._fb_offset = 0.0
        self.h1_s: float | None = None
        self.last: tuple[PredictedPose, PredictedPose] | None = None

    def observe(self, sample: LeaderSample, feedback_t: float | None) -> None:
        """Take one loop sample (see the class docstring).

        ``feedback_t`` is the stamp ``Feedback.t`` [s] of the feedback the sample was
        made with (None: none yet). Missing or non-finite values are skipped.
        """
        t, t_dev = _num(sample.t), _num(sample.t_device)
        if t is None:
            return
        if t_dev is not None:
            self.dev_offset = t - t_dev
        rv, rw = _num(sample.ref_v), _num(sample.ref_w)
        enabled = sample.enable is not False
        self.predictor.add_command(t, (rv or 0.0, rw or 0.0) if enabled else (0.0, 0.0))
        age, h2 = _num(sample.feedback_age_ms), _num(sample.h2_ms)
        h1 = _num(sample.h1_ms)
        if h1 is not None:
            self.h1_s = h1 / 1000.0
        if feedback_t is not None and age is not None and h2 is not None:
            self._fb_offsets.append(t - (age + h2) / 1000.0 - feedback_t)
            self._fb_offset = float(np.median(self._fb_offsets))

    @property
    def ready(self) -> bool:
        """True once a sample gave the device clock relation and a command."""
        return self.dev_offset is not None and len(self.predictor.commands) > 0

    def feedback_time(self, feedback_t: float) -> float:
        """Convert a feedback stamp to this host's message clock [s]."""
        return feedback_t + self._fb_offset

    def predict(
        self,
        now: float,
        pose: Sequence[float],
        speed: Sequence[float],
        feedback_t: float,
        h1_s: float,
    ) -> tuple[PredictedPose, PredictedPose]:
        """Predict the present state and the state ``h1_s`` later [message clock ``now``, s].

        From a feedback's pose, speeds and stamp (units of
        :meth:`DelayPredictor.trajectory`).
        """
        self.last = self.predictor.predict_now_and_ahead(pose, speed, self.feedback_time(feedback_t), now, h1_s)
        return self.last


def _num(v: object) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _first_order(a: float, s0: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Run ``s[k+1] = a s[k] + (1 - a) ref[k]`` from ``s[0] = s0``; return ``s[1:]``.

    Closed form ``s[k] = a^k (s0 + (1 - a) sum_{j<k} a^-(j+1) ref[j])`` with numpy (no scipy
    import on the leader's start); a plain loop where ``a^-n`` would overflow.
    """
    n = len(ref)
    if n == 0:
        return np.zeros((0, 2))
    if -n * math.log(a) < 600.0:
        k = np.arange(1, n + 1, dtype=float)[:, None]
        inv = a ** (-k)
        return a**k * (s0 + (1.0 - a) * np.cumsum(ref * inv, axis=0))
    out = np.empty((n, 2))
    s = np.asarray(s0, dtype=float).copy()
    for i in range(n):
        s = a * s + (1.0 - a) * ref[i]
        out[i] = s
    return out
