"""Forged video frames at the size bound are dropped before they are copied or opened (issue 32, item 6).

A real Zenoh pair: this process receives video with the project's receiver (the watch key
on); another process publishes genuine sealed frames (30 kB, under the same key) and, in
between, 2 MiB forged frames that copy the genuine frames' 8 bytes in clear (magic and key
id), so that only opening them could tell. The first forged frame fails authentication
(``bad_mac``); from then on each is dropped by its size (``too_large_under_attack``: more
than twice the largest authenticated frame plus 64 kB) before the copy and the cipher, while
every genuine frame is still accepted.
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
from bipedtele.link.messages import VideoFrame
from bipedtele.link.receivers import LatestReceiver
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session

pytestmark = pytest.mark.timeout(60)
KEY = bytes(range(32))

SENDER = textwrap.dedent(
    """
    import json, os, sys, time, zenoh
    from bipedtele.link.auth import MessageAuth
    from bipedtele.link.messages import VideoFrame, encode
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("scouting/multicast/enabled", "false")
    auth, key = MessageAuth(bytes(range(32))), sys.argv[2]
    with zenoh.open(c) as s:
        time.sleep(1.0)
        pub = s.declare_publisher(key)
        def genuine(seq):
            f = VideoFrame(sid=5, seq=seq, t=time.time(), camera="head", width=320, height=240,
                           t_capture=time.time(), jpeg=os.urandom(30_000))
            return auth.sign(encode(f), key)
        head = genuine(1)[:8]  # in clear on the wire
        for seq in range(1, 11):
            pub.put(genuine(seq))
            time.sleep(0.05)
            pub.put(head + os.urandom(2 * 1024 * 1024 - 8))
            time.sleep(0.05)
        time.sleep(1.0)
    """
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_forged_frames_at_the_size_bound_cost_no_copy_once_one_failed() -> None:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    keys = Keys("nao1")
    drops = DropCounter("video")
    got: list[int] = []
    with (
        open_session(NetworkConfig(mode="peer", listen=[endpoint])) as session,
        LatestReceiver(
            session,
            keys.video,
            VideoFrame,
            drops,
            SequenceGate(),
            auth=MessageAuth(KEY),
            on_message=lambda r: got.append(r.msg.seq),
        ),
    ):
        sender = subprocess.run(
            [sys.executable, "-c", SENDER, endpoint, keys.video], capture_output=True, text=True, timeout=40
        )
        assert sender.returncode == 0, sender.stderr[-2000:]
        deadline = time.monotonic() + 5.0
        while drops.total < 10 and time.monotonic() < deadline:
            time.sleep(0.05)
    counts = drops.counts()
    assert got == list(range(1, 11)), got  # every genuine frame
    assert counts == {"bad_mac": 1, "too_large_under_attack": 9}, counts
