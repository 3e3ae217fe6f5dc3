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

Websocket protocol
------------------
Server to browser:

- text ``{"type": "hello", "telemetry_hz": f, "keys": [...], "course": [[x, y, r], ...]}``
  on connect (``course``: the task's obstacles for the map, metres; empty when unknown);
- text ``{"type": "samples", "samples": [sample, ...]}``: new telemetry samples (a late
  client first gets the last ``history_s`` seconds); non-finite numbers are sent as null;
- binary video frame: ``b"VF"``, u8 name length, camera name (ASCII), f64 capture time [s]
  (little endian), u32 frame number, then the JPEG bytes.

Browser to server: text ``{"type": "joy", "x": x, "y": y}`` with x, y in [-1, 1]; x is
right-positive, y is up-positive (up = forward). The page re-sends the held position every
100 ms and sends (0, 0) on release. Text ``{"type": "hand", "release": true|false}``: the
buttons Release (give the robot up: another operator may take it) and Take (drive it
again, once it is free; docs/fleet.md, Hand-over). Anything else (binary, not JSON, unknown type, bad or
out-of-range numbers, over 1 KiB) is dropped and counted (:attr:`CockpitServer.stats`).

Access
------
The cockpit shows the robot's camera and, with the browser operator, drives the robot, so
every request is checked (``docs/cockpit.md``):

- **Host allow-list.** The ``Host`` header must name this server: the listen address,
  ``localhost``, ``127.0.0.1``, ``[::1]`` or one of ``allowed_hosts``. A web page whose
  name an attacker re-points at this machine (DNS rebinding) sends its own name as Host
  and is refused (403).
- **Per-run token.** A random token (``secrets.token_urlsafe``) is part of the printed
  address, ``http://HOST:PORT/?token=TOKEN``, as notebook servers do. Every request must
  carry it: the ``token`` query parameter, else the cookie the first page load sets
  (``HttpOnly``, ``SameSite=Strict``; the page's scripts, style sheet and websocket then
  carry it). Compared in constant time (:func:`hmac.compare_digest`); missing or wrong: 403.
- **Origin.** A websocket upgrade must carry an ``Origin`` (every browser sends one) whose
  scheme is http(s) and whose host and port are the request's (allowed) ``Host``; no Origin,
  ``null`` or another site's: 403.
- **Client cap.** At most ``max_clients`` websockets at once (each gets every frame, in
  the process that runs the haptic loop); the next one is accepted only to be told
  ``{"type": "refused", "reason": ...}`` and closed with code 1013 ("try again later").
- **Framing and headers.** Every response carries ``Content-Security-Policy`` (same-origin
  scripts, styles and connections, ``frame-ancestors 'none'``), ``X-Frame-Options: DENY``,
  ``X-Content-Type-Options: nosniff`` and ``Referrer-Policy: no-referrer``.

Refusals are counted (:attr:`CockpitServer.stats`) and logged at most once per reason
per 5 s.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import itertools
import json
import logging
import math
import secrets
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Awaitable, Callable, Iterable, Mapping
from importlib import resources
from typing import Any
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web
from bipedtele.drops import DropCounter
from bipedtele.foxglovews import parse_host
from bipedtele.leader.cockpit.guard import (
    ERR_LOG,
    Guard,
    GuardedHandler,
    Limits,
    Throttle,
    accept_loop,
    descriptor_budget,
)
from bipedtele.telemetry import LeaderSample, sample_to_json

__all__ = ["LOCAL_HOSTS", "SAMPLE_KEYS", "CockpitServer", "EncodedSample"]

LOG = logging.getLogger("bipedtele.leader.cockpit")

#: Telemetry keys the page plots or shows (others are shown as text). Units in docs/cockpit.md.
SAMPLE_KEYS: tuple[str, ...] = (
    "t", "ref_v", "ref_w", "z_e_v", "z_e_w", "eta_v", "eta_w", "force_v", "force_w",
    "h1_ms", "h2_ms", "alpha_m_v", "alpha_m_w", "s_r_v", "s_r_w", "T", "eps",
    "state", "link", "link_lost_s", "fb_age_ms", "loss_pct", "rx_kbps", "tx_kbps", "video_fps", "video_quality",
    "watchdog", "falls", "passes_done",
    "pose_x", "pose_y", "pose_yaw", "pred_x", "pred_y", "pred_yaw", "ahead_x", "ahead_y", "ahead_yaw", "ahead_dt",
)  # fmt: skip

_MAX_IN_TEXT = 1024
_VIDEO_MAGIC = b"VF"
_STATIC = ("index.html", "app.js", "plot.js", "map.js", "pad.js", "style.css")
_CONTENT_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}

#: Host names always allowed in the ``Host`` header (loopback).
LOCAL_HOSTS: tuple[str, ...] = ("localhost", "127.0.0.1", "::1")
#: Listen addresses that are not a name a browser uses.
_WILDCARDS = ("", "0.0.0.0", "::")
#: Sent with every response: the page may load only its own files and talk only to this
#: server, and no other site may frame it (clickjacking the joystick).
_SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob:; "
        "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}
