"""Leader devices: the ``--device`` choices and the profile's check come from the entry points,
and the follower and router processes stay free of leader device drivers."""

from __future__ import annotations

import subprocess
import sys

import pytest
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.leader.device import device_names, device_part

pytestmark = pytest.mark.timeout(120)

_PROBE = """
import sys
from bipedtele.config.profile import ConfigError, load_config
cfg = load_config("default")
cfg.section("joystick"); cfg.section("falcon")
import bipedtele.follower.app, bipedtele.tools.router
loaded = sorted(m for m in sys.modules if m.startswith("bipedtele.leader."))
print(" ".join(loaded))
"""


def test_follower_and_router_load_no_leader_device_driver() -> None:
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=60, check=True)
    loaded = out.stdout.split()
    assert not [m for m in loaded if m.startswith("bipedtele.leader.devices")], loaded
    assert "bipedtele.leader.app" not in loaded


def test_unknown_device_names_the_allowed_ones() -> None:
    with pytest.raises(ValueError, match="allowed: falcon, gamepad, joystick, keyboard, sim-falcon"):
        device_part("nope")


def test_leader_device_choices_come_from_the_entry_points() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "leader", "--device", "nope", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2, out.stderr  # argparse: a bad choice, one line, exit 2
    for name in device_names():
        assert name in out.stderr


def test_a_profile_naming_an_unknown_device_fails_at_load_naming_the_allowed_ones() -> None:
    with pytest.raises(
        ConfigError, match=r"device.*'nope'.*allowed: 'falcon', 'gamepad', 'joystick', 'keyboard', 'sim-falcon'"
    ):
        load_config("default", ['leader.device="nope"'])
