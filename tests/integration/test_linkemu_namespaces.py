"""The per-packet link emulator between two namespaces, for real (root, ``ip netns``).

One :class:`EmulatedLink` for the module (A = 10.234.0.1, B = 10.234.0.2, the emulator in
the middle namespace); each test restarts the emulator with its own impairments and runs
small bounded programs in A and B. The assertions are on behaviour the emulator must
cause (a round trip at least the two delays, a loss fraction, a minimum transfer time, a
silent window), never on how fast our code is.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from bipedtele.tools.netns import SIDE_A, SIDE_B, EmulatedLink, NetnsError

pytestmark = pytest.mark.timeout(120)

PORT = 5301  # written into the programs below

TCP_ECHO_SERVER = """
import socket
s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
s.bind(("0.0.0.0", 5301)); s.listen(1); s.settimeout(30)
c, _ = s.accept(); c.settimeout(30)
while (d := c.recv(65536)):
    c.sendall(d)
"""

TCP_ECHO_CLIENT = """
import socket, sys, time
c = socket.create_connection((sys.argv[1], 5301), timeout=30)
c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
for _ in range(6):
    t = time.monotonic(); c.sendall(b"x" * 100); n = 0
    while n < 100:
        n += len(c.recv(100))
    print(time.monotonic() - t)
"""

TCP_SINK = """
import socket, time
s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
s.bind(("0.0.0.0", 5301)); s.listen(1); s.settimeout(30)
c, _ = s.accept(); c.settimeout(30); n = 0; t0 = None
while (d := c.recv(65536)):
    t0 = t0 or time.monotonic(); n += len(d)
print(n, time.monotonic() - t0)
"""

TCP_SOURCE = """
import socket, sys
c = socket.create_connection((sys.argv[1], 5301), timeout=30)
c.sendall(b"y" * int(sys.argv[2])); c.shutdown(socket.SHUT_WR); c.recv(1)
"""

UDP_SINK = """
import json, socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("0.0.0.0", 5301))
s.settimeout(float(sys.argv[1])); got = []
try:
    while True:
        got.append(s.recv(100).decode())
except TimeoutError:
    pass
print(json.dumps(got))
"""

UDP_SOURCE = """
import socket, sys, time
n, gap, start = int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
while time.time() < start:
    time.sleep(0.001)
for k in range(n):
    s.sendto(("%d %.6f" % (k, time.time())).encode(), (sys.argv[1], 5301))
    time.sleep(gap)
