"""``bipedtele follower``: the robot-side process.

Opens the Zenoh session from ``[network]``, connects the robot (``--robot sim`` or
``naoqi``), and runs :class:`~bipedtele.follower.loop.FollowerLoop` at the control rate:
commands in (latest only), feedback/status/video out, clock pings answered, presence
declared, every message recorded to MCAP. With ``--realtime off`` (simulator only) the loop
runs as fast as the CPU allows, for tests and batch runs.

Stops cleanly on SIGINT/SIGTERM: the robot stops and stands, then everything closes.
A robot fault never ends the program: :class:`~bipedtele.follower.supervisor.RobotSupervisor`
stops the robot if it can be reached, logs, and goes on (reconnecting a lost robot);
camera faults cost frames only (:class:`~bipedtele.follower.video.VideoStreamer`).
Nothing is written (recording) before the configuration is valid.
"""

from __future__ import annotations

import argparse
import functools
import logging
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from bipedtele.cli import add_config_args, add_foxglove_arg, config_from_args
from bipedtele.config.profile import Config, ConfigError
from bipedtele.config.sections import ClockConfig, RobotConfig
from bipedtele.control.config import ControlConfig
from bipedtele.follower.capacity import FeedbackPlan, UplinkBudget
from bipedtele.follower.config import FollowerConfig
from bipedtele.follower.custody import CustodyGate
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.follower.realtime import RealtimeStepper
from bipedtele.follower.robot import FollowerRobot, RobotError, make_robot, robot_names, robot_part
from bipedtele.follower.supervisor import RobotSupervisor
from bipedtele.follower.video import VideoStreamer
from bipedtele.link.auth import MAC_OVERHEAD
from bipedtele.link.gate import FollowedSessionGate, SequenceGate
from bipedtele.link.inbox import CommandInbox
from bipedtele.link.messages import Command, Feedback, Message, Status, VideoFrame, encode
from bipedtele.link.node import Node, StepClock
from bipedtele.link.receivers import LatestReceiver, Received
from bipedtele.link.relink import control_code
from bipedtele.link.transport import MessagePublisher
from bipedtele.pacer import Pacer

__all__ = ["FollowerApp", "add_follower_parser"]

LOG = logging.getLogger(__name__)


