"""Attacks on the leader's browser cockpit, against a real leader process.

The leader runs with ``--operator browser``: whoever drives the cockpit's joystick drives
the robot. A test session subscribes to the leader's commands over Zenoh, so an attack that
works shows up as commands asking the robot to walk. The address the leader logs
(``cockpit: open http://127.0.0.1:PORT/?token=TOKEN``) is what its operator opens; the
attacker does not have it. Each test is one attack; every one succeeded against the
cockpit before it had access control (page and websocket open to anyone, Origin compared
with the attacker-controlled Host, no Origin accepted, no client cap, no framing policy).
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from urllib.parse import urlsplit

import aiohttp
import pytest
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import Command, Status
from bipedtele.link.receivers import MessageReceiver
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session
from e2e_support import HERE, Monitor, Proc, Procs, client_args, free_port, start_router, wait_until

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

FORWARD_JOY = '{"type": "joy", "x": 0, "y": 1}'


@dataclass
class Leader:
    proc: Proc
    url: str  # what the leader logged for its operator
    endpoint: str  # its Zenoh listen endpoint
    robot: str

    @property
    def base(self) -> str:
        parts = urlsplit(self.url)
        return f"{parts.scheme}://{parts.netloc}/"

    @property
    def port(self) -> int:
        return int(urlsplit(self.url).port or 80)

    @property
    def token(self) -> str:
        m = re.search(r"token=([^&\s]+)", self.url)
        return m.group(1) if m else ""


@pytest.fixture(scope="module")
def leader(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Leader]:
    folder = tmp_path_factory.mktemp("cockpit-adversary")
    procs = Procs(folder)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = f"ca{free_port()}"
    try:
        p = procs.start(
            "leader",
            [
                "leader",
                "--operator",
                "browser",
                "--set",
                f'robot.id="{robot}"',
                "--set",
                f'network.listen=["{endpoint}"]',
                "--set",
                "leader.cockpit_port=0",
                "--set",
                "record.enabled=false",
                "--duration",
                "0",
            ],
        )
        m = p.wait_log(r"leader ready.*cockpit (http://\S+)", 60.0)
        yield Leader(p, m.group(1), endpoint, robot)
    finally:
        procs.close()


def _http(url: str, headers: dict[str, str] | None = None) -> tuple[int, dict[str, str], bytes]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, dict(r.headers.items()), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers.items()), exc.read()


async def _drive(url: str, origin: str | None, headers: dict[str, str] | None = None, seconds: float = 1.5) -> str:
    """Open the cockpit websocket and hold the joystick forward; how it went."""
    async with aiohttp.ClientSession() as cs:
        try:
            async with cs.ws_connect(url, origin=origin, headers=headers) as ws:
                t_end = time.monotonic() + seconds
                while time.monotonic() < t_end:
                    await ws.send_str(FORWARD_JOY)
                    await asyncio.sleep(0.05)
                return "driven"
        except aiohttp.WSServerHandshakeError as exc:
            return f"refused {exc.status}"


def _forward_commands(
    leader: Leader, attack: str, origin: str | None, headers: dict[str, str] | None = None
) -> tuple[str, float]:
    """Run one websocket attack while listening to the leader's commands; return how the
    attack went and the largest forward speed the leader then commanded [cm/s]."""
    net = NetworkConfig(mode="peer", connect=[leader.endpoint], timeout_s=10.0)
    with (
        open_session(net) as session,
        MessageReceiver(session, Keys(leader.robot).cmd, Command, DropCounter("test"), maxlen=100_000) as rx,
    ):
        deadline = time.monotonic() + 10.0
        while not rx.drain() and time.monotonic() < deadline:  # the leader is heard
            time.sleep(0.05)
        outcome = asyncio.run(_drive(attack, origin, headers))
        time.sleep(0.5)  # the hand moves the handle; commands follow
        refs = [r.msg.ref[0] for r in rx.drain() if r.msg.enable]
    return outcome, max(refs, default=0.0)


@pytest.mark.timeout(120)
def test_the_printed_address_carries_a_token(leader: Leader) -> None:
    assert re.fullmatch(r"http://127\.0\.0\.1:\d+/\?token=[A-Za-z0-9_-]{32,}", leader.url), leader.url
    assert f"cockpit: open {leader.url}" in leader.proc.log()
    assert _http(leader.url)[0] == 200
    # The operator's own page drives the robot (so the refusals below are not a dead cockpit).
    outcome, forward = _forward_commands(leader, leader.base + f"ws?token={leader.token}", leader.base.rstrip("/"))
    assert outcome == "driven" and forward > 3.0, (outcome, forward)


@pytest.mark.timeout(120)
def test_no_token_no_cockpit(leader: Leader) -> None:
    outcome, forward = _forward_commands(leader, leader.base + "ws", leader.base.rstrip("/"))
    assert outcome == "refused 403" and forward < 0.5, (outcome, forward)
    for path in ("", "static/app.js", "healthz", "video/head.jpg"):
        status, _, _ = _http(leader.base + path)
        assert status == 403, (path, status)
    assert _http(leader.base + "?token=" + "A" * 32)[0] == 403


@pytest.mark.timeout(120)
def test_dns_rebinding_cannot_drive(leader: Leader) -> None:
    # evil.example now resolves to 127.0.0.1: the victim's browser sends Host and Origin
    # evil.example (both chosen by the attacker, so equal to each other).
    evil = f"evil.example:{leader.port}"
    outcome, forward = _forward_commands(leader, leader.base + "ws", f"http://{evil}", {"Host": evil})
    assert outcome == "refused 403" and forward < 0.5, (outcome, forward)
    assert _http(leader.base, {"Host": evil})[0] == 403


@pytest.mark.timeout(120)
def test_websocket_without_or_with_a_foreign_origin_is_refused(leader: Leader) -> None:
    ws = leader.base + f"ws?token={leader.token}"  # even with a leaked token
    for origin in (None, "http://evil.example", "null", f"http://127.0.0.1:{leader.port + 1}"):
        outcome, forward = _forward_commands(leader, ws, origin)
        assert outcome == "refused 403" and forward < 0.5, (origin, outcome, forward)


@pytest.mark.timeout(120)
def test_a_fifth_client_is_refused(leader: Leader) -> None:
    url, origin = leader.base + f"ws?token={leader.token}", leader.base.rstrip("/")

    async def five() -> tuple[list[str], str, int | None]:
        async with aiohttp.ClientSession() as cs:
            clients = [await cs.ws_connect(url, origin=origin) for _ in range(5)]
            first = []
            for ws in clients:
                msg = await ws.receive(timeout=10)
                first.append(json.loads(msg.data)["type"] if msg.type == aiohttp.WSMsgType.TEXT else str(msg.type))
            last = clients[-1]
            reason = first[-1]
            msg = await last.receive(timeout=10)
            code = last.close_code if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED) else None
            for ws in clients:
                await ws.close()
            return first[:-1], reason, code

    hellos, fifth, code = asyncio.run(five())
    assert hellos == ["hello"] * 4
    assert fifth == "refused" and code == 1013


@pytest.mark.timeout(120)
def test_no_site_can_frame_the_cockpit(leader: Leader) -> None:
    for url in (leader.url, leader.base):  # the page, and a refusal
        _, headers, _ = _http(url)
        assert "frame-ancestors 'none'" in headers.get("Content-Security-Policy", ""), headers
        assert headers.get("X-Frame-Options") == "DENY", headers


# --------------------------------------------------------------------------- floods
#
# Every flood runs as its own process (``cockpit_flood.py``), to 127.0.0.1 only, bounded in
# count and time. Before the cockpit had timeouts, caps and a failed-token rate limit
# (issue 20, item 4): 3,000 half-sent heads stayed open (none closed in 20 s, the leader's
# descriptors 23 -> 3,023); a token brute force made the 1 kHz haptic loop miss about 1,100
# ticks in 8 s; under a 1,024-descriptor limit the leader did not reconnect to a restarted
# router.

FLOOD = [sys.executable, str(HERE / "cockpit_flood.py")]
#: A leader under the descriptor limit of the issue's host (soft and hard 1024).
LIMITED = (
    "import resource, runpy, sys; resource.setrlimit(resource.RLIMIT_NOFILE, (1024, 1024)); "
    "sys.argv = ['bipedtele', *sys.argv[1:]]; runpy.run_module('bipedtele.cli', run_name='__main__')"
)


def _leader_args(robot: str, extra: list[str]) -> list[str]:
    return [
        "leader",
        "--operator",
        "browser",
        "--set",
        f'robot.id="{robot}"',
        "--set",
        "leader.cockpit_port=0",
        "--set",
        "record.enabled=false",
        "--duration",
        "0",
        *extra,
    ]


def _start_leader(procs: Procs, extra: list[str], *, limited: bool = False) -> Leader:
    robot = f"cf{free_port()}"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    args = _leader_args(robot, extra or ["--set", f'network.listen=["{endpoint}"]'])
    p = procs.start("leader", ["-c", LIMITED, *args], raw=True) if limited else procs.start("leader", args)
    m = p.wait_log(r"leader ready.*cockpit (http://\S+)", 60.0)
    return Leader(p, m.group(1), endpoint, robot)


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo.extend(int(c) for c in f.read().split())
        except OSError:
            continue
    return out


def _descriptors(pid: int) -> int:
    """Open descriptors of the leader and whatever it started (a cockpit process)."""
    n = 0
    for p in _tree(pid):
        try:
            n += len(os.listdir(f"/proc/{p}/fd"))
        except OSError:
            continue
    return n


def _flood(*args: str, timeout_s: float = 90.0) -> dict[str, object]:
    out = subprocess.run([*FLOOD, *args], capture_output=True, text=True, timeout=timeout_s, check=True)
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def _flood_bg(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([*FLOOD, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _genuine(leader: Leader, timeout_s: float = 10.0) -> int:
    """The operator's page load (with the token), retried for ``timeout_s``: the status."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return _http(leader.url)[0]
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


