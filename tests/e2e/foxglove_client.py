"""A Foxglove WebSocket client (the Foxglove WebSocket protocol) for the live-view test.

:func:`watch` connects, subscribes to every channel as it is advertised and counts the
messages per topic for a while; it keeps each channel's schema as advertised. Only what
the protocol defines: JSON ``advertise`` operations in, ``subscribe`` out, binary
message-data frames (opcode 1, subscription id u32, log time u64, payload) in.
"""

from __future__ import annotations

import asyncio
import json
import struct
import time
from dataclasses import dataclass, field
from typing import Any

import aiohttp

#: The protocol's names: foxglove-sdk's servers speak ``foxglove.sdk.v1``, older ones ``foxglove.websocket.v1``.
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")


@dataclass
class Seen:
    """What one client saw: channels by topic (as advertised), messages by topic, and when."""

    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    messages: dict[str, int] = field(default_factory=dict)
    first_payload: dict[str, Any] = field(default_factory=dict)
    t_open: float = 0.0
    t_close: float = 0.0
    server: dict[str, Any] = field(default_factory=dict)
    refused: int = 0  # the HTTP status of a refused upgrade (0: served)


async def _watch(url: str, seconds: float, headers: dict[str, str] | None = None) -> Seen:
    seen = Seen()
    try:
        await _session(url, seconds, headers or {}, seen)
    except aiohttp.WSServerHandshakeError as exc:
        seen.refused = exc.status
    return seen


async def _session(url: str, seconds: float, headers: dict[str, str], seen: Seen) -> None:
    by_sub: dict[int, str] = {}
    async with (
        aiohttp.ClientSession() as session,
        session.ws_connect(url, protocols=SUBPROTOCOLS, headers=headers) as ws,
    ):
        seen.t_open = time.time()
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                msg = await ws.receive(timeout=left)
            except TimeoutError:
                break
            if msg.type == aiohttp.WSMsgType.TEXT:
                op = json.loads(msg.data)
                if op.get("op") == "serverInfo":
                    seen.server = op
                elif op.get("op") == "advertise":
                    subs = []
                    for ch in op["channels"]:
                        seen.channels[ch["topic"]] = ch
                        sub = len(by_sub) + 1
                        by_sub[sub] = ch["topic"]
                        subs.append({"id": sub, "channelId": ch["id"]})
                    await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif msg.type == aiohttp.WSMsgType.BINARY and msg.data[:1] == b"\x01":
                (sub,) = struct.unpack_from("<I", msg.data, 1)
                topic = by_sub.get(sub, "?")
                seen.messages[topic] = seen.messages.get(topic, 0) + 1
                if topic not in seen.first_payload:
                    seen.first_payload[topic] = json.loads(msg.data[13:])
            elif msg.type in (aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                break
        seen.t_close = time.time()


def watch(url: str, seconds: float, headers: dict[str, str] | None = None) -> Seen:
    """Watch the live view at ``url`` (``ws://host:port/?token=...``) for ``seconds``.

    ``headers`` go with the upgrade (e.g. an ``Origin``); a refused upgrade is
    :attr:`Seen.refused` (its status), with nothing seen.
    """
    return asyncio.run(_watch(url, seconds, headers))
