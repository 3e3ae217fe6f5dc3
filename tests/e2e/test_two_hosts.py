"""Two hosts in network namespaces: TLS with user/password through a delayed path.

Layout (the test creates both namespaces and the veth pair, and removes them)::

    namespace bt-l-XXXX (operator's host)          namespace bt-f-XXXX (robot's host)
    leader --tls--> delay proxy 127.0.0.1:P  ==veth==>  router tls/10.231.N.2:7447 <--tls-- follower
                    (h1 forward, h2 backward)   10.231.N.1/30 <-> 10.231.N.2/30

The router requires mutual TLS (certificates from ``scripts/make-certs.sh``) and
user/password authentication, and only the ``leader`` user may publish commands: a client
with the follower's valid identity that publishes stop commands is let in (it receives
feedback) but none of its commands reaches the robot.

Certificates and the delay proxy: the proxy is a plain TCP relay, so TLS runs end to end
between the leader and the router, and the leader checks the router's certificate against
the address it dials: the proxy's ``127.0.0.1``. The router certificate therefore lists
both ``10.231.N.2`` (the follower dials it) and ``127.0.0.1`` in its subjectAltName (zenoh's
TLS, rustls, matches IP SANs). Without ``127.0.0.1`` in the list the leader is refused like an
impostor (``verify_name_on_connect``), so a real deployment with a relay in the path must
name the relay's address or a DNS name both sides resolve.

Refused clients: a client with a wrong password, and a client with the right password but
no client certificate, cannot open a Zenoh session at all; the mutual-TLS handshake or the
user/password exchange is rejected by the router before any session exists, so such a
client never receives a single message, and each is told which refusal it met
(``bipedtele.link.linkcheck.LinkError`` kinds ``credentials`` and ``tls_client_cert``). A client
with valid credentials, same path, does get in.
"""

from __future__ import annotations

import json
import secrets
import shutil
import statistics
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from e2e_support import (
    HERE,
    NO_VIDEO,
    Procs,
    free_port,
    records,
    start_follower,
    start_leader,
    walking_script,
)

FORWARD_S, BACKWARD_S = 0.080, 0.120  # emulated h1 (leader -> follower) and h2 [s]
ROUTER_PORT = 7447
REPO = HERE.parent.parent


@dataclass
class NetnsPair:
    """Two namespaces joined by a veth pair."""

    leader_ns: str
    follower_ns: str
    leader_ip: str
    follower_ip: str


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20)


def _delete(ns: str) -> None:
    pids = _ip("netns", "pids", ns).stdout.split()
    for pid in pids:  # only processes inside our own namespace
        subprocess.run(["kill", "-KILL", pid], capture_output=True, timeout=10)
    _ip("netns", "del", ns)


@pytest.fixture
def netns_pair() -> Iterator[NetnsPair]:
    """Create ``bt-l-XXXX`` and ``bt-f-XXXX`` with 10.231.N.1/30 and .2/30; remove them after."""
    if shutil.which("ip") is None:
        pytest.skip("needs iproute2 (`ip`): scripts/bootstrap.sh --test installs it")
    if shutil.which("openssl") is None:
        pytest.skip("needs openssl for scripts/make-certs.sh: scripts/bootstrap.sh --test installs it")
    tag = secrets.token_hex(2)
    n = int(tag, 16) % 254 + 1
    pair = NetnsPair(f"bt-l-{tag}", f"bt-f-{tag}", f"10.231.{n}.1", f"10.231.{n}.2")
    created: list[str] = []
    try:
        for ns in (pair.leader_ns, pair.follower_ns):
            r = _ip("netns", "add", ns)
            if r.returncode != 0:
                pytest.skip(
                    f"cannot create network namespaces (`ip netns add` needs root/CAP_SYS_ADMIN): {r.stderr.strip()}"
                )
            created.append(ns)
        vl, vf = f"btl-{tag}", f"btf-{tag}"
        steps = [
            ("link", "add", vl, "type", "veth", "peer", "name", vf),
            ("link", "set", vl, "netns", pair.leader_ns),
            ("link", "set", vf, "netns", pair.follower_ns),
            ("-n", pair.leader_ns, "addr", "add", f"{pair.leader_ip}/30", "dev", vl),
            ("-n", pair.follower_ns, "addr", "add", f"{pair.follower_ip}/30", "dev", vf),
            ("-n", pair.leader_ns, "link", "set", vl, "up"),
            ("-n", pair.follower_ns, "link", "set", vf, "up"),
            ("-n", pair.leader_ns, "link", "set", "lo", "up"),
            ("-n", pair.follower_ns, "link", "set", "lo", "up"),
        ]
        for step in steps:
            r = _ip(*step)
            if r.returncode != 0:
                pytest.skip(f"cannot set up the veth pair (`ip {' '.join(step)}`): {r.stderr.strip()}")
        yield pair
    finally:
        for ns in created:
            _delete(ns)  # also removes the veth pair


