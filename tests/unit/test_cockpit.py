"""Cockpit server without a browser: endpoints, protocol, input validation, and access:
per-run token, Host allow-list (DNS rebinding), websocket Origin, client cap, headers."""

from __future__ import annotations

import asyncio
import json
import struct
import time
import urllib.error
import urllib.request

import aiohttp
import pytest
from bipedtele.leader.cockpit import CockpitServer
from bipedtele.leader.cockpit.guard import Limits
from bipedtele.leader.cockpit.server import _parse_in


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def _request(url: str, headers: dict[str, str] | None = None) -> tuple[int, dict[str, str], bytes]:
    """GET with explicit headers (``Host`` replaces the one urllib would send)."""
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=5) as r:
            return r.status, dict(r.headers.items()), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers.items()), exc.read()


def _u(server: CockpitServer, path: str = "", token: str | None = None) -> str:
    """``http://127.0.0.1:PORT/PATH?token=...`` (the server's own token unless given)."""
    return f"{server.base_url}{path}?token={server.token if token is None else token}"


def _origin(server: CockpitServer) -> str:
    return server.base_url.rstrip("/")


async def _ws_status(url: str, origin: str | None = None, headers: dict[str, str] | None = None) -> int:
    """HTTP status of a websocket upgrade (101 when accepted)."""
    async with aiohttp.ClientSession() as cs:
        try:
            async with cs.ws_connect(url, origin=origin, headers=headers):
                return 101
        except aiohttp.WSServerHandshakeError as exc:
            return exc.status


@pytest.mark.timeout(30)
def test_endpoints_and_websocket_protocol() -> None:
    server = CockpitServer(telemetry_hz=50.0)
    server.publish_sample({"t": 1.0, "ref_v": 5.0})  # before start: kept as latest
    with server:
        assert server.port > 0 and server.base_url == f"http://127.0.0.1:{server.port}/"
        assert server.url == f"http://127.0.0.1:{server.port}/?token={server.token}"
        assert len(server.token) >= 32
        status, body = _get(_u(server, "healthz"))
        assert status == 200 and json.loads(body)["ok"] is True
        status, page = _get(server.url)
        assert status == 200 and b"<canvas" in page and b"/static/app.js" in page
        for name in ("app.js", "plot.js", "style.css"):
            assert _get(_u(server, "static/" + name))[0] == 200
        assert _get(_u(server, "static/../server.py"))[0] == 404
        assert _get(_u(server, "video/head.jpg"))[0] == 404
        server.publish_video("head", b"\xff\xd8fakejpeg", 12.5)
        status, jpeg = _get(_u(server, "video/head.jpg"))
        assert status == 200 and jpeg == b"\xff\xd8fakejpeg"
        time.sleep(0.1)
        server.publish_sample({"t": 2.0, "ref_v": float("nan"), "arr": (1, 2), "obj": object()})

        async def client() -> tuple[list[dict], list[bytes]]:
            texts: list[dict] = []
            frames: list[bytes] = []
            async with (
                aiohttp.ClientSession() as cs,
                cs.ws_connect(_u(server, "ws"), origin=_origin(server)) as ws,
            ):

                def got_t2() -> bool:
                    return any(s.get("t") == 2.0 for m in texts for s in m.get("samples", []))

                while not got_t2() or not frames:
                    msg = await asyncio.wait_for(ws.receive(), 5)
                    if msg.type == aiohttp.WSMsgType.TEXT:
                        texts.append(json.loads(msg.data))
                    else:
                        frames.append(msg.data)
                await ws.send_str('{"type": "joy", "x": -0.5, "y": 1}')
                for bad in (
                    "nope",
                    '{"type": "joy", "x": 1.5, "y": 0}',
                    '{"type": "x"}',
                    '{"type": "joy", "x": true, "y": 0}',
                    "[" * 2000,
                ):
                    await ws.send_str(bad)
                await ws.send_bytes(b"\x00")
                await ws.send_str('{"type": "joy", "x": 0.25, "y": -0.75}')
                for _ in range(100):
                    if server.stats["joystick_messages"] == 2:
                        break
                    await asyncio.sleep(0.02)
                assert server.joystick()[:2] == (0.25, -0.75)
            return texts, frames

        texts, frames = asyncio.run(client())
        assert texts[0]["type"] == "hello"
        samples = [s for m in texts[1:] for s in m["samples"]]
        assert samples[-1] == {"t": 2.0, "ref_v": None, "arr": [1, 2], "obj": samples[-1]["obj"]}
        assert isinstance(samples[-1]["obj"], str)
        frame = frames[0]
        assert frame[:2] == b"VF" and frame[2] == 4 and frame[3:7] == b"head"
        t, _n = struct.unpack("<dI", frame[7:19])
        assert t == 12.5 and frame[19:] == b"\xff\xd8fakejpeg"
        stats = server.stats
        assert stats["bad_messages"] == 6
        assert set(stats["bad_by_reason"]) == {
            "not_json",
            "out_of_range",
            "unknown_type",
            "bad_number",
            "too_long",
            "binary",
        }
        # The driving browser left: the stick is centred.
        for _ in range(100):
            joy = server.joystick()
            if joy is not None and joy[:2] == (0.0, 0.0):
                break
            time.sleep(0.02)
        assert server.joystick()[:2] == (0.0, 0.0)
    assert server.port > 0
    with pytest.raises(OSError):
        _get(_u(server, "healthz"))  # stopped: nothing listens


