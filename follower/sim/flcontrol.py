"""The paper's follower joint law: feedback linearisation (13)-(15) with an estimate of ``W`` (16)-(18).

A pure controller: :meth:`FeedbackLinearising.step` takes its state and the measurements
and returns the new state and the joint torques; it reads no clock and does no I/O (the
torque walker, :mod:`.torque_robot`, runs it every physics step).

Outputs ``y(x)`` (Sec. 3.1-3.2), position errors of the measured robot against the gait's
references, phase variable = the time since the step began (the gait is clock-driven):

- ``int y1``: eq. (8) on the stance leg, the hip's position over the ankle
  ``p_hip = thigh sin(q_h) + tibia sin(q_h + q_k)`` minus the reference's (its time
  derivative is ``v_hip`` at the leg's posture, so ``d/dt int y1 = v_hip - v_hipref``:
  the forward-speed error (6) integrated);
- ``y2``: the other pitch joints (9) (stance knee and ankle, swing hip, knee and ankle);
- ``int y3``: the two hip yaws, which make the turn (10)-(11), Fig. 5;
- the four roll joints (the lateral balance of Sec. 5).

Single support: 12 outputs for 12 motors, ``L_g L_f y`` square and invertible, so (14)
gives ``y'' = -v`` exactly. Double support: the closed chain leaves 6 degrees of freedom, so
the outputs are the stance leg's 6 (``int y1``, its knee, ankle, yaw and two rolls); the
other leg follows through the contact; the pseudo-inverse of (14) takes the smallest
torques that give ``y'' = -v`` (``L_g L_f y`` 6 x 12 of full row rank).

(15) evaluates ``L_f`` and ``L_g`` on a model (:class:`~.rigidbody.RigidBodyModel`), which
may be wrong; then ``y'' = -v - W`` (16). ``v = v1 + v2``, ``v1 = K y + K_d y'`` with the
joint loop (21), ``K = 1/eps^2``, ``K_d = 1/eps``, and ``v2 = -W_hat``. The swing leg's
outputs use the commanded ``eps``; the stance leg's (the torso's motion over the stance
foot) a slower ``body_eps``: the stance foot can push the floor only within its sole, and a
fast body loop asks for centres of pressure outside it whenever the gait's reference
changes speed (measured: the robot tips at ``body_eps = 0.05 s`` and walks at 0.2 s,
docs/method.md, "The torque walker").

``W_hat``: a **disturbance observer** (Chen, Ballance, Gawthrop and O'Reilly, "A nonlinear
disturbance observer for robotic manipulators", IEEE Trans. Ind. Electron. 47(4), 2000; of
the families the paper names for ``W_hat`` (robust adaptive [20-22], neural networks [23])
it is the one that needs no regressor of the floating-base contact dynamics and no training,
and it estimates exactly the residual of (16)): ``W`` is the model's predicted output
acceleration for the torques applied, minus the real one, ``W = y''_model(u) - y''``, and
``W_hat' = L (W - W_hat)``, computed from ``y'`` without differentiating it
(``xi = W_hat + L y'``, ``xi' = L (y''_model(u) - W_hat)``). Because it uses the torques
*applied* (after the motors' limits), saturation does not wind it up.

``W_hat`` is fed back in **single support only**. In double support the model holds both
feet 6-D on the floor, and what the observer then sees is mostly what that rigid contact
cannot describe: the gait's contact schedule and the feet's real contacts disagree on 18 %
of the physics steps (landing and lift-off), a foot rolls onto an edge, the floor's contact
is compliant. A disturbance observer is robust only where its model is close to the plant
within its bandwidth; fed back through the closed chain, that residual tipped the walker in
2.2-2.8 s even with the exact model (at every rate tried, 3-100/s, also low-passed, held
from the last single support, or per contact mode; docs/method.md, "The torque walker").
The observer keeps running in double support, so its estimate is current at lift-off.

What double support then lacks, the model must bring: **an adaptive estimate of the torso's
mass** (with head and arms: the largest and least known mass of the robot, where a payload
or a different arm posture goes), regressor-style (the robust adaptive family the paper
cites): in single support, every ``adapt_every`` steps, the sensitivity ``S`` of the model's
output accelerations to the torso's mass scale is taken by a finite difference and the scale
moves down the gradient of ``|W_hat|^2`` (normalised), so the model itself becomes right, in
double support too. Of the wrong model's errors only the torso's made the walker fall when
applied one at a time (measured, docs/method.md): the estimate adapts that one parameter.

The forward and turn speed loops (20), (22) with the obstacle term ``k_z f_v`` of (33) run
in the follower loop's reference model (28) (``bipedtele.control.reference``), whose speeds
``eta`` the gait turns into the references of ``int y1`` and ``int y3``: so
``v = K e + K_v f_v - W_hat`` reaches the joints as the paper's cascade writes it, with
``K_v f_v`` entering through the references.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from bipedtele.follower.sim.gait import ANKLE, AROLL, HIP, KNEE, ROLL, YAW
from bipedtele.follower.sim.rigidbody import Affine, Contacts, RigidBodyModel

__all__ = ["FeedbackLinearising", "FlInput", "FlOutput", "FlState", "MotorLimits", "output_rows"]

#: Output keys: 0-11 the joints (left leg, then right leg), 12 / 13 ``int y1`` on the left / right leg.
_P_KEY = {"L": 12, "R": 13}
_N_KEYS = 14


def output_rows(stance: str, contacts: Contacts) -> list[int]:
    """Return the output keys in use: the stance leg's 6, then (single support) the swing leg's 6.

    Keys 0-11 are joint errors, 12 / 13 ``int y1`` on the left / right leg.
    """
    st, sw = (0, 6) if stance == "L" else (6, 0)
    rows = [_P_KEY[stance], st + KNEE, st + ANKLE, st + YAW, st + ROLL, st + AROLL]
    if contacts != "LR":
        rows += [sw + YAW, sw + ROLL, sw + HIP, sw + KNEE, sw + ANKLE, sw + AROLL]
    return rows


@dataclass(frozen=True)
class MotorLimits:
    """A DC motor's torque-speed envelope per joint (docs/method.md, "The torque walker").

    ``|u| <= stall (1 - |dq| / no_load)`` in the direction of motion, ``|u| <= stall``
    against it (braking), ``u = 0`` driving beyond ``no_load``.

    Attributes
    ----------
    stall_nm : ndarray (12,)
        Stall torque at the joint [N m].
    no_load_rad_s : ndarray (12,)
        No-load speed at the joint [rad/s].
    """

    stall_nm: np.ndarray
    no_load_rad_s: np.ndarray

    def clip(self, u: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Return ``u`` [N m] within the envelope at joint speeds ``dq`` [rad/s]."""
        driving = np.sign(u) == np.sign(dq)
        room = np.where(
            driving, self.stall_nm * np.clip(1.0 - np.abs(dq) / self.no_load_rad_s, 0.0, 1.0), self.stall_nm
        )
        return np.clip(u, -room, room)


