"""``pilot``: the paper's task (Sec. 5, Fig. 10), steered from the delayed feedback.

Walk toward an obstacle and evade it by the left and the right side alternately, N passes,
steering only from the delayed feedback (pose and sonar) with a pure-pursuit law through
waypoints beside each obstacle.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from bipedtele.leader.blind import REARM_LINE
from bipedtele.leader.operator import Hand, Operator, OperatorContext
from bipedtele.leader.predictor import DelayPredictor, LivePredictor, PredictedPose
from bipedtele.link.messages import Feedback
from bipedtele.telemetry import LeaderSample

__all__ = ["DEFAULT_COURSE", "PREDICT_MODES", "Obstacle", "PilotOperator", "course_from_config"]

LOG = logging.getLogger(__name__)

#: What the pilot steers on: the reported pose, the predicted present pose, or the pose
#: predicted h1 ahead (see :class:`PilotOperator`).
PREDICT_MODES: tuple[str, ...] = ("off", "now", "h1")


@dataclass(frozen=True)
class Obstacle:
    """A round obstacle on the pilot's course.

    Attributes
    ----------
    x, y : float
        Centre in the world frame [m] (the frame of ``Feedback.pose``).
    radius : float
        Radius [m] (half the width of a box).
    """

    x: float
    y: float
    radius: float


@dataclass(frozen=True)
class _Pass:
    centre: np.ndarray
    u: np.ndarray  # direction of travel (unit)
    side: int  # +1: the robot passes on its left of the obstacle, -1: right
    waypoints: tuple[np.ndarray, ...]
    radius: float


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class PilotOperator(Operator):
    """The paper's evasion task (Sec. 5, Fig. 10) driven from delayed feedback.

    The course is a row of obstacles passed in order, then back in reverse order
    (a U-turn after the last), N passes in all. Pass k goes by the robot's *left* of its
    obstacle when k is even and by its *right* when k is odd (sides relative to the
    direction of travel, as the operator steers them). Each pass has three waypoints:
    on the course line ``approach_m`` before the obstacle, beside it at
    ``radius + clearance_m`` on the chosen side, and ``approach_m`` after it. A pass
    counts when the robot's (fed back) position crosses the line through the obstacle
    centre, perpendicular to the travel direction, on the chosen side.

    Steering is pure pursuit on the robot's pose: with ``predict = "off"`` the latest
    ``Feedback.pose`` (as it was h2 and more ago); with ``"now"`` the pose a
    :class:`~bipedtele.leader.predictor.DelayPredictor` predicts for the present from that
    feedback plus the commands in flight; with ``"h1"`` the pose it predicts for
    ``h1`` from now, when the command decided now reaches the robot (the classic predictor
    for delayed teleoperation: the loop then steers as without delay, up to the model's
    error). Passes are counted on the reported pose, never on a prediction. The predictor
    needs the loop's samples (:meth:`observe_sample`); until they come, or without a
    feedback, the pilot steers on the reported pose. The current waypoint is
    dropped once closer than the look-ahead distance; the turn speed is
    ``v * 2 sin(a) / L`` (rad/s -> deg/s) toward it, clipped, and the forward speed shrinks
    with the heading error (to 30 % beyond 60 degrees, as a person slows to turn round)
    and when a sonar reads below ``slow_range_m``.

    The pilot reads the cockpit's line as a person would: while it says "fresh feedback
    again: move the handle to walk on" (the robot stopped for old feedback,
    :mod:`bipedtele.leader.blind`), it pushes the handle on, its forward speed growing by
    ``rearm_push_cm_s2`` a second (at most ``speed_cm_s`` more), until walking resumes.
    Before, its handle stayed where the course put it while the robot stood, so the robot
    stood to the end of a 3G run (1 pass of 5).

    Parameters
    ----------
    obstacles : sequence of Obstacle
        The course (at least one).
    k_g : sequence of float
        Handle position -> speed gains (eq. 7, 11).
    passes : int
        Number of passes N.
    clearance_m, approach_m, lookahead_m : float
        Course geometry [m].
    speed_cm_s : float
        Cruise forward speed [cm/s].
    turn_max_deg_s : float
        Largest turn speed asked [deg/s].
    slow_range_m : float
        Sonar range below which the pilot slows [m].
    predict : str
        ``"off"``, ``"now"`` or ``"h1"``: the pose steered on (see above).
    predictor : DelayPredictor, optional
        The model for ``predict != "off"`` (default: ``DelayPredictor()``, lag 0.5 s).
    rearm_push_cm_s2 : float
        How fast the pilot pushes the handle on when the cockpit asks for a move [cm/s per s].
    """

    name = "pilot"

    def __init__(
        self,
        obstacles: Sequence[Obstacle],
        k_g: Sequence[float],
        passes: int = 10,
        clearance_m: float = 0.35,
        approach_m: float = 0.7,
        lookahead_m: float = 0.5,
        speed_cm_s: float = 6.0,
        turn_max_deg_s: float = 9.0,
        slow_range_m: float = 0.45,
        workspace_m: float = 0.05,
        hand: Hand | None = None,
        predict: str = "off",
        predictor: DelayPredictor | None = None,
        rearm_push_cm_s2: float = 2.0,
    ) -> None:
        super().__init__(k_g, workspace_m, hand)
        if not (math.isfinite(rearm_push_cm_s2) and rearm_push_cm_s2 > 0):
            raise ValueError(f"rearm_push_cm_s2 = {rearm_push_cm_s2!r}: allowed: a number > 0")
        self.rearm_push_cm_s2 = float(rearm_push_cm_s2)
        self._asked = False  # the cockpit asks for a handle move (fresh feedback after a blind stop)
        self._asked_t: float | None = None  # device time the pilot first read it [s]
        if predict not in PREDICT_MODES:
            raise ValueError(f"predict = {predict!r}: allowed: {', '.join(PREDICT_MODES)}")
        self.predict = predict
        self.live: LivePredictor | None = None if predict == "off" else LivePredictor(predictor or DelayPredictor())
        self.predicted: tuple[PredictedPose, PredictedPose] | None = None
        self._fb_seen: Feedback | None = None
        self._pred_fb: Feedback | None = None
        self._pred_t = -math.inf
        if not obstacles:
            raise ValueError("obstacles: allowed: at least one obstacle")
        if passes < 1:
            raise ValueError(f"passes = {passes}: allowed: an integer >= 1")
        self.obstacles = list(obstacles)
        self.passes = int(passes)
        self.clearance_m = clearance_m
        self.approach_m = approach_m
        self.lookahead_m = lookahead_m
        self.speed_cm_s = speed_cm_s
        self.turn_max_deg_s = turn_max_deg_s
        self.slow_range_m = slow_range_m
        self.passes_done = 0
        self.retries = 0
        self.sides: list[str] = []
        self._start: np.ndarray | None = None
        self._pass: _Pass | None = None
        self._wp = 0
        self._approached = False
        self._crossed = False
        self._turn_dir = 0.0
        self._t_done: float | None = None
        self.target: np.ndarray | None = None

    # ---------------------------------------------------------------- course

    def _direction(self) -> np.ndarray:
        assert self._start is not None
        first = np.array([self.obstacles[0].x, self.obstacles[0].y])
        last = np.array([self.obstacles[-1].x, self.obstacles[-1].y])
        d = last - first if len(self.obstacles) > 1 else first - self._start
        n = float(np.hypot(*d))
        return d / n if n > 1e-9 else np.array([1.0, 0.0])

    def _make_pass(self, k: int) -> _Pass:
        n = len(self.obstacles)
        lap, i = divmod(k, n)
        d = self._direction()
        order = list(range(n)) if lap % 2 == 0 else list(range(n - 1, -1, -1))
        u = d if lap % 2 == 0 else -d
        ob = self.obstacles[order[i]]
        c = np.array([ob.x, ob.y])
        # Approach and exit points: approach_m beyond the edge, but at most half-way to
        # the neighbouring obstacles of this lap (a slalom through a row).
        a = e = ob.radius + self.approach_m
        if i > 0:
            prev = self.obstacles[order[i - 1]]
            a = min(a, max(ob.radius, 0.5 * float((c - np.array([prev.x, prev.y])) @ u)))
        if i < n - 1:
            nxt = self.obstacles[order[i + 1]]
            e = min(e, max(ob.radius, 0.5 * float((np.array([nxt.x, nxt.y]) - c) @ u)))
        side = 1 if k % 2 == 0 else -1
        left = np.array([-u[1], u[0]])
        beside = c + side * left * (ob.radius + self.clearance_m)
        half = ob.radius + 0.5 * self.clearance_m
        wps = (c - u * a, beside - u * min(half, a), beside + u * min(half, e), c + u * e)
        return _Pass(c, u, side, wps, ob.radius)

    # ---------------------------------------------------------------- steering

    def _carrot(self, p: np.ndarray, ps: _Pass) -> np.ndarray | None:
        """Return the pure-pursuit goal.

        That is ``lookahead_m`` along the pass's path beyond the robot's projection on it
        (None past the path's end).
        """
        wps = ps.waypoints
        while self._wp < len(wps) - 2:
            a, b = wps[self._wp], wps[self._wp + 1]
            ab = b - a
            if float((p - a) @ ab) / float(ab @ ab) >= 1.0:
                self._wp += 1
            else:
                break
        a, b = wps[self._wp], wps[self._wp + 1]
        ab = b - a
        s = float((p - a) @ ab) / float(ab @ ab)
        if self._wp == len(wps) - 2 and s >= 1.0:
            return None
        point = a + min(max(s, 0.0), 1.0) * ab
        remaining = self.lookahead_m
        seg = self._wp
        while True:
            nxt = wps[seg + 1]
            d = float(np.hypot(*(nxt - point)))
            if remaining <= d or seg + 1 == len(wps) - 1:
                if d < 1e-9:
                    return nxt.copy()
                return point + (nxt - point) * min(1.0, remaining / d)
            remaining -= d
            point = nxt
            seg += 1

    def intended_speed(self, t: float, feedback: Feedback | None) -> np.ndarray:
        """Intended [forward cm/s, turn deg/s] at device time ``t`` [s] (see the class docstring)."""
        if feedback is None or self.done:
            if self.done and self._t_done is None:
                self._t_done = t
            self.target = None
            return np.zeros(2)
        self._fb_seen = feedback
        px, py, yaw = feedback.pose
        p_seen = np.array([px, py])
        p, yaw = self._steering_pose(t, feedback)
        if self._start is None:
            self._start = p_seen.copy()
        if self._pass is None:
            self._pass = self._make_pass(self.passes_done)
            self._wp = 0
        ps = self._pass
        rel = p_seen - ps.centre
        along = float(rel @ ps.u)
        lateral = float(rel @ np.array([-ps.u[1], ps.u[0]])) * ps.side
        if not self._approached and float(np.hypot(*(ps.waypoints[0] - p))) < self.lookahead_m:
            self._approached = True  # lined up before the obstacle: the pass begins
        if self._approached and not self._crossed and along > 0.0 and lateral > ps.radius:
            self._crossed = True
            self.sides.append("left" if ps.side > 0 else "right")
            self.passes_done += 1
            LOG.info("pilot: pass %d/%d done (%s)", self.passes_done, self.passes, self.sides[-1])
            if self.done:
                self._t_done = t
                self.target = None
                return np.zeros(2)
        target = self._carrot(p, ps) if self._approached else ps.waypoints[0].copy()
        at_exit = self._approached and float(np.hypot(*(ps.waypoints[-1] - p))) < self.lookahead_m
        if target is None or at_exit:
            if not self._crossed:
                # Reached the end of the pass without crossing on the chosen side: again.
                self.retries += 1
                LOG.warning("pilot: pass %d missed its side; trying again", self.passes_done + 1)
            else:
                self._pass = ps = self._make_pass(self.passes_done)
            self._wp = 0
            self._approached = float(np.hypot(*(ps.waypoints[0] - p))) < self.lookahead_m
            self._crossed = False
            target = self._carrot(p, ps) if self._approached else ps.waypoints[0].copy()
            assert target is not None
        self.target = target
        dx, dy = target - p
        dist = max(float(np.hypot(dx, dy)), 1e-6)
        a = _wrap(math.atan2(dy, dx) - yaw)
        v = self.speed_cm_s
        v_min = 0.25 * self.speed_cm_s
        sonar = min(feedback.sonar) if feedback.sonar else math.inf
        if 0.0 < sonar < self.slow_range_m:
            v *= max(0.4, sonar / self.slow_range_m)
        w_max = math.radians(self.turn_max_deg_s)
        look = max(self.lookahead_m, min(dist, 2.0 * self.lookahead_m))
        kappa = 2.0 * math.sin(a) / look  # pure-pursuit curvature [1/m]
        if abs(a) > math.pi / 2 and self._turn_dir == 0.0:
            # Goal behind: turn round away from the obstacle, as a person turning round to
            # come back would, and keep that direction until roughly facing the goal.
            ox, oy = ps.centre - p
            obstacle_left = math.cos(yaw) * oy - math.sin(yaw) * ox
            self._turn_dir = -1.0 if obstacle_left > 0.0 else 1.0
        elif abs(a) < math.pi / 4:
            self._turn_dir = 0.0
        if self._turn_dir != 0.0:
            kappa = self._turn_dir * 2.0 / self.lookahead_m
        if abs(kappa) * v / 100.0 > w_max:
            v = max(v_min, 100.0 * w_max / abs(kappa))  # slow down to make the turn
        w = math.degrees(float(np.clip(v / 100.0 * kappa, -w_max, w_max)))
        return np.array([v + self._push(t), w])

    def _push(self, t: float) -> float:
        """Forward speed added while the cockpit asks for a handle move [cm/s] (class docstring)."""
        if not self._asked:
            self._asked_t = None
            return 0.0
        if self._asked_t is None:
            self._asked_t = t
        return min(self.speed_cm_s, self.rearm_push_cm_s2 * (t - self._asked_t))

    def _steering_pose(self, t: float, feedback: Feedback) -> tuple[np.ndarray, float]:
        """Return the pose steered on: the reported one, or its prediction (class docstring)."""
        live = self.live
        px, py, yaw = feedback.pose
        if live is None or not live.ready or live.dev_offset is None:
            self.predicted = None
            return np.array([px, py]), float(yaw)
        # A new prediction for a new feedback, else every 20 ms (the commands move it on).
        if self.predicted is None or feedback is not self._pred_fb or t - self._pred_t >= 0.02:
            now = t + live.dev_offset
            h1 = feedback.h1_s if feedback.h1_s > 0.0 else (live.h1_s or 0.0)
            self.predicted = live.predict(now, feedback.pose, feedback.eta, feedback.t, h1)
            self._pred_fb, self._pred_t = feedback, t
        use = self.predicted[0] if self.predict == "now" else self.predicted[1]
        return np.array([use.x, use.y]), use.yaw

    def observe_sample(self, sample: LeaderSample) -> None:
        """Feed the loop sample to the predictor and read the cockpit's line (see the class docstring)."""
        self._asked = sample.blind == REARM_LINE
        if self.live is not None:
            fb = self._fb_seen
            self.live.observe(sample, fb.t if fb is not None else None)

    @property
    def done(self) -> bool:
        """True once the task is finished (see the class docstring)."""
        return self.passes_done >= self.passes

    def progress(self) -> dict[str, Any]:
        """Plain-data progress for telemetry."""
        return {
            **super().progress(),
            "passes_done": self.passes_done,
            "passes": self.passes,
            "sides": list(self.sides),
            "retries": self.retries,
            "t_done": self._t_done,
            "target": None if self.target is None else self.target.tolist(),
        }


#: The course used when neither ``[leader] pilot_obstacles`` nor ``[world] obstacles`` give
#: one: the simulated lab's task course (a box, a cylinder, a box in a row along +x,
#: offset left/right; boxes as their circumscribed circles).
DEFAULT_COURSE: tuple[Obstacle, ...] = (
    Obstacle(1.0, 0.15, 0.5 * math.hypot(0.2, 0.3)),
    Obstacle(2.0, -0.15, 0.12),
    Obstacle(3.0, 0.15, 0.5 * math.hypot(0.2, 0.3)),
)


def _obstacle_from(item: Any) -> Obstacle:
    """Build an obstacle from ``[x, y, radius]`` or a ``[world]`` obstacle.

    A ``[world]`` obstacle is a table or object with ``shape``, ``position`` [x, y, z] and
    ``size``: box edge lengths, or cylinder radius and height; a box counts as its
    circumscribed circle in the ground plane.
    """
    if isinstance(item, list | tuple) and len(item) == 3:
        return Obstacle(float(item[0]), float(item[1]), float(item[2]))

    def get(key: str) -> Any:
        return item.get(key) if isinstance(item, dict) else getattr(item, key, None)

    pos, size, shape = get("position"), get("size"), get("shape") or "box"
    if pos is None or size is None or len(pos) < 2 or len(size) < 1:
        raise ValueError(f"obstacle {item!r}: allowed: [x, y, radius] or a [world] obstacle with position and size")
    if shape == "cylinder":
        r = float(size[0])
    else:
        r = 0.5 * math.hypot(float(size[0]), float(size[1]) if len(size) > 1 else float(size[0]))
    return Obstacle(float(pos[0]), float(pos[1]), r)


def course_from_config(cfg: Any) -> list[Obstacle]:
    """Return the pilot's obstacles from a loaded :class:`bipedtele.config.profile.Config`.

    ``[leader] pilot_obstacles`` when not empty; otherwise ``obstacles`` of the
    ``[world]`` section read as plain data (the leader never imports follower code);
    otherwise :data:`DEFAULT_COURSE` (logged: the robot's world may differ).
    """
    leader = cfg.sections["leader"]
    if leader.pilot_obstacles:
        return [_obstacle_from(o) for o in leader.pilot_obstacles]
    world = cfg.sections.get("world")
    items = getattr(world, "obstacles", None) if world is not None else None
    if items:
        return [_obstacle_from(o) for o in items]
    LOG.warning("pilot: no [world] obstacles nor [leader] pilot_obstacles: using the default course")
    return list(DEFAULT_COURSE)


def build(ctx: OperatorContext) -> Operator:
    lc = ctx.leader
    return PilotOperator(
        course_from_config(ctx.cfg),
        ctx.k_g,
        passes=lc.pilot_passes,
        clearance_m=lc.pilot_clearance_m,
        approach_m=lc.pilot_approach_m,
        lookahead_m=lc.pilot_lookahead_m,
        speed_cm_s=lc.pilot_speed_cm_s,
        turn_max_deg_s=lc.pilot_turn_max_deg_s,
        slow_range_m=lc.pilot_slow_range_m,
        workspace_m=ctx.workspace_m,
        hand=ctx.hand,
        predict=lc.pilot_predict,
        predictor=DelayPredictor(tau_s=lc.pilot_predict_tau_s),
    )
