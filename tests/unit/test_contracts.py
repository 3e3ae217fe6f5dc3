"""Contract checkers run over every registered robot and leader device (Gymnasium-style).

Hardware needing a fake service (the NAOqi bridge, the Falcon over libftdi, the evdev
joystick) is checked with its fake in its own test module; here every registration is
checked for its spec and capability flags, and every simulated implementation through
the full checker.
"""

from __future__ import annotations

import pytest
from bipedtele.config import load_config
from bipedtele.follower.check import check_robot
from bipedtele.follower.robot import ROBOTS, make_robot
from bipedtele.follower.robots import ROBOT_SPECS, robot_names
from bipedtele.leader.check import check_device
from bipedtele.leader.device import DEVICES, DeviceError, make_device

pytestmark = pytest.mark.timeout(120)


def test_every_robot_spec_has_a_registered_driver_and_back() -> None:
    make_robot("sim", config=load_config("default"))  # loads the built-in drivers
    assert set(ROBOTS) <= set(ROBOT_SPECS)
    assert "sim" in ROBOTS
    for name in robot_names():
        spec = ROBOT_SPECS[name]
        assert spec.name == name and spec.section in load_config("default").sections


@pytest.mark.parametrize("name", [n for n in robot_names() if ROBOT_SPECS[n].simulated])
def test_simulated_robots_keep_the_contract(name: str) -> None:
    cfg = load_config("default")
    step = ROBOT_SPECS[name].step_s(cfg)
    assert step is not None and 0 < step <= 0.02
    check_robot(lambda: make_robot(name, config=cfg))


def test_every_device_flags_its_capability_and_simulated_ones_keep_the_contract() -> None:
    cfg = load_config("default")
    make_device("sim-falcon", config=cfg)
    assert "sim-falcon" in DEVICES
    for name in DEVICES:
        dev = make_device(name, config=cfg)
        if dev.simulated:
            check_device(lambda name=name: make_device(name, config=cfg))
            dev.set_operator(None)  # a simulated device takes a simulated hand
        else:
            with pytest.raises(DeviceError):
                dev.set_operator(None)
