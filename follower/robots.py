"""The follower robots the programs offer, with their capabilities: no driver is imported here.

Every robot of ``--robot`` and ``[follower] robot`` is one :class:`RobotSpec` in
:data:`ROBOT_SPECS`: its name, the profile section that configures it, and what the
program may do with it (run faster than real time, put it back on its start pose, step
its time in chunks). The choices of the command line and the check of the profile are
built from this table; :func:`bipedtele.follower.robot.make_robot` loads the driver
class registered under the same name (see :mod:`bipedtele.follower.builtin_robots`).

To add a robot: implement :class:`~bipedtele.follower.robot.FollowerRobot` (decorate the
class with ``@register_robot("name")`` and import its module in
:mod:`bipedtele.follower.builtin_robots`), then add its spec here; the contract test
(tests/unit/test_contracts.py) runs the checker over every spec.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["ROBOT_SPECS", "RobotSpec", "robot_names", "robot_spec"]


def _no_step(cfg: Any) -> float | None:
    return None


@dataclass(frozen=True)
class RobotSpec:
    """What the program knows about one robot before loading its driver.

    Attributes
    ----------
    name : str
        ``--robot`` value.
    section : str
        The profile section that configures it.
    simulated : bool
        Its time passes only in ``advance()``: it may run faster than real time
        (``--realtime off``) and be put back on its start pose (``--reset-on-leader``).
    step_s : callable
        ``step_s(cfg) -> float | None``: its time advances in steps of this [s] (a
        simulator's physics step); the real-time loop advances it one step at a time so
        a fresh command reaches the next step. None: its time passes by itself.
    doc : str
        One line for the help.
    """

    name: str
    section: str
    simulated: bool
    doc: str
    step_s: Callable[[Any], float | None] = _no_step


ROBOT_SPECS: dict[str, RobotSpec] = {
    "sim": RobotSpec(
        "sim",
        "sim",
        simulated=True,
        doc="the pybullet NAO",
        step_s=lambda cfg: 1.0 / float(cfg.section("sim").physics_hz),
    ),
    "naoqi": RobotSpec("naoqi", "naoqi", simulated=False, doc="a real NAO through NAOqi"),
}


def robot_names() -> list[str]:
    """Return the names of the robots offered, sorted."""
    return sorted(ROBOT_SPECS)


def robot_spec(name: str) -> RobotSpec:
    """Return the spec of ``name``.

    Raises
    ------
    ValueError
        No such robot; the message lists the allowed ones.
    """
    try:
        return ROBOT_SPECS[name]
    except KeyError:
        raise ValueError(f"robot {name!r}: allowed: {', '.join(robot_names())}") from None
