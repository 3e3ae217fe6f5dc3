"""FalconDevice against a fake libftdi1 with a simulated Falcon behind it."""

from __future__ import annotations

import ctypes
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from bipedtele.leader.device import DeviceError, DeviceNotConnectedError, make_device
from bipedtele.leader.devices import falcon_protocol as fp
from bipedtele.leader.devices.falcon import FalconDevice
from bipedtele.leader.devices.falcon_usb import load_libftdi

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fakes.fake_libftdi import FakeFalconLib

pytestmark = pytest.mark.timeout(60)


def _until(cond, timeout_s=3.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.005)
    raise AssertionError("condition not met in time")


def test_packets_round_trip_and_kinematics_invert():
    pk = fp.encode_command(np.array([100, -200, 32767]), fp.LED_GREEN, homing=True)
    assert len(pk) == 16 and pk[:1] == b"<" and pk[-1:] == b">"
    lib = FakeFalconLib()
    lib.baud = 1456312
    lib.homed = 0x7
    lib.buttons = 0b0101
    lib.ftdi_write_data(None, pk, 16)
    assert lib.efforts[-1].tolist() == [100, -200, 32767] and lib.homing_flags[-1]
    counts, homed, buttons = fp.decode_status(bytes(lib.out))
    assert homed == 0x7 and buttons == 0b0101
    assert np.allclose(fp.position(fp.encoder_angles(counts)), fp.CENTER, atol=2e-4)  # encoder resolution
    for p in (np.add(fp.CENTER, [0.04, 0.02, -0.04]), np.add(fp.CENTER, [-0.05, -0.03, 0.05])):
        assert np.allclose(fp.position(fp.arm_angles(p)), p, atol=1e-9)
    with pytest.raises(ValueError):
        fp.decode_status(b"<short>")


def test_connect_homes_then_reads_and_renders_forces():
    lib = FakeFalconLib(homing_packets=30)
    with FalconDevice(lib_loader=lambda: lib) as dev:
        homing = [led for led, h in zip(lib.leds, lib.homing_flags, strict=True) if h]
        assert len(homing) >= 30 and set(homing) == {fp.LED_RED}  # homing with the red LED
        assert not lib.homing_flags[-1] and lib.leds[-1] == fp.LED_GREEN
        lib.grip = fp.CENTER + np.array([0.02, 0.0, -0.03])  # pushed away and to the right
        _until(lambda: abs(dev.read().x_m[0] - 0.03) < 1e-3)
        x = dev.read().x_m
        assert x[0] == pytest.approx(0.03, abs=1e-3) and x[1] == pytest.approx(-0.02, abs=1e-3)
        assert np.allclose(dev.apply_force(np.array([20.0, -3.0])), [8.0, -3.0])
        n = len(lib.efforts)
        _until(lambda: len(lib.efforts) > n + 5)
        f = lib.cartesian_force()
        # handle axis 0 (+8 N forward) is -z, axis 1 (-3 N, to the right) is +x; y holds the centre
        assert f[2] == pytest.approx(-8.0, abs=0.05) and f[0] == pytest.approx(3.0, abs=0.05)
        assert abs(f[1]) < 0.05
        _until(lambda: dev.loops > 10)  # the I/O thread keeps running (no rate asserted)
    assert not lib.opened and lib.efforts[-1].tolist() == [0, 0, 0]  # motors off at exit


def test_firmware_is_loaded_when_missing(tmp_path):
    image = bytes(range(256)) * 3
    fw = tmp_path / "nvent_firmware.bin"
    fw.write_bytes(image)
    lib = FakeFalconLib(firmware_loaded=False, homing_packets=3)
    with pytest.raises(DeviceError, match="firmware_file"):
        FalconDevice(lib_loader=lambda: lib).connect()
    assert not lib.opened
    with FalconDevice(lib_loader=lambda: lib, firmware_file=str(fw)) as dev:
        assert bytes(lib.firmware) == image and lib.dtr[:2] == [0, 1]
        assert np.all(np.isfinite(dev.read().x_m))


def test_missing_library_device_permission_homing_are_one_line():
    def no_lib():
        raise OSError("libftdi1.so.2: cannot open shared object file")

    orig = ctypes.CDLL
    ctypes.CDLL = lambda *a, **k: no_lib()  # type: ignore[assignment,misc]
    try:
        with pytest.raises(DeviceError, match="apt-get install libftdi1-2"):
            load_libftdi()
    finally:
        ctypes.CDLL = orig  # type: ignore[misc]
    cases = [
        (FakeFalconLib(present=False), "no Novint Falcon .*0403:cb48"),
        (FakeFalconLib(permission=False), "udev rule"),
    ]
    for lib, msg in cases:
        with pytest.raises(DeviceError, match=msg) as info:
            FalconDevice(lib_loader=lambda lib=lib: lib).connect()
        assert "\n" not in str(info.value)
    lib = FakeFalconLib(homing_packets=10**9)
    with pytest.raises(DeviceError, match="not homed"):
        FalconDevice(lib_loader=lambda: lib, homing_timeout_s=1.0).connect()
    assert not lib.opened


def test_unplugged_mid_run_raises_device_error():
    lib = FakeFalconLib(homing_packets=2)
    dev = FalconDevice(lib_loader=lambda: lib)
    dev.connect()
    lib.unplugged = True
    _until(lambda: dev._error is not None)
    with pytest.raises(DeviceError, match="USB"):
        dev.read()
    dev.disconnect()
    with pytest.raises(DeviceNotConnectedError):
        dev.read()


def test_device_contract_and_registration():
    from bipedtele.leader.check import check_device

    assert isinstance(make_device("falcon"), FalconDevice)
    check_device(lambda: FalconDevice(lib_loader=lambda: FakeFalconLib(homing_packets=2)), steps=20)


def test_fake_falcon_drives_a_full_leader_loop():
    from bipedtele.control.config import ControlConfig
    from bipedtele.leader.config import LeaderConfig
    from bipedtele.leader.loop import LeaderLoop
    from bipedtele.link.inbox import FeedbackInbox
    from bipedtele.link.messages import Feedback

    lib = FakeFalconLib(homing_packets=2)
    sent = []
    with FalconDevice(lib_loader=lambda: lib) as dev:
        loop = LeaderLoop(
            dev,
            None,
            ControlConfig(),
            sent.append,
            FeedbackInbox(source=lambda: (Feedback(t=loop.now, z_e=[0.0, 0.0]), loop.now)),
            cfg=LeaderConfig(haptic_rate_hz=1000.0, cmd_rate_hz=100.0),
        )
        lib.grip = fp.CENTER + np.array([0.0, 0.0, -0.04])  # the hand pushes the grip forward
        _until(lambda: dev.read().x_m[0] > 0.039)
        for _ in range(400):
            loop.tick()
            time.sleep(0.0005)
        assert len(sent) >= 30 and sent[-1].ref[0] > 0.0  # walk forward asked
        assert loop.force[0] < 0.0  # pulled back towards z_e = 0
        n = len(lib.efforts)
        _until(lambda: len(lib.efforts) > n + 3)
        assert lib.cartesian_force()[2] > 0.0  # rendered towards the operator (+z)


def test_cli_without_falcon_exits_with_what_is_missing():
    proc = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "leader", "--device", "falcon", "--set", "leader.cockpit=false"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode in (1, 2)
    assert "libftdi1" in proc.stderr or "no Novint Falcon" in proc.stderr