_MIN_TOKEN_LEN = 16
_TOKEN_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_")
_Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


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


def check_token(token: str) -> str:
    """Return ``token`` if it can be a cockpit token (URL-safe characters, at least 16).

    Raises ValueError naming what is allowed otherwise.
    """
    if len(token) < _MIN_TOKEN_LEN or not set(token) <= _TOKEN_CHARS:
        raise ValueError(f"allowed: at least {_MIN_TOKEN_LEN} characters of A-Z a-z 0-9 - _")
    return token


def _clean(value: Any) -> Any:
    """Copy a telemetry value into JSON-safe form (non-finite -> None, unknown -> str)."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if hasattr(value, "tolist"):
        return _clean(value.tolist())
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value[:64]]
    if isinstance(value, Mapping):
        return {str(k): _clean(v) for k, v in list(value.items())[:64]}
    return str(value)[:200]


class EncodedSample(str):
    """A telemetry sample already encoded as JSON text (the cockpit process is fed these)."""


def _sample_json(sample: LeaderSample | EncodedSample | dict[str, Any]) -> str:
    """Return one telemetry sample as JSON text (non-finite numbers as null)."""
    if isinstance(sample, EncodedSample):
        return str(sample)
    if isinstance(sample, LeaderSample):
        return sample_to_json(sample).decode()
    return json.dumps({str(k): _clean(v) for k, v in sample.items()}, allow_nan=False)


#: Where a ``pad`` message comes from (the page's Gamepad API, or its keyboard).
PAD_SOURCES = ("gamepad", "keyboard")


def _parse_pad(msg: dict[str, Any]) -> tuple[str, float, float, bool]:
    """Validate a ``pad`` message's fields: ``(src, x, y, held)``; ValueError(reason) when bad."""
    src = msg.get("src")
    if src not in PAD_SOURCES:
        raise ValueError("bad_pad")
    held = msg.get("held")
    if not isinstance(held, bool):
        raise ValueError("bad_pad")
    x, y = _numbers(msg)
    return str(src), x, y, held


def _numbers(msg: dict[str, Any]) -> tuple[float, float]:
    out = []
    for key in ("x", "y"):
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ValueError("bad_number")
        if not -1.0 <= v <= 1.0:
            raise ValueError("out_of_range")
        out.append(float(v))
    return out[0], out[1]


def _parse_in(text: str) -> tuple[float, float] | bool | tuple[str, float, float, bool]:
    """Validate one browser message.

    Returns ``(x, y)`` of a joystick one, the flag of a hand one, ``(src, x, y, held)`` of a
    pad one. Raises ValueError(reason) when it is bad.
    """
    if len(text) > _MAX_IN_TEXT:
        raise ValueError("too_long")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError):
        raise ValueError("not_json") from None
    if isinstance(msg, dict) and msg.get("type") == "pad":
        return _parse_pad(msg)
    if isinstance(msg, dict) and msg.get("type") == "hand":
        release = msg.get("release")
        if not isinstance(release, bool):
            raise ValueError("bad_hand")
        return release
    if not isinstance(msg, dict) or msg.get("type") != "joy":
        raise ValueError("unknown_type")
    return _numbers(msg)


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


class _Client:
    """One browser connection: what it has already been sent."""

    def __init__(self, ws: web.WebSocketResponse) -> None:
        self.ws = ws
        self.last_sample = -1
        self.last_frame: dict[str, int] = {}
        self.wake = asyncio.Event()  # set when a new video frame is there


