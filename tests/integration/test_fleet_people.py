"""People, not roles: one person's certificate revoked, the others drive on.

``bipedtele setup fleet`` for one robot and two operators, alice and dave: each person
holds a certificate of their own (CN = the user). A real ``bipedtele router`` from the
written folder, started with ``[network] revoked = ["dave"]`` (what revoking him means:
the router's list; Zenoh's TLS reads no revocation list):

- dave, from his own folder (his certificate and password), is refused: no session;
- dave's certificate with alice's password (a stolen password) opens a session that
  may do nothing: his commands never reach the robot;
- alice, from her folder, commands the robot and hears its feedback through the same router.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import replace
from pathlib import Path

import pytest
from bipedtele.config.profile import load_config
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.linkcheck import LinkError
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session
from test_acl import Tap, _until, free_port

CLI = [sys.executable, "-m", "bipedtele.cli"]
KEYS = Keys("nao1")


@contextmanager
def fleet_router(tmp_path: Path, revoked: str) -> Iterator[Path]:
    """``setup fleet`` (alice and dave drive nao1) and its router with ``revoked``; yields the fleet folder."""
    port = free_port()
    out = tmp_path / "fleet"
    r = subprocess.run(
        [
            *CLI,
            "setup",
            "fleet",
            "--router-name",
            "127.0.0.1",
            "--router-port",
            str(port),
            "--robot",
            "nao1",
            "--operator",
            "alice=nao1",
            "--operator",
            "dave=nao1",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    router = subprocess.Popen(
        [
            *CLI,
            "router",
            "--config",
            str(out / "router" / "bipedtele.toml"),
            "--listen",
            f"tls/127.0.0.1:{port}",
            "--set",
            f"network.revoked={revoked}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert router.stdout is not None
        assert "listening on" in router.stdout.readline()
        yield out
    finally:
        router.send_signal(signal.SIGTERM)
        _, err = router.communicate(timeout=15)
        assert router.returncode == 0, err[-2000:]


def _net(fleet: Path, profile: str) -> NetworkConfig:
    net: NetworkConfig = load_config(fleet / profile).get(NetworkConfig)
    return replace(net, timeout_s=5.0)


@pytest.mark.timeout(120)
def test_revoking_dave_refuses_him_while_alice_drives(tmp_path: Path) -> None:
    with fleet_router(tmp_path, '["dave"]') as fleet, ExitStack() as stack:
        robot = stack.enter_context(open_session(_net(fleet, "robot-nao1/bipedtele.toml")))
        commands, feedback = Tap(), Tap()
        stack.callback(robot.declare_subscriber(KEYS.cmd, commands).undeclare)

        # dave, as himself: refused before any session exists
        with pytest.raises(LinkError) as refused:
            stack.enter_context(open_session(_net(fleet, "operator-dave/nao1.toml")))
        assert refused.value.kind == "credentials", refused.value

        # dave's certificate with alice's password: a session with no rights
        alice_net = _net(fleet, "operator-alice/nao1.toml")
        dave_net = _net(fleet, "operator-dave/nao1.toml")
        stolen = replace(dave_net, user="alice", password_file=alice_net.password_file)
        thief = stack.enter_context(open_session(stolen))

        alice = stack.enter_context(open_session(alice_net))
        stack.callback(alice.declare_subscriber(KEYS.feedback, feedback).undeclare)
        time.sleep(0.5)

        def drive() -> None:
            thief.put(KEYS.cmd, b"dave")
            alice.put(KEYS.cmd, b"alice")
            robot.put(KEYS.feedback, b"robot")

        assert _until(lambda: len(commands) >= 20 and len(feedback) >= 20, drive, 10.0), (len(commands), len(feedback))
        _until(lambda: False, drive, 1.0)
        got = {p for _, p in commands.samples}
        assert got == {b"alice"}, got  # alice drives; nothing of dave's reaches the robot
        assert any("udp/" in str(link.dst) for link in alice.info.links())
