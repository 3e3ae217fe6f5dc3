"""Network namespaces for emulated links on one machine.

:class:`VethLink`: two namespaces joined by a veth pair: a two-host link.

Used by ``bipedtele demo --delay-backend netem``: the leader runs in one namespace, the
follower and the router in the other, and all their traffic crosses the veth pair, whose
two ends each carry a netem qdisc (see :mod:`bipedtele.tools.netem_trace`). Needs root
(``ip netns``). The namespaces have unique names; the same addresses in every pair do no
harm since each pair is isolated from the rest.

Removal kills the processes still inside the two namespaces (only those: ``ip netns
pids``) and deletes the namespaces, which deletes the veth pair with them.

:class:`EmulatedLink`: three namespaces, side A, side B and a middle one where the
per-packet link emulator (``bipedtele link-emu``) bridges the two veth pairs: A and B share
one subnet, so the emulator is a transparent, impaired wire between them.

:class:`~bipedtele.tools.netns_relay.CockpitRelay` (the leader's cockpit reachable from
the host) lives in :mod:`bipedtele.tools.netns_relay`; it is imported here too.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import select
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from bipedtele.tools.netns_relay import CockpitRelay

__all__ = ["FOLLOWER", "LEADER", "MIDDLE", "SIDE_A", "SIDE_B", "CockpitRelay", "EmulatedLink", "NetnsError", "VethLink"]

LOG = logging.getLogger(__name__)

LEADER, FOLLOWER = "leader", "follower"


class NetnsError(RuntimeError):
    """The namespaces or the veth pair could not be made (one line: the command and why)."""


def _run(cmd: list[str], timeout: float = 20.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)


def _require_ip_and_root() -> None:
    """Raise NetnsError unless ``ip`` is installed and this process is root."""
    if shutil.which("ip") is None:
        raise NetnsError("the `ip` command (iproute2) is not installed")
    if os.geteuid() != 0:
        raise NetnsError("network namespaces need root")


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
        _require_ip_and_root()
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
            self.ns[LEADER],
            self.dev[LEADER],
            self.leader_ip,
            self.ns[FOLLOWER],
            self.dev[FOLLOWER],
            self.follower_ip,
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


SIDE_A, SIDE_B, MIDDLE = "a", "b", "mid"
#: What ``ethtool -K DEV ...`` would turn off on the veth ends that send into the wire.
WIRE_OFFLOADS = ("gro", "gso", "tso", "sg", "tx-checksum")


@dataclass
class EmulatedLink:
    """Side A and side B joined through the per-packet link emulator in a third namespace.

    ::

        ns A: dev[a] a_ip  ==veth==  dev[ma] | ns mid: link-emu | dev[mb]  ==veth==  dev[b] b_ip :ns B

    Namespaces ``bt-ea-TAG``, ``bt-eb-TAG``, ``bt-em-TAG``. The emulator (``python -m
    bipedtele.tools.linkemu --a dev[ma] --b dev[mb] ARGS``, forward = A -> B) starts on
    entering the context (or :meth:`start_emulator`), and is waited for until it forwards.
    Offloads are off on the A and B ends (every frame one wire packet); the middle ends
    have no addresses (no IPv6 autoconfiguration) and are promiscuous.

    Parameters
    ----------
    emulator_args : list of str
        Arguments of ``link-emu`` after ``--a``/``--b``, e.g. ``["--forward",
        "const:100ms", "--backward", "const:100ms", "--loss-forward", "1%"]``.
    tag : str
        Makes the names unique (default: 4 random hex digits).
    a_ip, b_ip : str
        Addresses of the two sides, in one ``/prefix``.
    log_path : Path, optional
        The emulator's log (stderr); default ``/tmp/bt-linkemu-TAG.log``.
    autostart : bool
        Start the emulator when entering the context.

    Attributes
    ----------
    ns, dev : dict
        Namespace and device names (keys ``SIDE_A``, ``SIDE_B``, ``MIDDLE``; devices also
        ``"ma"``, ``"mb"``: the middle's ends).
    """

    emulator_args: list[str] = field(default_factory=list)
    tag: str = field(default_factory=lambda: secrets.token_hex(2))
    a_ip: str = "10.234.0.1"
    b_ip: str = "10.234.0.2"
    prefix: int = 24
    log_path: Path | None = None
    autostart: bool = True
    ns: dict[str, str] = field(init=False)
    dev: dict[str, str] = field(init=False)
    created: list[str] = field(default_factory=list, init=False)
    hosts: dict[str, str] = field(default_factory=dict, init=False)
    emulator: subprocess.Popen[bytes] | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        t = self.tag
        self.ns = {SIDE_A: f"bt-ea-{t}", SIDE_B: f"bt-eb-{t}", MIDDLE: f"bt-em-{t}"}
        self.dev = {SIDE_A: f"btea-{t}", SIDE_B: f"bteb-{t}", "ma": f"btma-{t}", "mb": f"btmb-{t}"}
        if self.log_path is None:
            self.log_path = Path(f"/tmp/bt-linkemu-{t}.log")

    def ip(self, side: str) -> str:
        """Address of side A or B (or of a host added with :meth:`add_host`, by namespace)."""
        return {SIDE_A: self.a_ip, SIDE_B: self.b_ip, **self.hosts}[side]

    def exec_prefix(self, side: str) -> list[str]:
        """Command prefix that runs a program in a side's namespace (``SIDE_A``, ``SIDE_B``, ``MIDDLE`` or a host's namespace)."""
        return ["ip", "netns", "exec", self.ns.get(side, side)]

    def setup_commands(self) -> list[list[str]]:
        """Return the commands that make the topology (``ethtool`` steps run as ioctls)."""
        n, d = self.ns, self.dev
        cmds = [["ip", "netns", "add", n[k]] for k in (SIDE_A, SIDE_B, MIDDLE)]
        for side, inner in ((SIDE_A, "ma"), (SIDE_B, "mb")):
            ip = self.ip(side)
            cmds += [
                ["ip", "link", "add", d[side], "type", "veth", "peer", "name", d[inner]],
                [
                    "ethtool",
                    "-K",
                    d[side],
                    *(x for f in WIRE_OFFLOADS for x in (f.replace("tx-checksum", "tx"), "off")),
                ],
                ["ethtool", "-K", d[inner], "gro", "off"],
                ["ip", "link", "set", d[side], "netns", n[side]],
                ["ip", "link", "set", d[inner], "netns", n[MIDDLE]],
                ["ip", "-n", n[side], "addr", "add", f"{ip}/{self.prefix}", "dev", d[side]],
                ["ip", "-n", n[side], "link", "set", "lo", "up"],
                ["ip", "-n", n[side], "link", "set", d[side], "up"],
                ["ip", "-n", n[MIDDLE], "link", "set", d[inner], "addrgenmode", "none"],
                ["ip", "-n", n[MIDDLE], "link", "set", d[inner], "promisc", "on", "up"],
            ]
        return cmds

    def teardown_commands(self) -> list[list[str]]:
        """Return the namespace deletions :meth:`remove` runs (after stopping what runs inside)."""
        return [["ip", "netns", "del", n] for n in (*self.ns.values(), *self.hosts)]

    def _step(self, cmd: list[str]) -> None:
        if cmd[0] == "ethtool":
            from bipedtele.tools.linkemu import disable_offloads

            names = {"tx": "tx-checksum"}
            failed = disable_offloads(cmd[2], tuple(names.get(x, x) for x in cmd[3::2]))
            if failed:
                raise NetnsError(f"`{' '.join(cmd)}`: cannot turn off {', '.join(failed)}")
            return
        res = _run(cmd)
        if res.returncode != 0:
            err = (res.stderr.strip().splitlines() or ["failed"])[0]
            raise NetnsError(f"`{' '.join(cmd)}`: {err}")
        if cmd[:3] == ["ip", "netns", "add"]:
            self.created.append(cmd[3])
        elif cmd[:3] == ["ip", "link", "add"]:
            self.created.append(f"veth:{cmd[3]}")

    def create(self) -> EmulatedLink:
        """Make the namespaces and veth pairs (undone if a step fails); no emulator yet.

        Raises
        ------
        NetnsError
            Not root, no ``ip``, or a step failed (its command and error in one line).
        """
        _require_ip_and_root()
        try:
            for cmd in self.setup_commands():
                self._step(cmd)
        except BaseException:
            self.remove()
            raise
        LOG.info(
            "netns: %s (%s) <-> link-emu in %s <-> %s (%s)",
            self.ns[SIDE_A],
            self.a_ip,
            self.ns[MIDDLE],
            self.ns[SIDE_B],
            self.b_ip,
        )
        return self

    def pin_neighbours(self) -> None:
        """Make A's and B's ARP entries for each other permanent (no ARP crosses a lossy wire)."""
        mac = {}
        for side in (SIDE_A, SIDE_B):
            out = _run(["ip", "-n", self.ns[side], "-o", "link", "show", "dev", self.dev[side]]).stdout.split()
            mac[side] = out[out.index("link/ether") + 1]
        for side, other in ((SIDE_A, SIDE_B), (SIDE_B, SIDE_A)):
            self._step(
                [
                    "ip",
                    "-n",
                    self.ns[side],
                    "neigh",
                    "replace",
                    self.ip(other),
                    "lladdr",
                    mac[other],
                    "dev",
                    self.dev[side],
                    "nud",
                    "permanent",
                ]
            )

    def add_host(self, side: str, ip: str) -> str:
        """Put a new namespace behind side A or B, on a bridge in that side's namespace.

        The first call for a side moves its address from its veth end onto a bridge
        ``br0`` there (the side's own processes keep working). Returns the new
        namespace's name (``bt-eh<N>-TAG``; use it with :meth:`exec_prefix`); ``ip`` must
        be in the link's subnet.
        """
        n, d = self.ns[side], self.dev[side]
        k = len(self.hosts)
        host_ns, outer, inner = f"bt-eh{k}-{self.tag}", f"bth{k}-{self.tag}", f"bthp{k}-{self.tag}"
        cmds: list[list[str]] = []
        if _run(["ip", "-n", n, "link", "show", "dev", "br0"]).returncode != 0:
            cmds += [
                ["ip", "-n", n, "link", "add", "br0", "type", "bridge"],
                ["ip", "-n", n, "link", "set", d, "master", "br0"],
                ["ip", "-n", n, "addr", "del", f"{self.ip(side)}/{self.prefix}", "dev", d],
                ["ip", "-n", n, "addr", "add", f"{self.ip(side)}/{self.prefix}", "dev", "br0"],
                ["ip", "-n", n, "link", "set", "br0", "up"],
            ]
        cmds += [
            ["ip", "netns", "add", host_ns],
            ["ip", "link", "add", outer, "type", "veth", "peer", "name", inner],
            ["ip", "link", "set", outer, "netns", n],
            ["ip", "link", "set", inner, "netns", host_ns],
            ["ip", "-n", n, "link", "set", outer, "master", "br0", "up"],
            ["ip", "-n", host_ns, "addr", "add", f"{ip}/{self.prefix}", "dev", inner],
            ["ip", "-n", host_ns, "link", "set", "lo", "up"],
            ["ip", "-n", host_ns, "link", "set", inner, "up"],
        ]
        for cmd in cmds:
            self._step(cmd)
        self.hosts[host_ns] = ip
        return host_ns

    def start_emulator(self, args: list[str] | None = None, timeout_s: float = 20.0) -> None:
        """Start (or restart) the emulator with ``args`` (default ``emulator_args``); wait until it forwards.

        Raises
        ------
        NetnsError
            The emulator exited or did not report ready within ``timeout_s`` (with its log's last line).
        """
        self.stop_emulator()
        if args is not None:
            self.emulator_args = list(args)
        cmd = [
            *self.exec_prefix(MIDDLE),
            sys.executable,
            "-m",
            "bipedtele.tools.linkemu",
            "--a",
            self.dev["ma"],
            "--b",
            self.dev["mb"],
            *self.emulator_args,
        ]
        assert self.log_path is not None
        with open(self.log_path, "ab") as log:
            self.emulator = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, start_new_session=True)
        out = self.emulator.stdout
        assert out is not None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            ready, _, _ = select.select([out], [], [], 0.1)
            if ready:
                line = out.readline()
                if line.startswith(b"link-emu: forwarding"):
                    return
                if not line:
                    break
        self.stop_emulator()
        tail = (self.log_path.read_text(errors="replace").strip().splitlines() or ["no output"])[-1]
        raise NetnsError(f"link-emu did not start: {tail} (log: {self.log_path})")

    def stop_emulator(self, grace_s: float = 5.0) -> int | None:
        """Stop the emulator (SIGTERM, then SIGKILL); return its exit code (None: none ran)."""
        proc, self.emulator = self.emulator, None
        if proc is None:
            return None
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5.0)
        if proc.stdout is not None:
            proc.stdout.close()
        return proc.returncode

    def namespaces(self) -> list[str]:
        """Return the namespaces made so far (and not yet deleted)."""
        return [n for n in self.created if not n.startswith("veth:")]

    def remove(self, grace_s: float = 5.0) -> None:
        """Stop the emulator and what else runs in the namespaces, delete them (and the veths)."""
        self.stop_emulator(grace_s)
        _kill_inside(self.namespaces(), grace_s)
        for ns in self.namespaces():
            res = _run(["ip", "netns", "del", ns])
            if res.returncode != 0:
                LOG.warning("netns: cannot delete %s: %s", ns, res.stderr.strip())
            else:
                self.created.remove(ns)
        for item in [c for c in self.created if c.startswith("veth:")]:
            dev = item[5:]  # gone with its namespace, unless a step failed before it was moved
            if _run(["ip", "link", "show", "dev", dev]).returncode == 0:
                _run(["ip", "link", "del", "dev", dev])
            self.created.remove(item)
        self.hosts.clear()

    def __enter__(self) -> EmulatedLink:
        self.create()
        if self.autostart:
            try:
                self.start_emulator()
            except BaseException:
                self.remove()
                raise
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.remove()


def _ns_pids(namespaces: list[str]) -> list[int]:
    out: list[int] = []
    for ns in namespaces:
        res = _run(["ip", "netns", "pids", ns])
        out += [int(p) for p in res.stdout.split() if p.isdigit()]
    return out


def _kill_inside(namespaces: list[str], grace_s: float) -> None:
    """SIGTERM the processes inside ``namespaces`` (only those), SIGKILL after ``grace_s``."""
    pids = _ns_pids(namespaces)
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        deadline = time.monotonic() + (grace_s if sig == signal.SIGTERM else 2.0)
        while pids and time.monotonic() < deadline:
            time.sleep(0.05)
            pids = _ns_pids(namespaces)
        if not pids:
            return
