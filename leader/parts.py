"""The leader's built-in parts: five devices and three operator models, with the device settings sections.

Each ``PART`` here is one entry point (``bipedtele.devices``, ``bipedtele.operators`` in
pyproject.toml). Every program that loads a profile loads this module for the
``[joystick]`` and ``[falcon]`` sections the devices bring, so it holds no driver and no
model: each part imports its own module (``bipedtele.leader.devices.*``,
``bipedtele.leader.operators.*``) only when it builds one (the follower and the router never
load a leader device driver: tests/unit/test_device_parts.py). A new part needs none of this:
one module with its class, its settings and its part, and one entry point
(docs/architecture.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from bipedtele.config.profile import param
from bipedtele.leader.device import DevicePart
from bipedtele.leader.operator import OperatorPart
from bipedtele.parts import lazy

__all__ = [
    "BROWSER",
    "FALCON",
    "GAMEPAD",
    "JOYSTICK",
    "KEYBOARD",
    "PILOT",
    "SCRIPTED",
    "SIM_FALCON",
    "FFMode",
    "FalconConfig",
    "JoystickConfig",
    "PadConfig",
]

FFMode = Literal["auto", "constant", "rumble", "none"]


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
class PadConfig:
    """The ``[pad]`` section: the cockpit page's game controller and keyboard."""

    deadzone: float = param(0.08, lo=0.0, hi=0.5, doc="central dead zone of the stick, fraction of its half range")
    timeout_s: float = param(
        0.5, lo=0.05, hi=5.0, unit="s", doc="a page state older than this reads as centred, dead-man let go"
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


#: ``--device sim-falcon`` (its settings are in ``[leader]``).
SIM_FALCON = DevicePart(
    name="sim-falcon",
    doc="a simulated Novint Falcon (eq. 1)",
    build=lazy("bipedtele.leader.devices.sim_falcon:SimFalcon"),
    section="leader",
    simulated=True,
)
#: ``--device falcon``.
FALCON = DevicePart(
    name="falcon",
    doc="a Novint Falcon through libftdi1",
    build=lazy("bipedtele.leader.devices.falcon:FalconDevice"),
    section="falcon",
    config=FalconConfig,
)
#: ``--device joystick``.
JOYSTICK = DevicePart(
    name="joystick",
    doc="a Linux evdev joystick or gamepad",
    build=lazy("bipedtele.leader.devices.joystick:JoystickDevice"),
    section="joystick",
    config=JoystickConfig,
)
#: ``--device gamepad``.
GAMEPAD = DevicePart(
    name="gamepad",
    doc="a game controller in the cockpit's page (browser Gamepad API, any OS; rumble for the force)",
    build=lazy("bipedtele.leader.devices.pad:PadDevice"),
    section="pad",
    config=PadConfig,
    force_output=False,
    needs_cockpit=True,
)
#: ``--device keyboard``.
KEYBOARD = DevicePart(
    name="keyboard",
    doc="the keyboard in the cockpit's page (arrows, space as the dead-man, Escape to stop)",
    build=lazy("bipedtele.leader.devices.pad:KeyboardDevice"),
    section="pad",
    config=PadConfig,
    force_output=False,
    needs_cockpit=True,
)
#: ``--operator scripted``.
SCRIPTED = OperatorPart(
    name="scripted",
    doc="a profile of intended speeds over time ([leader] script)",
    build=lazy("bipedtele.leader.operators.scripted:build"),
)
#: ``--operator pilot``.
PILOT = OperatorPart(
    name="pilot",
    doc="the paper's task: evade obstacles left and right, N passes",
    build=lazy("bipedtele.leader.operators.pilot:build"),
)
#: ``--operator browser``.
BROWSER = OperatorPart(
    name="browser",
    doc="the cockpit's virtual joystick (leader.cockpit = true)",
    build=lazy("bipedtele.leader.operators.browser:build"),
)
