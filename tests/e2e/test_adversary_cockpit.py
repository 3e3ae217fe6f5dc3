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
import re
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from urllib.parse import urlsplit

import aiohttp
import pytest
from bipedtele.drops import DropCounter
from bipedtele.messages import Command
from bipedtele.sections import NetworkConfig
from bipedtele.transport import Keys, MessageReceiver, open_session
from e2e_support import Proc, Procs, free_port

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
        p = procs.start("leader", [
            "leader", "--operator", "browser", "--set", f'robot.id="{robot}"',
            "--set", f'network.listen=["{endpoint}"]', "--set", "leader.cockpit_port=0",
            "--set", "record.enabled=false", "--duration", "0",
        ])  # fmt: skip
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


def _forward_commands(leader: Leader, attack: str, origin: str | None, headers: dict[str, str] | None = None) -> tuple[str, float]:
    """Run one websocket attack while listening to the leader's commands; return how the
    attack went and the largest forward speed the leader then commanded [cm/s]."""
    net = NetworkConfig(mode="peer", connect=[leader.endpoint], timeout_s=10.0)
    with open_session(net) as session, MessageReceiver(
        session, Keys(leader.robot).cmd, Command, DropCounter("test"), maxlen=100_000
    ) as rx:  # fmt: skip
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
