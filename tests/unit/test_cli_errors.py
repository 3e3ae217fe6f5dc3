"""Bad arguments to the demo and follower programs: one line naming what is wrong and
what is allowed, exit code 2, and nothing started."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytestmark = pytest.mark.timeout(60)


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bipedtele.cli", *args], capture_output=True, text=True, timeout=50)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["demo", "--delay", "const:150ms"], "FORWARD,BACKWARD"),
        (["demo", "--delay", "const:150ms,sometimes"], "allowed"),
        (["demo", "--delay-trace", "/nonexistent/trace.csv"], "trace"),
        (["demo", "--delay", "const:1ms,const:1ms", "--delay-trace", "x.csv"], "at most one"),
        (["demo", "--duration", "-3"], "> 0"),
        (["demo", "--operator", "robot"], "invalid choice"),
        (["demo", "--set", "follower.watchdog_s=-1"], "follower.watchdog_s"),
        (["follower", "--robot", "naoqi", "--realtime", "off"], "only with the simulator"),
        (["follower", "--duration", "0"], "> 0"),
        (["follower", "--set", 'follower.cameras=["tail"]'], "head"),
        (["health", "--role", "router", "--timeout", "0"], "> 0"),
        (["leader", "--device", "gamepad", "--set", "leader.cockpit=false"], "leader.cockpit = true"),
        (["leader", "--foxglove", "127.0.0.1:99999"], "0-65535"),
        (["follower", "--foxglove", "0.0.0.0:8765"], "--allow-remote"),
        (["leader", "--set", "pad.deadzone=0.9"], "pad.deadzone"),
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(args: list[str], needle: str) -> None:
    proc = _run(*args)
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert needle in lines[0], lines[0]
    assert proc.stdout == ""
