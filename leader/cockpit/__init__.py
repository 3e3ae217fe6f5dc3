"""The leader's browser cockpit: live video, plots, status and a virtual joystick.

See :class:`CockpitServer` and ``docs/cockpit.md``.
"""

from bipedtele.leader.cockpit.server import SAMPLE_KEYS, CockpitServer

__all__ = ["SAMPLE_KEYS", "CockpitServer"]
