"""The simulated walker's turn limit-cycle onset and its command latency (issue 31, item 4).

Two measurements on the pybullet walker (:class:`~bipedtele.follower.sim.robot.SimNao`,
the clock-driven gait, the follower's servo (28)+(12) at 50 Hz), in simulated time:

Onset (:func:`constant_run`, :func:`find_onset`)
    From standing, the servo walks the robot under a constant reference (5 cm/s, 4 deg/s)
    with real damping ``[sigma, tau]`` for ``warmup_s``, then over ``cycles`` walking
    cycles (touchdown section to touchdown section, the window of
    :meth:`~bipedtele.follower.sim.poincare.WalkerMap.steady`) the per-tick measured
    speeds give ``forward_std`` [cm/s] and ``turn_std`` [deg/s]; ``limit_cycle`` is set when
    either exceeds its reference: the walker map's marker (docs/walker_map.md), same
    window, same threshold. The onset is the smallest turn damping ``tau`` with the
    marker set: a scan of ``tau`` brackets the first marked value, bisection narrows the
    bracket to ``resolution``.
Latency (:func:`step_latency`)
    Open loop (no servo): the robot walks at a constant command (5 cm/s, 4 deg/s); at one
    control tick the turn command steps by ``delta``. The latency is the lag of the
    accumulated torso yaw behind an ideal, immediate step: ``L = (t - t_s) - (psi_step(t) -
    psi_base(t)) / delta``, averaged over ``t`` in one whole walking cycle after the step
    has settled (so the within-step shape of the turn averages out), for a step at every
    control tick of one gait step (every phase). A pure delay ``L`` reads ``L`` at every
    phase; a command latched at step boundaries reads the wait until the next boundary
    plus whatever the robot adds. The per-tick turn rate of the baseline over a gait step,
    divided by its mean, is the within-step ``profile``.

Units: speeds cm/s and deg/s, times s, angles rad unless named ``_deg``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.follower.robot import WalkCommand
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.poincare import MapSettings, WalkerMap, check_alignment
from bipedtele.follower.sim.robot import SimNao
from bipedtele.follower.sim.world import WorldConfig

__all__ = [
    "OnsetResult",
    "OnsetSettings",
    "RunResult",
    "constant_run",
    "find_onset",
    "flip_growth",
    "oscillation_period",
    "step_latency",
    "step_means",
]

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class OnsetSettings:
    """What an onset run holds fixed.

    Attributes
    ----------
    sigma : float
        Forward damping (the walker map found the onset independent of it).
    eps : float
        Joint servo time constant [s] (what (30) picks: ``eps_range[0]``).
    v_ref, turn_ref : float
        Constant reference [cm/s, deg/s]; also the marker's thresholds.
    warmup_s : float
        Walking time from standing before the window [s].
    cycles : int
        Walking cycles in the window.
    control_rate_hz : float
        The servo's rate [Hz].
    """

    sigma: float = 0.0
    eps: float = 0.05
    v_ref: float = 5.0
    turn_ref: float = 4.0
    warmup_s: float = 60.0
    cycles: int = 8
    control_rate_hz: float = 50.0


@dataclass
class RunResult:
    """One constant-reference run.

    ``turn_std`` [deg/s] and ``forward_std`` [cm/s] over the window; ``turn_mean`` [deg/s];
    ``period_s`` the turn oscillation's period [s] (NaN without a limit cycle).
    """

    tau: float
    T: float
    turn_std: float
    forward_std: float
    turn_mean: float
    limit_cycle: bool
    fallen: bool
    period_s: float


@dataclass
class OnsetResult:
    """The onset at one ``T``: the last unmarked and first marked ``tau`` of the bracket."""

    T: float
    below: float
    above: float
    runs: list[RunResult] = field(default_factory=list)

    @property
    def width(self) -> float:
        """Bracket width in ``tau``."""
        return self.above - self.below

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        return {
            "T": self.T,
            "below": self.below,
            "above": self.above,
            "runs": [asdict(r) for r in sorted(self.runs, key=lambda r: r.tau)],
        }


def oscillation_period(x: np.ndarray, dt: float) -> float:
    """Mean period [s] of the oscillation of ``x`` about its mean, from its upward mean crossings.

    NaN with fewer than two upward crossings.
    """
    y = np.asarray(x, dtype=float) - float(np.mean(x))
    up = np.nonzero((y[:-1] < 0.0) & (y[1:] >= 0.0))[0]
    if up.size < 2:
        return math.nan
    # linear interpolation of each crossing inside its tick
    t = (up + (-y[up]) / (y[up + 1] - y[up])) * dt
    return float((t[-1] - t[0]) / (up.size - 1))


def constant_run(
    tau: float,
    T: float,
    settings: OnsetSettings | None = None,
    *,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
    start_tau: float | None = None,
) -> RunResult:
    """Walk from standing under the constant reference with turn damping ``tau``; the marker.

    The window is that of :meth:`WalkerMap.steady`: after ``warmup_s`` the walker runs to
    the next touchdown section of the left foot, then ``cycles`` more sections.
    ``start_tau``: the first half of the warm-up runs with this turn damping instead
    (to start ``tau`` from a limit cycle: a check for hysteresis).
    """
    st = settings or OnsetSettings()
    ms = MapSettings(
        v_ref=st.v_ref,
        turn_ref=st.turn_ref,
        control_rate_hz=st.control_rate_hz,
        warmup_s=st.warmup_s,
        average_cycles=st.cycles,
        contraction=False,
    )
    with WalkerMap([st.sigma, tau], T, st.eps, control=control, sim=sim, settings=ms) as m:
        sv = m.servo
        sv.tick()
        if start_tau is not None:
            sv.s_r[1] = start_tau
            sv.run(ms.warmup_s / 2.0)
            sv.s_r[1] = tau
            sv.run(ms.warmup_s / 2.0)
        else:
            sv.run(ms.warmup_s)
        sv.run_to_section(ms.foot, ms.lead_s)
        sv.trace = []
        for _ in range(ms.average_cycles):
            sv.run_to_section(ms.foot, ms.lead_s)
        speeds = np.array(sv.trace)
        sv.trace = None
        fallen = sv.fallen
    fwd_std, turn_std = (float(v) for v in speeds.std(axis=0))
    lc = fwd_std > st.v_ref or turn_std > st.turn_ref
    period = oscillation_period(speeds[:, 1], 1.0 / st.control_rate_hz) if lc else math.nan
    res = RunResult(
        tau=float(tau),
        T=float(T),
        turn_std=turn_std,
        forward_std=fwd_std,
        turn_mean=float(speeds[:, 1].mean()),
        limit_cycle=bool(lc),
        fallen=bool(fallen),
        period_s=period,
    )
    LOG.info(
        "T %.2f s tau %.3f: turn std %.2f deg/s, forward std %.2f cm/s, limit cycle %s, period %.2f s",
        T,
        tau,
        turn_std,
        fwd_std,
        lc,
        period,
    )
    return res


def find_onset(
    T: float,
    scan: list[float],
    resolution: float = 0.05,
    settings: OnsetSettings | None = None,
    **kw: Any,
) -> OnsetResult:
    """Bracket the smallest ``tau`` with a limit cycle at cycle time ``T`` [s].

    Runs every value of ``scan`` (ascending), takes the first marked value and the one
    before it as the bracket, then bisects it to at most ``resolution`` in ``tau``. Every
    run is kept in the result (the scan shows whether the marker is monotone in ``tau``).

    Raises
    ------
    ValueError
        When the first scan value is already marked or no value is.
    """
    taus = sorted(float(t) for t in scan)
    runs = [constant_run(t, T, settings, **kw) for t in taus]
    first = next((i for i, r in enumerate(runs) if r.limit_cycle), None)
    if first is None or first == 0:
        raise ValueError(
            f"T = {T:g} s: scan {taus}: the limit cycle {'never appears' if first is None else 'is already there'}"
        )
    lo, hi = taus[first - 1], taus[first]
    while hi - lo > resolution + 1e-9:
        mid = round(0.5 * (lo + hi), 6)
        r = constant_run(mid, T, settings, **kw)
        runs.append(r)
        if r.limit_cycle:
            hi = mid
        else:
            lo = mid
    return OnsetResult(float(T), lo, hi, runs)


def step_means(turn: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Mean of ``turn`` over each run of equal ``starts`` (one value per gait step, in order)."""
    edges = np.nonzero(np.diff(starts) != 0)[0] + 1
    return np.array([seg.mean() for seg in np.split(turn, edges)])


