"""The follower loop: the paper's follower side around any :class:`FollowerRobot`.

Every control period ``dt`` the loop

1. takes the newest admitted command from its :class:`~bipedtele.link.inbox.CommandInbox`,
   which owns every check on a command (too old, an outage's backlog, reordered, a new
   leader session) and feeds the forward-delay estimator h1 (1 s moving average,
   docs/method.md), whether the loop runs in the program or alone;
2. recomputes, when h1 or h2 moved, the equivalent damping sigma_e from (40) and the
   walking parameters (sigma_r, T, eps) from (30) (V.2 and V.3 of the cascade);
3. turns the sonar ranges into the fictitious force f_v (Sec. 3.2.1);
4. runs the reference model (28) with the observer (12) on the measured speeds to get the
   commanded walking speed, clamps it and sends it to the robot with T and eps;
5. runs the equivalent follower (29) with the fictitious-force term of (33): it gets the
   same held tangential force ``k_z f_v`` as the reference model (while the robot is
   asked to walk), so z_e, what the leader feels, falls near an obstacle;
6. publishes feedback, status and (at its own rate) camera frames.

Odometry: at a new touchdown (:meth:`FollowerRobot.footfall`) the loop emits a ``footfall``
event ``{t, robot_t, n, pose, step_s, ref}`` (``t`` on the loop clock [s], ``pose`` [m, m,
rad], ``step_s`` [s], ``ref`` the mean reference since the previous footfall [cm/s, deg/s]).

Safety: with no new command for ``watchdog_s`` (local receive time) the robot stops and
stands (``watchdog_stops``, event ``watchdog_stop``); a command with ``enable`` false, the
operator releasing, stops it as a normal end (``operator_stops``, event ``operator_stop``).
No outage's backlog reaches the robot (the inbox refuses it: ``cmd_backlog``,
``cmd_reordered``; :mod:`bipedtele.link.inbox`), nor a command stamped too far ahead (``future``).
A fall (torso tilt) stops it, is counted (every fall) and **latches**: the robot walks again
only after the operator re-arms (a command with ``enable`` false, then true) once it stands
again. Every delay is clamped at >= 0 before the estimators and control laws see it, so no
timestamp can make a tick raise. :meth:`FollowerLoop.fault` is what the program calls when
a tick or a robot call failed: the robot is stopped if it can be reached and the walk state
is forgotten, so walking resumes smoothly once the robot answers again. What the walk is is
one :class:`~bipedtele.follower.walkstate.WalkState`, moved by the events of its table.

Event-driven pickup: :meth:`FollowerLoop.pickup` (called as soon as a new command arrives)
re-runs this period's control update from the state at the period's start with the fresher
command, sends the result to the robot before its next physics step and publishes the
feedback that acknowledges it. The models still step once per period (the newest command is
the period's sample); (40) and (30) are recomputed under the same ``param_update_s`` rule.

The loop is transport-agnostic: it gets an inbox (fed by a Zenoh receiver in the program,
by a simulated transport in tests) and a callable for publishing. It is built in one call:
what the program changes while it runs (the feedback plan, its Status figures, who holds
the robot) it reads from callables given at construction, once per tick.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.follower_step import FollowerState
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reference import RealFollowerReference, ReferenceState
from bipedtele.control.schemes import make_scheme
from bipedtele.control.schemes.runtime import FollowerPort, received
from bipedtele.follower.backlog import DelayBaseline
from bipedtele.follower.capacity import FeedbackPlan
from bipedtele.follower.config import FollowerConfig
from bipedtele.follower.fictitious import FictitiousForce
from bipedtele.follower.report import FollowerTelemetry, feedback_message, pair
from bipedtele.follower.robot import FollowerRobot, RobotObservation, WalkCommand, WalkRefusedError
from bipedtele.follower.walkstate import WalkEvent, WalkState, next_state
from bipedtele.link.clock import conservative_delays
from bipedtele.link.drops import DropCounter
from bipedtele.link.inbox import COMMAND_COUNTERS, CommandInbox
from bipedtele.link.messages import MAX_SPEED, Command, Feedback, Status, fit_counters, new_session_id

__all__ = ["FollowerLoop", "FollowerTelemetry", "command_inbox"]

LOG = logging.getLogger(__name__)

CM = 100.0  # cm per m
#: Largest delay the loop passes on to (40) and (30) [s] (as the messages allow).
_MAX_DELAY_S = 60.0
#: The loop's counters and its inbox's, in every Status (``FollowerLoop.counters``).
_COUNTERS = (
    "cmd_accepted",
    "cmd_too_old",
    "watchdog_stops",
    "falls",
    "collisions",
    "robot_faults",
    "walk_refused",
    "leader_sessions",
    "resets",
    "operator_stops",
    "cmd_backlog",
    "cmd_reordered",
)


@dataclass
class _PeriodStart:
    """The state at a period's start that a command picked up later in the period restarts from (values)."""

    obs: RobotObservation
    reference: ReferenceState
    controller: FollowerState


