"""CP vs VP on the pybullet follower in simulated time (``bipedtele study --walker``).

The reduced study (:mod:`bipedtele.studies.study`) closes the loop on the reduced model
(20)-(23). Here the follower side is the real one: :class:`~bipedtele.follower.loop.FollowerLoop`
(delay estimate, (40), (30), the reference model (28) with the observer (12), the
equivalent follower (29)) driving the pybullet NAO (:class:`~bipedtele.follower.sim.robot.SimNao`,
no obstacles), stepped in simulated time with no real-time wait. The leader side, the
operator and the delays are the reduced study's: the same
:class:`~bipedtele.studies.study.SimulatedLeader`, the same delay models and, for equal seeds,
the same intentions and CP parameters (:func:`~bipedtele.studies.study.case_inputs`).

* The leader runs at the study's period (10 ms) and sends one :class:`Command` per period;
  a command sent at step ``k`` arrives ``ceil(h1/dt)`` steps later; the follower takes the
  newest arrived one (the loop's own intake: its h1 estimator, its age check).
* The follower ticks at ``follower.control_rate_hz`` and publishes a :class:`Feedback`
  per tick; it arrives ``ceil(h2/dt)`` leader steps later; the leader keeps the newest,
  estimates h2 with the 1 s moving average and reads h1 from the feedback, and schedules
  its damping by (40).
* CP: the run's constant ``sigma_r`` (uniform in ``s_r_range``) and ``T`` (uniform in the
  part of ``T_range`` the simulated NAO accepts, [0.8, 2] s by default), ``eps`` the
  configured value; the loop's (40) still sets ``sigma_e``. VP: the loop unchanged.
* ``follower.max_cmd_age_s`` is raised to the case's largest forward delay plus 0.5 s
  (the config's rule: above the worst delay), otherwise the long-delay cases would drop
  every command.

Reported per case and scheme, over the runs that did not fall: the time mean of
``|ref - eta|`` per follower tick, i.e. eqs. (6) and (10) with the reference the robot
applies and its measured v_hip (eq. 8) and turn rate, with 95 % CIs; the falls; VP's mean
``sigma_r`` and the mean cycle the robot applied.
"""

from __future__ import annotations

import dataclasses
import heapq
import logging
import math
import time
from typing import Any

import numpy as np
from bipedtele.config.profile import Config
from bipedtele.control.config import ControlConfig
from bipedtele.control.reduced import SimulatedLeader, StudyParams
from bipedtele.control.schemes import scheme_class
from bipedtele.control.schemes.runtime import LeaderPort, received
from bipedtele.follower.config import FollowerConfig
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.robot import SimNao
from bipedtele.follower.sim.torque_config import TorqueConfig
from bipedtele.follower.sim.world import WorldConfig
from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.messages import Command, Feedback, new_session_id
from bipedtele.studies.study import CASES, DelayCase, case_inputs
from scipy import stats

__all__ = ["WalkerRun", "run_walker_cli", "run_walker_study", "walker_run"]

LOG = logging.getLogger(__name__)


class _ConstantParameterLoop(FollowerLoop):
    """The follower loop with CP's constant ``(sigma_r, T, eps)``; (40) still sets sigma_e."""

    def __init__(self, *args: Any, cp: tuple[np.ndarray, float, float], **kwargs: Any) -> None:
        self._cp = cp
        super().__init__(*args, **kwargs)

    def _update_parameters(self, h1: float, h2: float) -> None:
        super()._update_parameters(h1, h2)
        s_r, T, eps = self._cp
        self._choice_s_r, self._T, self._eps = s_r.copy(), T, eps


@dataclasses.dataclass
class WalkerRun:
    """One closed-loop run on the walker."""

    forward_error: float
    turn_error: float
    fell: bool
    mean_T: float
    mean_s_r: list[float]
    ticks: int
    wall_s: float
    forward_intent_error: float = math.nan
    turn_intent_error: float = math.nan


def _arrivals(delays: np.ndarray, dt: float) -> np.ndarray:
    return np.arange(delays.size) + np.ceil(delays / dt - 1e-9).astype(int)


