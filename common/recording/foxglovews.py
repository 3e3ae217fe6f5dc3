"""The live view's server: the Foxglove WebSocket protocol behind a token, a Host and an Origin check.

What :class:`~bipedtele.recording.foxglovelive.LiveView` runs (aiohttp, extra ``foxglove``), in its own
thread and asyncio loop. Only what the protocol needs for watching: ``serverInfo`` and
``advertise`` out, ``subscribe`` and ``unsubscribe`` in, binary message-data frames (opcode
1, subscription id u32, log time u64 ns, payload) out; subprotocols ``foxglove.sdk.v1`` and
``foxglove.websocket.v1``.

Every upgrade is checked before anything is sent (each refusal a 403 with the reason, one
throttled log line, a counter):

- **Token**: the ``token`` query parameter must be this run's (printed once, as the
  cockpit's); ``fail_max`` wrong tokens of one address in ``fail_window_s`` lock it out
  (429) for ``lockout_s``.
- **Host**: a loopback name, the listen address, this machine's name, or (bound to all
  interfaces) an IP literal; a name an attacker points at this machine (DNS rebinding)
  is refused.
- **Origin**: none (a program, Foxglove's desktop app), Foxglove's web app
  (``https://app.foxglove.dev``) or this server itself; any other web page is refused.
- **Clients**: at most ``max_clients`` at once (``refused_full``).

A slow client loses data messages (its queue keeps the newest ``queue_max``), never
blocks the recorder.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import json
import logging
import socket
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

try:
    from aiohttp import WSMsgType, web
except ModuleNotFoundError:  # the extra is missing: LiveView says so when it starts
    web = None  # type: ignore[assignment]

if TYPE_CHECKING:
    from aiohttp import web as _web

__all__ = ["ALLOWED_ORIGINS", "SUBPROTOCOLS", "LiveServer", "ServerLimits"]

LOG = logging.getLogger("bipedtele.foxglove")
#: The protocol's names, newest first (foxglove-sdk's servers speak the first).
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
#: Web origins allowed besides none at all and this server's own: Foxglove's web app.
ALLOWED_ORIGINS = ("https://app.foxglove.dev", "https://studio.foxglove.dev")
LOCAL_HOSTS = ("localhost", "127.0.0.1", "::1")
_WILDCARDS = ("", "0.0.0.0", "::")
_DATA_OP = 1


@dataclass(frozen=True)
class ServerLimits:
    """The live view's limits (times in seconds)."""

    max_clients: int = 4  #: watching clients at once
    queue_max: int = 512  #: data frames queued per client (older ones dropped)
    max_text: int = 64 * 1024  #: largest client operation [bytes]
    fail_max: int = 10  #: wrong tokens of one address in ``fail_window_s`` that lock it
    fail_window_s: float = 10.0
    lockout_s: float = 30.0
    log_interval_s: float = 10.0  #: one refusal line per reason per interval


def parse_host(value: str) -> tuple[str, int | None] | None:
    """Return ``(name, port)`` of a Host header or URL netloc (lower case, IPv6 unbracketed), or None.

    Shared by the live view's and the cockpit's Host and Origin checks.
    """
    try:
        parts = urlsplit("//" + value)
        name, port = parts.hostname, parts.port
    except ValueError:
        return None
    if not name or parts.username is not None or parts.path or parts.query:
        return None
    return name.lower(), port


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


@dataclass
class _Client:
    ws: Any
    addr: str
    subs: dict[int, int] = field(default_factory=dict)  # subscription id -> channel id
    queue: deque[bytes | str] = field(default_factory=deque)
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    dropped: int = 0


