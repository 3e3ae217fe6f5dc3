"""The follower-robot contract: one abstract class every robot implements.

A :class:`FollowerRobot` is what the follower loop drives: the pybullet NAO
(``bipedtele.follower.sim``) and a real NAO through NAOqi (``bipedtele.follower.naoqi``).
The loop owns the paper's controllers; the robot realises walk commands and reports what
it measures. Units are SI here (m/s, rad/s); the loop converts to the paper's cm/s, deg/s.

Contract (checked by :func:`bipedtele.follower.check.check_robot`):

- ``connect()`` then ``observe()``/``send_walk()``/``stop()``/``advance()``; calling them
  before ``connect()`` raises :class:`RobotNotConnectedError`.
- ``send_walk(cmd)`` clamps to :attr:`limits` and returns what was actually sent; a robot
  that must not walk now raises :class:`WalkRefusedError` after stopping itself.
- ``stop()`` decelerates and stands; it is safe to call at any time, repeatedly.
- ``advance(dt)`` lets robot time move on by ``dt`` seconds: a simulator steps its
  physics, a real robot returns at once (its time passes by itself; the loop paces).
- ``disconnect()`` stops the robot first, is idempotent, and is also called on leaving a
  ``with`` block. Cleanup never lives in ``__del__``.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Literal, TypeVar

import numpy as np
from bipedtele.parts import PART_GROUPS, Part, Parts

__all__ = [
    "ROBOTS",
    "FollowerRobot",
    "Footfall",
    "RobotError",
    "RobotNotConnectedError",
    "RobotObservation",
    "RobotPart",
    "WalkCommand",
    "WalkLimits",
    "WalkRefusedError",
    "make_robot",
    "robot_names",
    "robot_part",
]

Camera = Literal["head", "scene"]


class RobotError(RuntimeError):
    """The robot failed (lost connection, bad answer). The message says what to do."""


class RobotNotConnectedError(RobotError):
    """A method was called before ``connect()`` or after ``disconnect()``."""


class WalkRefusedError(RobotError):
    """``send_walk`` refused on purpose (e.g. no watchdog guards a real NAO).

    The robot stopped itself and stands; the message says why and what to do. Not a fault.
    """


@dataclass(frozen=True)
class WalkLimits:
    """What the robot can be asked to do. NAO defaults (docs/hardware.md).

    Attributes
    ----------
    max_forward_m_s : float
        Largest forward speed [m/s] (negative speeds: walking backwards, same bound).
    max_turn_rad_s : float
        Largest turn rate [rad/s].
    cycle_s : (float, float)
        Allowed walking cycle time T [s].
    eps_s : (float, float)
        Allowed joint-servo gain eps [s] (eq. 21).
    """

    max_forward_m_s: float = 0.10
    max_turn_rad_s: float = math.radians(20.0)
    cycle_s: tuple[float, float] = (0.5, 5.0)
    eps_s: tuple[float, float] = (0.02, 1.0)


@dataclass(frozen=True)
class WalkCommand:
    """A walk request.

    Attributes
    ----------
    forward_m_s : float
        Forward speed of the hip [m/s].
    turn_rad_s : float
        Turn rate [rad/s], positive to the left (counter-clockwise seen from above).
    cycle_s : float
        Walking cycle time T [s] (two steps).
    eps_s : float
        Joint-servo gain eps [s]: the joint servo's time constant (eq. 21).
    """

    forward_m_s: float = 0.0
    turn_rad_s: float = 0.0
    cycle_s: float = 1.0
    eps_s: float = 0.1

    def clamped(self, limits: WalkLimits) -> WalkCommand:
        """Return this command within ``limits`` (non-finite values become 0 / the nearest bound)."""

        def clip(v: float, lo: float, hi: float, fallback: float) -> float:
            return float(np.clip(v, lo, hi)) if math.isfinite(v) else fallback

        f, t = limits.max_forward_m_s, limits.max_turn_rad_s
        return replace(
            self,
            forward_m_s=clip(self.forward_m_s, -f, f, 0.0),
            turn_rad_s=clip(self.turn_rad_s, -t, t, 0.0),
            cycle_s=clip(self.cycle_s, *limits.cycle_s, limits.cycle_s[1]),
            eps_s=clip(self.eps_s, *limits.eps_s, limits.eps_s[0]),
        )


@dataclass(frozen=True)
class Footfall:
    """The robot's latest touchdown: what its walk odometry is read at.

    A walk engine reports its speed per step (odometry): the displacement and yaw change
    between consecutive footfalls over the step time. :meth:`FollowerRobot.footfall` gives
    the latest; the follower loop records one ``footfall`` event per new touchdown; the
    report computes the odometry speed error from them (docs/recording.md).

    Attributes
    ----------
    n : int
        Touchdowns so far (increases by one per step; a new value is a new footfall).
    t : float
        Robot time of the touchdown [s] (the clock of :attr:`RobotObservation.t`).
    pose : (float, float, float)
        x [m], y [m], yaw [rad] at the touchdown, in the frame of :attr:`RobotObservation.pose`.
    step_s : float
        Duration of the step that ended with this touchdown [s] (T/2).
    """

    n: int
    t: float
    pose: tuple[float, float, float]
    step_s: float


@dataclass(frozen=True)
class RobotObservation:
    """What the robot measures, at robot time ``t``.

    Attributes
    ----------
    t : float
        Robot time [s] (simulation time for the simulator, wall time for a real robot).
    v_hip_m_s : float
        Forward hip speed [m/s] (eq. 8 on the simulator; odometry on a real NAO).
    turn_rate_rad_s : float
        Turn rate [rad/s].
    pose : (float, float, float)
        x [m], y [m], yaw [rad] (world frame on the simulator, odometry on a real NAO).
    sonar_m : (float, float)
        Left and right sonar ranges [m]; the sensor maximum when nothing is seen.
    tilt_rad : float
        Torso tilt from vertical [rad].
    fallen : bool
        The robot is down (tilt beyond the fall threshold, or the robot says so).
    walking : bool
        The robot is stepping (false once it stands still).
    joint_error_rad : float
        RMS joint tracking error of the gait joints [rad] (0 where not measurable).
    in_contact : bool
        The robot touches an obstacle (simulator only; false otherwise).
    """

    t: float
    v_hip_m_s: float
    turn_rate_rad_s: float
    pose: tuple[float, float, float]
    sonar_m: tuple[float, float]
    tilt_rad: float
    fallen: bool
    walking: bool
    joint_error_rad: float = 0.0
    in_contact: bool = False


class FollowerRobot(abc.ABC):
    """Base class of every follower robot. See the module docstring for the contract."""

    name: ClassVar[str] = ""
    limits: WalkLimits = WalkLimits()

    @property
    @abc.abstractmethod
    def is_connected(self) -> bool:
        """True between ``connect()`` and ``disconnect()``."""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the robot (load the simulation / reach NAOqi) and stand it up."""

    @abc.abstractmethod
    def disconnect(self) -> None:
        """Stop the robot, then release it. Idempotent."""

    @abc.abstractmethod
    def observe(self) -> RobotObservation:
        """Measure the robot now."""

    @abc.abstractmethod
    def send_walk(self, cmd: WalkCommand) -> WalkCommand:
        """Ask the robot to walk; return the command actually sent (clamped)."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Decelerate and stand. Safe at any time."""

    @abc.abstractmethod
    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds of robot time pass (the simulator steps; real robots return)."""

    def footfall(self) -> Footfall | None:
        """Return the latest touchdown (None: none yet, or the robot reports none).

        Robots that can tell when a foot lands (or sample their odometry once per step)
        override this; the loop calls it right after ``observe()``.
        """
        return None

    def capture(self, camera: Camera = "head") -> np.ndarray | None:
        """Return an RGB image (H x W x 3, uint8) from ``camera``, or None if it has no such camera."""
        return None

    def __enter__(self: R) -> R:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


R = TypeVar("R", bound=FollowerRobot)


def _no_step(cfg: Any) -> float | None:
    return None


@dataclass(frozen=True)
class RobotPart(Part):
    """A robot the follower offers (``--robot``, ``[follower] robot``).

    One entry point of ``bipedtele.robots``. ``build(config=cfg)`` returns a
    :class:`FollowerRobot` whose ``name`` is the part's.

    Attributes
    ----------
    simulated : bool
        Its time passes only in ``advance()``: it may run faster than real time
        (``--realtime off``) and be put back on its start pose (``--reset-on-leader``).
    step_s : callable
        ``step_s(cfg) -> float | None``: its time advances in steps of this [s] (a
        simulator's physics step); the real-time loop advances it one step at a time so a
        fresh command reaches the next step. None: its time passes by itself.
    """

    simulated: bool = False
    step_s: Callable[[Any], float | None] = _no_step


#: The robots: the entry points of ``bipedtele.robots`` (the recipe: docs/architecture.md).
ROBOTS: Parts[RobotPart] = Parts("robot", PART_GROUPS["robot"], RobotPart)


def robot_names() -> list[str]:
    """Return the names of the robots offered, sorted (nothing is imported)."""
    return ROBOTS.names()


def robot_part(name: str) -> RobotPart:
    """Return the robot registered as ``name`` (ValueError naming the allowed ones)."""
    return ROBOTS.get(name)


def make_robot(name: str, **kwargs: Any) -> FollowerRobot:
    """Build the robot registered as ``name`` (``config=cfg``)."""
    robot: FollowerRobot = ROBOTS.build(name, **kwargs)
    return robot