class _SchemeLeader:
    """The simulated operator and leader of one run, acting as the configured scheme does.

    The hand and handle are the reduced study's :class:`SimulatedLeader`; the damping and what
    the force follows come from the scheme (``control.scheme``) through the same
    :class:`~bipedtele.control.schemes.runtime.LeaderPort` the leader program uses, and each
    step it makes the command the leader would send.
    """

    def __init__(
        self,
        switch: np.ndarray,
        intent: np.ndarray,
        control: ControlConfig,
        params: StudyParams,
        worst: tuple[float, float],
    ) -> None:
        self.sim = SimulatedLeader(switch, intent, control, params)
        self.scheme = scheme_class(control.scheme)(control, worst)
        self.port = LeaderPort(self.scheme, np.asarray(control.k_m, dtype=float), control.wave_window_s)
        self.h2 = DelayEstimator(params.window_s)
        self.k_g = np.asarray(control.k_g, dtype=float)
        self.dt = params.dt
        self.sid = new_session_id()
        self.newest: tuple[int, Feedback, float] | None = None  # (sent at step, message, arrival [s])

    def intent_now(self) -> np.ndarray:
        """Return the operator's intended speeds now [cm/s, deg/s]."""
        return np.asarray(self.sim.intent[0, self.sim.seg[0]], dtype=float)

    def step(self, k: int, pending: list[tuple[int, int, Feedback]]) -> Command:
        """Take the feedback arrived by step ``k``, feel the newest, move the handle, return the command.

        ``pending`` is the heap of feedback in flight, ``(arrival step, sent step, message)``.
        """
        t = k * self.dt
        while pending and pending[0][0] <= k:
            ka, ks, msg = heapq.heappop(pending)
            self.h2.update(ks * self.dt, t)
            if self.newest is None or ks > self.newest[0]:
                self.newest = (ks, msg, ka * self.dt)
        fb = (self.newest[1], self.newest[2]) if self.newest is not None else None
        h1 = fb[0].h1_s if fb is not None else 0.0
        h2 = self.h2.value(t) or 0.0
        alpha_m, _ = self.scheme.damping(np.array([h1]), np.array([h2]))
        alpha = alpha_m[0]
        r_now = self.k_g * self.sim.x[0]
        if fb is None:
            z = np.zeros(2)
        else:
            m, t_recv = fb
            z = self.port.felt_speed(
                r_now,
                np.asarray(m.z_e),
                np.asarray(m.eta),
                received(m.wave),
                received(m.energy),
                m.t,
                t_recv,
                self.dt,
            )
        x = self.sim.step(t, z[None, :], alpha)[0]
        r_m = self.k_g * x
        wave, energy = self.port.outgoing(r_m)
        return Command(
            sid=self.sid,
            seq=k + 1,
            t=t,
            ref=[float(v) for v in r_m],
            x_m=[float(v) for v in x],
            h2_s=float(h2),
            alpha_m=[float(v) for v in alpha],
            enable=True,
            wave=wave,
            energy=energy,
        )


