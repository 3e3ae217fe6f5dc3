"""link-emu's token bucket against the kernel's tbf, in namespaces (root, ``ip netns``, ``tc``).

The same 60 UDP datagrams (1000 B, sent back to back after a quiet second) cross side A ->
side B three times: shaped by the kernel's ``tbf`` on A's interface (rate 400 kbit/s,
burst 16 KiB, limit 64 KiB; the emulator transparent), by ``link-emu --rate-forward
400kbit --burst-forward 16384``, and by link-emu's plain FIFO at 400 kbit/s. The token
bucket lets its burst through at once and then the rate binds, like tbf; the FIFO spreads
every frame (what the project's own emulator did alone, so a start or a probe never
overshot on it as it does behind a modem's or a policer's shaper).
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest
from bipedtele.tools.netns import SIDE_A, SIDE_B, EmulatedLink, NetnsError

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

N, SIZE = 60, 1000

SINK = """
import json, socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("0.0.0.0", 5333))
s.settimeout(3.0); got = []
try:
    while True:
        s.recv(2000); got.append(time.time())
except TimeoutError:
    pass
print(json.dumps(got))
"""

SOURCE = """
import socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
time.sleep(1.0)
for k in range(int(sys.argv[2])):
    s.sendto(b"x" * int(sys.argv[3]), (sys.argv[1], 5333))
"""


@pytest.fixture(scope="module")
def link(tmp_path_factory: pytest.TempPathFactory) -> Iterator[EmulatedLink]:
    if shutil.which("ip") is None or shutil.which("tc") is None:
        pytest.skip("needs iproute2 (`ip`, `tc`): scripts/bootstrap.sh --test installs it")
    if os.geteuid() != 0:
        pytest.skip("network namespaces, tc and raw sockets need root")
    n = secrets.randbelow(200) + 20
    emu = EmulatedLink(
        tag=f"b33{secrets.token_hex(1)[0]}",
        a_ip=f"10.236.{n}.1",
        b_ip=f"10.236.{n}.2",
        log_path=tmp_path_factory.mktemp("tbf") / "linkemu.log",
        autostart=False,
    )
    try:
        emu.create()
    except NetnsError as exc:
        pytest.skip(f"cannot make network namespaces here: {exc}")
    emu.pin_neighbours()
    try:
        yield emu
    finally:
        emu.remove()


def _burst(link: EmulatedLink) -> list[float]:
    """Arrival times [s] at B of the datagrams A sends back to back."""
    sink = subprocess.Popen(
        [*link.exec_prefix(SIDE_B), sys.executable, "-c", SINK],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(0.3)
    src = subprocess.run(
        [*link.exec_prefix(SIDE_A), sys.executable, "-c", SOURCE, link.b_ip, str(N), str(SIZE)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert src.returncode == 0, src.stderr
    out, err = sink.communicate(timeout=30)
    assert sink.returncode == 0, err
    times: list[float] = json.loads(out)
    return times


def _shape(times: list[float]) -> tuple[int, float]:
    """Datagrams within 30 ms of the first, and the rate of the last 30 [bit/s of payload]."""
    first = times[0]
    burst = sum(1 for t in times if t - first <= 0.03)
    tail = times[-30:]
    return burst, 8.0 * SIZE * (len(tail) - 1) / (tail[-1] - tail[0])


def test_link_emus_token_bucket_shapes_a_burst_as_the_kernels_tbf(link: EmulatedLink) -> None:
    dev = link.dev[SIDE_A]
    tc = [*link.exec_prefix(SIDE_A), "tc", "qdisc"]
    link.start_emulator([])
    subprocess.run(
        [*tc, "add", "dev", dev, "root", "tbf", "rate", "400kbit", "burst", "16kb", "limit", "64kb"],
        check=True,
        capture_output=True,
        timeout=20,
    )
    try:
        kernel = _burst(link)
    finally:
        subprocess.run([*tc, "del", "dev", dev, "root"], capture_output=True, timeout=20)
    link.start_emulator(["--rate-forward", "400kbit", "--burst-forward", "16384", "--queue-forward", "64kB"])
    emulated = _burst(link)
    link.start_emulator(["--rate-forward", "400kbit", "--queue-forward", "64kB"])
    fifo = _burst(link)
    link.stop_emulator()
    assert len(kernel) == len(emulated) == len(fifo) == N, (len(kernel), len(emulated), len(fifo))
    (kb, krate), (eb, erate), (fb, frate) = _shape(kernel), _shape(emulated), _shape(fifo)
    print(
        f"at once: tbf {kb}, link-emu bucket {eb}, FIFO {fb}; then tbf {krate:.0f}, bucket {erate:.0f}, "
        f"FIFO {frate:.0f} bit/s of payload"
    )
    # 16 KiB of 1042-byte frames pass at once behind both token buckets (17 within 30 ms here)
    assert abs(kb - eb) <= 2 and kb >= 12, (kb, eb)
    assert fb <= 3, fb  # the FIFO: one frame per 21 ms
    # then the token rate binds, the same behind both (payload: 1000 of each 1042 bytes)
    assert abs(krate - erate) <= 0.1 * krate, (krate, erate)
    assert abs(frate - erate) <= 0.1 * frate, (frate, erate)
