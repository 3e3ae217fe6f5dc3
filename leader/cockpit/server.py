"""The cockpit web server: live video, plots, status and a virtual joystick in a browser.

An aiohttp application runs in its own thread with its own asyncio loop, so the leader's
1 kHz loop is never disturbed: :meth:`CockpitServer.publish_sample` and
:meth:`CockpitServer.publish_video` only store the latest value (one assignment, no lock,
no cross-thread wake-up); the server thread samples them at ``telemetry_hz`` and pushes to
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

- text ``{"type": "hello", "telemetry_hz": f, "keys": [...]}`` on connect;
- text ``{"type": "samples", "samples": [sample, ...]}``: new telemetry samples (a late
  client first gets the last ``history_s`` seconds); non-finite numbers are sent as null;
- binary video frame: ``b"VF"``, u8 name length, camera name (ASCII), f64 capture time [s]
  (little endian), u32 frame number, then the JPEG bytes.

Browser to server: text ``{"type": "joy", "x": x, "y": y}`` with x, y in [-1, 1]; x is
right-positive, y is up-positive (up = forward). The page re-sends the held position every
100 ms and sends (0, 0) on release. Anything else (binary, not JSON, unknown type, bad or
out-of-range numbers, over 1 KiB) is dropped and counted (:attr:`CockpitServer.stats`).
A websocket whose ``Origin`` is not this server is refused (another web site open in the
same browser must not drive the robot).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import math
import struct
import threading
import time
from collections import deque
from collections.abc import Mapping
from importlib import resources
from typing import Any
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web
from bipedtele.drops import DropCounter

__all__ = ["SAMPLE_KEYS", "CockpitServer"]

LOG = logging.getLogger("bipedtele.leader.cockpit")

#: Telemetry keys the page plots or shows (others are shown as text). Units in docs/cockpit.md.
SAMPLE_KEYS: tuple[str, ...] = (
    "t", "ref_v", "ref_w", "z_e_v", "z_e_w", "eta_v", "eta_w", "force_v", "force_w",
    "h1_ms", "h2_ms", "alpha_m_v", "alpha_m_w", "s_r_v", "s_r_w", "T", "eps",
    "state", "link", "watchdog", "falls", "passes_done",
)  # fmt: skip

_MAX_IN_TEXT = 1024
_VIDEO_MAGIC = b"VF"
_STATIC = ("index.html", "app.js", "plot.js", "style.css")
_CONTENT_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}


def _clean(value: Any) -> Any:
    """A JSON-safe copy of a telemetry value (non-finite -> None, unknown -> str)."""
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


def _parse_joy(text: str) -> tuple[float, float]:
    """Validate one joystick message; raise ValueError(reason) when it is bad."""
    if len(text) > _MAX_IN_TEXT:
        raise ValueError("too_long")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError):
        raise ValueError("not_json") from None
    if not isinstance(msg, dict) or msg.get("type") != "joy":
        raise ValueError("unknown_type")
    out = []
    for key in ("x", "y"):
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ValueError("bad_number")
        if not -1.0 <= v <= 1.0:
            raise ValueError("out_of_range")
        out.append(float(v))
    return out[0], out[1]


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
    ) -> None:
        if not (math.isfinite(telemetry_hz) and 1.0 <= telemetry_hz <= 100.0):
            raise ValueError(f"telemetry_hz must be in [1, 100] Hz, got {telemetry_hz!r}")
        if not (math.isfinite(history_s) and 0.0 <= history_s <= 600.0):
            raise ValueError(f"history_s must be in [0, 600] s, got {history_s!r}")
        if not 0 <= port <= 65535:
            raise ValueError(f"port must be in [0, 65535], got {port!r}")
        self.host = host
        self._req_port = port
        self.telemetry_hz = float(telemetry_hz)
        self._period = 1.0 / self.telemetry_hz
        # Latest values, written by publisher threads (single reference assignments).
        self._sample: tuple[int, dict[str, Any]] | None = None
        self._sample_n = itertools.count(1)  # next() is atomic under the GIL
        self._frames: dict[str, tuple[int, float, bytes]] = {}
        self._frame_n = itertools.count(1)
        self._joy: tuple[float, float, float] | None = None
        # Server-thread state.
        self._history: deque[tuple[int, dict[str, Any]]] = deque(
            maxlen=max(1, int(history_s * self.telemetry_hz))
        )
        self._clients: set[_Client] = set()
        self._drops = DropCounter("cockpit/ws")
        self._counters = {"frames_pushed": 0, "samples_pushed": 0, "joystick_messages": 0,
                          "connections": 0, "refused_origin": 0}  # fmt: skip
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
    def url(self) -> str:
        """``http://host:port/`` of the page."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self._port}/"

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
        self._thread = threading.Thread(
            target=self._thread_main, args=(ready, failure), name="cockpit", daemon=True
        )
        self._thread.start()
        if not ready.wait(timeout_s):
            raise RuntimeError("cockpit server did not start in time")
        if failure:
            self._thread.join()
            self._thread = None
            raise failure[0]
        LOG.info("cockpit at %s", self.url)
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

    def publish_sample(self, sample: Mapping[str, Any]) -> None:
        """Offer the latest telemetry sample (keys in :data:`SAMPLE_KEYS`; others shown as
        text). Cheap and non-blocking; only the newest sample per telemetry period is sent."""
        self._sample = (next(self._sample_n), dict(sample))

    def publish_video(self, camera: str, jpeg: bytes, t: float) -> None:
        """Offer the latest JPEG of ``camera`` captured at ``t`` [s]; older frames are
        replaced (latest only)."""
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
        """``(x, y, t)``: the virtual joystick (x right, y up, each in [-1, 1]) and when it
        last changed or was re-sent [s, ``time.time()``]; None until a browser touches it.
        Falls back to (0, 0) when the browser that moved it disconnects."""
        return self._joy

    @property
    def stats(self) -> dict[str, Any]:
        """Counters: ``clients``, ``frames_pushed``, ``samples_pushed``,
        ``joystick_messages``, ``connections``, ``refused_origin``, ``bad_messages`` and
        ``bad_by_reason``."""
        out: dict[str, Any] = dict(self._counters)
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
        app = web.Application()
        app.router.add_get("/", self._page)
        app.router.add_get("/static/{name}", self._static_file)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/healthz", self._healthz)
        app.router.add_get("/favicon.ico", self._no_content)
        app.router.add_get("/video/{camera}.jpg", self._video_jpeg)
        runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=1.0)
        await runner.setup()
        self._runner = runner
        try:
            site = web.TCPSite(runner, self.host, self._req_port)
            await site.start()
            addresses = runner.addresses
            self._port = int(addresses[0][1]) if addresses else self._req_port
            ready.set()
            sampler = asyncio.create_task(self._sampler())
            await self._stopping.wait()
            sampler.cancel()
            for client in list(self._clients):
                await client.ws.close(code=1001, message=b"server stopping")
        finally:
            await runner.cleanup()

    async def _sampler(self) -> None:
        """Take the latest sample every telemetry period into the history."""
        last = 0
        while True:
            await asyncio.sleep(self._period)
            latest = self._sample
            if latest is not None and latest[0] != last:
                last = latest[0]
                self._history.append((last, {str(k): _clean(v) for k, v in latest[1].items()}))

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
        return web.json_response(
            {"ok": True, "clients": len(self._clients), "cameras": sorted(self._frames)}
        )

    async def _video_jpeg(self, request: web.Request) -> web.Response:
        frame = self._frames.get(request.match_info["camera"])
        if frame is None:
            raise web.HTTPNotFound(text="no frame yet")
        return web.Response(
            body=frame[2], content_type="image/jpeg", headers={"Cache-Control": "no-store"}
        )

    def _origin_ok(self, request: web.Request) -> bool:
        origin = request.headers.get("Origin")
        if origin is None:  # not a browser (tests, tools)
            return True
        return urlsplit(origin).netloc.lower() == request.host.lower()

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        if not self._origin_ok(request):
            self._counters["refused_origin"] += 1
            LOG.warning("cockpit: refused websocket from origin %r", request.headers.get("Origin"))
            raise web.HTTPForbidden(text="cross-origin websocket refused")
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=64 * 1024)
        await ws.prepare(request)
        client = _Client(ws)
        self._clients.add(client)
        self._counters["connections"] += 1
        await ws.send_str(
            json.dumps({"type": "hello", "telemetry_hz": self.telemetry_hz, "keys": SAMPLE_KEYS})
        )
        pusher = asyncio.create_task(self._push(client))
        moved_joystick = False
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    moved_joystick |= self._on_text(msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self._drops.drop("binary", f"{len(msg.data)} bytes")
                elif msg.type == WSMsgType.ERROR:
                    self._drops.drop("ws_error", str(ws.exception()))
        finally:
            pusher.cancel()
            self._clients.discard(client)
            if moved_joystick and not any(True for _ in self._clients):
                self._joy = (0.0, 0.0, time.time())  # the driver left: centre the stick
        return ws

    def _on_text(self, text: str) -> bool:
        try:
            x, y = _parse_joy(text)
        except ValueError as exc:
            self._drops.drop(str(exc), text[:80])
            return False
        self._joy = (x, y, time.time())
        self._counters["joystick_messages"] += 1
        return True

    async def _push(self, client: _Client) -> None:
        """Send a browser what is new: telemetry once per telemetry period, video frames as
        soon as they arrive (latest only per camera)."""
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
                        await ws.send_str(
                            json.dumps({"type": "samples", "samples": new}, allow_nan=False)
                        )
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