class FollowerLoop:
    """The follower controller around a connected robot.

    Parameters
    ----------
    robot : FollowerRobot
        A connected robot.
    control : ControlConfig
        The ``[control]`` section.
    cfg : FollowerConfig
        The ``[follower]`` section.
    inbox : CommandInbox
        Where commands are admitted (:func:`command_inbox`); the loop takes from it and
        checks nothing. Its counters and h1 are the loop's.
    publish : callable
        ``publish(msg)`` for Feedback and Status messages.
    now : callable
        Local clock [s] used for message times, delays and the watchdog (``time.time``;
        a simulated clock in tests).
    on_event : callable, optional
        ``on_event(name, detail_dict)`` for falls, watchdog stops, collisions (recording).
    conservative_rtt : callable, optional
        ntp clock mode: ``() -> rtt [s] | None``; with a value (40) and (30) use ``h1 = h2 = rtt``.
    on_new_leader : callable, optional
        ``on_new_leader(sid) -> bool``, called with a new leader session's first command;
        True: it put the robot back on its start pose (``--reset-on-leader``, simulator
        only), and the loop forgets its walk state and any fall latch.
    drops : DropCounter, optional
        The node's drop counter; its counts go into every Status as ``drop_<reason>``.
    sid : int, optional
        The follower's session id (default: a new random one).
    feedback_plan : callable, optional
        ``() -> FeedbackPlan``, read at every tick and pickup (the program's uplink budget,
        docs/follower.md; default: every command acknowledged, at ``feedback_rate_hz``). A
        callable, not a tick argument: the supervisor runs the tick and the real-time
        stepper the pickup, and neither knows the plan.
    extra_counters : callable, optional
        ``() -> dict``: the program's figures, merged into every Status.
    held_by : callable, optional
        ``() -> str | None``: who holds the robot (follower/custody.py), for the Status.
    """

    def __init__(
        self,
        robot: FollowerRobot,
        control: ControlConfig,
        cfg: FollowerConfig,
        inbox: CommandInbox,
        publish: Callable[[Any], bool | None],
        *,
        now: Callable[[], float] = time.time,
        on_event: Callable[[str, dict[str, Any]], None] | None = None,
        conservative_rtt: Callable[[], float | None] | None = None,
        on_new_leader: Callable[[int], bool] | None = None,
        drops: DropCounter | None = None,
        sid: int | None = None,
        feedback_plan: Callable[[], FeedbackPlan] | None = None,
        extra_counters: Callable[[], dict[str, int]] | None = None,
        held_by: Callable[[], str | None] | None = None,
    ) -> None:
        self.robot = robot
        self.control = control
        self.cfg = cfg
        self.dt = 1.0 / cfg.control_rate_hz
        self.inbox = inbox
        self._publish = publish
        self._now = now
        self._on_event = on_event or (lambda name, detail: None)
        self._conservative_rtt = conservative_rtt
        self._on_new_leader = on_new_leader
        self.sid = new_session_id() if sid is None else int(sid)
        self._drops = drops
        self.chooser = OnlineChooser(control)
        #: The control scheme (``[control] scheme``): the damping sigma_e that (29) and (30) use.
        self.scheme = make_scheme(control)
        self.reference = RealFollowerReference(control.D, control.k_s, control.k_z, control.beta_r, self.dt)
        self.fictitious = _fictitious_force(cfg)
        lim = robot.limits
        self.eta_max = np.array([lim.max_forward_m_s * CM, math.degrees(lim.max_turn_rad_s)])
        #: The scheme's follower step (:class:`~bipedtele.control.follower_step.FollowerController`):
        #: its law, its port, the equivalent follower (29); its state is a value.
        self.port = FollowerPort(self.scheme, np.asarray(control.k_m, dtype=float), control.wave_window_s, self.eta_max)
        #: Advances the step's equivalent follower (29), (33) one period: ``(ref, s_e, f_hold, cfg, dt) -> z_e``.
        self.equivalent = self.port.equivalent
        self.telemetry = FollowerTelemetry()
        self._counts: dict[str, int] = {k: 0 for k in _COUNTERS if k not in COMMAND_COUNTERS}
        default_plan = FeedbackPlan(True, float(cfg.feedback_rate_hz), math.inf)
        self._plan: Callable[[], FeedbackPlan] = feedback_plan or (lambda: default_plan)
        self._last_fb_t = -math.inf
        self._extra_counters = extra_counters
        self._held_by = held_by
        self._cmd: Command | None = None
        self._cmd_recv = -math.inf
        self._period: _PeriodStart | None = None
        self._h_used: tuple[float, float] | None = None
        self._s_e = np.full(2, control.s_e_min)
        self._choice_s_r = np.zeros(2)
        self._T, self._eps = 1.0, control.eps
        clamped = WalkCommand(cycle_s=self._T, eps_s=self._eps).clamped(robot.limits)
        self._T_sent, self._eps_sent = clamped.cycle_s, clamped.eps_s
        #: The walk's state (:mod:`bipedtele.follower.walkstate`): motion, fall latch, refusal.
        self.walk_state = WalkState.STANDING
        self._in_contact = False
        self._fb_seq = self._st_seq = 0
        self._next_fb = self._next_status = -math.inf
        self._footfall_n: int | None = None
        self._ref_sum, self._ref_n = np.zeros(2), 0
        self._update_parameters(0.0, 0.0)

    # ------------------------------------------------------------------ parameters

    def _update_parameters(self, h1: float, h2: float) -> None:
        """V.2 and V.3 of the cascade: sigma_e from the scheme (the paper's: (40)), then (sigma_r, T, eps) (30)."""
        h1, h2 = _delay(h1), _delay(h2)
        if self._h_used is not None:
            moved = max(abs(h1 - self._h_used[0]), abs(h2 - self._h_used[1]))
            if moved <= self.cfg.param_update_s:
                return
        _, s_e = self.scheme.damping(np.array([h1]), np.array([h2]))
        choice = self.chooser.choose(s_e[0])
        self._s_e = np.asarray(s_e[0], dtype=float)
        self._choice_s_r = np.asarray(choice.s_r, dtype=float)
        self._T = float(choice.T)
        self._eps = float(choice.eps)
        self._h_used = (h1, h2)

    # ------------------------------------------------------------------ command intake

    def _take_command(self, now: float) -> bool:
        """Apply the inbox's next command if there is one (it checked it); True when one was taken."""
        got = self.inbox.take_command(now)
        if got is None:
            return False
        self._cmd, self._cmd_recv = got.msg, got.t_recv
        if got.new_session and self._on_new_leader is not None and self._on_new_leader(got.msg.sid):
            self._after_reset(now)
        return True

    @property
    def counters(self) -> dict[str, int]:
        """The loop's counters and its inbox's, in one dict (a copy)."""
        inbox = self.inbox.counters
        return {k: inbox[k] if k in inbox else self._counts[k] for k in _COUNTERS}

    def _after_reset(self, now: float) -> None:
        """Forget the walk state and the latch: the robot was put back on its start pose."""
        self._counts["resets"] += 1
        self.reference.reset()
        self.port.state = self.port.controller.initial(1)
        self._fire(WalkEvent.RESET)
        LOG.info("new leader session: robot back on its start pose")
        self._on_event("reset", {"t": now})

    # ------------------------------------------------------------------ faults

    def fault(self, exc: BaseException) -> None:
        """Stop the robot if it can be reached and forget the walk: a tick or a robot call failed.

        Counted as ``robot_faults``; the state becomes ``error`` and a Status says so.
        Never raises. The next successful tick stops the robot again before anything else
        unless a fresh command makes it walk (the first stop may not have reached it).
        """
        self._counts["robot_faults"] += 1
        self.reference.reset()
        self._fire(WalkEvent.FAULT)
        self.telemetry.state = "error"
        try:
            self.robot.stop()
        except Exception as stop_exc:  # the robot may be unreachable: logged by the caller
            LOG.debug("stop after a fault failed: %s", stop_exc)
        self.publish_status()

    def publish_status(self) -> None:
        """Publish a Status now if one is due (used while ticks cannot run). Never raises."""
        try:
            now = self._now()
            if now >= self._next_status:
                self._next_status = max(now, self._next_status + 1.0 / self.cfg.status_rate_hz)
                self._send_status(now)
        except Exception as exc:
            LOG.debug("publishing a status failed: %s", exc)

    # ------------------------------------------------------------------ tick

    def tick(self) -> FollowerTelemetry:
        """Run one control period (the caller advances the robot by ``dt`` afterwards)."""
        now = self._now()
        self._take_command(now)  # first: a new leader may put the robot back on its start
        obs = self.robot.observe()
        self._watch(obs, now)
        # The period's starting state: a command picked up later in the period re-runs
        # the control update from here (:meth:`pickup`).
        self._period = _PeriodStart(obs, self.reference.state(), self.port.state)
        tel = self._control(now, obs)
        self._odometry(obs, now, tel.ref)
        if now >= self._next_fb:
            self._next_fb = max(now, self._next_fb + 1.0 / self._plan().rate_hz)
            self._send_feedback(now, obs)
            self._last_fb_t = now
        if now >= self._next_status:
            self._next_status = max(now, self._next_status + 1.0 / self.cfg.status_rate_hz)
            self._send_status(now)
        return tel

    def pickup(self) -> bool:
        """Take a command that arrived since the tick and apply it now (see the module docstring).

        The period's control update is run again from the state at the period's start
        with the new command, the result goes to the robot, and a Feedback acknowledging
        the command is published at once. A failure is handled as in :meth:`fault`; never
        raises.

        Returns
        -------
        bool
            True when a new command was accepted.
        """
        try:
            now = self._now()
            if not self._take_command(now):
                return False
            start = self._period
            if start is None:  # no tick yet: the first one takes it
                return True
            self.reference.restore(start.reference)
            self.port.state = start.controller
            old_ref = self.telemetry.ref
            tel = self._control(now, start.obs)
            self._ref_sum = self._ref_sum + (np.asarray(tel.ref, dtype=float) - np.asarray(old_ref, dtype=float))
            plan = self._plan()
            if plan.ack_each_command or now - self._last_fb_t >= plan.min_interval_s:
                # else the next periodic feedback acknowledges it
                self._send_feedback(now, start.obs)
                self._last_fb_t = now
                if not plan.ack_each_command and plan.rate_hz > 0:
                    # it stands for the period's feedback: periodic and acknowledgements together
                    # keep the plan's least interval (on top of the periodic feedback, commands
                    # arriving just before each tick were all acknowledged: the rate doubled)
                    self._next_fb = max(self._next_fb, now + 1.0 / plan.rate_hz)
            return True
        except Exception as exc:
            LOG.warning("applying a new command between ticks failed: %s", exc)
            self.fault(exc)
            return False

    def _watch(self, obs: RobotObservation, now: float) -> None:
        """Collisions and falls: count, report, and latch a fall (stopping the robot)."""
        if obs.in_contact and not self._in_contact:
            self._counts["collisions"] += 1
            self._on_event("collision", {"t": now, "pose": list(obs.pose)})
        self._in_contact = obs.in_contact

        if obs.fallen and not self.walk_state.lying:  # every fall: stop, count, latch
            self._counts["falls"] += 1
            LOG.error(
                "robot fell (tilt %.1f deg, fall %d): stopping; it walks again after it stands "
                "and the operator re-arms (release, then enable)",
                math.degrees(obs.tilt_rad),
                self._counts["falls"],
            )
            self._on_event("fall", {"t": now, "tilt_rad": obs.tilt_rad, "n": self._counts["falls"]})
            self.robot.stop()
            self._fire(WalkEvent.FELL)
        elif not obs.fallen and self.walk_state.lying:
            self._fire(WalkEvent.STOOD)

    def _control(self, now: float, obs: RobotObservation) -> FollowerTelemetry:
        """Run the period's control update: (40)/(30) when due, (28) and (29), the walk or stop."""
        tel = self.telemetry
        h1_est = self.inbox.h1.value(now)
        h1 = _delay(tel.h1_s if h1_est is None else h1_est)
        h2 = _delay(self._cmd.h2_s) if self._cmd is not None else 0.0
        rtt = self._conservative_rtt() if self._conservative_rtt is not None else None
        if rtt is not None:
            self._update_parameters(*conservative_delays(rtt))
        else:
            self._update_parameters(h1, h2)

        fresh = self._cmd is not None and now - self._cmd_recv <= self.cfg.watchdog_s and self._cmd.enable
        eta_meas = np.array([obs.v_hip_m_s * CM, math.degrees(obs.turn_rate_rad_s)])
        f_v = self.fictitious(*obs.sonar_m)
        ref = np.clip(np.asarray(self._cmd.ref), -self.eta_max, self.eta_max) if fresh and self._cmd else np.zeros(2)
        # The tangential force acting on the forward channel, held over the period: the
        # reference model (28) and the equivalent follower (33) get the same one.
        f_hold = np.zeros(2)
        if self.walk_state.latched:
            self._update_latch(obs, fresh)

        if self.walk_state.latched:
            state = "fallen"
            self.reference.reset()
            sent = None
        elif fresh:
            sent, state = self._walk(self._scheme_command(ref, eta_meas), eta_meas, f_v, now)
            if sent is not None:
                f_hold = np.array([f_v[0], 0.0])
        else:
            if self.walk_state.stop_due:
                if self.walk_state is WalkState.WALKING:
                    released = (
                        self._cmd is not None and not self._cmd.enable and now - self._cmd_recv <= self.cfg.watchdog_s
                    )
                    if released:  # a normal end: the operator let go
                        self._counts["operator_stops"] += 1
                        LOG.info("stopping: operator released")
                        self._on_event("operator_stop", {"t": now, "why": "operator released"})
                    else:
                        self._counts["watchdog_stops"] += 1
                        LOG.warning("stopping: no fresh command")
                        self._on_event("watchdog_stop", {"t": now, "why": "no fresh command"})
                self._fire(WalkEvent.NO_FRESH_COMMAND)
                self.robot.stop()
            self.reference.reset(z_r=self.reference.z_r)
            sent = None
            state = "stopping" if obs.walking else "standing"

        z_e = self.equivalent(ref, self._s_e, f_hold, self.control, self.dt)

        tel.t, tel.state, tel.ref, tel.eta_meas = now, state, ref, eta_meas
        tel.eta_cmd, tel.z_r, tel.z_e, tel.f_v = (
            self.reference.eta.copy(),
            self.reference.z_r.copy(),
            np.asarray(z_e),
            f_v,
        )
        tel.h1_s, tel.h2_s, tel.s_e, tel.s_r = h1, h2, self._s_e, self._choice_s_r
        # Report what the robot really got (it clamps T and eps to what it can do).
        if sent is not None:
            self._T_sent, self._eps_sent = sent.cycle_s, sent.eps_s
        tel.T, tel.eps, tel.sent, tel.obs = self._T_sent, self._eps_sent, sent, obs
        return tel

    def _scheme_command(self, ref: np.ndarray, eta_meas: np.ndarray) -> np.ndarray:
        """Return the speed command the scheme gives the reference model (28) [cm/s, deg/s].

        The received ``ref`` for the paper and P+d; the wave transform's or the passivity
        controller's command otherwise (:class:`~bipedtele.control.schemes.runtime.FollowerPort`).
        """
        cmd = self._cmd
        if cmd is None:  # not reached: called with a fresh command only
            return ref
        return self.port.command(
            ref, eta_meas, received(cmd.wave), received(cmd.energy), cmd.t, self._cmd_recv, self.dt
        )

    def _odometry(self, obs: RobotObservation, now: float, ref: np.ndarray) -> None:
        """Emit a ``footfall`` event for a new touchdown; sum the reference applied."""
        ff = self.robot.footfall()
        if ff is not None and ff.n != self._footfall_n:
            self._footfall_n = ff.n
            mean = self._ref_sum / self._ref_n if self._ref_n else np.asarray(ref, dtype=float)
            self._on_event(
                "footfall",
                {
                    "t": now - max(0.0, obs.t - ff.t),
                    "robot_t": ff.t,
                    "n": ff.n,
                    "pose": [float(v) for v in ff.pose],
                    "step_s": ff.step_s,
                    "ref": pair(mean, MAX_SPEED),
                },
            )
            self._ref_sum, self._ref_n = np.zeros(2), 0
        # this tick's reference acts until the next observation
        self._ref_sum = self._ref_sum + np.asarray(ref, dtype=float)
        self._ref_n += 1

    def _walk(
        self, ref: np.ndarray, eta_meas: np.ndarray, f_v: np.ndarray, now: float
    ) -> tuple[WalkCommand | None, str]:
        """Run the reference model (28) and send one walk command; a robot refusing to walk stands."""
        eta_cmd = self.reference.step(ref, eta_meas, self._choice_s_r, np.array([f_v[0], 0.0]), eta_max=self.eta_max)
        try:
            sent = self.robot.send_walk(
                WalkCommand(
                    forward_m_s=eta_cmd[0] / CM,
                    turn_rad_s=math.radians(eta_cmd[1]),
                    cycle_s=self._T,
                    eps_s=self._eps,
                )
            )
        except WalkRefusedError as exc:
            # The robot stopped itself and said why (once); do not wind the model up.
            reported = self.walk_state.refused
            self._fire(WalkEvent.WALK_REFUSED)
            if not reported:
                self._on_event("walk_refused", {"t": now, "why": str(exc)})
            self._counts["walk_refused"] += 1
            self.reference.reset()
            return None, "standing"
        self._fire(WalkEvent.WALK_SENT)
        return sent, "walking"

    def _update_latch(self, obs: RobotObservation, fresh: bool) -> None:
        """Fall latch: released by enable false, then a fresh enable true, while standing."""
        if obs.fallen:
            return  # lying: the re-arm counts only once the robot stands again
        if self._cmd is not None and not self._cmd.enable:
            self._fire(WalkEvent.RELEASE)
        elif fresh and self._fire(WalkEvent.REARM):
            self.reference.reset()
            LOG.info("operator re-armed after the fall: walking again")
            self._on_event("rearmed", {"t": self._now()})

    def _fire(self, event: WalkEvent) -> bool:
        """Move the walk state on ``event`` (:data:`~bipedtele.follower.walkstate.TRANSITIONS`); True when it changed."""
        state = next_state(self.walk_state, event)
        changed = state is not self.walk_state
        self.walk_state = state
        return changed

    # ------------------------------------------------------------------ messages

    def _send_feedback(self, now: float, obs: RobotObservation) -> None:
        if self._publish(self._feedback(now, obs)) is False:
            self._fb_seq -= 1  # held (the uplink's in-flight cap): never sent, so no gap in the sequence

    def _send_status(self, now: float) -> None:
        if self._publish(self.status(now)) is False:
            self._st_seq -= 1

    def _feedback(self, now: float, obs: RobotObservation) -> Feedback:
        self._fb_seq += 1
        wave, energy = self.port.outgoing(self.telemetry.eta_meas)
        cmd_seq = self._cmd.seq if self._cmd is not None else 0
        return feedback_message(self.telemetry, obs, self.sid, self._fb_seq, now, cmd_seq, wave, energy)

    def status(self, now: float) -> Status:
        """Return a Status message with the loop's counters."""
        self._st_seq += 1
        return Status(
            sid=self.sid,
            seq=self._st_seq,
            t=now,
            role="follower",
            state=self.telemetry.state,
            counters=self._counters(),
            text=f"robot={self.robot.name} T={self._T:.2f}s{self._status_note()}",
            held_by=(self._held_by() if self._held_by is not None else None) or "",
        )

    def _counters(self) -> dict[str, int]:
        counters = self.counters
        if self._drops is not None:
            counters.update({f"drop_{k}": v for k, v in self._drops.counts().items()})
        if self._extra_counters is not None:
            counters.update(self._extra_counters())
        return fit_counters(counters)

    def _status_note(self) -> str:
        if self.walk_state.latched:
            return " fall latched: stand the robot up, then release and re-enable"
        if self.walk_state.refused:
            return " robot refuses to walk (see the follower log)"
        if self.telemetry.state == "error":
            return " robot fault (see the follower log)"
        return ""


