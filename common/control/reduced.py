"""The reduced closed loop's parts shared by the study and the scheme comparison.

The channel (one message per control period, newest-arrived kept, a moving-average delay
estimate), the real follower's speed dynamics between impacts (exact ZOH), the simulated
operator's hand on the leader device, and the Student-t interval. Vectorised over runs.
Units: forward channel cm/s, turn channel deg/s, times s, forces N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.linalg import mat2, zoh2
from scipy import stats

__all__ = ["Channel", "SimulatedLeader", "StudyParams", "channel", "ci95", "hybrid_zoh"]


@dataclass(frozen=True)
class StudyParams:
    """Simulation settings that are not controller parameters.

    Attributes
    ----------
    duration_s : float
        Simulated time per run [s].
    dt : float
        Control period [s].
    leader_mass_kg : float
        Effective moving mass of the handle [kg].
    force_max_n : float
        Device force limit [N].
    hand_k, hand_b, hand_f_max, hand_tau : float
        Operator hand stiffness [N/m], damping [N s/m], strength [N], target lag [s].
    intent_mean_s, intent_min_s : float
        Mean and minimum time between changes of the operator's intention [s].
    forward_range, turn_max : tuple / float
        Intended forward speeds [cm/s] (uniform) and turn speeds in +-turn_max [deg/s].
    window_s : float
        Delay-estimate moving-average window [s].
    diverge_limit : float
        A run whose speed exceeds this [cm/s or deg/s] or becomes non-finite has diverged.
    """

    duration_s: float = 60.0
    dt: float = 0.01
    leader_mass_kg: float = 0.15
    force_max_n: float = 8.0
    hand_k: float = 300.0
    hand_b: float = 8.0
    hand_f_max: float = 15.0
    hand_tau: float = 0.15
    intent_mean_s: float = 6.0
    intent_min_s: float = 1.0
    forward_range: tuple[float, float] = (1.0, 7.0)
    turn_max: float = 7.0
    window_s: float = 1.0
    diverge_limit: float = 1e4


@dataclass(frozen=True)
class Channel:
    """What a receiver sees of one direction of the link over ``K`` control periods.

    Attributes
    ----------
    idx : numpy.ndarray
        Index of the newest message arrived by step ``k`` (-1: none yet), shape (K,) or
        (runs, K).
    estimate : numpy.ndarray
        The receiver's moving-average delay estimate at step ``k`` [s], shape as ``idx``.
    mean_s : float
        Mean one-way delay of the messages sent [s].
    ring : int
        Ring-buffer length that covers every lag [steps].
    lost : int
        Messages lost on the way.
    """

    idx: np.ndarray  # newest message index arrived by step k (-1: none yet)
    estimate: np.ndarray  # moving-average delay estimate at step k [s]
    mean_s: float
    ring: int  # ring-buffer length that covers every lag
    lost: int = 0


def channel(delays: np.ndarray, dt: float, window_s: float, lost: np.ndarray | None = None) -> Channel:
    """Arrivals and delay estimate of one message per period sent with ``delays`` [s].

    A message sent at step ``n`` arrives ``ceil(delays[n] / dt)`` steps later unless
    ``lost[n]``; the receiver keeps the newest message arrived (an older one arriving
    later is dropped, as the real transport does) and estimates the delay as the mean of
    the delays received in the last ``window_s`` [s], holding its last value across gaps.

    ``delays`` (and ``lost``) of shape ``(runs, K)`` give every run its own channel: ``idx``
    and ``estimate`` then have shape ``(runs, K)``, ``ring`` covers every run's lags,
    ``mean_s`` is the mean over all runs and ``lost`` counts every run's losses.
    """
    delays = np.asarray(delays, dtype=float)
    if delays.ndim == 2:
        rows = [channel(delays[i], dt, window_s, None if lost is None else lost[i]) for i in range(delays.shape[0])]
        return Channel(
            idx=np.stack([c.idx for c in rows]),
            estimate=np.stack([c.estimate for c in rows]),
            mean_s=float(delays.mean()),
            ring=max(c.ring for c in rows),
            lost=sum(c.lost for c in rows),
        )
    k_steps = delays.shape[0]
    n = np.arange(k_steps)
    arrive = n + np.ceil(delays / dt - 1e-9).astype(int)
    newest = np.full(k_steps, -1)
    ok = arrive < k_steps
    if lost is not None:
        ok &= ~lost
    np.maximum.at(newest, arrive[ok], n[ok])
    newest = np.maximum.accumulate(newest)
    lag = np.where(newest >= 0, n - newest, 0)
    # moving average over arrival time of the delays received in (t - window, t]
    w = max(1, round(window_s / dt))
    sums = np.bincount(arrive[ok], weights=delays[ok], minlength=k_steps)[:k_steps]
    counts = np.bincount(arrive[ok], minlength=k_steps)[:k_steps].astype(float)
    cs, cc = np.cumsum(sums), np.cumsum(counts)
    ws = cs - np.concatenate([np.zeros(w), cs[:-w]])
    wc = cc - np.concatenate([np.zeros(w), cc[:-w]])
    est = np.where(wc > 0, ws / np.maximum(wc, 1.0), np.nan)
    # before the first arrival: the receiver knows nothing; hold the first estimate
    first = np.flatnonzero(~np.isnan(est))
    est = np.where(np.isnan(est), est[first[0]] if first.size else 0.0, est)
    # gaps longer than the window: hold the last estimate
    est = _ffill(np.where(wc > 0, est, np.nan))
    lost_n = 0 if lost is None else int(lost.sum())
    return Channel(idx=newest, estimate=est, mean_s=float(delays.mean()), ring=int(lag.max()) + 2, lost=lost_n)


def _ffill(a: np.ndarray) -> np.ndarray:
    idx = np.where(~np.isnan(a), np.arange(a.size), 0)
    np.maximum.accumulate(idx, out=idx)
    out = a[idx]
    return np.where(np.isnan(out), np.nanmean(a) if np.any(~np.isnan(a)) else 0.0, out)


def hybrid_zoh(s_r: np.ndarray, cfg: ControlConfig, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-run ZOH of the real follower speed dynamics ``[eta, z_r]`` per channel.

    ``D eta' = k_s (ref - eta) - sigma_r (eta - z_r)/beta_r``, ``z_r' = (eta - z_r)/beta_r``.
    ``s_r`` has shape (n, 2); returns ``Phi`` (n, 2, 2, 2) and ``Gamma`` (n, 2, 2).
    """
    d = np.asarray(cfg.D, dtype=float)
    k = np.asarray(cfg.k_s, dtype=float)
    b = np.asarray(cfg.beta_r, dtype=float)
    s = np.asarray(s_r, dtype=float)
    a = mat2(-k / d - s / (d * b), s / (d * b), 1.0 / b + 0.0 * s, -1.0 / b + 0.0 * s)
    bm = np.zeros((*s.shape, 2, 1))
    bm[..., 0, 0] = k / d
    phi, gam = zoh2(a, bm, dt)
    return phi, gam[..., 0]


