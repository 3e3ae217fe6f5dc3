"""The leader-device contract: one abstract class every haptic/input device implements.

A :class:`LeaderDevice` is the operator's handle: the simulated Falcon
(``bipedtele.leader.devices.sim_falcon``), a real Novint Falcon through libnifalcon, a
force-feedback joystick through evdev. Two handle axes are used: axis 0 maps to the
forward speed, axis 1 to the turn speed (through ``k_g``, eq. 7 and 11).

Contract (checked by :func:`bipedtele.leader.check.check_device`):

- ``connect()`` then ``read()``/``apply_force()``/``advance()``; calling them before
  ``connect()`` raises :class:`DeviceNotConnectedError`.
- ``read()`` returns positions within :attr:`DeviceLimits.workspace_m` and finite values.
- ``apply_force(f)`` clamps each axis to ``force_max_n`` (non-finite -> 0) and returns
  the force actually applied.
- ``advance(dt)`` lets ``dt`` seconds of device time pass: a simulated device integrates
  its dynamics (eq. 1) under the applied force and the operator's force; a real device
  services its I/O and returns (the loop paces).
- ``disconnect()`` zeroes the force, is idempotent and runs on leaving a ``with`` block.
- ``set_operator(hand)`` attaches a simulated operator's hand (f_h of eq. 1) to a
  simulated device; physical devices are moved by a real hand and raise
  :class:`DeviceError`.
- Capability flags: :attr:`LeaderDevice.simulated`, :attr:`LeaderDevice.force_output`
  (False: the force is not put on the hand; a gamepad renders it as rumble) and
  :attr:`LeaderDevice.needs_cockpit` (its input comes from the cockpit's page:
  :meth:`LeaderDevice.attach_cockpit`).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, TypeVar

import numpy as np
from bipedtele.parts import PART_GROUPS, Part, Parts

__all__ = [
    "DEVICES",
    "DeviceError",
    "DeviceLimits",
    "DeviceNotConnectedError",
    "DevicePart",
    "HandleState",
    "LeaderDevice",
    "OperatorHand",
    "PadInput",
    "device_names",
    "device_part",
    "make_device",
]


class DeviceError(RuntimeError):
    """The device is missing or failed. The message says what is missing and how to get it."""


class DeviceNotConnectedError(DeviceError):
    """A method was called before ``connect()`` or after ``disconnect()``."""


@dataclass(frozen=True)
class DeviceLimits:
    """Physical limits of the handle (Novint Falcon defaults, docs/hardware.md).

    Attributes
    ----------
    workspace_m : float
        Half-width of the usable workspace on each axis [m] (handle in [-w, w]).
    force_max_n : float
        Largest force per axis [N].
    servo_rate_hz : float
        Rate of the device's servo loop [Hz].
    """

    workspace_m: float = 0.05
    force_max_n: float = 8.0
    servo_rate_hz: float = 1000.0


@dataclass(frozen=True)
class HandleState:
    """The handle at device time ``t``.

    Attributes
    ----------
    t : float
        Device time [s].
    x_m : numpy.ndarray
        Position of the two axes [m], shape (2,).
    dx_m : numpy.ndarray
        Velocity of the two axes [m/s], shape (2,).
    buttons : tuple of bool
        Button states (button 0 is the dead-man/enable button where the device has one).
    """

    t: float
    x_m: np.ndarray
    dx_m: np.ndarray
    buttons: tuple[bool, ...] = ()


@dataclass(frozen=True)
class PadInput:
    """One state of the cockpit page's controller (devices ``gamepad``, ``keyboard``).

    Attributes
    ----------
    src : str
        ``gamepad`` or ``keyboard``.
    x, y : float
        Stick (arrows) right and up, each in [-1, 1].
    held : bool
        The dead-man button is held (and no stop is latched).
    t : float
        When the server received it [s, ``time.time()``].
    """

    src: str
    x: float
    y: float
    held: bool
    t: float


class OperatorHand(Protocol):
    """A simulated operator's hand: the force f_h it puts on the handle (eq. 1)."""

    def hand_force(self, t: float, x_m: np.ndarray, dx_m: np.ndarray) -> np.ndarray:
        """Return the force [N] per axis on the handle.

        At device time ``t`` [s], position ``x_m`` [m] and velocity ``dx_m`` [m/s].
        """
        ...


