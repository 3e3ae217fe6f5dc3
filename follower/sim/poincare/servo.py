"""Physics, gait and the follower's servo (28), (12) as one steppable system with save/restore."""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pybullet as pb
from bipedtele.control.config import ControlConfig
from bipedtele.control.reference import RealFollowerReference
from bipedtele.follower.robot import WalkCommand
from bipedtele.follower.sim.poincare.state import CM
from bipedtele.follower.sim.robot import SimNao

# Robot attributes that are handles or configuration (not state): never copied.
_NOT_STATE = {
    "_client",
    "_robot",
    "_floor",
    "_joints",
    "_feet",
    "_obstacles",
    "world",
    "config",
    "geom",
    "limits",
    "sonar_range_m",
    "_dt",
    # the torque walker's law and model (its state, _fl, is copied)
    "torque",
    "law",
    "control_model",
    "_com",
    "last_output",
}


class WalkerServo:
    """Physics + gait + the follower's servo (28), (12) around one :class:`SimNao`.

    Per control tick: ``observe`` the robot, advance the reference model on the measured
    speeds with ``sigma_r``, send ``(eta, T, eps)``; then the physics advances one
    control period. This is what the follower loop does with a fresh command, minus
    the network, the equivalent follower and the fictitious force (no obstacles).

    Parameters
    ----------
    robot : SimNao
        A connected simulated NAO.
    control : ControlConfig
        ``D``, ``k_s``, ``k_z``, ``beta_r``.
    s_r : array_like, shape (2,)
        Real damping ``[sigma, tau]``.
    T, eps : float
        Walking cycle and joint-servo time constant [s].
    ref : array_like, shape (2,)
        Reference ``[cm/s, deg/s]``.
    dt : float
        Control period [s].
    """

    def __init__(
        self, robot: SimNao, control: ControlConfig, s_r: Any, T: float, eps: float, ref: Any, dt: float
    ) -> None:
        self.robot = robot
        self.s_r = np.broadcast_to(np.asarray(s_r, dtype=float), (2,)).copy()
        self.T = float(T)
        self.eps = float(eps)
        self.ref = np.broadcast_to(np.asarray(ref, dtype=float), (2,)).copy()
        self.dt = float(dt)
        self.reference = RealFollowerReference(control.D, control.k_s, control.k_z, control.beta_r, self.dt)
        lim = robot.limits
        self.eta_max = np.array([lim.max_forward_m_s * CM, math.degrees(lim.max_turn_rad_s)])
        self.eta_meas = np.zeros(2)
        self.fallen = False
        #: When a list, every tick appends the measured speeds ``[cm/s, deg/s]`` to it.
        self.trace: list[np.ndarray] | None = None

    # ------------------------------------------------------------------ running

    def tick(self) -> None:
        """Observe, run the servo, send the walk command (the physics does not advance)."""
        obs = self.robot.observe()
        self.fallen = self.fallen or obs.fallen
        self.eta_meas = np.array([obs.v_hip_m_s * CM, math.degrees(obs.turn_rate_rad_s)])
        if self.trace is not None:
            self.trace.append(self.eta_meas)
        self.reference.step(self.ref, self.eta_meas, self.s_r, np.zeros(2), eta_max=self.eta_max)
        self.send()

    def send(self) -> None:
        """Send the reference model's current ``eta`` with ``T`` and ``eps`` to the robot."""
        eta = self.reference.eta
        self.robot.send_walk(
            WalkCommand(
                forward_m_s=float(eta[0]) / CM, turn_rad_s=math.radians(float(eta[1])), cycle_s=self.T, eps_s=self.eps
            )
        )

    def step(self) -> None:
        """One control period: advance the physics, then tick."""
        self.robot.advance(self.dt)
        self.tick()

    def run(self, seconds: float) -> None:
        """Tick, then run for ``seconds`` of simulated time."""
        for _ in range(round(seconds / self.dt)):
            self.step()

    def touchdown_due(self, foot: str, lead_s: float = 0.0) -> float | None:
        """Return the start time [s] of the gait step that ends with the touchdown of ``foot``.

        Only when that touchdown is at most ``lead_s`` [s] away; None otherwise.
        """
        g = self.robot.gait
        step = g.step
        if step is None or step[0] != "walk" or g.stance == foot:
            return None
        return step[1] if step[1] + g.cycle_s / 2.0 - lead_s <= self.robot._t + 1e-6 else None

    def run_to_section(self, foot: str, lead_s: float = 0.0) -> int:
        """Run control periods until the next section.

        The section is the first tick at most ``lead_s`` before a touchdown of ``foot`` (a
        later touchdown than the one of the current tick).

        Returns the number of control periods run. Raises :class:`RuntimeError` when no
        touchdown comes within two cycles (the robot stopped).
        """
        now = self.touchdown_due(foot, lead_s)
        limit = round(2.0 * self.T / self.dt) + 5
        for n in range(1, limit + 1):
            self.robot.advance(self.dt)
            due = self.touchdown_due(foot, lead_s)
            self.tick()
            if due is not None and (now is None or due > now + 1e-6):
                return n
        raise RuntimeError(f"no touchdown of {foot} within {limit} control periods")

    # ------------------------------------------------------------------ state

    def snapshot(self) -> tuple[int, dict[str, Any]]:
        """Save the whole simulation: pybullet state id and a copy of the Python state."""
        c = self.robot._client
        sid = pb.saveState(physicsClientId=c)
        py = {k: copy.deepcopy(v) for k, v in vars(self.robot).items() if k not in _NOT_STATE}
        py["__servo__"] = (copy.deepcopy(self.reference), self.eta_meas.copy(), self.fallen)
        return sid, py

    def restore(self, snap: tuple[int, dict[str, Any]]) -> None:
        """Return to a :meth:`snapshot` (the snapshot stays reusable)."""
        sid, py = snap
        pb.restoreState(sid, physicsClientId=self.robot._client)
        for k, v in py.items():
            if k != "__servo__":
                setattr(self.robot, k, copy.deepcopy(v))
        ref, eta_meas, fallen = py["__servo__"]
        self.reference = copy.deepcopy(ref)
        self.eta_meas = eta_meas.copy()
        self.fallen = fallen

    def state(self) -> np.ndarray:
        """Return the map's state now (order :func:`state_names`)."""
        r = self.robot
        c, body = r._client, r._robot
        pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=c)
        lin, ang = pb.getBaseVelocity(body, physicsClientId=c)
        roll, pitch, yaw = pb.getEulerFromQuaternion(orn)
        cy, sy = math.cos(yaw), math.sin(yaw)
        rot = np.array([[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]])  # world -> heading
        js = pb.getJointStates(body, r._joints, physicsClientId=c)
        q = [s[0] for s in js]
        qd = [s[1] for s in js]
        g = r.gait
        ref_q = g._phases[-1].ctrl[-1] if g._phases else g._q
        sway = g._sway_end if g._phases else g._sway
        return np.concatenate(
            [
                [pos[2], roll, pitch],
                rot @ np.asarray(lin),
                rot @ np.asarray(ang),
                q,
                qd,
                self.reference.eta,
                self.reference.z_r,
                ref_q,
                [sway],
            ]
        )

    def set_state(self, x: np.ndarray) -> None:
        """Put the simulation in state ``x`` (keeps the current horizontal position and yaw).

        The walk command is re-sent so that the gait latches the new ``eta``.
        """
        r = self.robot
        c, body = r._client, r._robot
        x = np.asarray(x, dtype=float)
        pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=c)
        yaw = pb.getEulerFromQuaternion(orn)[2]
        cy, sy = math.cos(yaw), math.sin(yaw)
        back = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])  # heading -> world
        quat = pb.getQuaternionFromEuler([float(x[1]), float(x[2]), yaw])
        pb.resetBasePositionAndOrientation(body, [pos[0], pos[1], float(x[0])], quat, physicsClientId=c)
        pb.resetBaseVelocity(body, (back @ x[3:6]).tolist(), (back @ x[6:9]).tolist(), physicsClientId=c)
        q, qd = x[9:21], x[21:33]
        for j, qa, qda in zip(r._joints, q, qd, strict=True):
            pb.resetJointState(body, j, float(qa), float(qda), physicsClientId=c)
        r._q, r._qd = q.copy(), qd.copy()
        self.reference.eta = x[33:35].copy()
        self.reference.observer.z_r = x[35:37].copy()
        g = r.gait
        if g._phases:
            g._phases[-1].ctrl[-1] = x[37:49]
            g._sway_end = float(x[49])
        else:
            g._q = x[37:49].copy()
            g._sway = float(x[49])
        self.send()
