"""A robot, a device and an operator from another distribution: one module and one entry point each.

``tests/plugins/toy`` is what a third party would install: four modules (``toy_walker``,
``toy_handle``, ``toy_cruise``: settings, class and part in each; ``toy_scheme``, a control
scheme: tests/e2e/test_toy_scheme_demo.py) and one ``.dist-info``
whose ``entry_points.txt`` holds one line per part. Nothing in bipedtele names them. With
that folder on ``PYTHONPATH``:

- the contract checkers pass over every registered part, the toys included, and each
  part's section is in the profile (``[toy_walker] log_path`` is settable with ``--set``);
- ``--robot``, ``--device`` and ``--operator`` offer them;
- router, ``bipedtele follower --robot toy-walker`` and ``bipedtele leader --device
  toy-handle --operator toy-cruise`` run as separate processes on real Zenoh sessions, and
  the toy robot is driven: it walks forward at the speed the toy operator intends through
  the toy handle (the robot's own call log says so).

The recipe this proves is in docs/architecture.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from e2e_support import CLI, HERE, Procs, free_port, start_follower, start_leader, start_router, wait_until

PLUGIN = HERE.parent / "plugins" / "toy"
ENV = {"PYTHONPATH": os.pathsep.join([str(PLUGIN), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}

_CONTRACTS = """
import json
from bipedtele.config.profile import load_config
from bipedtele.follower.check import check_robot
from bipedtele.follower.robot import ROBOTS, make_robot
from bipedtele.leader.check import check_device
from bipedtele.leader.device import DEVICES, make_device
from bipedtele.leader.operator import OPERATORS, make_operator
from bipedtele.leader.operator_check import check_operator
from bipedtele.parts import PART_GROUPS

cfg = load_config("default")
check_robot(lambda: make_robot("toy-walker", config=cfg))
for name in DEVICES:
    if DEVICES.get(name).simulated:
        check_device(lambda name=name: make_device(name, config=cfg))
for name in OPERATORS:
    check_operator(lambda name=name: make_operator(name, cfg, joystick=lambda: None))
built = {
    "robot": make_robot("toy-walker", config=cfg).name,
    "device": make_device("toy-handle", config=cfg).name,
    "operator": make_operator("toy-cruise", cfg).name,
}
print(json.dumps({"robots": ROBOTS.names(), "devices": DEVICES.names(), "operators": OPERATORS.names(),
                  "sections": sorted(cfg.sections), "built": built}))
"""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **ENV}
    return subprocess.run(list(args), capture_output=True, text=True, timeout=120, env=env, cwd="/")


@pytest.mark.timeout(180)
def test_the_toy_parts_are_registered_checked_and_offered() -> None:
    res = _run(sys.executable, "-c", _CONTRACTS)
    assert res.returncode == 0, res.stderr[-3000:]
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert {"sim", "naoqi", "toy-walker"} <= set(got["robots"])
    assert {"sim-falcon", "falcon", "joystick", "toy-handle"} <= set(got["devices"])
    assert {"scripted", "pilot", "browser", "toy-cruise"} <= set(got["operators"])
    assert {"toy_walker", "toy_handle"} <= set(got["sections"])
    assert got["built"] == {"robot": "toy-walker", "device": "toy-handle", "operator": "toy-cruise"}
    follower_help = _run(*CLI, "follower", "--help").stdout
    leader_help = _run(*CLI, "leader", "--help").stdout
    assert "toy-walker" in follower_help
    assert "toy-handle" in leader_help and "toy-cruise" in leader_help
    # without the plugin on the path, nothing of it is offered
    plain = subprocess.run(
        [*CLI, "follower", "--robot", "toy-walker", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd="/",
        env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"},
    )
    assert plain.returncode == 2 and "toy-walker" in plain.stderr


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(180)
def test_bipedtele_drives_the_toy_robot_from_the_toy_handle_and_operator(procs: Procs, tmp_path: Path) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    calls = tmp_path / "toy-walker.jsonl"
    start_router(procs, ep)
    follower = start_follower(
        procs,
        ep,
        ["--robot", "toy-walker", "--set", f'toy_walker.log_path="{calls}"', "--set", "follower.camera_fps=0"],
        env=ENV,
    )
    leader = start_leader(
        procs,
        ep,
        ["--device", "toy-handle", "--operator", "toy-cruise", "--set", "leader.pilot_speed_cm_s=5"],
        env=ENV,
    )

    def walked() -> bool:
        if not calls.exists():
            return False
        sent = [json.loads(line) for line in calls.read_text().splitlines() if '"send_walk"' in line]
        return sum(1 for c in sent if c["forward_m_s"] > 0.02) >= 20

    wait_until(walked, 60.0, "the toy robot walking forward at more than 2 cm/s", procs.logs)
    assert leader.stop() == 0, leader.tail()
    assert follower.alive(), follower.tail()
    time.sleep(1.0)  # the watchdog stops the robot once the leader is gone
    assert follower.stop() == 0, follower.tail()
    log = [json.loads(line) for line in calls.read_text().splitlines()]
    assert log[0]["call"] == "connect" and log[-1]["call"] == "disconnect"
    assert any(c["call"] == "stop" for c in log[-5:])
