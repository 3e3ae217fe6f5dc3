"""``bipedtele leader``: the operator's side as a program.

Opens the Zenoh session from ``[network]``, declares the leader's presence, publishes
commands (and status, and clock pings in ``[clock] mode = "ntp"``), receives feedback,
status and video, serves the browser cockpit, records everything to MCAP and runs the
1 kHz :class:`~bipedtele.leader.loop.LeaderLoop` in the main thread until the operator
model is done, ``--duration`` passed, or SIGINT/SIGTERM. On the way out it sends
``enable = false`` commands so the robot stops at once, then prints a one-line summary.

Order: arguments and configuration are checked first (one line, exit 2), then the session
opens and the device connects; only then does the cockpit serve (its address, with the
run's access token, is logged as ``cockpit: open http://HOST:PORT/?token=TOKEN``) and the
recording start. While the follower is present, :class:`~bipedtele.leader.reach.CommandReach`
watches that its feedback acknowledges our commands: if none does for 1.5 s a WARNING names
the cause the evidence points to (the follower heard: ``commands not reaching the robot:
refused by the router's ACL?``; nothing heard: ``link lost: no feedback for N s (path or
router down?)``), and a run in which none ever got through ends with exit code
:data:`EXIT_NOT_REACHED` (3).

:class:`~bipedtele.leader.linkquality.LinkQuality` measures the link from what arrives
(feedback age, loss, goodput, video rate); it judges, for the feedback inbox
(:class:`~bipedtele.link.inbox.FeedbackInbox`, where every check on feedback is made), whether a
feedback is young enough: one older than its bound is refused (counted as the drop
``fb_too_old``) and never reaches the loop; the link state in the
sample (``link``) is its verdict, and the leader's Status carries ``rx_bps``,
``fb_loss_ppm`` and ``fb_age_ms`` for the follower to adapt its rates.
"""

from __future__ import annotations

import argparse
import functools
import logging
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bipedtele.cli import add_config_args, add_foxglove_arg, config_from_args
from bipedtele.config.profile import Config, ConfigError
from bipedtele.config.sections import ClockConfig, NetworkConfig, RobotConfig
from bipedtele.control.config import ControlConfig
from bipedtele.leader.config import LeaderConfig
from bipedtele.leader.device import DeviceError, LeaderDevice, PadInput, device_names, make_device
from bipedtele.leader.linkquality import LinkQuality
from bipedtele.leader.loop import LeaderLoop
from bipedtele.leader.operator import Operator, make_operator, operator_names
from bipedtele.leader.operators.pilot import course_from_config
from bipedtele.leader.predictor import DelayPredictor, LivePredictor
from bipedtele.leader.reach import CommandReach
from bipedtele.leader.report import fill_link, link_counters
from bipedtele.leader.report import summary as report_summary
from bipedtele.leader.side import LeaderSide
from bipedtele.leader.videoparts import FrameAssembler
from bipedtele.link.auth import MAC_OVERHEAD
from bipedtele.link.gate import SequenceGate
from bipedtele.link.inbox import FeedbackInbox
from bipedtele.link.messages import Command, Feedback, Message, Status, VideoFrame, encode
from bipedtele.link.node import Node, StepClock
from bipedtele.link.receivers import Received
from bipedtele.link.transport import PresenceWatcher
from bipedtele.telemetry import LeaderSample

# fill_link and link_counters: the link report's helpers, as this module offered them before the side thread moved
__all__ = ["COCKPIT_TOKEN_ENV", "EXIT_NOT_REACHED", "LeaderApp", "add_leader_parser", "fill_link", "link_counters"]

LOG = logging.getLogger(__name__)


def _make_device(cfg: Config, name: str) -> LeaderDevice:
    try:
        # A name not offered fails before any driver is built; every device reads its own
        # settings ([leader], [falcon], [joystick]) from the profile.
        return make_device(name, config=cfg)
    except ValueError as exc:
        raise ConfigError(f"--device {name!r}: {exc}") from None


#: Exit code of a run in which the follower was there but none of our commands reached it.
EXIT_NOT_REACHED = 3
#: Environment variable that sets the cockpit token instead of a random one (a launcher
#: that opens the page itself); URL-safe, at least 16 characters.
COCKPIT_TOKEN_ENV = "BIPEDTELE_COCKPIT_TOKEN"


def _cockpit_token() -> str | None:
    value = os.environ.get(COCKPIT_TOKEN_ENV)
    if value is None:
        return None
    from bipedtele.leader.cockpit.server import check_token

    try:
        return check_token(value)
    except ValueError as exc:
        raise ConfigError(f"{COCKPIT_TOKEN_ENV}: {exc}") from None


