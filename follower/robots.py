"""Importing this module registers the built-in follower robots (``make_robot`` does it).

Each robot registers itself with :func:`bipedtele.follower.robot.register_robot`; a robot
whose optional dependency is missing is simply not registered.
"""

import contextlib

from bipedtele.follower.sim.robot import SimNao  # noqa: F401  (the pybullet NAO, --robot sim)

with contextlib.suppress(ImportError):  # the real NAO through NAOqi (qi is needed only to connect)
    from bipedtele.follower.naoqi import NaoqiRobot  # noqa: F401
