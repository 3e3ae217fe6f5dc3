"""The split layout's UDP control link under forged datagrams, in network namespaces.

Layout (the test makes both namespaces and the veth pair, and removes them)::

    namespace b32a-r-XXXX (router's host)                 namespace b32a-f-XXXX (robot's host)
    router tls/udp 10.232.N.1:7447, leader   ==veth==   follower (split: TLS + UDP links)

The three folders of ``bipedtele setup two-hosts --router-name 10.232.N.1`` (mutual TLS,
logins, the ACL, the message key, ``links = "split"``), run as the README says, the
leader's pilot replaced by a constant-speed script. An attacker forges datagrams with the
addresses of the real UDP link (a raw socket: the receiving kernel cannot tell them from
the peer's):

- to the follower's UDP port, from the router's address and port: a Zenoh Close (``23 00``);
- to the router's UDP port, from the follower's address and port: 40 bytes of garbage (an
  unknown message id, then random bytes: ``udp_spoof.py --garbage``);
- then the router's datagrams to the follower's UDP port are dropped in the robot's host
  (a NAT that rebound the port, a filter): the link is dead at one end, TLS still passes;
- last, a Zenoh Close to the leader's UDP port, from the router's address.

Each may cost a stop and a reconnect, never the robot: it walks again within 3 s, with
one log line on each side naming what happened, and nobody is restarted.
"""

from __future__ import annotations

import json
import re
import secrets
import shutil
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from adversary_support import counters, recorded_feedback, wait_recorded_state
from bipedtele.recording.format import read_records
from e2e_support import CLI, HERE, NO_VIDEO, Proc, Procs, walking_script

SPOOF = str(HERE / "udp_spoof.py")
PORT = 7447
#: The log line of each side naming the cause of a lost link.
LINE = {
    "follower": r"WARNING bipedtele\.link\.relink",
    "leader": r"WARNING bipedtele\.link\.relink",
    "router": r"WARNING bipedtele\.tools\.router: client \S+ lost",
}
#: The robot must walk again within this long of the attack [s] (the leader commands all along).
WALK_AGAIN_S = 3.0


@dataclass
class Hosts:
    """The router's and the robot's namespaces and addresses."""

    router_ns: str
    robot_ns: str
    router_ip: str
    robot_ip: str


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20)


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    """``b32a-r-XXXX`` (10.232.N.1/30) and ``b32a-f-XXXX`` (10.232.N.2/30) on a veth pair; removed after."""
    for tool in ("ip", "openssl", "ss"):
        if shutil.which(tool) is None:
            pytest.skip(f"needs `{tool}` (scripts/bootstrap.sh --test installs iproute2 and openssl)")
    tag = secrets.token_hex(2)
    n = int(tag, 16) % 250 + 2
    h = Hosts(f"b32a-r-{tag}", f"b32a-f-{tag}", f"10.232.{n}.1", f"10.232.{n}.2")
    made: list[str] = []
    try:
        for ns in (h.router_ns, h.robot_ns):
            r = _ip("netns", "add", ns)
            if r.returncode != 0:
                pytest.skip(f"cannot create network namespaces (needs root): {r.stderr.strip()}")
            made.append(ns)
        vr, vf = f"b32ar-{tag}", f"b32af-{tag}"
        for step in (
            ("link", "add", vr, "type", "veth", "peer", "name", vf),
            ("link", "set", vr, "netns", h.router_ns),
            ("link", "set", vf, "netns", h.robot_ns),
            ("-n", h.router_ns, "addr", "add", f"{h.router_ip}/30", "dev", vr),
            ("-n", h.robot_ns, "addr", "add", f"{h.robot_ip}/30", "dev", vf),
            ("-n", h.router_ns, "link", "set", vr, "up"),
            ("-n", h.robot_ns, "link", "set", vf, "up"),
            ("-n", h.router_ns, "link", "set", "lo", "up"),
            ("-n", h.robot_ns, "link", "set", "lo", "up"),
        ):
            r = _ip(*step)
            assert r.returncode == 0, f"ip {' '.join(step)}: {r.stderr}"
        yield h
    finally:
        for ns in made:
            for pid in _ip("netns", "pids", ns).stdout.split():  # only what runs inside our own namespace
                subprocess.run(["kill", "-KILL", pid], capture_output=True, timeout=10)
            _ip("netns", "del", ns)


def _udp_peer_ports(ns: str, peer_ip: str) -> list[tuple[int, int]]:
    """(local port, peer port) of the UDP sockets in ``ns`` connected to ``peer_ip``'s router port."""
    out = subprocess.run(["ip", "netns", "exec", ns, "ss", "-Hun"], capture_output=True, text=True, timeout=20).stdout
    found = []
    for line in out.splitlines():
        cols = line.split()
        local, peer = cols[-2], cols[-1]
        if peer == f"{peer_ip}:{PORT}" and not local.endswith(f":{PORT}"):
            found.append((int(local.rpartition(":")[2]), int(peer.rpartition(":")[2])))
    return found


def _spoof(procs: Procs, ns: str, src: str, dst: str, extra: list[str]) -> None:
    p = procs.start("spoof", [SPOOF, "--src", src, "--dst", dst, *extra], raw=True, netns=ns)
    assert p.popen.wait(timeout=30) == 0, p.tail()


