"""The simulated walker's own Poincare map (the 3-D counterpart of eqs. 24-26).

The reduced model (20)-(23) is the only walker whose map the paper computes. Here the map
is that of the walker the follower really runs: pybullet physics, the gait
(:mod:`bipedtele.follower.sim.gait`) and the follower's servo (the reference model (28)
with the observer (12), :class:`~bipedtele.control.reference.RealFollowerReference`, at
the follower's control rate), with a constant reference and no network.

Section
    The touchdown of a chosen foot. The gait is clock-driven, so the touchdown is the
    scheduled end of the step whose swing leg is that foot; the section is the control
    tick at that instant, after the tick (observe, servo, send). ``T/2`` must be a
    multiple of both the physics period and the control period, so that every touchdown
    falls on a tick and the map is autonomous (:func:`check_alignment`).
State (:func:`state_names`, 50 values)
    Base height, roll and pitch; base linear and angular velocity in the heading frame;
    the 12 joint angles and rates; the servo's commanded speeds ``eta`` and observer
    estimates ``z_r`` (gait phase variables: what the gait latches at touchdown); the
    gait's reference pose at touchdown (12 angles, the start of the next step's joint
    references) and its lateral sway. Horizontal position and yaw are left out: the map
    is invariant to them on flat ground (they would add the neutral eigenvalue 1).
Map
    From a state at the section, run the walker until the same foot touches down again
    (one walking cycle ``T``, two steps, like the reduced model's one reset per cycle).
Jacobian
    Central differences (26) around the fixed point; every evaluation restores the
    whole simulation (pybullet ``saveState``/``restoreState`` plus the Python state of
    the robot, its gait and the servo) and applies one perturbation.
Fixed point
    Found by walking until steady (``warmup_s``) from standing and averaging the section
    states of ``average_cycles`` cycles; its residual ``|P(x*) - x*|`` (scaled by the
    perturbation sizes) is reported. That average is not a fixed point of the map: with
    ``newton_iterations`` (``--newton N``) damped Newton steps on ``P(x) - x = 0`` refine
    it (:meth:`WalkerMap.newton`), and the radius of (26) is measured there at 0.3, 1 and
    3 times the perturbation sizes.
Limit cycle
    The per-tick speeds over the averaging cycles give an oscillation marker
    (:meth:`WalkerMap.steady`): the turn loop's limit cycle at high turn damping is
    periodic in ``T``, so the section sees a fixed point there.
Table
    ``--table FILE`` tabulates the map over forward damping x turn damping x ``T``
    (:func:`walker_table`): the surrogate of ``control.hybrid_model = "walker"``
    (:mod:`bipedtele.control.walker_map`, docs/walker_map.md).

Perturbation sizes are small and physical (1 mm-scale, 1 mrad-scale, :data:`DELTAS`),
not the paper's ``dq = 1`` (rad), ``dqdot = 0.375``: the reduced model is affine, so any
size is exact there, while a perturbation of 1 rad would topple the 3-D walker.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import pybullet as pb
from bipedtele.config import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.control.reference import RealFollowerReference
from bipedtele.control.walker_map import TABLE_FORMAT
from bipedtele.follower.config import FollowerConfig
from bipedtele.follower.robot import WalkCommand
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.model import LEG_JOINTS
from bipedtele.follower.sim.robot import SimNao
from bipedtele.follower.sim.torque_config import TorqueConfig
from bipedtele.follower.sim.world import WorldConfig

__all__ = [
    "DELTAS",
    "TABLE_FORMAT",
    "MapSettings",
    "NewtonResult",
    "WalkerMap",
    "WalkerServo",
    "check_alignment",
    "state_names",
    "walker_rho",
    "walker_table",
]

LOG = logging.getLogger(__name__)

CM = 100.0

#: Perturbation size per state group (units of the state).
DELTAS: dict[str, float] = {
    "base_z": 1e-4,  # m
    "base_rp": 1e-3,  # rad
    "base_v": 1e-3,  # m/s
    "base_w": 1e-2,  # rad/s
    "q": 1e-3,  # rad
    "qd": 1e-2,  # rad/s
    "servo": 1e-2,  # cm/s, deg/s
    "gait_q": 1e-3,  # rad
    "gait_sway": 1e-4,  # m
}

_JOINTS = [f"{side}{j}" for side in "LR" for j in LEG_JOINTS]
_GROUPS: list[tuple[str, list[str]]] = [
    ("base_z", ["base_z"]),
    ("base_rp", ["base_roll", "base_pitch"]),
    ("base_v", ["base_v_fwd", "base_v_left", "base_v_up"]),
    ("base_w", ["base_w_x", "base_w_y", "base_w_z"]),
    ("q", [f"q_{n}" for n in _JOINTS]),
    ("qd", [f"qd_{n}" for n in _JOINTS]),
    ("servo", ["eta_v", "eta_d", "z_r_v", "z_r_d"]),
    ("gait_q", [f"ref_{n}" for n in _JOINTS]),
    ("gait_sway", ["sway"]),
]

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


def state_names() -> list[str]:
    """Names of the map's state, in order (50 values)."""
    return [n for _, names in _GROUPS for n in names]


def perturbation_sizes(scale: float = 1.0) -> np.ndarray:
    """Per-state perturbation of (26), :data:`DELTAS` times ``scale``."""
    return np.array([DELTAS[g] * scale for g, names in _GROUPS for _ in names])


