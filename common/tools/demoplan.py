"""What ``bipedtele demo`` starts: the processes' command lines and the delay backend's plan.

A :class:`DemoPlan` is built from the demo's arguments (:mod:`bipedtele.tools.demo`, which
runs it); it can be inspected without starting anything (``--dry-run``, the tests): the
command line of each process (:meth:`DemoPlan.commands`), and the netem or packet
backend's setup, replay and teardown (:meth:`DemoPlan.netem_plan`,
:meth:`DemoPlan.packet_plan`).
"""

from __future__ import annotations

import secrets
import shlex
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from bipedtele.link.delaymodels import parse_delay_model
from bipedtele.tools.netem_trace import schedule
from bipedtele.tools.netns import FOLLOWER, LEADER, MIDDLE, SIDE_A, SIDE_B, EmulatedLink, VethLink

__all__ = ["DemoPlan", "free_port"]


def free_port() -> int:
    """Return a TCP port on 127.0.0.1 that is free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class DemoPlan:
    """Everything the demo starts; built from the arguments, inspectable by tests."""

    run_dir: Path
    profile: str
    overrides: list[str]
    forward: str
    backward: str
    operator: str
    duration_s: float | None
    headless: bool
    record: Path
    router_port: int = field(default_factory=free_port)
    proxy_port: int = field(default_factory=free_port)
    cockpit_port: int = field(default_factory=free_port)
    follower_args: list[str] = field(default_factory=list)
    leader_args: list[str] = field(default_factory=list)
    t0: float = field(default_factory=time.time)
    backend: str = "proxy"
    #: The cockpit's per-run access token (given to the leader in its environment).
    cockpit_token: str = field(default_factory=lambda: secrets.token_urlsafe(24))
    link: VethLink | EmulatedLink | None = None
    #: Impairment arguments of ``link-emu`` besides the delays (packet backend).
    impairments: list[str] = field(default_factory=list)
    #: netem options per end besides the delays (netem backend: loss, rate, limit).
    netem_extra: dict[str, list[str]] = field(default_factory=dict)

    def emulator_args(self) -> list[str]:
        """Return the ``link-emu`` arguments of the packet backend (forward = leader -> follower)."""
        return [
            "--forward",
            self.forward,
            "--backward",
            self.backward,
            "--t0",
            f"{self.t0:.6f}",
            "--stats-json",
            str(self.run_dir / "linkemu.json"),
            *self.impairments,
        ]

    def commands(self) -> dict[str, list[str]]:
        """Return the command lines of the processes, in start order.

        Four with the proxy; three with netem, each prefixed by ``ip netns exec NS``.
        """
        exe = [sys.executable, "-m", "bipedtele.cli"]
        common = ["--config", self.profile]
        if self.backend in ("netem", "packet"):
            # a per-packet path carries UDP: control on its own best-effort link (docs/links.md)
            common += ["--set", 'network.links="split"']
        for item in self.overrides:
            common += ["--set", item]
        router_ep, leader_ep, in_l, in_f = self._placement()
        leader = [
            *in_l,
            *exe,
            "leader",
            *common,
            "--set",
            'network.mode="client"',
            "--set",
            f'network.connect=["{leader_ep}"]',
            "--set",
            "network.listen=[]",
            "--set",
            f"leader.cockpit_port={0 if self.headless else self.cockpit_port}",
            "--operator",
            self.operator,
            "--record",
            str(self.record),
            *self.leader_args,
        ]
        if self.duration_s is not None:
            leader += ["--duration", f"{self.duration_s:g}"]
        out = {"router": [*in_f, *exe, "router", *common, "--listen", router_ep]}
        if self.backend == "proxy":
            out["proxy"] = self._proxy_command(exe)
        return {
            **out,
            "follower": [
                *in_f,
                *exe,
                "follower",
                *common,
                "--set",
                'network.mode="client"',
                "--set",
                f'network.connect=["{router_ep}"]',
                "--set",
                "network.listen=[]",
                "--record",
                str(self.run_dir / "follower.mcap"),
                *self.follower_args,
            ],
            "leader": leader,
        }

    def _placement(self) -> tuple[str, str, list[str], list[str]]:
        """Return where the processes run: the router's endpoint, the leader's, and the leader's and follower's prefixes.

        netem and packet: across the veth pair or the emulated wire, each side in its
        namespace (``ip netns exec NS``); proxy: on 127.0.0.1, the leader through the proxy.
        """
        if self.backend == "netem":
            if not isinstance(self.link, VethLink):
                raise ValueError("the netem backend needs a VethLink")
            router_ep = f"tcp/{self.link.follower_ip}:{self.router_port}"
            return router_ep, router_ep, self.link.exec_prefix(LEADER), self.link.exec_prefix(FOLLOWER)
        if self.backend == "packet":
            if not isinstance(self.link, EmulatedLink):
                raise ValueError("the packet backend needs an EmulatedLink")
            router_ep = f"tcp/{self.link.b_ip}:{self.router_port}"
            return router_ep, router_ep, self.link.exec_prefix(SIDE_A), self.link.exec_prefix(SIDE_B)
        return f"tcp/127.0.0.1:{self.router_port}", f"tcp/127.0.0.1:{self.proxy_port}", [], []

    def _proxy_command(self, exe: list[str]) -> list[str]:
        """Return the delay proxy's command line (proxy backend): h1 forward, h2 backward."""
        return [
            *exe,
            "delay-proxy",
            "--listen",
            f"127.0.0.1:{self.proxy_port}",
            "--target",
            f"127.0.0.1:{self.router_port}",
            "--forward",
            self.forward,
            "--backward",
            self.backward,
            "--t0",
            f"{self.t0:.6f}",
        ]

    def netem_plan(self, t_end: float) -> list[str]:
        """Return the netem backend's commands as text lines: setup, ``tc`` over time, teardown.

        Parameters
        ----------
        t_end : float
            How far to list the trace replay [s].
        """
        if not isinstance(self.link, VethLink):
            raise ValueError("the netem backend needs a VethLink")
        link = self.link
        lines = [
            f"# netem backend: leader in {link.ns[LEADER]} ({link.dev[LEADER]} {link.leader_ip}), "
            f"follower and router in {link.ns[FOLLOWER]} ({link.dev[FOLLOWER]} {link.follower_ip})",
            "# setup",
            *(" ".join(c) for c in link.setup_commands()),
            f"# qdiscs: h1 {self.forward} on {link.dev[LEADER]}, h2 {self.backward} on "
            f"{link.dev[FOLLOWER]}; seconds after the start, then the command",
        ]
        forward, backward = parse_delay_model(self.forward), parse_delay_model(self.backward)
        lines += [
            f"{s.t:.3f} {' '.join(s.command)}" for s in schedule(link, forward, backward, t_end, self.netem_extra)
        ]
        lines += [
            "# teardown (after stopping the processes inside the namespaces)",
            *(" ".join(c) for c in link.teardown_commands()),
        ]
        return lines

    def packet_plan(self) -> list[str]:
        """Return the packet backend's setup, emulator and teardown commands as text lines."""
        if not isinstance(self.link, EmulatedLink):
            raise ValueError("the packet backend needs an EmulatedLink")
        link = self.link
        emu = [
            *link.exec_prefix(MIDDLE),
            sys.executable,
            "-m",
            "bipedtele.tools.linkemu",
            "--a",
            link.dev["ma"],
            "--b",
            link.dev["mb"],
            *self.emulator_args(),
        ]
        return [
            f"# packet backend: leader in {link.ns[SIDE_A]} ({link.a_ip}), follower and router in "
            f"{link.ns[SIDE_B]} ({link.b_ip}), link-emu in {link.ns[MIDDLE]}",
            "# setup (the ethtool steps run as ioctls)",
            *(" ".join(c) for c in link.setup_commands()),
            "# emulator (forward = leader -> follower = h1, backward = h2)",
            shlex.join(emu),
            "# teardown (after stopping the processes inside the namespaces)",
            *(" ".join(c) for c in link.teardown_commands()),
        ]
