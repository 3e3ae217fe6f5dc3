"""Issue 24: the cockpit page's gamepad and keyboard as leader devices (the contract, the mapping, the flags)."""

from __future__ import annotations

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.leader.check import check_device
from bipedtele.leader.device import DEVICES, DeviceError, PadInput, make_device

pytestmark = pytest.mark.timeout(30)


class Page:
    """What the cockpit hands the device: the page's newest controller state."""

    def __init__(self) -> None:
        self.t = 1000.0
        self.state: PadInput | None = None

    def clock(self) -> float:
        return self.t

    def set(self, src: str, x: float, y: float, held: bool) -> None:
        self.state = PadInput(src, x, y, held, self.t)


def _device(name: str, page: Page):  # type: ignore[no-untyped-def]
    dev = make_device(name, config=load_config("default"))
    dev._clock = page.clock  # the device's time source: the page's clock here
    dev.attach_cockpit(lambda: page.state)
    return dev


@pytest.mark.parametrize("name", ["gamepad", "keyboard"])
def test_the_page_devices_keep_the_contract_and_flag_no_force_output(name: str) -> None:
    page = Page()
    page.set(name, 0.3, 1.0, True)
    check_device(lambda: _device(name, page))
    part = DEVICES.get(name)
    dev = _device(name, page)
    assert not dev.simulated and not dev.force_output and dev.needs_cockpit
    assert (part.simulated, part.force_output, part.needs_cockpit) == (False, False, True)
    with pytest.raises(DeviceError):
        dev.set_operator(None)  # a person holds it


def test_stick_to_handle_like_the_other_devices_dead_man_and_staleness() -> None:
    page = Page()
    dev = _device("gamepad", page)
    dev.connect()
    w, dz = dev.limits.workspace_m, dev.deadzone
    page.set("gamepad", 0.04, 0.9, True)  # x inside the dead zone
    hs = dev.read()
    assert hs.x_m == pytest.approx([0.98 * w * (0.9 - dz) / (1 - dz), 0.0]) and hs.buttons == (True,)
    page.set("gamepad", 1.0, -1.0, False)  # full right and back, dead-man let go
    hs = dev.read()
    assert hs.x_m == pytest.approx([-0.98 * w, -0.98 * w]) and hs.buttons == (False,)
    page.set("keyboard", 0.0, 1.0, True)  # another source: not this device's
    assert dev.read().buttons == (False,) and np.all(dev.read().x_m == 0.0)
    page.set("gamepad", 0.0, 1.0, True)
    page.t += dev.timeout_s + 0.01  # the page went silent
    hs = dev.read()
    assert np.all(hs.x_m == 0.0) and hs.buttons == (False,)
    assert dev.apply_force(np.array([20.0, -1.0])) == pytest.approx([dev.limits.force_max_n, -1.0])
    assert dev.force == pytest.approx([dev.limits.force_max_n, -1.0])  # what the page rumbles


def test_without_the_cockpit_it_says_so() -> None:
    dev = make_device("gamepad", config=load_config("default"))
    with pytest.raises(DeviceError, match=r"leader\.cockpit = true"):
        dev.connect()