class FollowerApp:
    """The follower program on the node runtime (see the module docstring).

    Every argument and setting is checked when it is built (one line, exit 2); nothing
    is opened or written before :meth:`run`.

    Parameters
    ----------
    cfg : Config
        The loaded profile.
    robot_name : str, optional
        Overrides ``[follower] robot``.
    realtime : bool, optional
        Overrides ``[follower] realtime``.
    duration_s : float, optional
        Stop after this much robot time [s].
    record : Path, optional
        MCAP file (default: a new file in ``[record] dir`` when recording is enabled).
    reset_on_leader : bool
        Put the robot back on its start pose whenever a new leader session begins
        (simulated robots only).
    """

    def __init__(
        self,
        cfg: Config,
        *,
        robot_name: str | None = None,
        realtime: bool | None = None,
        duration_s: float | None = None,
        record: Path | None = None,
        reset_on_leader: bool = False,
    ) -> None:
        self.cfg = cfg
        self.fcfg = cfg.get(FollowerConfig)
        self.robot_name = robot_name or self.fcfg.robot
        try:
            self.part = robot_part(self.robot_name)
        except ValueError as exc:
            raise ConfigError(f"--robot: {exc}") from None
        self.realtime = self.fcfg.realtime if realtime is None else realtime
        simulated = "robot " + " or ".join(repr(n) for n in robot_names() if robot_part(n).simulated)
        if not self.realtime and not self.part.simulated:
            raise ConfigError(
                f"--realtime off with robot {self.robot_name!r}: allowed: only with the simulator ({simulated})"
            )
        if reset_on_leader and not self.part.simulated:
            raise ConfigError(
                f"--reset-on-leader with robot {self.robot_name!r}: allowed: only with the simulator ({simulated})"
            )
        self.reset_on_leader = reset_on_leader
        try:
            # Every setting is checked (the robot's section too) before anything is written.
            self.robot: FollowerRobot = make_robot(self.robot_name, config=cfg)
        except ValueError as exc:
            raise ConfigError(f"--robot: {exc}") from None
        self.duration_s = duration_s
        self.node = Node(
            cfg, "follower", takeover_after_s=self.fcfg.watchdog_s, record=record
        )  # a bad key file or --record fails here
        # The command gate follows one leader session (another takes over only after the
        # watchdog's silence): the only de-duplication of commands. Its live sid binds
        # the clock link.
        # Without the message key a forged high seq is rolled back after 3 real commands.
        # Around it, who holds the robot: another operator takes it only after a release.
        self.gate = CustodyGate(
            SequenceGate(takeover_after_s=self.fcfg.watchdog_s, rollback_after=0 if self.node.auth else 3),
            cfg.get(RobotConfig).id,
        )
        self.dt = 1.0 / self.fcfg.control_rate_hz
        self.clock: Callable[[], float] = time.time if self.realtime else StepClock(self.dt)
        # Woken by the command receiver: a fresh command is applied at once (pickup).
        self.pacer: Pacer | None = None
        self._stepper: RealtimeStepper | None = None
        self._outlets: dict[type[Message], tuple[MessagePublisher, str]] = {}
        # The uplink: bytes sent counted at the publish call, the leader's rx_bps in.
        self.budget = UplinkBudget(self.clock)
        self._mac_bytes = MAC_OVERHEAD if self.node.auth is not None else 0
        self._fb_times: list[float] = []
        self._plan = FeedbackPlan(True, float(self.fcfg.feedback_rate_hz), math.inf)
        self._status_rx: LatestReceiver[Status] | None = None
        self._video: VideoStreamer | None = None

    # ------------------------------------------------------------------ wiring

    def _on_take(self, cmd: Command) -> None:
        self.budget.on_h2(cmd.h2_s)  # the leader's feedback-path delay, from every command taken
        if cmd.fb_echo is not None:
            # the newest feedback's stamps: the uplink's queue, fast, and a stall without the leader's Status
            self.budget.on_echo(cmd.fb_echo, self.node.to_local(cmd.t))

    def _on_command(self, got: Received[Command]) -> None:  # Zenoh's thread: wake the loop
        if self.pacer is not None:
            self.pacer.notify()

    def _publish(self, msg: Message) -> bool:
        """Send ``msg``; False when the uplink's in-flight cap holds it (the loop reuses its sequence number).

        Over the cap a feedback never leaves, and a Status only as a probe (docs/network.md).
        """
        fb, inflight = isinstance(msg, Feedback), self.budget.inflight
        if (fb and not inflight.admit_feedback(self.clock())) or (
            isinstance(msg, Status) and not inflight.admit_probe(self.clock())
        ):
            return False  # over the in-flight cap: the next one carries the newest state
        pub, topic = self._outlets[type(msg)]
        self.node.send(pub, msg, topic)
        stamp = msg.counters.get("uplink_t_us") if isinstance(msg, Status) else None
        # a Status counted at its stamp: the leader's echo of the stamp acknowledges it too
        self.budget.sent(len(encode(msg)) + self._mac_bytes, feedback=fb, at=None if stamp is None else stamp / 1e6)
        if fb:
            self._fb_times.append(self.clock())
        return True

    def _publish_video(self, frame: VideoFrame) -> None:  # the video thread
        self.node.pubs.video.put(frame)
        self.budget.sent(len(encode(frame)) + self._mac_bytes, video=True)

    def _adapt(self) -> None:
        """Once per tick: the leader's figures in, the feedback plan and video's budget out."""
        got = self._status_rx.take() if self._status_rx is not None else None
        if got is not None and got.msg.role == "leader":
            self.budget.on_leader_status(got.msg.counters, self.node.to_local(got.msg.t), got.msg.sid)
        most = 0.0 if self._video is None else self._video.most_bps()
        self.budget.update(most)
        self._plan = self.budget.feedback_plan(self.fcfg.feedback_rate_hz, most)  # the loop reads it
        if self._video is not None:
            b = self.budget
            self._video.set_budget(b.video_budget_bps(), b.frame_bits_max(), b.part_bits_max())

    def _status_counters(self) -> dict[str, int]:
        """Return the program's figures for its Status: the uplink's (docs/follower.md, Capacity) and, in real time, the stepper's."""
        b, now = self.budget, self.clock()
        self._fb_times = [t for t in self._fb_times if t > now - 2.0]
        vb = b.video_budget_bps()
        out = {
            "tx_bps": round(b.tx_bps()),
            "feedback_hz": round(len(self._fb_times) / 2.0),
            "capacity_limited": int(b.limited),
            # the estimate behind the verdict (0: unknown), h2 above its minimum, and why
            "uplink_capacity_bps": round(min(b.capacity_bps, 1e9)) if math.isfinite(b.capacity_bps) else 0,
            "uplink_excess_ms": round(1000.0 * b.excess_s),
            **{f"uplink_{k}": v for k, v in b.signals.items()},
            **b.inflight_counters(),
            # this Status's send stamp [us]: the leader echoes the newest it received (uplink_t_echo_us)
            "uplink_t_us": max(0, round(1e6 * now)),
        }
        if self._video is not None:
            video = self._video
            out["video_budget_bps"] = round(min(video.most_bps(), 1e9) if vb is None else vb)
            out.update(video.counters())
        else:
            out["video_budget_bps"] = 0
        out.update(takes=self.gate.takes, releases=self.gate.releases)
        # which link carries control (the split layout's UDP one?), and how often it was reopened
        out.update(control_link=control_code(self.node.control_link), relinks=self.node.reopens)
        if self._stepper is not None:  # real time: does the robot keep pace with the wall clock?
            st = self._stepper
            out.update(ticks=st.ticks, steps_caught_up=st.caught_up_steps, steps_dropped=st.dropped_steps)
        return out

    def _reset_robot(self, sid: int) -> bool:
        """``on_new_leader`` for ``--reset-on-leader``: the robot back on its start pose."""
        reset = getattr(self.robot, "reset_pose", None)
        if reset is None:
            return False
        LOG.info("new leader session %d: putting the robot back on the course start", sid)
        reset()
        return True

    def _make_loop(self, robot: FollowerRobot, inbox: CommandInbox) -> FollowerLoop:
        node = self.node
        return FollowerLoop(
            robot,
            self.cfg.get(ControlConfig),
            self.fcfg,
            inbox,
            self._publish,
            now=self.clock,
            drops=node.drops,
            sid=node.sid,
            on_event=node.event,
            conservative_rtt=node.round_trip,
            on_new_leader=self._reset_robot if self.reset_on_leader else None,
            feedback_plan=lambda: self._plan,
            extra_counters=self._status_counters,
            held_by=lambda: self.gate.held_by,
        )

    # ------------------------------------------------------------------ run

    def run(self) -> int:
        """Run until a signal or ``duration_s`` of robot time; return the exit code.

        0: clean end; 1: the robot could not be connected at the start.
        """
        with self.node as node:
            try:
                robot = node.enter(self.robot)
            except RobotError as exc:
                LOG.error("robot %s: %s", self.robot_name, exc)
                return 1
            # Configuration, session and robot are good: now the recording and our presence.
            node.start_recording({})
            node.declare_presence()
            pubs = node.pubs
            self._outlets = {Feedback: (pubs.feedback, "feedback/sent"), Status: (pubs.status, "status/sent")}
            # The driving leader's Status: what it receives of ours (rx_bps) for the uplink
            # budget; only the session whose commands the gate takes (not a waiting operator's).
            followed = FollowedSessionGate(lambda: self.gate.bound_sid)
            self._status_rx = node.receive(node.keys.status, Status, followed, topic="status/recv", ignore_sid=node.sid)
            # Every admitted command: recorded once here, into the inbox the loop takes from
            # (every check on a command; h1, and the leader's h2 for the uplink budget).
            cmd_rx = node.receive(
                node.keys.cmd,
                Command,
                self.gate,
                topic="cmd/recv",
                on_message=self._on_command,
                max_age_s=self.fcfg.max_cmd_age_s,  # before the gate: an old replay never binds it
                inbox=functools.partial(
                    command_inbox,
                    self.fcfg,
                    to_local=node.to_local,
                    on_take=self._on_take,
                    delay_window_s=self.cfg.get(ClockConfig).delay_window_s,
                ),
            )
            assert isinstance(cmd_rx.inbox, CommandInbox)
            loop = self._make_loop(robot, cmd_rx.inbox)
            backoff = getattr(getattr(robot, "config", None), "reconnect_backoff_s", (0.2, 5.0))
            supervisor = RobotSupervisor(robot, loop, backoff_s=(float(backoff[0]), float(backoff[1])))
            video = node.enter(
                VideoStreamer(
                    robot,
                    self.fcfg.cameras,
                    self.fcfg.camera_fps,
                    self._publish_video,
                    now=self.clock,
                    jpeg_quality=self.fcfg.jpeg_quality,
                    sid=node.sid,
                    admit=self.budget.admit_video,
                )
            )
            self._video = video
            node.link_clocks(peer_sid=lambda: self.gate.live_sid)
            LOG.info(
                "follower %s ready: robot %s, key %s, %s",
                node.keys.cmd.split("/")[1],
                self.robot_name,
                node.keys.cmd,
                "real time" if self.realtime else "as fast as possible",
            )
            if self.realtime:
                self._run_realtime(robot, loop, supervisor, video)
            else:
                self._run_fast(supervisor, video)
            _log_stop(loop.counters, supervisor, video.stats)
        return 0

    def _over(self, start_t: float) -> bool:
        return self.duration_s is not None and self.clock() - start_t >= self.duration_s

    def _run_fast(self, supervisor: RobotSupervisor, video: VideoStreamer) -> None:
        """Faster than real time: one tick, then one period of robot time, and so on."""
        clock = self.clock
        assert isinstance(clock, StepClock)
        start_t = clock()

        def step(t: float) -> bool:
            self._adapt()
            tel = supervisor.tick()
            if tel is not None:
                video.maybe_capture(tel.t)
            supervisor.advance(self.dt)
            return not self._over(start_t)

        self.node.run_stepped(clock, step)

    def _run_realtime(
        self, robot: FollowerRobot, loop: FollowerLoop, supervisor: RobotSupervisor, video: VideoStreamer
    ) -> None:
        """Run in real time: a tick every period, the robot's time moved on step by step between.

        Between ticks the robot's time moves on one step at a time on the wall clock, and
        a command that arrives is applied before the next step (:meth:`FollowerLoop.pickup`).
        """
        step_s = self.part.step_s(self.cfg)
        n_sub = max(1, math.ceil(self.dt / step_s - 1e-9)) if step_s else 1
        sub_dt = self.dt / n_sub
        self.pacer = pacer = Pacer(sub_dt, clock=time.monotonic)
        self._stepper = stepper = RealtimeStepper(pacer, n_sub)
        start_t = self.clock()

        def tick() -> None:
            self._adapt()
            tel = supervisor.tick()
            if tel is not None:
                video.maybe_capture(tel.t)

        def pickup() -> None:
            if robot.is_connected:
                loop.pickup()

        stepper.run(
            tick,
            lambda: supervisor.advance(sub_dt),
            pickup,
            lambda: self.node.stopping or self._over(start_t),
        )
        if stepper.caught_up_steps or stepper.dropped_steps:
            LOG.info(
                "real time: %d steps caught up after overruns, %d given up (lag over %.2f s)",
                stepper.caught_up_steps,
                stepper.dropped_steps,
                stepper.max_lag_steps * sub_dt,
            )