@pytest.mark.timeout(30)
def test_every_request_needs_the_token() -> None:
    many = Limits(fail_max=100)  # 18 refusals from one address: no lockout here (see test_cockpit_guard)
    with CockpitServer(limits=many) as server, CockpitServer() as other:
        assert server.token != other.token  # one per run
        paths = ("", "static/app.js", "healthz", "video/head.jpg", "ws")
        for path in paths:
            assert _get(server.base_url + path)[0] == 403, path  # no token
            assert _get(_u(server, path, token="x" * 32))[0] == 403, path  # wrong token
            assert _get(_u(server, path, token=other.token))[0] == 403, path  # another run's
        status, _, body = _request(server.base_url)
        assert status == 403 and b"?token=" in body  # says what to open
        # The printed address works and sets the cookie the page's own requests carry.
        status, headers, _ = _request(server.url)
        assert status == 200
        cookie = headers["Set-Cookie"]
        assert cookie.startswith(f"{server.cookie_name}={server.token};")
        assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
        with_cookie = {"Cookie": f"{server.cookie_name}={server.token}"}
        for path in ("static/app.js", "healthz", ""):
            assert _request(server.base_url + path, with_cookie)[0] == 200, path
        bad_cookie = {"Cookie": f"{server.cookie_name}={other.token}"}
        assert _request(server.base_url + "healthz", bad_cookie)[0] == 403
        # The websocket too: no token -> refused even with the right Origin; cookie or query -> in.
        assert asyncio.run(_ws_status(server.base_url + "ws", _origin(server))) == 403
        assert asyncio.run(_ws_status(server.base_url + "ws", _origin(server), with_cookie)) == 101
        assert asyncio.run(_ws_status(_u(server, "ws"), _origin(server))) == 101
        assert server.stats["refused_token"] == 3 * len(paths) + 3


