"""``TorqueNao``: the pybullet NAO driven by joint torques from the paper's joint law (``--robot sim-torque``).

The body, the gait, the world and every measurement are :class:`~.robot.SimNao`'s; only the
actuation differs. pybullet's joint motors are off (zero force, no joint or link damping);
every physics step (``[torque] physics_hz``, 1 kHz by default) :class:`~.flcontrol.FeedbackLinearising`
computes the joint torques of (15) on a rigid-body model whose masses, inertias and torso
centre of mass are off by up to ``[torque] model_error`` (:func:`~.rigidbody.perturbed_geometry`),
with the disturbance observer's ``W_hat``, and the motors' torque-speed envelope cuts them
(:class:`~.flcontrol.MotorLimits`). Nothing holds the robot up but those torques and the
floor: it can fall.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any, ClassVar

import numpy as np
import pybullet as pb
from bipedtele.config.profile import Config, resolve_section
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.flcontrol import FeedbackLinearising, FlInput, FlOutput, FlState, MotorLimits
from bipedtele.follower.sim.gait import AROLL, ROLL, YAW
from bipedtele.follower.sim.rigidbody import RigidBodyModel, perturbed_geometry, state_from_pybullet
from bipedtele.follower.sim.robot import SimNao
from bipedtele.follower.sim.torque_config import TorqueConfig
from bipedtele.follower.sim.world import WorldConfig

__all__ = ["TorqueNao", "motor_limits"]

LOG = logging.getLogger(__name__)


def motor_limits(cfg: TorqueConfig) -> MotorLimits:
    """Return the 12 leg joints' torque-speed envelope from ``[torque]``."""
    pitch_w, roll_w = cfg.no_load_rad_s()
    stall = np.full(6, cfg.pitch_stall_nm)
    speed = np.full(6, pitch_w)
    for j in (YAW, ROLL, AROLL):
        stall[j], speed[j] = cfg.roll_stall_nm, roll_w
    return MotorLimits(np.tile(stall, 2), np.tile(speed, 2))


class TorqueNao(SimNao):
    """The simulated NAO on joint torques (``--robot sim-torque``).

    Parameters
    ----------
    config : Config, optional
        A whole profile: its ``[sim]``, ``[world]`` and ``[torque]`` sections.
    world : WorldConfig, optional
        Obstacles and scene camera (overrides the profile's ``[world]``).
    torque : TorqueConfig, optional
        Overrides the profile's ``[torque]``.
    **overrides
        Fields of :class:`SimConfig` to change.
    """

    name: ClassVar[str] = "sim-torque"

    def __init__(
        self,
        config: SimConfig | Config | None = None,
        world: WorldConfig | None = None,
        torque: TorqueConfig | None = None,
        **overrides: Any,
    ) -> None:
        super().__init__(config, world, **overrides)
        self.torque = torque or resolve_section(config if isinstance(config, Config) else None, TorqueConfig, "torque")
        self._dt = self.torque.dt_s
        pitch, roll = self.torque.reflected_inertia_kgm2()
        self.geom = dataclasses.replace(self.geom, rotor_pitch_kgm2=pitch, rotor_roll_kgm2=roll)
        self.control_model = RigidBodyModel(perturbed_geometry(self.geom, self.torque.model_error))
        self.law = FeedbackLinearising(
            self.control_model, self.torque.dob_rate_s, motor_limits(self.torque), self.torque.mass_rate_s
        )
        self._fl = FlState()
        self._com = np.array([0.0, 0.0, self.geom.torso_com_z])
        self.last_output: FlOutput | None = None
        self.saturated_steps = 0

    def _build_world(self) -> None:
        super()._build_world()
        c, rob = self._client, self._robot
        pb.changeDynamics(rob, -1, linearDamping=0.0, angularDamping=0.0, physicsClientId=c)
        for j in range(pb.getNumJoints(rob, physicsClientId=c)):
            pb.changeDynamics(rob, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0, physicsClientId=c)
        pb.setJointMotorControlArray(rob, self._joints, pb.VELOCITY_CONTROL, forces=[0.0] * 12, physicsClientId=c)
        self._fl = FlState()

    def _reset_state(self) -> None:
        super()._reset_state()
        self._fl = FlState()

    def _actuate(self, q: np.ndarray, qd: np.ndarray, qref: np.ndarray, qdref: np.ndarray) -> None:
        c, rob = self._client, self._robot
        pos, orn = pb.getBasePositionAndOrientation(rob, physicsClientId=c)
        lin, ang = pb.getBaseVelocity(rob, physicsClientId=c)
        qf, vf = state_from_pybullet(
            np.asarray(pos), np.asarray(orn), np.asarray(lin), np.asarray(ang), q, qd, self._com
        )
        inp = FlInput(
            qf,
            vf,
            qref,
            qdref,
            self.gait.acceleration(),
            self.gait.stance,
            self.gait.support,
            self._eps,
            self.torque.body_eps_s,
        )
        self._fl, u, out = self.law.step(self._fl, inp, self._dt)
        self.last_output = out
        self.saturated_steps += out.saturated
        pb.setJointMotorControlArray(rob, self._joints, pb.TORQUE_CONTROL, forces=u.tolist(), physicsClientId=c)