def _run(args: argparse.Namespace) -> int:
    if args.naoqi_url:
        args.overrides.append(f"naoqi.url={args.naoqi_url!r}".replace("'", '"'))
    if args.unguarded_robot_may_keep_walking:
        args.overrides.append("naoqi.allow_unguarded=true")
    cfg = config_from_args(args)
    if args.duration is not None and args.duration <= 0:
        raise ConfigError(f"--duration {args.duration}: allowed: a number of seconds > 0")
    realtime = None if args.realtime is None else args.realtime == "on"
    app = FollowerApp(
        cfg,
        robot_name=args.robot,
        realtime=realtime,
        duration_s=args.duration,
        record=Path(args.record) if args.record else None,
        reset_on_leader=args.reset_on_leader,
    )
    return app.run()


def add_follower_parser(sub: Any) -> None:
    """``bipedtele follower``: run the robot side."""
    p = sub.add_parser("follower", help="run the robot side (pybullet NAO or a real NAO)")
    add_config_args(p)
    p.add_argument("--robot", choices=robot_names(), default=None, help="robot (default: [follower] robot)")
    p.add_argument(
        "--naoqi-url",
        default=None,
        metavar="URL",
        help="real NAO: tcp://HOST:9559 or tcps://HOST:9503 (sets naoqi.url)",
    )
    p.add_argument("--realtime", choices=["on", "off"], default=None, help="pace in real time (off: simulator only)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds of robot time")
    p.add_argument("--record", default=None, metavar="F.mcap", help="recording file")
    add_foxglove_arg(p)
    p.add_argument(
        "--reset-on-leader",
        action="store_true",
        help="simulator only: put the robot back on the course start when a new leader session begins",
    )
    p.add_argument(
        "--unguarded-robot-may-keep-walking",
        action="store_true",
        help="real NAO: walk even when no BipedteleGuard answers (sets naoqi.allow_unguarded = true). "
        "Without a guard, a follower that dies or loses the robot's network leaves the NAO walking",
    )
    p.set_defaults(func=_run)


def _log_stop(counters: Mapping[str, int], supervisor: RobotSupervisor, vs: Mapping[str, Any]) -> None:
    """Log the follower's last figures: the loop's counters, the robot's faults and where the video frames went."""
    LOG.info(
        "follower stopping: %s, robot faults %d, reconnects %d, camera errors %d; video frames: "
        "captured %d, published %d, replaced in the slot %d, held by the uplink %d, over budget %d, "
        "cut short %d parts",
        dict(counters),
        supervisor.faults,
        supervisor.reconnects,
        vs["errors"],
        vs["captured"],
        vs["published"],
        vs["dropped"],
        vs["held"],
        vs["throttled"],
        vs["parts_dropped"],
    )
