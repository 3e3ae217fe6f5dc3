"""JoystickDevice with a fake evdev event stream (always) and a virtual uinput pad (where allowed)."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest

evdev = pytest.importorskip("evdev")
from bipedtele.leader.device import DeviceError, DeviceNotConnectedError, make_device  # noqa: E402
from bipedtele.leader.devices.joystick import JoystickDevice, ff_direction  # noqa: E402
from evdev import ecodes  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fakes.fake_evdev import FakeInputDevice  # noqa: E402

pytestmark = pytest.mark.timeout(30)


def _device(fake: FakeInputDevice, **kw) -> JoystickDevice:
    return JoystickDevice(opener=lambda path: fake, lister=lambda: [fake.path], **kw)


def test_ff_direction_follows_the_kernel_convention():
    assert ff_direction(np.array([-1.0, 0.0])) == 0x0000  # pull towards the user: down
    assert ff_direction(np.array([0.0, 1.0])) == 0x4000  # left
    assert ff_direction(np.array([1.0, 0.0])) == 0x8000  # push away: up
    assert ff_direction(np.array([0.0, -1.0])) == 0xC000  # right


def test_axes_map_to_the_falcon_workspace():
    fake = FakeInputDevice(lo=0, hi=255)
    with _device(fake, deadzone=0.0, enable_button="BTN_SOUTH") as dev:
        assert np.allclose(dev.read().x_m, 0.0, atol=1e-3)
        assert dev.read().buttons == (False, False)
        fake.move(ecodes.ABS_Y, 0)  # stick fully forward (reads minimum)
        fake.move(ecodes.ABS_X, 255)  # fully right
        x = dev.read().x_m
        assert x[0] == pytest.approx(0.05, rel=0.01) and x[1] == pytest.approx(-0.05, rel=0.01)
        fake.move(ecodes.ABS_Y, 64)
        assert dev.read().x_m[0] == pytest.approx(0.05 * 64 / 127.5, rel=0.02)
        fake.move(ecodes.BTN_SOUTH, 1)
        assert dev.read().buttons == (True, False)
        assert np.all(np.abs(dev.read().x_m) <= 0.05)


def test_deadzone_and_flat_hold_the_centre():
    fake = FakeInputDevice(lo=-32768, hi=32767, flat=1024)
    with _device(fake, deadzone=0.1) as dev:
        fake.move(ecodes.ABS_Y, -3000)  # inside 10 %
        assert dev.read().x_m[0] == 0.0
        fake.move(ecodes.ABS_Y, -32768)
        assert dev.read().x_m[0] == pytest.approx(0.05)


def test_constant_force_effect_tracks_direction_and_level():
    fake = FakeInputDevice(ff=(ecodes.FF_CONSTANT, ecodes.FF_GAIN))
    with _device(fake, ff_rate_hz=1000.0) as dev:
        assert dev.ff_mode == "constant"
        eid = fake.uploads[0].id if fake.uploads[0].id >= 0 else 0
        assert (ecodes.EV_FF, eid, 1) in fake.writes  # playing
        time.sleep(0.002)
        applied = dev.apply_force(np.array([4.0, 0.0]))
        assert np.allclose(applied, [4.0, 0.0])
        eff = fake.uploads[-1]
        assert eff.type == ecodes.FF_CONSTANT and eff.direction == 0x8000
        assert eff.u.ff_constant_effect.level == pytest.approx(0x7FFF / 2, abs=1)
        time.sleep(0.002)
        dev.apply_force(np.array([0.0, -100.0]))  # clamped to 8 N, to the right
        eff = fake.uploads[-1]
        assert eff.direction == 0xC000 and eff.u.ff_constant_effect.level == 0x7FFF
        assert len(fake.effects) == 1  # updated in place, not piled up
    assert fake.closed and fake.effects == {}
    assert fake.writes[-1] == (ecodes.EV_FF, eid, 0)  # stopped before closing


def test_rumble_fallback_and_no_feedback():
    fake = FakeInputDevice(ff=(ecodes.FF_RUMBLE,))
    with _device(fake, ff_rate_hz=1000.0) as dev:
        assert dev.ff_mode == "rumble"
        time.sleep(0.002)
        dev.apply_force(np.array([0.0, 8.0]))
        eff = fake.uploads[-1]
        assert eff.type == ecodes.FF_RUMBLE and eff.u.ff_rumble_effect.strong_magnitude == 0xFFFE
    fake = FakeInputDevice(ff=())
    with _device(fake) as dev:
        assert dev.ff_mode == "none"
        assert np.allclose(dev.apply_force(np.array([20.0, np.nan])), [8.0, 0.0])
        assert fake.uploads == []


def test_missing_device_and_unplug_are_one_line_errors():
    with pytest.raises(DeviceError, match="no joystick") as info:
        JoystickDevice(opener=lambda p: FakeInputDevice(), lister=lambda: []).connect()
    assert "\n" not in str(info.value)
    with pytest.raises(DeviceError, match="named like 'xbox'"):
        JoystickDevice(
            device="xbox", opener=lambda p: FakeInputDevice(name="Fake Pad"), lister=lambda: ["/dev/input/event3"]
        ).connect()
    with pytest.raises(DeviceError, match="no device at /nonexistent/event0"):
        JoystickDevice(device="/nonexistent/event0").connect()
    fake = FakeInputDevice()
    dev = _device(fake)
    with pytest.raises(DeviceNotConnectedError):
        dev.read()
    dev.connect()
    fake.fail_reads = True
    with pytest.raises(DeviceError, match="gone"):
        dev.read()
    assert not dev.is_connected


def test_registered_and_passes_the_device_contract():
    from bipedtele.leader.check import check_device

    assert isinstance(make_device("joystick"), JoystickDevice)
    check_device(lambda: _device(FakeInputDevice()), steps=20)


def test_fake_stream_drives_a_full_leader_loop():
    from bipedtele.control.config import ControlConfig
    from bipedtele.leader.config import LeaderConfig
    from bipedtele.leader.loop import LeaderLoop
    from bipedtele.link.inbox import FeedbackInbox
    from bipedtele.link.messages import Feedback

    fake = FakeInputDevice(ff=(ecodes.FF_CONSTANT,))
    sent = []
    with _device(fake, ff_rate_hz=1000.0, deadzone=0.0) as dev:
        loop = LeaderLoop(
            dev,
            None,
            ControlConfig(),
            sent.append,
            FeedbackInbox(source=lambda: (Feedback(t=loop.now, z_e=[0.0, 0.0]), loop.now)),
            cfg=LeaderConfig(haptic_rate_hz=1000.0, cmd_rate_hz=100.0),
        )
        fake.move(ecodes.ABS_Y, 0)  # full forward: the robot is asked to walk, z_e = 0 pulls back
        for _ in range(400):
            loop.tick()
            time.sleep(0.0002)
        assert len(sent) >= 30
        assert sent[-1].ref[0] > 0.0  # forward speed asked
        assert loop.force[0] < 0.0  # the operator feels the pull back
        eff = fake.uploads[-1]
        assert eff.type == ecodes.FF_CONSTANT and eff.u.ff_constant_effect.level > 0
        assert min(eff.direction, 0x10000 - eff.direction) < 0x200  # towards the user (0x0000)


uinput_ok = os.path.exists("/dev/uinput") and os.access("/dev/uinput", os.W_OK)


@pytest.mark.skipif(
    not uinput_ok, reason="/dev/uinput is missing or not writable here (needs the uinput module and permission)"
)
def test_virtual_uinput_pad():
    caps = {
        ecodes.EV_ABS: [
            (ecodes.ABS_X, evdev.AbsInfo(0, -100, 100, 0, 0, 0)),
            (ecodes.ABS_Y, evdev.AbsInfo(0, -100, 100, 0, 0, 0)),
        ],
        ecodes.EV_KEY: [ecodes.BTN_SOUTH],
    }
    with evdev.UInput(caps, name="bipedtele-test-pad") as ui:
        time.sleep(0.3)  # udev creates the node
        with JoystickDevice(device="bipedtele-test-pad", deadzone=0.0) as dev:
            assert dev.ff_mode == "none"
            ui.write(ecodes.EV_ABS, ecodes.ABS_Y, -100)
            ui.syn()
            deadline = time.monotonic() + 3.0
            while dev.read().x_m[0] < 0.049 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert dev.read().x_m[0] == pytest.approx(0.05)
