"""Helpers of the end-to-end tests: starting programs, monitoring a run.

Every program runs as ``python -m bipedtele.cli ...`` in its own process group (or inside
a network namespace with ``ip netns exec``), with stdout and stderr going to a log file in
the test's tmp folder. The :class:`Procs` fixture stops every process it started when the
test ends, pass or fail: SIGTERM to the process group, then SIGKILL after a grace period.

Helpers build the command-line overrides the tests share (client mode towards one
router, a short constant-speed script for the scripted operator, little or no video).
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import Feedback, Status
from bipedtele.link.receivers import MessageReceiver, Received
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session
from bipedtele.recording.format import Record, read_records

CLI = [sys.executable, "-m", "bipedtele.cli"]
HERE = Path(__file__).resolve().parent


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port on ``host`` that is free right now."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def client_args(endpoint: str) -> list[str]:
    """Overrides that make a program a Zenoh client of the router at ``endpoint``."""
    return [
        "--set",
        'network.mode="client"',
        "--set",
        f'network.connect=["{endpoint}"]',
        "--set",
        "network.listen=[]",
    ]


def walking_script(forward_cm_s: float = 5.0, turn_deg_s: float = 0.0, until_s: float = 600.0) -> list[str]:
    """Scripted operator holding a constant speed [cm/s, deg/s] from the start."""
    return [
        "--operator",
        "scripted",
        "--set",
        f"leader.script=[[0, {forward_cm_s:g}, {turn_deg_s:g}], [{until_s:g}, {forward_cm_s:g}, {turn_deg_s:g}]]",
        "--set",
        'leader.script_interp="step"',
        "--set",
        "leader.cockpit=false",
    ]


NO_VIDEO = ["--set", "follower.camera_fps=0"]
# The leader's blind stop off (60 s): after feedback older than blind_stop_s the robot walks
# again only when the operator moves the handle (tests/e2e/test_uplink_gap.py), which a
# constant script never does; for tests whose subject is elsewhere (a restart, a freeze).
NO_BLIND_STOP = ["--set", "leader.blind_stop_s=60"]
SLOW_VIDEO = ["--set", "follower.camera_fps=2", "--set", 'follower.cameras=["scene"]']


@dataclass
class Proc:
    """One started program."""

    name: str
    popen: subprocess.Popen[bytes]
    log_path: Path

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log(self) -> str:
        """The log so far (stdout and stderr together)."""
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def wait_log(self, pattern: str, timeout_s: float) -> re.Match[str]:
        """Wait until a line of the log matches ``pattern``; fail the test otherwise."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while True:
            m = rx.search(self.log())
            if m:
                return m
            if not self.alive():
                pytest.fail(f"{self.name} exited (rc {self.popen.returncode}) before {pattern!r}:\n{self.tail()}")
            if time.monotonic() > deadline:
                pytest.fail(f"{self.name}: no {pattern!r} within {timeout_s:g} s:\n{self.tail()}")
            time.sleep(0.05)

    def tail(self, n: int = 30) -> str:
        return "\n".join(self.log().splitlines()[-n:])

    def signal(self, sig: int) -> None:
        """Send ``sig`` to the process group (the program and anything it started)."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.popen.pid, sig)

    def stop(self, timeout_s: float = 10.0) -> int:
        """SIGTERM, wait up to ``timeout_s``, then SIGKILL; return the exit code."""
        if self.alive():
            self.signal(signal.SIGTERM)
            try:
                return self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.signal(signal.SIGKILL)
        return self.popen.wait(timeout=10.0)


class Procs:
    """Starts programs for one test and guarantees they are stopped afterwards."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.started: list[Proc] = []

    def start(
        self,
        name: str,
        args: list[str],
        *,
        netns: str | None = None,
        raw: bool = False,
        env: dict[str, str] | None = None,
    ) -> Proc:
        """Start ``python -m bipedtele.cli ARGS`` (``raw``: ``python ARGS``), logs to ``NAME.log``.

        ``netns``: run it inside that network namespace (``ip netns exec``).
        """
        argv = ([sys.executable] if raw else list(CLI)) + args
        if netns is not None:
            argv = ["ip", "netns", "exec", netns, *argv]
        log_path = self.folder / f"{name}.log"
        n = 1
        while log_path.exists():
            n += 1
            log_path = self.folder / f"{name}-{n}.log"
        full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        with open(log_path, "wb") as log:
            popen = subprocess.Popen(
                argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
                cwd=self.folder,
                env=full_env,
            )
        proc = Proc(name, popen, log_path)
        self.started.append(proc)
        return proc

    def close(self) -> None:
        """Stop everything still running: SIGTERM to all, then SIGKILL to what is left."""
        running = [p for p in self.started if p.alive()]
        for p in reversed(running):
            p.signal(signal.SIGTERM)
        deadline = time.monotonic() + 8.0
        for p in running:
            try:
                p.popen.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.signal(signal.SIGKILL)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    p.popen.wait(timeout=5.0)

    def logs(self) -> str:
        """The tails of every log (for failure messages)."""
        return "\n".join(f"--- {p.name} ({p.log_path.name})\n{p.tail(15)}" for p in self.started)


