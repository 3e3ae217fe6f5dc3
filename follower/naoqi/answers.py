"""Checks on what NAOqi answers.

Every value the bridge uses is validated here, so a wrong type or shape from the robot becomes a clear :class:`RobotError`, never a crash
deeper in the loop.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from bipedtele.follower.robot import RobotError

__all__ = ["as_bool", "as_floats", "decode_image"]


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def as_floats(value: Any, n: int, what: str) -> tuple[float, ...]:
    """``value`` as ``n`` finite floats.

    Raises
    ------
    RobotError
        ``value`` is not a list of ``n`` finite numbers.
    """
    if isinstance(value, str | bytes | bytearray) or not isinstance(value, Sequence) or len(value) != n:
        raise RobotError(f"NAOqi answered {what} = {_short(value)}: expected a list of {n} numbers")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise RobotError(f"NAOqi answered {what} = {_short(value)}: expected a list of {n} finite numbers")
        out.append(float(v))
    return tuple(out)


def as_bool(value: Any, what: str) -> bool:
    """``value`` as a bool (NAOqi answers bools, sometimes 0/1)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    raise RobotError(f"NAOqi answered {what} = {_short(value)}: expected true or false")


def decode_image(value: Any) -> np.ndarray:
    """Return an ALVideoDevice ``getImageRemote`` answer as an H x W x 3 uint8 RGB image.

    The answer is ``[width, height, layers, colorspace, ts_s, ts_us, data, camera, ...]``
    with ``data`` the ``width * height * layers`` raw bytes (kRGBColorSpace: 3 layers).

    Raises
    ------
    RobotError
        No image (``None``: the camera is busy or unsubscribed) or a malformed one.
    """
    if value is None:
        raise RobotError("ALVideoDevice.getImageRemote answered no image (camera busy or not subscribed)")
    if isinstance(value, str | bytes) or not isinstance(value, Sequence) or len(value) < 7:
        raise RobotError(
            f"ALVideoDevice.getImageRemote answered {_short(value)}: expected [w, h, layers, colorspace, s, us, data, ...]"
        )
    w, h, layers = value[0], value[1], value[2]
    if not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in (w, h, layers)):
        raise RobotError(
            f"ALVideoDevice image header {_short(list(value[:6]))}: expected positive integer width, height, layers"
        )
    if layers != 3:
        raise RobotError(f"ALVideoDevice image has {layers} layers: expected 3 (kRGBColorSpace = 11)")
    data = value[6]
    if isinstance(data, memoryview):
        data = data.tobytes()
    if not isinstance(data, bytes | bytearray):
        raise RobotError(f"ALVideoDevice image data is {type(data).__name__}: expected raw bytes")
    if len(data) != w * h * layers:
        raise RobotError(
            f"ALVideoDevice image data has {len(data)} bytes: expected {w}x{h}x{layers} = {w * h * layers}"
        )
    return np.frombuffer(bytes(data), dtype=np.uint8).reshape(h, w, layers).copy()