def command_inbox(cfg: FollowerConfig, **kwargs: Any) -> CommandInbox:
    """Return a command inbox with the ``[follower]`` section's take checks.

    ``max_cmd_age_s``, ``watchdog_s`` and a :class:`~bipedtele.follower.backlog.DelayBaseline`
    over ``backlog_window_s``; ``kwargs`` go to :class:`~bipedtele.link.inbox.CommandInbox`
    (``source`` for a loop run alone; the admission checks).
    """
    baseline = DelayBaseline(window_s=cfg.backlog_window_s, relearn_s=cfg.backlog_window_s)
    return CommandInbox(cfg.max_cmd_age_s, cfg.watchdog_s, baseline, **kwargs)


def _fictitious_force(cfg: FollowerConfig) -> FictitiousForce:
    """Return the sonar's fictitious force f_v (Sec. 3.2.1) as the ``[follower]`` section sets it."""
    return FictitiousForce(
        d_safe=cfg.sonar_d_safe_m,
        d_stop=cfg.sonar_d_stop_m,
        f_max=cfg.sonar_f_max,
        sonar_yaw_rad=math.radians(cfg.sonar_yaw_deg),
    )


def _delay(h: float | None) -> float:
    """Return a delay sample made safe for the control laws: finite, in [0, 60] s."""
    if h is None or not math.isfinite(h):
        return 0.0
    return min(max(float(h), 0.0), _MAX_DELAY_S)