"""


@pytest.fixture(scope="module")
def link(tmp_path_factory: pytest.TempPathFactory) -> Iterator[EmulatedLink]:
    if shutil.which("ip") is None:
        pytest.skip("needs iproute2 (`ip`): scripts/bootstrap.sh --test installs it")
    if os.geteuid() != 0:
        pytest.skip("network namespaces and raw sockets need root")
    emu = EmulatedLink(log_path=tmp_path_factory.mktemp("linkemu") / "linkemu.log", autostart=False)
    try:
        emu.create()
    except NetnsError as exc:
        pytest.skip(f"cannot make network namespaces here (`ip netns add` failed): {exc}")
    emu.pin_neighbours()  # no ARP on the lossy wire
    try:
        yield emu
    finally:
        emu.remove()


def _start(link: EmulatedLink, side: str, code: str, *args: str) -> subprocess.Popen[str]:
    cmd = [*link.exec_prefix(side), sys.executable, "-c", code, *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _finish(proc: subprocess.Popen[str], timeout: float = 60.0) -> str:
    out, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err[-2000:]
    return out


def _stats(path: Path) -> dict[str, dict[str, object]]:
    data: dict[str, dict[str, object]] = json.loads(path.read_text())
    return data


def test_tcp_round_trip_is_the_two_delays(link: EmulatedLink) -> None:
    link.start_emulator(["--forward", "const:100ms", "--backward", "const:100ms"])
    server = _start(link, SIDE_B, TCP_ECHO_SERVER)
    time.sleep(0.5)
    rtts = [float(x) for x in _finish(_start(link, SIDE_A, TCP_ECHO_CLIENT, link.b_ip)).split()]
    _finish(server)
    assert len(rtts) == 6
    assert min(rtts) >= 0.195, rtts
    assert sorted(rtts)[len(rtts) // 2] < 0.400, rtts


@pytest.mark.slow
def test_random_loss_on_udp_is_binomial(link: EmulatedLink, tmp_path: Path) -> None:
    stats = tmp_path / "stats.json"
    link.start_emulator(["--loss-forward", "20%", "--seed", "11", "--stats-json", str(stats)])
    n, p = 500, 0.2
    sink = _start(link, SIDE_B, UDP_SINK, "4.0")
    source = _start(link, SIDE_A, UDP_SOURCE, link.b_ip, str(n), "0.002", f"{time.time() + 0.5:.6f}")
    _finish(source)
    got = json.loads(_finish(sink))
    link.stop_emulator()
    lost = 1.0 - len(got) / n
    sd = math.sqrt(p * (1 - p) / n)
    assert p - 5 * sd <= lost <= p + 5 * sd, lost
    dropped = _stats(stats)["forward"]["dropped"]
    assert isinstance(dropped, dict)
    assert dropped["loss"] >= n - len(got) and dropped["queue"] == dropped["outage"] == 0


@pytest.mark.slow
def test_rate_cap_bounds_a_tcp_transfer(link: EmulatedLink, tmp_path: Path) -> None:
    stats = tmp_path / "stats.json"
    size, rate = 250_000, 1e6
    link.start_emulator(
        [
            "--forward",
            "const:10ms",
            "--backward",
            "const:10ms",
            "--rate-forward",
            "1mbit",
            "--queue-forward",
            "32kB",
            "--stats-json",
            str(stats),
        ]
    )
    sink = _start(link, SIDE_B, TCP_SINK)
    time.sleep(0.5)
    t = time.monotonic()
    _finish(_start(link, SIDE_A, TCP_SOURCE, link.b_ip, str(size)))
    elapsed = time.monotonic() - t
    received, _ = _finish(sink).split()
    link.stop_emulator()
    assert int(received) == size
    assert elapsed >= size * 8 / rate, elapsed
    fwd = _stats(stats)["forward"]
    assert isinstance(fwd["queue_bytes_max"], int) and 0 < fwd["queue_bytes_max"] <= 32_000


@pytest.mark.slow
def test_outage_drops_everything_in_its_window(link: EmulatedLink, tmp_path: Path) -> None:
    stats = tmp_path / "stats.json"
    t0 = time.time() + 2.0  # the models' origin: after the emulator and the programs started
    link.start_emulator(["--outage-forward", "at=1s,for=1s", "--t0", f"{t0:.6f}", "--stats-json", str(stats)])
    # 300 datagrams every 10 ms from t0 - 0.3 s: they span the window [t0 + 1, t0 + 2).
    sink = _start(link, SIDE_B, UDP_SINK, "4.0")
    source = _start(link, SIDE_A, UDP_SOURCE, link.b_ip, "300", "0.01", f"{t0 - 0.3:.6f}")
    _finish(source)
    got = json.loads(_finish(sink))
    link.stop_emulator()
    sent_at = {int(k): float(ts) - t0 for k, ts in (g.split() for g in got)}
    assert not [s for s in sent_at.values() if 1.02 <= s < 1.98], "datagrams crossed during the outage"
    assert any(s < 1.0 for s in sent_at.values()) and any(s >= 2.0 for s in sent_at.values()), sent_at
    # Everything sent before or after the window arrived (no other impairment): one gap.
    seqs = sorted(sent_at)
    gaps = [(a, b) for a, b in itertools.pairwise(seqs) if b != a + 1]
    assert len(gaps) == 1 and seqs[0] == 0 and seqs[-1] == 299, gaps
    dropped = _stats(stats)["forward"]["dropped"]
    assert isinstance(dropped, dict) and 80 <= dropped["outage"] <= 110 and dropped["loss"] == 0


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    # Run outside the checkout: a stale bipedtele.egg-info there would hide new sub-commands.
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", *args], capture_output=True, text=True, timeout=60, cwd="/"
    )


def test_bad_arguments_are_one_line_exit_2() -> None:
    for args, words in (
        (["--a", "x0", "--b", "x0"], "two different interfaces"),
        (["--a", "x0", "--b", "x1", "--loss-forward", "ge:p=1%"], "needs p"),
        (["--a", "x0", "--b", "x1", "--rate-backward", "fast"], "not a rate"),
        (["--a", "x0", "--b", "x1", "--outage-forward", "at=1s"], "needs at= and for="),
    ):
        res = _cli("link-emu", *args)
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 2 and len(lines) == 1 and words in lines[0], res.stderr


def test_demo_packet_backend_dry_run_prints_the_plan(tmp_path: Path) -> None:
    res = _cli(
        "demo",
        "--delay-backend",
        "packet",
        "--dry-run",
        "--headless",
        "--duration",
        "1",
        "--loss",
        "ge:p=1%,r=30%",
        "--rate-up",
        "2mbit",
        "--outage",
        "at=5s,for=1s",
        "--run-dir",
        str(tmp_path / "r"),
    )
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert "# process proxy" not in out and "# packet backend: leader in bt-ea-" in out
    emu = next(line for line in out.splitlines() if "bipedtele.tools.linkemu" in line)
    for part in (
        "--forward trace:intercontinental:h1",
        "--backward trace:intercontinental:h2",
        "--rate-forward 2mbit",
        "--outage-backward at=5s,for=1s",
    ):
        assert part in emu
    assert not (tmp_path / "r").exists()  # a dry run starts nothing


# Zenoh sessions built by the project (zenoh_config): B listens, A connects and publishes.
ZENOH_SINK = """
import sys, time, zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.zenohsession import zenoh_config
net = NetworkConfig(mode="peer", listen=["tcp/0.0.0.0:5301"], connect=[])
got = []
with zenoh.open(zenoh_config(net)) as s, s.declare_subscriber("bt/shm", lambda x: got.append(len(x.payload.to_bytes()))):
    print("ready", flush=True)
    end = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < end and len(got) < int(sys.argv[2]):
        time.sleep(0.05)