HELD_MAX_S = 11.0


@pytest.mark.timeout(180)
def test_idle_connections_are_closed_and_the_cockpit_still_answers(procs: Procs) -> None:
    leader = _start_leader(procs, [])
    time.sleep(2.0)
    fds0 = _descriptors(leader.proc.pid)
    flood = _flood_bg("idle", "--port", str(leader.port), "--n", "3000", "--seconds", "20")
    time.sleep(4.0)
    fds_peak = _descriptors(leader.proc.pid)
    out, err = flood.communicate(timeout=90)
    assert flood.returncode == 0, err
    res = json.loads(out.strip().splitlines()[-1])
    print(
        f"idle flood: {res['opened']} opened, {res['closed']} closed or refused, {res['still_open']} open "
        f"after 20 s (held {res['still_open_held_s']} s since acknowledged, {res['still_open_unacked']} never "
        f"acknowledged); closed p50 {res['closed_p50_s']} s, acknowledged-to-closed max "
        f"{res['ack_to_close_max_s']} s; descriptors {fds0} -> {fds_peak} (4 s in)"
    )
    assert res["opened"] == 3000, res
    # Closed by the header timeout (5 s from the accept) or refused at once by the caps. A
    # connection is judged from when the server's kernel acknowledged its half head: one
    # whose final ACK the kernel dropped while the accept queue was full completes only
    # when a SYN-ACK retransmission (1, 3, 7, 15 s) gets through, so on a loaded machine
    # some complete at 15 s and are still within their 5 s at the flood's end (a CI run had
    # 41 of 3,000 so). Without the header timeout every admitted connection is held the
    # 20 s or, with aiohttp's keep-alive timer, until 15 s after its accept (measured: 13.9 s
    # from the acknowledgement). HELD_MAX_S: the 5 s, a late accept of the niced cockpit
    # (its accept queue drains at 2,000 refusals a second at least), the 1 s poll.
    assert res["ack_to_close_max_s"] is not None and res["ack_to_close_max_s"] < HELD_MAX_S, res
    assert not res["still_open_held_s"] or max(res["still_open_held_s"]) < HELD_MAX_S, res
    assert _genuine(leader) == 200
    wait_until(
        lambda: _descriptors(leader.proc.pid) <= fds0 + 20,
        15.0,
        "the descriptors to come back",
        lambda: f"{fds0} -> {_descriptors(leader.proc.pid)}",
    )
    assert fds_peak < fds0 + 600, (fds0, fds_peak)
    log = leader.proc.log()
    assert "Traceback" not in log and len(log) < 200_000, log[-3000:]