class LiveServer:
    """The guarded Foxglove WebSocket server (see the module docstring).

    Parameters
    ----------
    host, port : str, int
        Listen address (port 0: any free one; see :attr:`port`).
    name : str
        Server name shown in Foxglove.
    token : str
        The access token clients must give (``?token=``).
    limits : ServerLimits, optional
    """

    def __init__(self, host: str, port: int, name: str, token: str, limits: ServerLimits | None = None) -> None:
        if web is None:
            raise ModuleNotFoundError("No module named 'aiohttp'", name="aiohttp")
        self.host, self.name, self.limits = host, name, limits or ServerLimits()
        self._req_port, self.port = port, 0
        self._token = token.encode("ascii")
        hosts = set(LOCAL_HOSTS) | {socket.gethostname().lower(), socket.getfqdn().lower()}
        if host not in _WILDCARDS:
            hosts.add(host.lower())
        self.allowed_hosts = frozenset(hosts)
        self._channels: dict[int, dict[str, Any]] = {}
        self._clients: list[_Client] = []
        self._fails: dict[str, deque[float]] = {}
        self._locked: dict[str, float] = {}
        self._last_line: dict[str, float] = {}
        self.counters = {
            k: 0
            for k in (
                "refused_token",
                "refused_host",
                "refused_origin",
                "refused_full",
                "refused_rate",
                "refused_protocol",
                "served",
                "dropped",
            )
        }
        self.subscribed: frozenset[int] = frozenset()  # channels someone watches (read from any thread)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        ready, failure = threading.Event(), list[BaseException]()
        self._thread = threading.Thread(target=self._main, args=(ready, failure), name="foxglove", daemon=True)
        self._thread.start()
        ready.wait(10.0)
        if failure:
            raise failure[0]

    # ------------------------------------------------------------------ any thread

    def add_channel(self, channel: dict[str, Any]) -> None:
        """Advertise ``channel`` (its ``id``, ``topic``, ``encoding``, ``schemaName``, ``schema``, ...)."""
        self._call(self._advertise, channel)

    def publish(self, cid: int, payload: bytes, log_time_ns: int) -> None:
        """Send one payload on channel ``cid`` to its subscribers (queued; never blocks)."""
        if cid in self.subscribed:
            self._call(self._fanout, cid, payload, log_time_ns)

    def stop(self) -> None:
        """Close every client and stop listening (idempotent)."""
        if self._stop is not None:
            self._call(self._stop.set)
        self._thread.join(5.0)

    def _call(self, fn: Any, *args: Any) -> None:
        loop = self._loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(fn, *args)

    # ------------------------------------------------------------------ the server's loop

    def _main(self, ready: threading.Event, failure: list[BaseException]) -> None:
        loop = asyncio.new_event_loop()
        try:
            loop.run_until_complete(self._serve(loop, ready))
        except BaseException as exc:  # a bind error ends up here
            if not ready.is_set():
                failure.append(exc)
            else:  # pragma: no cover
                LOG.exception("foxglove live view failed")
        finally:
            self._loop = None
            ready.set()
            loop.close()

    async def _serve(self, loop: asyncio.AbstractEventLoop, ready: threading.Event) -> None:
        assert web is not None
        self._stop = asyncio.Event()
        app = web.Application()
        app.router.add_get("/{tail:.*}", self._handle)
        runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=1.0)
        await runner.setup()
        try:
            site = web.TCPSite(runner, self.host or None, self._req_port, reuse_address=True)
            await site.start()
            server = site._server
            assert server is not None
            sockets = getattr(server, "sockets", None) or []
            self.port = int(sockets[0].getsockname()[1]) if sockets else self._req_port
            self._loop = loop
            ready.set()
            await self._stop.wait()
            for client in list(self._clients):
                await client.ws.close(code=1001, message=b"server stopping")
        finally:
            await runner.cleanup()

    def _advertise(self, channel: dict[str, Any]) -> None:
        self._channels[int(channel["id"])] = channel
        text = json.dumps({"op": "advertise", "channels": [channel]})
        for client in self._clients:
            self._queue(client, text)

    def _fanout(self, cid: int, payload: bytes, log_time_ns: int) -> None:
        for client in self._clients:
            for sub, ch in client.subs.items():
                if ch == cid:
                    self._queue(client, struct.pack("<BIQ", _DATA_OP, sub, log_time_ns) + payload)

    def _queue(self, client: _Client, item: bytes | str) -> None:
        if isinstance(item, bytes) and len(client.queue) >= self.limits.queue_max:
            client.queue.popleft()
            client.dropped += 1
            self.counters["dropped"] += 1
        client.queue.append(item)
        client.wake.set()

    def _resubscribed(self) -> None:
        self.subscribed = frozenset(ch for c in self._clients for ch in c.subs.values())

    # ------------------------------------------------------------------ access

    def _refuse(self, counter: str, reason: str, addr: str, status: int = 403) -> Any:
        assert web is not None
        self.counters[counter] += 1
        now = time.monotonic()
        if now - self._last_line.get(counter, -1e9) >= self.limits.log_interval_s:
            self._last_line[counter] = now
            LOG.warning("foxglove live view: refused a client from %s: %s", addr, reason)
        return web.Response(status=status, text=f"bipedtele live view: {reason}\n")

    def _token_ok(self, given: str | None) -> bool:
        try:
            data = (given or "").encode("ascii")
        except UnicodeEncodeError:
            return False
        return bool(data) and hmac.compare_digest(data, self._token)

    def _host_ok(self, host: str | None) -> bool:
        parsed = parse_host(host) if host else None
        if parsed is None:
            return False
        return parsed[0] in self.allowed_hosts or (self.host in _WILDCARDS and _is_ip(parsed[0]))

    def _origin_ok(self, origin: str | None, host: str | None) -> bool:
        if origin is None:
            return True  # not a browser page: a program (the token still guards it)
        if origin in ALLOWED_ORIGINS:
            return True
        try:
            parts = urlsplit(origin)
        except ValueError:
            return False
        got, want = parse_host(parts.netloc), parse_host(host or "")
        return parts.scheme in ("http", "https") and got is not None and got == want and self._host_ok(host)

    def _locked_out(self, addr: str, bad_token: bool) -> bool:
        now = time.monotonic()
        until = self._locked.get(addr)
        if until is not None and now < until:
            return True
        self._locked.pop(addr, None)
        if bad_token:
            q = self._fails.setdefault(addr, deque())
            q.append(now)
            while q and now - q[0] > self.limits.fail_window_s:
                q.popleft()
            if len(q) >= self.limits.fail_max:
                q.clear()
                self._locked[addr] = now + self.limits.lockout_s
            if len(self._fails) > 10_000:
                self._fails = {a: d for a, d in self._fails.items() if d}
        return False

    def _check(self, request: _web.Request) -> Any:
        """Return the refusal of a request, or None when it may watch."""
        addr = request.remote or "?"
        token_ok = self._token_ok(request.query.get("token"))
        if self._locked_out(addr, not token_ok):
            return self._refuse("refused_rate", "too many wrong tokens; try again later", addr, 429)
        if not self._host_ok(request.headers.get("Host")):
            return self._refuse("refused_host", "this Host is not allowed (DNS rebinding?)", addr)
        if not token_ok:
            return self._refuse(
                "refused_token", "open the address the program printed: ws://HOST:PORT/?token=TOKEN", addr
            )
        if not self._origin_ok(request.headers.get("Origin"), request.headers.get("Host")):
            return self._refuse("refused_origin", "a web page of another origin may not watch", addr)
        if len(self._clients) >= self.limits.max_clients:
            return self._refuse("refused_full", f"{self.limits.max_clients} clients watch already", addr, 503)
        return None

    # ------------------------------------------------------------------ a client

    async def _handle(self, request: _web.Request) -> Any:
        assert web is not None
        refusal = self._check(request)
        if refusal is not None:
            return refusal
        ws = web.WebSocketResponse(protocols=SUBPROTOCOLS, max_msg_size=self.limits.max_text, heartbeat=None)
        if not ws.can_prepare(request).ok:
            self.counters["refused_protocol"] += 1
            return web.Response(status=426, text="bipedtele live view: a Foxglove WebSocket; open it in Foxglove\n")
        await ws.prepare(request)
        client = _Client(ws, request.remote or "?")
        self._clients.append(client)
        self.counters["served"] += 1
        LOG.info("foxglove live view: a client from %s watches", client.addr)
        info = {
            "op": "serverInfo",
            "name": self.name,
            "capabilities": [],
            "supportedEncodings": [],
            "metadata": {},
            "sessionId": str(id(self)),
        }
        self._queue(client, json.dumps(info))
        if self._channels:
            self._queue(client, json.dumps({"op": "advertise", "channels": list(self._channels.values())}))
        sender = asyncio.create_task(self._send(client))
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    self._operation(client, msg.data)
        finally:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender
            self._clients.remove(client)
            self._resubscribed()
        return ws

    async def _send(self, client: _Client) -> None:
        with contextlib.suppress(ConnectionError, RuntimeError):
            while not client.ws.closed:
                await client.wake.wait()
                client.wake.clear()
                while client.queue:
                    item = client.queue.popleft()
                    if isinstance(item, str):
                        await client.ws.send_str(item)
                    else:
                        await client.ws.send_bytes(item)

    def _operation(self, client: _Client, text: str) -> None:
        try:
            op = json.loads(text)
            if op.get("op") == "subscribe":
                for s in op["subscriptions"][:1024]:
                    if int(s["channelId"]) in self._channels and len(client.subs) < 4096:
                        client.subs[int(s["id"])] = int(s["channelId"])
            elif op.get("op") == "unsubscribe":
                for sub in op["subscriptionIds"]:
                    client.subs.pop(int(sub), None)
            else:
                return
        except (ValueError, KeyError, TypeError, AttributeError):
            return  # not an operation we know: ignored
        self._resubscribed()
