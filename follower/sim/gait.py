"""The walking gait of the simulated NAO (paper Sec. 3.1, Fig. 5), pure numpy.

A walking cycle of length ``T`` has two steps of ``T/2``. Each step starts at an impact
(the swing foot lands and becomes the new stance leg), spends the fraction ``phi`` in
double support, then lifts the other leg and swings it forward (single support).

Per leg, the joint references of every phase are **Bezier curves** (degree 5) whose
control points are fitted to the inverse kinematics of the planned motion at the start of
the phase, end points pinned so phases join without jumps:

- a leg on the ground advances the *linearised* hip position of eq. (8),
  ``p_hip = a1 (-q_a) + a2 (-q_a - q_k)`` (a1 tibia, a2 thigh), at the commanded speed
  ``v``, at constant hip height; so eq. (8) on the reference gives ``v_hip = v`` exactly;
- the swing leg lifts the foot by ``step_height`` (NAO StepHeight 0.02 m) and lands it
  ``S (1 + phi) / 2`` ahead of the hip, ``S = v T / 2`` being the step length, so the
  two legs repeat the same pattern half a cycle apart (the paper's phase shift);
- ankles keep the feet parallel to the upright torso: ``q_a = -(q_h + q_k)``, ankle roll
  ``= -`` hip roll;
- lateral sway by hip and ankle roll moves the torso over the stance foot: the periodic
  linear-inverted-pendulum motion whose zero-moment point rests on the stance foot in
  single support and crosses over in double support (:meth:`GaitConfig.sway`), so the
  sway matches any cycle time ``T``;
- turning (Fig. 5): the stance leg's hip yaw moves by half the cycle's turn during single
  support (from ``+Delta/2`` to ``-Delta/2``, ``Delta = omega T / 2``) while the swing leg's
  hip yaw pre-rotates the landing foot; in double support the yaws hold.

Commands (speed, turn rate, cycle time) are latched at step boundaries. Stopping finishes
the current step, then one settling step (both feet down) brings the hip between the feet
and the sway to zero: standing within one cycle of the request.

Joint order: :data:`bipedtele.follower.sim.model.LEG_JOINTS` of the left leg, then the
right leg (12 angles) [rad].
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from bipedtele.follower.sim.bezier import BezierFitter, evaluate
from bipedtele.follower.sim.model import NaoGeometry

__all__ = ["Gait", "GaitConfig", "Leg", "ik_linear", "ik_sagittal", "p_hip_linear"]

Leg = Literal["L", "R"]
G = 9.81  # m/s^2

# Index of each joint inside a leg's 6-vector.
YAW, ROLL, HIP, KNEE, ANKLE, AROLL = range(6)


@dataclass(frozen=True)
class GaitConfig:
    """Gait shape.

    Attributes
    ----------
    leg_height_m : float
        Vertical hip-to-ankle distance while walking [m] (straight leg: 0.2029 m).
    step_height_m : float
        Swing-foot clearance [m] (NAO StepHeight).
    double_support : float
        phi: fraction of the cycle with both feet down (0..0.6).
    max_step_m : float
        Largest step length [m] (NAO MaxStepX); bounds ``|v| <= 2 max_step / T``.
    max_turn_step_rad : float
        Largest turn per step [rad].
    com_height_m : float
        Pendulum height for the sway amplitude [m].
    zmp_y_m : float
        Lateral distance from the mid line the zero-moment point should reach [m].
    sway_com_ratio : float
        Centre-of-mass shift per torso shift (the feet do not move) [-].
    """

    leg_height_m: float = 0.185
    step_height_m: float = 0.02
    double_support: float = 0.3
    max_step_m: float = 0.04
    max_turn_step_rad: float = math.radians(20.0)
    com_height_m: float = 0.26
    zmp_y_m: float = 0.045
    sway_com_ratio: float = 0.85

    def sway(self, cycle_s: float, tau: np.ndarray) -> np.ndarray:
        """Torso sway [m] (to the left) at time ``tau`` [s] after the start of a left-stance step.

        The periodic solution of the linear inverted pendulum ``y'' = w^2 (y - p)``,
        ``w^2 = g / z_c``, for a zero-moment point ``p`` that stays at ``+zmp_y`` during left
        single support, at ``-zmp_y`` during right single support and moves linearly in
        double support (harmonic by harmonic: ``Y_k = P_k / (1 + (k 2 pi / T)^2 / w^2)``),
        divided by :attr:`sway_com_ratio`. A right-stance step uses the negative.
        """
        coef = _sway_fourier(round(cycle_s, 6), self.double_support, self.zmp_y_m, self.com_height_m)
        k = np.arange(1, len(coef) + 1)
        ang = 2.0 * np.pi * np.outer(np.asarray(tau, float).ravel(), k) / cycle_s
        y = (np.cos(ang) * coef.real - np.sin(ang) * coef.imag).sum(axis=1)
        return (y / self.sway_com_ratio).reshape(np.shape(tau))


@functools.lru_cache(maxsize=64)
def _sway_fourier(cycle_s: float, phi: float, zmp_y: float, com_h: float) -> np.ndarray:
    """Complex Fourier coefficients (harmonics 1..15, doubled) of the pendulum's periodic sway [m]."""
    n = 512
    t = np.arange(n) / n  # fraction of the cycle, left-stance step first
    ds = phi / 2.0
    p = np.where(t < 0.5, 1.0, -1.0)
    p = np.where(t < ds, -1.0 + 2.0 * t / ds, p)
    p = np.where((t >= 0.5) & (t < 0.5 + ds), 1.0 - 2.0 * (t - 0.5) / ds, p)
    spec = np.fft.rfft(zmp_y * p) / n * 2.0
    k = np.arange(1, 16)
    w2 = G / com_h
    return spec[1:16] / (1.0 + (2.0 * np.pi * k / cycle_s) ** 2 / w2)