class LeaderDevice(abc.ABC):
    """Base class of every leader device. See the module docstring for the contract."""

    name: ClassVar[str] = ""
    #: Capability flag: True when a simulated operator's hand moves the device (operator
    #: models drive it, :meth:`set_operator` accepts a hand); False when a person holds it.
    simulated: ClassVar[bool] = False
    #: Capability flag: True when ``apply_force`` pushes the operator's hand (a Falcon, a
    #: force-feedback stick); False when the force is only shown (a gamepad's rumble).
    force_output: ClassVar[bool] = True
    #: Capability flag: True when the input comes from the cockpit's browser page (the
    #: leader then needs ``leader.cockpit = true`` and calls :meth:`attach_cockpit`).
    needs_cockpit: ClassVar[bool] = False
    limits: DeviceLimits = DeviceLimits()

    @property
    @abc.abstractmethod
    def is_connected(self) -> bool:
        """True between ``connect()`` and ``disconnect()``."""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the device (and home it where needed)."""

    @abc.abstractmethod
    def disconnect(self) -> None:
        """Zero the force and release the device. Idempotent."""

    @abc.abstractmethod
    def read(self) -> HandleState:
        """Read the handle now."""

    @abc.abstractmethod
    def apply_force(self, force_n: np.ndarray) -> np.ndarray:
        """Command a force [N] per axis; return the force actually applied (clamped)."""

    @abc.abstractmethod
    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds of device time pass (simulated devices integrate eq. 1)."""

    def set_operator(self, hand: OperatorHand | None) -> None:
        """Attach a simulated hand (``None`` detaches). Only simulated devices accept one."""
        raise DeviceError(
            f"device {self.name!r} is moved by a real hand; operator models need a simulated "
            "device (--device sim-falcon)"
        )

    def attach_cockpit(self, pad: Any) -> None:
        """Give a device that reads the cockpit's page its input (``() -> PadInput | None``)."""
        raise DeviceError(f"device {self.name!r} does not read the cockpit's page")

    def clamp_force(self, force_n: np.ndarray) -> np.ndarray:
        """``force_n`` clamped to the device limit, non-finite entries set to 0."""
        f = np.asarray(force_n, dtype=float).reshape(2)
        f = np.where(np.isfinite(f), f, 0.0)
        lim = self.limits.force_max_n
        return np.clip(f, -lim, lim)

    def __enter__(self: D) -> D:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


D = TypeVar("D", bound=LeaderDevice)


@dataclass(frozen=True)
class DevicePart(Part):
    """A leader device the leader offers (``--device``, ``[leader] device``).

    One entry point of ``bipedtele.devices``. ``build(config=cfg)`` returns a
    :class:`LeaderDevice` whose ``name`` is the part's.

    Attributes
    ----------
    simulated : bool
        A simulated operator's hand moves it (operator models drive it); False when a
        person holds it. Equal to the device's :attr:`LeaderDevice.simulated`.
    force_output : bool
        The force reaches the hand (equal to :attr:`LeaderDevice.force_output`).
    needs_cockpit : bool
        Its input comes from the cockpit's page (equal to :attr:`LeaderDevice.needs_cockpit`).
    """

    simulated: bool = False
    force_output: bool = True
    needs_cockpit: bool = False


#: The leader devices: the entry points of ``bipedtele.devices`` (the recipe: docs/architecture.md).
DEVICES: Parts[DevicePart] = Parts("device", PART_GROUPS["device"], DevicePart)


def device_names() -> list[str]:
    """Return the names of the devices offered, sorted (nothing is imported)."""
    return DEVICES.names()


def device_part(name: str) -> DevicePart:
    """Return the device registered as ``name`` (ValueError naming the allowed ones)."""
    return DEVICES.get(name)


def make_device(name: str, **kwargs: Any) -> LeaderDevice:
    """Build the device registered as ``name`` (``config=cfg`` and the device's keywords)."""
    device: LeaderDevice = DEVICES.build(name, **kwargs)
    return device
