"""Cockpit server without a browser: endpoints, protocol, input validation, origin check."""

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
from bipedtele.leader.cockpit.server import _parse_joy


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


@pytest.mark.timeout(30)
def test_endpoints_and_websocket_protocol() -> None:
    server = CockpitServer(telemetry_hz=50.0)
    server.publish_sample({"t": 1.0, "ref_v": 5.0})  # before start: kept as latest
    with server:
        assert server.port > 0 and server.url == f"http://127.0.0.1:{server.port}/"
        status, body = _get(server.url + "healthz")
        assert status == 200 and json.loads(body)["ok"] is True
        status, page = _get(server.url)
        assert status == 200 and b"<canvas" in page and b"/static/app.js" in page
        for name in ("app.js", "plot.js", "style.css"):
            assert _get(server.url + "static/" + name)[0] == 200
        assert _get(server.url + "static/../server.py")[0] == 404
        assert _get(server.url + "video/head.jpg")[0] == 404
        server.publish_video("head", b"\xff\xd8fakejpeg", 12.5)
        status, jpeg = _get(server.url + "video/head.jpg")
        assert status == 200 and jpeg == b"\xff\xd8fakejpeg"
        time.sleep(0.1)
        server.publish_sample({"t": 2.0, "ref_v": float("nan"), "arr": (1, 2), "obj": object()})

        async def client() -> tuple[list[dict], list[bytes]]:
            texts: list[dict] = []
            frames: list[bytes] = []
            async with aiohttp.ClientSession() as cs, cs.ws_connect(server.url + "ws") as ws:
                def got_t2() -> bool:
                    return any(s.get("t") == 2.0 for m in texts for s in m.get("samples", []))

                while not got_t2() or not frames:
                    msg = await asyncio.wait_for(ws.receive(), 5)
                    if msg.type == aiohttp.WSMsgType.TEXT:
                        texts.append(json.loads(msg.data))
                    else:
                        frames.append(msg.data)
                await ws.send_str('{"type": "joy", "x": -0.5, "y": 1}')
                for bad in ("nope", '{"type": "joy", "x": 1.5, "y": 0}', '{"type": "x"}',
                            '{"type": "joy", "x": true, "y": 0}', "[" * 2000):  # fmt: skip
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
        assert set(stats["bad_by_reason"]) == {"not_json", "out_of_range", "unknown_type",
                                                "bad_number", "too_long", "binary"}  # fmt: skip
        # The driving browser left: the stick is centred.
        for _ in range(100):
            joy = server.joystick()
            if joy is not None and joy[:2] == (0.0, 0.0):
                break
            time.sleep(0.02)
        assert server.joystick()[:2] == (0.0, 0.0)
    assert server.port > 0
    with pytest.raises(OSError):
        _get(server.url + "healthz")  # stopped: nothing listens


@pytest.mark.timeout(30)
def test_cross_origin_websocket_refused() -> None:
    with CockpitServer() as server:

        async def attempt(origin: str) -> int:
            async with aiohttp.ClientSession() as cs:
                try:
                    async with cs.ws_connect(server.url + "ws", origin=origin):
                        return 101
                except aiohttp.WSServerHandshakeError as exc:
                    return exc.status

        assert asyncio.run(attempt("http://evil.example")) == 403
        assert asyncio.run(attempt(f"http://127.0.0.1:{server.port}")) == 101
        assert server.stats["refused_origin"] == 1


def test_port_in_use_and_bad_parameters() -> None:
    with CockpitServer() as first, pytest.raises(OSError):
        CockpitServer(port=first.port).start()
    with pytest.raises(ValueError, match="telemetry_hz"):
        CockpitServer(telemetry_hz=0)
    with pytest.raises(ValueError, match="port"):
        CockpitServer(port=70000)


@pytest.mark.parametrize(
    ("text", "reason"),
    [("{", "not_json"), ('{"type":"joy","x":null,"y":0}', "bad_number"),
     ('{"type":"joy","x":0,"y":-1.01}', "out_of_range"), ("[1]", "unknown_type")],
)  # fmt: skip
def test_parse_joy_rejects(text: str, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        _parse_joy(text)
    assert _parse_joy('{"type":"joy","x":-1,"y":1}') == (-1.0, 1.0)
