"""Contract checkers run over every registered robot and leader device (Gymnasium-style).

Hardware needing a fake service (the NAOqi bridge, the Falcon over libftdi, the evdev
joystick) is checked with its fake in its own test module; here every registration is
checked for its spec and capability flags, and every simulated implementation through
the full checker.
"""

from __future__ import annotations

import pytest
from bipedtele.config.profile import load_config
from bipedtele.follower.check import check_robot
from bipedtele.follower.robot import make_robot, robot_names, robot_part
from bipedtele.leader.check import check_device
from bipedtele.leader.device import DEVICES, DeviceError, make_device

pytestmark = pytest.mark.timeout(120)


def test_every_robot_part_builds_a_robot_of_its_name() -> None:
    cfg = load_config("default")
    assert "sim" in robot_names()
    for name in robot_names():
        part = robot_part(name)
        assert part.section in cfg.sections
        assert make_robot(name, config=cfg).name == name  # built, not connected


@pytest.mark.parametrize("name", [n for n in robot_names() if robot_part(n).simulated])
def test_simulated_robots_keep_the_contract(name: str) -> None:
    cfg = load_config("default")
    step = robot_part(name).step_s(cfg)
    assert step is not None and 0 < step <= 0.02
    check_robot(lambda: make_robot(name, config=cfg))


def test_every_device_flags_its_capability_and_simulated_ones_keep_the_contract() -> None:
    cfg = load_config("default")
    assert "sim-falcon" in DEVICES
    for name in DEVICES:
        dev = make_device(name, config=cfg)
        assert dev.name == name and dev.simulated is DEVICES.get(name).simulated
        if dev.simulated:
            check_device(lambda name=name: make_device(name, config=cfg))
            dev.set_operator(None)  # a simulated device takes a simulated hand
        else:
            with pytest.raises(DeviceError):
                dev.set_operator(None)