@pytest.mark.timeout(30)
def test_dns_rebinding_host_is_refused() -> None:
    # A page on evil.example whose name now resolves to 127.0.0.1 reaches this port with
    # Host (and Origin) evil.example: refused, even with the token (e.g. leaked in a log).
    with CockpitServer(allowed_hosts=["Robot-Desk.lan"]) as server:
        port = server.port
        for host in (
            f"evil.example:{port}",
            "evil.example",
            f"127.0.0.1.evil.example:{port}",
            f"user@localhost:{port}",
            "",
        ):
            status, headers, _ = _request(server.url, {"Host": host})
            assert status == 403, host
            assert "frame-ancestors 'none'" in headers["Content-Security-Policy"]
        evil = {"Host": f"evil.example:{port}"}
        assert asyncio.run(_ws_status(_u(server, "ws"), f"http://evil.example:{port}", evil)) == 403
        for host in (f"localhost:{port}", f"127.0.0.1:{port}", f"robot-desk.lan:{port}", "LOCALHOST"):
            assert _request(server.url, {"Host": host})[0] == 200, host
        assert server.stats["refused_host"] == 6
    with pytest.raises(ValueError, match="allowed_hosts"):
        CockpitServer(allowed_hosts=["http://x/y"])


@pytest.mark.timeout(30)
def test_websocket_needs_this_pages_origin() -> None:
    with CockpitServer() as server:
        url = _u(server, "ws")
        port = server.port
        assert asyncio.run(_ws_status(url)) == 403  # no Origin (not a browser page of ours)
        for origin in (
            "http://evil.example",
            f"http://evil.example:{port}",
            "null",
            f"http://127.0.0.1:{port + 1 if port < 65535 else port - 1}",  # another local site
            f"file://127.0.0.1:{port}",
            f"http://localhost:{port}",
        ):
            # (localhost is allowed, but this request's Host is 127.0.0.1: not this page)
            assert asyncio.run(_ws_status(url, origin)) == 403, origin
        assert asyncio.run(_ws_status(url, f"http://127.0.0.1:{port}")) == 101
        assert asyncio.run(_ws_status(url, f"http://localhost:{port}", {"Host": f"localhost:{port}"})) == 101
        assert server.stats["refused_origin"] == 7
        assert server.joystick() is None


@pytest.mark.timeout(30)
def test_only_an_authenticated_page_moves_the_joystick() -> None:
    with CockpitServer() as server:

        async def push(url: str, origin: str | None) -> str:
            async with aiohttp.ClientSession() as cs:
                try:
                    async with cs.ws_connect(url, origin=origin) as ws:
                        await ws.send_str('{"type": "joy", "x": 0.5, "y": 1}')
                        await ws.receive(timeout=5)  # hello
                        for _ in range(100):
                            if server.joystick() is not None:
                                break
                            await asyncio.sleep(0.02)
                        return "open"
                except aiohttp.WSServerHandshakeError as exc:
                    return str(exc.status)

        assert asyncio.run(push(server.base_url + "ws", _origin(server))) == "403"
        assert asyncio.run(push(_u(server, "ws", token="A" * 32), _origin(server))) == "403"
        assert asyncio.run(push(_u(server, "ws"), None)) == "403"
        assert server.joystick() is None and server.stats["joystick_messages"] == 0
        assert asyncio.run(push(_u(server, "ws"), _origin(server))) == "open"
        # moved, then centred when it left (the server handles the close on its own thread)
        deadline = time.monotonic() + 5.0
        while (joy := server.joystick()) is not None and joy[:2] != (0.0, 0.0) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert joy is not None and joy[:2] == (0.0, 0.0)
        assert server.stats["joystick_messages"] == 1


