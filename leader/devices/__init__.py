"""Leader devices: importing this package registers the built-in device drivers.

After the import ``bipedtele.leader.device.make_device("sim-falcon")`` works. What the
program knows about a device before loading its driver (name, settings section,
capability) is in :mod:`bipedtele.leader.device_specs`.

Hardware drivers (``falcon``, ``joystick``) live in their own modules here and register
themselves the same way; they must import cleanly without their hardware or libraries
(raise :class:`bipedtele.leader.device.DeviceError` from ``connect()`` instead).
"""

import contextlib

from bipedtele.leader.devices.sim_falcon import SimFalcon, SimFalconParams

__all__ = ["SimFalcon", "SimFalconParams"]

# Hardware drivers register themselves on import (they import without their libraries;
# a missing library is reported by connect()).
with contextlib.suppress(ImportError):
    from bipedtele.leader.devices import joystick as _joystick  # noqa: F401
with contextlib.suppress(ImportError):
    from bipedtele.leader.devices import falcon as _falcon  # noqa: F401
