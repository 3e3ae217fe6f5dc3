r"""Stability margin of the released handle: critical delays, decay rates, and how conservative (40) is.

The loop, per channel, once the operator lets go of the handle (no hand force): the handle
(mass ``m``) feels the leader force (31) from the delayed equivalent follower (29), which
is driven by the delayed handle position::

    m x'' = -k_m (k_g x - z_e(t - h2)) - alpha_m x'
    D beta_e z_e'' + (D + sigma_e) z_e' + k_s z_e = k_s k_g x(t - h1)

For constant delays only the round trip ``h = h1 + h2`` matters; the characteristic
equation is ``P(s) - K G(s) e^{-s h} = 0`` with ``P(s) = m s^2 + alpha_m s + K``,
``K = k_m k_g`` [N/m] and ``G(s) = k_s / (D beta_e s^2 + (D + sigma_e) s + k_s)``
(``G(0) = 1``: ``s = 0`` is always a root, the released handle may rest anywhere; the margin
is about the other roots, i.e. the handle's speed).

- **Small-gain (delay-independent) test**: if ``|K G(jw)| < |P(jw)|`` for every ``w > 0``
  and the loop is stable at ``h = 0``, no root crosses the imaginary axis for any constant
  delay: stable for every constant delay (:func:`small_gain_holds`).
- **Critical constant delay** (:func:`critical_delay`): the smallest ``h`` at which a root
  reaches ``jw``: at each ``w`` where ``|P(jw)| = |K G(jw)|``, ``h = (-arg(P/(K G)) mod 2 pi)/w``.
- **(40)'s boundary**: the damping (40) asks for, ``alpha_m = K (h1 + h2/4)`` (margin 0).
- **Bisection under time-varying delays** (:func:`critical_scale`): the released handle
  simulated (semi-implicit Euler, ``dt`` 2 ms) with delays that jitter and drift; the
  critical mean delay is the smallest at which the handle's speed grows, found by
  bisection, and the *decay rate* is the slope of the log RMS speed over the run's second
  half [1/s] (negative: it settles).

Units: forward channel cm/s and m (``k_g`` (cm/s)/m), turn channel deg/s; forces N;
damping N s/m; delays s. See docs/schemes.md (The stability-margin map).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.damping import schedule_damping_array
from bipedtele.control.schemes import factorial
from scipy.optimize import brentq

__all__ = [
    "RULES",
    "DelayProcess",
    "LoopParams",
    "critical_delay",
    "critical_scale",
    "decay_rates",
    "ratio_alpha",
    "rule_damping",
    "small_gain_holds",
]

#: Damping rules of the map: the floor, a fixed damping ratio, (40) scheduled on the
#: delays, (40) for the run's largest delays held.
RULES: tuple[str, ...] = ("floor", "ratio", "scheduled", "worst-case")
#: Damping ratio of the ``ratio`` rule (the comparison's ``ratio`` damping's).
FIXED_RATIO = factorial.FIXED_RATIO


@dataclass(frozen=True)
class LoopParams:
    """One channel of the released-handle loop (module docstring).

    Attributes
    ----------
    m : float
        Handle mass [kg].
    k_m : float
        Leader gain [N per (cm/s) or N per (deg/s)].
    k_g : float
        Handle position to speed [(cm/s)/m or (deg/s)/m].
    D, k_s, beta_e : float
        The equivalent follower's mass (or inertia), gain and filter time constant [s].
    sigma_e : float
        Its damping (same unit as ``D``).
    alpha : float
        Leader damping [N s/m].
    """

    m: float
    k_m: float
    k_g: float
    D: float
    k_s: float
    beta_e: float
    sigma_e: float
    alpha: float

    @property
    def K(self) -> float:
        """Handle position stiffness ``k_m k_g`` [N/m]."""
        return self.k_m * self.k_g

    @classmethod
    def from_config(cls, cfg: ControlConfig, channel: int, mass_kg: float, sigma_e: float, alpha: float) -> LoopParams:
        """Return the loop of ``channel`` (0 forward, 1 turn) with the configured gains."""
        return cls(
            mass_kg,
            cfg.k_m[channel],
            cfg.k_g[channel],
            cfg.D[channel],
            cfg.k_s[channel],
            cfg.beta_e[channel],
            float(sigma_e),
            float(alpha),
        )


def _p_and_q(p: LoopParams, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = 1j * w
    return p.m * s * s + p.alpha * s + p.K, p.K * p.k_s / (p.D * p.beta_e * s * s + (p.D + p.sigma_e) * s + p.k_s)


def _stable_without_delay(p: LoopParams) -> bool:
    # (m s^2 + a s + K)(D b s^2 + (D + sig) s + k_s) - K k_s = s * cubic: the cubic Hurwitz
    poly = np.polymul([p.m, p.alpha, p.K], [p.D * p.beta_e, p.D + p.sigma_e, p.k_s])
    poly[-1] -= p.K * p.k_s
    roots = np.roots(poly[:-1])  # the constant term is 0: divide by s
    return bool(np.all(roots.real < 0.0))


_W = np.logspace(-4, 4, 20001)


def small_gain_holds(p: LoopParams) -> bool:
    """Return whether ``|K G(jw)| < |P(jw)|`` for every ``w > 0`` (on a log grid 1e-4..1e4 rad/s) and the loop is stable at ``h = 0``."""
    pw, qw = _p_and_q(p, _W)
    return _stable_without_delay(p) and bool(np.all(np.abs(qw) < np.abs(pw)))


def critical_delay(p: LoopParams) -> float:
    """Return the smallest constant round-trip delay [s] at which a root reaches the imaginary axis.

    ``inf`` when no frequency has ``|P(jw)| = |K G(jw)|`` (stable for every constant
    delay, if stable at 0); ``0.0`` when the loop is unstable without delay.
    """
    if not _stable_without_delay(p):
        return 0.0

    def f(w: float) -> float:
        pw, qw = _p_and_q(p, np.asarray([w]))
        return float(np.abs(pw[0]) ** 2 - np.abs(qw[0]) ** 2)

    pw, qw = _p_and_q(p, _W)
    g = np.abs(pw) ** 2 - np.abs(qw) ** 2
    best = math.inf
    for i in np.flatnonzero(np.sign(g[:-1]) != np.sign(g[1:])):
        w = brentq(f, _W[i], _W[i + 1], xtol=1e-12)
        ratio = _p_and_q(p, np.asarray([w]))
        phase = -np.angle(ratio[0][0] / ratio[1][0])  # e^{-j w h} = P / (K G)
        best = min(best, float(np.mod(phase, 2.0 * math.pi)) / w)
    return best


@dataclass(frozen=True)
class DelayProcess:
    """Round-trip delay over time, split equally between the two directions.

    ``h(t) = mean + jitter * u_k + drift(t)``, ``u_k`` uniform in [-1, 1] held for 20 ms
    (one message's delay), ``drift`` a triangle wave of slope ``+-rate`` between
    ``-mean/2`` and ``+mean/2`` (dT/dt); never below 0.

    Attributes
    ----------
    mean : float
        Mean round-trip delay [s].
    jitter : float
        Jitter amplitude [s].
    rate : float
        Slope of the drift, dT/dt [s/s] (0: none).
    """

    mean: float
    jitter: float = 0.0
    rate: float = 0.0

    def sample(self, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Return ``h(t)`` [s] at the times ``t`` [s]."""
        u = rng.uniform(-1.0, 1.0, int(t[-1] / 0.02) + 2)[(t / 0.02).astype(int)]
        drift = np.zeros_like(t)
        if self.rate > 0.0 and self.mean > 0.0:
            period = 2.0 * self.mean / self.rate  # up by mean, down by mean
            phase = np.mod(t, period) / period
            drift = self.mean * (np.where(phase < 0.5, 2.0 * phase, 2.0 - 2.0 * phase) - 0.5)
        return np.asarray(np.maximum(0.0, self.mean + self.jitter * u + drift), dtype=float)


def ratio_alpha(k_pos: np.ndarray | float, mass_kg: float) -> np.ndarray:
    """Return the leader damping [N s/m] that gives the handle the damping ratio :data:`FIXED_RATIO`."""
    return factorial.ratio_damping(k_pos, mass_kg, FIXED_RATIO)


def rule_damping(
    rule: str, cfg: ControlConfig, h1: np.ndarray, h2: np.ndarray, mass_kg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(alpha_m, sigma_e)`` of a damping rule for delays ``h1``, ``h2`` [s], each shaped ``(..., 2)``.

    ``floor``: the configured lower bounds; ``ratio``: a handle damping ratio of
    :data:`FIXED_RATIO`, ``sigma_e`` at its floor; ``scheduled``: (40) on the delays as they
    are; ``worst-case``: (40) on the largest delays of the array's last axis but one, held.

    Raises
    ------
    ValueError
        An unknown rule.
    """
    shape = np.broadcast_shapes(np.shape(h1), np.shape(h2))
    k_pos = np.asarray(cfg.k_m, dtype=float) * np.asarray(cfg.k_g, dtype=float)
    if rule == "floor":
        return np.full((*shape, 2), cfg.alpha_m_min), np.full((*shape, 2), cfg.s_e_min)
    if rule == "ratio":
        return np.broadcast_to(ratio_alpha(k_pos, mass_kg), (*shape, 2)), np.full((*shape, 2), cfg.s_e_min)
    if rule == "scheduled":
        a, s, _, _ = schedule_damping_array(np.ravel(h1), np.ravel(h2), cfg)
        return a.reshape(*shape, 2), s.reshape(*shape, 2)
    if rule == "worst-case":
        w1 = np.broadcast_to(np.max(h1, axis=-1, keepdims=True), shape)
        w2 = np.broadcast_to(np.max(h2, axis=-1, keepdims=True), shape)
        return rule_damping("scheduled", cfg, w1, w2, mass_kg)
    raise ValueError(f"rule = {rule!r}: allowed: {', '.join(RULES)}")


def decay_rates(
    params: list[LoopParams],
    h: np.ndarray,
    dt: float,
    alpha: np.ndarray | None = None,
    sigma_e: np.ndarray | None = None,
    v0: float = 0.05,
) -> np.ndarray:
    """Simulate released handles and return each one's speed decay rate [1/s].

    Parameters
    ----------
    params : list of LoopParams
        One loop per run (``n`` runs).
    h : numpy.ndarray
        Round-trip delay of each run at each step, shape ``(n, steps)`` [s] (half each way).
    dt : float
        Step [s].
    alpha, sigma_e : numpy.ndarray, optional
        Damping of each run at each step ``(n, steps)`` (default: each loop's own, held).
    v0 : float
        The handle's initial speed [m/s] (the operator lets go of a moving handle).

    Returns
    -------
    numpy.ndarray
        Slope of the log of the peak RMS speed (0.5 s windows) per round trip, after the
        first [1/s]: negative settles, positive grows (:func:`_log_slopes`). The run should
        last several round trips.
    """
    n, steps = h.shape
    col = {
        f: np.asarray([getattr(p, f) for p in params], dtype=float) for f in ("m", "k_m", "k_g", "D", "k_s", "beta_e")
    }
    k_pos = col["k_m"] * col["k_g"]
    alpha = np.repeat(np.asarray([p.alpha for p in params])[:, None], steps, 1) if alpha is None else alpha
    sigma_e = np.repeat(np.asarray([p.sigma_e for p in params])[:, None], steps, 1) if sigma_e is None else sigma_e
    lag = np.rint(0.5 * h / dt).astype(int)  # each direction carries half the round trip
    ring = int(lag.max()) + 2
    xs, zs = np.zeros((ring, n)), np.zeros((ring, n))
    x, v, eta, z = np.zeros(n), np.full(n, v0), np.zeros(n), np.zeros(n)
    rows = np.arange(n)
    win = max(1, round(0.5 / dt))
    sq = np.zeros((steps // win, n))
    for k in range(steps):
        xs[k % ring] = x
        zs[k % ring] = z
        ref = col["k_g"] * xs[(k - lag[:, k]) % ring, rows]
        z_rx = zs[(k - lag[:, k]) % ring, rows]
        # the equivalent follower (29): D eta' = k_s (ref - z) - sigma (eta - z)/beta, z' = (eta - z)/beta
        dz = (eta - z) / col["beta_e"]
        eta = eta + dt * (col["k_s"] * (ref - z) - sigma_e[:, k] * dz) / col["D"]
        z = z + dt * dz
        # the handle, damping implicit: m v' = -K x + k_m z_rx - alpha v
        a_k = alpha[:, k]
        v = (v + dt / col["m"] * (-k_pos * x + col["k_m"] * z_rx)) / (1.0 + dt * a_k / col["m"])
        x = x + dt * v
        if k // win < sq.shape[0]:
            sq[k // win] += v * v
    seg = np.maximum(1.0, h.mean(axis=1))  # a round trip: an echo returns once per segment
    return _log_slopes(np.sqrt(sq / win), win * dt, seg, floor=1e-10 * v0)


def _log_slopes(rms: np.ndarray, window_s: float, segment_s: np.ndarray, floor: float) -> np.ndarray:
    """Slope of the log of the peak RMS speed per round trip, per run (columns) [1/s].

    The released handle's motion returns as an echo once per round trip, so a stable loop
    may show a rising RMS within one; the peak over each round trip (``segment_s``) falls
    when it settles and rises when it grows. The fit covers the segments after the first;
    segments whose peak is at the floor (round-off: settled) end it.
    """
    n_win, n = rms.shape
    out = np.empty(n)
    for j in range(n):
        per = max(1, round(segment_s[j] / window_s))
        peaks = np.asarray([rms[i : i + per, j].max() for i in range(0, n_win - per + 1, per)])
        above = np.flatnonzero(peaks > floor)
        end = int(above[-1]) + 1 if above.size else 0
        start = 1 if end >= 3 else 0
        if end - start < 2:
            out[j] = -math.inf  # settled within the first round trip
            continue
        t = np.arange(start, end) * per * window_s
        y = np.log(peaks[start:end])
        tc = t - t.mean()
        out[j] = float((tc * (y - y.mean())).sum() / (tc * tc).sum())
    return out


def critical_scale(
    base: list[LoopParams],
    processes: list[DelayProcess],
    rules: list[str] | None,
    cfg: ControlConfig,
    *,
    channels: list[int] | None = None,
    hi: float = 8.0,
    iters: int = 12,
    duration_s: float = 30.0,
    dt: float = 0.002,
    seed: int = 0,
) -> np.ndarray:
    """Return the critical mean round-trip delay [s] of each case, by bisection (``inf``: none up to ``hi``).

    Case ``i`` is the loop ``base[i]`` under the delay process ``processes[i]`` with its
    ``mean`` (and ``jitter``) replaced by ``scale`` times themselves... exactly: the mean is
    the bisection variable, jitter and drift rate kept; unstable when the released handle's
    speed grows (:func:`decay_rates` > 0). ``rules[i]`` (optional) sets the damping from the
    delays each step (:func:`rule_damping`, for the channel ``channels[i]`` of ``cfg``,
    forward by default); None keeps each loop's own.
    """
    n = len(base)
    lo_v, hi_v = np.zeros(n), np.full(n, float(hi))
    duration_s = max(duration_s, 6.0 * hi)  # several round trips at the longest delay
    steps = round(duration_s / dt)
    t = np.arange(steps) * dt

    def unstable(means: np.ndarray) -> np.ndarray:
        rng = np.random.default_rng(seed)
        h = np.stack([replace(pr, mean=float(mu)).sample(t, rng) for pr, mu in zip(processes, means, strict=True)])
        alpha = sigma = None
        if rules is not None:
            alpha, sigma = np.zeros((n, steps)), np.zeros((n, steps))
            for i, rule in enumerate(rules):
                ch = 0 if channels is None else channels[i]
                a, s = rule_damping(rule, cfg, 0.5 * h[i][None, :], 0.5 * h[i][None, :], base[i].m)
                alpha[i], sigma[i] = a[0, :, ch], s[0, :, ch]
        return decay_rates(base, h, dt, alpha, sigma) > 0.0

    top = unstable(hi_v)
    for _ in range(iters):
        mid = 0.5 * (lo_v + hi_v)
        bad = unstable(mid)
        hi_v = np.where(bad, mid, hi_v)
        lo_v = np.where(bad, lo_v, mid)
    return np.where(top, hi_v, math.inf)


#: The map's delay variants: (jitter [s], dT/dt [s/s]) and their labels.
VARIANTS: tuple[tuple[str, float, float], ...] = (
    ("constant", 0.0, 0.0),
    ("jitter 0.2 s", 0.2, 0.0),
    ("drift 0.5 s/s", 0.0, 0.5),
)
CHANNELS: tuple[str, ...] = ("forward", "turn")


def _finite(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def _decay_grid(
    cfg: ControlConfig, mass_kg: float, means: list[float], alphas: list[float], duration_s: float, dt: float, seed: int
) -> dict[str, list[list[list[float | None]]]]:
    """Decay rates [1/s] per variant, channel, damping and mean delay (sigma_e at its floor)."""
    steps = round(max(duration_s, 6.0 * max([*means, 1.0])) / dt)
    t = np.arange(steps) * dt
    loops, procs = [], []
    for ch in range(2):
        for a in alphas:
            for mu in means:
                for _, jit, rate in VARIANTS:
                    loops.append(LoopParams.from_config(cfg, ch, mass_kg, cfg.s_e_min, a))
                    procs.append(DelayProcess(mu, jit, rate))
    rng = np.random.default_rng(seed)
    rates = decay_rates(loops, np.stack([pr.sample(t, rng) for pr in procs]), dt)
    shaped = rates.reshape(2, len(alphas), len(means), len(VARIANTS))
    return {
        label: [
            [
                [_finite(shaped[ch, i, j, v]) if shaped[ch, i, j, v] > -math.inf else None for j in range(len(means))]
                for i in range(len(alphas))
            ]
            for ch in range(2)
        ]
        for v, (label, _, _) in enumerate(VARIANTS)
    }


def margin_map(
    cfg: ControlConfig,
    mass_kg: float = 0.15,
    means: tuple[float, ...] = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0),
    alphas: tuple[float, ...] = (0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 40.0),
    *,
    hi: float = 8.0,
    iters: int = 10,
    duration_s: float = 30.0,
    dt: float = 0.002,
    seed: int = 0,
) -> dict[str, object]:
    """Return the stability-margin map of the released handle (module docstring) as a JSON-ready map.

    Per channel: the small-gain verdict and the analytic critical constant delay for each
    damping in ``alphas`` (``sigma_e`` at its floor); (40)'s damping for each mean delay
    (margin 0 and the configured one); the decay rate over ``alphas`` x ``means`` for each
    delay variant (:data:`VARIANTS`); and, per damping rule and variant, the critical mean
    round-trip delay by bisection (None: none up to ``hi``).
    """
    k_pos = np.asarray(cfg.k_m, dtype=float) * np.asarray(cfg.k_g, dtype=float)
    mu = np.asarray(means, dtype=float)
    channels = []
    for ch, name in enumerate(CHANNELS):
        loops = [LoopParams.from_config(cfg, ch, mass_kg, cfg.s_e_min, a) for a in alphas]
        channels.append(
            {
                "name": name,
                "K_n_per_m": float(k_pos[ch]),
                "alpha_floor": cfg.alpha_m_min,
                "alpha_ratio": float(ratio_alpha(k_pos[ch], mass_kg)),
                "small_gain": [small_gain_holds(p) for p in loops],
                "critical_constant_delay_s": [_finite(critical_delay(p)) for p in loops],
                "alpha_40": [float(v) for v in k_pos[ch] * (0.5 * mu + 0.125 * mu)],
                "alpha_40_margin": [float(v) for v in (1.0 + cfg.margin) * k_pos[ch] * (0.5 * mu + 0.125 * mu)],
            }
        )
    decay = _decay_grid(cfg, mass_kg, list(means), list(alphas), duration_s, dt, seed)
    base, procs, rules, keys = [], [], [], []
    for ch in range(2):
        for rule in RULES:
            for label, jit, rate in VARIANTS:
                base.append(LoopParams.from_config(cfg, ch, mass_kg, cfg.s_e_min, cfg.alpha_m_min))
                procs.append(DelayProcess(1.0, jit, rate))
                rules.append(rule)
                keys.append((ch, rule, label))
    crit = critical_scale(
        base,
        procs,
        rules,
        cfg,
        channels=[k[0] for k in keys],
        hi=hi,
        iters=iters,
        duration_s=duration_s,
        dt=dt,
        seed=seed,
    )
    for c in channels:
        c["decay_per_s"] = {label: decay[label][CHANNELS.index(str(c["name"]))] for label in decay}
        c["critical_mean_delay_s"] = {rule: {} for rule in RULES}
    for (ch, rule, label), v in zip(keys, crit, strict=True):
        channels[ch]["critical_mean_delay_s"][rule][label] = _finite(float(v))  # type: ignore[index]
    return {
        "model": {
            "mass_kg": mass_kg,
            "sigma_e": cfg.s_e_min,
            "dt_s": dt,
            "duration_s": duration_s,
            "seed": seed,
            "bisection_hi_s": hi,
            "bisection_iters": iters,
        },
        "means_s": list(means),
        "alphas": list(alphas),
        "variants": [v[0] for v in VARIANTS],
        "rules": list(RULES),
        "channels": channels,
    }
