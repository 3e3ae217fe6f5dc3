"""The leader's browser cockpit: live video, plots, status and a virtual joystick.

See :class:`CockpitServer` (in a thread of this process), :class:`CockpitProcess` (the
same server in a child process, what the leader runs) and ``docs/cockpit.md``.
"""

from bipedtele.leader.cockpit.process import CockpitProcess
from bipedtele.leader.cockpit.server import SAMPLE_KEYS, CockpitServer

__all__ = ["SAMPLE_KEYS", "CockpitProcess", "CockpitServer"]
