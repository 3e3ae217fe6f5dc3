"""User-space TCP relay that delays each direction independently (no root needed).

Every chunk of bytes read from one side is released to the other side at its arrival
time plus the delay of the direction's model evaluated at that arrival time, and never
before the chunk that arrived before it (byte order is kept, like on a real link, so a
falling delay makes chunks queue behind earlier ones).

Zenoh over it: the follower listens on ``tcp/127.0.0.1:P``; the proxy listens on ``Q``
and targets ``P``; the leader connects to ``tcp/127.0.0.1:Q``. ``forward`` is the
leader -> follower direction (client -> target), ``backward`` the other.

Zenoh batches messages on TCP; since each chunk is delayed at its own arrival time,
every message in it sees the model's delay.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.link.delaymodels import ALLOWED_SPECS, DelayModel, parse_delay_model

__all__ = ["DelayProxy", "DirectionStats", "add_delay_proxy_parser", "parse_hostport"]

LOG = logging.getLogger("bipedtele.tools.delayproxy")
CHUNK = 256 * 1024


def parse_hostport(text: str, what: str = "address") -> tuple[str, int]:
    """Parse ``HOST:PORT`` (``[v6]:PORT`` for IPv6).

    Raises
    ------
    ConfigError
        One line with what is allowed.
    """
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(f"{what} {text!r}: allowed: HOST:PORT with PORT in [0, 65535]")
    return host, int(port)


@dataclass
class DirectionStats:
    """Counters of one direction.

    Attributes
    ----------
    chunks, bytes : int
        Relayed so far.
    late_s : list of float
        For the last chunks (bounded), release lateness: actual write time minus the
        scheduled release time [s] (>= 0; scheduler and event-loop latency).
    """

    chunks: int = 0
    bytes: int = 0
    late_s: list[float] = field(default_factory=list)

    def record_late(self, late: float, keep: int = 10000) -> None:
        """Keep how late [s] a chunk went out (the last ``keep`` values)."""
        self.late_s.append(late)
        if len(self.late_s) > keep:
            del self.late_s[: len(self.late_s) - keep]


class DelayProxy:
    """Asyncio TCP relay with per-direction delay models.

    Parameters
    ----------
    listen : (host, port)
        Where to accept clients (port 0: any free port, see :attr:`port`).
    target : (host, port)
        Where to connect for each client.
    forward : DelayModel
        Delay of client -> target bytes.
    backward : DelayModel
        Delay of target -> client bytes.
    t0 : float, optional
        Time origin of the models (unix time [s]): a model is evaluated at
        ``time.time() - t0``. Default: when the proxy starts. Lets a test or a second
        proxy align with a trace.
    """

    def __init__(
        self,
        listen: tuple[str, int],
        target: tuple[str, int],
        forward: DelayModel,
        backward: DelayModel,
        t0: float | None = None,
    ) -> None:
        self.listen = listen
        self.target = target
        self.forward = forward
        self.backward = backward
        self.t0 = t0
        self.stats = {"forward": DirectionStats(), "backward": DirectionStats()}
        self.connections = 0
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._writers: set[asyncio.StreamWriter] = set()
        self._handlers: set[asyncio.Task[Any]] = set()

    @property
    def port(self) -> int:
        """The port actually listened on (after :meth:`start`)."""
        if self._server is None:
            raise RuntimeError("proxy not started")
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        """Start listening."""
        if self.t0 is None:
            self.t0 = time.time()
        self._server = await asyncio.start_server(self._on_client, *self.listen, reuse_address=True)
        LOG.info(
            "delay-proxy listening on %s:%d -> %s:%d (forward %s, backward %s)",
            self.listen[0],
            self.port,
            *self.target,
            self.forward.spec,
            self.backward.spec,
        )

    async def close(self) -> None:
        """Stop listening and close every connection."""
        if self._server is not None:
            self._server.close()
        for w in list(self._writers):
            w.close()
        pending = [*self._tasks, *self._handlers]
        for t in pending:
            t.cancel()
        if pending:
            await asyncio.gather(*pending, return_exceptions=True)
        if self._server is not None:
            await self._server.wait_closed()
        self._server = None

    async def __aenter__(self) -> DelayProxy:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    def _spawn(self, coro: Any) -> asyncio.Task[None]:
        task: asyncio.Task[None] = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    async def _on_client(self, c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._handlers.add(task)
        try:
            await self._relay(c_reader, c_writer)
        except asyncio.CancelledError:
            # the proxy is closing: end normally (asyncio's stream callback would log a
            # cancelled handler as an error)
            c_writer.close()
        finally:
            if task is not None:
                self._handlers.discard(task)

    async def _relay(self, c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        self._writers.add(c_writer)
        try:
            t_reader, t_writer = await asyncio.open_connection(*self.target)
        except OSError as exc:
            LOG.warning("delay-proxy: cannot connect to %s:%d (%s); closing client", *self.target, exc)
            c_writer.close()
            self._writers.discard(c_writer)
            return
        self._writers.add(t_writer)
        for w in (c_writer, t_writer):
            sock = w.get_extra_info("socket")
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.connections += 1
        peer = c_writer.get_extra_info("peername")
        LOG.info("delay-proxy: connection %d from %s", self.connections, peer)
        done = asyncio.Event()
        a = self._spawn(self._pipe(c_reader, t_writer, self.forward, self.stats["forward"], done))
        b = self._spawn(self._pipe(t_reader, c_writer, self.backward, self.stats["backward"], done))
        with contextlib.suppress(asyncio.CancelledError):  # the proxy is closing
            await done.wait()
        # One side closed (and its pending bytes were delivered): close both sides.
        for w in (c_writer, t_writer):
            w.close()
            self._writers.discard(w)
        for t in (a, b):
            t.cancel()
        await asyncio.gather(a, b, return_exceptions=True)
        LOG.info("delay-proxy: connection from %s closed", peer)

    async def _pipe(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        model: DelayModel,
        stats: DirectionStats,
        done: asyncio.Event,
    ) -> None:
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue()
        t0 = self.t0 if self.t0 is not None else time.time()

        async def read() -> None:
            last = -float("inf")
            try:
                while True:
                    data = await reader.read(CHUNK)
                    now = loop.time()
                    if not data:
                        break
                    release = max(now + model.delay_s(time.time() - t0), last)
                    last = release
                    queue.put_nowait((release, data))
            except (ConnectionError, OSError):
                pass
            finally:
                queue.put_nowait(None)

        reader_task = loop.create_task(read())
        try:
            while True:
                item = await queue.get()
                if item is None:
                    break
                release, data = item
                wait = release - loop.time()
                if wait > 0:
                    await asyncio.sleep(wait)
                stats.record_late(max(0.0, loop.time() - release))
                writer.write(data)
                stats.chunks += 1
                stats.bytes += len(data)
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            reader_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader_task
            done.set()


# --------------------------------------------------------------------------- command


def _model(spec: str, seed: int) -> DelayModel:
    return parse_delay_model(spec, seed=seed)


async def serve(proxy: DelayProxy, stop: asyncio.Event, ready: Callable[[int], None] | None = None) -> None:
    """Run ``proxy`` until ``stop`` is set."""
    async with proxy:
        if ready is not None:
            ready(proxy.port)
        await stop.wait()


def run(args: argparse.Namespace) -> int:
    """``bipedtele delay-proxy``: run until SIGINT/SIGTERM."""
    listen = parse_hostport(args.listen, "--listen")
    target = parse_hostport(args.target, "--target")
    forward = _model(args.forward, args.seed)
    backward = _model(args.backward, args.seed + 1)
    proxy = DelayProxy(listen, target, forward, backward, t0=args.t0)

    def ready(port: int) -> None:
        print(f"delay-proxy: listening on {listen[0]}:{port} -> {target[0]}:{target[1]}", flush=True)  # noqa: T201 (CLI output)

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        try:
            await serve(proxy, stop, ready)
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(sig)

    try:
        asyncio.run(main())
    except OSError as exc:
        raise ConfigError(f"--listen {args.listen!r}: cannot listen ({exc.strerror})") from None
    for name, st in proxy.stats.items():
        LOG.info("delay-proxy %s: %d chunks, %d bytes", name, st.chunks, st.bytes)
    return 0


def add_delay_proxy_parser(sub: Any) -> None:
    """Register ``bipedtele delay-proxy``."""
    p = sub.add_parser(
        "delay-proxy",
        help="TCP relay that delays each direction (no root)",
        description=f"User-space TCP relay with independent delay models. MODEL: {ALLOWED_SPECS}.",
    )
    p.add_argument("--listen", required=True, metavar="HOST:PORT", help="where clients connect (port 0: any)")
    p.add_argument("--target", required=True, metavar="HOST:PORT", help="where the proxy connects")
    p.add_argument("--forward", required=True, metavar="MODEL", help="client -> target delay model")
    p.add_argument("--backward", required=True, metavar="MODEL", help="target -> client delay model")
    p.add_argument("--seed", type=int, default=0, help="seed of the random models (default 0)")
    p.add_argument(
        "--t0",
        type=float,
        default=None,
        metavar="UNIX_TIME",
        help="time origin of the models in unix seconds (default: proxy start)",
    )
    p.set_defaults(func=run)