@dataclass
class FlState:
    """The controller's state: the disturbance observer's ``xi`` per output key and which keys were active.

    Attributes
    ----------
    xi : ndarray (14,)
        ``W_hat + L y'`` [rad/s^2, m/s^2 for ``int y1``].
    active : ndarray of bool (14,)
        Keys in use at the last step.
    torso_scale : float
        The adaptive estimate of the torso's mass (with head and arms) as a multiple of the
        model's [-].
    ticks : int
        Single-support steps taken (the estimate moves every ``adapt_every`` of them).
    """

    xi: np.ndarray = field(default_factory=lambda: np.zeros(_N_KEYS))
    active: np.ndarray = field(default_factory=lambda: np.zeros(_N_KEYS, dtype=bool))
    torso_scale: float = 1.0
    ticks: int = 0

    def copy(self) -> FlState:
        """Return an independent copy."""
        return FlState(self.xi.copy(), self.active.copy(), self.torso_scale, self.ticks)


@dataclass(frozen=True)
class FlInput:
    """What one step of the joint law reads.

    Attributes
    ----------
    q, v : ndarray
        Free-flyer state (19,), (18,) (:mod:`.rigidbody`'s convention).
    q_ref, dq_ref, ddq_ref : ndarray (12,)
        Gait references [rad, rad/s, rad/s^2].
    stance : str
        The stance leg, ``"L"`` or ``"R"``.
    contacts : {"L", "R", "LR"}
        The feet the gait holds on the floor.
    eps_s : float
        Joint-loop time constant ``eps`` of (21) [s] of the swing leg's outputs.
    body_eps_s : float
        The same for the stance leg's outputs, which move the torso over the stance foot [s].
    """

    q: np.ndarray
    v: np.ndarray
    q_ref: np.ndarray
    dq_ref: np.ndarray
    ddq_ref: np.ndarray
    stance: str
    contacts: Contacts
    eps_s: float
    body_eps_s: float


