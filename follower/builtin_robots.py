"""Importing this module registers the built-in robot classes (``make_robot`` does it).

Each robot class registers itself with :func:`bipedtele.follower.robot.register_robot`; a
robot whose optional dependency is missing is simply not registered. What the program
needs to know about a robot before loading its driver is in :mod:`bipedtele.follower.robots`.
"""

import contextlib

from bipedtele.follower.sim.robot import SimNao  # noqa: F401  (the pybullet NAO, --robot sim)

with contextlib.suppress(ImportError):  # the real NAO through NAOqi (qi is needed only to connect)
    from bipedtele.follower.naoqi import NaoqiRobot  # noqa: F401
