"""The robot's side.

The pybullet NAO and the NAOqi bridge behind one contract (:mod:`bipedtele.follower.robot`), the gait, sonar and fictitious force, cameras, and the
follower loop with the paper's follower controllers.
"""