@dataclass(frozen=True)
class FlOutput:
    """One step's result besides the torques.

    Attributes
    ----------
    rows : list of int
        Output keys in use.
    y, dy : ndarray
        Outputs and their rates.
    v : ndarray
        ``v = v1 - W_hat`` applied.
    w_hat : ndarray
        The estimate ``W_hat`` per output (fed back in single support only).
    ddy_model : ndarray
        The model's output accelerations for the torques applied (``-v`` unless a motor limit cut in).
    saturated : bool
        A motor limit cut the torques.
    torso_scale : float
        The torso-mass estimate the step used [-].
    """

    rows: list[int]
    y: np.ndarray
    dy: np.ndarray
    v: np.ndarray
    w_hat: np.ndarray
    ddy_model: np.ndarray
    saturated: bool
    torso_scale: float = 1.0


def _p_hip(
    q_h: float, q_k: float, dq_h: float, dq_k: float, thigh: float, tibia: float
) -> tuple[float, np.ndarray, float]:
    """Eq. (8) at the posture: ``p_hip`` [m], its gradient over (hip, knee) [m/rad] and ``dH/dt dq`` [m/s^2]."""
    s1, s12 = np.sin(q_h), np.sin(q_h + q_k)
    c1, c12 = np.cos(q_h), np.cos(q_h + q_k)
    p = thigh * s1 + tibia * s12
    grad = np.array([thigh * c1 + tibia * c12, tibia * c12])
    curv = -thigh * s1 * dq_h**2 - tibia * s12 * (dq_h + dq_k) ** 2
    return float(p), grad, float(curv)