def _write_profiles(d: Path, pair: NetnsPair, certs: Path) -> dict[str, Path]:
    (d / "creds.txt").write_text("leader:leader-pw\nfollower:follower-pw\n")
    (d / "leader.pw").write_text("leader-pw\n")
    (d / "follower.pw").write_text("follower-pw\n")
    for p in ("creds.txt", "leader.pw", "follower.pw"):
        (d / p).chmod(0o600)
    common = f'[network]\ntls_root_ca = "{certs}/ca.pem"\ntls_mutual = true\ntimeout_s = 10.0\n'
    profiles = {
        "router": common
        + (
            f'tls_cert = "{certs}/router.pem"\ntls_key = "{certs}/router.key"\n'
            f'credentials_file = "{d}/creds.txt"\npublishers_allowed = ["leader"]\nfollowers_allowed = ["follower"]\n'
        ),
        "leader": common
        + (
            f'tls_cert = "{certs}/leader.pem"\ntls_key = "{certs}/leader.key"\n'
            f'user = "leader"\npassword_file = "{d}/leader.pw"\n'
        ),
        "follower": common
        + (
            f'tls_cert = "{certs}/follower.pem"\ntls_key = "{certs}/follower.key"\n'
            f'user = "follower"\npassword_file = "{d}/follower.pw"\n'
        ),
    }
    out = {}
    for name, text in profiles.items():
        out[name] = d / f"{name}.toml"
        out[name].write_text(text)
    return out


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(180)
def test_two_hosts_tls_userpwd_delay_proxy(netns_pair: NetnsPair, procs: Procs, tmp_path: Path) -> None:
    pair = netns_pair
    certs = tmp_path / "certs"
    subprocess.run(
        ["bash", str(REPO / "scripts" / "make-certs.sh"), str(certs), pair.follower_ip, "127.0.0.1"],
        check=True,
        capture_output=True,
        timeout=60,
    )
    prof = _write_profiles(tmp_path, pair, certs)
    router_ep = f"tls/{pair.follower_ip}:{ROUTER_PORT}"
    proxy_port = free_port()  # any port: the leader namespace has nothing else listening
    proxy_ep = f"tls/127.0.0.1:{proxy_port}"
    f_rec, l_rec = tmp_path / "follower.mcap", tmp_path / "leader.mcap"

    router = procs.start(
        "router", ["router", "--config", str(prof["router"]), "--listen", router_ep], netns=pair.follower_ns
    )
    router.wait_log(r"router: \S+ listening on", 30.0)
    proxy = procs.start(
        "proxy",
        [
            "delay-proxy",
            "--listen",
            f"127.0.0.1:{proxy_port}",
            "--target",
            f"{pair.follower_ip}:{ROUTER_PORT}",
            "--forward",
            f"const:{FORWARD_S * 1000:g}ms",
            "--backward",
            f"const:{BACKWARD_S * 1000:g}ms",
        ],
        netns=pair.leader_ns,
    )
    follower = start_follower(
        procs,
        router_ep,
        ["--config", str(prof["follower"]), *NO_VIDEO],
        netns=pair.follower_ns,
        record=f_rec,
        wait=False,
    )
    leader = start_leader(
        procs,
        proxy_ep,
        ["--config", str(prof["leader"]), *walking_script(5.0)],
        netns=pair.leader_ns,
        record=l_rec,
        wait=False,
    )
    follower.wait_log(r"follower \S+ ready", 60.0)
    leader.wait_log(r"leader ready", 60.0)

    # Who gets in, from the operator's namespace through the same proxy, while the robot walks.
    zc = [str(HERE / "zclient.py"), "--connect", proxy_ep, "--ca", str(certs / "ca.pem"), "--seconds", "2"]
    mine = ["--cert", str(certs / "leader.pem"), "--key", str(certs / "leader.key")]
    clients = {
        "valid": procs.start(
            "client-valid", [*zc, *mine, "--user", "leader", "--password", "leader-pw"], raw=True, netns=pair.leader_ns
        ),
        "wrong_password": procs.start(
            "client-wrongpw", [*zc, *mine, "--user", "leader", "--password", "guess"], raw=True, netns=pair.leader_ns
        ),
        "no_client_cert": procs.start(
            "client-nocert", [*zc, "--user", "leader", "--password", "leader-pw"], raw=True, netns=pair.leader_ns
        ),
        # a valid identity that is not the leader tries to stop the robot: the router's
        # access control drops its commands
        "follower_commands": procs.start(
            "client-rogue",
            [
                *zc,
                "--cert",
                str(certs / "follower.pem"),
                "--key",
                str(certs / "follower.key"),
                "--user",
                "follower",
                "--password",
                "follower-pw",
                "--put-cmd",
            ],
            raw=True,
            netns=pair.leader_ns,
        ),
    }
    results = {}
    for name, c in clients.items():
        assert c.popen.wait(timeout=60) == 0, c.tail()
        results[name] = json.loads(c.log().strip().splitlines()[-1])

    time.sleep(3.0)  # a few seconds of teleoperation through the delayed TLS path
    t_teleop_end = time.time()
    assert leader.stop() == 0, leader.tail()
    assert follower.stop() == 0, follower.tail()
    assert proxy.stop() == 0, proxy.tail()
    assert router.stop() == 0, router.tail()

    # ---- who was let in
    assert results["valid"]["opened"] and results["valid"]["feedback"] > 10, results["valid"]
    for name, kind in (("wrong_password", "credentials"), ("no_client_cert", "tls_client_cert")):
        r = results[name]
        assert not r["opened"] and r["feedback"] == 0, (name, r)
        assert r.get("kind") == kind, (name, r)  # each refusal names its cause

    rogue = results["follower_commands"]
    # let in, but its role (follower) neither commands nor reads the leader's feedback
    assert rogue["opened"] and rogue["put_cmd"] > 20 and rogue["feedback"] == 0, rogue

    # ---- commands reached the follower, feedback reached the leader, with the emulated delays
    cmds = records(f_rec, "cmd/recv")
    assert rogue["sid"] not in {r.data["sid"] for r in cmds}, "a non-leader's command reached the robot"
    assert len(cmds) > 100 and len({r.data["sid"] for r in cmds}) == 1
    events = [r.data for r in records(f_rec, "events")]
    assert not any(e["event"] == "operator_stop" and e["t"] < t_teleop_end for e in events), events
    fbs = [r.data for r in records(f_rec, "feedback/sent")]
    assert sum(1 for d in fbs if d["state"] == "walking") > 100
    assert not any(d["state"] == "fallen" for d in fbs)
    fb_recv = records(l_rec, "feedback/recv")
    assert len(fb_recv) > 100

    # one-way delays of each message (one clock: both namespaces share the host's)
    h1_msgs = statistics.median(r.t_recv - r.data["t"] for r in cmds)
    h2_msgs = statistics.median(r.t_recv - r.data["t"] for r in fb_recv)
    # the programs' own 1 s moving-average estimates, once warm
    states = [r.data for r in records(l_rec, "leader/state")]
    warm = [s for s in states if s.get("h1_ms") and s.get("h2_ms")]
    assert len(warm) > 50
    late = warm[len(warm) // 2 :]
    h1_est = statistics.median(s["h1_ms"] for s in late) / 1000
    h2_est = statistics.median(s["h2_ms"] for s in late) / 1000
    print(
        f"h1: emulated {FORWARD_S * 1000:.0f} ms, message median {h1_msgs * 1000:.1f} ms, leader's estimate {h1_est * 1000:.1f} ms"
    )
    print(
        f"h2: emulated {BACKWARD_S * 1000:.0f} ms, message median {h2_msgs * 1000:.1f} ms, leader's estimate {h2_est * 1000:.1f} ms"
    )
    # the emulated delay plus TLS, Zenoh and scheduling on this host: a few ms
    for got, want in ((h1_msgs, FORWARD_S), (h1_est, FORWARD_S), (h2_msgs, BACKWARD_S), (h2_est, BACKWARD_S)):
        assert want <= got + 0.002 and got < want + 0.025, (got, want)