def check_alignment(T: float, physics_hz: float, control_rate_hz: float) -> None:
    """Raise :class:`ConfigError` unless ``T/2`` is a whole number of physics and control periods."""
    for name, hz in (("physics", physics_hz), ("control", control_rate_hz)):
        n = T / 2.0 * hz
        if abs(n - round(n)) > 1e-6:
            raise ConfigError(
                f"T = {T:g} s: allowed: T/2 a multiple of the {name} period 1/{hz:g} s "
                "(every touchdown must fall on a control tick)"
            )


@dataclass(frozen=True)
class MapSettings:
    """Operating conditions of the walker's map.

    Attributes
    ----------
    v_ref, turn_ref : float
        Constant reference ``k_g x_m`` [cm/s, deg/s] (the paper's 5 cm/s and 4 deg/s).
    foot : {"L", "R"}
        Foot whose touchdown is the section.
    control_rate_hz : float
        The servo's rate (the follower's default 50 Hz).
    warmup_s : float
        Walking time before the fixed point is taken [s].
    average_cycles : int
        Cycles after the warm-up whose section states are averaged into the fixed point.
    delta_scale : float
        Factor on :data:`DELTAS`.
    contraction : bool
        Also measure the contraction per cycle by iterating the map (:meth:`WalkerMap.contraction`).
    newton_iterations : int
        When > 0, :meth:`WalkerMap.analyse` also solves ``P(x) = x`` by Newton from the
        averaged state (:meth:`WalkerMap.newton`), at most this many Jacobians.
    newton_scales : tuple of float
        Factors on :data:`DELTAS` at which the radius of (26) is measured at the Newton
        fixed point.
    newton_max_step : float
        Largest Newton step per state value, in perturbation sizes (a trust region: the map
        is non-smooth beyond a few sizes).
    torque : TorqueConfig or None
        None: the position walker (``--robot sim``); a ``[torque]`` section: the torque
        walker (``--robot sim-torque``, :class:`~.torque_robot.TorqueNao`), whose joint law's
        state (observer, torso-mass estimate) is kept at the fixed point's in every
        evaluation (it is not in the map's state vector).
    """

    v_ref: float = 5.0
    turn_ref: float = 4.0
    foot: Literal["L", "R"] = "L"
    control_rate_hz: float = 50.0
    warmup_s: float = 30.0
    average_cycles: int = 8
    lead_s: float = 0.1
    delta_scale: float = 1.0
    contraction: bool = True
    newton_iterations: int = 0
    newton_scales: tuple[float, ...] = (0.3, 1.0, 3.0)
    newton_max_step: float = 10.0
    torque: TorqueConfig | None = None

    def physics_hz(self, sim: SimConfig) -> float:
        """Return the walker's physics rate [Hz]: ``[torque]``'s for the torque walker, else ``[sim]``'s."""
        return self.torque.physics_hz if self.torque is not None else sim.physics_hz

    def build_robot(self, sim: SimConfig) -> SimNao:
        """Return the walker these settings name, not yet connected, on an empty floor."""
        if self.torque is None:
            return SimNao(sim, world=WorldConfig())
        from bipedtele.follower.sim.torque_robot import TorqueNao

        return TorqueNao(sim, world=WorldConfig(), torque=self.torque)


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


@dataclass
class WalkerMapResult:
    """One operating point of the walker's map."""

    sigma_r: list[float]
    T: float
    eps: float
    rho_walker: float
    eigenvalues: list[complex]
    fixed_point_speed: float
    fixed_point_v_hip: float
    fixed_point_turn: float
    residual: float
    spread: float
    contraction: float
    transient: float
    fallen: bool
    evaluations: int
    sim_seconds: float
    forward_std: float = math.nan
    turn_std: float = math.nan
    limit_cycle: bool = False
    newton: dict[str, Any] | None = None