print(len(got), sum(got))
"""

ZENOH_SOURCE = """
import sys, time, zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.zenohsession import zenoh_config
net = NetworkConfig(mode="peer", listen=[], connect=["tcp/" + sys.argv[1] + ":5301"])
with zenoh.open(zenoh_config(net)) as s:
    pub = s.declare_publisher("bt/shm")
    time.sleep(1.5)  # the link up and the subscriber declared
    for _ in range(int(sys.argv[2])):
        pub.put(b"j" * 8000)
        time.sleep(0.02)
    time.sleep(1.0)
"""


def test_zenoh_messages_over_3_kb_cross_the_emulated_wire(link: EmulatedLink, tmp_path: Path) -> None:
    """Zenoh's shared memory carried every message over 3 kB (the video frames) between
    processes of one machine through /dev/shm: around the namespaces, the emulated link,
    TLS and the rate cap (a 300 kbit/s uplink delivered 800 kbit/s of video, 12 ms old).
    The project's sessions must send them on the wire."""
    stats = tmp_path / "stats.json"
    link.start_emulator(["--stats-json", str(stats)])
    n = 40
    sink = _start(link, SIDE_B, ZENOH_SINK, "20", str(n))
    assert sink.stdout is not None and sink.stdout.readline().strip() == "ready"
    _finish(_start(link, SIDE_A, ZENOH_SOURCE, link.b_ip, str(n)))
    count, total = (int(x) for x in _finish(sink).split())
    link.stop_emulator()
    assert count == n and total == n * 8000
    forwarded = _stats(stats)["forward"]["forwarded_bytes"]
    assert isinstance(forwarded, int) and forwarded >= n * 8000, forwarded
