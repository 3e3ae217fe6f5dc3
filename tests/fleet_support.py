"""Helpers of the fleet and sites tests (issue 23): a written router as a process, a payload tap."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def written_router(
    folder: Path, profile: str, port: int, connect: list[str] | None = None
) -> Iterator[subprocess.Popen[str]]:
    """``bipedtele router --config PROFILE`` run from ``folder`` (as printed by setup), on
    ``tls/127.0.0.1:PORT`` (and linked to ``connect``); yields the process once it listens."""
    args = ["--set", f'network.listen=["tls/127.0.0.1:{port}"]']
    if connect is not None:
        args += ["--set", "network.connect=[" + ", ".join(f'"{c}"' for c in connect) + "]"]
    router = subprocess.Popen(
        [sys.executable, "-m", "bipedtele.cli", "router", "--config", profile, *args],
        cwd=folder,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert router.stdout is not None
        line = router.stdout.readline()
        assert "listening" in line, router.stderr.read() if router.stderr else line
        yield router
    finally:
        if router.poll() is None:
            router.terminate()
            router.wait(10)


class Tap:
    """A subscriber callback counting what arrives, by key and by payload."""

    def __init__(self) -> None:
        self.by_key: Counter[str] = Counter()
        self.by: Counter[bytes] = Counter()
        self._lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.by_key[str(sample.key_expr)] += 1
            self.by[sample.payload.to_bytes()] += 1

    def n(self, payload: bytes) -> int:
        """How many times ``payload`` arrived."""
        with self._lock:
            return self.by[payload]
