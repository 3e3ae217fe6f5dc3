"""``bipedtele demo``: the whole teleoperation on one machine, with emulated delay.

Starts four processes and wires them like an intercontinental run::

    leader (client) --tcp--> delay proxy (h1 forward / h2 backward) --tcp--> router <-- follower (client)

Both sides are Zenoh clients of the router, so all their traffic crosses the proxy and
nothing bypasses the delay. The demo prints the cockpit URL, waits for the operator to
finish the task (or ``--duration``), stops every process cleanly (SIGTERM, then SIGKILL
after a grace period), and prints the Table 2 report computed from the leader's
recording (the same JSON keys as ``bipedtele report``).

The core starts the leader and follower by command name, so it imports neither.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from bipedtele.cli import OneLineParser, add_config_args
from bipedtele.config import ConfigError, load_config
from bipedtele.delaymodels import parse_delay_model
from bipedtele.shutdown import shutdown_on_signals

__all__ = ["DemoPlan", "add_demo_parser", "run_demo"]

LOG = logging.getLogger(__name__)

DEFAULT_DELAY = ("trace:intercontinental:h1", "trace:intercontinental:h2")


def _say(line: str) -> None:
    """CLI output (not logging: this is what the user asked the command for)."""
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class DemoPlan:
    """Everything the demo starts; built from the arguments, inspectable by tests."""

    run_dir: Path
    profile: str
    overrides: list[str]
    forward: str
    backward: str
    operator: str
    duration_s: float | None
    headless: bool
    record: Path
    router_port: int = field(default_factory=free_port)
    proxy_port: int = field(default_factory=free_port)
    cockpit_port: int = field(default_factory=free_port)
    follower_args: list[str] = field(default_factory=list)
    leader_args: list[str] = field(default_factory=list)
    t0: float = field(default_factory=time.time)

    def commands(self) -> dict[str, list[str]]:
        """Command lines of the four processes, in start order."""
        exe = [sys.executable, "-m", "bipedtele.cli"]
        common = ["--config", self.profile]
        for item in self.overrides:
            common += ["--set", item]
        router_ep = f"tcp/127.0.0.1:{self.router_port}"
        proxy_ep = f"tcp/127.0.0.1:{self.proxy_port}"
        leader = [
            *exe, "leader", *common,
            "--set", 'network.mode="client"', "--set", f'network.connect=["{proxy_ep}"]',
            "--set", 'network.listen=[]',
            "--set", f"leader.cockpit_port={0 if self.headless else self.cockpit_port}",
            "--operator", self.operator, "--record", str(self.record),
            *self.leader_args,
        ]
        if self.duration_s is not None:
            leader += ["--duration", f"{self.duration_s:g}"]
        return {
            "router": [*exe, "router", *common, "--listen", router_ep],
            "proxy": [
                *exe, "delay-proxy", "--listen", f"127.0.0.1:{self.proxy_port}",
                "--target", f"127.0.0.1:{self.router_port}",
                "--forward", self.forward, "--backward", self.backward, "--t0", f"{self.t0:.6f}",
            ],
            "follower": [
                *exe, "follower", *common,
                "--set", 'network.mode="client"', "--set", f'network.connect=["{router_ep}"]',
                "--set", 'network.listen=[]',
                "--record", str(self.run_dir / "follower.mcap"), *self.follower_args,
            ],
            "leader": leader,
        }


@dataclass
class _Proc:
    name: str
    popen: subprocess.Popen[bytes]
    log: IO[bytes]


@contextlib.contextmanager
def _processes(plan: DemoPlan) -> Iterator[dict[str, _Proc]]:
    """Start the processes (each in its own process group); stop them all on exit."""
    procs: dict[str, _Proc] = {}
    try:
        for name, cmd in plan.commands().items():
            log = open(plan.run_dir / f"{name}.log", "wb")  # noqa: SIM115 - closed below
            LOG.debug("starting %s: %s", name, " ".join(cmd))
            popen = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            procs[name] = _Proc(name, popen, log)
            time.sleep(0.3 if name in ("router", "proxy") else 0.0)
        yield procs
    finally:
        # Leader first (it releases the robot), then follower, proxy, router.
        for name in ("leader", "follower", "proxy", "router"):
            p = procs.get(name)
            if p is not None and p.popen.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.popen.pid, signal.SIGTERM)
        deadline = time.monotonic() + 10.0
        for p in procs.values():
            try:
                p.popen.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                LOG.warning("%s did not stop on SIGTERM: killing it", p.name)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.popen.pid, signal.SIGKILL)
                p.popen.wait(timeout=5.0)
            p.log.close()


def run_demo(plan: DemoPlan, *, json_path: Path | None = None) -> int:
    """Run the demo described by ``plan``; print the report. Returns the exit code."""
    from bipedtele.recording import read_records
    from bipedtele.report import compute_report, format_report

    plan.run_dir.mkdir(parents=True, exist_ok=True)
    plan.t0 = time.time()  # origin of trace delay models (recorded for later checks)
    (plan.run_dir / "plan.json").write_text(
        json.dumps({"t0": plan.t0, "forward": plan.forward, "backward": plan.backward,
                    "commands": plan.commands()}, indent=2) + "\n"
    )
    with shutdown_on_signals() as stop, _processes(plan) as procs:
        if not plan.headless:
            _say(f"cockpit: http://127.0.0.1:{plan.cockpit_port}/")
        _say(f"run folder: {plan.run_dir}  (logs and recordings)")
        leader = procs["leader"].popen
        while not stop.is_set():
            if leader.poll() is not None:
                break
            dead = [n for n in ("router", "proxy", "follower") if procs[n].popen.poll() is not None]
            if dead:
                LOG.error("%s exited early; see %s", dead[0], plan.run_dir / f"{dead[0]}.log")
                break
            time.sleep(0.2)
        leader_rc = leader.poll()
    if not plan.record.exists():
        sys.stderr.write(f"bipedtele demo: no recording at {plan.record}; see the logs in {plan.run_dir}\n")
        return 1
    report = compute_report(read_records(plan.record))
    _say(format_report(report))
    if json_path is not None:
        json_path.write_text(json.dumps(report, indent=2) + "\n")
    return 0 if leader_rc in (0, None) else 1


def _parse_delay(text: str) -> tuple[str, str]:
    parts = text.split(",")
    if len(parts) != 2:
        raise ConfigError(f"--delay {text!r}: allowed: FORWARD,BACKWARD models, e.g. const:150ms,const:220ms")
    for p in parts:
        parse_delay_model(p)
    return parts[0], parts[1]


def _run(args: argparse.Namespace) -> int:
    if args.delay_trace and args.delay:
        raise ConfigError("--delay-trace and --delay: allowed: at most one of them")
    if args.delay_trace:
        path = Path(args.delay_trace)
        forward, backward = f"trace:{path}:h1", f"trace:{path}:h2"
        parse_delay_model(forward)
    elif args.delay:
        forward, backward = _parse_delay(args.delay)
    else:
        forward, backward = DEFAULT_DELAY
    load_config(args.config, args.overrides)  # fail early, before any process starts
    if args.duration is not None and args.duration <= 0:
        raise ConfigError(f"--duration {args.duration}: allowed: a number of seconds > 0")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    run_dir = Path(args.run_dir or Path("runs") / f"demo-{stamp}")
    record = Path(args.record) if args.record else run_dir / "leader.mcap"
    plan = DemoPlan(
        run_dir=run_dir,
        profile=args.config,
        overrides=list(args.overrides),
        forward=forward,
        backward=backward,
        operator=args.operator,
        duration_s=args.duration,
        headless=args.headless,
        record=record,
    )
    return run_demo(plan, json_path=Path(args.json) if args.json else None)


def add_demo_parser(sub: Any) -> None:
    """``bipedtele demo``: router, follower, leader and delay proxy on this machine."""
    p: OneLineParser = sub.add_parser(
        "demo", help="run the whole teleoperation on this machine with an intercontinental delay"
    )
    add_config_args(p, default="localhost-delay")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default: when the task is done)")
    p.add_argument("--delay-trace", default=None, metavar="F", help="CSV trace t_s,h1_ms,h2_ms (default: the shipped intercontinental trace)")
    p.add_argument("--delay", default=None, metavar="FWD,BWD", help="delay models, e.g. const:150ms,const:220ms")
    p.add_argument("--operator", default="pilot", choices=["pilot", "scripted", "browser"], help="who drives (default: pilot)")
    p.add_argument("--headless", action="store_true", help="no cockpit server")
    p.add_argument("--record", default=None, metavar="F.mcap", help="leader recording (default: RUN_DIR/leader.mcap)")
    p.add_argument("--json", default=None, metavar="F", help="write the report as JSON")
    p.add_argument("--run-dir", default=None, metavar="DIR", help="folder for logs and recordings")
    p.set_defaults(func=_run)