def walker_run(
    *,
    switch: np.ndarray,
    intent: np.ndarray,
    h1: np.ndarray,
    h2: np.ndarray,
    control: ControlConfig,
    follower: FollowerConfig,
    sim: SimConfig,
    params: StudyParams,
    cp: tuple[np.ndarray, float, float] | None,
    lost: tuple[np.ndarray, np.ndarray] | None = None,
    torque: TorqueConfig | None = None,
) -> WalkerRun:
    """Simulate one run (CP when ``cp = (sigma_r, T, eps)`` is given, VP otherwise).

    ``switch``/``intent`` are one run's operator intentions (shapes (1, n), (1, n, 2));
    ``h1``/``h2`` the one-way delay of a message sent at each leader step [s]; ``lost``
    marks the commands and the feedback messages lost on the way (none by default). Both
    sides run ``control.scheme`` (pd-worst-case sized for this run's largest delays).
    ``torque``: drive the torque walker (``--robot sim-torque``) with this ``[torque]``
    instead of the position walker.
    """
    t_wall = time.perf_counter()
    dt = params.dt
    k_steps = h1.size
    every = max(1, round(1.0 / (follower.control_rate_hz * dt)))
    fcfg = dataclasses.replace(
        follower, realtime=False, max_cmd_age_s=max(follower.max_cmd_age_s, float(h1.max()) + 0.5)
    )
    worst = (float(h1.max()), float(h2.max()))
    control = dataclasses.replace(control, worst_delays_s=list(worst))
    lost1, lost2 = lost if lost is not None else (np.zeros(k_steps, bool), np.zeros(k_steps, bool))
    clock = [0.0]
    arr1 = _arrivals(h1, dt)
    pending_cmd: list[tuple[int, int, Command]] = []
    pending_fb: list[tuple[int, int, Feedback]] = []
    latest_cmd: list[tuple[Command, float] | None] = [None]
    leader = _SchemeLeader(switch, intent, control, params, worst)
    step_now = [0]

    def publish(msg: Any) -> None:
        k = step_now[0]
        if isinstance(msg, Feedback) and not lost2[k]:
            heapq.heappush(pending_fb, (k + math.ceil(h2[k] / dt - 1e-9), k, msg))

    robot = SimNao(sim, world=WorldConfig()) if torque is None else _torque_nao(sim, torque)
    robot.connect()
    try:
        kwargs: dict[str, Any] = {"now": lambda: clock[0]}
        loop: FollowerLoop
        if cp is None:
            loop = FollowerLoop(
                robot, control, fcfg, command_inbox(fcfg, source=lambda: latest_cmd[0]), publish, **kwargs
            )
        else:
            inbox = command_inbox(fcfg, source=lambda: latest_cmd[0])
            loop = _ConstantParameterLoop(robot, control, fcfg, inbox, publish, cp=cp, **kwargs)
        acc = _Accumulator()
        newest_cmd_seq = -1
        for k in range(k_steps):
            t = k * dt
            clock[0] = t
            step_now[0] = k
            cmd = leader.step(k, pending_fb)
            if not lost1[k]:
                heapq.heappush(pending_cmd, (int(arr1[k]), k, cmd))
            while pending_cmd and pending_cmd[0][0] <= k:
                ka, ks, c = heapq.heappop(pending_cmd)
                if ks > newest_cmd_seq:
                    newest_cmd_seq = ks
                    latest_cmd[0] = (c, ka * dt)
            if k % every == 0:
                tel = loop.tick()
                robot.advance(loop.dt)
                acc.add(tel, leader.intent_now())
    finally:
        robot.disconnect()
    return acc.result(time.perf_counter() - t_wall)


def _torque_nao(sim: SimConfig, torque: TorqueConfig) -> SimNao:
    from bipedtele.follower.sim.torque_robot import TorqueNao

    return TorqueNao(sim, world=WorldConfig(), torque=torque)


class _Accumulator:
    """Per-tick sums of one walker run."""

    def __init__(self) -> None:
        self.err = np.zeros(2)
        self.intent_err = np.zeros(2)
        self.ticks = 0
        self.fell = False
        self.sum_T = 0.0
        self.n_walk = 0
        self.sum_sr = np.zeros(2)

    def add(self, tel: Any, intent: np.ndarray) -> None:
        eta = np.asarray(tel.eta_meas)
        self.ticks += 1
        self.err += np.abs(np.asarray(tel.ref) - eta)
        self.intent_err += np.abs(intent - eta)
        if tel.sent is not None:  # the cycle the robot applied while walking
            self.sum_T += tel.T
            self.n_walk += 1
        self.sum_sr += np.asarray(tel.s_r, dtype=float)
        self.fell = self.fell or tel.state == "fallen"

    def result(self, wall_s: float) -> WalkerRun:
        n = max(self.ticks, 1)
        mean_T = self.sum_T / self.n_walk if self.n_walk else math.nan
        return WalkerRun(
            float(self.err[0] / n),
            float(self.err[1] / n),
            self.fell,
            mean_T,
            (self.sum_sr / n).tolist(),
            self.ticks,
            wall_s,
            float(self.intent_err[0] / n),
            float(self.intent_err[1] / n),
        )


