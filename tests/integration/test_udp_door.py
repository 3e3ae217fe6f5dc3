"""No weaker door on UDP: a password without a certificate gets nothing over the router's UDP listener.

A real ``bipedtele router`` from ``bipedtele setup two-hosts`` (mutual TLS, logins, the
ACL, ``links = "split"``: it also listens on UDP at its TLS port). Zenoh has no TLS for
UDP, so a session opened over ``udp/`` shows the router a password and no certificate.

- An intruder who holds the leader's password (then the follower's) but no certificate
  opens a session over ``udp/`` only and puts on every key (status, video, feedback,
  commands, clock), declares subscribers on them and a presence token: the genuine
  sessions receive none of it, it receives nothing of theirs, and its token is never seen.
  (On the code before the fix the session got its user's rights: the leader's password
  put status and commands that reached the follower's subscribers, and read feedback.)
- The genuine split layout (mutual TLS on the first link, control on UDP) still carries
  commands, feedback, status and video both ways through the same router.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest
import zenoh
from bipedtele.config.profile import load_config
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session, zenoh_config
from test_acl import Tap, free_port

CLI = [sys.executable, "-m", "bipedtele.cli"]
KEYS = Keys("nao1")
NAMES = ("cmd", "feedback", "status", "video", "clock")


@contextmanager
def two_hosts_router(tmp_path: Path) -> Iterator[tuple[Path, int]]:
    """``setup two-hosts`` for 127.0.0.1 and its router on a free port; yields (setup folder, port)."""
    port = free_port()
    out = tmp_path / "setup"
    r = subprocess.run(
        [*CLI, "setup", "two-hosts", "--router-name", "127.0.0.1", "--router-port", str(port), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    router = subprocess.Popen(
        [*CLI, "router", "--config", str(out / "router" / "bipedtele.toml"), "--listen", f"tls/127.0.0.1:{port}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert router.stdout is not None
        assert "listening on" in router.stdout.readline()
        yield out, port
    finally:
        router.send_signal(signal.SIGTERM)
        _, err = router.communicate(timeout=15)
        assert router.returncode == 0, err[-2000:]


def _net(setup: Path, host: str) -> NetworkConfig:
    net: NetworkConfig = load_config(setup / host / "bipedtele.toml").get(NetworkConfig)
    return net


def _udp_only(setup: Path, host: str, port: int) -> zenoh.Session:
    """A session over the router's UDP listener with ``host``'s user and password, and no certificate."""
    net = _net(setup, host)
    password = Path(net.password_file).read_text().strip()
    bare = NetworkConfig(
        mode="client", connect=[f"udp/127.0.0.1:{port}"], user=net.user, password=password, timeout_s=5.0
    )
    return zenoh.open(zenoh_config(bare))


def _until(cond: Callable[[], bool], step: Callable[[], None], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        step()
        if cond():
            return True
        time.sleep(0.05)
    return False


@pytest.mark.timeout(120)
def test_a_password_without_a_certificate_over_udp_gets_nothing(tmp_path: Path) -> None:
    with two_hosts_router(tmp_path) as (setup, port), ExitStack() as stack:
        leader = stack.enter_context(open_session(_net(setup, "operator")))
        follower = stack.enter_context(open_session(_net(setup, "robot")))
        # what the genuine sessions receive, by key
        got = {name: Tap() for name in NAMES}
        for name in ("feedback", "status", "video"):
            stack.callback(leader.declare_subscriber(getattr(KEYS, name), got[name]).undeclare)
        for name in ("cmd", "clock"):
            stack.callback(follower.declare_subscriber(getattr(KEYS, name), got[name]).undeclare)
        leaders_seen = Tap()
        stack.callback(follower.liveliness().declare_subscriber(f"{KEYS.presence('leader')}/*", leaders_seen).undeclare)
        time.sleep(0.5)

        intruders = {who: _udp_only(setup, who, port) for who in ("operator", "robot")}
        for s in intruders.values():
            stack.callback(s.close)
        heard = {who: Tap() for who in intruders}
        for who, s in intruders.items():
            stack.callback(s.declare_subscriber("bipedtele/**", heard[who]).undeclare)
            stack.callback(s.liveliness().declare_token(f"{KEYS.presence('leader')}/intruder-{who}").undeclare)
        time.sleep(0.5)

        def intrude() -> None:
            for who, s in intruders.items():
                for name in NAMES:
                    s.put(getattr(KEYS, name), b"intruder-" + who.encode())

        _until(lambda: False, intrude, 2.0)
        assert not [(k, len(t)) for k, t in got.items() if any(p.startswith(b"intruder") for _, p in t.samples)], {
            k: len(t) for k, t in got.items()
        }
        assert not [k for k, _ in leaders_seen.samples if "intruder" in k], leaders_seen.samples

        # the genuine split layout: every kind of message both ways, control on UDP
        def genuine() -> None:
            for name in ("cmd", "clock", "status"):
                leader.put(getattr(KEYS, name), b"genuine", priority=zenoh.Priority.REAL_TIME)
            for name in ("feedback", "video", "status"):
                follower.put(getattr(KEYS, name), b"genuine")

        def all_genuine() -> bool:
            return all(any(p == b"genuine" for _, p in got[n].samples) for n in NAMES)

        assert _until(all_genuine, genuine, 10.0), {k: len(t) for k, t in got.items()}
        assert any("udp/" in str(link.dst) for link in leader.info.links())
        # ...and nothing of it reached the intruders (each hears only its own puts, in its own session)
        foreign = {w: [(k, p) for k, p in t.samples if p != b"intruder-" + w.encode()] for w, t in heard.items()}
        assert not any(foreign.values()), foreign