def ik_sagittal(x: np.ndarray, h: np.ndarray, l1: float, l2: float) -> tuple[np.ndarray, np.ndarray]:
    """Thigh and tibia angles from vertical [rad] putting the hip at ``x`` ahead of and ``h`` above the ankle [m].

    ``l1`` thigh, ``l2`` tibia [m]. The knee bends forward (tibia angle > thigh angle).
    """
    r2 = x * x + h * h
    c = np.clip((l1 * l1 + l2 * l2 - r2) / (2 * l1 * l2), -1.0, 1.0)
    knee = math.pi - np.arccos(c)
    beta = np.arctan2(l2 * np.sin(knee), l1 + l2 * np.cos(knee))
    th1 = np.arctan2(x, h) - beta
    return th1, th1 + knee


def ik_linear(p: np.ndarray, h: np.ndarray, l1: float, l2: float) -> tuple[np.ndarray, np.ndarray]:
    """Thigh and tibia angles [rad] with linearised hip position ``l1 th1 + l2 th2 = p`` and height ``h`` [m]."""
    th1, th2 = ik_sagittal(np.asarray(p, float), np.asarray(h, float), l1, l2)
    for _ in range(6):  # Newton on (l1 th1 + l2 th2 - p, l1 cos th1 + l2 cos th2 - h)
        f1 = l1 * th1 + l2 * th2 - p
        f2 = l1 * np.cos(th1) + l2 * np.cos(th2) - h
        det = l1 * l2 * (np.sin(th1) - np.sin(th2))
        d1 = (-l2 * np.sin(th2) * f1 - l2 * f2) / det
        d2 = (l1 * np.sin(th1) * f1 + l1 * f2) / det
        th1, th2 = th1 - d1, th2 - d2
    return th1, th2


def p_hip_linear(q_hip: float, q_knee: float, thigh: float, tibia: float) -> float:
    """Eq. (8): linearised hip position over the ankle [m] from hip and knee pitch [rad].

    With the ankle at ``q_a = -(q_h + q_k)``: ``a1 (-q_a) + a2 (-q_a - q_k)``, a1 tibia, a2 thigh.
    """
    q_a = -(q_hip + q_knee)
    return tibia * (-q_a) + thigh * (-q_a - q_knee)


