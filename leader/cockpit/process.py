"""The cockpit in its own process: a flood of the web server never takes the haptic loop's CPU.

:class:`CockpitProcess` has :class:`~bipedtele.leader.cockpit.server.CockpitServer`'s
interface (``start``/``stop``, ``url``, ``publish_sample``, ``publish_video``,
``joystick``, ``stats``) and runs that server in a child process (``spawn``; niced), so
the leader's interpreter lock and descriptors are never the web server's. Measured with
a token brute force against a real leader (docs/cockpit.md): in the leader's thread the
1 kHz loop missed 1,749-2,954 ticks in 8 s even with the failed-token limit; in a process,
about what it misses at rest.

The leader and the child talk over one pipe (``multiprocessing.Pipe``):

- leader -> child, from a feeder thread at ``telemetry_hz`` (and at once for a new video
  frame): ``b"S"`` + the latest sample as JSON text (encoded once, in the feeder thread),
  ``b"V"`` + a video frame, ``b"T"`` a stats request, ``b"Q"`` stop;
- child -> leader, read by a reader thread: ``("ready", port)``, ``("error", exc)``,
  ``("joy", (x, y, t))`` at each joystick change, ``("stats", dict)``, ``("log", level,
  name, text)`` (the child's log lines, re-logged here: one log, one format).

``publish_sample`` and ``publish_video`` only store a reference (as in the thread
version): the haptic loop never touches the pipe. The child ends when the pipe closes
(the leader stopped or died).
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import struct
import threading
import time
from collections.abc import Iterable, Mapping
from multiprocessing.connection import Connection
from typing import Any

from bipedtele.leader.cockpit.guard import Limits
from bipedtele.leader.cockpit.server import CockpitServer, EncodedSample, _sample_json
from bipedtele.telemetry import LeaderSample

__all__ = ["CockpitProcess"]

LOG = logging.getLogger("bipedtele.leader.cockpit")
_NICE = 10


class CockpitProcess:
    """The browser cockpit served by a child process (same interface as ``CockpitServer``).

    Parameters are :class:`CockpitServer`'s; they are checked here, before the child starts.
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
        force_max_n: float = 8.0,
    ) -> None:
        allowed = list(allowed_hosts)
        course = [(float(ob[0]), float(ob[1]), float(ob[2])) for ob in course]
        # Checks the arguments and draws the token; never started in this process.
        spec = CockpitServer(
            host,
            port,
            telemetry_hz=telemetry_hz,
            history_s=history_s,
            token=token,
            allowed_hosts=allowed,
            max_clients=max_clients,
            course=course,
            limits=limits,
            force_max_n=force_max_n,
        )
        self._spec = spec
        self.host, self.token = spec.host, spec.token
        self.telemetry_hz = spec.telemetry_hz
        self.allowed_hosts = spec.allowed_hosts
        self._kwargs: dict[str, Any] = dict(
            host=host,
            port=port,
            telemetry_hz=telemetry_hz,
            history_s=history_s,
            token=spec.token,
            allowed_hosts=allowed,
            max_clients=max_clients,
            course=course,
            limits=spec.limits,
            force_max_n=spec.force_max_n,
        )
        self._sample: tuple[int, LeaderSample | dict[str, Any]] | None = None
        self._sample_n = 0
        self._frames: dict[str, tuple[int, float, bytes]] = {}
        self._frame_n = 0
        self._joy: tuple[float, float, float] | None = None
        self._released = False
        self._pad: tuple[str, float, float, bool, float] | None = None
        self._stats: dict[str, Any] = {}
        self._stats_event = threading.Event()
        self._send_lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._conn: Connection | None = None
        self._proc: Any = None
        self._threads: list[threading.Thread] = []
        self._port = 0

    # ------------------------------------------------------------------ like CockpitServer

    @property
    def port(self) -> int:
        """The bound TCP port (0 before :meth:`start`)."""
        return self._port

    @property
    def base_url(self) -> str:
        """``http://host:port/`` without the token."""
        self._spec._port = self._port
        return self._spec.base_url

    @property
    def url(self) -> str:
        """The address to open: ``http://host:port/?token=TOKEN``."""
        return f"{self.base_url}?token={self.token}"

    @property
    def cookie_name(self) -> str:
        """Name of the token cookie."""
        return f"bipedtele_cockpit_{self._port}"

    @property
    def pid(self) -> int | None:
        """The child's process id (None before :meth:`start`)."""
        return self._proc.pid if self._proc is not None else None

    def publish_sample(self, sample: LeaderSample | Mapping[str, Any]) -> None:
        """Offer the latest telemetry sample (one reference stored; see ``CockpitServer``)."""
        self._sample_n += 1
        self._sample = (self._sample_n, sample if isinstance(sample, LeaderSample) else dict(sample))

    def publish_video(self, camera: str, jpeg: bytes, t: float) -> None:
        """Offer the latest JPEG of ``camera`` captured at ``t`` [s] (latest only)."""
        self._frame_n += 1
        self._frames[camera] = (self._frame_n, float(t), bytes(jpeg))
        self._wake.set()

    def joystick(self) -> tuple[float, float, float] | None:
        """Return ``(x, y, t)`` as the child last reported it (see ``CockpitServer.joystick``)."""
        return self._joy

    def released(self) -> bool:
        """Return the page's hand as the child last reported it (see ``CockpitServer.released``)."""
        return self._released

    def pad(self) -> tuple[str, float, float, bool, float] | None:
        """Return the page's controller as the child last reported it (see ``CockpitServer.pad``)."""
        return self._pad

    @property
    def stats(self) -> dict[str, Any]:
        """Return the child's counters (the last known ones when it does not answer in 2 s)."""
        if self._conn is not None and self._proc is not None and self._proc.is_alive():
            self._stats_event.clear()
            if self._send(b"T"):
                self._stats_event.wait(2.0)
        return dict(self._stats)

    def start(self, timeout_s: float = 30.0) -> CockpitProcess:
        """Start the child and wait until it listens.

        Raises
        ------
        OSError
            The address cannot be bound.
        RuntimeError
            Already started, or the child did not come up in ``timeout_s`` seconds.
        """
        if self._proc is not None:
            raise RuntimeError("cockpit server already started")
        ctx = multiprocessing.get_context("spawn")  # never fork a process with Zenoh's threads
        mine, theirs = ctx.Pipe(duplex=True)
        self._proc = ctx.Process(target=_child_main, args=(theirs, self._kwargs), name="bipedtele-cockpit", daemon=True)
        self._proc.start()
        theirs.close()
        self._conn = mine
        if not mine.poll(timeout_s):
            self.stop()
            raise RuntimeError("cockpit server did not start in time")
        try:
            first = mine.recv()
        except (EOFError, OSError):
            self.stop()
            raise RuntimeError("cockpit process ended before it listened") from None
        if first[0] == "error":
            self.stop()
            raise first[1]
        self._port = int(first[1])
        for target, name in ((self._reader, "cockpit-reader"), (self._feeder, "cockpit-feeder")):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        LOG.debug("cockpit listening on %s (process %d)", self.base_url, self._proc.pid)
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop the child (its browsers are closed) and the threads that feed it."""
        proc = self._proc
        if proc is None:
            return
        self._stop.set()
        self._wake.set()
        self._send(b"Q")
        proc.join(timeout_s)
        if proc.is_alive():  # pragma: no cover - a stuck child
            LOG.warning("cockpit process did not stop within %.1f s: killing it", timeout_s)
            proc.kill()
            proc.join(5.0)
        if self._conn is not None:
            self._conn.close()
        for t in self._threads:
            t.join(2.0)
        self._threads.clear()
        self._proc = None

    def __enter__(self) -> CockpitProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ leader side threads

    def _send(self, data: bytes) -> bool:
        conn = self._conn
        if conn is None:
            return False
        try:
            with self._send_lock:
                conn.send_bytes(data)
        except (OSError, ValueError):  # the child is gone
            return False
        return True

    def _feeder(self) -> None:
        """Send the latest sample every telemetry period and each new video frame at once."""
        period = 1.0 / self.telemetry_hz
        last_sample = 0
        sent_frames: dict[str, int] = {}
        next_t = time.monotonic()
        while not self._stop.is_set():
            self._wake.wait(max(0.0, next_t - time.monotonic()))
            self._wake.clear()
            if time.monotonic() >= next_t:
                next_t = time.monotonic() + period
                latest = self._sample
                if latest is not None and latest[0] != last_sample:
                    last_sample = latest[0]
                    if not self._send(b"S" + _sample_json(latest[1]).encode()):
                        return
            for camera, (n, t, jpeg) in list(self._frames.items()):
                if n != sent_frames.get(camera):
                    sent_frames[camera] = n
                    name = camera.encode("utf-8", "replace")[:255]
                    if not self._send(b"V" + bytes([len(name)]) + name + struct.pack("<d", t) + jpeg):
                        return

    def _reader(self) -> None:
        """Take the child's joystick, stats and log lines."""
        conn = self._conn
        assert conn is not None
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError, ValueError):
                if not self._stop.is_set():
                    LOG.warning("cockpit process ended (exit code %s)", getattr(self._proc, "exitcode", None))
                return
            kind = msg[0]
            if kind == "joy":
                self._joy = msg[1]
            elif kind == "hand":
                self._released = bool(msg[1])
            elif kind == "pad":
                self._pad = msg[1]
            elif kind == "stats":
                self._stats = msg[1]
                self._stats_event.set()
            elif kind == "log":
                logging.getLogger(msg[2]).log(msg[1], "%s", msg[3])


