"""The websocket feed: telemetry and video pushed to every browser, its joystick, pad and hand taken in.

The handlers are methods of :class:`Feed`, a base of
:class:`~bipedtele.leader.cockpit.server.CockpitServer`; the messages are
:mod:`bipedtele.leader.cockpit.protocol`'s.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import struct
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from aiohttp import WSMsgType, web
from bipedtele.leader.cockpit.access import Access
from bipedtele.leader.cockpit.protocol import _VIDEO_MAGIC, SAMPLE_KEYS, EncodedSample, _parse_in, _sample_json
from bipedtele.link.drops import DropCounter
from bipedtele.telemetry import LeaderSample

LOG = logging.getLogger("bipedtele.leader.cockpit")


class _Client:
    """One browser connection: what it has already been sent."""

    def __init__(self, ws: web.WebSocketResponse) -> None:
        self.ws = ws
        self.last_sample = -1
        self.last_frame: dict[str, int] = {}
        self.wake = asyncio.Event()  # set when a new video frame is there


class Feed(Access):
    """The websocket feed of :class:`~bipedtele.leader.cockpit.server.CockpitServer` (its attributes)."""

    telemetry_hz: float
    course: list[list[float]]
    force_max_n: float
    max_clients: int
    _period: float
    _sample: tuple[int, LeaderSample | EncodedSample | dict[str, Any]] | None
    _frames: dict[str, tuple[int, float, bytes]]
    _joy: tuple[float, float, float] | None
    _pad: tuple[str, float, float, bool, float] | None
    _released: bool
    _history: deque[tuple[int, str]]
    _clients: set[_Client]
    _drops: DropCounter
    _on_joystick: Callable[[tuple[float, float, float]], None] | None
    _on_hand: Callable[[bool], None] | None
    _on_pad: Callable[[tuple[str, float, float, bool, float]], None] | None

    async def _sampler(self) -> None:
        """Take the latest sample every telemetry period into the history."""
        last = 0
        while True:
            await asyncio.sleep(self._period)
            latest = self._sample
            if latest is not None and latest[0] != last:
                last = latest[0]
                self._history.append((last, _sample_json(latest[1])))

    def _wake_clients(self) -> None:
        for client in list(self._clients):
            client.wake.set()

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        if not self._origin_ok(request):
            limited = await self._limited(request, bad_token=False)
            if limited is not None:
                return limited
            origin = request.headers.get("Origin")
            raise self._refuse(
                "refused_origin",
                "bad_origin" if origin else "no_origin",
                f"Origin {str(origin)[:80]!r}",
                "websocket refused: it needs the Origin of this page (a browser sends it)",
            )
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=64 * 1024)
        client = _Client(ws)
        if len(self._clients) >= self.max_clients:
            self._counters["refused_full"] += 1
            self._refusals.drop("too_many_clients", f"{request.remote}")
            reason = f"too many cockpit clients (at most {self.max_clients}); close another tab and reload"
            await ws.prepare(request)
            await ws.send_str(json.dumps({"type": "refused", "reason": reason}))
            await ws.close(code=1013, message=reason.encode()[:120])
            return ws
        self._clients.add(client)  # before any await: the cap holds for concurrent upgrades
        try:
            await ws.prepare(request)
        except BaseException:
            self._clients.discard(client)
            raise
        self._counters["connections"] += 1
        pusher: asyncio.Task[None] | None = None
        moved_joystick = False
        try:
            await ws.send_str(
                json.dumps(
                    {
                        "type": "hello",
                        "telemetry_hz": self.telemetry_hz,
                        "keys": SAMPLE_KEYS,
                        "course": self.course,
                        "force_max_n": self.force_max_n,
                    }
                )
            )
            pusher = asyncio.create_task(self._push(client))
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    moved_joystick |= self._on_text(msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self._drops.drop("binary", f"{len(msg.data)} bytes")
                elif msg.type == WSMsgType.ERROR:
                    self._drops.drop("ws_error", str(ws.exception()))
        finally:
            if pusher is not None:
                pusher.cancel()
            self._clients.discard(client)
            if moved_joystick and not any(True for _ in self._clients):
                self._set_joy((0.0, 0.0, time.time()))  # the driver left: centre the stick
        return ws

    def _on_text(self, text: str) -> bool:
        try:
            got = _parse_in(text)
        except ValueError as exc:
            self._drops.drop(str(exc), text[:80])
            return False
        if isinstance(got, tuple) and len(got) == 4:
            src, x, y, held = got
            self._pad = (src, x, y, held, time.time())
            self._counters["pad_messages"] += 1
            if self._on_pad is not None:
                self._on_pad(self._pad)
            return False
        if isinstance(got, bool):
            self._counters["hand_messages"] += 1
            if got != self._released:
                self._released = got
                if self._on_hand is not None:
                    self._on_hand(got)
            return False
        x, y = got  # type: ignore[misc]
        self._set_joy((x, y, time.time()))
        self._counters["joystick_messages"] += 1
        return True

    def _set_joy(self, joy: tuple[float, float, float]) -> None:
        self._joy = joy
        if self._on_joystick is not None:
            self._on_joystick(joy)

    async def _push(self, client: _Client) -> None:
        """Send a browser what is new.

        Telemetry once per telemetry period, video frames as soon as they arrive (latest
        only per camera).
        """
        ws = client.ws
        loop = asyncio.get_running_loop()
        next_samples = loop.time()
        try:
            while not ws.closed:
                if loop.time() >= next_samples:
                    next_samples = loop.time() + self._period
                    new = [s for n, s in self._history if n > client.last_sample]
                    if new:
                        client.last_sample = self._history[-1][0]
                        await ws.send_str('{"type":"samples","samples":[' + ",".join(new) + "]}")
                        self._counters["samples_pushed"] += len(new)
                client.wake.clear()
                for camera, (n, t, jpeg) in list(self._frames.items()):
                    if n > client.last_frame.get(camera, 0):
                        client.last_frame[camera] = n
                        name = camera.encode("ascii", "replace")[:255]
                        head = _VIDEO_MAGIC + bytes([len(name)]) + name
                        await ws.send_bytes(head + struct.pack("<dI", t, n & 0xFFFFFFFF) + jpeg)
                        self._counters["frames_pushed"] += 1
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(client.wake.wait(), max(0.0, next_samples - loop.time()))
        except (ConnectionError, RuntimeError) as exc:  # client went away mid-send
            LOG.debug("cockpit: client push ended: %s", exc)