def _smooth(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


@dataclass
class _Phase:
    t0: float
    duration: float
    ctrl: np.ndarray  # (degree + 1, 12)


@dataclass
class _Step:
    kind: Literal["walk", "shift", "settle"]
    stance: Leg
    t0: float
    cycle_s: float
    v: float
    turn: float  # turn of this step [rad]


class Gait:
    """Joint references for walking, turning, starting and stopping.

    Parameters
    ----------
    config : GaitConfig
        Gait shape.
    geom : NaoGeometry
        Leg lengths.
    """

    def __init__(self, config: GaitConfig | None = None, geom: NaoGeometry | None = None) -> None:
        self.cfg = config or GaitConfig()
        self.geom = geom or NaoGeometry()
        self._fit = BezierFitter(5, 12)
        self._cmd = (0.0, 0.0, 1.0)  # v [m/s], omega [rad/s], T [s]
        self._stop = True
        self._t = 0.0
        self._q = self.standing_pose()
        self._sway = 0.0
        self._step: _Step | None = None
        self._phases: list[_Phase] = []
        self._last_stance: Leg = "R"

    # ------------------------------------------------------------------ public API

    def standing_pose(self) -> np.ndarray:
        """The 12 joint angles of standing [rad]: feet under the hips, knees bent."""
        l1, l2 = self.geom.thigh, self.geom.tibia
        th1, th2 = ik_linear(np.array(0.0), np.array(self.cfg.leg_height_m), l1, l2)
        leg = np.array([0.0, 0.0, float(th1), float(th2 - th1), float(-th2), 0.0])
        return np.concatenate([leg, leg])

    def max_forward(self, cycle_s: float) -> float:
        """Largest forward speed [m/s] at cycle time ``cycle_s`` [s] (step length bound)."""
        return 2.0 * self.cfg.max_step_m / cycle_s

    def command(self, v: float, omega: float, cycle_s: float) -> None:
        """Walk at ``v`` [m/s] turning at ``omega`` [rad/s] with cycle ``cycle_s`` [s] from the next step.

        Zero speed and zero turn rate mean stop. Values are clamped to the gait's limits.
        """
        cycle_s = float(cycle_s)
        vmax = self.max_forward(cycle_s)
        wmax = 2.0 * self.cfg.max_turn_step_rad / cycle_s
        v = float(np.clip(v, -vmax, vmax))
        omega = float(np.clip(omega, -wmax, wmax))
        self._cmd = (v, omega, cycle_s)
        self._stop = abs(v) < 1e-4 and abs(omega) < 1e-4

    def stop(self) -> None:
        """Finish the current step, then settle and stand."""
        self._cmd = (0.0, 0.0, self._cmd[2])
        self._stop = True

    def reset(self, t: float) -> None:
        """Stand still at time ``t`` [s]."""
        self._t = t
        self._q = self.standing_pose()
        self._sway = 0.0
        self._step = None
        self._phases = []
        self._stop = True
        self._cmd = (0.0, 0.0, self._cmd[2])

    @property
    def walking(self) -> bool:
        """True while stepping (false once standing)."""
        return self._step is not None

    @property
    def stance(self) -> Leg:
        """The stance leg: the leg that landed last (switches at impact)."""
        return self._step.stance if self._step is not None else self._last_stance

    @property
    def step(self) -> tuple[str, float, float, float] | None:
        """Current step: kind, start time [s], speed [m/s], turn [rad]; None when standing."""
        s = self._step
        return None if s is None else (s.kind, s.t0, s.v, s.turn)

    @property
    def cycle_s(self) -> float:
        """Cycle time of the current step (or the commanded one when standing) [s]."""
        return self._step.cycle_s if self._step is not None else self._cmd[2]

    def update(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint references and their rates at time ``t`` [s] (non-decreasing).

        Returns
        -------
        q : ndarray (12,)
            Joint angles [rad].
        qd : ndarray (12,)
            Joint speeds [rad/s].
        """
        self._t = t
        if self._step is None and not self._stop:
            self._plan_step("shift", "L", t)
        while self._phases and t >= self._phases[-1].t0 + self._phases[-1].duration:
            self._end_step(self._phases[-1].t0 + self._phases[-1].duration)
        if not self._phases:
            return self._q.copy(), np.zeros(12)
        ph = self._phases[0] if t < self._phases[0].t0 + self._phases[0].duration else self._phases[-1]
        q, qd = evaluate(ph.ctrl, (t - ph.t0) / ph.duration, ph.duration)
        return q, qd

    # ------------------------------------------------------------------ planning

    def _end_step(self, t_end: float) -> None:
        step = self._step
        assert step is not None
        self._q = self._phases[-1].ctrl[-1].copy()
        self._sway = self._sway_end
        self._last_stance = step.stance
        swing: Leg = "R" if step.stance == "L" else "L"
        if step.kind == "settle":
            self._step, self._phases = None, []
            if not self._stop:
                self._plan_step("shift", "L", t_end)
        elif self._stop:
            self._plan_step("settle", swing if step.kind == "walk" else step.stance, t_end)
        else:
            self._plan_step("walk", swing, t_end)

    def _plan_step(self, kind: Literal["walk", "shift", "settle"], stance: Leg, t0: float) -> None:
        cfg, g = self.cfg, self.geom
        l1, l2 = g.thigh, g.tibia
        v, omega, cycle = self._cmd
        prev_v = self._step.v if self._step is not None else 0.0
        if kind == "shift" or kind == "settle":
            v, turn = 0.0, 0.0
        else:
            turn = omega * cycle / 2.0
        ts = cycle / 2.0
        phi = cfg.double_support
        t_ds = phi * ts
        step = _Step(kind, stance, t0, cycle, v, turn)
        st = 0 if stance == "L" else 6
        sw = 6 - st
        q0 = self._q
        sigma = 1.0 if stance == "L" else -1.0
        amp = 0.0 if kind == "settle" else 1.0
        y_nom0 = sigma * amp * float(cfg.sway(cycle, np.array(0.0)))
        dy0 = self._sway - y_nom0
        p_st0 = p_hip_linear(q0[st + HIP], q0[st + KNEE], l1, l2)
        p_sw0 = p_hip_linear(q0[sw + HIP], q0[sw + KNEE], l1, l2)
        yaw_st0, yaw_sw0 = q0[st + YAW], q0[sw + YAW]
        settle_d = -(p_st0 + p_sw0) / 2.0

        def sway(tau: np.ndarray) -> np.ndarray:
            nom = sigma * amp * cfg.sway(cycle, tau)
            return nom + dy0 * (1.0 - _smooth(tau / ts))

        def ground_p(p0: float, tau: np.ndarray) -> np.ndarray:
            if kind == "settle":  # cubic Hermite: speed prev_v -> 0, hip to mid-feet
                s = tau / ts
                h10, h01 = s - 2 * s**2 + s**3, 3 * s**2 - 2 * s**3
                return p0 + prev_v * ts * h10 + settle_d * h01
            return p0 + v * tau

        def leg_angles(p_or_x: np.ndarray, lift: np.ndarray, y: np.ndarray, yaw: np.ndarray,
                       linear: bool) -> np.ndarray:
            hv = cfg.leg_height_m - lift
            roll = np.arctan2(-y, hv)
            hs = np.sqrt(y * y + hv * hv)
            th1, th2 = (ik_linear if linear else ik_sagittal)(p_or_x, hs, l1, l2)
            return np.stack([yaw, roll, th1, th2 - th1, -th2, -roll], axis=1)

        s = self._fit.s
        phases: list[_Phase] = []
        delta = np.zeros(12)
        segments = [(0.0, t_ds), (t_ds, ts)] if t_ds > 1e-6 else [(0.0, ts)]
        for a, b in segments:
            tau = a + s * (b - a)
            y = sway(tau)
            in_ss = a >= t_ds - 1e-9
            # stance leg: on the ground all step; yaw turns during single support
            yaw_st_end = -turn / 2.0 if kind == "walk" else yaw_st0
            f_yaw = _smooth((tau - t_ds) / (ts - t_ds)) if in_ss else np.zeros_like(tau)
            q_st = leg_angles(ground_p(p_st0, tau), np.zeros_like(tau), y,
                              yaw_st0 + (yaw_st_end - yaw_st0) * f_yaw, linear=True)
            if in_ss and kind == "walk":
                # swing: hip-over-ankle x from lift-off to landing, Bezier in x, bump in z
                th1, th2 = ik_linear(np.array(ground_p(p_sw0, np.array(a))), np.array(cfg.leg_height_m), l1, l2)
                x_lo = float(l1 * np.sin(th1) + l2 * np.sin(th2))
                x_td = -v * ts * (1.0 + phi) / 2.0
                d = b - a
                u = s
                cx = np.array([x_lo, x_lo + v * d / 3.0, x_td - v * d / 3.0, x_td])
                x = ((1 - u) ** 3 * cx[0] + 3 * (1 - u) ** 2 * u * cx[1]
                     + 3 * (1 - u) * u**2 * cx[2] + u**3 * cx[3])
                lift = cfg.step_height_m * 16.0 * u**2 * (1 - u) ** 2
                yaw_sw = yaw_sw0 + (turn / 2.0 - yaw_sw0) * _smooth(u)
                q_sw = leg_angles(x, lift, y, yaw_sw, linear=False)
            else:
                q_sw = leg_angles(ground_p(p_sw0, tau), np.zeros_like(tau), y,
                                  np.full_like(tau, yaw_sw0), linear=True)
            samples = np.zeros((len(s), 12))
            samples[:, st:st + 6] = q_st
            samples[:, sw:sw + 6] = q_sw
            if a == 0.0:  # join the previous reference exactly, spread the rest out
                delta = q0 - samples[0]
            samples += np.outer(1.0 - _smooth(tau / ts), delta)
            if phases:
                samples[0] = phases[-1].ctrl[-1]
            phases.append(_Phase(t0 + a, b - a, self._fit.fit(samples)))
        self._sway_end = float(sway(np.array(ts)))
        self._step, self._phases = step, phases