@dataclass
class NewtonResult:
    """A Newton solve of ``P(x) = x`` (:meth:`WalkerMap.newton`).

    Attributes
    ----------
    x : numpy.ndarray
        The last iterate (state units, :func:`state_names`).
    residual_max, residual_rms : list of float
        ``|P(x) - x|`` in perturbation sizes, largest and RMS over the state, at the
        start and after every accepted step.
    steps : list of float
        Largest component of every accepted step [perturbation sizes].
    damping : list of float
        The step factor accepted at every iteration (1, 1/2, ... 1/16).
    rho_by_scale : dict
        Radius of (26) at ``x`` per factor on :data:`DELTAS` (keys ``"0.3"``, ``"1"``, ...).
    fallen : bool
        The walker fell in some evaluation.
    """

    x: np.ndarray
    residual_max: list[float]
    residual_rms: list[float]
    steps: list[float]
    rho_by_scale: dict[str, float]
    fallen: bool
    damping: list[float] = dataclasses.field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields (without ``x``)."""
        return {
            "residual_max": self.residual_max,
            "residual_rms": self.residual_rms,
            "steps": self.steps,
            "damping": self.damping,
            "rho_by_scale": self.rho_by_scale,
            "fallen": self.fallen,
        }


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v * v)))


class WalkerMap:
    """The walker's Poincare map at one ``(sigma_r, T, eps)``.

    Parameters
    ----------
    s_r, T, eps
        Real damping ``[sigma, tau]``, walking cycle [s] and joint servo [s].
    control : ControlConfig, optional
        Servo gains (default: the paper's).
    sim : SimConfig, optional
        The simulated NAO (default ``[sim]`` values, no obstacles).
    settings : MapSettings, optional
    """

    def __init__(
        self,
        s_r: Any,
        T: float,
        eps: float,
        *,
        control: ControlConfig | None = None,
        sim: SimConfig | None = None,
        settings: MapSettings | None = None,
    ) -> None:
        self.settings = settings or MapSettings()
        self.sim = sim or SimConfig()
        check_alignment(T, self.settings.physics_hz(self.sim), self.settings.control_rate_hz)
        lo, hi = self.sim.cycle_min_s, self.sim.cycle_max_s
        if not lo - 1e-9 <= T <= hi + 1e-9:
            raise ConfigError(f"T = {T:g} s: allowed: the simulated NAO's cycle range [{lo:g}, {hi:g}] s")
        self.control = control or ControlConfig()
        self.robot = self.settings.build_robot(self.sim)
        self.robot.connect()
        st = self.settings
        self.servo = WalkerServo(
            self.robot, self.control, s_r, T, eps, [st.v_ref, st.turn_ref], 1.0 / st.control_rate_hz
        )
        self.evaluations = 0
        self.sim_seconds = 0.0
        self.transient = math.nan

    def close(self) -> None:
        """Disconnect the simulation."""
        self.robot.disconnect()

    def __enter__(self) -> WalkerMap:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def steady(self) -> np.ndarray:
        """Walk from standing for ``warmup_s``, then ``average_cycles`` more cycles.

        Returns the fixed-point estimate: the mean of the section states of those cycles
        (for a walker that settles, the fixed point itself; for one whose touchdown state
        keeps wandering, e.g. between contact modes of the landing foot, the centre of the
        wandering, whose size :attr:`spread` reports; :meth:`newton` refines it).

        Over those cycles the measured speeds of every control tick give
        :attr:`forward_std` [cm/s] and :attr:`turn_std` [deg/s], their standard deviations
        within the cycle; :attr:`limit_cycle` is set when either exceeds its reference
        (``v_ref``, ``turn_ref``): the walker then oscillates by more than it is asked to
        walk. The turn loop's limit cycle at high turn damping (the servo saturating at
        +-25 deg/s within every cycle) is periodic in ``T``, so the section alone sees a
        fixed point there; this marker is what tells it apart.
        """
        sv, st = self.servo, self.settings
        sv.tick()
        sv.run(st.warmup_s)
        sv.run_to_section(st.foot, st.lead_s)
        states = [sv.state()]
        path = 0.0
        turned = 0.0
        elapsed = 0.0
        sv.trace = []
        for _ in range(st.average_cycles):
            p0 = self.robot._base()
            n = sv.run_to_section(st.foot, st.lead_s)
            p1 = self.robot._base()
            heading = p0[2] + 0.5 * _wrap(p1[2] - p0[2])
            path += (p1[0] - p0[0]) * math.cos(heading) + (p1[1] - p0[1]) * math.sin(heading)
            turned += _wrap(p1[2] - p0[2])
            elapsed += n * sv.dt
            states.append(sv.state())
        self.sim_seconds += st.warmup_s + elapsed + sv.T
        speeds = np.array(sv.trace)
        sv.trace = None
        self.forward_std, self.turn_std = (float(v) for v in speeds.std(axis=0))
        self.limit_cycle = self.forward_std > st.v_ref or self.turn_std > st.turn_ref
        arr = np.array(states)
        x0 = arr.mean(axis=0)
        d = perturbation_sizes(st.delta_scale)
        self.spread = float(np.max(np.abs(arr - x0) / d))
        self.speed = CM * path / elapsed if elapsed > 0 else 0.0
        self.turn_rate = math.degrees(turned / elapsed) if elapsed > 0 else 0.0
        self._x0 = x0
        self._snap = sv.snapshot()
        return x0.copy()

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``P(x)``: the saved section with state ``x``, run for one walking cycle."""
        sv = self.servo
        sv.restore(self._snap)
        sv.set_state(x)
        n = sv.run_to_section(self.settings.foot, self.settings.lead_s)
        self.evaluations += 1
        self.sim_seconds += n * sv.dt
        return sv.state()

    def jacobian(self, x0: np.ndarray, scale: float | None = None) -> tuple[np.ndarray, bool]:
        """Central differences (26) around ``x0``: ``2 n`` evaluations of :meth:`apply`.

        ``scale`` is the factor on :data:`DELTAS` (default ``settings.delta_scale``).
        Returns the Jacobian and whether the walker fell in any evaluation.
        """
        sv = self.servo
        d = perturbation_sizes(self.settings.delta_scale if scale is None else scale)
        jac = np.empty((d.size, d.size))
        fallen = False
        for i in range(d.size):
            e = np.zeros(d.size)
            e[i] = d[i]
            plus = self.apply(x0 + e)
            fallen |= sv.fallen
            minus = self.apply(x0 - e)
            fallen |= sv.fallen
            jac[:, i] = (plus - minus) / (2.0 * d[i])
        return jac, fallen

    def residual(self, x: np.ndarray) -> np.ndarray:
        """``(P(x) - x) / delta``: the fixed-point residual in perturbation sizes (one evaluation)."""
        return (self.apply(x) - x) / perturbation_sizes(self.settings.delta_scale)

    def newton(self, x0: np.ndarray, *, jac: np.ndarray | None = None) -> NewtonResult:
        """Solve ``P(x) = x`` by damped Newton steps from ``x0``.

        In perturbation-size units ``y = x / delta`` the step solves ``(J_y - I) s = -r``
        (least squares, so a direction the map leaves alone costs nothing), ``J_y`` the
        central-difference Jacobian (26) at the current point. A step is capped at
        ``newton_max_step`` sizes per value, then halved up to 4 times until the RMS
        residual falls; with no fall the solve stops. At most ``newton_iterations``
        Jacobians (``jac``, the Jacobian at ``x0`` if already computed, counts as the
        first). At the last point the radius of (26) is measured for every factor of
        ``newton_scales``.
        """
        st = self.settings
        d = perturbation_sizes(st.delta_scale)
        x = np.asarray(x0, dtype=float).copy()
        r = self.residual(x)
        res_max, res_rms, steps, damping = [float(np.max(np.abs(r)))], [_rms(r)], [], []
        fallen = self.servo.fallen
        for k in range(st.newton_iterations):
            if k > 0 or jac is None:
                jac, f = self.jacobian(x)
                fallen |= f
            jy = jac * d[None, :] / d[:, None]
            step = np.linalg.lstsq(jy - np.eye(d.size), -r, rcond=1e-6)[0]
            big = float(np.max(np.abs(step)))
            if big > st.newton_max_step:
                step *= st.newton_max_step / big
            alpha = 1.0
            for _ in range(5):
                trial = x + alpha * step * d
                r_new = self.residual(trial)
                fallen |= self.servo.fallen
                if _rms(r_new) < res_rms[-1]:
                    break
                alpha *= 0.5
            else:
                LOG.info("newton: no step lowers the residual after %d iterations", k)
                break
            x, r = trial, r_new
            res_max.append(float(np.max(np.abs(r))))
            res_rms.append(_rms(r))
            steps.append(alpha * float(np.max(np.abs(step))))
            damping.append(alpha)
            LOG.info(
                "newton %d: step %.2f sizes, residual rms %.3g max %.3g", k + 1, steps[-1], res_rms[-1], res_max[-1]
            )
        rho: dict[str, float] = {}
        for sc in st.newton_scales:
            jk, f = self.jacobian(x, sc)
            fallen |= f
            rho[f"{sc:g}"] = float(np.max(np.abs(np.linalg.eigvals(jk))))
        return NewtonResult(x, res_max, res_rms, steps, rho, bool(fallen), damping)

    def contraction(
        self, x0: np.ndarray, *, directions: int = 2, cycles: int = 20, size: float = 30.0, seed: int = 0
    ) -> float:
        """Measured contraction per cycle of a perturbation, without linearisation.

        From ``x0`` and from ``x0 + size * delta * v`` (``v`` a random unit direction in
        perturbation-size units) the walker runs ``cycles`` cycles; the distance between the
        two at the section, in perturbation-size units, shrinks (or grows) by a factor per
        cycle of ``(d_m / d_0)^(1/m)``. Returns the largest over ``directions``. For a
        smooth map this tends to the spectral radius; for the walker, whose contacts make
        the map non-smooth at the scale of the perturbations of (26), it is the check of
        what the Jacobian's radius claims.

        The horizon must outlast the transient: a perturbation of 30 sizes can first grow
        (up to 17 times in the first 3-4 cycles at the default operating point, when it
        switches the landing foot's contact and kicks the turn servo) and only then decay
        at 0.6-0.8 per cycle; over 10 cycles the estimate then reads about 1, over 20 it
        reads the decay (docs/method.md). The largest ``d_m / d_0`` over the horizon and the
        directions is kept in :attr:`transient`.
        """
        sv = self.servo
        d = perturbation_sizes(self.settings.delta_scale)
        rng = np.random.default_rng(seed)

        def run(x: np.ndarray) -> np.ndarray:
            sv.restore(self._snap)
            sv.set_state(x)
            out = []
            for _ in range(cycles):
                sv.run_to_section(self.settings.foot, self.settings.lead_s)
                out.append(sv.state())
            self.sim_seconds += cycles * sv.T
            return np.array(out)

        nominal = run(x0)
        worst = 0.0
        self.transient = 0.0
        for _ in range(directions):
            v = rng.standard_normal(d.size)
            v *= size / np.sqrt(np.mean(v * v))
            pert = run(x0 + v * d)
            dist = np.sqrt(np.mean(((pert - nominal) / d) ** 2, axis=1))
            worst = max(worst, float(dist[-1] / size) ** (1.0 / cycles))
            self.transient = max(self.transient, float(np.max(dist)) / size)
        return worst

    def analyse(self) -> WalkerMapResult:
        """Compute the fixed point, the Jacobian (26) by central differences and its spectral radius."""
        x0 = self.steady()
        sv = self.servo
        d = perturbation_sizes(self.settings.delta_scale)
        residual = float(np.max(np.abs(self.apply(x0) - x0) / d))
        jac, fallen = self.jacobian(x0)
        eig = np.linalg.eigvals(jac)
        contraction = self.contraction(x0) if self.settings.contraction else math.nan
        newton = None
        if self.settings.newton_iterations > 0:
            newton = self.newton(x0, jac=jac).as_dict()
            LOG.info(
                "newton: residual %.3g -> %.3g (max, perturbation sizes); radius at the fixed point %s",
                newton["residual_max"][0],
                newton["residual_max"][-1],
                newton["rho_by_scale"],
            )
        return WalkerMapResult(
            sigma_r=sv.s_r.tolist(),
            T=sv.T,
            eps=sv.eps,
            rho_walker=float(np.max(np.abs(eig))),
            eigenvalues=sorted(eig.tolist(), key=lambda z: -abs(z)),
            fixed_point_speed=float(self.speed),
            fixed_point_v_hip=float(x0[35]),
            fixed_point_turn=float(self.turn_rate),
            residual=residual,
            spread=self.spread,
            contraction=contraction,
            transient=self.transient,
            fallen=bool(fallen),
            evaluations=self.evaluations,
            sim_seconds=self.sim_seconds,
            forward_std=self.forward_std,
            turn_std=self.turn_std,
            limit_cycle=self.limit_cycle,
            newton=newton,
        )


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def walker_rho(s_r: Any, T: float, eps: float, **kw: Any) -> WalkerMapResult:
    """Build a :class:`WalkerMap`, analyse it, close it."""
    with WalkerMap(s_r, T, eps, **kw) as m:
        return m.analyse()


