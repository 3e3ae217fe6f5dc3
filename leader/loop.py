"""The leader loop: the paper's leader side around any :class:`LeaderDevice`.

Every haptic tick (1 kHz by default) the loop

1. reads the handle (x_m, dx_m);
2. takes the newest admitted feedback from its :class:`~bipedtele.link.inbox.FeedbackInbox`,
   which owns every check on it and feeds the backward-delay estimator h2 (1 s moving
   average of ``t_recv - feedback.t``) with every feedback admitted, whether the loop runs
   in the program or alone; h1 is the follower's own estimate (``feedback.h1_s``); in ntp
   mode with the conservative split, ``h1 = h2 = rtt``;
3. takes the damping alpha_m from the control scheme (``[control] scheme``,
   :mod:`bipedtele.control.schemes`) at the current (h1, h2): the paper's schedules (40)
   (:func:`bipedtele.control.damping.schedule_damping`);
4. computes the force (31) with the latest ``z_e``, which is ``z_e(t - h2)`` by
   construction (it travelled h2 to get here), or with the robot's measured speed for a
   P+d scheme (:func:`bipedtele.control.leader_law.leader_force`);
5. scales it by the *link gain*: 1 while feedback is fresh; once no new feedback arrived
   for ``feedback_timeout_s`` it falls linearly to 0 over ``fade_s`` (and rises the same
   way when feedback returns), so a lost link never leaves the operator pushed by a
   frozen error; the device's clamp (8 N) bounds it, and a *slew limit* bounds how fast
   the force on the handle may change (``force_rate_max_n_s`` per axis, 80 N/s: the full
   8 N takes at least 0.1 s), so no received value (a corrupted or forged ``z_e``, a jump
   of the delay estimate and thus of alpha_m) can give the hand a step;
6. lets the device time pass (a simulated device integrates eq. 1 with the operator's
   hand attached);
7. at ``cmd_rate_hz`` updates the operator model and sends a :class:`Command`
   (``ref = k_g x_m``; a stop while the operator is *blind*, see
   :mod:`bipedtele.leader.blind`), and makes the telemetry sample
   (:class:`bipedtele.telemetry.LeaderSample`) read by the operator model, the cockpit and
   the recorder.

The loop is transport-agnostic: it gets a ``send_command(Command)`` callable and a
feedback inbox (fed by a Zenoh receiver or by a simulated transport), so tests drive it in
simulated time (:meth:`LeaderLoop.run_for`) and the program over Zenoh in real time
(:meth:`LeaderLoop.run`, paced by :class:`bipedtele.pacer.Pacer`).

Message ``t`` fields and staleness use ``clock`` (``time.time`` by default: delays are
computed across processes); pacing uses a monotonic clock.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.leader_law import leader_force
from bipedtele.control.schemes import make_scheme
from bipedtele.control.schemes.runtime import LeaderPort, received
from bipedtele.leader.blind import BlindGuard
from bipedtele.leader.config import LeaderConfig
from bipedtele.leader.device import LeaderDevice
from bipedtele.leader.operator import Operator
from bipedtele.link.delayestimate import conservative_delays
from bipedtele.link.inbox import FeedbackInbox
from bipedtele.link.messages import MAX_TIME, MIN_TIME, Command, Feedback, new_session_id
from bipedtele.pacer import Pacer, PeriodStats, realtime_scheduling, set_timer_slack
from bipedtele.telemetry import LeaderSample

__all__ = ["LeaderLoop"]

LOG = logging.getLogger(__name__)

#: The link state shown for each loop state (others as they are); the program replaces it
#: with the measured one (bipedtele.leader.linkquality).
_LINK = {"starting": "waiting", "running": "ok", "feedback_stale": "stale"}

#: Recompute (40) when h1 or h2 moved by more than this [s].
_DAMPING_STEP_S = 0.0005


class LeaderLoop:
    """The leader controller around a connected device.

    Parameters
    ----------
    device : LeaderDevice
        A connected device.
    operator : Operator or None
        The simulated operator; it is attached to the device (``set_operator``). None for
        a physical device held by a person.
    control : ControlConfig
        ``k_m``, ``k_g`` and the damping scheduler's parameters.
    send_command : callable
        ``send_command(Command)``: publish one command (never blocks).
    inbox : FeedbackInbox
        Where feedback is admitted; the loop takes the newest not taken before (receive
        time on ``clock``) and reads h2 from it.
    cfg : LeaderConfig, optional
        Rates, feedback timeout, fade and g_m (defaults if omitted).
    clock : callable
        Time for message stamps and staleness [s] (``time.time``).
    conservative_rtt : callable, optional
        ntp mode: ``() -> rtt [s] | None``; when it gives a value, (40) uses
        ``h1 = h2 = rtt`` (the split of the round trip is unknown).
    sid : int, optional
        Session id of the commands (random by default).
    on_sample : callable, optional
        Called with the telemetry sample (:class:`~bipedtele.telemetry.LeaderSample`) at
        every command, after the operator model saw it; the program completes it and
        hands it to the cockpit and the recorder.
    operator_name : str
        Who drives (``[network] user``), sent in every command: the robot's hand-over
        rule keys on it (docs/fleet.md, Hand-over).
    feedback_age : callable, optional
        ``feedback_age(now) -> s | None``: age of the newest usable feedback (now minus its
        send time on the local clock); default ``now - feedback.t`` (one clock).
    on_blind : callable, optional
        ``on_blind(event, data)``: the blind guard's ``blind_stop`` / ``blind_over`` events.
    hand : callable, optional
        ``hand() -> bool``, read at every command: True while the operator gives the robot
        up (cockpit button Release), False after Take (docs/fleet.md, Hand-over). Default:
        never released.

    Attributes
    ----------
    released : bool
        What ``hand`` said at the last command. True: commands are stops with ``release``
        set, and another operator may take the robot; False: the loop drives, and takes
        the robot once it is free.
    """

    def __init__(
        self,
        device: LeaderDevice,
        operator: Operator | None,
        control: ControlConfig,
        send_command: Callable[[Command], None],
        inbox: FeedbackInbox,
        *,
        cfg: LeaderConfig | None = None,
        clock: Callable[[], float] = time.time,
        conservative_rtt: Callable[[], float | None] | None = None,
        sid: int | None = None,
        on_sample: Callable[[LeaderSample], None] | None = None,
        operator_name: str = "",
        feedback_age: Callable[[float], float | None] | None = None,
        on_blind: Callable[[str, dict[str, float]], None] | None = None,
        hand: Callable[[], bool] | None = None,
    ) -> None:
        self.device = device
        self.operator_name = operator_name
        self.released = False
        self._hand = hand
        self.operator = operator
        self.control = control
        self.cfg = cfg or LeaderConfig()
        self._send = send_command
        self.inbox = inbox
        self._clock = clock
        self._conservative_rtt = conservative_rtt
        self.sid = sid if sid is not None else new_session_id()
        self._on_sample = on_sample
        self.dt = 1.0 / self.cfg.haptic_rate_hz
        self._cmd_every = max(1, round(self.cfg.haptic_rate_hz / self.cfg.cmd_rate_hz))
        self._k_m = np.asarray(control.k_m, dtype=float)
        self._k_g = np.asarray(control.k_g, dtype=float)
        self._g_m = np.asarray(self.cfg.g_m, dtype=float)
        if operator is not None:
            device.set_operator(operator)
        # State.
        self.ticks = 0
        self.seq = 0
        self.now = math.nan
        self._fb: Feedback | None = None
        self._fb_recv = -math.inf
        self.gain = 0.0
        self._gain_t: float | None = None
        self.h1: float | None = None
        self.h2: float | None = None
        self._damp_at: tuple[float, float] | None = None
        #: The control scheme (``[control] scheme``): the damping and what the force follows.
        self.scheme = make_scheme(control)
        self.port = LeaderPort(self.scheme, np.asarray(control.k_m, dtype=float), control.wave_window_s)
        self.alpha_m = self._scheme_damping(0.0, 0.0)
        self.force = np.zeros(2)
        self.force_cmd = np.zeros(2)
        self._force_t: float | None = None
        self.slew_limited_ticks = 0
        self.x_m = np.zeros(2)
        self.dx_m = np.zeros(2)
        self.enable = True
        self.state = "starting"
        self.last_command: Command | None = None
        self.sample: LeaderSample | None = None
        self.period_stats = PeriodStats()
        self.missed_ticks = 0
        self._stop = threading.Event()
        self._fb_age = feedback_age
        #: Stops the robot while the newest feedback is older than ``blind_stop_s``.
        self.blind = BlindGuard(
            self.cfg.blind_stop_s, device.limits.workspace_m, on_event=on_blind, settle_s=self.cfg.fade_s + 0.3
        )

    def feedback_age(self, now: float) -> float | None:
        """Age of the newest usable feedback at ``now`` [s] (None before the first)."""
        if self._fb_age is not None:
            return self._fb_age(now)
        return None if self._fb is None else max(0.0, now - self._fb.t)

    # ------------------------------------------------------------------ one tick

    @property
    def feedback(self) -> Feedback | None:
        """The latest feedback taken (None before the first)."""
        return self._fb

    @property
    def feedback_count(self) -> int:
        """Feedback taken by the loop so far."""
        return self.inbox.taken

    def _take_feedback(self) -> None:
        got = self.inbox.take_feedback()
        if got is not None:
            self._fb, self._fb_recv = got.msg, got.t_recv

    def _fb_echo(self) -> list[float] | None:
        """Return the newest feedback's send stamp and receive time [s], for the follower's queue signal (None: none yet)."""
        if self._fb is None:
            return None
        echo = [float(self._fb.t), float(self._fb_recv)]
        return echo if all(MIN_TIME <= v <= MAX_TIME for v in echo) else None

    def _delays(self, now: float) -> tuple[float, float]:
        self.h2 = self.inbox.h2.value(now)
        self.h1 = self._fb.h1_s if self._fb is not None else None
        if self._conservative_rtt is not None:
            rtt = self._conservative_rtt()
            if rtt is not None:
                return conservative_delays(rtt)
        return (self.h1 or 0.0), (self.h2 or 0.0)

    def _update_damping(self, now: float) -> None:
        h1, h2 = self._delays(now)
        last = self._damp_at
        if last is None or abs(h1 - last[0]) > _DAMPING_STEP_S or abs(h2 - last[1]) > _DAMPING_STEP_S:
            self._damp_at = (h1, h2)
            self.alpha_m = self._scheme_damping(h1, h2)

    def _scheme_damping(self, h1: float, h2: float) -> np.ndarray:
        """Return the scheme's leader damping at delays ``h1``, ``h2`` [s] (the paper's: (40)) [N s/m]."""
        alpha_m, _ = self.scheme.damping(np.array([h1]), np.array([h2]))
        return np.asarray(alpha_m[0], dtype=float)

    def _felt_speed(self) -> np.ndarray:
        """Return what the force (31) follows [cm/s, deg/s].

        ``z_e`` (the paper), the robot's measured speed (P+d), the speed the wave transform
        gives, each through the scheme's passivity controller if it has one
        (:class:`~bipedtele.control.schemes.runtime.LeaderPort`).
        """
        r_m = np.asarray(self._k_g * self.x_m, dtype=float)
        fb = self._fb
        if fb is None:
            return r_m
        return self.port.felt_speed(
            r_m,
            np.asarray(fb.z_e),
            np.asarray(fb.eta),
            received(fb.wave),
            received(fb.energy),
            fb.t,
            self._fb_recv,
            self.dt,
        )

    def _update_gain(self, now: float) -> None:
        fresh = self._fb is not None and now - self._fb_recv <= self.cfg.feedback_timeout_s
        target = 1.0 if fresh else 0.0
        # The fade runs on clock time (not tick counts), so skipped ticks do not stretch it.
        step = self.dt if self._gain_t is None else min(max(now - self._gain_t, 0.0), 1.0)
        self._gain_t = now
        if self.cfg.fade_s <= 0.0:
            self.gain = target
        elif self.gain < target:
            self.gain = min(target, self.gain + step / self.cfg.fade_s)
        elif self.gain > target:
            self.gain = max(target, self.gain - step / self.cfg.fade_s)
        if self._fb is None:
            self.state = "starting"
        else:
            self.state = "running" if fresh else "feedback_stale"

    def _slew(self, now: float, target: np.ndarray) -> np.ndarray:
        """Return ``target`` [N] slew-limited from the force applied last.

        Moved by at most ``force_rate_max_n_s`` times the clock time since the previous
        tick (one nominal period at the first tick, at most 50 ms after a stall), per axis.
        """
        step = self.dt if self._force_t is None else min(max(now - self._force_t, 0.0), 0.05)
        self._force_t = now
        limit = self.cfg.force_rate_max_n_s * step
        out = np.clip(target, self.force - limit, self.force + limit)
        if not np.array_equal(out, target):
            self.slew_limited_ticks += 1
        return out

    def tick(self, now: float | None = None, dt: float | None = None) -> None:
        """One haptic period: read, force, (command), advance the device by ``dt`` [s].

        Parameters
        ----------
        now : float, optional
            Current time on ``clock`` [s] (read from ``clock`` when omitted).
        dt : float, optional
            Device time to advance [s] (one nominal period when omitted).
        """
        now = self._clock() if now is None else now
        self.now = now
        hs = self.device.read()
        self.x_m, self.dx_m = hs.x_m, hs.dx_m
        self._take_feedback()
        self._update_damping(now)
        self._update_gain(now)
        f = leader_force(
            self.x_m, self.dx_m, self._felt_speed(), k_m=self._k_m, k_g=self._k_g, alpha_m=self.alpha_m, g_m=self._g_m
        )
        self.force_cmd = self.gain * f
        self.force = self.device.apply_force(self._slew(now, self.device.clamp_force(self.force_cmd)))
        if self.ticks % self._cmd_every == 0:
            self._command(now, hs.t, hs.buttons)
        self.device.advance(self.dt if dt is None else dt)
        self.ticks += 1

    def _command(self, now: float, t_dev: float, buttons: tuple[bool, ...]) -> None:
        op = self.operator
        if op is not None:
            op.update(t_dev, self._fb)
        let_go = bool(buttons) and not buttons[0]
        self.released = hand_off = bool(self._hand()) if self._hand is not None else False
        blind = self.blind.check(now, self._fb is not None, self.feedback_age(now), self.x_m)
        self.enable = not let_go and not hand_off and not (op is not None and op.done) and not blind
        ref = self._k_g * self.x_m if self.enable else np.zeros(2)
        wave, energy = self.port.outgoing(ref)
        self.seq += 1
        cmd = Command(
            sid=self.sid,
            seq=self.seq,
            t=now,
            ref=[float(ref[0]), float(ref[1])],
            x_m=[float(self.x_m[0]), float(self.x_m[1])],
            dx_m=[float(self.dx_m[0]), float(self.dx_m[1])],
            h2_s=float(min(max(self.h2 or 0.0, 0.0), 60.0)),
            alpha_m=[float(self.alpha_m[0]), float(self.alpha_m[1])],
            enable=self.enable,
            wave=wave,
            energy=energy,
            operator=self.operator_name,
            release=hand_off,
            fb_echo=self._fb_echo(),
        )
        try:
            self._send(cmd)
        except Exception as exc:  # a transport hiccup must not stop the haptic loop
            LOG.warning("sending a command failed: %s", exc)
        self.last_command = cmd
        self.sample = sample = self._make_sample(now, t_dev, cmd)
        if self.operator is not None:
            self.operator.observe_sample(sample)  # e.g. the pilot's predictor
        if self._on_sample is not None:
            self._on_sample(sample)

    def _make_sample(self, now: float, t_dev: float, cmd: Command) -> LeaderSample:
        fb = self._fb
        h1, h2 = self.h1, self.h2
        sample = LeaderSample(
            t=now,
            t_device=t_dev,
            seq=cmd.seq,
            ref_v=cmd.ref[0],
            ref_w=cmd.ref[1],
            x_v=float(self.x_m[0]),
            x_w=float(self.x_m[1]),
            dx_v=float(self.dx_m[0]),
            dx_w=float(self.dx_m[1]),
            force_v=float(self.force[0]),
            force_w=float(self.force[1]),
            h1_ms=None if h1 is None else 1000.0 * h1,
            h2_ms=None if h2 is None else 1000.0 * h2,
            delay_ms=None if h1 is None or h2 is None else 1000.0 * (h1 + h2),
            alpha_m_v=float(self.alpha_m[0]),
            alpha_m_w=float(self.alpha_m[1]),
            gain=float(self.gain),
            enable=self.enable,
            hand="released" if cmd.release else "drive",
            me=self.operator_name,
            leader_state=self.state,
            link=_LINK.get(self.state, self.state),
            feedback_age_ms=None if fb is None else 1000.0 * (now - self._fb_recv),
            blind=self.blind.words(),
            blind_stops=self.blind.stops,
        )
        if fb is not None:
            sample.z_e_v, sample.z_e_w = fb.z_e
            sample.z_r_v, sample.z_r_w = fb.z_r
            sample.eta_v, sample.eta_w = fb.eta
            sample.s_r_v, sample.s_r_w = fb.s_r
            sample.s_e_v, sample.s_e_w = fb.s_e
            sample.T, sample.eps, sample.state = fb.T, fb.eps, fb.state
            sample.pose_x, sample.pose_y, sample.pose_yaw = fb.pose
            sample.sonar_l, sample.sonar_r = fb.sonar
            sample.f_v_t, sample.f_v_n = fb.f_v
        if self.operator is not None:
            prog = self.operator.progress()
            sample.operator = prog.get("operator")
            sample.intended_v, sample.intended_w = prog.get("intended", [0.0, 0.0])
            if "passes_done" in prog:
                sample.passes_done = int(prog["passes_done"])
        return sample

    def send_stop(self, repeats: int = 3) -> None:
        """Zero the force and send ``enable = False`` commands that release the robot.

        The follower stops and stands at once instead of waiting for its watchdog, and
        another operator may take the robot (the leader is leaving).
        """
        try:
            self.device.apply_force(np.zeros(2))
        except Exception as exc:  # the device may already be gone
            LOG.debug("zeroing the force at stop: %s", exc)
        self.force = np.zeros(2)
        self.enable = False
        for _ in range(repeats):
            self.seq += 1
            cmd = Command(
                sid=self.sid,
                seq=self.seq,
                t=self._clock(),
                x_m=[float(v) for v in self.x_m],
                h2_s=float(min(max(self.h2 or 0.0, 0.0), 60.0)),
                alpha_m=[float(v) for v in self.alpha_m],
                enable=False,
                energy=self.port.outgoing(np.zeros(2))[1],
                operator=self.operator_name,
                release=True,
            )
            try:
                self._send(cmd)
            except Exception as exc:
                LOG.warning("sending the stop command failed: %s", exc)
            self.last_command = cmd
        self.state = "stopped"

    # ------------------------------------------------------------------ running

    @property
    def done(self) -> bool:
        """True once the operator model finished its task."""
        return self.operator is not None and self.operator.done

    def stop(self) -> None:
        """Ask :meth:`run` to return after the current tick (thread-safe)."""
        self._stop.set()

    def run_for(self, seconds: float, realtime: bool = False, until_done: bool = False) -> None:
        """Run ``seconds`` of loop time.

        ``realtime=False`` steps as fast as possible in *virtual* time: the k-th tick sees
        ``now = t0 + k * dt`` where t0 continues from the previous call (or ``clock()`` at
        the first one); the feedback source can read :attr:`now`. ``realtime=True`` is
        :meth:`run` with a duration.
        """
        if realtime:
            self.run(duration_s=seconds, until_done=until_done)
            return
        n = round(seconds / self.dt)
        t0 = self._clock() if math.isnan(self.now) else self.now + self.dt
        for k in range(n):
            self.tick(now=t0 + k * self.dt)
            if until_done and self.done:
                break

    def run(
        self,
        stop: threading.Event | None = None,
        duration_s: float | None = None,
        until_done: bool = True,
        mono: Callable[[], float] = time.perf_counter,
    ) -> None:
        """Run in real time until stopped, ``duration_s`` [s] passed or the operator finished.

        It stops when ``stop`` is set, :meth:`stop` is called, ``duration_s`` passed or
        (``until_done``) the operator finished.

        Each tick advances the device by the real time elapsed since the previous one, so
        a simulated device stays in real time even after an overrun.
        """
        set_timer_slack()
        with realtime_scheduling(self.cfg.rt_priority):
            pacer = Pacer(self.dt, spin_s=self.cfg.spin_s, clock=mono)
            t_start = pacer.start
            last = t_start
            self._stop.clear()
            while not self._stop.is_set() and not (stop is not None and stop.is_set()):
                t = mono()
                self.period_stats.add(t)
                self.tick(dt=min(max(t - last, 0.0), 0.05) if self.ticks else self.dt)
                last = t
                if duration_s is not None and t - t_start >= duration_s:
                    break
                if until_done and self.done:
                    break
                missed = pacer.missed
                pacer.wait()
                self.missed_ticks += pacer.missed - missed
