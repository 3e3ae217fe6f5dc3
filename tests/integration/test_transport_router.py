"""`bipedtele router` with user/password authentication and access control: only the
users in `publishers_allowed` may put on bipedtele/*/cmd; a wrong password is refused,
says so, and the router logs the refusal with the client's address."""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.drops import DropCounter
from bipedtele.link.linkcheck import LinkError
from bipedtele.link.messages import Command, Status
from bipedtele.link.receivers import MessageReceiver
from bipedtele.link.transport import Keys, Publishers, Stamper
from bipedtele.link.zenohsession import open_session


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _client(ep: str, user: str, password: str, timeout_s: float = 5.0) -> NetworkConfig:
    return NetworkConfig(mode="client", connect=[ep], user=user, password=password, timeout_s=timeout_s)


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_router_auth_and_command_acl(tmp_path: Path) -> None:
    creds = tmp_path / "creds.txt"
    creds.write_text("leader:lpw\nfollower:fpw\n")
    profile = tmp_path / "router.toml"
    profile.write_text(
        f'[network]\nmode = "router"\ncredentials_file = "{creds}"\npublishers_allowed = ["leader"]\n'
        'followers_allowed = ["follower"]\n'
    )
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    router = subprocess.Popen(
        [sys.executable, "-m", "bipedtele.cli", "router", "--config", str(profile), "--listen", ep],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert router.stdout is not None
        assert f"listening on {ep}" in router.stdout.readline()
        keys = Keys("nao1")
        lead, foll = Stamper(), Stamper()
        drops = DropCounter("acl")
        with open_session(_client(ep, "leader", "lpw")) as ls, open_session(_client(ep, "follower", "fpw")) as fs:  # noqa: SIM117
            with (
                MessageReceiver(fs, keys.cmd, Command, drops) as f_cmd,
                MessageReceiver(ls, keys.cmd, Command, drops) as l_cmd,
                MessageReceiver(ls, keys.status, Status, drops) as l_status,
                Publishers(ls, keys) as lp,
                Publishers(fs, keys) as fp,
            ):
                time.sleep(0.5)
                # control traffic drops on congestion: on a loaded machine a message can be
                # lost, so publish until 3 of each went through (bounded)
                follower_view: list[int] = []
                leader_view: list[int] = []
                statuses = 0
                deadline = time.monotonic() + 10.0
                while follower_view.count(lead.sid) < 3 or statuses < 3:
                    assert time.monotonic() < deadline, (follower_view, statuses)
                    lp.cmd.put(lead.make(Command))
                    fp.cmd.put(foll.make(Command))  # denied by the router
                    fp.status.put(foll.make(Status))  # allowed
                    time.sleep(0.1)
                    follower_view += [r.msg.sid for r in f_cmd.drain()]
                    leader_view += [r.msg.sid for r in l_cmd.drain()]
                    statuses += len(l_status.drain())
                time.sleep(0.3)
                leader_view += [r.msg.sid for r in l_cmd.drain()]
        # the leader's commands cross the router; the follower's are denied there (they
        # only reach the follower's own session, locally)
        assert follower_view.count(lead.sid) >= 3
        assert leader_view.count(lead.sid) >= 3
        assert foll.sid not in leader_view
        # a wrong password is refused, and the client is told so
        with (
            pytest.raises(LinkError, match="user/password refused for user 'follower'") as info,
            open_session(_client(ep, "follower", "wrong", 1.0)),
        ):
            pass
        assert info.value.kind == "credentials"
    finally:
        router.send_signal(signal.SIGTERM)
        _, err = router.communicate(timeout=15)
    assert router.returncode == 0, err[-2000:]
    assert "router shutting down" in err
    # the router logged the refusal: the reason and the client's address
    assert re.search(r"refused a session from 127\.0\.0\.1:\d+: user/password refused: wrong password", err), err[
        -3000:
    ]
