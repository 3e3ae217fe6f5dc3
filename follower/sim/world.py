"""The ``[world]`` section: the simulated lab (obstacles and the fixed scene camera).

Example (the paper's task course, Sec. 5: obstacles to evade left and right alternately)::

    [world]
    scene_camera_eye = [-0.8, -1.6, 1.3]
    scene_camera_target = [1.2, 0.0, 0.2]

    [[world.obstacles]]
    shape = "box"
    position = [1.0, 0.15, 0.25]
    size = [0.2, 0.3, 0.5]

    [[world.obstacles]]
    shape = "cylinder"
    position = [2.0, -0.15, 0.25]
    size = [0.12, 0.5]          # radius, height

    [[world.obstacles]]
    shape = "box"
    position = [3.0, 0.15, 0.25]
    size = [0.2, 0.3, 0.5]

The robot starts at the origin facing +x. :data:`TASK_COURSE` holds these obstacles.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from bipedtele.config.profile import param

__all__ = ["TASK_COURSE", "Obstacle", "WorldConfig"]


@dataclass(frozen=True)
class Obstacle:
    """A fixed obstacle.

    ``position`` is the centre [m] in the world frame (x forward of the robot's start,
    z up). ``size`` is ``[x, y, z]`` edge lengths [m] for a box, ``[radius, height]`` [m]
    for an upright cylinder.
    """

    shape: Literal["box", "cylinder"] = param("box", doc="box or cylinder (upright)")
    position: list[float] = param(
        default_factory=lambda: [1.0, 0.0, 0.25], lo=-100.0, hi=100.0, unit="m", doc="centre x, y, z"
    )
    size: list[float] = param(
        default_factory=lambda: [0.2, 0.3, 0.5],
        lo=0.001,
        hi=50.0,
        unit="m",
        doc="box: edge lengths x, y, z; cylinder: radius, height",
    )

    def __post_init__(self) -> None:
        if len(self.position) != 3:
            raise ValueError(f"position = {self.position}: allowed: 3 numbers x, y, z")
        want = 3 if self.shape == "box" else 2
        if len(self.size) != want:
            allowed = "3 numbers x, y, z" if want == 3 else "2 numbers radius, height"
            raise ValueError(f"size = {self.size}: allowed for a {self.shape}: {allowed}")


@dataclass(frozen=True)
class WorldConfig:
    """The simulated world: obstacles and the fixed lab camera."""

    obstacles: list[Obstacle] = param(default_factory=list, doc="fixed obstacles ([[world.obstacles]] tables)")
    scene_camera_eye: list[float] = param(
        default_factory=lambda: [-0.8, -1.6, 1.3], lo=-100.0, hi=100.0, unit="m", doc="scene camera position"
    )
    scene_camera_target: list[float] = param(
        default_factory=lambda: [1.2, 0.0, 0.2], lo=-100.0, hi=100.0, unit="m", doc="point the scene camera looks at"
    )
    scene_camera_fov_deg: float = param(60.0, lo=10.0, hi=120.0, unit="deg", doc="scene camera vertical field of view")
    floor_friction: float = param(1.0, lo=0.05, hi=5.0, doc="floor friction coefficient")

    def __post_init__(self) -> None:
        for name in ("scene_camera_eye", "scene_camera_target"):
            if len(getattr(self, name)) != 3:
                raise ValueError(f"{name}: allowed: 3 numbers x, y, z")


#: The paper's task course (Sec. 5): three obstacles to pass alternately left and right.
TASK_COURSE: tuple[Obstacle, ...] = (
    Obstacle("box", [1.0, 0.15, 0.25], [0.2, 0.3, 0.5]),
    Obstacle("cylinder", [2.0, -0.15, 0.25], [0.12, 0.5]),
    Obstacle("box", [3.0, 0.15, 0.25], [0.2, 0.3, 0.5]),
)
