"""The leader devices the program offers, with their settings: no driver is imported here.

Every device of ``--device`` and ``[leader] device`` is one :class:`DeviceSpec` in
:data:`DEVICE_SPECS`: its name, the profile section that configures it, and whether a
simulated operator's hand moves it. The ``[joystick]`` and ``[falcon]`` sections are
defined here too, so that loading a profile (every program does, the follower and the
router included) never imports a device driver. The command line's choices are built
from this table; :func:`bipedtele.leader.device.make_device` loads the driver class
registered under the same name (the drivers register themselves when
:mod:`bipedtele.leader.devices` is imported).

To add a device: implement :class:`~bipedtele.leader.device.LeaderDevice` in a module of
:mod:`bipedtele.leader.devices` (decorate the class with ``@register_device("name")`` and
import the module in that package's ``__init__``), put its settings section here (and
under ``bipedtele.config`` in pyproject.toml's entry points), then add its spec; the
contract tests (tests/unit/test_contracts.py, tests/unit/test_device_specs.py) check
that specs and drivers match.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from bipedtele.config import param

__all__ = [
    "DEVICE_SPECS",
    "DeviceSpec",
    "FFMode",
    "FalconConfig",
    "JoystickConfig",
    "device_names",
    "device_spec",
]

FFMode = Literal["auto", "constant", "rumble", "none"]


@dataclass(frozen=True)
class DeviceSpec:
    """What the program knows about one leader device before loading its driver.

    Attributes
    ----------
    name : str
        ``--device`` value.
    section : str
        The profile section that configures it.
    simulated : bool
        A simulated operator's hand moves it (operator models drive it); False when a
        person holds it. Equal to the driver's :attr:`LeaderDevice.simulated`.
    doc : str
        One line for the help.
    """

    name: str
    section: str
    simulated: bool
    doc: str


DEVICE_SPECS: dict[str, DeviceSpec] = {
    "sim-falcon": DeviceSpec("sim-falcon", "leader", simulated=True, doc="a simulated Novint Falcon (eq. 1)"),
    "falcon": DeviceSpec("falcon", "falcon", simulated=False, doc="a Novint Falcon through libftdi1"),
    "joystick": DeviceSpec("joystick", "joystick", simulated=False, doc="a Linux evdev joystick or gamepad"),
}


def device_names() -> list[str]:
    """Return the names of the devices offered, sorted."""
    return sorted(DEVICE_SPECS)


def device_spec(name: str) -> DeviceSpec:
    """Return the spec of ``name``.

    Raises
    ------
    ValueError
        No such device; the message lists the allowed ones.
    """
    try:
        return DEVICE_SPECS[name]
    except KeyError:
        raise ValueError(f"device {name!r}: allowed: {', '.join(device_names())}") from None


@dataclass(frozen=True)
class JoystickConfig:
    """The ``[joystick]`` section: which evdev device and how its axes map."""

    device: str = param(
        "", doc="/dev/input/eventN, or part of the device name; empty: the first device with the two axes"
    )
    axis_forward: str = param("ABS_Y", doc="evdev axis giving handle axis 0 (forward speed)")
    axis_turn: str = param("ABS_X", doc="evdev axis giving handle axis 1 (turn)")
    invert_forward: bool = param(True, doc="stick forward reads negative on most pads: invert so forward is +")
    invert_turn: bool = param(True, doc="stick left reads negative: invert so left (counter-clockwise) is +")
    deadzone: float = param(0.05, lo=0.0, hi=0.5, doc="central dead zone, fraction of the half range")
    force_feedback: FFMode = param("auto", doc="auto: constant force if supported, else rumble, else none")
    ff_rate_hz: float = param(100.0, lo=1.0, hi=1000.0, unit="Hz", doc="largest effect update rate")
    enable_button: str = param(
        "",
        doc="dead-man button, reported as button 0 (e.g. BTN_SOUTH, BTN_TRIGGER): walking only while held; empty: none, and no buttons are reported",
    )


@dataclass(frozen=True)
class FalconConfig:
    """The ``[falcon]`` section."""

    firmware_file: str = param(
        "", doc="Novint firmware image (e.g. nvent_firmware.bin from libnifalcon); needed once per power-up"
    )
    homing_timeout_s: float = param(60.0, lo=1.0, hi=600.0, unit="s", doc="give up homing after this long")
    io_rate_hz: float = param(1000.0, lo=100.0, hi=2000.0, unit="Hz", doc="I/O loop rate")
    force_gain: float = param(
        1.0, lo=0.0, hi=10.0, doc="scale of motor efforts (libnifalcon's units: effort = -(dtheta/dp) F)"
    )
    hold_stiffness_n_m: float = param(
        150.0, lo=0.0, hi=2000.0, unit="N/m", doc="spring holding the unused vertical axis at the centre"
    )
    hold_damping_n_s_m: float = param(3.0, lo=0.0, hi=100.0, unit="N s/m", doc="damper on the vertical axis")
    center_z_m: float = param(0.11, lo=0.05, hi=0.2, unit="m", doc="z of the workspace centre (grip rest point)")
    enable_button: int = param(
        -1,
        lo=-1,
        hi=3,
        doc="grip button (bit 0-3) used as the dead-man switch, reported as button 0; -1: none, and no buttons are reported",
    )
    io_timeout_s: float = param(
        0.5, lo=0.01, hi=10.0, unit="s", doc="no status packet for this long: the Falcon is gone"
    )
