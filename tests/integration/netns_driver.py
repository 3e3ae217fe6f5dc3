"""Driver of tests/integration/test_netem_namespaces.py: the netem backend's link, for real.

Makes a :class:`bipedtele.tools.netns.VethLink` (as ``bipedtele demo --delay-backend netem``
does), starts a Zenoh router in the follower's namespace on the veth address and, from the
leader's namespace, ``bipedtele health --role router`` across the veth pair; prints one
JSON line (namespaces, devices, PIDs, the health result), then waits for SIGINT/SIGTERM and
leaves its ``with`` blocks, which removes everything.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

from bipedtele.shutdown import shutdown_on_signals
from bipedtele.tools.netns import FOLLOWER, LEADER, VethLink

CLI = [sys.executable, "-m", "bipedtele.cli"]


def main() -> int:
    with shutdown_on_signals() as stop, VethLink() as link:
        endpoint = f"tcp/{link.follower_ip}:7447"
        router = subprocess.Popen(
            [*link.exec_prefix(FOLLOWER), *CLI, "router", "--listen", endpoint],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        health = None
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not stop.is_set():
            health = subprocess.run(
                [
                    *link.exec_prefix(LEADER),
                    *CLI,
                    "health",
                    "--role",
                    "router",
                    "--set",
                    'network.mode="client"',
                    "--set",
                    f'network.connect=["{endpoint}"]',
                    "--set",
                    "network.timeout_s=5.0",
                ],
                capture_output=True,
                text=True,
                timeout=60,
            )
            if health.returncode == 0:
                break
            time.sleep(0.5)
        print(
            json.dumps(
                {
                    "ns": link.ns,
                    "dev": link.dev,
                    "router_pid": router.pid,
                    "health_rc": None if health is None else health.returncode,
                    "health": "" if health is None else (health.stdout + health.stderr).strip(),
                    "pids_inside": link.pids(),
                }
            ),
            flush=True,
        )
        stop.wait(120.0)
    router.wait(timeout=10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