def grid(sigmas: Sequence[float], Ts: Sequence[float]) -> list[tuple[float, float]]:
    """Return the ``(sigma_r, T)`` points of a grid, sigma-major."""
    return [(float(s), float(t)) for s in sigmas for t in Ts]


# ----------------------------------------------------------------------------- operating point


def alignment_quantum(physics_hz: float, control_rate_hz: float) -> float:
    """Smallest ``T/2`` step [s] that is a whole number of physics and control periods."""
    a, b = round(physics_hz), round(control_rate_hz)
    if abs(a - physics_hz) > 1e-9 or abs(b - control_rate_hz) > 1e-9:
        raise ConfigError(
            f"physics_hz = {physics_hz:g}, control_rate_hz = {control_rate_hz:g}: allowed: whole numbers of Hz"
        )
    return 1.0 / math.gcd(a, b)


def operating_point(
    control: ControlConfig, sim: SimConfig, control_rate_hz: float = 50.0, physics_hz: float | None = None
) -> dict[str, Any]:
    """Return the follower's parameters at zero delay: (40) then (30), as the robot applies them.

    The robot clamps ``T`` and ``eps`` to what it accepts; ``T`` is then rounded to the
    nearest cycle whose touchdowns fall on control ticks (:func:`alignment_quantum`) at
    ``physics_hz`` [Hz] (default ``sim.physics_hz``).
    """
    from bipedtele.control.damping import schedule_damping
    from bipedtele.control.online import OnlineChooser

    choice = OnlineChooser(control).choose(schedule_damping(0.0, 0.0, control).s_e)
    q = 2.0 * alignment_quantum(sim.physics_hz if physics_hz is None else physics_hz, control_rate_hz)
    T = float(np.clip(choice.T, sim.cycle_min_s, sim.cycle_max_s))
    T = float(
        np.clip(round(T / q) * q, math.ceil(sim.cycle_min_s / q - 1e-9) * q, math.floor(sim.cycle_max_s / q + 1e-9) * q)
    )
    return {
        "sigma_r": [float(v) for v in choice.s_r],
        "T": T,
        "eps": float(np.clip(choice.eps, 0.02, 1.0)),
        "T_chosen": float(choice.T),
        "eps_chosen": float(choice.eps),
    }


