"""Two network namespaces joined by a veth pair: a two-host link on one machine.

Used by ``bipedtele demo --delay-backend netem``: the leader runs in one namespace, the
follower and the router in the other, and all their traffic crosses the veth pair, whose
two ends each carry a netem qdisc (see :mod:`bipedtele.tools.netem_trace`). Needs root
(``ip netns``). The namespaces have unique names; the same addresses in every pair do no
harm since each pair is isolated from the rest.

Removal kills the processes still inside the two namespaces (only those: ``ip netns
pids``) and deletes the namespaces, which deletes the veth pair with them.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from types import TracebackType

__all__ = ["FOLLOWER", "LEADER", "CockpitRelay", "NetnsError", "VethLink"]

LOG = logging.getLogger(__name__)

LEADER, FOLLOWER = "leader", "follower"


class NetnsError(RuntimeError):
    """The namespaces or the veth pair could not be made (one line: the command and why)."""


def _run(cmd: list[str], timeout: float = 20.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)


@dataclass
class VethLink:
    """Two network namespaces joined by a veth pair.

    Namespaces ``bt-dl-TAG`` (leader side) and ``bt-df-TAG`` (follower side), veth ends
    ``btdl-TAG`` and ``btdf-TAG``.

    Parameters
    ----------
    tag : str
        Makes the names unique (default: 4 random hex digits).
    leader_ip, follower_ip : str
        Addresses of the two veth ends, in one /30.

    Attributes
    ----------
    ns, dev : dict
        Namespace and veth device name of each side (``LEADER``, ``FOLLOWER``).
    """

    tag: str = field(default_factory=lambda: secrets.token_hex(2))
    leader_ip: str = "10.233.0.1"
    follower_ip: str = "10.233.0.2"
    prefix: int = 30
    ns: dict[str, str] = field(init=False)
    dev: dict[str, str] = field(init=False)
    created: list[str] = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        self.ns = {LEADER: f"bt-dl-{self.tag}", FOLLOWER: f"bt-df-{self.tag}"}
        self.dev = {LEADER: f"btdl-{self.tag}", FOLLOWER: f"btdf-{self.tag}"}

    def ip(self, side: str) -> str:
        """Address of one side's veth end."""
        return self.leader_ip if side == LEADER else self.follower_ip

    def setup_commands(self) -> list[list[str]]:
        """Return the ``ip`` commands that make the two namespaces and the veth pair."""
        l_ns, f_ns = self.ns[LEADER], self.ns[FOLLOWER]
        l_dev, f_dev = self.dev[LEADER], self.dev[FOLLOWER]
        return [
            ["ip", "netns", "add", l_ns],
            ["ip", "netns", "add", f_ns],
            ["ip", "link", "add", l_dev, "type", "veth", "peer", "name", f_dev],
            ["ip", "link", "set", l_dev, "netns", l_ns],
            ["ip", "link", "set", f_dev, "netns", f_ns],
            ["ip", "-n", l_ns, "addr", "add", f"{self.leader_ip}/{self.prefix}", "dev", l_dev],
            ["ip", "-n", f_ns, "addr", "add", f"{self.follower_ip}/{self.prefix}", "dev", f_dev],
            ["ip", "-n", l_ns, "link", "set", "lo", "up"],
            ["ip", "-n", f_ns, "link", "set", "lo", "up"],
            ["ip", "-n", l_ns, "link", "set", l_dev, "up"],
            ["ip", "-n", f_ns, "link", "set", f_dev, "up"],
        ]

    def teardown_commands(self) -> list[list[str]]:
        """Return the commands :meth:`remove` runs (after killing what runs inside)."""
        return [["ip", "netns", "del", self.ns[LEADER]], ["ip", "netns", "del", self.ns[FOLLOWER]]]

    def exec_prefix(self, side: str) -> list[str]:
        """Command prefix that runs a program inside one side's namespace."""
        return ["ip", "netns", "exec", self.ns[side]]

    def create(self) -> VethLink:
        """Make the namespaces and the veth pair (undone if a step fails).

        Raises
        ------
        NetnsError
            Not root, no ``ip``, or a step failed (its command and error in one line).
        """
        if shutil.which("ip") is None:
            raise NetnsError("the `ip` command (iproute2) is not installed")
        if os.geteuid() != 0:
            raise NetnsError("network namespaces need root")
        try:
            for cmd in self.setup_commands():
                res = _run(cmd)
                if res.returncode != 0:
                    err = (res.stderr.strip().splitlines() or ["failed"])[0]
                    raise NetnsError(f"`{' '.join(cmd)}`: {err}")
                if cmd[:3] == ["ip", "netns", "add"]:
                    self.created.append(cmd[3])
                elif cmd[:3] == ["ip", "link", "add"]:
                    self.created.append(f"veth:{self.dev[LEADER]}")
        except BaseException:
            self.remove()
            raise
        LOG.info(
            "netns: %s (%s %s) <-> %s (%s %s)",
            self.ns[LEADER], self.dev[LEADER], self.leader_ip, self.ns[FOLLOWER], self.dev[FOLLOWER], self.follower_ip,
        )
        return self

    def namespaces(self) -> list[str]:
        """Return the namespaces made so far (and not yet deleted)."""
        return [n for n in self.created if not n.startswith("veth:")]

    def pids(self) -> list[int]:
        """Return the processes inside the two namespaces."""
        out: list[int] = []
        for ns in self.namespaces():
            res = _run(["ip", "netns", "pids", ns])
            out += [int(p) for p in res.stdout.split() if p.isdigit()]
        return out

    def remove(self, grace_s: float = 5.0) -> None:
        """Stop what runs inside (TERM, then KILL after ``grace_s``), delete both namespaces."""
        pids = self.pids()
        for sig in (signal.SIGTERM, signal.SIGKILL):
            for pid in pids:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, sig)
            deadline = time.monotonic() + (grace_s if sig == signal.SIGTERM else 2.0)
            while pids and time.monotonic() < deadline:
                time.sleep(0.05)
                pids = self.pids()
            if not pids:
                break
        for ns in self.namespaces():
            res = _run(["ip", "netns", "del", ns])
            if res.returncode != 0:
                LOG.warning("netns: cannot delete %s: %s", ns, res.stderr.strip())
            else:
                self.created.remove(ns)
        veth = f"veth:{self.dev[LEADER]}"
        if veth in self.created:
            # gone with its namespace, unless a step failed before it was moved there
            if _run(["ip", "link", "show", "dev", self.dev[LEADER]]).returncode == 0:
                _run(["ip", "link", "del", "dev", self.dev[LEADER]])
            self.created.remove(veth)
        LOG.info("netns: removed %s and %s", self.ns[LEADER], self.ns[FOLLOWER])

    def __enter__(self) -> VethLink:
        return self.create()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.remove()