def _alternation(
    tau: float,
    T: float,
    st: OnsetSettings,
    seconds: float,
    start: tuple[float, float] | None,
    control: ControlConfig | None,
    sim: SimConfig | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Run the servo from standing; the step-to-step alternation ``|s_j - s_{j-1}| / 2`` [deg/s] and its times [s].

    ``start = (tau0, t0)``: turn damping ``tau0`` until ``t0`` [s], ``tau`` after; only steps
    that begin after ``t0`` are returned then.
    """
    ms = MapSettings(v_ref=st.v_ref, turn_ref=st.turn_ref, control_rate_hz=st.control_rate_hz, contraction=False)
    with WalkerMap(
        [st.sigma, tau if start is None else start[0]], T, st.eps, control=control, sim=sim, settings=ms
    ) as m:
        sv = m.servo
        sv.tick()
        turn, starts = [], []
        for k in range(round(seconds / sv.dt)):
            if start is not None and abs(k * sv.dt - start[1]) < 1e-9:
                sv.s_r[1] = tau
            sv.step()
            step = m.robot.gait.step
            if step is None or step[0] != "walk" or (start is not None and step[1] < start[1] - 1e-9):
                continue
            turn.append(sv.eta_meas[1])
            starts.append(step[1])
    st_arr = np.array(starts)
    s = step_means(np.array(turn), st_arr)
    return np.abs(np.diff(s)) / 2.0, np.unique(st_arr)[1:]


def flip_growth(
    tau: float,
    T: float,
    settings: OnsetSettings | None = None,
    *,
    seconds: float = 90.0,
    skip_s: float = 6.0,
    band: tuple[float, float] = (1.0, 5.0),
    start_tau: float | None = None,
    control: ControlConfig | None = None,
    sim: SimConfig | None = None,
) -> dict[str, Any]:
    """Growth per walking cycle of the step-to-step turn alternation (the flip mode), measured.

    The measured turn rate is averaged over every gait step (``s_j``); the alternation
    ``a_j = |s_j - s_{j-1}| / 2`` [deg/s] of a mode whose step-map eigenvalue is ``mu``
    (-1 at a flip) changes by ``|mu|`` per step. ``log a_j`` is fitted by a line over the
    steps with ``a_j`` inside ``band`` [deg/s]: above the gait's own step-to-step
    alternation (0.2-0.8 deg/s measured below the onset), below the servo's saturation
    (25 deg/s), so the loop is linear there. ``radius = |mu|^2``: growth per cycle.

    First from standing (``seconds`` of walking, steps after ``skip_s``, up to the first
    step above the band): a growing mode crosses the band. When fewer than 6 steps fall in
    the band, again from the limit cycle: ``start_tau`` (default ``tau + 1``) for 30 s,
    then ``tau``: a decaying mode crosses the band from above. NaN when neither gives 6
    steps.
    """
    st = settings or OnsetSettings()

    def fit(a: np.ndarray, t: np.ndarray, t_min: float, from_above: bool) -> tuple[float, int]:
        idx = np.nonzero(t >= t_min)[0]
        sel: list[int] = []
        for i in idx:
            if a[i] > band[1]:
                if from_above and not sel:
                    continue
                break
            if a[i] >= band[0]:
                sel.append(int(i))
            elif from_above and sel:
                break
        if len(sel) < 6:
            return math.nan, len(sel)
        slope = float(np.polyfit(t[sel], np.log(a[sel]), 1)[0])  # per second
        return math.exp(slope * T), len(sel)

    a, t = _alternation(tau, T, st, seconds, None, control, sim)
    radius, n = fit(a, t, skip_s, False)
    how = "from standing"
    if n < 6:
        t0 = round(30.0 / T) * T
        a, t = _alternation(tau, T, st, t0 + seconds, (tau + 1.0 if start_tau is None else start_tau, t0), control, sim)
        radius, n = fit(a, t, t0, True)
        how = "from the limit cycle"
    LOG.info("T %.2f s tau %.3f: flip growth per cycle %.4f over %d steps (%s)", T, tau, radius, n, how)
    return {"tau": float(tau), "T": float(T), "radius": radius, "steps_fitted": n, "start": how}


# --------------------------------------------------------------------------- latency


def _open_loop(
    T: float, sim: SimConfig, dt: float, n_ticks: int, turn: np.ndarray, v_cm_s: float, eps: float
) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Walk open loop with the per-tick turn command ``turn`` [deg/s]; unwrapped yaw, turn rates, step starts.

    Returns the torso yaw [rad] and the measured turn rate [deg/s] after every tick, and the
    start times [s] of the gait's walking steps.
    """
    robot = SimNao(sim, world=WorldConfig())
    robot.connect()
    try:
        yaw = np.empty(n_ticks)
        rate = np.empty(n_ticks)
        starts: list[float] = []
        last = None
        for k in range(n_ticks):
            robot.send_walk(
                WalkCommand(forward_m_s=v_cm_s / 100.0, turn_rad_s=math.radians(float(turn[k])), cycle_s=T, eps_s=eps)
            )
            robot.advance(dt)
            obs = robot.observe()
            step = robot.gait.step
            if step is not None and step[0] == "walk" and step[1] != last:
                last = step[1]
                starts.append(float(step[1]))
            yaw[k] = robot._yaw_unwrapped
            rate[k] = math.degrees(obs.turn_rate_rad_s)
        return yaw, rate, starts
    finally:
        robot.disconnect()


def step_latency(
    T: float,
    *,
    base: float = 4.0,
    delta: float = 4.0,
    v_cm_s: float = 5.0,
    eps: float = 0.05,
    settle_s: float = 10.0,
    after_cycles: int = 3,
    control_rate_hz: float = 50.0,
    stride: int = 1,
    sim: SimConfig | None = None,
) -> dict[str, Any]:
    """Measure the turn command's latency on the walker, open loop, at every phase of a step.

    Parameters
    ----------
    T : float
        Walking cycle [s].
    base, delta : float
        Turn command before the step and its increment [deg/s].
    v_cm_s : float
        Forward command [cm/s].
    settle_s : float
        Walking time before the first step time [s]; the step times are the control ticks
        of the gait step that starts first after it.
    after_cycles : int
        Whole walking cycles between the last step time and the averaging cycle.
    stride : int
        Step times every ``stride`` control ticks of the gait step (1: every tick).

    Returns
    -------
    dict
        ``latency_s`` per step time (list), their ``mean_s``, ``min_s``, ``max_s``,
        ``phase_s`` (each step time after the gait step's start [s]), ``profile`` (the
        baseline's per-tick turn rate over a gait step divided by its mean, averaged
        over the steps of the averaging window) and ``mean_rate_deg_s`` (the baseline's
        mean turn rate over whole cycles).
    """
    sim = sim or SimConfig()
    check_alignment(T, sim.physics_hz, control_rate_hz)
    dt = 1.0 / control_rate_hz
    h = T / 2.0
    per_step = round(h / dt)
    # the first walking step after settle_s: find it on a baseline run
    n_total = round((settle_s + 2 * T + (after_cycles + 1) * T + T) / dt)
    cmd = np.full(n_total, base)
    yaw_b, rate_b, starts = _open_loop(T, sim, dt, n_total, cmd, v_cm_s, eps)
    t0 = next(s for s in starts if s >= settle_s - 1e-9)
    k0 = round(t0 / dt)  # tick index whose end time is t0 is k0 - 1; the command sent after it
    win_a = k0 + per_step + after_cycles * round(T / dt)
    win = np.arange(win_a, win_a + round(T / dt))
    t_end = (win + 1) * dt  # the tick's yaw is read at the end of its period
    lat = []
    phase = []
    for j in range(0, per_step, stride):
        # the command of tick index k is sent at time k * dt, before the physics of [k dt, (k+1) dt)
        ks = k0 + j
        c = cmd.copy()
        c[ks:] = base + delta
        yaw_s, _, _ = _open_loop(T, sim, dt, n_total, c, v_cm_s, eps)
        t_s = ks * dt
        d_yaw = yaw_s[win] - yaw_b[win]
        lat.append(float(np.mean((t_end - t_s) - d_yaw / math.radians(delta))))
        phase.append(j * dt)
        LOG.info("T %.2f s: step %.2f s into the gait step: latency %.3f s", T, j * dt, lat[-1])
    # baseline profile over whole gait steps in the window
    seg = rate_b[win_a : win_a + 2 * per_step].reshape(2, per_step)
    settings = {
        "base_deg_s": base,
        "delta_deg_s": delta,
        "v_cm_s": v_cm_s,
        "eps_s": eps,
        "settle_s": settle_s,
        "after_cycles": after_cycles,
        "control_rate_hz": control_rate_hz,
    }
    return _latency_result(T, phase, lat, seg, settings)


def _latency_result(
    T: float, phase: list[float], lat: list[float], seg: np.ndarray, settings: dict[str, Any]
) -> dict[str, Any]:
    """Return :func:`step_latency`'s result from the latencies [s] and the baseline's per-tick turn rates ``seg``."""
    mean_rate = float(seg.mean())
    arr = np.array(lat)
    return {
        "T": float(T),
        "phase_s": phase,
        "latency_s": lat,
        "mean_s": float(arr.mean()),
        "min_s": float(arr.min()),
        "max_s": float(arr.max()),
        "profile": (seg.mean(axis=0) / mean_rate).tolist(),
        "mean_rate_deg_s": mean_rate,
        "settings": settings,
    }
