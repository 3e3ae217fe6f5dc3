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
import contextlib
import logging
import time
from pathlib import Path
from typing import Any

from bipedtele.auth import load_message_auth
from bipedtele.cli import add_config_args, config_from_args
from bipedtele.clock import ClockSync
from bipedtele.clocklink import ClockLink
from bipedtele.config import Config, ConfigError
from bipedtele.drops import DropCounter
from bipedtele.follower.loop import DEFAULT_MAX_FUTURE_S, FollowerLoop
from bipedtele.follower.robot import FollowerRobot, RobotError, make_robot
from bipedtele.follower.supervisor import RobotSupervisor
from bipedtele.follower.video import VideoStreamer
from bipedtele.gate import SequenceGate
from bipedtele.messages import ClockPing, ClockPong, Command, Feedback, Message, Status, VideoFrame
from bipedtele.recording import Recorder, recording_for_run
from bipedtele.shutdown import shutdown_on_signals
from bipedtele.transport import (
    Keys,
    LatestReceiver,
    Publishers,
    declare_presence,
    open_session,
)

__all__ = ["add_follower_parser", "main"]

LOG = logging.getLogger(__name__)


def _robot_from_config(cfg: Config, name: str) -> FollowerRobot:
    try:
        return make_robot(name, config=cfg)
    except ValueError as exc:
        raise ConfigError(f"--robot: {exc}") from None


def _reset_hook(robot: FollowerRobot) -> Any:
    """``on_new_leader`` for ``--reset-on-leader``: the robot back on its start pose."""

    def on_new_leader(sid: int) -> bool:
        reset = getattr(robot, "reset_pose", None)
        if reset is None:
            return False
        LOG.info("new leader session %d: putting the robot back on the course start", sid)
        reset()
        return True

    return on_new_leader


class _Pacer:
    """Sleeps to keep a fixed period without drift (skips ahead after overruns)."""

    def __init__(self, period: float) -> None:
        self.period = period
        self.next = time.monotonic()
        self.overruns = 0

    def wait(self) -> None:
        self.next += self.period
        delay = self.next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        elif delay < -self.period:
            self.overruns += 1
            self.next = time.monotonic()