def _ci95(x: np.ndarray) -> tuple[float, list[float]]:
    if x.size == 0:
        return math.nan, [math.nan, math.nan]
    m = float(x.mean())
    if x.size < 2:
        return m, [m, m]
    half = float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return m, [m - half, m + half]


def _summary(rs: list[WalkerRun]) -> dict[str, Any]:
    ok = [r for r in rs if not r.fell]
    f, fci = _ci95(np.array([r.forward_error for r in ok]))
    t, tci = _ci95(np.array([r.turn_error for r in ok]))
    return {
        "forward_error": f,
        "forward_ci95": fci,
        "turn_error": t,
        "turn_ci95": tci,
        "falls": sum(r.fell for r in rs),
        "diverged": sum(r.fell for r in rs),
        "mean_T_s": float(np.mean([r.mean_T for r in rs])),
        "mean_s_r": np.mean([r.mean_s_r for r in rs], axis=0).tolist(),
        "runs": [dataclasses.asdict(r) for r in rs],
    }


def run_walker_study(
    control: ControlConfig,
    follower: FollowerConfig,
    sim: SimConfig,
    *,
    runs: int = 3,
    seed: int = 0,
    duration_s: float = 30.0,
    cases: tuple[DelayCase, ...] = CASES,
) -> dict[str, Any]:
    """CP and VP, ``runs`` each, per delay case, on the walker.

    Returns
    -------
    dict
        ``{"seed", "runs", "duration_s", "dt_s", "wall_s", "ticks_per_s", "cases": [...]}``,
        each case like the reduced study's (``forward_error``, ``forward_ci95``, ...), with
        ``falls`` and the per-run records.
    """
    params = StudyParams(duration_s=duration_s)
    t_lo = max(control.T_range[0], sim.cycle_min_s)
    t_hi = min(control.T_range[1], sim.cycle_max_s)
    t0 = time.perf_counter()
    ticks = 0
    out = []
    for case in cases:
        inp = case_inputs(case, runs, seed, control, params, T_bounds=(t_lo, t_hi))
        res: dict[str, list[WalkerRun]] = {"cp": [], "vp": []}
        for i in range(runs):
            common: dict[str, Any] = {
                "switch": inp.switch[i : i + 1],
                "intent": inp.intent[i : i + 1],
                "h1": inp.h1,
                "h2": inp.h2,
                "control": control,
                "follower": follower,
                "sim": sim,
                "params": params,
            }
            res["cp"].append(walker_run(cp=(inp.cp_s_r[i], float(inp.cp_T[i]), control.eps), **common))
            res["vp"].append(walker_run(cp=None, **common))
            ticks += res["cp"][-1].ticks + res["vp"][-1].ticks
            LOG.info(
                "walker study %s run %d: CP %.2f/%.2f VP %.2f/%.2f",
                case.name,
                i,
                res["cp"][-1].forward_error,
                res["cp"][-1].turn_error,
                res["vp"][-1].forward_error,
                res["vp"][-1].turn_error,
            )
        out.append(
            {
                "name": case.name,
                "h1_ms": 1e3 * float(inp.h1.mean()),
                "h2_ms": 1e3 * float(inp.h2.mean()),
                "description": case.description,
                "cp": _summary(res["cp"]),
                "vp": _summary(res["vp"]),
            }
        )
    wall = time.perf_counter() - t0
    return {
        "seed": seed,
        "runs": runs,
        "duration_s": duration_s,
        "dt_s": params.dt,
        "wall_s": wall,
        "ticks_per_s": ticks / wall if wall > 0 else math.nan,
        "cases": out,
    }


def run_walker_cli(cfg: Config, *, runs: int, seed: int, duration_s: float) -> dict[str, Any]:
    """Entry point of ``bipedtele study --walker`` (group ``bipedtele.study_backends``)."""
    return run_walker_study(
        cfg.get(ControlConfig), cfg.get(FollowerConfig), cfg.get(SimConfig), runs=runs, seed=seed, duration_s=duration_s
    )