# ----------------------------------------------------------------------------- grid and CLI


def _point(args: tuple[list[float], float, float, ControlConfig, SimConfig, MapSettings]) -> dict[str, Any]:
    from bipedtele.control.hybrid import rho_hybrid

    s_r, T, eps, control, sim, settings = args
    r = walker_rho(s_r, T, eps, control=control, sim=sim, settings=settings)
    loop = dataclasses.replace(control, hybrid_model="speed-loop").hybrid()
    row = {
        "sigma_r": [float(v) for v in s_r],
        "T": float(T),
        "eps": float(eps),
        "rho_walker": r.rho_walker,
        "rho_reduced": rho_hybrid(s_r, T, eps, control.dp, control),
        "rho_reduced_speed_loop": rho_hybrid(s_r, T, eps, loop.dp, loop),
        "fixed_point_speed": r.fixed_point_speed,
        "fixed_point_v_hip": r.fixed_point_v_hip,
        "fixed_point_turn": r.fixed_point_turn,
        "residual": r.residual,
        "spread": r.spread,
        "contraction": r.contraction,
        "transient": r.transient,
        "fallen": r.fallen,
        "eigenvalues": [[float(z.real), float(z.imag)] for z in r.eigenvalues[:6]],
        "evaluations": r.evaluations,
        "sim_seconds": r.sim_seconds,
        "forward_std": r.forward_std,
        "turn_std": r.turn_std,
        "limit_cycle": r.limit_cycle,
    }
    if r.newton is not None:
        row["newton"] = r.newton
    return row


def poincare_grid(
    sigmas: Sequence[float],
    Ts: Sequence[float],
    *,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
    settings: MapSettings | None = None,
    jobs: int = 1,
) -> dict[str, Any]:
    """Compute the walker's and the reduced model's radii over ``sigma_r`` x ``T``.

    Both channels' ``sigma_r``; plus the follower's operating point (:func:`operating_point`).

    Returns
    -------
    dict
        ``{"points": [...], "operating_point": {...}, "v_ref", "turn_ref", "foot",
        "control_rate_hz", "lead_s", "warmup_s", "speed_loop": {"dp", "k_v"}}``; each point
        has ``sigma_r``, ``T``, ``rho_walker``, ``rho_reduced``, ``rho_reduced_speed_loop``,
        ``fixed_point_speed`` [cm/s] and diagnostics (``residual``, ``spread`` in
        perturbation sizes, ``fallen``, ``forward_std`` [cm/s], ``turn_std`` [deg/s],
        ``limit_cycle``, the largest ``eigenvalues``). With ``settings.newton_iterations``
        the operating point (only) also gets ``newton`` (:meth:`NewtonResult.as_dict`).
    """
    control = control or ControlConfig()
    sim = sim or SimConfig()
    st = settings or MapSettings()
    op = operating_point(control, sim, st.control_rate_hz, st.physics_hz(sim))
    eps = op["eps"]
    for T in Ts:
        check_alignment(T, st.physics_hz(sim), st.control_rate_hz)
    grid_st = dataclasses.replace(st, newton_iterations=0)
    tasks = [([s, s], T, eps, control, sim, grid_st) for s, T in grid(sigmas, Ts)]
    tasks.append((op["sigma_r"], op["T"], eps, control, sim, st))
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs) as pool:
            rows = list(pool.map(_point, tasks))
    else:
        rows = []
        for t in tasks:
            rows.append(_point(t))
            LOG.info("poincare: sigma_r %s T %.2f: rho_walker %.3f", t[0], t[1], rows[-1]["rho_walker"])
    op_row = rows.pop()
    op_row.update({k: op[k] for k in ("T_chosen", "eps_chosen")})
    return {
        "points": rows,
        "operating_point": op_row,
        "v_ref": st.v_ref,
        "turn_ref": st.turn_ref,
        "foot": st.foot,
        "control_rate_hz": st.control_rate_hz,
        "lead_s": st.lead_s,
        "warmup_s": st.warmup_s,
        "delta_scale": st.delta_scale,
        "speed_loop": {"dp": control.calibrated_dp, "k_v": control.calibrated_k_v},
    }