def wait_until(pred: Callable[[], bool], timeout_s: float, what: str, on_fail: Callable[[], str] = str) -> None:
    """Poll ``pred`` every 50 ms until true; fail the test with ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s:g} s waiting for {what}\n{on_fail()}")
        time.sleep(0.05)


# --------------------------------------------------------------------------- programs

READY = {
    "router": r"router: \S+ listening on",
    "follower": r"follower \S+ ready",
    "leader": r"leader ready",
}


def start_router(
    procs: Procs,
    endpoint: str,
    extra: list[str] | None = None,
    *,
    netns: str | None = None,
    name: str = "router",
    env: dict[str, str] | None = None,
) -> Proc:
    """Start ``bipedtele router --listen ENDPOINT`` and wait until it listens (``env``: added to its environment)."""
    p = procs.start(name, ["router", *(extra or []), "--listen", endpoint], netns=netns, env=env)
    p.wait_log(READY["router"], 30.0)
    return p


def start_follower(
    procs: Procs,
    endpoint: str,
    extra: list[str] | None = None,
    *,
    netns: str | None = None,
    name: str = "follower",
    record: Path | None = None,
    wait: bool = True,
    env: dict[str, str] | None = None,
) -> Proc:
    """Start the sim follower as a client of ``endpoint`` (recording to ``record``; ``env``: added to its environment)."""
    args = ["follower", *client_args(endpoint), *(extra or [])]
    if record is not None:
        args += ["--record", str(record)]
    p = procs.start(name, args, netns=netns, env=env)
    if wait:
        p.wait_log(READY["follower"], 60.0)
    return p


def start_leader(
    procs: Procs,
    endpoint: str,
    extra: list[str] | None = None,
    *,
    netns: str | None = None,
    name: str = "leader",
    record: Path | None = None,
    wait: bool = True,
    env: dict[str, str] | None = None,
) -> Proc:
    """Start the leader (sim Falcon) as a client of ``endpoint`` (recording to ``record``; ``env``: added to its environment)."""
    args = ["leader", *client_args(endpoint), *(extra or [])]
    if record is not None:
        args += ["--record", str(record)]
    p = procs.start(name, args, netns=netns, env=env)
    if wait:
        p.wait_log(READY["leader"], 60.0)
    return p


def start_delay_proxy(
    procs: Procs, listen_port: int, target_port: int, forward: str, backward: str, *, name: str = "proxy"
) -> Proc:
    """Start ``bipedtele delay-proxy`` from 127.0.0.1:LISTEN_PORT to 127.0.0.1:TARGET_PORT.

    ``forward`` delays what flows towards the target (h1 for a leader behind the proxy),
    ``backward`` what flows back (h2); delay models as on the command line (``const:100ms``).
    """
    p = procs.start(
        name,
        [
            "delay-proxy",
            "--listen",
            f"127.0.0.1:{listen_port}",
            "--target",
            f"127.0.0.1:{target_port}",
            "--forward",
            forward,
            "--backward",
            backward,
        ],
    )
    p.wait_log(r"delay-proxy: listening on", 30.0)
    return p


# --------------------------------------------------------------------------- monitor


class Monitor:
    """A Zenoh client session in the test that watches one robot's feedback and status.

    Every valid Feedback and Status is kept with its receive time (``time.time()``).
    ``user`` and ``password`` log it in where the router requires it.
    """

    def __init__(self, endpoint: str, robot_id: str = "nao1", *, user: str = "", password: str = "") -> None:
        self.endpoint = endpoint
        self.user, self.password = user, password
        self.keys = Keys(robot_id)
        self.drops = DropCounter("monitor")
        self.feedback: list[Received[Feedback]] = []
        self.status: list[Received[Status]] = []
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> Monitor:
        net = NetworkConfig(
            mode="client", connect=[self.endpoint], timeout_s=10.0, user=self.user, password=self.password
        )
        session = self._stack.enter_context(open_session(net))
        self._fb = self._stack.enter_context(
            MessageReceiver(session, self.keys.feedback, Feedback, self.drops, maxlen=1_000_000)
        )
        self._st = self._stack.enter_context(
            MessageReceiver(session, self.keys.status, Status, self.drops, maxlen=1_000_000)
        )
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def poll(self) -> None:
        """Move what arrived into ``feedback`` and ``status``."""
        self.feedback.extend(self._fb.drain())
        self.status.extend(self._st.drain())

    def states_since(self, t: float) -> list[str]:
        self.poll()
        return [r.msg.state for r in self.feedback if r.t_recv >= t]

    def wait_state(self, state: str, since: float, timeout_s: float, hold_s: float = 0.0) -> float:
        """Wait for feedback in ``state`` received after ``since`` that stays so for ``hold_s``.

        Returns the receive time [s] of the first feedback of that stretch.
        """
        first: list[float] = []

        def ok() -> bool:
            self.poll()
            first.clear()
            start = None
            for r in self.feedback:
                if r.t_recv < since:
                    continue
                start = (r.t_recv if start is None else start) if r.msg.state == state else None
            if start is None or self.feedback[-1].t_recv - start < hold_s:
                return False
            first.append(start)
            return True

        wait_until(
            ok,
            timeout_s,
            f"feedback state {state!r} for {hold_s:g} s",
            lambda: f"states: {self.states_since(since)[-20:]}",
        )
        return first[0]

    def follower_status(self) -> list[Received[Status]]:
        self.poll()
        return [r for r in self.status if r.msg.role == "follower"]


# --------------------------------------------------------------------------- recordings


def records(path: Path, topic: str | None = None) -> list[Record]:
    """Records of one MCAP file (all topics, or one)."""
    return [r for r in read_records(path) if topic is None or r.topic == topic]
