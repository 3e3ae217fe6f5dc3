"""A split-layout client session reopens itself after a forged datagram (bipedtele.link.relink), on loopback.

A real ``bipedtele router`` (TCP with ``links = "split"``: it also listens on UDP) in its
own process; in the test, a :class:`~bipedtele.link.relink.RelinkSession` client with a
subscriber, a liveliness token and a liveliness subscriber, and a plain client that
publishes and watches the token. Forged datagrams (raw socket, root only) with the real
UDP link's addresses: a Close to the client's UDP port, then garbage to the router's.
After each the session is reopened once, control is on UDP again, the subscriber receives
again and the token is seen under the new session.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.relink import RelinkSession
from bipedtele.link.zenohsession import open_raw, open_session
from test_acl import Tap, _until, free_port

SPOOF = Path(__file__).resolve().parents[1] / "e2e" / "udp_spoof.py"


def _spoof(src: str, dst: str, *payload: str) -> None:
    r = subprocess.run(
        [sys.executable, str(SPOOF), "--src", src, "--dst", dst, *payload], capture_output=True, text=True, timeout=30
    )
    assert r.returncode == 0, r.stderr


@pytest.mark.timeout(90)
@pytest.mark.skipif(os.geteuid() != 0, reason="forged datagrams need a raw socket (root)")
def test_a_forged_close_or_garbage_costs_one_reopen(tmp_path: Path) -> None:
    port = free_port()
    router = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "router",
            "--listen",
            f"tcp/127.0.0.1:{port}",
            "--set",
            'network.links="split"',
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert router.stdout is not None and "listening on" in router.stdout.readline()
        net = NetworkConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"], links="split", timeout_s=5.0)
        relinked = RelinkSession(lambda: open_raw(net), control="udp", silence_s=0)
        with open_session(NetworkConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"])) as other:
            got, tokens = Tap(), Tap()
            sub = relinked.declare_subscriber("t/x", got)
            token = relinked.liveliness().declare_token(f"t/presence/{relinked.zid()}")
            watch = other.liveliness().declare_subscriber("t/presence/*", tokens, history=True)
            pub = other.declare_publisher("t/x", priority=zenoh.Priority.REAL_TIME)

            def receives() -> bool:
                n = len(got)
                return _until(lambda: len(got) > n + 5, lambda: pub.put(b"x"), 5.0)

            assert _until(lambda: relinked.control_now() == "udp", lambda: None, 5.0)
            assert receives()
            for n, attack in enumerate(("close", "garbage"), 1):
                link = next(link for link in relinked.info.links() if str(link.dst).startswith("udp/"))
                mine = str(link.src).partition("/")[2].partition("?")[0]
                theirs = str(link.dst).partition("/")[2].partition("?")[0]
                zid = str(relinked.zid())
                if attack == "close":
                    _spoof(theirs, mine, "--hex", "2300")
                else:
                    _spoof(mine, theirs, "--garbage", "40")
                assert _until(lambda n=n: relinked.reopens == n, lambda: None, 5.0), (attack, relinked.reopens)
                assert str(relinked.zid()) != zid
                assert _until(lambda: relinked.control_now() == "udp", lambda: None, 5.0), relinked.control_now()
                assert receives(), attack
                new = f"t/presence/{relinked.zid()}"
                assert _until(lambda new=new: any(k == new for k, _ in tokens.samples), lambda: None, 5.0), attack
            assert relinked.reopens == 2
            time.sleep(1.5)  # the router judges a client's lost link after 0.3 s
            for d in (pub, watch, token, sub):
                d.undeclare()
        relinked.close()
    finally:
        router.send_signal(signal.SIGTERM)
        _, err = router.communicate(timeout=15)
    assert "client" in err and "lost its udp link" in err, err[-3000:]  # the router's line for the garbage