def _missed_ticks(rx: MessageReceiver[Status], last: list[int], wait_s: float = 3.0) -> int:
    """The leader's ``missed_ticks`` counter in its newest status (waits for a fresh one)."""
    deadline = time.monotonic() + wait_s
    t_ask = time.time()
    while time.monotonic() < deadline:
        for r in rx.drain():
            if r.msg.role == "leader" and "missed_ticks" in r.msg.counters:
                last[:] = [int(r.msg.counters["missed_ticks"]), int(r.t_recv >= t_ask)]
        if last and last[1]:
            return last[0]
        time.sleep(0.05)
    raise AssertionError("no fresh leader status")


@pytest.mark.timeout(180)
def test_token_brute_force_is_rate_limited_and_spares_the_haptic_loop(procs: Procs) -> None:
    leader = _start_leader(procs, [])
    net = NetworkConfig(mode="peer", connect=[leader.endpoint], timeout_s=10.0)
    window = 8.0
    with (
        open_session(net) as session,
        MessageReceiver(session, Keys(leader.robot).status, Status, DropCounter("test"), maxlen=10_000) as rx,
    ):
        last: list[int] = []
        time.sleep(3.0)  # the leader settles
        m0 = _missed_ticks(rx, last)
        time.sleep(window)
        m1 = _missed_ticks(rx, last)
        res = _flood("brute", "--port", str(leader.port), "--requests", "40000", "--seconds", str(window))
        m2 = _missed_ticks(rx, last)
    rest, flooded = m1 - m0, m2 - m1
    status = res["status"]
    assert isinstance(status, dict)
    print(
        f"brute force: {res['sent']} guesses in {res['elapsed_s']} s ({res['rate_hz']}/s), answers {status}; "
        f"haptic loop missed {rest} ticks in {window:g} s at rest, {flooded} under the flood"
    )
    assert status.get("429", 0) > 0, status
    assert status.get("200", 0) == 0, status
    assert flooded <= 3 * rest + 100, (rest, flooded)  # 100 ticks: 1.25 % of the window (noise of a 2-core host)
    assert _genuine(leader) == 200  # the token's holder is never locked out
    log = leader.proc.log()
    assert "Traceback" not in log and len(log) < 200_000, log[-3000:]