# ---------------------------------------------------------------------- the child


class _PipeLog(logging.Handler):
    """Send the child's log records to the leader (already throttled by the cockpit's filters)."""

    def __init__(self, send: Any) -> None:
        super().__init__()
        self._send = send

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):
            self._send(("log", record.levelno, record.name, record.getMessage()))


def _child_main(conn: Connection, kwargs: dict[str, Any]) -> None:  # pragma: no cover - runs in the child
    """Serve the cockpit until the leader says stop or goes away."""
    # Ctrl-C and the process group's SIGTERM are the leader's to handle: it stops us (or
    # its end closes the pipe), after it released the robot.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    nice = getattr(os, "nice", None)  # not on Windows
    if nice is not None:
        with contextlib.suppress(OSError):
            nice(_NICE)  # the haptic loop's CPU comes first
    lock = threading.Lock()

    def send(obj: Any) -> None:
        with lock:
            conn.send(obj)

    root = logging.getLogger()
    root.handlers[:] = [_PipeLog(send)]
    root.setLevel(logging.INFO)
    try:
        server = CockpitServer(
            **kwargs,
            on_joystick=lambda joy: send(("joy", joy)),
            on_hand=lambda rel: send(("hand", rel)),
            on_pad=lambda pad: send(("pad", pad)),
        ).start()
    except BaseException as exc:
        send(("error", exc))
        return
    send(("ready", server.port))
    try:
        while True:
            data = conn.recv_bytes()
            kind = data[:1]
            if kind == b"S":
                server.publish_sample(EncodedSample(data[1:].decode()))
            elif kind == b"V":
                n = data[1]
                name = data[2 : 2 + n].decode("utf-8", "replace")
                (t,) = struct.unpack_from("<d", data, 2 + n)
                server.publish_video(name, data[10 + n :], t)
            elif kind == b"T":
                send(("stats", server.stats))
            elif kind == b"Q":
                break
    except (EOFError, OSError):
        pass  # the leader went away
    finally:
        server.stop()
        with contextlib.suppress(OSError):
            conn.close()