class LeaderApp:
    """The leader program on the node runtime (see the module docstring).

    Every argument and setting is checked when it is built (one line, exit 2); nothing
    is opened, served or written before :meth:`run`.

    Parameters
    ----------
    cfg : Config
        Loaded profile.
    operator_name, device_name : str, optional
        Override ``[leader] operator`` / ``device``.
    duration_s : float, optional
        Stop after this long [s] (``[leader] duration_s`` when omitted; 0 = no limit). With
        a duration the scripted operator holds its last point's speed until the end
        instead of ending the run.
    realtime : bool, optional
        Override ``[leader] realtime``. Off runs the loop as fast as possible with message
        times on a virtual clock (tests and tools only: a real-time follower sees it as
        time passing faster).
    record : Path, optional
        MCAP file (default: a new file in ``[record] dir`` when recording is enabled).
    """

    def __init__(
        self,
        cfg: Config,
        *,
        operator_name: str | None = None,
        device_name: str | None = None,
        duration_s: float | None = None,
        realtime: bool | None = None,
        record: Path | None = None,
    ) -> None:
        self.cfg = cfg
        self.lc = lc = cfg.get(LeaderConfig)
        self.op_name = operator_name or lc.operator
        self.dev_name = device_name or lc.device
        self.realtime = lc.realtime if realtime is None else realtime
        self.duration = lc.duration_s if duration_s is None else duration_s
        if self.op_name not in operator_names():
            raise ConfigError(f"--operator {self.op_name!r}: allowed: {', '.join(operator_names())}")
        if self.op_name == "browser" and not lc.cockpit:
            raise ConfigError("--operator browser: allowed only with the cockpit (leader.cockpit = true)")
        self.device = _make_device(cfg, self.dev_name)  # a bad name fails here, before any I/O
        self.token = _cockpit_token() if lc.cockpit else None
        self.cockpit: Any = None  # the cockpit server, once it runs (the browser operator reads it)
        if self.device.needs_cockpit:  # a gamepad or the keyboard in the cockpit's page
            if not lc.cockpit:
                raise ConfigError(
                    f"--device {self.dev_name}: it is read in the cockpit's page; allowed: with leader.cockpit = true"
                )
            self.device.attach_cockpit(self._pad)
        self.loop: LeaderLoop | None = None
        self.aux: LeaderSide | None = None
        try:
            operator: Operator | None = make_operator(
                self.op_name,
                cfg,
                workspace_m=self.device.limits.workspace_m,
                joystick=self._joystick if lc.cockpit else None,
                hold_script=bool(self.duration),
            )
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        if not self.device.simulated:
            operator = None  # a person holds a physical device
            LOG.info("device %s is held by a person: operator model %s not used", self.dev_name, self.op_name)
        self.operator = operator
        self.node = Node(
            cfg, "leader", takeover_after_s=cfg.get(LeaderConfig).feedback_timeout_s, record=record
        )  # a bad key file or --record fails here
        # The feedback gate follows one follower session; its live sid binds the clock link.
        # Without the message key a forged high seq is rolled back after 3 real feedbacks.
        self.fb_gate = SequenceGate(takeover_after_s=lc.feedback_timeout_s, rollback_after=0 if self.node.auth else 3)
        self.reach = CommandReach(
            self._commands_sent,
            key_drops=self.node.drops.counts,
            robot_id=cfg.get(RobotConfig).id,
            user=cfg.get(NetworkConfig).user,
            holder=self._holder,
            released=self._released,
        )
        self.link = LinkQuality(feedback_timeout_s=lc.feedback_timeout_s)
        self._frames = FrameAssembler(self.node.drops)
        self._mac_bytes = MAC_OVERHEAD if self.node.auth is not None else 0
        self.clock: Callable[[], float] = time.time if self.realtime else StepClock(1.0 / lc.haptic_rate_hz)
        # The predictive display's fields (docs/cockpit.md): the pilot's own predictor when
        # it steers on one, else one fed here from the same samples.
        live = getattr(operator, "live", None)
        self.own_live = live is None
        self.live: LivePredictor = LivePredictor(DelayPredictor(tau_s=lc.pilot_predict_tau_s)) if live is None else live
        self.predict_every = max(1, round(lc.cmd_rate_hz / lc.cockpit_rate_hz))

    # ------------------------------------------------------------------ wiring

    def _holder(self) -> str | None:
        """Who holds the robot, from the follower's newest status (None: none heard yet)."""
        st = self.aux.follower_status if self.aux is not None else None
        return st.held_by if st is not None else None

    def _released(self) -> bool:
        return bool(self.loop is not None and self.loop.released)

    def _hand(self) -> bool:
        """Return the cockpit's hand: True after its Release, False after its Take."""
        return bool(self.cockpit is not None and self.cockpit.released())

    def _pad(self) -> PadInput | None:
        """Return the page's controller (``--device gamepad``, ``keyboard``), None before the cockpit runs."""
        got = self.cockpit.pad() if self.cockpit is not None else None
        return PadInput(*got) if got is not None else None

    def _joystick(self) -> tuple[float, float, float] | None:
        return self.cockpit.joystick() if self.cockpit is not None else None

    def _commands_sent(self) -> int:
        return self.loop.seq if self.loop is not None else 0

    def _size(self, msg: Message) -> int:
        """Payload size of a received message [bytes]: its encoding (as the sender's) plus the MAC.

        The receiver does not hand over the size it read; msgpack encodes a decoded
        message back to the same bytes.
        """
        return len(encode(msg)) + self._mac_bytes

    def _judge_feedback(self, got: Received[Feedback], t_sent: float) -> bool:
        """Tell the link of a feedback the inbox admitted or found too old; whether it is young enough.

        ``t_sent`` is its send time on the local clock [s]. Zenoh's thread.
        """
        msg = got.msg
        if not self.link.on_feedback(msg.sid, msg.seq, t_sent, got.t_recv, self._size(msg)):
            return False  # the inbox counts it (fb_too_old)
        self.reach.on_feedback(msg, got.t_recv - t_sent)  # only young feedback acknowledges commands
        return True

    def _on_video(self, got: Received[VideoFrame]) -> None:
        msg = got.msg
        self.reach.on_heard(got.t_recv - self.node.to_local(msg.t))  # old frames: a stalled uplink, not the ACL
        nbytes = self._size(msg)
        if msg.parts > 1:
            self.link.on_video_part(got.t_recv, nbytes)
        frame = self._frames.add(msg)  # a frame sent in parts: whole once its last part came
        if frame is None:
            return
        self.node.record("video/recv", frame, got.t_recv)
        self.link.on_video(
            got.t_recv,
            nbytes if frame is msg else self._size(frame),
            frame.width,
            frame.height,
            counted=frame is not msg,
        )
        if self.cockpit is not None:
            self.cockpit.publish_video(frame.camera, frame.jpeg, frame.t_capture)

    def _on_status(self, got: Received[Status]) -> None:
        if got.msg.role == "follower":
            self.reach.on_heard(got.t_recv - self.node.to_local(got.msg.t))
            self.link.on_status(got.t_recv, self._size(got.msg))

    def _feedback_inbox(self, **checks: Any) -> FeedbackInbox:
        """Build the feedback inbox with the node's ``checks``: h2, the link's judgement."""
        return FeedbackInbox(
            delay_window_s=self.cfg.get(ClockConfig).delay_window_s, judge=self._judge_feedback, **checks
        )

    def _send_command(self, cmd: Command) -> None:
        self.node.pubs.cmd.put(cmd)
        self.node.record("cmd/sent", cmd, cmd.t)

    def _on_sample(self, sample: LeaderSample) -> None:
        """Complete each loop sample (the loop fed the operator already), then show and record it.

        Fills the prediction fields and the follower's status; the sample is not changed
        after it went to the cockpit and the recorder.
        """
        if self.loop is not None:
            fb = self.loop.feedback
            if self.own_live:
                self.live.observe(sample, fb.t if fb is not None else None)
                if fb is not None and (sample.seq or 0) % self.predict_every == 0:
                    self.live.predict(sample.t, fb.pose, fb.eta, fb.t, fb.h1_s)
            if self.live.last is not None:
                now, ahead = self.live.last
                sample.pred_x, sample.pred_y, sample.pred_yaw = now.x, now.y, now.yaw
                sample.ahead_x, sample.ahead_y, sample.ahead_yaw = ahead.x, ahead.y, ahead.yaw
                sample.ahead_dt = ahead.t - now.t
        if self.aux is not None:
            self.aux.fill(sample)
        sample.control_link = self.node.control_words(sample.t)  # split layouts: which link carries control
        if self.cockpit is not None:
            self.cockpit.publish_sample(sample)
        self.node.record("leader/state", sample, sample.t)

    def _start_cockpit(self) -> Any:
        lc = self.lc
        from bipedtele.leader.cockpit import CockpitProcess

        try:  # its own process: a flood of the web server never takes the haptic loop's CPU
            cockpit = CockpitProcess(
                lc.cockpit_host,
                lc.cockpit_port,
                telemetry_hz=lc.cockpit_rate_hz,
                token=self.token,
                allowed_hosts=lc.cockpit_allowed_hosts,
                max_clients=lc.cockpit_max_clients,
                course=_map_course(self.cfg),
                force_max_n=self.device.limits.force_max_n,
            ).start()
        except OSError as exc:
            raise ConfigError(
                f"leader.cockpit_port = {lc.cockpit_port}: cannot serve on {lc.cockpit_host} "
                f"({exc.strerror or exc}); allowed: a free port, or 0 for any"
            ) from None
        self.node.on_close(cockpit.stop)
        return cockpit

    # ------------------------------------------------------------------ run

    def run(self, stats: dict[str, Any] | None = None) -> int:
        """Run until done, ``duration_s`` or a signal; return the exit code.

        0: clean end; 1: the device failed; :data:`EXIT_NOT_REACHED`: the follower was
        there but none of our commands reached it. Nothing is served or recorded before the
        Zenoh session is open. ``stats``, when given, is filled at the end with the loop's
        figures (period statistics, counters, progress).
        """
        lc, node = self.lc, self.node
        with node:
            # Python threads (Zenoh callbacks, cockpit, recorder) hand the GIL back to the
            # haptic loop sooner than the default 5 ms.
            node.on_close(functools.partial(sys.setswitchinterval, sys.getswitchinterval()))
            sys.setswitchinterval(0.0005)
            node.declare_presence()
            presence = node.watch_presence("follower")
            try:
                node.enter(self.device)
            except DeviceError as exc:
                LOG.error("device %s: %s", self.dev_name, exc)
                return 1
            # Configuration, session and device are good: now the cockpit and the recording.
            if lc.cockpit:
                self.cockpit = self._start_cockpit()
            recorder = node.start_recording({"operator": self.op_name, "device": self.dev_name}, jpeg_every=10)
            loop, aux = self._wire(presence)
            self._log_ready()
            node.event("start", {"operator": self.op_name})
            t_start = time.time()
            self._run_loop(loop)
            elapsed = time.time() - t_start
            done = loop.done
            aux.record_progress(time.time())  # the last pass may have ended the run just now
            path = recorder.path if recorder is not None else None
            summary, never_reached = self._finish(loop, done, elapsed, path)
            if stats is not None:
                stats.update(self._stats(loop, done, elapsed, never_reached))
        print(summary, flush=True)  # noqa: T201 - the program's one-line result
        return EXIT_NOT_REACHED if never_reached else 0

    def _wire(self, presence: PresenceWatcher) -> tuple[LeaderLoop, LeaderSide]:
        """Open the receivers, build the haptic loop on the feedback inbox and start the side thread."""
        lc, node = self.lc, self.node
        # every check on feedback, h2 and the link's judgement in one inbox; too old:
        # refused before the gate binds and h2 moves
        fb_rx = node.receive(
            node.keys.feedback,
            Feedback,
            self.fb_gate,
            topic="feedback/recv",
            max_age_s=self.link.max_age_s,
            inbox=self._feedback_inbox,
        )
        assert isinstance(fb_rx.inbox, FeedbackInbox)
        node.receive(node.keys.video, VideoFrame, SequenceGate(), on_message=self._on_video)
        status_rx = node.receive(
            node.keys.status,
            Status,
            SequenceGate(),
            topic="status/recv",
            ignore_sid=node.sid,
            on_message=self._on_status,
        )
        node.link_clocks(peer_sid=lambda: self.fb_gate.live_sid)
        self.loop = loop = LeaderLoop(
            self.device,
            self.operator,
            self.cfg.get(ControlConfig),
            self._send_command,
            fb_rx.inbox,
            cfg=lc,
            clock=self.clock,
            conservative_rtt=node.round_trip,
            on_sample=self._on_sample,
            sid=node.sid,
            operator_name=self.cfg.get(NetworkConfig).user,
            feedback_age=self.link.feedback_age if self.realtime else None,
            on_blind=node.event,
            hand=self._hand,
        )
        side = LeaderSide(
            loop,
            node.pubs,
            self.cfg,
            status_rx,
            presence,
            node.drops,
            node.record,
            self.reach,
            self.link,
            hand=self._hand,
        )
        self.aux = aux = node.enter(side)
        return loop, aux

    def _log_ready(self) -> None:
        LOG.info(
            "leader ready: robot %s, device %s, operator %s, %s%s",
            self.cfg.get(RobotConfig).id,
            self.dev_name,
            self.op_name if self.operator is not None else "(person)",
            "real time" if self.realtime else "as fast as possible",
            f", cockpit {self.cockpit.url}" if self.cockpit is not None else "",
        )
        if self.cockpit is not None:
            LOG.info("cockpit: open %s", self.cockpit.url)

    def _finish(self, loop: LeaderLoop, done: bool, elapsed: float, path: Path | None) -> tuple[str, bool]:
        """Stop the robot, record the end; return the one-line summary and whether no command ever got through."""
        node = self.node
        node.event("done" if done else "stop", {"elapsed_s": elapsed})
        loop.send_stop()
        never_reached = self.reach.never_acknowledged
        if never_reached:
            node.event("commands_not_reaching", {"commands": loop.seq})
        summary = report_summary(
            loop, self.op_name, self.operator, elapsed, node.drops, path, self.realtime, self.reach, self.link
        )
        return summary, never_reached

    def _stats(self, loop: LeaderLoop, done: bool, elapsed: float, never_reached: bool) -> dict[str, Any]:
        """Return the run's figures for ``run(stats=...)``: period statistics, counters, progress."""
        out: dict[str, Any] = dict(loop.period_stats.summary(loop.dt))
        out.update(
            missed_ticks=loop.missed_ticks,
            commands=loop.seq,
            feedback=self.link.fb_arrived,
            feedback_used=loop.feedback_count,
            fb_too_old=self.link.fb_too_old,
            drops=self.node.drops.total,
            done=done,
            elapsed_s=elapsed,
            progress=self.operator.progress() if self.operator is not None else {},
            cockpit=self.cockpit.stats if self.cockpit is not None else {},
            acknowledged=self.reach.acknowledged,
            never_reached=self.reach.never_reached,
            never_acknowledged=never_reached,
            link_lost_warnings=self.reach.lost_warnings,
            slew_limited_ticks=loop.slew_limited_ticks,
        )
        return out

    def _run_loop(self, loop: LeaderLoop) -> None:
        """Run the haptic loop in the main thread: paced in real time, or stepped as fast as possible."""
        stop = self.node.stop
        if self.realtime:
            loop.run(stop=stop, duration_s=self.duration or None, until_done=True)
            return
        clock = self.clock
        assert isinstance(clock, StepClock)
        limit = round(self.duration * self.lc.haptic_rate_hz) if self.duration else None

        def step(t: float) -> bool:
            if loop.done or (limit is not None and clock.ticks >= limit):
                return False
            loop.tick(now=t)
            return True

        self.node.run_stepped(clock, step)