def _lines(p: Proc, pattern: str) -> list[str]:
    return [line for line in p.log().splitlines() if re.search(pattern, line)]


def _attack_and_recover(procs: Procs, hosts: Hosts, rec: Path, which: str, logs: dict[str, Proc]) -> dict[str, Any]:
    """One attack on a UDP link (module docstring); when the robot walked again, the log lines."""
    ns, ip = (hosts.router_ns, hosts.router_ip) if which == "close-leader" else (hosts.robot_ns, hosts.robot_ip)
    found = _udp_peer_ports(ns, hosts.router_ip)
    assert found, f"before the {which} attack: no UDP link to the router in {ns} (control not on UDP)"
    (local, peer), *_ = found
    before = {name: len(_lines(p, LINE[name])) for name, p in logs.items()}
    t_attack = time.time()
    if which in ("close", "close-leader"):  # to the client's UDP port, as if from the router
        _spoof(procs, hosts.router_ns, f"{hosts.router_ip}:{peer}", f"{ip}:{local}", ["--hex", "2300"])
    elif which == "garbage":  # to the router's UDP port, as if from the follower's control link
        _spoof(procs, hosts.robot_ns, f"{hosts.robot_ip}:{local}", f"{hosts.router_ip}:{peer}", ["--garbage", "40"])
    else:  # dead: the router's datagrams to that port vanish (a NAT that rebound it), TLS still passes
        r = subprocess.run(
            [
                "ip",
                "netns",
                "exec",
                hosts.robot_ns,
                "iptables",
                "-A",
                "INPUT",
                "-p",
                "udp",
                "--dport",
                str(local),
                "-j",
                "DROP",
            ],
            capture_output=True,
            text=True,
            timeout=20,
        )
        assert r.returncode == 0, r.stderr
    t_walk = wait_recorded_state(rec, "walking", t_attack, timeout_s=20.0, hold_s=1.0)
    time.sleep(2.0)  # the log lines of the recovery (the router judges a loss after 0.3 s)
    out: dict[str, Any] = {"walk_again_s": round(t_walk - t_attack, 2)}
    out.update({name: _lines(p, LINE[name])[before[name] :] for name, p in logs.items()})
    out["stopped"] = any(s != "walking" for t, s in recorded_feedback(rec) if t_attack <= t <= t_walk)
    return out


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_forged_udp_datagrams_cost_at_most_a_stop(hosts: Hosts, procs: Procs, tmp_path: Path) -> None:
    setup = tmp_path / "setup"
    r = subprocess.run(
        [*CLI, "setup", "two-hosts", "--router-name", hosts.router_ip, "--out", str(setup)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    f_rec = tmp_path / "follower.mcap"
    router = procs.start("router", ["router", "--config", f"{setup}/router/bipedtele.toml"], netns=hosts.router_ns)
    router.wait_log(r"router: \S+ listening on", 30.0)
    follower = procs.start(
        "follower",
        ["follower", "--config", f"{setup}/robot/bipedtele.toml", *NO_VIDEO, "--record", str(f_rec)],
        netns=hosts.robot_ns,
    )
    l_rec = tmp_path / "leader.mcap"
    leader = procs.start(
        "leader",
        ["leader", "--config", f"{setup}/operator/bipedtele.toml", *walking_script(5.0), "--record", str(l_rec)],
        netns=hosts.router_ns,
    )
    follower.wait_log(r"follower \S+ ready", 60.0)
    leader.wait_log(r"leader ready", 60.0)
    wait_recorded_state(f_rec, "walking", 0.0, timeout_s=40.0, hold_s=1.5)
    pids = {p.name: p.pid for p in (router, follower, leader)}
    logs = {"follower": follower, "leader": leader, "router": router}
    results: dict[str, Any] = {}
    for which in ("close", "garbage", "dead", "close-leader"):
        results[which] = res = _attack_and_recover(procs, hosts, f_rec, which, logs)
        print(which, json.dumps(res, indent=1))
        assert res["walk_again_s"] <= WALK_AGAIN_S, (which, res)
        # one line on each side naming the cause: the client attacked, and the router (a link dead at
        # the robot's end is invisible to the router)
        client = "leader" if which == "close-leader" else "follower"
        assert len(res[client]) == 1, (which, res[client])
        assert len(res["router"]) == (0 if which == "dead" else 1), (which, res["router"])
    assert "closed" in results["close"]["follower"][0], results["close"]
    assert "udp" in results["garbage"]["follower"][0] and "closed" in results["garbage"]["follower"][0]
    assert "lost its udp link" in results["garbage"]["router"][0]
    assert "control link silent" in results["dead"]["follower"][0], results["dead"]
    assert "closed" in results["close-leader"]["leader"][0], results["close-leader"]
    # the follower's Status says where control travels: its own UDP link again, reopened three times
    time.sleep(1.5)
    last = counters(list(read_records(f_rec)))[-1][1]
    assert last["control_link"] == 1 and last["relinks"] == 3, last
    # and so does the leader's status line (its recorded samples): control on its own UDP link
    controls = [r.data.get("control_link") for r in read_records(l_rec) if r.topic == "leader/state"]
    assert controls and controls[-1] == "udp", controls[-5:]
    # nobody was restarted, nothing crashed
    for p in (router, follower, leader):
        assert p.alive() and p.pid == pids[p.name], p.tail()
        assert "Traceback" not in p.log(), p.tail(40)
