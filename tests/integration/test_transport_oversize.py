"""Oversized payloads are dropped before they are copied, authenticated or decoded (issue 20, finding 3).

A real Zenoh router-less pair: this process subscribes with the project's receiver (message
key on), another process floods the command key with 100 kB payloads that carry a fake
signature header. Each must be counted as ``too_large`` (the size check comes first), not
as ``bad_mac`` (which means the MAC was computed over the whole payload first). Payloads of
16 MiB never reach the receiver at all: Zenoh's defragmentation buffer is bounded
(``MAX_ZENOH_MESSAGE``) and drops them.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import textwrap
import time

import pytest
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.auth import MessageAuth
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command
from bipedtele.link.receivers import MAX_CONTROL_PAYLOAD, MAX_ZENOH_MESSAGE, LatestReceiver
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session

pytestmark = pytest.mark.timeout(60)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


FLOOD = textwrap.dedent(
    """
    import json, sys, time, zenoh
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(c) as s:
        time.sleep(1.0)
        pub = s.declare_publisher(sys.argv[2])
        junk = b"\\x01" + b"\\x00" * 32 + b"\\x00" * int(sys.argv[4])  # a signature-like header, then junk
        for _ in range(int(sys.argv[3])):
            pub.put(junk)
            time.sleep(0.05)
        time.sleep(1.0)
    """
)


def test_oversized_payloads_are_dropped_before_the_mac(tmp_path) -> None:
    port = _free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    net = NetworkConfig(mode="peer", listen=[endpoint])
    keys = Keys("nao1")
    auth = MessageAuth(b"k" * 32)
    drops = DropCounter("cmd")
    with (
        open_session(net) as session,
        LatestReceiver(session, keys.cmd, Command, drops, SequenceGate(), auth=auth) as rx,
    ):
        flood = subprocess.run(
            [sys.executable, "-c", FLOOD, endpoint, keys.cmd, "10", str(100 * 1024)],
            capture_output=True,
            text=True,
            timeout=40,
        )
        assert flood.returncode == 0, flood.stderr[-2000:]
        deadline = time.monotonic() + 5.0
        while drops.total < 10 and time.monotonic() < deadline:
            time.sleep(0.05)
        counts = drops.counts()
        assert rx.take() is None
        assert counts.get("too_large", 0) == 10, counts
        assert "bad_mac" not in counts and "no_mac" not in counts, counts
        assert rx.max_bytes == MAX_CONTROL_PAYLOAD
        big = subprocess.run(
            [sys.executable, "-c", FLOOD, endpoint, keys.cmd, "3", str(16 * 1024 * 1024)],
            capture_output=True,
            text=True,
            timeout=40,
        )
        assert big.returncode == 0, big.stderr[-2000:]
        time.sleep(0.5)
        assert drops.counts() == counts, "a 16 MiB message reached the receiver"
        assert rx.take() is None
    assert MAX_ZENOH_MESSAGE < 16 * 1024 * 1024
