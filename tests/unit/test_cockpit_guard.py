"""The cockpit's guard without a leader: header timeout, connection caps, failed-token
lockout (429, the token's holder still served), throttled logs, the cockpit in its own
process, and the demo's token-holding log files (0600 in a 0700 folder)."""

from __future__ import annotations

import asyncio
import json
import logging
import socket
import stat
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import aiohttp
import pytest
from bipedtele.leader.cockpit import CockpitProcess, CockpitServer
from bipedtele.leader.cockpit.guard import Guard, Limits, Throttle, descriptor_budget


def _get(url: str) -> int:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return int(r.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)


def _closed_within(s: socket.socket, seconds: float) -> float | None:
    """Seconds until the server closes ``s`` (None if still open after ``seconds``)."""
    t0 = time.monotonic()
    while True:  # what is still to come of an answer is read on the way
        left = seconds - (time.monotonic() - t0)
        if left <= 0:
            return None
        s.settimeout(left)
        try:
            data = s.recv(4096)
        except TimeoutError:
            return None
        except OSError:
            data = b""
        if not data:
            return time.monotonic() - t0


@pytest.mark.timeout(30)
def test_half_sent_heads_are_closed_and_idle_keep_alive_too() -> None:
    limits = Limits(header_timeout_s=0.5, idle_timeout_s=1.0)
    with CockpitServer(limits=limits) as server:
        half = socket.create_connection(("127.0.0.1", server.port))
        half.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never finished
        silent = socket.create_connection(("127.0.0.1", server.port))
        assert (_closed_within(half, 3.0) or 9) < 2.0
        assert (_closed_within(silent, 3.0) or 9) < 2.0
        # A genuine keep-alive connection: served, then closed when idle.
        alive = socket.create_connection(("127.0.0.1", server.port))
        alive.sendall(f"GET /healthz?token={server.token} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
        assert alive.recv(12).startswith(b"HTTP/1.1 200")
        t = _closed_within(alive, 4.0)
        assert t is not None and 0.5 < t < 3.0, t
        assert server.stats["closed_no_head"] == 2


@pytest.mark.timeout(30)
def test_connections_over_the_cap_are_refused_at_once() -> None:
    with CockpitServer(limits=Limits(per_address=4, header_timeout_s=5.0)) as server:
        held = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(4)]
        for s in held:  # keep-alive connections of the token holder: none closed to make room
            s.sendall(f"GET /healthz?token={server.token} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
            assert s.recv(12).startswith(b"HTTP/1.1 200")
        time.sleep(0.2)
        extra = socket.create_connection(("127.0.0.1", server.port))
        assert (_closed_within(extra, 2.0) or 9) < 1.0  # reset at once
        assert server.stats["refused_conn_address"] >= 1 and server.stats["open_connections"] == 4
        for s in held:
            s.close()
        deadline = time.monotonic() + 5
        while server.stats["open_connections"] and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _get(server.url) == 200


@pytest.mark.timeout(30)
def test_failed_tokens_lock_the_address_but_not_the_token_holder() -> None:
    limits = Limits(fail_max=5, fail_window_s=10.0, lockout_s=30.0, hold_s=0.2)
    with CockpitServer(limits=limits) as server:
        codes = [_get(server.base_url + f"healthz?token={'x' * 32}") for _ in range(8)]
        assert codes[:5] == [403] * 5 and codes[5:] == [429] * 3, codes
        assert _get(server.url) == 200  # the right token is always served
        assert server.stats["lockouts"] == 1 and server.stats["refused_rate"] == 3


def test_guard_counts() -> None:
    g = Guard(Limits(per_address=2, fail_max=3, fail_window_s=1.0, lockout_s=5.0, refusals_per_s=2), total_cap=3)
    assert [g.admit("a"), g.admit("a"), g.admit("a")] == [None, None, "too_many_from_address"]
    assert g.admit("b") is None and g.admit("c") == "too_many_connections"
    g.release("a")
    assert g.admit("c") is None
    assert not g.failed("x", 0.0) and not g.failed("x", 0.5) and g.failed("x", 0.9)
    assert g.locked("x", 4.0) and not g.locked("x", 6.0)
    assert not g.failed("y", 0.0) and not g.failed("y", 2.0) and not g.failed("y", 4.0)  # spread out
    t = time.monotonic() + 100
    assert [g.may_answer(t), g.may_answer(t), g.may_answer(t)] == [True, True, False]
    cap, figures = descriptor_budget(Limits())
    assert 8 <= cap <= 256 and figures["nofile_soft"] > figures["descriptors_used"]


def test_throttle_one_line_per_kind_with_a_count(caplog: pytest.LogCaptureFixture) -> None:
    log = logging.getLogger("test.cockpit.throttle")
    log.addFilter(Throttle(interval_s=0.3))
    with caplog.at_level(logging.ERROR, logger=log.name):
        for _ in range(100):
            try:
                raise OSError(24, "Too many open files")
            except OSError:
                log.exception("accept failed")
        time.sleep(0.35)
        log.error("accept failed")
    lines = [r for r in caplog.records if r.name == log.name]
    assert len(lines) == 2
    assert lines[0].exc_info is None and "Too many open files" in lines[0].getMessage()
    assert "and 99 more like it" in lines[1].getMessage()


@pytest.mark.timeout(60)
def test_cockpit_process_serves_like_the_thread() -> None:
    with CockpitProcess(telemetry_hz=50.0) as cockpit:
        assert cockpit.pid is not None and cockpit.port > 0
        assert _get(cockpit.url) == 200 and _get(cockpit.base_url) == 403
        cockpit.publish_sample({"t": 1.0, "ref_v": 5.0})
        cockpit.publish_video("head", b"\xff\xd8jpeg\xff\xd9", 12.5)

        async def drive() -> list[str]:
            got: list[str] = []
            async with (
                aiohttp.ClientSession() as cs,
                cs.ws_connect(f"{cockpit.base_url}ws?token={cockpit.token}", origin=cockpit.base_url.rstrip("/")) as ws,
            ):
                end = time.monotonic() + 5
                while time.monotonic() < end and not {"samples", "video"} <= set(got):
                    msg = await ws.receive(timeout=5)
                    got.append(json.loads(msg.data)["type"] if msg.type == aiohttp.WSMsgType.TEXT else "video")
                await ws.send_str('{"type": "joy", "x": 0.25, "y": 1}')
                await asyncio.sleep(0.3)
            return got

        got = asyncio.run(drive())
        assert {"hello", "samples", "video"} <= set(got), got
        joy = cockpit.joystick()
        assert joy is not None and joy[:2] in ((0.25, 1.0), (0.0, 0.0)), joy  # centred once the driver left
        stats = cockpit.stats
        assert stats["joystick_messages"] == 1 and stats["frames_pushed"] >= 1 and stats["refused_token"] == 1
        pid = cockpit.pid
    assert cockpit.pid is None
    with pytest.raises(OSError):
        urllib.request.urlopen(f"http://127.0.0.1:{cockpit.port}/", timeout=2)
    assert pid is not None


def test_demo_logs_are_private(tmp_path: Path) -> None:
    from bipedtele.tools import demo

    run_dir = tmp_path / "run"
    run_dir.mkdir(mode=0o755)
    (run_dir / "leader.log").write_text("old\n")
    (run_dir / "leader.log").chmod(0o644)
    cmd = [sys.executable, "-c", "print('cockpit: open http://127.0.0.1:1/?token=secret')"]
    plan = SimpleNamespace(run_dir=run_dir, cockpit_token="t" * 32, commands=lambda: {"leader": cmd})
    run_dir.chmod(0o700)  # what run_demo does before it starts anything
    with demo._processes(plan) as procs:  # type: ignore[arg-type]
        procs["leader"].popen.wait(10)
    assert stat.S_IMODE((run_dir / "leader.log").stat().st_mode) == 0o600
    assert "token=secret" in (run_dir / "leader.log").read_text()


@pytest.mark.timeout(30)
def test_the_token_holder_gets_in_whatever_connections_without_it_hold() -> None:
    """Issue 32, item 6: slowloris connections filling the total cap (and the token holder's
    own address's cap) do not keep the operator's page out: the oldest of them is closed to
    make room. Before: the token holder's connection was reset at once."""
    limits = Limits(per_address=6, total=6, header_timeout_s=10.0)
    with CockpitServer(limits=limits) as server:
        server.guard.total_cap = 6  # not lowered by the descriptor budget
        slow = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(6)]
        for s in slow:
            s.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never finished
        time.sleep(0.3)
        assert server.stats["open_connections"] == 6
        assert [_get(server.url) for _ in range(3)] == [200, 200, 200]
        assert server.stats["evicted_untrusted"] >= 1
        assert _closed_within(slow[0], 0.5) is not None  # the oldest slow one went
        assert server.stats["open_connections"] <= 6
        for s in slow:
            s.close()
