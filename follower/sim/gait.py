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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from bipedtele.follower.sim.bezier import BezierFitter, evaluate, second_derivative
from bipedtele.follower.sim.model import NaoGeometry

__all__ = ["Gait", "GaitConfig", "Leg", "hip_speed", "hip_x", "ik_linear", "ik_sagittal", "p_hip_linear"]

Leg = Literal["L", "R"]
G = 9.81  # m/s^2

#: Fractions of the swing by which the swing foot has moved over its landing spot and has
#: come down [-]; the rest of the swing it holds still just above, then on, the floor.
_MOVE_DONE = 0.7
_LIFT_DONE = 0.85

# Index of each joint inside a leg's 6-vector.
YAW, ROLL, HIP, KNEE, ANKLE, AROLL = range(6)


def _leg_angles(
    leg_height_m: float, l1: float, l2: float, x: np.ndarray, lift: np.ndarray, y: np.ndarray, yaw: np.ndarray
) -> np.ndarray:
    """Return one leg's joint angles (yaw, roll, pitch, knee, ankle pitch, ankle roll) [rad] for its hip over its ankle.

    ``x``, ``y``: hip over ankle in the foot frame [m]; ``lift``: the foot above the floor [m].
    """
    hv = leg_height_m - lift
    roll = np.arctan2(-y, hv)
    hs = np.sqrt(y * y + hv * hv)
    th1, th2 = ik_sagittal(x, hs, l1, l2)
    return np.stack([yaw, roll, th1, th2 - th1, -th2, -roll], axis=1)


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
    """Eq. (8) linearised about straight legs: hip position over the ankle [m] from hip and knee pitch [rad].

    With the ankle at ``q_a = -(q_h + q_k)``: ``a1 (-q_a) + a2 (-q_a - q_k)``, a1 tibia, a2 thigh.
    About 10 % longer than the true :func:`hip_x` for the crouched walk (docs/follower.md).
    """
    q_a = -(q_hip + q_knee)
    return tibia * (-q_a) + thigh * (-q_a - q_knee)


def hip_x(q_hip: float, q_knee: float, thigh: float, tibia: float) -> float:
    """Hip position ahead of the ankle [m] in the leg's sagittal plane from hip and knee pitch [rad]."""
    return float(thigh * np.sin(q_hip) + tibia * np.sin(q_hip + q_knee))


def hip_speed(q_hip: float, q_knee: float, dq_hip: float, dq_knee: float, thigh: float, tibia: float) -> float:
    """Eq. (8) with its lever arms at the current posture: the hip's speed over the ankle [m/s].

    ``v_hip = a1 (-dq_a) + a2 (-dq_a - dq_k)`` with ``a1 = tibia cos(q_a)``,
    ``a2 = thigh cos(q_a + q_k)`` (``q_a = -(q_h + q_k)``): the linearisation of the hip
    position about the posture the leg is in, which is the exact time derivative of
    :func:`hip_x` (the paper leaves ``a1``, ``a2`` open; with the bare link lengths eq. (8)
    is linearised about straight legs and reads 10 % fast on NAO's crouched walk).
    """
    q_a = -(q_hip + q_knee)
    dq_a = -(dq_hip + dq_knee)
    return float(tibia * np.cos(q_a) * (-dq_a) + thigh * np.cos(q_a + q_knee) * (-dq_a - dq_knee))