# ----------------------------------------------------------------------------- the surrogate table


def _table_point(args: tuple[float, float, float, float, ControlConfig, SimConfig, MapSettings]) -> dict[str, Any]:
    sigma, tau, T, eps, control, sim, settings = args
    r = walker_rho([sigma, tau], T, eps, control=control, sim=sim, settings=settings)
    return {
        "rho": r.rho_walker,
        "limit_cycle": r.limit_cycle,
        "fallen": r.fallen,
        "forward_std": r.forward_std,
        "turn_std": r.turn_std,
        "speed": r.fixed_point_speed,
        "turn_rate": r.fixed_point_turn,
        "residual": r.residual,
        "spread": r.spread,
        "contraction": r.contraction,
    }


def walker_table(
    sigmas: Sequence[float],
    taus: Sequence[float],
    Ts: Sequence[float],
    *,
    eps: float | None = None,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
    settings: MapSettings | None = None,
    jobs: int = 1,
) -> dict[str, Any]:
    """Tabulate the walker's map over ``sigma`` (forward) x ``tau`` (turn) x ``T``.

    The surrogate that ``control.hybrid_model = "walker"`` interpolates in (30)
    (:mod:`bipedtele.control.walker_map`, docs/walker_map.md). Every grid point is one
    :func:`walker_rho` (warm-up, the averaged fixed point, the central-difference radius of
    (26); the contraction only when ``settings.contraction``).

    Parameters
    ----------
    sigmas, taus : sequence of float
        Forward and turn real damping (cm/s and deg/s channels, the units of ``D``).
    Ts : sequence of float
        Walking cycles [s], each aligned (:func:`check_alignment`).
    eps : float, optional
        Joint servo time constant [s]; default the follower's operating point's (what (30)
        picks, ``eps_range[0]``).

    Returns
    -------
    dict
        ``format``, the axes ``sigma``, ``tau``, ``T``, ``eps``; per field (``rho``,
        ``limit_cycle``, ``fallen``, ``forward_std`` [cm/s], ``turn_std`` [deg/s],
        ``speed`` [cm/s], ``turn_rate`` [deg/s], ``residual``, ``spread``,
        ``contraction``) a nested list indexed ``[sigma][tau][T]``; ``settings`` (the
        operating conditions) and ``wall_s``.
    """
    import time

    control = control or ControlConfig()
    sim = sim or SimConfig()
    st = settings or MapSettings(contraction=False)
    if eps is None:
        eps = operating_point(control, sim, st.control_rate_hz)["eps"]
    for T in Ts:
        check_alignment(T, sim.physics_hz, st.control_rate_hz)
    axes = ([float(v) for v in sigmas], [float(v) for v in taus], [float(v) for v in Ts])
    for name, ax in zip(("sigma", "tau", "T"), axes, strict=True):
        if any(b <= a for a, b in itertools.pairwise(ax)):
            raise ConfigError(f"--{name} {ax}: allowed: strictly increasing values")
    # T-major last, largest T first in the queue: the slow points start early
    tasks = [(s, t, T, eps, control, sim, st) for s in axes[0] for t in axes[1] for T in axes[2]]
    order = sorted(range(len(tasks)), key=lambda i: -tasks[i][2])
    t0 = time.perf_counter()
    rows = _table_rows(tasks, order, jobs)
    ns, nt, n_t = (len(a) for a in axes)

    def field(key: str) -> list[list[list[Any]]]:
        return [[[rows[(i * nt + j) * n_t + k][key] for k in range(n_t)] for j in range(nt)] for i in range(ns)]

    keys = ("rho", "limit_cycle", "fallen", "forward_std", "turn_std", "speed", "turn_rate", "residual", "spread",
            "contraction")  # fmt: skip
    return {
        "format": TABLE_FORMAT,
        "sigma": axes[0],
        "tau": axes[1],
        "T": axes[2],
        "eps": float(eps),
        **{k: field(k) for k in keys},
        "settings": _table_settings(st, sim, control),
        "wall_s": time.perf_counter() - t0,
    }


def _table_rows(tasks: list[Any], order: list[int], jobs: int) -> list[dict[str, Any]]:
    """Run the table's points (in ``order``, on ``jobs`` processes); rows in the tasks' order."""
    rows: list[dict[str, Any]] = [{} for _ in tasks]
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs) as pool:
            for k, row in zip(order, pool.map(_table_point, [tasks[i] for i in order]), strict=True):
                rows[k] = row
                LOG.info("table: sigma %.2f tau %.2f T %.2f: rho %.3f%s", *tasks[k][:3], row["rho"],
                         " limit cycle" if row["limit_cycle"] else "")  # fmt: skip
    else:
        for k in order:
            rows[k] = _table_point(tasks[k])
            LOG.info("table: sigma %.2f tau %.2f T %.2f: rho %.3f", *tasks[k][:3], rows[k]["rho"])
    return rows


