"""The netem backend's network namespaces and veth pair, made and removed for real.

This kernel has no ``sch_netem``, so the qdiscs themselves cannot be applied here (their
plan is checked in tests/unit/test_netem.py with ``--dry-run``). What can run does:

- the two namespaces and the veth pair are made, carry a Zenoh session from the leader's
  side to a router on the follower's side, and are removed with the processes inside,
  also when the program holding them gets SIGINT;
- ``run_demo`` with the netem backend on a kernel without netem fails in one line at the
  first ``tc`` command and leaves no namespace behind.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from bipedtele.tools.netem import netem_available
from bipedtele.tools.netns import FOLLOWER, LEADER, VethLink

pytestmark = pytest.mark.timeout(180)

HERE = Path(__file__).resolve().parent


def _namespaces() -> set[str]:
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=20).stdout
    return {line.split()[0] for line in out.splitlines() if line.strip()}


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}").exists() and "Z" not in Path(f"/proc/{pid}/stat").read_text().split()[2]


@pytest.fixture(autouse=True)
def _needs_netns() -> None:
    if shutil.which("ip") is None:
        pytest.skip("needs iproute2 (`ip`): scripts/bootstrap.sh --test installs it")
    if os.geteuid() != 0:
        pytest.skip("network namespaces need root")


def test_veth_link_is_made_and_removed() -> None:
    link = VethLink()
    with link:
        assert {link.ns[LEADER], link.ns[FOLLOWER]} <= _namespaces()
        for side in (LEADER, FOLLOWER):
            shown = subprocess.run(
                ["ip", "-n", link.ns[side], "-o", "addr", "show", "dev", link.dev[side]],
                capture_output=True,
                text=True,
                timeout=20,
                check=True,
            ).stdout
            assert f"{link.ip(side)}/30" in shown
        # the ends live only in the namespaces, not on the host
        host = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True, timeout=20).stdout
        assert link.dev[LEADER] not in host and link.dev[FOLLOWER] not in host
        sleeper = subprocess.Popen([*link.exec_prefix(FOLLOWER), sys.executable, "-c", "import time; time.sleep(300)"])
        assert sleeper.pid in link.pids()
    assert sleeper.wait(timeout=10) == -signal.SIGTERM  # stopped by the removal
    assert not ({link.ns[LEADER], link.ns[FOLLOWER]} & _namespaces())
    assert link.pids() == []


@pytest.mark.slow
def test_zenoh_crosses_the_veth_pair_and_sigint_removes_everything() -> None:
    driver = subprocess.Popen(
        [sys.executable, str(HERE / "netns_driver.py")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert driver.stdout is not None
        line = driver.stdout.readline()
        assert line, driver.stderr.read() if driver.stderr else ""
        info = json.loads(line)
        assert info["health_rc"] == 0, info["health"]
        assert "router reachable at tcp/10.233.0.2:7447" in info["health"]
        ns = set(info["ns"].values())
        assert ns <= _namespaces()
        assert info["router_pid"] in info["pids_inside"]
        driver.send_signal(signal.SIGINT)
        assert driver.wait(timeout=60) == 0, driver.stderr.read() if driver.stderr else ""
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.wait(timeout=10)
    assert not (ns & _namespaces())
    assert not _alive(info["router_pid"])


def test_demo_netem_backend_without_netem_fails_in_one_line_and_cleans_up(tmp_path: Path) -> None:
    ok, why = netem_available()
    if ok:
        pytest.skip(f"this kernel has netem ({why}): the failure path cannot be shown here")
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "from bipedtele.tools.demo import DemoPlan, run_demo\n"
        "from bipedtele.tools.netns import VethLink\n"
        f"run = Path({str(tmp_path)!r})\n"
        "link = VethLink()\n"
        "print(link.ns['leader'], link.ns['follower'], flush=True)\n"
        "plan = DemoPlan(run_dir=run, profile='localhost-delay', overrides=[], forward='const:100ms',\n"
        "                backward='const:120ms', operator='pilot', duration_s=1.0, headless=True,\n"
        "                record=run / 'leader.mcap', backend='netem', link=link)\n"
        "sys.exit(run_demo(plan))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    names = set(res.stdout.split()[:2])
    assert res.returncode == 1, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bipedtele demo: netem backend: `tc -n "), lines
    assert "qdisc add" in lines[0]
    assert not (names & _namespaces())
    assert not list(tmp_path.glob("*.log"))  # no process was started


def test_a_failed_setup_step_is_one_line_and_leaves_nothing() -> None:
    from bipedtele.tools.netns import NetnsError

    link = VethLink(leader_ip="10.233.0.300")  # refused by `ip addr add`, after the veth was made
    with pytest.raises(NetnsError, match=r"^`ip -n bt-dl-\w+ addr add 10\.233\.0\.300/30 dev btdl-\w+`: ") as err:
        link.create()
    assert "\n" not in str(err.value)
    assert not ({link.ns[LEADER], link.ns[FOLLOWER]} & _namespaces())
    host = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True, timeout=20).stdout
    assert link.dev[LEADER] not in host and link.dev[FOLLOWER] not in host
    assert link.created == []


def test_cockpit_relay_reaches_a_server_inside_the_leader_namespace(tmp_path: Path) -> None:
    import socket
    import time
    import urllib.request

    from bipedtele.tools.netns import CockpitRelay

    (tmp_path / "index.html").write_text("cockpit inside bt-dl\n")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with VethLink() as link:
        server = subprocess.Popen(
            [
                *link.exec_prefix(LEADER),
                sys.executable,
                "-m",
                "http.server",
                str(port),
                "--bind",
                "127.0.0.1",
                "--directory",
                str(tmp_path),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        with CockpitRelay(link, port) as relay:
            body, deadline = "", time.monotonic() + 30.0
            while time.monotonic() < deadline:
                try:
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}/index.html", timeout=5) as r:
                        body = r.read().decode()
                    break
                except OSError:
                    time.sleep(0.2)
            assert body == "cockpit inside bt-dl\n"
        assert relay.proc is not None and relay.proc.poll() is not None  # stopped on exit
    server.wait(timeout=10)
