"""The leader's cockpit reachable from the host when the leader runs in a network namespace.

:class:`CockpitRelay` makes the listening socket in the host's namespace and hands it to a
relay process started inside the leader's namespace (``python -m
bipedtele.tools.netns_relay relay FD PORT``), which connects there for each browser
connection. Used with :class:`~bipedtele.tools.netns.VethLink` and
:class:`~bipedtele.tools.netns.EmulatedLink` (``bipedtele demo``).
"""

from __future__ import annotations

import asyncio
import signal
import socket
import subprocess
import sys
from typing import Protocol


class _Namespaces(Protocol):
    """What the relay needs of a link (:class:`~bipedtele.tools.netns.VethLink`, ``EmulatedLink``)."""

    def exec_prefix(self, side: str) -> list[str]:
        """Return the command prefix that runs a program in ``side``'s namespace."""
        ...


__all__ = ["CockpitRelay"]


class CockpitRelay:
    """Relay that makes the leader's cockpit reachable from the host.

    The cockpit listens on ``127.0.0.1:PORT`` in the leader's namespace; the relay serves
    the host's ``127.0.0.1:PORT``.

    The listening socket is made here, in the host's namespace, and handed (inherited
    descriptor) to a relay process started inside the leader's namespace, which connects
    there for each browser connection: one socket in each namespace, no routing between them.

    Parameters
    ----------
    link : VethLink or EmulatedLink
        Created namespaces.
    port : int
        The cockpit's port, the same on both sides.
    side : str
        The leader's side (``LEADER``, ``"leader"``, for a VethLink; ``SIDE_A`` for an EmulatedLink).
    """

    def __init__(self, link: _Namespaces, port: int, side: str = "leader") -> None:
        self.link, self.port, self.side = link, port, side
        self.proc: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> CockpitRelay:
        with socket.socket() as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(("127.0.0.1", self.port))
            sock.listen(16)
            fd = sock.fileno()
            cmd = [
                *self.link.exec_prefix(self.side),
                sys.executable,
                "-m",
                "bipedtele.tools.netns_relay",
                "relay",
                str(fd),
                str(self.port),
            ]
            self.proc = subprocess.Popen(cmd, pass_fds=[fd], start_new_session=True)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5.0)


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        writer.close()


async def _relay(fd: int, port: int) -> None:
    async def on_client(c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        try:
            t_reader, t_writer = await asyncio.open_connection("127.0.0.1", port)
        except OSError:
            c_writer.close()
            return
        await asyncio.gather(_pipe(c_reader, t_writer), _pipe(t_reader, c_writer))

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    server = await asyncio.start_server(on_client, sock=socket.socket(fileno=fd))
    async with server:
        await stop.wait()


def _main(argv: list[str]) -> int:
    """``python -m bipedtele.tools.netns_relay relay FD PORT`` (started by :class:`CockpitRelay`)."""
    if len(argv) != 3 or argv[0] != "relay" or not argv[1].isdigit() or not argv[2].isdigit():
        sys.stderr.write("usage: python -m bipedtele.tools.netns_relay relay FD PORT\n")
        return 2
    asyncio.run(_relay(int(argv[1]), int(argv[2])))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
