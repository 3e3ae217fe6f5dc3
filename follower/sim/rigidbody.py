"""The simulated NAO as a rigid-body model with its stance contacts (pinocchio), pure computation.

This is the model behind the paper's feedback linearisation (13)-(15): for the robot of
:mod:`.model` standing on one foot (single support) or two (double support), the joint
accelerations are affine in the joint torques,

``qdd_j = A(x) u + b(x)``,

the constrained form of (2): ``M(q) a + h(q, v) = S^T u + J_c^T lambda`` with the feet's
6-D velocity held at zero (``J_c a + Jdot_c v = 0``, flat feet on a flat floor: assumption 3,
no bounce, no slip). Eliminating the contact wrenches ``lambda``:

``a = N M^-1 (S^T u - h) - M^-1 J_c^T Lambda Jdot_c v``, ``Lambda = (J_c M^-1 J_c^T)^-1``,
``N = I - M^-1 J_c^T Lambda J_c``,

so ``A = S N M^-1 S^T`` and ``b = S (-N M^-1 h - M^-1 J_c^T Lambda Jdot_c v)``, ``S`` the
selection of the 12 actuated joints. In double support ``A`` has rank 6 (the closed chain
leaves 6 degrees of freedom to 12 motors): the pseudo-inverse of (14) picks the smallest
torques among those that give the same motion.

Why pinocchio (``pin`` on the package index) rather than pybullet's own dynamics: the model
must be a *second* robot, deliberately wrong (masses, inertias and centre-of-mass offsets
off, :func:`perturbed_geometry`), built from the same URDF text, and evaluated at the state
pybullet measures; pinocchio evaluates ``M``, ``h``, the foot Jacobians and ``Jdot v`` from a
URDF string in about 30 us (``bench/follower.py`` prints the controller's cost per step),
without a second physics world to keep in step. See docs/method.md, "The torque walker".

State convention: pinocchio's free flyer, ``q = [p, quat(x, y, z, w), q_j]`` with ``p`` the
torso link's origin in the world [m], and ``v = [v_o, w, dq_j]`` with the origin's linear
and the angular velocity in the torso frame [m/s, rad/s]. :func:`state_from_pybullet`
converts pybullet's base state (its base frame is the torso's centre of mass).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pinocchio as pin
from bipedtele.follower.sim.model import LEG_JOINTS, NaoGeometry, nao_urdf

__all__ = ["Contacts", "RigidBodyModel", "perturbed_geometry", "state_from_pybullet"]

Contacts = Literal["L", "R", "LR", ""]

N_JOINTS = 12
_FOOT_FRAMES = {"L": "L_foot", "R": "R_foot"}


def perturbed_geometry(geom: NaoGeometry, error: float) -> NaoGeometry:
    """Return ``geom`` with its masses off by up to ``error`` (a fraction, e.g. 0.2) [-].

    The pattern is fixed, not random, so that a run is reproducible and the sign of each
    error is stated: torso (head and arms) ``+error``, thighs ``-error``, tibias
    ``+0.75 error``, feet ``-0.5 error``, the small joint links ``+error``; the torso's
    centre of mass ``error x 0.1 m`` higher; the motors' reflected rotor inertias ``-error``.
    Link inertias follow their masses (the URDF builder derives them from mass and size), so
    they are off by the same fractions.
    """
    if not 0.0 <= error < 1.0:
        raise ValueError(f"error = {error}: allowed: 0 <= error < 1")
    return dataclasses.replace(
        geom,
        m_torso=geom.m_torso * (1.0 + error),
        m_thigh=geom.m_thigh * (1.0 - error),
        m_tibia=geom.m_tibia * (1.0 + 0.75 * error),
        m_foot=geom.m_foot * (1.0 - 0.5 * error),
        m_small=geom.m_small * (1.0 + error),
        torso_com_z_m=geom.torso_com_z + 0.1 * error,
        rotor_pitch_kgm2=geom.rotor_pitch_kgm2 * (1.0 - error),
        rotor_roll_kgm2=geom.rotor_roll_kgm2 * (1.0 - error),
    )


def state_from_pybullet(
    base_pos: np.ndarray,
    base_quat: np.ndarray,
    base_lin: np.ndarray,
    base_ang: np.ndarray,
    q_j: np.ndarray,
    dq_j: np.ndarray,
    com_offset: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Convert pybullet's base state to pinocchio's free-flyer ``(q, v)``.

    Parameters
    ----------
    base_pos, base_quat : ndarray
        Position of the torso's centre of mass [m] and orientation (x, y, z, w), world frame.
    base_lin, base_ang : ndarray
        Linear velocity of the torso's centre of mass [m/s] and angular velocity [rad/s], world frame.
    q_j, dq_j : ndarray (12,)
        Joint angles [rad] and speeds [rad/s].
    com_offset : ndarray (3,)
        The torso's centre of mass in the torso link frame [m] (the URDF's inertial origin).
    """
    rot = pin.Quaternion(base_quat[3], base_quat[0], base_quat[1], base_quat[2]).toRotationMatrix()
    c_w = rot @ com_offset
    origin = np.asarray(base_pos) - c_w
    v_origin = np.asarray(base_lin) - np.cross(base_ang, c_w)
    q = np.concatenate([origin, base_quat, q_j])
    v = np.concatenate([rot.T @ v_origin, rot.T @ np.asarray(base_ang), dq_j])
    return q, v