def main(
    cfg: Config,
    *,
    robot_name: str | None = None,
    realtime: bool | None = None,
    duration_s: float | None = None,
    record: Path | None = None,
    reset_on_leader: bool = False,
) -> int:
    """Run the follower until a signal or ``duration_s`` of robot time.

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
        (simulator only).
    """
    fcfg = cfg.section("follower")
    name = robot_name or fcfg.robot
    rt = fcfg.realtime if realtime is None else realtime
    if not rt and name != "sim":
        raise ConfigError(f"--realtime off with robot {name!r}: allowed: only with the simulator (robot 'sim')")
    if reset_on_leader and name != "sim":
        raise ConfigError(f"--reset-on-leader with robot {name!r}: allowed: only with the simulator (robot 'sim')")
    keys = Keys(cfg.section("robot").id)
    # Every setting is checked (the robot's section too) before anything is written.
    robot_obj = _robot_from_config(cfg, name)
    ck = cfg.section("clock")
    max_future_s = float(getattr(ck, "max_future_s", DEFAULT_MAX_FUTURE_S))
    auth = load_message_auth(cfg.section("network"))  # a bad key file fails here, before any I/O
    rec_cfg = cfg.section("record")
    if record is not None and record.exists():
        raise ConfigError(f"--record {record}: the file exists; allowed: a new file (never overwritten)")
    ntp = ck.mode == "ntp"
    sync = ClockSync(ck.ping_window) if ntp else None
    drops = DropCounter("follower")
    # The command gate follows one leader session (another takes over only after the
    # watchdog's silence); its live sid binds the clock link.
    cmd_gate = SequenceGate(takeover_after_s=fcfg.watchdog_s)

    with contextlib.ExitStack() as stack:
        stop = stack.enter_context(shutdown_on_signals())
        session = stack.enter_context(open_session(cfg.section("network")))
        pubs = stack.enter_context(Publishers(session, keys, auth=auth))
        try:
            robot = stack.enter_context(robot_obj)
        except RobotError as exc:
            LOG.error("robot %s: %s", name, exc)
            return 1
        # Configuration, session and robot are good: now the recording and our presence.
        recorder: Recorder | None = None
        if record is not None or rec_cfg.enabled:
            recorder = stack.enter_context(recording_for_run(
                record, rec_cfg.dir, "follower", flush_s=rec_cfg.flush_s,
                metadata={"role": "follower", "config": cfg.to_dict()},
            ))  # fmt: skip
        stack.enter_context(declare_presence(session, keys, "follower"))

        def on_command(got: Any) -> None:  # every accepted command, once, in the receiver
            if recorder is not None:
                recorder.write("cmd/recv", got.msg, got.t_recv)

        cmd_rx = stack.enter_context(LatestReceiver(
            session, keys.cmd, Command, drops, cmd_gate, clock_sync=sync, auth=auth,
            max_future_s=max_future_s, on_message=on_command,
        ))  # fmt: skip

        def publish(msg: Message) -> None:
            if isinstance(msg, Feedback):
                pubs.feedback.put(msg)
                topic = "feedback/sent"
            elif isinstance(msg, Status):
                msg = Status(**{**msg.__dict__, "counters": {**msg.counters, **{f"drop_{k}": v for k, v in drops.counts().items()}}})
                pubs.status.put(msg)
                topic = "status/sent"
            else:
                pubs.video.put(msg)
                topic = "video/sent"
            if recorder is not None and not isinstance(msg, VideoFrame):
                recorder.write(topic, msg, time.time())

        def latest_command() -> tuple[Command, float] | None:
            got = cmd_rx.latest()
            return (got.msg, got.t_recv) if got is not None else None

        def on_event(event: str, detail: dict[str, Any]) -> None:
            if recorder is not None:
                recorder.write("events", {"event": event, **detail}, time.time())

        ticks = [0]
        if rt:
            clock = time.time
        else:
            # Faster than real time: message times follow robot time, offset to the wall
            # clock at start so they stay plausible to receivers.
            t0_wall = time.time()

            def clock() -> float:
                return t0_wall + ticks[0] * loop.dt

        loop = FollowerLoop(
            robot, cfg.section("control"), fcfg, latest_command, publish,
            now=clock, to_local=sync.to_local if sync is not None else (lambda t: t),
            delay_window_s=ck.delay_window_s, on_event=on_event,
            conservative_rtt=(lambda: sync.rtt) if sync is not None and ck.conservative_split else None,
            max_future_s=max_future_s, on_new_leader=_reset_hook(robot) if reset_on_leader else None,
        )
        naoqi_cfg = getattr(robot, "config", None)
        backoff = tuple(getattr(naoqi_cfg, "reconnect_backoff_s", (0.2, 5.0)))
        supervisor = RobotSupervisor(robot, loop, backoff_s=(float(backoff[0]), float(backoff[1])))
        video = stack.enter_context(
            VideoStreamer(robot, fcfg.cameras, fcfg.camera_fps, pubs.video.put, now=clock, jpeg_quality=fcfg.jpeg_quality)
        )
        # Clock pings: answered and sent off the control loop, bound to the followed leader.
        link = stack.enter_context(ClockLink(
            pubs.clock.put, loop.sid, sync=sync, drops=drops, ping_rate_hz=ck.ping_rate_hz,
            answer_rate_hz=ck.answer_rate_hz, peer_sid=lambda: cmd_gate.live_sid,
        ))  # fmt: skip
        stack.enter_context(LatestReceiver(
            session, keys.clock, (ClockPing, ClockPong), drops, ignore_sid=loop.sid, auth=auth,
            on_message=link.on_message,
        ))  # fmt: skip
        LOG.info("follower %s ready: robot %s, key %s, %s", keys.cmd.split("/")[1], name, keys.cmd, "real time" if rt else "as fast as possible")
        pacer = _Pacer(loop.dt)
        start_t = clock()
        while not stop.is_set():
            tel = supervisor.tick()
            if tel is not None:
                video.maybe_capture(tel.t)
            supervisor.advance(loop.dt)
            if duration_s is not None and clock() - start_t >= duration_s:
                break
            if rt:
                pacer.wait()
            else:
                ticks[0] += 1
        LOG.info("follower stopping: %s, robot faults %d, reconnects %d, camera errors %d",
                 dict(loop.counters), supervisor.faults, supervisor.reconnects, video.stats["errors"])
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.naoqi_url:
        args.overrides.append(f"naoqi.url={args.naoqi_url!r}".replace("'", '"'))
    if args.unguarded_robot_may_keep_walking:
        args.overrides.append("naoqi.allow_unguarded=true")
    cfg = config_from_args(args)
    if args.duration is not None and args.duration <= 0:
        raise ConfigError(f"--duration {args.duration}: allowed: a number of seconds > 0")
    realtime = None if args.realtime is None else args.realtime == "on"
    return main(
        cfg, robot_name=args.robot, realtime=realtime, duration_s=args.duration,
        record=Path(args.record) if args.record else None, reset_on_leader=args.reset_on_leader,
    )


def add_follower_parser(sub: Any) -> None:
    """``bipedtele follower``: run the robot side."""
    p = sub.add_parser("follower", help="run the robot side (pybullet NAO or a real NAO)")
    add_config_args(p)
    p.add_argument("--robot", choices=["sim", "naoqi"], default=None, help="robot (default: [follower] robot)")
    p.add_argument("--naoqi-url", default=None, metavar="URL", help="real NAO: tcp://HOST:9559 or tcps://HOST:9503 (sets naoqi.url)")
    p.add_argument("--realtime", choices=["on", "off"], default=None, help="pace in real time (off: simulator only)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds of robot time")
    p.add_argument("--record", default=None, metavar="F.mcap", help="recording file")
    p.add_argument(
        "--reset-on-leader", action="store_true",
        help="simulator only: put the robot back on the course start when a new leader session begins",
    )
    p.add_argument(
        "--unguarded-robot-may-keep-walking", action="store_true",
        help="real NAO: walk even when no BipedteleGuard answers (sets naoqi.allow_unguarded = true). "
        "Without a guard, a follower that dies or loses the robot's network leaves the NAO walking",
    )
    p.set_defaults(func=_run)