@pytest.mark.timeout(30)
def test_client_cap_refuses_the_next_browser_clearly() -> None:
    with CockpitServer(max_clients=4) as server:

        async def scenario() -> tuple[list[str], int | None, str]:
            async with aiohttp.ClientSession() as cs:
                url, origin = _u(server, "ws"), _origin(server)
                first = [await cs.ws_connect(url, origin=origin) for _ in range(4)]
                hellos = [json.loads((await ws.receive(timeout=5)).data)["type"] for ws in first]
                fifth = await cs.ws_connect(url, origin=origin)
                refusal = json.loads((await fifth.receive(timeout=5)).data)
                closing = await fifth.receive(timeout=5)
                assert closing.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED)
                code = fifth.close_code
                assert refusal["type"] == "refused" and "too many" in refusal["reason"]
                await first[0].close()
                for _ in range(100):
                    if server.stats["clients"] == 3:
                        break
                    await asyncio.sleep(0.02)
                again = await cs.ws_connect(url, origin=origin)  # a slot is free again
                hello = json.loads((await again.receive(timeout=5)).data)["type"]
                for ws in [*first[1:], again]:
                    await ws.close()
                return hellos, code, hello

        hellos, code, hello = asyncio.run(scenario())
        assert hellos == ["hello"] * 4 and code == 1013 and hello == "hello"
        assert server.stats["refused_full"] == 1 and server.stats["connections"] == 5


@pytest.mark.timeout(30)
def test_no_framing_headers_on_every_response() -> None:
    with CockpitServer() as server:
        for url in (
            server.url,
            _u(server, "static/app.js"),
            _u(server, "healthz"),
            _u(server, "video/none.jpg"),
            server.base_url,
            _u(server, "ws"),
        ):
            status, headers, _ = _request(url)
            assert status in (200, 400, 403, 404), url
            csp = headers.get("Content-Security-Policy", "")
            assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp, (url, headers)
            assert headers.get("X-Frame-Options") == "DENY", url
            assert headers.get("Referrer-Policy") == "no-referrer", url


def test_token_and_cap_parameters() -> None:
    with CockpitServer(token="my-chosen-token-0123456789") as server:
        assert server.url.endswith("/?token=my-chosen-token-0123456789")
    for bad in ("short", "has space in the token ok", "x" * 15):
        with pytest.raises(ValueError, match="token"):
            CockpitServer(token=bad)
    with pytest.raises(ValueError, match="max_clients"):
        CockpitServer(max_clients=0)


def test_port_in_use_and_bad_parameters() -> None:
    with CockpitServer() as first, pytest.raises(OSError):
        CockpitServer(port=first.port).start()
    with pytest.raises(ValueError, match="telemetry_hz"):
        CockpitServer(telemetry_hz=0)
    with pytest.raises(ValueError, match="port"):
        CockpitServer(port=70000)


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("{", "not_json"),
        ('{"type":"joy","x":null,"y":0}', "bad_number"),
        ('{"type":"joy","x":0,"y":-1.01}', "out_of_range"),
        ("[1]", "unknown_type"),
        ('{"type":"hand","release":1}', "bad_hand"),
        ('{"type":"hand"}', "bad_hand"),
        ('{"type":"pad","src":"mouse","x":0,"y":0,"held":true}', "bad_pad"),
        ('{"type":"pad","src":"gamepad","x":0,"y":0,"held":1}', "bad_pad"),
        ('{"type":"pad","src":"gamepad","x":2,"y":0,"held":true}', "out_of_range"),
    ],
)
def test_parse_in_rejects(text: str, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        _parse_in(text)
    assert _parse_in('{"type":"joy","x":-1,"y":1}') == (-1.0, 1.0)
    assert _parse_in('{"type":"hand","release":true}') is True
    assert _parse_in('{"type":"pad","src":"keyboard","x":1,"y":-1,"held":false}') == ("keyboard", 1.0, -1.0, False)


def test_docs_name_every_field_the_cockpit_is_sent() -> None:
    """Issue 24: docs/cockpit.md's key table matches the fields the leader sends the page."""
    import re
    from pathlib import Path

    from bipedtele.telemetry import LeaderSample

    doc = (Path(__file__).resolve().parents[2] / "docs" / "cockpit.md").read_text(encoding="utf-8")
    table = "\n".join(line for line in doc.splitlines() if line.startswith("| `"))
    named = set(re.findall(r"`([a-z_0-9A-Z]+)`", table))
    missing = [f for f in LeaderSample.__struct_fields__ if f not in named]
    assert not missing, f"docs/cockpit.md does not describe: {missing}"