def _table_settings(st: MapSettings, sim: SimConfig, control: ControlConfig) -> dict[str, Any]:
    """Return the operating conditions a table was made under (stored with it)."""
    return {
        "v_ref": st.v_ref,
        "turn_ref": st.turn_ref,
        "foot": st.foot,
        "control_rate_hz": st.control_rate_hz,
        "lead_s": st.lead_s,
        "warmup_s": st.warmup_s,
        "average_cycles": st.average_cycles,
        "delta_scale": st.delta_scale,
        "physics_hz": sim.physics_hz,
        "D": list(control.D),
        "k_s": list(control.k_s),
        "k_z": list(control.k_z),
        "beta_r": list(control.beta_r),
    }


def plot_poincare(data: dict[str, Any]) -> Any:
    """Draw the Fig. 6 counterpart.

    ``rho_walker``, the walker's measured contraction and the reduced model's
    ``max|l_hybrid|`` (paper and speed loop) over ``sigma_r`` x ``T``; the plane at 1 marks
    the stability limit; the red dot is the follower's operating point (its ``sigma_r`` axis
    value is the forward channel's).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    pts = data["points"]
    sig = sorted({p["sigma_r"][0] for p in pts})
    Ts = sorted({p["T"] for p in pts})
    look = {(p["sigma_r"][0], p["T"]): p for p in pts}
    s, t = np.meshgrid(np.asarray(sig), np.asarray(Ts), indexing="ij")
    keys = (
        ("rho_walker", "3-D walker: radius of (26)"),
        ("contraction", "3-D walker: measured contraction"),
        ("rho_reduced", "reduced model, paper dp, k_v"),
        ("rho_reduced_speed_loop", "reduced model, speed loop"),
    )
    fig = Figure(figsize=(17.0, 4.4), layout="constrained")
    for i, (key, title) in enumerate(keys):
        ax = fig.add_subplot(1, len(keys), i + 1, projection="3d")
        z = np.array([[look[(a, b)][key] for b in Ts] for a in sig])
        if len(sig) > 1 and len(Ts) > 1:
            ax.plot_surface(s, t, z, cmap="viridis", linewidth=0, alpha=0.9)
            ax.plot_surface(s, t, np.ones_like(z), color="red", alpha=0.15, linewidth=0)
        ax.scatter(s.ravel(), t.ravel(), z.ravel(), color="k", s=8)
        if i < 2:
            op = data["operating_point"]
            ax.scatter([op["sigma_r"][0]], [op["T"]], [op[key]], color="red", s=30, label="operating point")
            ax.legend(fontsize=7)
        ax.set_xlabel("sigma_r")
        ax.set_ylabel("T [s]")
        ax.set_zlabel("spectral radius")
        ax.set_zlim(0.0, max(1.5, float(np.nanmax(z)) * 1.05))
        ax.set_title(title, fontsize=9)
    return fig


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{text!r}: allowed: comma-separated numbers") from None


def _run_table(args: argparse.Namespace, cfg: Any, sigmas: list[float], Ts: list[float], st: MapSettings) -> int:
    """``bipedtele poincare --table F``: tabulate the walker's map, write it, print its rows."""
    import json
    import sys
    from pathlib import Path

    taus = _floats(args.tau)
    if not taus or min(taus) < 0:
        raise ConfigError("--tau: allowed: a non-empty list, tau >= 0")
    sim = cfg.get(SimConfig)
    table = walker_table(sigmas, taus, Ts, control=cfg.get(ControlConfig), sim=sim, settings=st, jobs=args.jobs)
    table["command"] = (
        f"bipedtele poincare --table {args.table} --sigma {args.sigma} --tau {args.tau} --T {args.T} "
        f"--warmup {args.warmup:g} --delta-scale {args.delta_scale:g} --foot {args.foot} --jobs {args.jobs}"
    )
    try:
        Path(args.table).write_text(json.dumps(table, indent=1) + "\n", encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"--table {args.table}: cannot write ({exc.strerror})") from None
    sys.stdout.write("sigma  tau    T [s]  rho_walker  turn_std  forward_std  speed  turn_rate  limit_cycle\n")
    for i, sg in enumerate(table["sigma"]):
        for j, ta in enumerate(table["tau"]):
            for k, T in enumerate(table["T"]):
                f = {key: table[key][i][j][k] for key in ("rho", "turn_std", "forward_std", "speed", "turn_rate")}
                lc = "yes" if table["limit_cycle"][i][j][k] else "no"
                sys.stdout.write(
                    f"{sg:5.2f}  {ta:5.2f}  {T:5.2f}  {f['rho']:10.3f}  {f['turn_std']:8.2f}  "
                    f"{f['forward_std']:11.2f}  {f['speed']:5.2f}  {f['turn_rate']:9.2f}  {lc}\n"
                )
    sys.stdout.write(f"({table['wall_s']:.0f} s wall)\n")
    return 0


