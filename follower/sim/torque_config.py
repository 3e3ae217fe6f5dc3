"""The torque-driven pybullet NAO as a part (``--robot sim-torque``) and its ``[torque]`` section.

The robot is the ``[sim]`` NAO (same body, gait, sensors and world) with pybullet's motors
off: every physics step the paper's joint law (15) computes the joint torques on a
deliberately wrong rigid-body model, with a disturbance observer for ``W_hat``
(:mod:`bipedtele.follower.sim.flcontrol`). See docs/method.md, "The torque walker".

Motor limits: NAO's leg joints are driven by Maxon RE-Max 24 motors (stall torque 59.5 mN m,
no-load speed 8,000 rpm) through reduction ratios of 130.85 (hip, knee and ankle pitch) and
201.3 (hip yaw-pitch, hip roll, ankle roll): 7.78 N m and 366.83 deg/s (6.40 rad/s), and
11.97 N m and 238.45 deg/s (4.16 rad/s) at the joint, before the gears' efficiency
(Aldebaran's NAO H25 documentation, "Motors", V3.2-V4.0; the same motors drive the V5 and V6
legs). The defaults below are those figures. The rotor's inertia, reflected through the
gears (``rotor x ratio^2``: 0.0068 and 0.0162 kg m^2 with 4 g cm^2), dominates a NAO leg
joint's own inertia; 4 g cm^2 is the order of magnitude of a 24 mm ironless-rotor DC motor
(with its first gear stage), an estimate, not a measured figure of NAO's parts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bipedtele.config.profile import param
from bipedtele.follower.robot import RobotPart
from bipedtele.parts import lazy

__all__ = ["PART", "TorqueConfig"]


@dataclass(frozen=True)
class TorqueConfig:
    """Torque-driven NAO settings (``[torque]``; the body, gait and sensors are ``[sim]``'s)."""

    physics_hz: float = param(500.0, lo=500.0, hi=4000.0, unit="Hz", doc="physics and joint-law rate (>= 500 Hz)")
    body_eps_s: float = param(
        0.2, lo=0.01, hi=2.0, unit="s", doc="time constant of the stance leg's outputs (the torso over the stance foot)"
    )
    model_error: float = param(
        0.2,
        lo=0.0,
        hi=0.5,
        doc="the joint law's model: masses, inertias and torso centre of mass off by up to this fraction",
    )
    dob_rate_s: float = param(
        20.0, lo=0.0, hi=400.0, unit="1/s", doc="the disturbance observer's rate L for W_hat (0: W_hat = 0)"
    )
    mass_rate_s: float = param(
        5.0,
        lo=0.0,
        hi=100.0,
        unit="1/s",
        doc="gain of the torso-mass adaptation from W_hat in single support (0: the model's mass is kept)",
    )
    pitch_stall_nm: float = param(
        7.78, lo=0.1, hi=100.0, unit="N m", doc="stall torque of the hip, knee, ankle pitch joints"
    )
    pitch_no_load_deg_s: float = param(
        366.83, lo=10.0, hi=3000.0, unit="deg/s", doc="no-load speed of the hip, knee, ankle pitch joints"
    )
    roll_stall_nm: float = param(
        11.97, lo=0.1, hi=100.0, unit="N m", doc="stall torque of the hip yaw, hip roll, ankle roll joints"
    )
    roll_no_load_deg_s: float = param(
        238.45, lo=10.0, hi=3000.0, unit="deg/s", doc="no-load speed of the hip yaw, hip roll, ankle roll joints"
    )
    rotor_gcm2: float = param(
        4.0, lo=0.0, hi=100.0, unit="g cm^2", doc="each leg motor's rotor inertia (x ratio^2 at the joint)"
    )
    pitch_ratio: float = param(130.85, lo=1.0, hi=1000.0, doc="gear ratio of the hip, knee, ankle pitch joints")
    roll_ratio: float = param(201.3, lo=1.0, hi=1000.0, doc="gear ratio of the hip yaw, hip roll, ankle roll joints")

    @property
    def dt_s(self) -> float:
        """Physics step [s]."""
        return 1.0 / self.physics_hz

    def reflected_inertia_kgm2(self) -> tuple[float, float]:
        """Rotor inertia seen at the pitch and at the yaw/roll joints [kg m^2] (rotor x ratio^2)."""
        rotor = self.rotor_gcm2 * 1e-7
        return rotor * self.pitch_ratio**2, rotor * self.roll_ratio**2

    def no_load_rad_s(self) -> tuple[float, float]:
        """No-load speeds [rad/s] of the pitch and of the yaw/roll joints."""
        return math.radians(self.pitch_no_load_deg_s), math.radians(self.roll_no_load_deg_s)


#: ``--robot sim-torque`` (entry point ``bipedtele.robots``).
PART = RobotPart(
    name="sim-torque",
    doc="the pybullet NAO driven by joint torques from the paper's feedback linearisation (15)",
    build=lazy("bipedtele.follower.sim.torque_robot:TorqueNao"),
    section="torque",
    config=TorqueConfig,
    simulated=True,
    step_s=lambda cfg: 1.0 / float(cfg.get(TorqueConfig).physics_hz),
)
