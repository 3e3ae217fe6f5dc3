"""Contract checker for :class:`~bipedtele.leader.device.LeaderDevice` implementations.

``check_device(factory)`` exercises a *fresh* device the way the leader loop uses it and
raises :class:`DeviceContractError` naming the first broken rule (like Gymnasium's
``check_env``). Hardware drivers run it in their tests against the real device or a
faithful fake of its I/O layer.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from bipedtele.leader.device import DeviceNotConnectedError, HandleState, LeaderDevice

__all__ = ["DeviceContractError", "check_device"]


class DeviceContractError(AssertionError):
    """A device broke the LeaderDevice contract; the message says which rule."""


def _expect(cond: bool, rule: str) -> None:
    if not cond:
        raise DeviceContractError(rule)


def _check_state(dev: LeaderDevice, hs: object, where: str) -> HandleState:
    _expect(isinstance(hs, HandleState), f"{where}: read() must return a HandleState")
    assert isinstance(hs, HandleState)
    x = np.asarray(hs.x_m, dtype=float)
    dx = np.asarray(hs.dx_m, dtype=float)
    _expect(x.shape == (2,) and dx.shape == (2,), f"{where}: x_m and dx_m must have shape (2,)")
    _expect(bool(np.all(np.isfinite(x)) and np.all(np.isfinite(dx))), f"{where}: read() values must be finite")
    _expect(math.isfinite(hs.t), f"{where}: read().t must be finite")
    w = dev.limits.workspace_m
    _expect(bool(np.all(np.abs(x) <= w + 1e-9)), f"{where}: position {x} outside the workspace +-{w} m")
    _expect(all(isinstance(b, bool) for b in hs.buttons), f"{where}: buttons must be bools")
    return hs


def check_device(factory: Callable[[], LeaderDevice], *, steps: int = 200) -> None:
    """Check the LeaderDevice contract on devices made by ``factory``.

    Rules checked: calls before ``connect()`` raise :class:`DeviceNotConnectedError`;
    ``connect``/``disconnect`` are idempotent; the context manager connects and
    disconnects; ``apply_force`` clamps to ``force_max_n`` and maps NaN/inf to 0 and
    returns the applied force; ``read`` gives finite values inside the workspace, also
    under the largest forces for ``steps`` servo periods; ``advance`` accepts 0 and one
    servo period; calls after ``disconnect()`` raise again.

    Raises
    ------
    DeviceContractError
        The first rule broken.
    """
    dev = factory()
    _expect(isinstance(dev, LeaderDevice), "factory must return a LeaderDevice")
    lim = dev.limits
    _expect(lim.workspace_m > 0 and lim.force_max_n > 0 and lim.servo_rate_hz > 0, "limits must be positive")
    _expect(not dev.is_connected, "a new device must not be connected")
    for name, call in (
        ("read()", dev.read),
        ("apply_force()", lambda: dev.apply_force(np.zeros(2))),
        ("advance()", lambda: dev.advance(0.001)),
    ):
        try:
            call()
        except DeviceNotConnectedError:
            pass
        else:
            raise DeviceContractError(f"{name} before connect() must raise DeviceNotConnectedError")

    dev.connect()
    dev.connect()  # idempotent
    _expect(dev.is_connected, "is_connected must be true after connect()")
    _check_state(dev, dev.read(), "after connect")
    fmax = lim.force_max_n
    cases = [
        (np.array([0.0, 0.0]), np.array([0.0, 0.0])),
        (np.array([0.5 * fmax, -0.5 * fmax]), np.array([0.5 * fmax, -0.5 * fmax])),
        (np.array([10 * fmax, -10 * fmax]), np.array([fmax, -fmax])),
        (np.array([math.nan, math.inf]), np.array([0.0, 0.0])),
        (np.array([-math.inf, 2 * fmax]), np.array([0.0, fmax])),
    ]
    for asked, want in cases:
        got = np.asarray(dev.apply_force(asked), dtype=float)
        _expect(got.shape == (2,), "apply_force() must return the applied force, shape (2,)")
        _expect(
            bool(np.allclose(got, want)),
            f"apply_force({asked.tolist()}) applied {got.tolist()}, expected {want.tolist()} (clamp, non-finite -> 0)",
        )
    dev.apply_force(np.zeros(2))
    dev.advance(0.0)
    period = 1.0 / lim.servo_rate_hz
    for sign in (1.0, -1.0):
        for _ in range(steps):
            dev.apply_force(np.array([sign * fmax, -sign * fmax]))
            dev.advance(period)
            _check_state(dev, dev.read(), "under full force")
    dev.apply_force(np.zeros(2))

    dev.disconnect()
    dev.disconnect()  # idempotent
    _expect(not dev.is_connected, "is_connected must be false after disconnect()")
    try:
        dev.read()
    except DeviceNotConnectedError:
        pass
    else:
        raise DeviceContractError("read() after disconnect() must raise DeviceNotConnectedError")

    dev2 = factory()
    with dev2 as entered:
        _expect(entered is dev2, "__enter__ must return the device")
        _expect(dev2.is_connected, "entering a with block must connect")
        _check_state(dev2, dev2.read(), "in a with block")
    _expect(not dev2.is_connected, "leaving a with block must disconnect")