def _run(args: argparse.Namespace) -> int:
    import json
    import sys
    from pathlib import Path

    from bipedtele.cli import config_from_args

    cfg = config_from_args(args)
    sigmas, Ts = _floats(args.sigma), _floats(args.T)
    if args.newton < 0:
        raise ConfigError(f"--newton {args.newton}: allowed: >= 0")
    if not sigmas or not Ts or min(sigmas) < 0:
        raise ConfigError("--sigma/--T: allowed: non-empty lists, sigma >= 0")
    if args.jobs < 1:
        raise ConfigError(f"--jobs {args.jobs}: allowed: >= 1")
    if not args.warmup >= 5.0:
        raise ConfigError(f"--warmup {args.warmup}: allowed: >= 5 s")
    st = MapSettings(
        foot=args.foot,
        warmup_s=args.warmup,
        delta_scale=args.delta_scale,
        control_rate_hz=cfg.get(FollowerConfig).control_rate_hz,
        contraction=not args.table,
        newton_iterations=args.newton,
        torque=walker_torque(args.robot, cfg),
    )
    sim = cfg.get(SimConfig)
    for T in Ts:
        if not sim.cycle_min_s - 1e-9 <= T <= sim.cycle_max_s + 1e-9:
            raise ConfigError(
                f"--T {T:g}: allowed: the simulated NAO's cycle range [{sim.cycle_min_s:g}, {sim.cycle_max_s:g}] s"
            )
    if args.table:
        return _run_table(args, cfg, sigmas, Ts, st)
    data = poincare_grid(sigmas, Ts, control=cfg.get(ControlConfig), sim=sim, settings=st, jobs=args.jobs)
    if args.json:
        try:
            Path(args.json).write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"--json {args.json}: cannot write ({exc.strerror})") from None
    if args.plot:
        try:
            plot_poincare(data).savefig(args.plot, dpi=90)
        except OSError as exc:
            raise ConfigError(f"--plot {args.plot}: cannot write ({exc.strerror})") from None
    out = sys.stdout
    out.write(
        "sigma_r      T [s]  rho_walker  contraction  transient  rho_reduced  rho_speed_loop  speed [cm/s]  spread  "
        "turn_std  limit_cycle\n"
    )
    for p in [*data["points"], data["operating_point"]]:
        s = "/".join(f"{v:.2f}" for v in p["sigma_r"])
        out.write(
            f"{s:<12} {p['T']:5.2f}  {p['rho_walker']:10.3f}  {p['contraction']:11.3f}  {p['transient']:9.2f}  {p['rho_reduced']:11.3f}  "
            f"{p['rho_reduced_speed_loop']:14.3f}  {p['fixed_point_speed']:12.2f}  {p['spread']:6.1f}  "
            f"{p['turn_std']:8.2f}  {'yes' if p['limit_cycle'] else 'no'}\n"
        )
    out.write("(last row: the follower's operating point at zero delay)\n")
    nw = data["operating_point"].get("newton")
    if nw is not None:
        rho = ", ".join(f"{k}x: {v:.3f}" for k, v in nw["rho_by_scale"].items())
        out.write(
            f"operating point, Newton on P(x) = x: residual max {nw['residual_max'][0]:.3g} -> {nw['residual_max'][-1]:.3g}, "
            f"rms {nw['residual_rms'][0]:.3g} -> {nw['residual_rms'][-1]:.3g} (perturbation sizes, "
            f"{len(nw['steps'])} steps); radius of (26) at the fixed point by perturbation size {rho}\n"
        )
    return 0


def walker_torque(robot: str, cfg: Any) -> TorqueConfig | None:
    """``--robot``: None for the position walker (``sim``), the profile's ``[torque]`` for ``sim-torque``."""
    from bipedtele.config import resolve_section

    return resolve_section(cfg, TorqueConfig, "torque") if robot == "sim-torque" else None


def add_walker_arg(p: Any) -> None:
    """``--robot {sim,sim-torque}``: the simulated walker whose map is measured."""
    p.add_argument(
        "--robot",
        choices=["sim", "sim-torque"],
        default="sim",
        help="the position walker (sim, default) or the torque walker (sim-torque: the paper's joint law (15))",
    )


def add_poincare_parser(sub: Any) -> None:
    """``bipedtele poincare [--json F] [--plot F.png] [--sigma 0,2.5,5] [--T 0.8,1.2,1.6]``."""
    from bipedtele.cli import add_config_args

    p = sub.add_parser("poincare", help="the simulated walker's own Poincare map next to the reduced model's")
    p.add_argument("--sigma", default="0,2.5,5", help="real damping values, both channels (default 0,2.5,5)")
    p.add_argument(
        "--T",
        default="0.8,1.2,1.6",
        help="walking cycles [s]; T/2 on the control and physics grid (default 0.8,1.2,1.6)",
    )
    p.add_argument("--foot", choices=["L", "R"], default="L", help="foot whose touchdown is the section (default L)")
    p.add_argument("--warmup", type=float, default=30.0, help="walking time before the fixed point [s] (default 30)")
    p.add_argument(
        "--delta-scale", type=float, default=1.0, help="factor on the perturbation sizes of (26) (default 1)"
    )
    p.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    p.add_argument(
        "--tau",
        default="0,1.5,2.5,3,3.5,5",
        help="turn damping values of --table (default 0,1.5,2.5,3,3.5,5)",
    )
    p.add_argument(
        "--table",
        metavar="FILE",
        help="tabulate the walker's map over --sigma (forward) x --tau (turn) x --T into FILE, the surrogate of "
        'hybrid_model = "walker" (shipped: common/data/walker_map.json; docs/walker_map.md); no contraction runs',
    )
    p.add_argument(
        "--newton",
        type=int,
        default=0,
        metavar="N",
        help="at the operating point, solve P(x) = x by Newton (at most N Jacobians) and measure the radius there "
        "at 0.3/1/3x the perturbation sizes (default 0: off)",
    )
    p.add_argument("--json", metavar="FILE", help="write the points as JSON")
    p.add_argument("--plot", metavar="FILE.png", help="write the surfaces (Fig. 6 counterpart)")
    add_walker_arg(p)
    add_config_args(p)
    p.set_defaults(func=_run)