def ci95(x: np.ndarray) -> tuple[float, list[float]]:
    """Mean and Student-t 95 % interval ``[lo, hi]`` of the finite values of ``x``."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    n = x.size
    if n == 0:
        return math.nan, [math.nan, math.nan]
    m = float(x.mean())
    if n < 2:
        return m, [m, m]
    half = float(stats.t.ppf(0.975, n - 1) * x.std(ddof=1) / math.sqrt(n))
    return m, [m - half, m + half]


class SimulatedLeader:
    """The simulated operator's hand on the leader device, vectorised over runs.

    The operator intends the speeds ``intent`` (switching at the times ``switch``); the
    intention ``ref / k_g`` is smoothed (``hand_tau``) and a PD hand pulls the handle. The
    handle (1) moves under the hand and the leader force (31) clamped to ``force_max_n``,
    damping terms implicit.

    Parameters
    ----------
    switch, intent : numpy.ndarray
        As :class:`CaseInputs` (``n`` runs).
    cfg : ControlConfig
        ``k_g``, ``k_m``.
    params : StudyParams
        Hand, handle and period.
    """

    def __init__(self, switch: np.ndarray, intent: np.ndarray, cfg: ControlConfig, params: StudyParams) -> None:
        self.switch, self.intent, self.params = switch, intent, params
        n = switch.shape[0]
        self.n_seg = switch.shape[1] - 1
        self.k_g = np.asarray(cfg.k_g, dtype=float)
        self.k_m = np.asarray(cfg.k_m, dtype=float)
        self.a_hand = 1.0 - math.exp(-params.dt / params.hand_tau)
        self.rows = np.arange(n)
        self.x = np.zeros((n, 2))
        self.v = np.zeros((n, 2))
        self.x_d = np.zeros((n, 2))
        self.seg = np.zeros(n, dtype=int)
        self.f_m = np.zeros((n, 2))
        self.f_h = np.zeros((n, 2))
        #: Time the operator lets go of the handle [s] (never, by default).
        self.release_t = math.inf

    def step(self, t: float, z_rx: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """Advance one period at time ``t`` [s]; return the handle position ``x_m`` [m].

        ``z_rx`` is the received ``z_e``, ``alpha`` the leader damping [N s/m]. From
        :attr:`release_t` [s] on the operator has let go: no hand force.
        """
        p, dt, m = self.params, self.params.dt, self.params.leader_mass_kg
        hand_k, hand_b = (p.hand_k, p.hand_b) if t < self.release_t else (0.0, 0.0)
        adv = self.switch[self.rows, np.minimum(self.seg + 1, self.n_seg)] <= t
        self.seg = np.where(adv, np.minimum(self.seg + 1, self.n_seg), self.seg)
        target = self.intent[self.rows, self.seg] / self.k_g
        self.x_d += (target - self.x_d) * self.a_hand
        x, v = self.x, self.v
        spring = -self.k_m * (self.k_g * x - z_rx)
        hand_pos = hand_k * (self.x_d - x)
        v_new = (v + dt / m * (spring + hand_pos)) / (1.0 + dt * (alpha + hand_b) / m)
        f_m = spring - alpha * v_new
        f_h = hand_pos - hand_b * v_new
        clamp_m = np.abs(f_m) > p.force_max_n
        clamp_h = np.abs(f_h) > p.hand_f_max
        if clamp_m.any() or clamp_h.any():
            # saturated forces are constant over the step; unsaturated damping stays implicit
            denom = 1.0 + dt * (np.where(clamp_m, 0.0, alpha) + np.where(clamp_h, 0.0, hand_b)) / m
            num = v + dt / m * (
                np.where(clamp_m, np.sign(f_m) * p.force_max_n, spring)
                + np.where(clamp_h, np.sign(f_h) * p.hand_f_max, hand_pos)
            )
            v_new = num / denom
            f_m = np.where(clamp_m, np.sign(f_m) * p.force_max_n, spring - alpha * v_new)
            f_h = np.where(clamp_h, np.sign(f_h) * p.hand_f_max, hand_pos - hand_b * v_new)
        self.f_m = f_m
        self.f_h = f_h
        self.v = v_new
        self.x = x + dt * v_new
        return self.x
