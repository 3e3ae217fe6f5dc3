"""Paired comparison of the control schemes on the reduced closed loop, over delay regimes.

Every registered scheme (:mod:`bipedtele.control.schemes`) runs the same ``runs`` operators
(intentions, hand) over the same delays and losses of a regime, so run ``i`` of one scheme
and run ``i`` of another differ only by the scheme: the differences are paired. The loop is
the study's (:mod:`bipedtele.control.study`: simulated operator and handle (1), (31)-(32);
one message per period each way, the newest kept; the real follower's reduced hybrid model
(20), (22), (12) with the impact reset and ``(sigma_r, T)`` changed only at impacts), with
the scheme's own port laws (:class:`~bipedtele.control.schemes.base.Scheme`, called on all
runs at once, arrays of shape ``(runs, 2)``): the damping both sides use, the leader's force
and the follower's command from what arrived, what each side sends (``z_e`` of the reduced
model's equivalent follower, the robot's speed, or a wave: the scheme picks), and the
passivity controllers.

Metrics per run (channels ``forward`` [cm/s] and ``turn`` [deg/s]):

* ``*_error``: time mean of ``|k_g x_m(t - h1) - eta|``, eqs. (6), (10) (the operator's
  command as received against the robot's speed);
* ``*_intent_error``: time mean of ``|intended speed - eta|``: what the operator wanted
  against what the robot did (the coordination error also falls when the force drags the
  handle towards the robot; this one does not);
* ``*_force_error``: RMS of the coupling force felt less ``k_m (k_g x_m - eta)``, the force
  with no delay (transparency) [N];
* ``*_effort``: time mean of the operator's hand force ``|f_h|`` [N];
* ``*_po_leader``, ``*_po_follower``: the least value of each port's passivity observer
  [N cm or N deg] (negative: the channel gave out energy nobody put in);
* ``peak``: the largest robot speed, and ``unstable``: ``peak`` above ``unstable_factor``
  times the largest intended speed (such runs are left out of the other means and counted).

The **stability margin** of a scheme is the largest delay scale of the shipped trace
(``margin_scales`` from x1 on; x0, no delay, is reported as the reference) up to which at
most 5 % of the runs oscillate at every scale, in runs
where the operator lets go of the handle mid-run (the hand holds no longer; what is left is
the handle, the link and the robot): a run oscillates when the released handle still moves
(RMS speed over the last quarter above ``oscillation_m_s``) or the robot's speed leaves the
bound of ``unstable``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.equivalent import equivalent_matrices
from bipedtele.control.linalg import zoh2
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import SimulatedLeader, StudyParams, channel, ci95, hybrid_zoh
from bipedtele.control.schemes import Scheme, scheme_class, scheme_names
from bipedtele.control.schemes.ports import EnergyCounter
from bipedtele.control.study import DelayCase, case_inputs

__all__ = [
    "MARGIN_SCALES",
    "METRICS",
    "REGIMES",
    "CompareParams",
    "Regime",
    "RegimeInputs",
    "compare_markdown",
    "compare_steps",
    "paired_cell",
    "regime_inputs",
    "run_compare",
    "simulate",
]

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class Regime:
    """A delay regime: delay models, a scale on them, an optional step, message loss.

    Attributes
    ----------
    name, description : str
        Table label and one line.
    h1, h2 : str
        Delay-model specs (:mod:`bipedtele.delaymodels`) of each direction.
    scale : float
        Factor on both delays.
    step_s : tuple of float or None
        ``(before, after)`` [s]: both delays constant, jumping mid-run (``h1``, ``h2`` unused).
    loss : float
        Probability that a message is lost, each direction, independently.
    """

    name: str
    description: str
    h1: str = "trace:intercontinental:h1"
    h2: str = "trace:intercontinental:h2"
    scale: float = 1.0
    step_s: tuple[float, float] | None = None
    loss: float = 0.0


REGIMES: tuple[Regime, ...] = (
    Regime("trace", "the shipped intercontinental trace (130-370 ms, time-varying, asymmetric)"),
    Regime("trace-x2", "the shipped trace, delays doubled", scale=2.0),
    Regime("trace-x4", "the shipped trace, delays x4 (0.5-1.5 s)", scale=4.0),
    Regime("satellite", "1.5 s +- 0.2 s each way", "uniform:1500ms:200ms", "uniform:1500ms:200ms"),
    Regime("congested-satellite", "3.5 s +- 0.3 s each way", "uniform:3500ms:300ms", "uniform:3500ms:300ms"),
    Regime("step", "0.3 s each way, 3 s from mid-run on", step_s=(0.3, 3.0)),
    Regime("trace-loss", "the shipped trace, 5 % of the messages lost each way", loss=0.05),
)

#: Delay scales of the shipped trace over which the stability margin is sought.
MARGIN_SCALES: tuple[float, ...] = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)

_CHANNEL_METRICS = ("error", "intent_error", "force_error", "effort", "po_leader", "po_follower")
#: Every metric reported per run (``unstable`` is a count, not a mean).
METRICS: tuple[str, ...] = (
    *(f"{c}_{m}" for m in _CHANNEL_METRICS for c in ("forward", "turn")),
    "peak",
)


@dataclass(frozen=True)
class CompareParams:
    """Settings of a comparison that are not controller parameters.

    Attributes
    ----------
    study : StudyParams
        Operator, handle, period and duration (the study's).
    unstable_factor : float
        A run is unstable when the robot's speed exceeds this times the largest intended one.
    wave_window_s : float
        Window over which the wave gain measures the delay's rate [s], passed to the scheme
        (:meth:`~bipedtele.control.schemes.base.Scheme.received_gains`); the real loops use
        0.5 s (:data:`~bipedtele.control.schemes.runtime.LOOP_WAVE_WINDOW_S`) until one value
        is chosen by measurement.
    release_fraction : float
        In the margin runs, the operator lets go of the handle at this fraction of the run.
    oscillation_m_s : float
        A margin run oscillates when the released handle's RMS speed over the run's last
        quarter exceeds this [m/s] on either axis (2 mm/s: 0.3 cm/s of forward command).
    """

    study: StudyParams = field(default_factory=StudyParams)
    unstable_factor: float = 3.0
    wave_window_s: float = 0.1
    release_fraction: float = 0.5
    oscillation_m_s: float = 0.002


@dataclass(frozen=True)
class RegimeInputs:
    """What one regime feeds every scheme: delays, losses and the operators (paired)."""

    h1: np.ndarray
    h2: np.ndarray
    lost1: np.ndarray
    lost2: np.ndarray
    switch: np.ndarray
    intent: np.ndarray


def regime_inputs(regime: Regime, runs: int, seed: int, cfg: ControlConfig, params: StudyParams) -> RegimeInputs:
    """Draw a regime's delays, losses and operators (seeded; equal for every scheme)."""
    inp = case_inputs(DelayCase(regime.name, regime.h1, regime.h2, regime.description), runs, seed, cfg, params)
    h1, h2 = inp.h1 * regime.scale, inp.h2 * regime.scale
    if regime.step_s is not None:
        before, after = regime.step_s
        late = np.arange(h1.size) >= h1.size // 2
        h1 = np.where(late, after, before).astype(float)
        h2 = h1.copy()
    rng = np.random.default_rng([seed, 7])
    lost1 = rng.random(h1.size) < regime.loss
    lost2 = rng.random(h2.size) < regime.loss
    return RegimeInputs(h1, h2, lost1, lost2, inp.switch, inp.intent)


def _equivalent_steps(s_e_k: np.ndarray, cfg: ControlConfig, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact ZOH of (29) for every distinct ``sigma_e`` of the run, and which one each step uses."""
    uniq, inverse = np.unique(s_e_k, axis=0, return_inverse=True)
    a_eq, b_eq = equivalent_matrices(uniq, cfg.D, cfg.k_s, cfg.beta_e, cfg.k_z)
    phi, gam = zoh2(a_eq, b_eq, dt)
    return phi, gam, inverse.reshape(-1)


class _Loop:
    """State of ``n`` paired runs of one scheme on one regime."""

    def __init__(self, scheme: Scheme, inp: RegimeInputs, cfg: ControlConfig, cp: CompareParams) -> None:
        p = cp.study
        self.scheme, self.cfg, self.dt = scheme, cfg, p.dt
        self.n = n = inp.switch.shape[0]
        self.ch1 = channel(inp.h1, p.dt, p.window_s, inp.lost1)
        self.ch2 = channel(inp.h2, p.dt, p.window_s, inp.lost2)
        self.alpha_k, self.s_e_k = scheme.damping(self.ch1.estimate, self.ch2.estimate)
        self.phi_eq, self.gam_eq, self.eq_index = _equivalent_steps(self.s_e_k, cfg, p.dt)
        w = round(cp.wave_window_s / p.dt)  # this runner's window, passed to the scheme (docs/schemes.md)
        self.gain1, self.gain2 = scheme.received_gains(self.ch1.idx, w), scheme.received_gains(self.ch2.idx, w)
        self.leader = SimulatedLeader(inp.switch, inp.intent, cfg, p)
        self.k_g = np.asarray(cfg.k_g, dtype=float)
        self.k_m = np.asarray(cfg.k_m, dtype=float)
        self.dp = np.array([cfg.dp, cfg.dp_turn])
        self.eq = np.zeros((n, 2, 2))  # [eta_e, z_e] per channel
        self.eq_k = -1  # the period eq was last advanced to
        self.hy = np.zeros((n, 2, 2))  # [eta, z_r] per channel
        self.phase = 0.0
        self.cmd_buf = np.zeros((self.ch1.ring, n, 2))  # k_g x_m sent
        self.wave_buf = np.zeros((self.ch1.ring, n, 2))  # u_m sent
        self.ein_m_buf = np.zeros((self.ch1.ring, n, 2))  # leader port's input energy sent
        self.fb_buf = np.zeros((self.ch2.ring, n, 2))  # z_e, eta or v_s sent back
        self.ein_s_buf = np.zeros((self.ch2.ring, n, 2))
        self.port_m, self.port_s = EnergyCounter((n, 2)), EnergyCounter((n, 2))
        self.sums = {m: np.zeros((n, 2)) for m in ("error", "intent", "force2", "effort")}
        self.peak = np.zeros(n)
        self.late_from = round(0.75 * inp.h1.size)
        self.late_v2 = np.zeros((n, 2))

    def _received(self, buf: np.ndarray, idx: int, ring: int) -> np.ndarray:
        return buf[idx % ring] if idx >= 0 else np.zeros((self.n, 2))

    def leader_tick(self, k: int, t: float) -> None:
        """Advance the leader: feel what arrived, move the handle, send the command (the scheme's laws)."""
        i2, ring2 = int(self.ch2.idx[k]), self.ch2.ring
        scheme, k_m = self.scheme, self.k_m
        r_now = self.k_g * self.leader.x
        law = scheme.leader_force(r_now, self._received(self.fb_buf, i2, ring2), self.gain2[k], k_m)
        ein_s_rx = self._received(self.ein_s_buf, i2, ring2)
        law = scheme.limit_leader(law, r_now, self.port_m, ein_s_rx, k_m, self.dt)
        f_m = law.force
        self.port_m.add(f_m * r_now, self.dt, ein_s_rx)  # every scheme's port, for its observer metric (P_m)
        eta = self.hy[..., 0]
        self.sums["force2"] += (f_m - k_m * (r_now - eta)) ** 2
        # the simulated handle renders the force: it follows r - F/k_m (law.followed(), to rounding)
        x = self.leader.step(t, r_now - f_m / k_m, self.alpha_k[k])
        self.sums["effort"] += np.abs(self.leader.f_h)
        if k >= self.late_from:
            self.late_v2 += self.leader.v**2
        r_m = self.k_g * x
        slot = k % self.ch1.ring
        self.cmd_buf[slot] = r_m
        self.ein_m_buf[slot] = self.port_m.e_in
        wave = scheme.command_wave(r_m, law, k_m)
        if wave is not None:
            self.wave_buf[slot] = wave

    def _equivalent(self, k: int, ref: np.ndarray) -> np.ndarray:
        """Advance the reduced model's equivalent follower (29) to period ``k`` on ``ref``; return ``z_e``.

        Advanced once per period however often the scheme asks (and never for a scheme that
        does not ask: it is the comparison's costliest step).
        """
        if self.eq_k != k:
            self.eq_k = k
            j = self.eq_index[k]
            self.eq = (
                np.einsum("cij,ncj->nci", self.phi_eq[j], self.eq) + self.gam_eq[j][None, :, :, 0] * ref[:, :, None]
            )
        return np.asarray(self.eq[:, :, 1])

    def follower_tick(self, k: int, hybrid: tuple[np.ndarray, np.ndarray]) -> None:
        """Advance the follower: take the newest command, drive the robot, send the feedback (the scheme's laws)."""
        i1, ring1 = int(self.ch1.idx[k]), self.ch1.ring
        scheme, k_m = self.scheme, self.k_m
        ref = self._received(self.cmd_buf, i1, ring1)
        eta = self.hy[..., 0]
        c = scheme.follower_command(ref, self._received(self.wave_buf, i1, ring1), self.gain1[k], eta, k_m)
        ein_m_rx = self._received(self.ein_m_buf, i1, ring1)
        c = scheme.limit_follower(c, eta, self.port_s, ein_m_rx, k_m, self.dt)
        self.port_s.add(-k_m * (c - eta) * c, self.dt, ein_m_rx)  # P_s (ports.follower_power)
        phi_h, gam_h = hybrid
        h0 = phi_h[..., 0, 0] * self.hy[..., 0] + phi_h[..., 0, 1] * self.hy[..., 1] + gam_h[..., 0] * c
        h1 = phi_h[..., 1, 0] * self.hy[..., 0] + phi_h[..., 1, 1] * self.hy[..., 1] + gam_h[..., 1] * c
        self.hy = np.stack([h0, h1], -1)
        self.fb_buf[k % self.ch2.ring] = scheme.feedback_signal(lambda: self._equivalent(k, ref), self.hy[..., 0], k_m)
        self.ein_s_buf[k % self.ch2.ring] = self.port_s.e_in
        self.sums["error"] += np.abs(ref - self.hy[..., 0])
        lead = self.leader
        self.sums["intent"] += np.abs(lead.intent[lead.rows, lead.seg] - self.hy[..., 0])
        self.peak = np.maximum(self.peak, np.abs(self.hy[..., 0]).max(axis=1))


def simulate(
    scheme: Scheme,
    inp: RegimeInputs,
    cfg: ControlConfig,
    cp: CompareParams,
    chooser: OnlineChooser,
    *,
    release: bool = False,
    progress: Callable[[int], None] | None = None,
) -> dict[str, np.ndarray]:
    """Run one scheme over one regime's inputs; return every metric per run (``(runs,)`` arrays).

    With ``release`` the operator lets go of the handle at ``cp.release_fraction`` of the
    run; ``released_motion`` is then the handle's RMS speed over the last quarter [m/s]
    (largest axis) and ``oscillating`` whether it exceeds ``cp.oscillation_m_s``.
    """
    p = cp.study
    k_steps = inp.h1.size
    loop = _Loop(scheme, inp, cfg, cp)
    if release:
        loop.leader.release_t = cp.release_fraction * k_steps * p.dt
    choice = chooser.choose(loop.s_e_k[0])
    hybrid = hybrid_zoh(np.repeat(choice.s_r[None, :], loop.n, axis=0), cfg, p.dt)
    T, phase = choice.T, 0.0
    report_every = max(1, k_steps // 50)
    for k in range(k_steps):
        loop.leader_tick(k, k * p.dt)
        loop.follower_tick(k, hybrid)
        phase += p.dt
        if phase >= T - 1e-9:  # impact: reset, then the next cycle's parameters (30)
            loop.hy[..., 0] *= loop.dp
            phase -= T
            choice = chooser.choose(loop.s_e_k[k])
            hybrid = hybrid_zoh(np.repeat(choice.s_r[None, :], loop.n, axis=0), cfg, p.dt)
            T = choice.T
        if progress is not None and (k + 1) % report_every == 0:
            progress(report_every)
    out: dict[str, np.ndarray] = {}
    for c, ch in enumerate(("forward", "turn")):
        out[f"{ch}_error"] = loop.sums["error"][:, c] / k_steps
        out[f"{ch}_intent_error"] = loop.sums["intent"][:, c] / k_steps
        out[f"{ch}_force_error"] = np.sqrt(loop.sums["force2"][:, c] / k_steps)
        out[f"{ch}_effort"] = loop.sums["effort"][:, c] / k_steps
        out[f"{ch}_po_leader"] = loop.port_m.min_observer[:, c]
        out[f"{ch}_po_follower"] = loop.port_s.min_observer[:, c]
    out["peak"] = loop.peak
    limit = cp.unstable_factor * max(p.forward_range[1], p.turn_max)
    out["unstable"] = ~np.isfinite(loop.peak) | (loop.peak > limit)
    out["released_motion"] = np.sqrt(loop.late_v2 / max(1, k_steps - loop.late_from)).max(axis=1)
    out["oscillating"] = out["unstable"] | ~(out["released_motion"] <= cp.oscillation_m_s)
    return out


def paired_cell(
    runs: dict[str, np.ndarray], base: dict[str, np.ndarray] | None, metrics: tuple[str, ...] = METRICS
) -> dict[str, Any]:
    """Summarise one scheme's runs of one regime: mean and 95 % interval per metric, paired against ``base``.

    ``runs[m]`` holds metric ``m`` per run, ``runs["unstable"]`` the runs left out (diverged,
    fell); run ``i`` of ``runs`` and of ``base`` share their operator and delays.
    """
    ok = ~runs["unstable"]
    cell: dict[str, Any] = {"n": int(ok.sum()), "unstable": int(runs["unstable"].sum())}
    both = ok if base is None else ok & ~base["unstable"]
    for m in metrics:
        mean, ci = ci95(runs[m][ok])
        cell[m] = {"mean": mean, "ci95": ci}
        if base is not None:
            d_mean, d_ci = ci95(runs[m][both] - base[m][both])
            cell[m]["diff"] = {"mean": d_mean, "ci95": d_ci, "n": int(both.sum())}
    return cell


def compare_steps(runs_steps: int, schemes: int, regimes: int, margin_scales: int) -> int:
    """Return the control periods a comparison simulates (the progress total)."""
    return runs_steps * schemes * (regimes + margin_scales)


def _margin(unstable_by_scale: dict[float, float]) -> float | None:
    """Largest scale >= 1 up to which at most 5 % oscillate (x0 is the no-delay reference, not counted)."""
    best: float | None = None
    for s in sorted(k for k in unstable_by_scale if k >= 1.0):
        if unstable_by_scale[s] > 0.05:
            break
        best = s
    return best


def run_compare(
    runs: int = 200,
    seed: int = 0,
    cfg: ControlConfig | None = None,
    cp: CompareParams | None = None,
    *,
    schemes: tuple[str, ...] | None = None,
    regimes: tuple[Regime, ...] = REGIMES,
    margin_scales: tuple[float, ...] = MARGIN_SCALES,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Compare every scheme on every regime (reduced model), paired against ``paper``.

    Parameters
    ----------
    runs : int
        Runs per scheme and regime (the same operators for every scheme).
    schemes : tuple of str, optional
        Registered names (default: all; ``paper`` is always run, as the reference).
    margin_scales : tuple of float
        Delay scales of the shipped trace for the stability margin (``()``: none).

    Returns
    -------
    dict
        ``{"plant": "reduced", "seed", "runs", "duration_s", "elapsed_s", "schemes": {name:
        title}, "regimes": [...], "cells": {regime: {scheme: cell}}, "margin": {scheme:
        {"scale", "oscillating_by_scale", "released_motion_median_m_s"}}}``; a cell holds ``n``,
        ``unstable`` and, per metric, ``mean``, ``ci95`` and (except for ``paper``) the paired
        ``diff`` against ``paper``.
    """
    if runs < 2:
        raise ValueError(f"runs = {runs}: allowed: >= 2 (a 95 % interval needs two)")
    cfg = cfg or ControlConfig()
    cp = cp or CompareParams()
    names = list(schemes) if schemes else scheme_names()
    if "paper" not in names:
        names.insert(0, "paper")
    classes = {n: scheme_class(n) for n in names}
    chooser = OnlineChooser(cfg)
    started = time.monotonic()
    cells: dict[str, dict[str, Any]] = {}
    unstable: dict[str, dict[float, float]] = {n: {} for n in names}
    motion: dict[str, dict[float, float]] = {n: {} for n in names}
    margin_regimes = tuple(Regime(f"margin-x{s:g}", f"shipped trace x{s:g}", scale=s) for s in margin_scales)
    for regime in regimes + margin_regimes:
        inp = regime_inputs(regime, runs, seed, cfg, cp.study)
        worst = (float(inp.h1.max()), float(inp.h2.max()))
        margin = regime in margin_regimes
        per_scheme = {
            n: simulate(cls(cfg, worst), inp, cfg, cp, chooser, release=margin, progress=progress)
            for n, cls in classes.items()
        }
        if margin:
            for n, r in per_scheme.items():
                unstable[n][regime.scale] = float(r["oscillating"].mean())
                motion[n][regime.scale] = float(np.median(r["released_motion"]))
            continue
        cells[regime.name] = {
            n: paired_cell(r, None if n == "paper" else per_scheme["paper"]) for n, r in per_scheme.items()
        }
        LOG.info("compare: %s done (%.0f s)", regime.name, time.monotonic() - started)
    return {
        "plant": "reduced",
        "seed": seed,
        "runs": runs,
        "duration_s": cp.study.duration_s,
        "elapsed_s": time.monotonic() - started,
        "schemes": {n: classes[n].title for n in names},
        "regimes": [{"name": r.name, "description": r.description} for r in regimes],
        "cells": cells,
        "margin": _margins(unstable, motion) if margin_scales else {},
    }


def _margins(oscillating: dict[str, dict[float, float]], motion: dict[str, dict[float, float]]) -> dict[str, Any]:
    """Per scheme: the margin, the share of oscillating runs and the median released-handle speed per scale."""
    return {
        n: {
            "scale": _margin(u),
            "oscillating_by_scale": {f"{s:g}": v for s, v in u.items()},
            "released_motion_median_m_s": {f"{s:g}": v for s, v in motion[n].items()},
        }
        for n, u in oscillating.items()
    }


def _fmt(v: dict[str, Any], key: str = "") -> str:
    d = v[key] if key else v
    if not math.isfinite(d["mean"]):
        return "-"
    lo, hi = d["ci95"]
    return f"{d['mean']:.2f} [{lo:.2f}, {hi:.2f}]"


def _walker_lines(walker: dict[str, Any]) -> list[str]:
    """Return the walker cells as markdown: errors, paired differences against the paper, falls."""
    lines = [
        f"The pybullet walker (the real follower loop), {walker['runs']} paired runs per cell, "
        f"{walker['duration_s']:g} s each, {walker['wall_s']:.0f} s wall. Coordination error per follower tick "
        "|ref - eta| and intent error [cm/s, deg/s], mean [95 % CI] and paired difference against `paper`; "
        "fallen runs are left out and counted.",
        "",
        "| regime | scheme | forward | - paper | turn | - paper | intent fwd - paper | intent turn - paper | falls |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for regime, per in walker["cells"].items():
        for name, c in per.items():
            diffs = [
                _fmt(c[m], "diff") if "diff" in c[m] else ""
                for m in ("forward_error", "turn_error", "forward_intent_error", "turn_intent_error")
            ]
            lines.append(
                f"| {regime} | {name} | {_fmt(c['forward_error'])} | {diffs[0]} | {_fmt(c['turn_error'])} | "
                f"{diffs[1]} | {diffs[2]} | {diffs[3]} | {c['unstable']} |"
            )
    return lines


_WINNER_METRICS = (
    ("forward_error", "coordination fwd"),
    ("turn_error", "coordination turn"),
    ("forward_intent_error", "intent fwd"),
    ("turn_intent_error", "intent turn"),
    ("forward_force_error", "force error fwd"),
)


def _winners(result: dict[str, Any]) -> list[str]:
    """Per regime and metric: the scheme with the lowest mean, and whether it beats the paper for sure."""
    head = " | ".join(label for _, label in _WINNER_METRICS)
    lines = [
        "Lowest mean per regime and metric (a `*`: its paired 95 % interval against `paper` lies below zero; "
        "`paper` itself: no other scheme's lies below zero).",
        "",
        f"| regime | {head} |",
        "| --- |" + " --- |" * len(_WINNER_METRICS),
    ]
    for regime, per in result["cells"].items():
        row = []
        for metric, _ in _WINNER_METRICS:
            name = min(per, key=lambda n: per[n][metric]["mean"] if math.isfinite(per[n][metric]["mean"]) else math.inf)
            diff = per[name][metric].get("diff")
            sure = name == "paper" or (diff is not None and diff["ci95"][1] < 0.0)
            row.append(f"{name}{'*' if sure and name != 'paper' else ''}")
        lines.append(f"| {regime} | {' | '.join(row)} |")
    return lines


def compare_markdown(result: dict[str, Any]) -> str:
    """Return the comparison as markdown: per regime, each scheme's errors and the paired differences."""
    lines = [
        f"Reduced model, {result['runs']} paired runs per scheme and regime, {result['duration_s']:g} s each, "
        f"seed {result['seed']}. Mean [95 % CI] of the time-mean coordination error |eq. (6)| [cm/s] and "
        "|eq. (10)| [deg/s], the paired difference against `paper` (negative: better than the paper), the "
        "paired difference of the intent error (intended speed against the robot's), the "
        "force error against the delay-free coupling [N, forward], and the least passivity observer at the "
        "leader and follower ports [N cm, forward]; unstable runs are left out and counted.",
        "",
        "| regime | scheme | forward | - paper | turn | - paper | intent fwd - paper | intent turn - paper "
        "| force error | PO leader / follower | unstable |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for regime, per in result["cells"].items():
        for name, c in per.items():
            dfw = _fmt(c["forward_error"], "diff") if "diff" in c["forward_error"] else ""
            dtu = _fmt(c["turn_error"], "diff") if "diff" in c["turn_error"] else ""
            ifw = _fmt(c["forward_intent_error"], "diff") if "diff" in c["forward_intent_error"] else ""
            itu = _fmt(c["turn_intent_error"], "diff") if "diff" in c["turn_intent_error"] else ""
            po = f"{c['forward_po_leader']['mean']:.1f} / {c['forward_po_follower']['mean']:.1f}"
            lines.append(
                f"| {regime} | {name} | {_fmt(c['forward_error'])} | {dfw} | {_fmt(c['turn_error'])} | {dtu} | {ifw} | {itu} | "
                f"{_fmt(c['forward_force_error'])} | {po} | {c['unstable']} |"
            )
    lines += ["", *_winners(result)]
    if result.get("walker"):
        lines += ["", *_walker_lines(result["walker"])]
    if result.get("margin"):
        lines += [
            "",
            "Handle released mid-run: share of runs still oscillating over the last quarter (released handle's "
            "RMS speed above the threshold) per delay scale of the shipped trace (x0: no delay, the reference), "
            "and the median RMS [mm/s].",
            "",
            "| scheme | stability margin (largest scale, <= 5 % oscillating) | oscillating share by scale "
            "| median released-handle speed by scale [mm/s] |",
            "| --- | --- | --- | --- |",
        ]
        for name, m in result["margin"].items():
            share = ", ".join(f"x{s}: {100 * v:.0f} %" for s, v in m["oscillating_by_scale"].items())
            med = ", ".join(f"x{s}: {1e3 * v:.1f}" for s, v in m["released_motion_median_m_s"].items())
            margin = f"x{m['scale']:g}" if m["scale"] is not None else "none (oscillates at x1)"
            lines.append(f"| {name} | {margin} | {share} | {med} |")
    return "\n".join(lines) + "\n"