class CockpitRelay:
    """Relay that makes the leader's cockpit reachable from the host.

    The cockpit listens on ``127.0.0.1:PORT`` in the leader's namespace; the relay serves
    the host's ``127.0.0.1:PORT``.

    The listening socket is made here, in the host's namespace, and handed (inherited
    descriptor) to a relay process started inside the leader's namespace, which connects
    there for each browser connection: one socket in each namespace, no routing between them.

    Parameters
    ----------
    link : VethLink
        Created namespaces.
    port : int
        The cockpit's port, the same on both sides.
    """

    def __init__(self, link: VethLink, port: int) -> None:
        self.link, self.port = link, port
        self.proc: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> CockpitRelay:
        with socket.socket() as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(("127.0.0.1", self.port))
            sock.listen(16)
            fd = sock.fileno()
            cmd = [*self.link.exec_prefix(LEADER), sys.executable, "-m", "bipedtele.tools.netns", "relay", str(fd), str(self.port)]
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
    """``python -m bipedtele.tools.netns relay FD PORT`` (started by :class:`CockpitRelay`)."""
    if len(argv) != 3 or argv[0] != "relay" or not argv[1].isdigit() or not argv[2].isdigit():
        sys.stderr.write("usage: python -m bipedtele.tools.netns relay FD PORT\n")
        return 2
    asyncio.run(_relay(int(argv[1]), int(argv[2])))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