@dataclass(frozen=True)
class Affine:
    """Joint accelerations affine in the torques: ``qdd_j = A u + b``.

    Attributes
    ----------
    A : ndarray (12, 12)
        [rad/s^2 per N m].
    b : ndarray (12,)
        [rad/s^2].
    wrench_u, wrench_0 : ndarray or None
        The feet's contact wrenches are ``wrench_u u + wrench_0`` [N, N m] (6 per foot in its
        frame at the ankle: force, then moment); None without contacts.
    """

    A: np.ndarray
    b: np.ndarray
    wrench_u: np.ndarray | None = None
    wrench_0: np.ndarray | None = None


class RigidBodyModel:
    """The simulated NAO's rigid-body dynamics on its stance feet.

    Parameters
    ----------
    geom : NaoGeometry
        Lengths and masses of the model (pass :func:`perturbed_geometry` for a wrong model).
    """

    def __init__(self, geom: NaoGeometry | None = None) -> None:
        self.geom = geom or NaoGeometry()
        self.model = pin.buildModelFromXML(nao_urdf(self.geom), pin.JointModelFreeFlyer())
        self.data = self.model.createData()
        names = [self.model.names[i] for i in range(2, self.model.njoints)]
        expected = [f"{side}{j}" for side in "LR" for j in LEG_JOINTS]
        if names != expected:
            raise RuntimeError(f"pinocchio joint order {names} differs from the gait's {expected}")
        self._foot = {k: self.model.getFrameId(v) for k, v in _FOOT_FRAMES.items()}
        self._torso = self.model.inertias[1].copy()  # the free flyer's body: torso, head and arms

    @property
    def mass(self) -> float:
        """Total mass [kg]."""
        return float(sum(i.mass for i in self.model.inertias))

    def affine(self, q: np.ndarray, v: np.ndarray, contacts: Contacts, torso_scale: float = 1.0) -> Affine:
        """Return ``A``, ``b`` of ``qdd_j = A u + b`` at state ``(q, v)`` with the feet ``contacts`` held.

        Parameters
        ----------
        q, v : ndarray
            Free-flyer configuration (19,) and velocity (18,) (see the module's convention).
        contacts : {"L", "R", "LR", ""}
            The feet on the floor ("" : none, free fall).
        torso_scale : float
            The torso's (with head and arms) mass and rotational inertia, as a multiple of this
            model's [-]; its centre of mass stays. The adaptive law's estimate
            (:class:`~.flcontrol.FeedbackLinearising`).
        """
        model, data = self.model, self.data
        t0 = self._torso
        model.inertias[1] = pin.Inertia(t0.mass * torso_scale, t0.lever.copy(), t0.inertia * torso_scale)
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(model, data, q, v)
        m_inv = np.linalg.inv(M)
        s_t = np.zeros((model.nv, N_JOINTS))
        s_t[6:, :] = np.eye(N_JOINTS)
        if contacts:
            jac = np.vstack([pin.getFrameJacobian(model, data, self._foot[k], pin.LOCAL) for k in contacts])
            gamma = np.concatenate(
                [pin.getFrameAcceleration(model, data, self._foot[k], pin.LOCAL).vector for k in contacts]
            )
            mj = m_inv @ jac.T
            lam = np.linalg.inv(jac @ mj)
            n_proj = np.eye(model.nv) - mj @ lam @ jac
            a_u = n_proj @ m_inv @ s_t
            a_0 = -n_proj @ m_inv @ h - mj @ lam @ gamma
            # lambda = -Lambda (J M^-1 (S^T u - h) + gamma)
            return Affine(a_u[6:], a_0[6:], -lam @ (mj.T @ s_t), lam @ (mj.T @ h - gamma))
        a_u = m_inv @ s_t
        a_0 = -m_inv @ h
        return Affine(a_u[6:], a_0[6:])
