"""``bipedtele link-emu``: a user-space per-packet link emulator (an impaired L2 wire).

Forwards Ethernet frames between two interfaces through raw ``AF_PACKET`` sockets, one
bound to each, like a two-port bridge: ARP, IPv4, IPv6, TCP, TLS, UDP and QUIC all run end
to end and see the emulated round trip, retransmissions and losses included. Each
direction applies its own :class:`bipedtele.link.impairments.Direction` (delay model, loss,
rate cap with a byte queue, outages); frames of one direction are never reordered.

One thread, one selector loop: frames are read as they arrive, judged by the model at
their arrival time, and kept in a FIFO per direction until their release time. Frames
the kernel reports as our own sends (``PACKET_OUTGOING``) are skipped, so the bridge never
loops. Segmentation and checksum offloads must be off on the interfaces that *send* into
the wire (the far ends of the veth pairs) so that every frame is one wire packet with a
complete checksum: :func:`disable_offloads` does that without the ``ethtool`` program
(:class:`bipedtele.tools.netns.EmulatedLink` calls it); the emulator itself turns GRO off
on its two interfaces.

Counters per direction are logged every ``--stats-every`` seconds and at the end, and
written as JSON to ``--stats-json`` if given. SIGINT/SIGTERM stop it cleanly.
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import fcntl
import json
import logging
import os
import selectors
import signal
import socket
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.link.delaymodels import ALLOWED_SPECS, parse_delay_model
from bipedtele.link.impairments import (
    ALLOWED_LOSS,
    ALLOWED_OUTAGE,
    ALLOWED_QUEUE,
    ALLOWED_RATE,
    Direction,
    RateQueue,
    Shaper,
    parse_loss,
    parse_outage,
    parse_queue,
    parse_rate,
)
from bipedtele.link.shapers import ALLOWED_TRACE, TokenBucket, TraceRate, load_mahimahi

__all__ = ["LinkEmulator", "add_link_emu_parser", "build_direction", "build_shaper", "disable_offloads", "run"]

LOG = logging.getLogger("bipedtele.tools.linkemu")

ETH_P_ALL = 0x0003
PACKET_OUTGOING = 4
SIOCETHTOOL = 0x8946
# Legacy ethtool "set" commands (struct ethtool_value {u32 cmd; u32 data;}).
_ETHTOOL_SET = {"tx-checksum": 0x17, "sg": 0x19, "tso": 0x1F, "gso": 0x24, "gro": 0x2C}
MAX_FRAME = 65536
BATCH = 256
RCVBUF = 4 * 1024 * 1024
IDLE_S = 0.1


def disable_offloads(dev: str, features: tuple[str, ...] = ("gro", "gso", "tso", "sg", "tx-checksum")) -> list[str]:
    """Turn offloads off on ``dev`` (in the caller's network namespace), like ``ethtool -K``.

    Parameters
    ----------
    dev : str
        Interface name.
    features : tuple of str
        Among ``gro``, ``gso``, ``tso``, ``sg``, ``tx-checksum``.

    Returns
    -------
    list of str
        The features that could not be turned off (with the error), empty when all were.
    """
    failed = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for name in features:
            value = (ctypes.c_uint32 * 2)(_ETHTOOL_SET[name], 0)
            ifreq = struct.pack("16sP", dev.encode()[:15], ctypes.addressof(value)).ljust(40, b"\0")
            try:
                fcntl.ioctl(sock.fileno(), SIOCETHTOOL, ifreq)
            except OSError as exc:
                failed.append(f"{name} ({exc.strerror})")
    return failed


def build_direction(
    delay: str,
    loss: str = "none",
    rate: str = "none",
    queue: str = "64kB",
    outages: list[str] | None = None,
    seed: int = 0,
    burst: str | None = None,
) -> Direction:
    """Build one direction's model from its specs (ConfigError, one line, when one is bad).

    ``rate``: a rate (a FIFO serialising at it; with ``burst``, a token bucket of that many
    bytes, the kernel's tbf) or ``mahimahi:NAME|FILE`` (a capacity trace).
    """
    return Direction(
        parse_delay_model(delay, seed=seed),
        parse_loss(loss, seed=seed + 1000),
        build_shaper(rate, queue, burst),
        [parse_outage(o) for o in outages or []],
    )


def build_shaper(rate: str, queue: str = "64kB", burst: str | None = None) -> Shaper | None:
    """Build the bottleneck of ``--rate``, ``--queue`` and ``--burst`` (None: none; ConfigError when bad)."""
    size = parse_queue(queue)
    if rate.strip().startswith("mahimahi:"):
        if burst is not None:
            raise ConfigError(f"--burst {burst!r} with --rate {rate!r}; allowed: a burst with a rate in bits/s only")
        return TraceRate(load_mahimahi(rate.strip().removeprefix("mahimahi:")), size)
    bps = parse_rate(rate)
    if bps is None:
        if burst is not None:
            raise ConfigError(f"--burst {burst!r} without a rate; allowed: a burst with --rate RATE")
        return None
    if burst is None:
        return RateQueue(bps, size)
    return TokenBucket(bps, parse_queue(burst), size)


@dataclass
class _Port:
    """One interface: its socket and the FIFO of frames waiting to be sent out of it."""

    dev: str
    sock: socket.socket
    pending: collections.deque[tuple[float, bytes]] = field(default_factory=collections.deque)


class LinkEmulator:
    """Forward frames between two interfaces, impaired per direction.

    Parameters
    ----------
    dev_a, dev_b : str
        Interfaces (in this process's namespace); ``forward`` is a -> b.
    forward, backward : Direction
        The two directions' models.
    t_origin : float
        Model time of the start [s] (0: the models' origin is the start; a demo passes
        ``time.time() - T0`` so that traces line up with its other processes).
    clock : callable
        Monotonic clock [s].
    """

    def __init__(
        self,
        dev_a: str,
        dev_b: str,
        forward: Direction,
        backward: Direction,
        t_origin: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.dev_a, self.dev_b = dev_a, dev_b
        self.forward, self.backward = forward, backward
        self.clock = clock
        self._offset = t_origin - clock()
        self.send_errors = 0
        self.oversize = 0
        self._ports: list[_Port] = []

    def now(self) -> float:
        """Model time [s]."""
        return self.clock() + self._offset

    def open(self) -> None:
        """Bind one raw socket to each interface (needs CAP_NET_RAW)."""
        for dev in (self.dev_a, self.dev_b):
            failed = disable_offloads(dev, ("gro",))
            if failed:
                LOG.debug("link-emu: %s: could not turn off %s", dev, ", ".join(failed))
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF)
                sock.bind((dev, ETH_P_ALL))
            except OSError:
                sock.close()
                self.close()
                raise
            sock.setblocking(False)
            self._ports.append(_Port(dev, sock))

    def close(self) -> None:
        """Close the sockets (frames still waiting are dropped)."""
        for port in self._ports:
            port.sock.close()
        self._ports = []

    def stats(self) -> dict[str, Any]:
        """Return the counters as a JSON-ready dict."""
        return {
            "t_s": round(self.now(), 3),
            "forward": {"dev": f"{self.dev_a}->{self.dev_b}", **self.forward.counters.as_dict()},
            "backward": {"dev": f"{self.dev_b}->{self.dev_a}", **self.backward.counters.as_dict()},
            "send_errors": self.send_errors,
            "oversize_frames": self.oversize,
        }

    def log_stats(self) -> None:
        """Log one line per direction."""
        for name, d in (("forward", self.forward), ("backward", self.backward)):
            c = d.counters
            LOG.info(
                "link-emu %s: %d frames (%d B) forwarded; dropped loss %d, queue %d, outage %d; queue max %d B",
                name,
                c.forwarded,
                c.forwarded_bytes,
                c.dropped["loss"],
                c.dropped["queue"],
                c.dropped["outage"],
                c.queue_bytes_max,
            )

    def run(
        self, stop: Callable[[], bool], stats_every_s: float = 10.0, on_stats: Callable[[], None] | None = None
    ) -> None:
        """Forward until ``stop()`` returns True (checked at least every 0.1 s)."""
        if not self._ports:
            self.open()
        a, b = self._ports
        routes = {a.sock.fileno(): (self.forward, b), b.sock.fileno(): (self.backward, a)}
        sel = selectors.DefaultSelector()
        for port in (a, b):
            sel.register(port.sock, selectors.EVENT_READ, port)
        next_stats = self.clock() + stats_every_s
        try:
            while not stop():
                self._release(a)
                self._release(b)
                heads = [p.pending[0][0] for p in (a, b) if p.pending]
                wait = min([IDLE_S, *(h - self.now() for h in heads)])
                for key, _ in sel.select(max(0.0, wait)):
                    src: _Port = key.data
                    self._receive(src, *routes[src.sock.fileno()])
                if self.clock() >= next_stats:
                    next_stats += stats_every_s
                    self.log_stats()
                    if on_stats is not None:
                        on_stats()
        finally:
            sel.close()

    def _receive(self, port: _Port, model: Direction, out: _Port) -> None:
        for _ in range(BATCH):
            try:
                frame, addr = port.sock.recvfrom(MAX_FRAME)
            except BlockingIOError:
                return
            if addr[2] == PACKET_OUTGOING:
                continue
            if len(frame) > 1518:
                self.oversize += 1
                if self.oversize == 1:
                    LOG.warning(
                        "link-emu: %d-byte frame on %s: turn off segmentation offloads on the sender",
                        len(frame),
                        port.dev,
                    )
            verdict = model.admit(self.now(), len(frame))
            if verdict.release_s is not None:
                out.pending.append((verdict.release_s, frame))

    def _release(self, port: _Port) -> None:
        now = self.now()
        while port.pending and port.pending[0][0] <= now:
            _, frame = port.pending.popleft()
            try:
                port.sock.send(frame)
            except OSError as exc:
                self.send_errors += 1
                if self.send_errors == 1:
                    LOG.warning("link-emu: cannot send a %d-byte frame on %s: %s", len(frame), port.dev, exc.strerror)


def _write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def run(args: argparse.Namespace) -> int:
    """``bipedtele link-emu``: forward until SIGINT/SIGTERM."""
    if args.a == args.b:
        raise ConfigError(f"--a and --b are both {args.a!r}; allowed: two different interfaces")
    if not args.stats_every > 0:
        raise ConfigError(f"--stats-every {args.stats_every}: allowed: a number of seconds > 0")
    forward = build_direction(
        args.forward,
        args.loss_forward,
        args.rate_forward,
        args.queue_forward,
        args.outage_forward,
        args.seed,
        args.burst_forward,
    )
    backward = build_direction(
        args.backward,
        args.loss_backward,
        args.rate_backward,
        args.queue_backward,
        args.outage_backward,
        args.seed + 1,
        args.burst_backward,
    )
    t_origin = time.time() - args.t0 if args.t0 is not None else 0.0
    emu = LinkEmulator(args.a, args.b, forward, backward, t_origin=t_origin)
    try:
        emu.open()
    except OSError as exc:
        raise ConfigError(
            f"--a {args.a!r} / --b {args.b!r}: cannot open a raw socket ({exc.strerror}); allowed: existing interfaces, as root"
        ) from None
    stopping: list[int] = []

    def on_signal(signum: int, _frame: object) -> None:
        stopping.append(signum)

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    stats_path = Path(args.stats_json) if args.stats_json else None
    dump = (lambda: _write_json(stats_path, emu.stats())) if stats_path is not None else None
    sys.stdout.write(f"link-emu: forwarding {args.a} <-> {args.b}\n")
    sys.stdout.flush()
    try:
        emu.run(lambda: bool(stopping), args.stats_every, dump)
    finally:
        emu.close()
        for s, h in old.items():
            signal.signal(s, h)
    emu.log_stats()
    if dump is not None:
        dump()
    return 0


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--a", required=True, metavar="DEV", help="interface of side A")
    p.add_argument("--b", required=True, metavar="DEV", help="interface of side B")
    for name, arrow in (("forward", "a -> b"), ("backward", "b -> a")):
        p.add_argument(
            f"--{name}", default="const:0ms", metavar="MODEL", help=f"{arrow} delay model (default const:0ms)"
        )
        p.add_argument(
            f"--loss-{name}", default="none", metavar="SPEC", help=f"{arrow} loss: {ALLOWED_LOSS}".replace("%", "%%")
        )
        p.add_argument(
            f"--rate-{name}",
            default="none",
            metavar="RATE",
            help=f"{arrow} rate cap: {ALLOWED_RATE}; or a capacity trace: {ALLOWED_TRACE}",
        )
        p.add_argument(
            f"--burst-{name}",
            default=None,
            metavar="SIZE",
            help=f"{arrow} token bucket of SIZE bytes at the rate (the kernel's tbf): {ALLOWED_QUEUE} (default: none, a FIFO)",
        )
        p.add_argument(
            f"--queue-{name}",
            default="64kB",
            metavar="SIZE",
            help=f"{arrow} queue of the rate cap: {ALLOWED_QUEUE} (default 64kB)",
        )
        p.add_argument(
            f"--outage-{name}",
            action="append",
            default=[],
            metavar="SPEC",
            help=f"{arrow} outage (repeatable): {ALLOWED_OUTAGE}",
        )
    p.add_argument("--seed", type=int, default=0, help="seed of the random models (default 0)")
    p.add_argument(
        "--t0",
        type=float,
        default=None,
        metavar="UNIX_TIME",
        help="time origin of the models and outages (default: start)",
    )
    p.add_argument(
        "--stats-every", type=float, default=10.0, metavar="S", help="log the counters every S seconds (default 10)"
    )
    p.add_argument(
        "--stats-json", default=None, metavar="FILE", help="also write the counters to FILE (JSON) then and at exit"
    )


DESCRIPTION = (
    "Per-packet link emulator: bridges two interfaces through raw sockets, delaying, losing, "
    f"rate-limiting and cutting each direction. MODEL: {ALLOWED_SPECS}. Needs root."
)


def add_link_emu_parser(sub: Any) -> None:
    """Register ``bipedtele link-emu``."""
    p = sub.add_parser(
        "link-emu", help="per-packet link emulator between two interfaces (root)", description=DESCRIPTION
    )
    _add_arguments(p)
    p.set_defaults(func=run)


def _main(argv: list[str]) -> int:
    """``python -m bipedtele.tools.linkemu ARGS`` (what EmulatedLink starts; same as the sub-command)."""
    from bipedtele.cli import OneLineParser

    parser = OneLineParser(prog="bipedtele link-emu", description=DESCRIPTION)
    _add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return run(args)
    except ConfigError as exc:
        sys.stderr.write(f"bipedtele link-emu: config error: {exc}\n")
        return 2


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