def _map_course(cfg: Config) -> list[tuple[float, float, float]]:
    """Return the obstacles the cockpit's map draws.

    The pilot's course (``[leader] pilot_obstacles``), else the ``[world]`` obstacles;
    empty when neither is set.
    """
    lc, world = cfg.get(LeaderConfig), cfg.sections.get("world")  # [world]: the follower's, by name
    if not lc.pilot_obstacles and not getattr(world, "obstacles", None):
        return []
    try:
        return [(o.x, o.y, o.radius) for o in course_from_config(cfg)]
    except ValueError as exc:
        LOG.warning("cockpit map: no obstacles (%s)", exc)
        return []


def _run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration >= 0):
        raise ConfigError(f"--duration {args.duration}: allowed: a number of seconds >= 0")
    realtime = None if args.realtime is None else args.realtime == "on"
    app = LeaderApp(
        cfg,
        operator_name=args.operator,
        device_name=args.device,
        duration_s=args.duration,
        realtime=realtime,
        record=Path(args.record) if args.record else None,
    )
    return app.run()


def add_leader_parser(sub: Any) -> None:
    """``bipedtele leader``: run the operator's side."""
    p = sub.add_parser("leader", help="run the operator's side (haptic device, operator model, cockpit)")
    add_config_args(p)
    p.add_argument("--operator", choices=operator_names(), help="operator model (default: [leader] operator)")
    p.add_argument("--device", choices=device_names(), help="leader device (default: [leader] device)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (0: no limit)")
    p.add_argument("--realtime", choices=["on", "off"], help="pace in real time (default: [leader] realtime)")
    p.add_argument("--record", metavar="FILE", help="MCAP file (default: a new leader-<time>.mcap in [record] dir)")
    add_foxglove_arg(p)
    p.set_defaults(func=_run)
