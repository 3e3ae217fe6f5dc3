"""Leader devices. Importing this package registers the built-in devices, so that
``bipedtele.leader.device.make_device("sim-falcon")`` works.

Hardware drivers (``falcon``, ``joystick``) live in their own modules here and register
themselves the same way; they must import cleanly without their hardware or libraries
(raise :class:`bipedtele.leader.device.DeviceError` from ``connect()`` instead).
"""

from bipedtele.leader.devices.sim_falcon import SimFalcon, SimFalconParams

__all__ = ["SimFalcon", "SimFalconParams"]
