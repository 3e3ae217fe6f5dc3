"""``bipedtele observe``: an observer's cockpit, the video and status of its robots, commanding none.

::

    bipedtele observe --config observer-carol/bipedtele.toml [--robot nao1 ...] \
        [--cockpit-port 8090] [--duration S] [--report FILE]

Logs in with an observer's profile (``bipedtele setup fleet --observer carol=nao1,nao2``),
receives each robot's video (``bipedtele/<id>/video``) and Status (``.../status``, the
follower's and its leaders'), each verified with the robot's watch key
(:func:`bipedtele.link.auth.watch_key`), and serves them in the cockpit page: one video tile per
robot and camera (``<id>/<camera>``), and per robot its state, who holds it and its
leaders' operators in the page's table. It declares no publisher and holds no message key:
it has nothing to command with, and the router's ACL refuses its puts (docs/fleet.md).

Prints the cockpit's address (with its token) on start; ``--report`` writes what it
received per robot (frames, statuses, the last state and holder) as JSON at the end. Exit
0 at the end (``--duration`` or a signal); 1 when the router cannot be reached; 2 for bad
arguments.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig, RobotConfig
from bipedtele.leader.cockpit.server import CockpitServer
from bipedtele.leader.config import LeaderConfig
from bipedtele.leader.videoparts import FrameAssembler
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import SequenceGate
from bipedtele.link.linkcheck import LinkError
from bipedtele.link.messages import Status, VideoFrame
from bipedtele.link.receivers import LatestReceiver, MessageReceiver, Received
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session
from bipedtele.shutdown import shutdown_on_signals
from bipedtele.tools.fleetstatus import watch_auths, watched_robots

__all__ = ["Watched", "add_observe_parser", "main"]

LOG = logging.getLogger("bipedtele.observe")


@dataclass
class Watched:
    """What the observer received of one robot.

    Attributes
    ----------
    frames : int
        Whole video frames shown.
    statuses : int
        Status messages (follower and leaders).
    state : str
        The follower's newest state (empty: none heard).
    held_by : str
        Who holds the robot, from the follower's newest status.
    operators : list of str
        The operators of the leaders heard.
    verified : bool
        Whether a watch key verified what arrived (False: no key for this robot).
    """

    frames: int = 0
    statuses: int = 0
    state: str = ""
    held_by: str = ""
    operators: list[str] = field(default_factory=list)
    verified: bool = False


class _Robot:
    """One robot's receivers into the cockpit."""

    def __init__(self, robot: str, session: Any, cockpit: CockpitServer, auth: Any) -> None:
        self.robot, self.cockpit = robot, cockpit
        self.watched = Watched(verified=auth is not None)
        self.drops = DropCounter(f"observe/{robot}")
        self._frames = FrameAssembler(self.drops)
        self._lock = threading.Lock()
        keys = Keys(robot)
        self.video: LatestReceiver[VideoFrame] = LatestReceiver(
            session, keys.video, VideoFrame, self.drops, SequenceGate(), on_message=self._on_video, auth=auth
        )
        self.status: MessageReceiver[Status] = MessageReceiver(session, keys.status, Status, self.drops, auth=auth)

    def _on_video(self, got: Received[VideoFrame]) -> None:
        frame = self._frames.add(got.msg)
        if frame is None:
            return
        with self._lock:
            self.watched.frames += 1
        self.cockpit.publish_video(f"{self.robot}/{frame.camera}", frame.jpeg, frame.t_capture)

    def poll(self) -> dict[str, Any]:
        """Take the new statuses; return this robot's fields for the page's table."""
        w = self.watched
        for got in self.status.drain():
            st = got.msg
            w.statuses += 1
            if st.role == "follower":
                w.state, w.held_by = st.state, st.held_by
            elif st.operator and st.operator not in w.operators:
                w.operators.append(st.operator)
        r = self.robot
        return {
            f"{r}_state": w.state or "-",
            f"{r}_held_by": w.held_by or "-",
            f"{r}_frames": w.frames,
            f"{r}_leaders": ",".join(w.operators) or "-",
        }

    def close(self) -> None:
        self.video.close()
        self.status.close()


def main(cfg: Any, robots: list[str] | None, duration_s: float | None, report: Path | None) -> int:
    """Run the observer's cockpit until ``duration_s`` or a signal; return the exit code."""
    net = cfg.get(NetworkConfig)
    lc = cfg.get(LeaderConfig)
    ids = watched_robots(robots, net, cfg.get(RobotConfig).id)
    auths = watch_auths(net, ids, cfg.get(RobotConfig).id)
    for r in ids:
        if r not in auths:
            LOG.warning(
                "robot %s: no watch key (%s/%s.watch): its video and status are not verified",
                r,
                net.watch_key_dir or "[network] watch_key_dir",
                r,
            )
    mode = "client" if net.connect else "peer"
    cockpit = CockpitServer(
        lc.cockpit_host,
        lc.cockpit_port,
        telemetry_hz=2.0,
        allowed_hosts=lc.cockpit_allowed_hosts,
        max_clients=lc.cockpit_max_clients,
    )
    with shutdown_on_signals() as stop, open_session(net, mode=mode, listen=[]) as session, cockpit:
        watched = {r: _Robot(r, session, cockpit, auths.get(r)) for r in ids}
        LOG.info("observing %s: cockpit %s (watching only: this login commands nothing)", ", ".join(ids), cockpit.url)
        end = time.monotonic() + duration_s if duration_s else float("inf")
        try:
            while not stop.wait(0.5) and time.monotonic() < end:
                sample: dict[str, Any] = {"t": time.time()}
                for w in watched.values():
                    sample.update(w.poll())
                cockpit.publish_sample(sample)
        finally:
            for w in watched.values():
                w.close()
        out = {r: asdict(w.watched) for r, w in watched.items()}
    for r, got in out.items():
        LOG.info(
            "observed %s: %d frames, %d statuses, state %s, held by %s",
            r,
            got["frames"],
            got["statuses"],
            got["state"] or "-",
            got["held_by"] or "-",
        )
    if report is not None:
        report.write_text(json.dumps({"robots": out}, indent=1) + "\n")
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.duration is not None and not 0 < args.duration <= 86400:
        raise ConfigError(f"--duration {args.duration:g}: allowed: 0 to 86400 s")
    cfg = config_from_args(args)
    try:
        return main(cfg, args.robot, args.duration, args.report)
    except LinkError as exc:
        sys.stderr.write(f"observe: {exc}\n")
        return 1
    except OSError as exc:
        raise ConfigError(f"leader.cockpit_port: cannot serve ({exc}); allowed: a free port, or 0 for any") from None


def add_observe_parser(sub: Any) -> None:
    """``bipedtele observe``: the observer's cockpit."""
    p = sub.add_parser("observe", help="an observer's cockpit: its robots' video and status, commanding none")
    add_config_args(p)
    p.add_argument("--robot", action="append", metavar="ID", help="a robot to watch (repeat; default: every watch key)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--report", type=Path, metavar="FILE", help="write what was received per robot as JSON at the end")
    p.set_defaults(func=_run)