@pytest.mark.timeout(240)
def test_leader_reconnects_to_a_restarted_router_while_the_cockpit_is_flooded(procs: Procs) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = start_router(procs, ep)
    leader = _start_leader(procs, client_args(ep), limited=True)
    with Monitor(ep, leader.robot) as mon:
        wait_until(
            lambda: any(r.msg.role == "leader" for r in (mon.poll(), mon.status)[1]), 20.0, "the leader's status"
        )
        idle = _flood_bg("idle", "--port", str(leader.port), "--n", "3000", "--seconds", "25")
        brute = _flood_bg("brute", "--port", str(leader.port), "--requests", "60000", "--seconds", "20")
        try:
            time.sleep(3.0)
            router.signal(signal.SIGKILL)
            router.popen.wait(timeout=10)
            time.sleep(3.0)
            t_back = time.time()
            start_router(procs, ep, name="router2")

            def back() -> bool:
                mon.poll()
                return any(r.msg.role == "leader" and r.t_recv > t_back for r in mon.status)

            wait_until(back, 15.0, "the leader's status through the new router")
            reconnect_s = min(r.t_recv for r in mon.status if r.msg.role == "leader" and r.t_recv > t_back) - t_back
        finally:
            for p in (idle, brute):
                p.communicate(timeout=90)
    print(f"leader heard through the new router {reconnect_s:.2f} s after it started (cockpit flooded)")
    assert reconnect_s < 5.0, reconnect_s
    assert leader.proc.alive(), leader.proc.tail()
    assert _genuine(leader) == 200
    log = leader.proc.log()
    assert "Traceback" not in log and len(log) < 500_000, log[-3000:]