def _cumtrapz(f: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Cumulative trapezoid integral of ``f`` over ``x``, starting at 0."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(x))])


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
    omega: float  # turn rate of this step [rad/s]


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
        """Return the 12 joint angles of standing [rad]: feet under the hips, knees bent."""
        l1, l2 = self.geom.thigh, self.geom.tibia
        th1, th2 = ik_sagittal(np.array(0.0), np.array(self.cfg.leg_height_m), l1, l2)
        leg = np.array([0.0, 0.0, float(th1), float(th2 - th1), float(-th2), 0.0])
        return np.concatenate([leg, leg])

    def max_forward(self, cycle_s: float) -> float:
        """Largest forward speed [m/s] at cycle time ``cycle_s`` [s] (step length bound)."""
        return 2.0 * self.cfg.max_step_m / cycle_s

    def max_turn(self, cycle_s: float) -> float:
        """Largest turn rate [rad/s] at cycle time ``cycle_s`` [s] (turn per step bound)."""
        return 2.0 * self.cfg.max_turn_step_rad / cycle_s

    def command(self, v: float, omega: float, cycle_s: float) -> None:
        """Walk at ``v`` [m/s] turning at ``omega`` [rad/s] with cycle ``cycle_s`` [s] from the next step.

        Zero speed and zero turn rate mean stop. Values are clamped to the gait's limits.
        """
        cycle_s = float(cycle_s)
        vmax = self.max_forward(cycle_s)
        wmax = self.max_turn(cycle_s)
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
        ph = next((p for p in self._phases if t < p.t0 + p.duration), self._phases[-1])
        q, qd = evaluate(ph.ctrl, (t - ph.t0) / ph.duration, ph.duration)
        return q, qd

    def acceleration(self) -> np.ndarray:
        """Joint reference accelerations [rad/s^2] (12,) at the time of the last :meth:`update`.

        The second derivative of the phase's Bezier curve; zero while standing. Phases join
        in position, so this jumps where one phase meets the next.
        """
        t = self._t
        if not self._phases:
            return np.zeros(12)
        ph = next((p for p in self._phases if t < p.t0 + p.duration), self._phases[-1])
        return second_derivative(ph.ctrl, (t - ph.t0) / ph.duration, ph.duration)

    @property
    def support(self) -> Literal["L", "R", "LR"]:
        """The feet the reference holds on the floor at the time of the last :meth:`update`.

        Both, except in the single support of a walking step, from lift-off until the swing
        foot has come down over its landing spot (the fraction ``_LIFT_DONE`` of the swing):
        then the stance leg alone. The phase variable is the time since the step began.
        """
        s = self._step
        if s is None or s.kind != "walk":
            return "LR"
        ts = s.cycle_s / 2.0
        t_ds = self.cfg.double_support * ts
        tau = self._t - s.t0
        return s.stance if t_ds <= tau < t_ds + _LIFT_DONE * (ts - t_ds) else "LR"

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
        if kind == "shift" or kind == "settle":
            v, omega = 0.0, 0.0
        ts = cycle / 2.0
        phi = cfg.double_support
        t_ds = phi * ts
        step = _Step(kind, stance, t0, cycle, v, omega * ts, omega)
        st = 0 if stance == "L" else 6
        sw = 6 - st
        swing: Leg = "R" if stance == "L" else "L"
        q0 = self._q
        sigma = 1.0 if stance == "L" else -1.0
        amp = 0.0 if kind == "settle" else 1.0
        y_nom0 = sigma * amp * float(cfg.sway(cycle, np.array(0.0)))
        dy0 = self._sway - y_nom0
        x_st0 = hip_x(q0[st + HIP], q0[st + KNEE], l1, l2)
        x_sw0 = hip_x(q0[sw + HIP], q0[sw + KNEE], l1, l2)
        settle_d = -(x_st0 + x_sw0) / 2.0

        def sway(tau: np.ndarray) -> np.ndarray:
            """Torso's lateral offset over the ankles, in the torso frame [m]."""
            nom = sigma * amp * cfg.sway(cycle, tau)
            return nom + dy0 * (1.0 - _smooth(tau / ts))

        # Feet on the ground, planned on a fine grid: the torso moves at v and turns at omega, so
        # each hip moves over its foot at (v -+ hip_offset_y omega, sway') in the torso frame;
        # the foot is turned by the hip yaw q from the torso, so in the foot's frame (where the
        # leg's roll and pitch act) that velocity is rotated by -q, and integrated.
        tau_f = np.linspace(0.0, ts, 241)
        y_t = sway(tau_f)
        dy_t = np.gradient(y_t, tau_f)

        def ground(o: int, leg: Leg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return self._ground(o, leg, kind, (v, omega), tau_f, dy_t, settle_d)

        gx_st, gy_st, gyaw_st = ground(st, stance)
        gx_sw, gy_sw, gyaw_sw = ground(sw, swing)

        def leg_angles(x: np.ndarray, lift: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> np.ndarray:
            return _leg_angles(cfg.leg_height_m, l1, l2, x, lift, y, yaw)

        def at(tau: np.ndarray, *series: np.ndarray) -> list[np.ndarray]:
            return [np.interp(tau, tau_f, f) for f in series]

        s = self._fit.s
        phases: list[_Phase] = []
        delta = np.zeros(12)
        t_sw = t_ds + _MOVE_DONE * (ts - t_ds)  # the swing foot has arrived over its landing spot
        segments = [(0.0, t_ds), (t_ds, t_sw), (t_sw, ts)] if t_ds > 1e-6 else [(0.0, t_sw), (t_sw, ts)]
        for a, b in segments:
            tau = a + s * (b - a)
            in_ss = a >= t_ds - 1e-9
            x, y, yaw = at(tau, gx_st, gy_st, gyaw_st)
            q_st = leg_angles(x, np.zeros_like(tau), y, yaw)
            if in_ss and kind == "walk":
                lift_off = [float(f[0]) for f in at(np.array([t_ds]), gx_sw, gy_sw, gyaw_sw)]
                q_sw = leg_angles(*self._swing(tau, swing, (v, omega), (ts, t_ds), lift_off, sway))
            else:
                x, y, yaw = at(tau, gx_sw, gy_sw, gyaw_sw)
                q_sw = leg_angles(x, np.zeros_like(tau), y, yaw)
            samples = np.zeros((len(s), 12))
            samples[:, st : st + 6] = q_st
            samples[:, sw : sw + 6] = q_sw
            if a == 0.0:  # join the previous reference exactly, spread the rest out
                delta = q0 - samples[0]
            samples += np.outer(1.0 - _smooth(tau / ts), delta)
            if phases:
                samples[0] = phases[-1].ctrl[-1]
            phases.append(_Phase(t0 + a, b - a, self._fit.fit(samples)))
        self._sway_end = float(sway(np.array(ts)))
        self._step, self._phases = step, phases

    def _ground(
        self,
        o: int,
        leg: Leg,
        kind: str,
        speed: tuple[float, float],
        tau_f: np.ndarray,
        dy_t: np.ndarray,
        settle_d: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Plan a foot on the ground: hip over ankle in its frame (x, y) [m] and hip yaw [rad] on ``tau_f`` [s].

        ``o``: the leg's first joint; ``speed``: the step's (v [m/s], omega [rad/s]);
        ``dy_t``: the torso's lateral speed on ``tau_f`` [m/s]; ``settle_d``: where a settle
        step brings the hip [m].
        """
        cfg, g, q0, prev = self.cfg, self.geom, self._q, self._step
        v, omega = speed
        ts = float(tau_f[-1])
        x0 = hip_x(q0[o + HIP], q0[o + KNEE], g.thigh, g.tibia)
        y0 = -cfg.leg_height_m * math.tan(q0[o + ROLL])
        yaw = q0[o + YAW] - omega * tau_f
        if kind == "settle":  # cubic Hermite in x: speed prev -> 0, hip to mid-feet
            v_prev = self._leg_speed(leg, prev.v, prev.omega) if prev is not None else 0.0
            sn = tau_f / ts
            vx = v_prev * (1 - 4 * sn + 3 * sn**2) + settle_d * (6 * sn - 6 * sn**2) / ts
        else:
            vx = np.full_like(tau_f, self._leg_speed(leg, v, omega))
        c, sn_q = np.cos(yaw), np.sin(yaw)
        vxf, vyf = vx * c + dy_t * sn_q, -vx * sn_q + dy_t * c
        return x0 + _cumtrapz(vxf, tau_f), y0 + _cumtrapz(vyf, tau_f), yaw

    def _swing(
        self,
        tau: np.ndarray,
        swing: Leg,
        speed: tuple[float, float],
        times: tuple[float, float],
        lift_off: list[float],
        sway: Callable[[np.ndarray], np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Plan the swing foot from lift-off to landing: hip over ankle x, lift, y [m] and yaw [rad] on ``tau``.

        ``speed``: (v [m/s], omega [rad/s]); ``times``: (half cycle ts, double support t_ds)
        [s]; ``lift_off``: x, y [m] and yaw [rad] at lift-off; ``sway``: the torso's lateral
        offset over the ankles [m].
        """
        cfg = self.cfg
        v, omega = speed
        ts, t_ds = times
        phi = cfg.double_support
        x_lo, y_lo, yaw_lo = lift_off
        # swing: hip-over-ankle x from lift-off to landing, Bezier in x, bump in z
        v_sw = self._leg_speed(swing, v, omega)
        d = ts - t_ds
        u = (tau - t_ds) / d
        # the swing leg leads: it lands its foot turned ahead of the torso by half the
        # turn of its coming contact, the hip at (x_td, sway) in the torso frame
        yaw_td = omega * ts * (1.0 + phi) / 2.0
        x_td_t, y_td_t = -v_sw * ts * (1.0 + phi) / 2.0, float(sway(np.array(ts)))
        x_td = x_td_t * math.cos(yaw_td) + y_td_t * math.sin(yaw_td)
        y_td = -x_td_t * math.sin(yaw_td) + y_td_t * math.cos(yaw_td)
        # the foot moves (forward, sideways, turning) by quintic smoothsteps while it is
        # up and is still over the floor before landing, so an early touchdown neither
        # drags nor spins it; the hip keeps moving over it at v_sw
        done = _smooth(u / _MOVE_DONE)
        x = x_lo + v_sw * d * u - (x_lo + v_sw * d - x_td) * done
        w = np.clip(u / _LIFT_DONE, 0.0, 1.0)
        lift = cfg.step_height_m * 16.0 * w**2 * (1 - w) ** 2
        y = sway(tau) + (y_lo - float(sway(np.array(t_ds)))) * (1.0 - done) + (y_td - y_td_t) * done
        # the swing leg leads: the foot's own yaw (hip yaw + torso yaw) turns ahead
        yaw = yaw_lo - omega * d * u + (yaw_td - yaw_lo + omega * d) * done
        return x, lift, y, yaw

    def _leg_speed(self, leg: Leg, v: float, omega: float) -> float:
        """Speed [m/s] of a hip over its planted foot when the torso moves at ``v`` turning at ``omega``."""
        side = 1.0 if leg == "L" else -1.0
        return v - side * self.geom.hip_offset_y * omega
