"""The cockpit web server: live video, plots, status and a virtual joystick in a browser.

An aiohttp application runs in its own thread with its own asyncio loop (the leader runs
this server in a child process: :class:`~bipedtele.leader.cockpit.process.CockpitProcess`;
the timeouts, caps and rate limits are :mod:`bipedtele.leader.cockpit.guard`'s):
:meth:`CockpitServer.publish_sample` and :meth:`CockpitServer.publish_video` only store the
latest value (one assignment, no lock, no cross-thread wake-up); the server thread samples them at ``telemetry_hz`` and pushes to
every connected browser over a websocket.

Endpoints
---------
``/``            the page (``static/index.html``; plain HTML/JS/CSS, no build step, no CDN)
``/static/*``    its scripts and style sheet
``/ws``          websocket: server -> browser JSON text (``hello``, ``samples``) and binary
                 video frames; browser -> server JSON text (``joy``)
``/video/NAME.jpg``  the latest JPEG of a camera (404 before the first frame)
``/healthz``     ``{"ok": true, "clients": n, ...}``

Modules
-------
The websocket protocol and the checks of a browser's messages are
:mod:`bipedtele.leader.cockpit.protocol`'s, who may connect (Host, token, Origin, headers)
:mod:`bipedtele.leader.cockpit.access`'s, the websocket feed
:mod:`bipedtele.leader.cockpit.feed`'s; this module starts, stops and publishes, wires the
guard, the routes and the listening socket, and serves the page's files. Every name these
modules export is importable from here.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
import secrets
import socket
import threading
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from importlib import resources
from typing import Any

from aiohttp import web
from bipedtele.leader.cockpit.access import LOCAL_HOSTS, check_token
from bipedtele.leader.cockpit.feed import Feed, _Client
from bipedtele.leader.cockpit.guard import (
    ERR_LOG,
    Guard,
    GuardedHandler,
    Limits,
    Throttle,
    accept_loop,
    descriptor_budget,
)
from bipedtele.leader.cockpit.protocol import PAD_SOURCES, SAMPLE_KEYS, EncodedSample
from bipedtele.leader.cockpit.protocol import _parse_in as _parse_in
from bipedtele.leader.cockpit.protocol import _sample_json as _sample_json
from bipedtele.link.drops import DropCounter
from bipedtele.recording.foxglovews import parse_host
from bipedtele.telemetry import LeaderSample

__all__ = ["LOCAL_HOSTS", "PAD_SOURCES", "SAMPLE_KEYS", "CockpitServer", "EncodedSample", "check_token"]

LOG = logging.getLogger("bipedtele.leader.cockpit")

#: Listen addresses that are not a name a browser uses.
_WILDCARDS = ("", "0.0.0.0", "::")
#: The server's own counters (:attr:`CockpitServer.stats`), each from 0.
_COUNTERS = (
    "frames_pushed",
    "samples_pushed",
    "joystick_messages",
    "hand_messages",
    "pad_messages",
    "connections",
    "refused_host",
    "refused_token",
    "refused_origin",
    "refused_full",
)
_STATIC = ("index.html", "app.js", "plot.js", "map.js", "pad.js", "style.css")
_CONTENT_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}


def _loop_error(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
    """Log an error of the server's loop: one line per kind per interval, no traceback."""
    exc = context.get("exception")
    what = str(context.get("message", "error"))
    ERR_LOG.error(f"cockpit: {what}" + (f": {type(exc).__name__}" if exc is not None else ""), exc_info=exc)


def _throttle_logs(interval_s: float) -> None:
    """Throttle the cockpit's error loggers and aiohttp's (idempotent)."""
    for name in (ERR_LOG.name, "aiohttp.server", "aiohttp.web", "aiohttp.websocket"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, Throttle) for f in logger.filters):
            logger.addFilter(Throttle(interval_s))


def _check_figures(telemetry_hz: float, history_s: float, port: int, max_clients: int, force_max_n: float) -> None:
    """Raise ValueError naming the first of the server's figures out of its range."""
    if not (math.isfinite(telemetry_hz) and 1.0 <= telemetry_hz <= 100.0):
        raise ValueError(f"telemetry_hz must be in [1, 100] Hz, got {telemetry_hz!r}")
    if not (math.isfinite(history_s) and 0.0 <= history_s <= 600.0):
        raise ValueError(f"history_s must be in [0, 600] s, got {history_s!r}")
    if not 0 <= port <= 65535:
        raise ValueError(f"port must be in [0, 65535], got {port!r}")
    if not 1 <= max_clients <= 1000:
        raise ValueError(f"max_clients must be in [1, 1000], got {max_clients!r}")
    if not (math.isfinite(force_max_n) and force_max_n > 0):
        raise ValueError(f"force_max_n must be > 0 N, got {force_max_n!r}")


