"""Leader devices, one module each: its settings section, its driver and its :data:`PART`.

Each module's ``PART`` (a :class:`bipedtele.leader.device.DevicePart`) is its entry point
in ``bipedtele.devices``. Hardware drivers import cleanly without their hardware or
libraries: a missing one is reported by ``connect()`` as a
:class:`bipedtele.leader.device.DeviceError`.
"""
