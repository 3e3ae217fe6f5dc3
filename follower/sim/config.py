"""The pybullet NAO as a part (``--robot sim``) and its ``[sim]`` section: physics, servo, sensors and gait.

The driver (:class:`bipedtele.follower.sim.robot.SimNao`) imports pybullet: :data:`PART`
loads it only when it builds one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from bipedtele.config.profile import param
from bipedtele.follower.robot import RobotPart
from bipedtele.parts import lazy

__all__ = ["PART", "SONAR_RANGE_M", "SimConfig"]

#: Reliable sonar range [m] per NAO version (docs/hardware.md): (min, max).
SONAR_RANGE_M = {"V3": (0.25, 2.55), "V4": (0.25, 2.55), "V5": (0.20, 0.80), "V6": (0.20, 0.80)}


@dataclass(frozen=True)
class SimConfig:
    """Simulated NAO settings (see docs/follower.md). Pacing is the follower loop's job."""

    physics_hz: float = param(240.0, lo=100.0, hi=2000.0, unit="Hz", doc="physics step rate")
    solver_iterations: int = param(100, lo=5, hi=200, doc="pybullet constraint-solver iterations per step")
    gravity_m_s2: float = param(9.81, lo=0.0, hi=30.0, unit="m/s^2", doc="gravity")
    max_torque_nm: float = param(10.0, lo=0.1, hi=100.0, unit="N m", doc="joint torque limit of the leg servos")
    foot_friction: float = param(1.0, lo=0.05, hi=5.0, doc="sole friction coefficient")
    nao_version: Literal["V3", "V4", "V5", "V6"] = param("V6", doc="NAO version: sets the sonar range")
    sonar_yaw_deg: float = param(22.0, lo=0.0, hi=60.0, unit="deg", doc="yaw of each chest sonar's axis")
    sonar_cone_deg: float = param(60.0, lo=1.0, hi=120.0, unit="deg", doc="sonar cone opening")
    fall_tilt_deg: float = param(45.0, lo=5.0, hi=90.0, unit="deg", doc="torso tilt that counts as a fall")
    fall_height_m: float = param(0.18, lo=0.0, hi=0.3, unit="m", doc="torso origin below this height counts as a fall")
    camera_width: int = param(320, lo=16, hi=1920, doc="camera image width [px]")
    camera_height: int = param(240, lo=12, hi=1080, doc="camera image height [px]")
    leg_height_m: float = param(0.185, lo=0.15, hi=0.20, unit="m", doc="hip-to-ankle height while walking")
    step_height_m: float = param(0.02, lo=0.0, hi=0.05, unit="m", doc="swing-foot clearance (NAO StepHeight)")
    double_support: float = param(0.3, lo=0.05, hi=0.6, doc="phi: fraction of the cycle with both feet down")
    max_step_m: float = param(0.04, lo=0.005, hi=0.08, unit="m", doc="largest step length (NAO MaxStepX)")
    max_turn_deg_s: float = param(25.0, lo=1.0, hi=60.0, unit="deg/s", doc="largest turn rate accepted")
    cycle_min_s: float = param(0.8, lo=0.3, hi=5.0, unit="s", doc="shortest walking cycle T accepted")
    cycle_max_s: float = param(2.0, lo=0.3, hi=5.0, unit="s", doc="longest walking cycle T accepted")

    def __post_init__(self) -> None:
        if not self.cycle_min_s < self.cycle_max_s:
            raise ValueError("cycle_min_s, cycle_max_s: allowed: cycle_min_s < cycle_max_s")


#: ``--robot sim`` (entry point ``bipedtele.robots``).
PART = RobotPart(
    name="sim",
    doc="the pybullet NAO",
    build=lazy("bipedtele.follower.sim.robot:SimNao"),
    section="sim",
    config=SimConfig,
    simulated=True,
    step_s=lambda cfg: 1.0 / float(cfg.get(SimConfig).physics_hz),
)
