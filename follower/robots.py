"""Importing this module registers the built-in follower robots (``make_robot`` does it).

Each robot registers itself with :func:`bipedtele.follower.robot.register_robot`; a robot
whose optional dependency is missing is simply not registered.
"""

try:  # the real NAO through NAOqi (needs nothing at import; qi only when connecting)
    from bipedtele.follower.naoqi import NaoqiRobot  # noqa: F401
except ImportError:  # pragma: no cover
    pass