class FeedbackLinearising:
    """Eq. (15) with a disturbance observer for ``W_hat``.

    Parameters
    ----------
    model : RigidBodyModel
        The model (15) evaluates ``L_f``, ``L_g`` on (exact or deliberately wrong).
    dob_rate_s : float
        The observer's rate ``L`` [1/s]; 0 turns ``W_hat`` off (``W_hat = 0``).
    limits : MotorLimits or None
        The motors' envelope; None: unlimited.
    mass_rate_s : float
        Gain ``gamma`` of the torso-mass adaptation [1/s] (0: the model's mass is kept); it
        needs the observer (``dob_rate_s > 0``).
    adapt_every : int
        Single-support steps between two moves of the estimate (each costs one more model evaluation).
    """

    #: Bounds of the torso-mass estimate, multiples of the model's [-].
    SCALE_RANGE = (0.5, 2.0)

    def __init__(
        self,
        model: RigidBodyModel,
        dob_rate_s: float,
        limits: MotorLimits | None = None,
        mass_rate_s: float = 0.0,
        adapt_every: int = 10,
    ) -> None:
        if dob_rate_s < 0:
            raise ValueError(f"dob_rate_s = {dob_rate_s}: allowed: >= 0 [1/s]")
        if mass_rate_s < 0:
            raise ValueError(f"mass_rate_s = {mass_rate_s}: allowed: >= 0 [1/s]")
        if adapt_every < 1:
            raise ValueError(f"adapt_every = {adapt_every}: allowed: an integer >= 1")
        self.model = model
        self.rate = float(dob_rate_s)
        self.mass_rate = float(mass_rate_s)
        self.adapt_every = int(adapt_every)
        self.limits = limits
        self.torque_weight = 1e-2  # [1/(N m)^2 relative to the ankle moments' 1/(N m)^2]
        self._thigh, self._tibia = model.geom.thigh, model.geom.tibia

    def outputs(self, inp: FlInput) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return the rows, ``H = dy/dq_j``, ``y``, ``y'`` and the drift ``dH/dt dq_j - r''`` of the outputs."""
        rows = output_rows(inp.stance, inp.contacts)
        qj, dqj = inp.q[7:], inp.v[6:]
        H = np.zeros((len(rows), 12))
        y = np.zeros(len(rows))
        dy = np.zeros(len(rows))
        drift = np.zeros(len(rows))
        for i, key in enumerate(rows):
            if key < 12:
                H[i, key] = 1.0
                y[i] = qj[key] - inp.q_ref[key]
                dy[i] = dqj[key] - inp.dq_ref[key]
                drift[i] = -inp.ddq_ref[key]
                continue
            o = 0 if key == _P_KEY["L"] else 6
            h, k = o + HIP, o + KNEE
            p, grad, curv = _p_hip(qj[h], qj[k], dqj[h], dqj[k], self._thigh, self._tibia)
            pr, gr, cr = _p_hip(inp.q_ref[h], inp.q_ref[k], inp.dq_ref[h], inp.dq_ref[k], self._thigh, self._tibia)
            H[i, [h, k]] = grad
            y[i] = p - pr
            dy[i] = grad @ dqj[[h, k]] - gr @ inp.dq_ref[[h, k]]
            drift[i] = curv - (gr @ inp.ddq_ref[[h, k]] + cr)
        return rows, H, y, dy, drift

    def _allocate(self, lglf: np.ndarray, target: np.ndarray, aff: Affine) -> np.ndarray:
        """Torques ``u`` with ``L_g L_f y u = target``: (14)'s pseudo-inverse, weighted in double support.

        Single support: ``L_g L_f y`` is square, ``u`` is unique. Double support: among the
        torques that give the same motion (6 of 12 directions only squeeze the feet against
        each other), the one that minimises ``|u|^2 + w |moments at the ankles|^2``
        (the feet's centres of pressure under the ankles, so neither foot is asked to pull on
        the floor or to tip), by its KKT system.
        """
        if aff.wrench_u is None or aff.wrench_0 is None or lglf.shape[0] >= lglf.shape[1]:
            return np.linalg.pinv(lglf, rcond=1e-10) @ target
        moments = [i for i in range(aff.wrench_u.shape[0]) if i % 6 in (3, 4)]
        cm, c = aff.wrench_u[moments], aff.wrench_0[moments]
        n, m = lglf.shape[1], lglf.shape[0]
        kkt = np.zeros((n + m, n + m))
        kkt[:n, :n] = self.torque_weight * np.eye(n) + cm.T @ cm
        kkt[:n, n:] = lglf.T
        kkt[n:, :n] = lglf
        rhs = np.concatenate([-cm.T @ c, target])
        return np.linalg.solve(kkt, rhs)[:n]

    def step(self, state: FlState, inp: FlInput, dt: float) -> tuple[FlState, np.ndarray, FlOutput]:
        """One step of (15): return the new state, the joint torques [N m] (12,) and what was computed.

        Parameters
        ----------
        state : FlState
            The observer's state (not changed: a new one is returned).
        inp : FlInput
            Measurements and references.
        dt : float
            Time to the next step [s] (the observer's integration step).
        """
        rows, H, y, dy, drift = self.outputs(inp)
        scale = state.torso_scale
        aff = self.model.affine(inp.q, inp.v, inp.contacts, scale)
        lglf = H @ aff.A
        lf2 = H @ aff.b + drift
        idx = np.asarray(rows)
        xi = state.xi.copy()
        fresh = ~state.active[idx]
        L = self.rate
        xi[idx[fresh]] = L * dy[fresh]  # a new output starts with W_hat = 0
        w_hat = xi[idx] - L * dy if L > 0 else np.zeros(len(rows))
        eps = np.full(len(rows), inp.eps_s)
        eps[:6] = inp.body_eps_s
        single = inp.contacts != "LR"
        # W_hat acts in single support only; in double support the observer runs on (so its
        # estimate is current at lift-off) but its estimate is not fed back (module docstring)
        v = y / eps**2 + dy / eps - (w_hat if single else 0.0)
        u = self._allocate(lglf, -lf2 - v, aff)
        applied = u if self.limits is None else self.limits.clip(u, inp.v[6:])
        ddy_model = lglf @ applied + lf2
        if L > 0:
            xi[idx] += dt * L * (ddy_model - w_hat)
        ticks = state.ticks + int(single)
        if single and L > 0 and self.mass_rate > 0 and ticks % self.adapt_every == 0:
            scale = self._adapt(scale, inp, H, drift, applied, ddy_model, w_hat, self.adapt_every * dt)
        active = np.zeros(_N_KEYS, dtype=bool)
        active[idx] = True
        out = FlOutput(rows, y, dy, v, w_hat, ddy_model, bool(np.any(applied != u)), state.torso_scale)
        return FlState(xi, active, scale, ticks), applied, out

    def _adapt(
        self,
        scale: float,
        inp: FlInput,
        H: np.ndarray,
        drift: np.ndarray,
        applied: np.ndarray,
        ddy_model: np.ndarray,
        w_hat: np.ndarray,
        interval_s: float,
    ) -> float:
        """One move of the torso-mass estimate: normalised gradient descent of ``|W_hat|^2``.

        ``W = y''_model - y''`` is, to first order, ``S (scale - scale_true)`` with ``S`` the
        sensitivity of the model's output accelerations (at the torques applied) to the
        scale, taken by a finite difference; so ``scale' = -gamma S^T W_hat / (1 + |S|^2)``
        over ``interval_s`` [s], within :attr:`SCALE_RANGE`.
        """
        step = 0.05
        aff = self.model.affine(inp.q, inp.v, inp.contacts, scale + step)
        sens = (H @ (aff.A @ applied + aff.b) + drift - ddy_model) / step
        scale -= interval_s * self.mass_rate * float(sens @ w_hat) / (1.0 + float(sens @ sens))
        return float(np.clip(scale, *self.SCALE_RANGE))