class CockpitServer:
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
        self._counters = {"frames_pushed": 0, "samples_pushed": 0, "joystick_messages": 0, "hand_messages": 0, "pad_messages": 0, "connections": 0,
                          "refused_host": 0, "refused_token": 0, "refused_origin": 0, "refused_full": 0}  # fmt: skip
        self._descriptors: dict[str, int] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._stopping: asyncio.Event | None = None
        self._port = 0
        self._static = {name: resources.files(__package__).joinpath("static", name).read_bytes()
                        for name in _STATIC}  # fmt: skip

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

    @property
    def cookie_name(self) -> str:
        """Name of the token cookie (per port: cookies do not tell ports apart)."""
        return f"bipedtele_cockpit_{self._port}"

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

    def _wake_clients(self) -> None:
        for client in list(self._clients):
            client.wake.set()

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
        runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=1.0,
                               keepalive_timeout=self.limits.idle_timeout_s)  # fmt: skip
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

            infos = await loop.getaddrinfo(self.host or None, self._req_port, type=socket.SOCK_STREAM,
                                           flags=socket.AI_PASSIVE)  # fmt: skip
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

    async def _sampler(self) -> None:
        """Take the latest sample every telemetry period into the history."""
        last = 0
        while True:
            await asyncio.sleep(self._period)
            latest = self._sample
            if latest is not None and latest[0] != last:
                last = latest[0]
                self._history.append((last, _sample_json(latest[1])))

    # ------------------------------------------------------------------ access

    def _refuse(self, counter: str, reason: str, detail: str, text: str) -> web.HTTPForbidden:
        self._counters[counter] += 1
        self._refusals.drop(reason, detail)
        return web.HTTPForbidden(text=f"bipedtele cockpit: {text}\n")

    def _host_ok(self, host: str | None) -> bool:
        parsed = parse_host(host) if host else None
        return parsed is not None and parsed[0] in self.allowed_hosts

    def _token_ok(self, given: str) -> bool:
        try:
            data = given.encode("ascii")
        except UnicodeEncodeError:
            return False
        return hmac.compare_digest(data, self._token_bytes)

    async def _limited(self, request: web.Request, *, bad_token: bool) -> web.StreamResponse | None:
        """Count a refused request (against its address if ``bad_token``); its answer when limited.

        An address locked out by failed tokens (``fail_max`` in ``fail_window_s``) gets 429
        for ``lockout_s`` instead of the reason; beyond the global budget of refusal answers
        the connection is aborted unanswered. None: not limited, the caller refuses with
        the reason.
        """
        guard, addr = self.guard, request.remote or "?"
        if guard is None:
            return None
        now = time.monotonic()
        protocol = request.protocol
        if not guard.may_answer(now):
            if isinstance(protocol, GuardedHandler):
                protocol.hold(self.limits.hold_s)  # no answer: it waits, and guesses no more
            await asyncio.sleep(self.limits.hold_s + 1.0)  # closed before: never answered
            return web.Response(status=429)
        if bad_token and guard.locked(addr, now):
            guard.counters["refused_rate"] += 1
            self._refusals.drop("rate_limited", addr)
            if isinstance(protocol, GuardedHandler):
                protocol.hold(self.limits.hold_s)  # this answer, then nothing more for a while
            return web.Response(
                status=429, text="bipedtele cockpit: too many refused requests; try again later\n",
                headers={"Retry-After": str(round(self.limits.lockout_s))},
            )  # fmt: skip
        if bad_token and guard.failed(addr, now):
            self._refusals.drop("locked_out", f"{addr} for {self.limits.lockout_s:g} s")
        return None

    @web.middleware
    async def _guard(self, request: web.Request, handler: _Handler) -> web.StreamResponse:
        """Host allow-list and token on every request; sets the token cookie.

        A request with the right Host and token is always served; the others count against
        their address (:meth:`_limited`).
        """
        host = request.headers.get("Host")
        in_query = request.query.get("token")
        given = in_query if in_query is not None else request.cookies.get(self.cookie_name)
        host_ok, token_ok = self._host_ok(host), bool(given) and self._token_ok(given or "")
        if not (host_ok and token_ok):
            limited = await self._limited(request, bad_token=not token_ok)
            if limited is not None:
                return limited
        if not host_ok:
            raise self._refuse(
                "refused_host", "bad_host", f"Host {str(host)[:80]!r} from {request.remote}",
                "this Host is not allowed (allowed: the listen address, localhost, 127.0.0.1, [::1] "
                "and leader.cockpit_allowed_hosts)",
            )  # fmt: skip
        if not token_ok:
            raise self._refuse(
                "refused_token", "bad_token" if given else "no_token", f"{request.path} from {request.remote}",
                "open the address the leader printed: http://HOST:PORT/?token=TOKEN",
            )  # fmt: skip
        if isinstance(request.protocol, GuardedHandler):
            request.protocol.trust()  # the token holder's connection is never closed to make room
        response = await handler(request)
        if in_query is not None and not response.prepared:
            response.set_cookie(self.cookie_name, self.token, httponly=True, samesite="Strict", path="/")
        return response

    async def _add_headers(self, request: web.Request, response: web.StreamResponse) -> None:
        for key, value in _SECURITY_HEADERS.items():
            response.headers.setdefault(key, value)

    def _origin_ok(self, request: web.Request) -> bool:
        """Tell whether the websocket's Origin is this very server as the browser reached it.

        That is the Host header, already on the allow-list: scheme http(s), same host
        and port.
        """
        origin = request.headers.get("Origin")
        if not origin:
            return False
        try:
            parts = urlsplit(origin)
        except ValueError:
            return False
        if parts.scheme not in ("http", "https") or parts.path not in ("", "/") or parts.query:
            return False
        got, want = parse_host(parts.netloc), parse_host(request.headers.get("Host", ""))
        if got is None or want is None or got[0] not in self.allowed_hosts:
            return False
        default = 443 if parts.scheme == "https" else 80
        return got[0] == want[0] and (got[1] or default) == (want[1] or default)

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

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        if not self._origin_ok(request):
            limited = await self._limited(request, bad_token=False)
            if limited is not None:
                return limited
            origin = request.headers.get("Origin")
            raise self._refuse(
                "refused_origin", "bad_origin" if origin else "no_origin", f"Origin {str(origin)[:80]!r}",
                "websocket refused: it needs the Origin of this page (a browser sends it)",
            )  # fmt: skip
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
