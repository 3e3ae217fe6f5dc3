"""``SimNao``: the pybullet NAO behind the :class:`FollowerRobot` contract (``--robot sim``).

Physics runs headless (``pybullet.DIRECT``) at ``[sim] physics_hz``; ``advance(dt)`` steps
it. Every physics step the gait (:mod:`.gait`) gives joint references ``q_ref, dq_ref`` and
a first-order joint servo with feed-forward (not the paper's second-order (21); the torque
walker, :mod:`.torque_robot`, runs (15) and (21)): each joint gets the velocity command
``dq_ref + (q_ref - q) / eps`` through pybullet's velocity motor (a stiff constraint
limited by ``max_torque_nm``), so a tracking error decays with time constant ``eps``
(bandwidth ``1/eps``). See docs/follower.md for why.

Measurements (``observe``):

- ``v_hip``: eq. (8) on the measured stance-leg ankle and knee pitch of every physics
  step, averaged over the time since the previous ``observe`` (the finite difference of
  ``p_hip`` over the control period). The stance leg switches at impact.
- turn rate: torso yaw change since the previous ``observe`` over the elapsed time.
- sonar: two cones on the chest by ray casts (:meth:`sonar`), fall: torso tilt/height.
- ``footfall()``: the torso pose at the physics step where the gait starts a new step after a
  walking step (the swing foot lands), its robot time, a touchdown counter and the length
  of the step that ended (:class:`~bipedtele.follower.robot.Footfall`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import tempfile
from typing import Any, ClassVar

import numpy as np
import pybullet as pb
from bipedtele.config.profile import Config, resolve_section
from bipedtele.follower.robot import (
    Camera,
    FollowerRobot,
    Footfall,
    RobotError,
    RobotNotConnectedError,
    RobotObservation,
    WalkCommand,
    WalkLimits,
)
from bipedtele.follower.sim.config import SONAR_RANGE_M, SimConfig
from bipedtele.follower.sim.gait import HIP, KNEE, YAW, Gait, GaitConfig, hip_speed
from bipedtele.follower.sim.model import LEG_JOINTS, NaoGeometry, nao_urdf
from bipedtele.follower.sim.world import WorldConfig

__all__ = ["HEAD_HFOV_DEG", "HEAD_VFOV_DEG", "SimNao"]

LOG = logging.getLogger(__name__)

HEAD_HFOV_DEG = 60.9
HEAD_VFOV_DEG = 47.6
_HEAD_CAM = (0.058, 0.0, 0.19)  # camera position in the torso frame [m]
_SONAR_XYZ = (0.056, 0.042, 0.05)  # left sonar in the torso frame [m] (right: y mirrored)
_SETTLE_S = 0.4


class SimNao(FollowerRobot):
    """The simulated NAO (``--robot sim``: its part is in :mod:`bipedtele.follower.sim.config`).

    Parameters
    ----------
    config : SimConfig or Config, optional
        The ``[sim]`` section (or a whole profile holding ``[sim]`` and ``[world]``).
    world : WorldConfig, optional
        Obstacles and scene camera (overrides the profile's ``[world]``).
    **overrides
        Fields of :class:`SimConfig` to change, e.g. ``physics_hz=480``.

    Raises
    ------
    ConfigError
        An override is not a field of :class:`SimConfig` or out of range.
    """

    name: ClassVar[str] = "sim"

    def __init__(
        self, config: SimConfig | Config | None = None, world: WorldConfig | None = None, **overrides: Any
    ) -> None:
        cfg = resolve_section(config, SimConfig, "sim", overrides)
        self.world = world or resolve_section(config if isinstance(config, Config) else None, WorldConfig, "world")
        self.config = cfg
        self.geom = NaoGeometry()
        self.gait = Gait(
            GaitConfig(
                leg_height_m=cfg.leg_height_m,
                step_height_m=cfg.step_height_m,
                double_support=cfg.double_support,
                max_step_m=cfg.max_step_m,
            ),
            self.geom,
        )
        self.limits = WalkLimits(
            max_forward_m_s=2.0 * cfg.max_step_m / cfg.cycle_min_s,
            max_turn_rad_s=math.radians(cfg.max_turn_deg_s),
            cycle_s=(cfg.cycle_min_s, cfg.cycle_max_s),
            eps_s=(0.02, 1.0),
        )
        self.sonar_range_m = SONAR_RANGE_M[cfg.nao_version]
        self._client: int | None = None
        self._dt = 1.0 / cfg.physics_hz
        self._eps = WalkCommand().eps_s
        self._touchdowns = 0  # never reset: a new footfall always has a new number
        self._reset_state()

    def _reset_state(self) -> None:
        self._t = 0.0
        self._steps = 0
        self._carry = 0.0
        self._q = np.zeros(12)
        self._qd = np.zeros(12)
        self._qref = np.zeros(12)
        self._vhip_sum = 0.0
        self._vhip_n = 0
        self._last_obs_t = 0.0
        self._last_yaw = 0.0
        self._yaw_unwrapped = 0.0
        self._history: list[tuple[float, float, float]] = []  # t, x, y for cycle speed
        self._v_hip_last = 0.0
        self._turn_last = 0.0
        self._gait_step: tuple[str, float, float, float] | None = None
        self._footfall: Footfall | None = None

    # ------------------------------------------------------------------ lifecycle

    @property
    def is_connected(self) -> bool:
        """True while a pybullet physics server is attached."""
        return self._client is not None

    def connect(self) -> None:
        """Start headless physics, build the world and let the robot settle on its feet."""
        if self._client is not None:
            return
        cfg = self.config
        client = pb.connect(pb.DIRECT)
        if client < 0:
            raise RobotError("pybullet: could not start a physics server (DIRECT)")
        self._client = client
        try:
            self._build_world()
        except Exception:
            pb.disconnect(physicsClientId=client)
            self._client = None
            raise
        self._reset_state()
        self.gait.reset(0.0)
        # let the robot settle on its feet before robot time starts
        self._run_physics(round(_SETTLE_S / self._dt))
        self._t, self._steps = 0.0, 0
        self.gait.reset(0.0)
        self._last_yaw = self._yaw_unwrapped = self._base()[2]
        LOG.info(
            "sim NAO ready (%s): %.0f Hz physics, %d obstacles, sonar %s",
            self.name,
            1.0 / self._dt,
            len(self.world.obstacles),
            cfg.nao_version,
        )

    def _build_world(self) -> None:
        cfg, c = self.config, self._client
        pb.setGravity(0, 0, -cfg.gravity_m_s2, physicsClientId=c)
        pb.setTimeStep(self._dt, physicsClientId=c)
        pb.setPhysicsEngineParameter(numSolverIterations=cfg.solver_iterations, physicsClientId=c)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        plane_vis = pb.createVisualShape(
            pb.GEOM_BOX,
            halfExtents=[15, 15, 0.001],
            visualFramePosition=[0, 0, -0.001],
            rgbaColor=[0.75, 0.72, 0.65, 1],
            physicsClientId=c,
        )
        self._floor = pb.createMultiBody(0, plane, plane_vis, physicsClientId=c)
        pb.changeDynamics(self._floor, -1, lateralFriction=self.world.floor_friction, physicsClientId=c)
        fd, path = tempfile.mkstemp(suffix=".urdf", prefix="bipedtele_nao_")
        try:
            with os.fdopen(fd, "w") as fh:
                fh.write(nao_urdf(self.geom, cfg.max_torque_nm))
            z0 = cfg.leg_height_m + self.geom.foot_height + self.geom.hip_offset_z + 0.001
            self._robot = pb.loadURDF(path, [0, 0, z0], flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        finally:
            os.unlink(path)
        index = {
            pb.getJointInfo(self._robot, j, physicsClientId=c)[1].decode(): j
            for j in range(pb.getNumJoints(self._robot, physicsClientId=c))
        }
        self._joints = [index[f"{side}{name}"] for side in "LR" for name in LEG_JOINTS]
        self._feet = [index["LAnkleRoll"], index["RAnkleRoll"]]
        for j in self._feet:
            pb.changeDynamics(self._robot, j, lateralFriction=cfg.foot_friction, physicsClientId=c)
        q0 = self.gait.standing_pose()
        for j, q in zip(self._joints, q0, strict=True):
            pb.resetJointState(self._robot, j, q, physicsClientId=c)
        self._obstacles: list[int] = []
        for ob in self.world.obstacles:
            if ob.shape == "box":
                half = [s / 2 for s in ob.size]
                col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c)
                vis = pb.createVisualShape(
                    pb.GEOM_BOX, halfExtents=half, rgbaColor=[0.8, 0.3, 0.2, 1], physicsClientId=c
                )
            else:
                r, h = ob.size
                col = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=r, height=h, physicsClientId=c)
                vis = pb.createVisualShape(
                    pb.GEOM_CYLINDER, radius=r, length=h, rgbaColor=[0.2, 0.6, 0.3, 1], physicsClientId=c
                )
            self._obstacles.append(pb.createMultiBody(0, col, vis, list(ob.position), physicsClientId=c))
        self._qref = q0.copy()

    def reset_pose(self) -> None:
        """Put the robot back on its start pose (the origin facing +x), standing.

        The world is rebuilt as at ``connect()`` and the robot settles on its feet; robot
        time goes on from where it was (it never runs backwards). Used by the follower's
        ``--reset-on-leader`` so that each leader session starts on the course start.
        """
        c = self._need()
        t_keep, steps_keep = self._t, self._steps
        pb.resetSimulation(physicsClientId=c)
        self._build_world()
        self._reset_state()
        self.gait.reset(0.0)
        self._run_physics(round(_SETTLE_S / self._dt))
        self._t, self._steps = t_keep, steps_keep
        self._last_obs_t = t_keep
        self.gait.reset(t_keep)
        self._last_yaw = self._yaw_unwrapped = self._base()[2]
        LOG.info("sim NAO back on its start pose")

    def disconnect(self) -> None:
        """Stop the gait and end the physics server."""
        if self._client is None:
            return
        try:
            self.gait.stop()
        finally:
            pb.disconnect(physicsClientId=self._client)
            self._client = None

    def _need(self) -> int:
        if self._client is None:
            raise RobotNotConnectedError("sim NAO: call connect() first (or use it in a with block)")
        return self._client

    # ------------------------------------------------------------------ commands

    def send_walk(self, cmd: WalkCommand) -> WalkCommand:
        """Walk at ``cmd`` from the next step, clamped to the limits and the gait's step bounds; the clamp."""
        self._need()
        c = cmd.clamped(self.limits)
        vmax, wmax = self.gait.max_forward(c.cycle_s), self.gait.max_turn(c.cycle_s)
        c = dataclasses.replace(
            c,
            forward_m_s=float(np.clip(c.forward_m_s, -vmax, vmax)),
            turn_rad_s=float(np.clip(c.turn_rad_s, -wmax, wmax)),
        )
        self._eps = c.eps_s
        self.gait.command(c.forward_m_s, c.turn_rad_s, c.cycle_s)
        return c

    def stop(self) -> None:
        """Finish the current step, then settle and stand."""
        self._need()
        self.gait.stop()

    def advance(self, dt: float) -> None:
        """Run the physics (and the gait) for ``dt`` [s] of robot time."""
        self._need()
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"dt = {dt}: allowed: a finite number >= 0 [s]")
        self._carry += dt
        n = int(self._carry / self._dt + 1e-9)
        self._carry -= n * self._dt
        self._run_physics(n)

    def _run_physics(self, n: int) -> None:
        c = self._client
        rob, joints = self._robot, self._joints
        thigh, tibia, hip_y = self.geom.thigh, self.geom.tibia, self.geom.hip_offset_y
        for _ in range(n):
            states = pb.getJointStates(rob, joints, physicsClientId=c)
            q = np.fromiter((s[0] for s in states), float, 12)
            qd = np.fromiter((s[1] for s in states), float, 12)
            qref, qdref = self.gait.update(self._t)
            step = self.gait.step
            if step != self._gait_step:
                self._step_changed(step)
            self._actuate(q, qd, qref, qdref)
            pb.stepSimulation(physicsClientId=c)
            self._steps += 1
            self._t = self._steps * self._dt
            # eq. (8) on the stance leg at its posture, measured joint angles and speeds, carried
            # from the stance hip to the hips' centre by the turn (torso yaw rate -dq_yaw)
            o, side = (0, 1.0) if self.gait.stance == "L" else (6, -1.0)
            v_st = hip_speed(q[o + HIP], q[o + KNEE], qd[o + HIP], qd[o + KNEE], thigh, tibia)
            self._vhip_sum += v_st - side * hip_y * qd[o + YAW]
            self._vhip_n += 1
            self._q, self._qd, self._qref = q, qd, qref

    def _actuate(self, q: np.ndarray, qd: np.ndarray, qref: np.ndarray, qdref: np.ndarray) -> None:
        """Drive the joints for one physics step: velocity motors at ``qdref + (qref - q) / eps`` (first order).

        ``q``, ``qd``: measured joint angles [rad] and speeds [rad/s]; ``qref``, ``qdref``: the gait's.
        """
        vel = qdref + (qref - q) / self._eps
        pb.setJointMotorControlArray(
            self._robot,
            self._joints,
            pb.VELOCITY_CONTROL,
            targetVelocities=vel.tolist(),
            forces=[self.config.max_torque_nm] * 12,
            physicsClientId=self._client,
        )

    def _step_changed(self, step: tuple[str, float, float, float] | None) -> None:
        """Record a touchdown when the gait begins a new step after a walking step."""
        prev, self._gait_step = self._gait_step, step
        if prev is None or prev[0] != "walk" or step is None:
            return
        self._touchdowns += 1
        x, y, yaw, _, _ = self._base()
        self._footfall = Footfall(
            self._touchdowns, float(step[1]), (float(x), float(y), float(yaw)), float(step[1] - prev[1])
        )

    # ------------------------------------------------------------------ measurements

    def _base(self) -> tuple[float, float, float, float, float]:
        pos, orn = pb.getBasePositionAndOrientation(self._robot, physicsClientId=self._client)
        rot = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
        yaw = math.atan2(rot[1, 0], rot[0, 0])
        tilt = math.acos(float(np.clip(rot[2, 2], -1.0, 1.0)))
        return pos[0], pos[1], yaw, tilt, pos[2]

    def observe(self) -> RobotObservation:
        """Measure speeds, pose, sonar, tilt and contacts since the previous call."""
        self._need()
        x, y, yaw, tilt, z = self._base()
        dyaw = (yaw - self._last_yaw + math.pi) % (2 * math.pi) - math.pi
        self._yaw_unwrapped += dyaw
        self._last_yaw = yaw
        elapsed = self._t - self._last_obs_t
        if self._vhip_n:
            self._v_hip_last = self._vhip_sum / self._vhip_n
        if elapsed > 0:
            self._turn_last = dyaw / elapsed
        self._vhip_sum, self._vhip_n, self._last_obs_t = 0.0, 0, self._t
        self._history.append((self._t, x, y))
        horizon = self._t - 2.0 * self.config.cycle_max_s
        while len(self._history) > 2 and self._history[0][0] < horizon:
            self._history.pop(0)
        cfg = self.config
        fallen = tilt > math.radians(cfg.fall_tilt_deg) or z < cfg.fall_height_m
        err = float(np.sqrt(np.mean((self._qref - self._q) ** 2)))
        contact = any(pb.getContactPoints(self._robot, ob, physicsClientId=self._client) for ob in self._obstacles)
        return RobotObservation(
            t=self._t,
            v_hip_m_s=float(self._v_hip_last),
            turn_rate_rad_s=float(self._turn_last),
            pose=(float(x), float(y), float(yaw)),
            sonar_m=self.sonar(),
            tilt_rad=float(tilt),
            fallen=bool(fallen),
            walking=self.gait.walking,
            joint_error_rad=err,
            in_contact=bool(contact),
        )

    def footfall(self) -> Footfall | None:
        """Return the latest touchdown: torso pose where the gait began a step after a walking step."""
        self._need()
        return self._footfall

    def cycle_speed(self) -> float:
        """Torso ground speed along its heading, averaged over the last walking cycle [m/s].

        Smooth across impacts (unlike eq. (8)); 0 until a cycle of observations exists.
        """
        self._need()
        if len(self._history) < 2:
            return 0.0
        t1, x1, y1 = self._history[-1]
        span = self.gait.cycle_s
        old = next((h for h in self._history if h[0] >= t1 - span - 1e-9), self._history[0])
        t0, x0, y0 = old
        if t1 - t0 < 0.5 * span:
            return 0.0
        yaw = self._last_yaw
        return float(((x1 - x0) * math.cos(yaw) + (y1 - y0) * math.sin(yaw)) / (t1 - t0))

    def sonar(self) -> tuple[float, float]:
        """Return the left and right sonar ranges [m].

        The nearest obstacle in each cone, clamped to the NAO version's range; the maximum
        when nothing is seen.

        Each 60-degree cone is sampled by 5 x 3 rays (azimuth x elevation) in one
        ``rayTestBatch``; only obstacles count (floor echoes are ignored).
        """
        c = self._need()
        lo, hi = self.sonar_range_m
        pos, orn = pb.getBasePositionAndOrientation(self._robot, physicsClientId=c)
        rot = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
        half = math.radians(self.config.sonar_cone_deg) / 2.0
        az = np.linspace(-0.85 * half, 0.85 * half, 5)
        el = np.array([-0.4 * half, 0.0, 0.4 * half])
        starts, ends = [], []
        for s in (1.0, -1.0):
            origin = np.asarray(pos) + rot @ np.array([_SONAR_XYZ[0], s * _SONAR_XYZ[1], _SONAR_XYZ[2]])
            yaw0 = s * math.radians(self.config.sonar_yaw_deg)
            for a in az:
                for e in el:
                    d = np.array([math.cos(e) * math.cos(yaw0 + a), math.cos(e) * math.sin(yaw0 + a), math.sin(e)])
                    starts.append(origin.tolist())
                    ends.append((origin + rot @ d * hi).tolist())
        hits = pb.rayTestBatch(starts, ends, physicsClientId=c)
        per = len(az) * len(el)
        out = []
        obstacles = set(self._obstacles)
        for k in range(2):
            r = hi
            for h in hits[k * per : (k + 1) * per]:
                if h[0] in obstacles:
                    r = min(r, h[2] * hi)
            out.append(float(np.clip(r, lo, hi)))
        return out[0], out[1]

    def capture(self, camera: Camera = "head") -> np.ndarray | None:
        """Render a QVGA RGB image (H x W x 3 uint8) from the head or the fixed scene camera.

        Rendered with pybullet's TinyRenderer (CPU, no GPU or display needed).
        """
        c = self._need()
        w, h = self.config.camera_width, self.config.camera_height
        if camera == "head":
            pos, orn = pb.getBasePositionAndOrientation(self._robot, physicsClientId=c)
            rot = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
            eye = np.asarray(pos) + rot @ np.array(_HEAD_CAM)
            fwd = rot @ np.array([1.0, 0.0, -0.02])
            view = pb.computeViewMatrix(eye.tolist(), (eye + fwd).tolist(), (rot @ [0.0, 0.0, 1.0]).tolist())
            proj = pb.computeProjectionMatrixFOV(HEAD_VFOV_DEG, w / h, 0.02, 10.0)
        elif camera == "scene":
            view = pb.computeViewMatrix(self.world.scene_camera_eye, self.world.scene_camera_target, [0, 0, 1])
            proj = pb.computeProjectionMatrixFOV(self.world.scene_camera_fov_deg, w / h, 0.05, 20.0)
        else:
            return None
        img = pb.getCameraImage(
            w, h, view, proj, renderer=pb.ER_TINY_RENDERER, flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=c
        )
        rgba = np.asarray(img[2], dtype=np.uint8).reshape(h, w, 4)
        return np.ascontiguousarray(rgba[:, :, :3])
