"""A real NAO through NAOqi (libqi-python): the ``naoqi`` follower robot.

``NaoqiRobot`` implements :class:`bipedtele.follower.robot.FollowerRobot` over a ``qi``
session (``tcp://HOST:9559``, or ``tcps://HOST:9503`` with user/password on NAOqi >= 2.9);
``NaoqiConfig`` is its ``[naoqi]`` config section. Importing this package needs the ``qi``
package only when a robot connects.
"""

from bipedtele.follower.naoqi.config import NaoqiConfig
from bipedtele.follower.naoqi.gait import MoveConfig, move_config_for
from bipedtele.follower.naoqi.robot import NaoqiRobot

__all__ = ["MoveConfig", "NaoqiConfig", "NaoqiRobot", "move_config_for"]