class CockpitServer(Feed):
    """The leader's browser cockpit, served from a background thread.

    Parameters
    ----------
    host : str
        Address to bind (default loopback only).
    port : int
        TCP port; 0 picks a free one (see :attr:`port` after :meth:`start`).
    telemetry_hz : float
        Rate at which the latest sample is taken and pushed to browsers [Hz].
    history_s : float
        Telemetry kept for browsers that connect late [s].
    token : str, optional
        The access token (URL-safe, at least 16 characters); a random one
        (``secrets.token_urlsafe(24)``) when omitted. See :attr:`url`.
    allowed_hosts : iterable of str
        Host names (or addresses) accepted in the ``Host`` header besides the listen
        address and :data:`LOCAL_HOSTS` (e.g. the machine's name when listening on all
        interfaces behind a tunnel).
    max_clients : int
        Most websocket clients at once (>= 1).
    course : iterable of (float, float, float)
        Obstacles ``(x [m], y [m], radius [m])`` drawn on the page's map (the frame of
        ``Feedback.pose``).

    Notes
    -----
    ``publish_*`` may be called from any thread before, during and after the server runs;
    they cost one dict copy (samples) or one assignment (video) and never block.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        telemetry_hz: float = 25.0,
        history_s: float = 30.0,
        token: str | None = None,
        allowed_hosts: Iterable[str] = (),
        max_clients: int = 4,
        course: Iterable[tuple[float, float, float]] = (),
        limits: Limits | None = None,
        on_joystick: Callable[[tuple[float, float, float]], None] | None = None,
        on_hand: Callable[[bool], None] | None = None,
        on_pad: Callable[[tuple[str, float, float, bool, float]], None] | None = None,
        force_max_n: float = 8.0,
    ) -> None:
        self.limits = limits or Limits()
        self._on_joystick = on_joystick
        self._on_hand = on_hand
        self._on_pad = on_pad
        self._pad: tuple[str, float, float, bool, float] | None = None
        _check_figures(telemetry_hz, history_s, port, max_clients, force_max_n)
        self.force_max_n = float(force_max_n)
        self._released = False
        self.guard: Guard | None = None
        self.course = [[float(v) for v in ob] for ob in course]
        if any(len(ob) != 3 or not all(math.isfinite(v) for v in ob) for ob in self.course):
            raise ValueError("course: allowed: finite (x, y, radius) triples [m]")
        if token is not None:
            try:
                check_token(token)
            except ValueError as exc:
                raise ValueError(f"token: {exc}") from None
        self.host = host
        self.token = token if token is not None else secrets.token_urlsafe(24)
        self._token_bytes = self.token.encode("ascii")
        self.max_clients = int(max_clients)
        names = {host.strip("[]").lower()} - set(_WILDCARDS)
        names.update(LOCAL_HOSTS)
        for name in allowed_hosts:
            parsed = parse_host(name.strip())
            if parsed is None:
                raise ValueError(f"allowed_hosts: {name!r} is not a host name or address")
            names.add(parsed[0])
        self.allowed_hosts: frozenset[str] = frozenset(names)
        self._req_port = port
        self.telemetry_hz = float(telemetry_hz)
        self._period = 1.0 / self.telemetry_hz
        # Latest values, written by publisher threads (single reference assignments).
        self._sample: tuple[int, LeaderSample | EncodedSample | dict[str, Any]] | None = None
        self._sample_n = itertools.count(1)  # next() is atomic under the GIL
        self._frames: dict[str, tuple[int, float, bytes]] = {}
        self._frame_n = itertools.count(1)
        self._joy: tuple[float, float, float] | None = None
        # Server-thread state.
        self._history: deque[tuple[int, str]] = deque(  # (number, sample as JSON text)
            maxlen=max(1, int(history_s * self.telemetry_hz))
        )
        self._clients: set[_Client] = set()
        self._drops = DropCounter("cockpit/ws")
        self._refusals = DropCounter("cockpit/http")
        self._counters = dict.fromkeys(_COUNTERS, 0)
        self._descriptors: dict[str, int] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._stopping: asyncio.Event | None = None
        self._port = 0
        self._static = {name: resources.files(__package__).joinpath("static", name).read_bytes() for name in _STATIC}

    # ------------------------------------------------------------------ lifecycle

    @property
    def port(self) -> int:
        """The bound TCP port (0 before :meth:`start`)."""
        return self._port

    @property
    def base_url(self) -> str:
        """``http://host:port/`` without the token.

        A wildcard listen address is shown as ``127.0.0.1``.
        """
        host = "127.0.0.1" if self.host in _WILDCARDS else self.host
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self._port}/"

    @property
    def url(self) -> str:
        """The address to open: ``http://host:port/?token=TOKEN``."""
        return f"{self.base_url}?token={self.token}"

    def start(self, timeout_s: float = 10.0) -> CockpitServer:
        """Start the server thread and wait until it listens.

        Raises
        ------
        OSError
            The address cannot be bound (port in use, bad host).
        RuntimeError
            Already started, or the server did not come up in ``timeout_s`` seconds.
        """
        if self._thread is not None:
            raise RuntimeError("cockpit server already started")
        ready = threading.Event()
        failure: list[BaseException] = []
        _throttle_logs(self.limits.log_interval_s)
        self._thread = threading.Thread(target=self._thread_main, args=(ready, failure), name="cockpit", daemon=True)
        self._thread.start()
        if not ready.wait(timeout_s):
            raise RuntimeError("cockpit server did not start in time")
        if failure:
            self._thread.join()
            self._thread = None
            raise failure[0]
        LOG.debug("cockpit listening on %s", self.base_url)
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        """Close every browser connection and the listening socket; join the thread."""
        thread, loop, stopping = self._thread, self._loop, self._stopping
        if thread is None:
            return
        if loop is not None and stopping is not None and thread.is_alive():
            loop.call_soon_threadsafe(stopping.set)
        thread.join(timeout_s)
        if thread.is_alive():  # pragma: no cover - a stuck client; the thread is a daemon
            LOG.warning("cockpit thread did not stop within %.1f s", timeout_s)
        self._thread = None

    def __enter__(self) -> CockpitServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ publishing

    def publish_sample(self, sample: LeaderSample | EncodedSample | Mapping[str, Any]) -> None:
        """Offer the latest telemetry sample (keys in :data:`SAMPLE_KEYS`; others as text).

        Cheap and non-blocking; only the newest sample per telemetry period is sent.

        Parameters
        ----------
        sample : LeaderSample, EncodedSample or Mapping
            The leader's :class:`~bipedtele.telemetry.LeaderSample` (kept by reference:
            the caller must not change it afterwards; its unset fields are not sent), one
            already encoded as JSON text, or a map (copied; values that are not JSON are
            sent as text).
        """
        item = sample if isinstance(sample, LeaderSample | EncodedSample) else dict(sample)
        self._sample = (next(self._sample_n), item)

    def publish_video(self, camera: str, jpeg: bytes, t: float) -> None:
        """Offer the latest JPEG of ``camera`` captured at ``t`` [s].

        Older frames are replaced (latest only).
        """
        self._frames[camera] = (next(self._frame_n), float(t), bytes(jpeg))
        loop = self._loop
        if loop is not None and self._clients:
            # Wake the pushers now instead of at the next telemetry period (video latency).
            with contextlib.suppress(RuntimeError):  # the loop closed while stopping
                loop.call_soon_threadsafe(self._wake_clients)

    def joystick(self) -> tuple[float, float, float] | None:
        """Return ``(x, y, t)``: the virtual joystick and when it last changed.

        x right, y up, each in [-1, 1]; ``t`` [s, ``time.time()``] when it last changed or
        was re-sent; None until a browser touches it. Falls back to (0, 0) when the
        browser that moved it disconnects.
        """
        return self._joy

    def released(self) -> bool:
        """Return True after the page's Release, False after its Take (and at the start)."""
        return self._released

    def pad(self) -> tuple[str, float, float, bool, float] | None:
        """Return the page's controller: ``(src, x, y, held, t)`` (None before any; see ``pad`` in docs/cockpit.md)."""
        return self._pad

    @property
    def stats(self) -> dict[str, Any]:
        """Return the counters.

        ``clients``, ``frames_pushed``, ``samples_pushed``, ``joystick_messages``,
        ``connections``, refusals (``refused_host``, ``refused_token``,
        ``refused_origin``, ``refused_full``), ``bad_messages`` and ``bad_by_reason``; the
        guard's (:class:`~bipedtele.leader.cockpit.guard.Guard`): ``refused_conn_address``,
        ``refused_conn_total``, ``closed_no_head``, ``refused_rate`` (429),
        ``closed_unanswered``, ``lockouts``, ``open_connections``; ``nofile_soft``,
        ``descriptors_used``, ``total_cap``.
        """
        out: dict[str, Any] = dict(self._counters)
        if self.guard is not None:
            out.update(self.guard.counters, open_connections=self.guard.total)
        out.update(self._descriptors)
        out["clients"] = len(self._clients)
        out["bad_by_reason"] = self._drops.counts()
        out["bad_messages"] = self._drops.total
        return out

    # ------------------------------------------------------------------ server thread

    def _thread_main(self, ready: threading.Event, failure: list[BaseException]) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve(ready, failure))
        except BaseException as exc:  # bind errors end up here
            if not ready.is_set():
                failure.append(exc)
            else:  # pragma: no cover
                LOG.exception("cockpit server failed")
        finally:
            ready.set()
            loop.close()
            self._loop = None

    async def _serve(self, ready: threading.Event, failure: list[BaseException]) -> None:
        self._stopping = asyncio.Event()
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(_loop_error)
        total_cap, self._descriptors = descriptor_budget(self.limits)
        guard = self.guard = Guard(self.limits, total_cap)
        app = web.Application(middlewares=[self._guard])
        app.on_response_prepare.append(self._add_headers)
        app.router.add_get("/", self._page)
        app.router.add_get("/static/{name}", self._static_file)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/healthz", self._healthz)
        app.router.add_get("/favicon.ico", self._no_content)
        app.router.add_get("/video/{camera}.jpg", self._video_jpeg)
        runner = web.AppRunner(
            app,
            handle_signals=False,
            access_log=None,
            shutdown_timeout=1.0,
            keepalive_timeout=self.limits.idle_timeout_s,
        )
        await runner.setup()
        self._runner = runner
        listener: socket.socket | None = None
        acceptor: asyncio.Task[None] | None = None
        try:
            manager = runner.server
            assert manager is not None
            kwargs = manager._kwargs  # what aiohttp's own factory passes (access log, keep-alive)

            def connection(addr: str) -> GuardedHandler:
                return GuardedHandler(manager, guard=guard, addr=addr, loop=loop, **kwargs)

            infos = await loop.getaddrinfo(
                self.host or None, self._req_port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
            )
            family, _, _, _, address = infos[0]
            listener = socket.socket(family, socket.SOCK_STREAM)
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind(address)
            listener.listen(128)
            listener.setblocking(False)
            self._port = int(listener.getsockname()[1])
            acceptor = asyncio.create_task(accept_loop(listener, guard, connection, self._conn_refused))
            ready.set()
            sampler = asyncio.create_task(self._sampler())
            await self._stopping.wait()
            sampler.cancel()
            for client in list(self._clients):
                await client.ws.close(code=1001, message=b"server stopping")
        finally:
            if acceptor is not None:
                acceptor.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await acceptor
            if listener is not None:
                listener.close()
            await runner.cleanup()

    def _conn_refused(self, reason: str, addr: str) -> None:
        self._refusals.drop(reason, addr)

    # ------------------------------------------------------------------ handlers

    async def _page(self, request: web.Request) -> web.Response:
        return self._file_response("index.html")

    async def _static_file(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in self._static:
            raise web.HTTPNotFound()
        return self._file_response(name)

    def _file_response(self, name: str) -> web.Response:
        ctype = _CONTENT_TYPES[name[name.rindex(".") :]]
        return web.Response(
            body=self._static[name],
            content_type=ctype,
            charset="utf-8",
            headers={"Cache-Control": "no-cache"},
        )

    async def _no_content(self, request: web.Request) -> web.Response:
        return web.Response(status=204)

    async def _healthz(self, request: web.Request) -> web.Response:
        return web.json_response({"ok": True, "clients": len(self._clients), "cameras": sorted(self._frames)})

    async def _video_jpeg(self, request: web.Request) -> web.Response:
        frame = self._frames.get(request.match_info["camera"])
        if frame is None:
            raise web.HTTPNotFound(text="no frame yet")
        return web.Response(body=frame[2], content_type="image/jpeg", headers={"Cache-Control": "no-store"})
