"""The internet bench's hosts: three network namespaces around the emulator, the README's programs in them.

``bipedtele setup two-hosts`` once (:func:`setup_two_hosts`), its folders copied into each
host's working folder (:func:`copy_hosts`), the namespaces and the emulator between them
(:func:`topology`), each program started in its host (:func:`start`, :class:`Proc`), the
kernel's tbf on the robot's interface (:func:`shape_robot`) and the operator's sockets
(:func:`operator_sockets`). Used by ``bench/internet.py``.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from bipedtele.tools.netns import SIDE_A, SIDE_B, EmulatedLink

REPO = Path(__file__).resolve().parent.parent


CLI = [sys.executable, "-m", "bipedtele.cli"]


ROUTER_NAME = "router.bt.test"


PORT = 7447


HOSTS = ("router", "robot", "operator")


@dataclass
class Proc:
    name: str
    popen: subprocess.Popen[bytes]
    log_path: Path

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def tail(self, n: int = 15) -> str:
        return "\n".join(self.log().splitlines()[-n:])

    def wait_log(self, pattern: str, timeout_s: float) -> None:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while not rx.search(self.log()):
            if not self.alive():
                raise RuntimeError(
                    f"{self.name} exited (rc {self.popen.returncode}) before {pattern!r}:\n{self.tail()}"
                )
            if time.monotonic() > deadline:
                raise RuntimeError(f"{self.name}: no {pattern!r} within {timeout_s:g} s:\n{self.tail()}")
            time.sleep(0.1)

    def stop(self, timeout_s: float = 10.0) -> int | None:
        if self.alive():
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.popen.pid, signal.SIGTERM)
            try:
                return self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.popen.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            return self.popen.wait(timeout=5.0)
        return None


def start(name: str, args: list[str], *, netns: str, cwd: Path, log_dir: Path) -> Proc:
    """``ip netns exec NS python -m bipedtele.cli ARGS`` in ``cwd``, output to ``log_dir/NAME.log``."""
    log_path = log_dir / f"{name}.log"
    with open(log_path, "wb") as log:
        popen = subprocess.Popen(
            ["ip", "netns", "exec", netns, *CLI, *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            cwd=cwd,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    return Proc(name, popen, log_path)


def setup_two_hosts(out: Path) -> dict[str, list[str]]:
    """Run ``bipedtele setup two-hosts`` once; return host -> the printed command (after ``bipedtele``)."""
    r = subprocess.run(
        [*CLI, "setup", "two-hosts", "--router-name", ROUTER_NAME, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    if r.returncode != 0:
        raise RuntimeError(f"setup two-hosts failed: {r.stderr.strip()}")
    commands = {}
    for host in HOSTS:
        m = re.search(rf"^\s*{host}:\s+bipedtele (.+)$", r.stdout, re.MULTILINE)
        if not m:
            raise RuntimeError(f"setup did not print the {host}'s command:\n{r.stdout}")
        commands[host] = m.group(1).split()
    return commands


def copy_hosts(setup_out: Path, run_dir: Path, links: str | None) -> dict[str, Path]:
    """Copy each host folder into ``run_dir/host-H/`` (modes kept); set ``links`` if given."""
    homes = {}
    for host in HOSTS:
        home = run_dir / f"host-{host}"
        home.mkdir(parents=True)
        shutil.copytree(setup_out / host, home / host)
        if links is not None:
            prof = home / host / "bipedtele.toml"
            text, n = re.subn(r'^links = "[a-z-]+"', f'links = "{links}"', prof.read_text(), flags=re.MULTILINE)
            if n != 1:
                raise RuntimeError(f"{prof}: no `links = ...` line to rewrite")
            prof.write_text(text)
        homes[host] = home
    return homes


@dataclass
class Topology:
    link: EmulatedLink
    ns: dict[str, str]  # host -> namespace
    ip: dict[str, str]
    etc: list[Path] = field(default_factory=list)

    def remove(self) -> None:
        self.link.remove()
        for d in self.etc:
            shutil.rmtree(d, ignore_errors=True)


@contextlib.contextmanager
def topology(kind: str, emulator_log: Path, tag: str | None = None) -> Iterator[Topology]:
    """The three hosts around the emulator (not started yet); torn down on exit (``tag``: 4 characters of the names)."""
    tag = tag or secrets.token_hex(2)
    n = secrets.randbelow(250) + 2
    a_ip, b_ip, c_ip = f"10.235.{n}.1", f"10.235.{n}.2", f"10.235.{n}.3"
    link = EmulatedLink([], tag=tag, a_ip=a_ip, b_ip=b_ip, log_path=emulator_log, autostart=False)
    top = Topology(link, {}, {})
    try:
        link.create()
        link.pin_neighbours()  # no ARP request crosses a lossy wire
        third = link.add_host(SIDE_B, c_ip)
        alone = "operator" if kind == "intercontinental" else "robot"
        other = "robot" if kind == "intercontinental" else "operator"
        top.ns = {alone: link.ns[SIDE_A], "router": link.ns[SIDE_B], other: third}
        top.ip = {alone: a_ip, "router": b_ip, other: c_ip}
        for ns in top.ns.values():
            d = Path("/etc/netns") / ns  # `ip netns exec` mounts d/hosts over /etc/hosts
            d.mkdir(parents=True, exist_ok=True)
            top.etc.append(d)
            (d / "hosts").write_text(f"127.0.0.1 localhost\n{top.ip['router']} {ROUTER_NAME}\n")
        yield top
    finally:
        top.remove()


def operator_sockets(ns: str, out: Path) -> dict[str, int]:
    """Count the operator host's TCP and UDP sockets to the router's port (``ss``), saved to ``out``."""
    r = subprocess.run(["ip", "netns", "exec", ns, "ss", "-tuanp"], capture_output=True, text=True, timeout=20)
    out.write_text(r.stdout + r.stderr)
    mine = [ln.split() for ln in r.stdout.splitlines() if f":{PORT} " in ln + " "]
    return {
        "tcp": sum(1 for w in mine if w and w[0] == "tcp" and w[1] == "ESTAB"),
        "udp": sum(1 for w in mine if w and w[0] == "udp"),
    }


def shape_robot(top: Topology, tbf: tuple[str, ...]) -> None:
    """The kernel's tbf on the robot's egress, before the (then transparent) emulator."""
    dev = top.link.dev[SIDE_A]
    tc = ["ip", "netns", "exec", top.ns["robot"], "tc", "qdisc", "add", "dev", dev, "root", "tbf", *tbf]
    r = subprocess.run(tc, capture_output=True, text=True, timeout=20)
    if r.returncode != 0:
        raise RuntimeError(f"tc tbf: {r.stderr.strip()}")
