"""The paper's numerical study (Sec. 4, Fig. 8): constant (CP) vs variable (VP) parameters.

For each delay case, ``runs`` closed-loop simulations with **constant parameters** (CP:
``sigma_r`` per channel uniform in ``s_r_range``, ``T`` uniform in ``T_range``, ``eps`` the
configured value, all fixed for the run) and ``runs`` with **variable parameters** (VP:
``sigma_r``, ``T``, ``eps`` from the online choice (30), fed by the 1 s moving-average delay
estimates). Both schemes use the damping scheduler (40) for ``alpha_m`` and ``sigma_e``.
CP run ``i`` and VP run ``i`` share the operator's intentions (paired comparison).

The loop, per control period ``dt`` (all runs at once, numpy over the run axis):

* **Operator** (simulated): intends a speed pair that changes at random instants (mean
  6 s apart); the intention ``ref/k_g`` is smoothed (0.15 s) and a PD hand pulls the handle
  (``k_h = 300 N/m``, ``b_h = 8 N s/m``, ``|f_h| <= 15 N``), so the force feedback pushes it
  off its target as it would a human's.
* **Leader** (1), (31)-(32): a Falcon-like handle of mass 0.15 kg (``C_m = 0``, ``g_m``
  compensated) under ``f_m`` clamped to 8 N; damping terms implicit (stable at any
  ``alpha_m``), then the position (symplectic Euler).
* **Channel**: one command and one feedback message per period; a message sent at step
  ``n`` arrives ``ceil(h(t_n)/dt)`` steps later; receivers keep the newest arrived message
  (older ones arriving later are dropped), as the real transport does.
* **Delay estimate**: the receiver's mean of the one-way delays of the messages it got in
  the last 1 s (time window), shared with the other side (sharing latency ignored).
* **Equivalent follower** (29) driven by the received ``k_g x_m(t - h1)``, exact ZOH, with
  ``sigma_e`` from (40); ``z_e`` goes back to the leader.
* **Real follower**: the reduced hybrid model (20), (22), (12) in speed coordinates
  ``[eta, z_r]`` per channel (exact ZOH between impacts, ``f_v = 0``) with the impact reset
  ``eta_v <- dp eta_v`` (``eta_d <- dp_turn eta_d``) at the end of every walking cycle;
  ``sigma_r`` and ``T`` change only at impacts (one cycle = one set of parameters, as in the
  Poincare analysis). The joint block (21) is decoupled from the speeds, so ``eps`` enters
  only through the choice (30).

Reported per case and scheme: the mean over runs of the time-mean absolute coordination
errors, eqs. (6) and (10): forward ``|k_gv x_mv(t - h1) - v_hip|`` [cm/s] and turn
``|k_gd x_md(t - h1) - v_delta|`` [deg/s], with 95 % confidence intervals (Student t over
runs), and the number of diverged runs (non-finite state or a speed above 1e4), which are
left out of the means. Separately, the **periodic-orbit offset**: the time mean of
``d(sigma_r, T) |k_g x_m(t - h1)|``, where ``d`` is the mean speed deficit of the reduced
model's periodic orbit at the parameters in use (:func:`orbit_deficit`): what the resets
alone cost at a constant command, with no delay. Where the error and the offset are close,
the error is the resets' doing, not the delays'.

:func:`run_sensitivity` repeats the comparison over a small grid of the settings the paper
leaves open (:data:`SENSITIVITY`) and :func:`sensitivity_markdown` writes its table.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.damping import schedule_damping_array
from bipedtele.control.follower_step import FollowerController, equivalent_steps
from bipedtele.control.hybrid import orbit_speed_deficit
from bipedtele.control.online import Choice, OnlineChooser
from bipedtele.control.reduced import SimulatedLeader, StudyParams, channel, ci95, hybrid_zoh
from bipedtele.control.schemes import scheme_class
from bipedtele.link.delaymodels import parse_delay_model

__all__ = [
    "CASES",
    "SENSITIVITY",
    "CaseInputs",
    "DelayCase",
    "SimulatedLeader",
    "StudyParams",
    "case_inputs",
    "delay_sampler",
    "orbit_deficit",
    "run_case",
    "run_sensitivity",
    "run_study",
    "sensitivity_markdown",
    "study_markdown",
    "study_steps",
]

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class DelayCase:
    """One delay scenario: forward (``h1``) and backward (``h2``) delay model specs."""

    name: str
    h1: str
    h2: str
    description: str


CASES: tuple[DelayCase, ...] = (
    DelayCase("lan", "const:2ms", "const:2ms", "same-site LAN: 2 ms each way, constant"),
    DelayCase(
        "continental",
        "uniform:40ms:15ms",
        "uniform:40ms:15ms",
        "same-continent internet: 40 ms +- 15 ms each way, uniform jitter per message (reordering)",
    ),
    DelayCase(
        "asymmetric",
        "const:300ms",
        "const:100ms",
        "asymmetric: 300 ms leader->robot, 100 ms back, constant",
    ),
    DelayCase(
        "intercontinental",
        "trace:intercontinental:h1",
        "trace:intercontinental:h2",
        "recorded intercontinental trace (130-370 ms, time-varying, asymmetric), shipped CSV",
    ),
    DelayCase(
        "satellite",
        "uniform:1500ms:200ms",
        "uniform:1500ms:200ms",
        "satellite hop plus a congested path: 1.5 s +- 0.2 s each way; with the default D and "
        "margin, (40) lifts sigma_e off its floor on the turn channel only",
    ),
    DelayCase(
        "congested-satellite",
        "uniform:3500ms:300ms",
        "uniform:3500ms:300ms",
        "satellite path with seconds of queueing: 3.5 s +- 0.3 s each way; (40) lifts sigma_e "
        "off its floor on both channels",
    ),
)


# ----------------------------------------------------------------------------- delays


def delay_sampler(spec: str, seed: int) -> Callable[[float], float]:
    """``t -> delay [s]`` for a delay-model spec (:mod:`bipedtele.link.delaymodels`)."""
    delay_s: Callable[[float], float] = parse_delay_model(spec, seed=seed).delay_s
    return delay_s


# ----------------------------------------------------------------------------- follower


# ----------------------------------------------------------------------------- one case


def _summary(err: np.ndarray, offset: np.ndarray, diverged: np.ndarray) -> dict[str, Any]:
    ok = ~diverged
    out: dict[str, Any] = {}
    for c, ch in enumerate(("forward", "turn")):
        m, ci = ci95(err[ok, c])
        o, oci = ci95(offset[ok, c])
        out[f"{ch}_error"] = m
        out[f"{ch}_ci95"] = ci
        out[f"{ch}_orbit_offset"] = o
        out[f"{ch}_orbit_offset_ci95"] = oci
    out["diverged"] = int(diverged.sum())
    return out


def orbit_deficit(s_r: np.ndarray, T: np.ndarray, cfg: ControlConfig) -> np.ndarray:
    """Return the periodic orbit's mean speed deficit per run and channel.

    As a fraction of a constant reference (:func:`~bipedtele.control.hybrid.orbit_speed_deficit`).

    ``s_r`` has shape (n, 2), ``T`` shape (n,); returns (n, 2).
    """
    d, k, b = (np.asarray(v, dtype=float) for v in (cfg.D, cfg.k_s, cfg.beta_r))
    dps = (cfg.dp, cfg.dp_turn)
    return np.stack(
        [orbit_speed_deficit(s_r[:, c], T, float(d[c]), float(k[c]), float(b[c]), dps[c]) for c in range(2)], -1
    )


@dataclass(frozen=True)
class CaseInputs:
    """What one delay case feeds ``runs`` paired runs.

    The same for the reduced and the walker study with equal seeds.

    Attributes
    ----------
    h1, h2 : numpy.ndarray
        One-way delay of a message sent at step ``k`` [s], shape (K,).
    cp_s_r, cp_T : numpy.ndarray
        CP's fixed real damping (runs, 2) and walking cycle (runs,) [s].
    switch, intent : numpy.ndarray
        Operator: times its intention changes (runs, n) [s] and the intended speeds
        (runs, n, 2) [cm/s, deg/s].
    """

    h1: np.ndarray
    h2: np.ndarray
    cp_s_r: np.ndarray
    cp_T: np.ndarray
    switch: np.ndarray
    intent: np.ndarray


def case_inputs(
    case: DelayCase,
    runs: int,
    seed: int,
    cfg: ControlConfig,
    params: StudyParams,
    *,
    T_bounds: tuple[float, float] | None = None,
) -> CaseInputs:
    """Draw a case's delays, CP parameters and operator intentions (seeded per case).

    ``T_bounds`` narrows CP's walking-cycle range (default ``cfg.T_range``) without
    changing the random stream, so run ``i`` keeps its intentions.
    """
    dt = params.dt
    k_steps = round(params.duration_s / dt)
    case_seed = [seed, CASES.index(case) if case in CASES else 99]
    rng = np.random.default_rng(case_seed)
    t_grid = np.arange(k_steps) * dt
    offset = float(rng.uniform(0.0, 240.0)) if case.h1.startswith("trace") else 0.0
    h = []
    for j, spec in enumerate((case.h1, case.h2)):
        f = delay_sampler(spec, seed=int(rng.integers(0, 2**31 - 1)) + j)
        h.append(np.array([f(offset + t) for t in t_grid]))
    s_lo, s_hi = cfg.s_r_range
    t_lo, t_hi = cfg.T_range if T_bounds is None else T_bounds
    cp_sr = rng.uniform(s_lo, s_hi, size=(runs, 2))
    cp_T = rng.uniform(t_lo, t_hi, size=runs)
    n_seg = int(params.duration_s / params.intent_min_s) + 2
    gaps = params.intent_min_s + rng.exponential(params.intent_mean_s - params.intent_min_s, size=(runs, n_seg))
    switch = np.concatenate([np.zeros((runs, 1)), np.cumsum(gaps, axis=1)], axis=1)
    fwd_t = rng.uniform(*params.forward_range, size=(runs, n_seg + 1))
    turn_t = rng.uniform(-params.turn_max, params.turn_max, size=(runs, n_seg + 1))
    return CaseInputs(h[0], h[1], cp_sr, cp_T, switch, np.stack([fwd_t, turn_t], -1))


class _CaseRun:
    """``runs`` CP and ``runs`` VP closed loops of one delay case, stepped together."""

    def __init__(
        self, case: DelayCase, runs: int, seed: int, cfg: ControlConfig, params: StudyParams, chooser: OnlineChooser
    ) -> None:
        self.cfg, self.params, self.chooser, self.runs = cfg, params, chooser, runs
        dt = self.dt = params.dt
        self.k_steps = round(params.duration_s / dt)
        inp = self.inp = case_inputs(case, runs, seed, cfg, params)
        self.ch1 = channel(inp.h1, dt, params.window_s)
        self.ch2 = channel(inp.h2, dt, params.window_s)
        self.alpha_k, self.s_e_k, _, _ = schedule_damping_array(self.ch1.estimate, self.ch2.estimate, cfg)
        # VP: the online choice for every distinct s_e met along the case (shared by all runs)
        # VP runs start together and share the choice, so they take it at the same steps:
        # the choice is computed (memoised) only where it is used.
        self.used: list[Choice] = []
        first = self.choice_at(0)
        # (29) discretised once per distinct sigma_e of the case (closed-form 2x2 ZOH)
        uniq, inverse = np.unique(self.s_e_k, axis=0, return_inverse=True)
        self.phi_eq, self.gam_eq = equivalent_steps(uniq, cfg, dt)
        self.inverse = inverse.reshape(-1)
        n_all = self.n_all = 2 * runs
        self.vp = np.zeros(n_all, dtype=bool)
        self.vp[runs:] = True
        # CP parameters, drawn per run, fixed
        self.s_r = np.concatenate([inp.cp_s_r, np.repeat(first.s_r[None, :], runs, axis=0)])
        self.T_run = np.concatenate([inp.cp_T, np.full(runs, first.T)])
        self.eps_used = np.concatenate([np.full(runs, cfg.eps), np.full(runs, first.eps)])
        self.deficit = orbit_deficit(self.s_r, self.T_run, cfg)
        # operator intentions: the same for CP run i and VP run i
        self.leader = SimulatedLeader(
            np.concatenate([inp.switch, inp.switch]), np.concatenate([inp.intent, inp.intent]), cfg, params
        )
        self.k_g = np.asarray(cfg.k_g, dtype=float)
        self.dp = np.array([cfg.dp, cfg.dp_turn])
        # the follower step's equivalent follower (29) (the paper's law: the robot gets ref, z_e is fed back)
        self.follower = FollowerController(scheme_class("paper")(cfg), np.asarray(cfg.k_m, dtype=float))
        self.foll_state = self.follower.initial(n_all)
        self.hy = np.zeros((n_all, 2, 2))  # [eta, z_r] per channel
        self.phase = np.zeros(n_all)
        self.phi_h, self.gam_h = hybrid_zoh(self.s_r, cfg, dt)
        self.cmd_buf = np.zeros((self.ch1.ring, n_all, 2))
        self.fb_buf = np.zeros((self.ch2.ring, n_all, 2))
        self.err_sum = np.zeros((n_all, 2))
        self.offset_sum = np.zeros((n_all, 2))
        self.peak = np.zeros(n_all)
        self.sum_T = np.zeros(n_all)
        self.sum_sr = np.zeros((n_all, 2))
        self.n_cycles = np.zeros(n_all)

    def choice_at(self, k: int) -> Choice:
        """Return the online choice (30) for step ``k``'s sigma_e, remembered for the report."""
        c = self.chooser.choose(self.s_e_k[k])
        self.used.append(c)
        return c

    def step(self, k: int) -> None:
        """Advance every run one control period."""
        dt, ch1, ch2, n_all = self.dt, self.ch1, self.ch2, self.n_all
        t = k * dt
        # operator and leader (31)-(32) with the feedback received
        i2 = ch2.idx[k]
        z_rx = self.fb_buf[i2 % ch2.ring] if i2 >= 0 else np.zeros((n_all, 2))
        x = self.leader.step(t, z_rx, self.alpha_k[k])
        self.cmd_buf[k % ch1.ring] = self.k_g * x
        # follower: newest command received
        i1 = ch1.idx[k]
        ref = self.cmd_buf[i1 % ch1.ring] if i1 >= 0 else np.zeros((n_all, 2))
        # equivalent follower (29), shared discretisation for this step's sigma_e
        j = self.inverse[k]
        zoh = (np.broadcast_to(self.phi_eq[j], (n_all, 2, 2, 2)), np.broadcast_to(self.gam_eq[j], (n_all, 2, 2, 2)))
        self.foll_state = self.follower.equivalent(self.foll_state, ref, zoh, None)
        self.fb_buf[k % ch2.ring] = self.foll_state.eq[:, :, 1]
        # real follower: hybrid speed dynamics between impacts, per-run matrices
        phi_h, gam_h, hy = self.phi_h, self.gam_h, self.hy
        h0 = phi_h[..., 0, 0] * hy[..., 0] + phi_h[..., 0, 1] * hy[..., 1] + gam_h[..., 0] * ref
        h1_ = phi_h[..., 1, 0] * hy[..., 0] + phi_h[..., 1, 1] * hy[..., 1] + gam_h[..., 1] * ref
        self.hy = hy = np.stack([h0, h1_], -1)
        self.phase += dt
        hit = self.phase >= self.T_run - 1e-9
        if hit.any():
            self._impact(k, hit)
        self.err_sum += np.abs(ref - hy[..., 0])
        self.offset_sum += self.deficit * np.abs(ref)
        self.peak = np.maximum(self.peak, np.abs(hy[..., 0]).max(axis=1))

    def _impact(self, k: int, hit: np.ndarray) -> None:
        """Reset the runs whose cycle ends; VP runs take the next cycle's parameters (30)."""
        cfg, dt = self.cfg, self.dt
        self.hy[hit, :, 0] *= self.dp
        self.phase[hit] -= self.T_run[hit]
        self.sum_T[hit] += self.T_run[hit]
        self.sum_sr[hit] += self.s_r[hit]
        self.n_cycles[hit] += 1
        upd = hit & self.vp
        if upd.any():
            ck = self.choice_at(k)
            self.T_run[upd] = ck.T
            self.s_r[upd] = ck.s_r
            self.eps_used[upd] = ck.eps
            p, g = hybrid_zoh(self.s_r[upd], cfg, dt)
            self.phi_h[upd] = p
            self.gam_h[upd] = g
            self.deficit[upd] = orbit_deficit(self.s_r[upd], self.T_run[upd], cfg)

    def summary(self, case: DelayCase) -> dict[str, Any]:
        """Return the case's report (see :func:`run_case`)."""
        k_steps, runs, n_all, s_e_k = self.k_steps, self.runs, self.n_all, self.s_e_k
        mean_err = self.err_sum / k_steps
        mean_offset = self.offset_sum / k_steps
        peak = self.peak
        diverged = ~np.isfinite(mean_err).all(axis=1) | ~np.isfinite(peak) | (peak > self.params.diverge_limit)
        cp_sl, vp_sl = slice(0, runs), slice(runs, n_all)
        out: dict[str, Any] = {
            "name": case.name,
            "h1_ms": 1e3 * self.ch1.mean_s,
            "h2_ms": 1e3 * self.ch2.mean_s,
            "description": case.description,
            "s_e": {
                "mean": s_e_k.mean(axis=0).tolist(),
                "max": s_e_k.max(axis=0).tolist(),
                "floor_left": [bool(v) for v in np.asarray((s_e_k > self.cfg.s_e_min + 1e-12).any(axis=0)).tolist()],
            },
            "cp": _summary(mean_err[cp_sl], mean_offset[cp_sl], diverged[cp_sl]),
            "vp": _summary(mean_err[vp_sl], mean_offset[vp_sl], diverged[vp_sl]),
        }
        cyc = np.maximum(self.n_cycles[vp_sl], 1)
        out["vp"]["mean_T_s"] = float(np.mean(self.sum_T[vp_sl] / cyc))
        out["vp"]["mean_s_r"] = (self.sum_sr[vp_sl] / cyc[:, None]).mean(axis=0).tolist()
        out["vp"]["eps"] = float(np.mean(self.eps_used[vp_sl]))
        used_T = np.array([c.T for c in self.used])
        used_sr = np.array([c.s_r for c in self.used])
        out["vp"]["T_span_s"] = [float(used_T.min()), float(used_T.max())]
        out["vp"]["s_r_span"] = [used_sr.min(axis=0).tolist(), used_sr.max(axis=0).tolist()]
        out["_runs"] = {"mean_error": mean_err, "diverged": diverged, "cp_T": self.inp.cp_T, "cp_s_r": self.inp.cp_s_r}
        return out


def run_case(
    case: DelayCase,
    runs: int,
    seed: int,
    cfg: ControlConfig,
    params: StudyParams,
    chooser: OnlineChooser,
    *,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Simulate ``runs`` CP and ``runs`` VP closed loops for one delay case.

    Returns
    -------
    dict
        ``{"name", "h1_ms", "h2_ms", "description", "cp": {...}, "vp": {...}}`` with the
        summaries described in the module docstring (plus per-run arrays under ``"_runs"``
        for callers that want them; not JSON-serialised by :func:`run_study`).
    """
    run = _CaseRun(case, runs, seed, cfg, params, chooser)
    report_every = max(1, run.k_steps // 50)
    for k in range(run.k_steps):
        run.step(k)
        if progress is not None and (k + 1) % report_every == 0:
            progress(report_every)
    return run.summary(case)


# ----------------------------------------------------------------------------- study


def study_steps(params: StudyParams, cases: tuple[DelayCase, ...] = CASES) -> int:
    """Return the number of control periods a study simulates (the progress total)."""
    return round(params.duration_s / params.dt) * len(cases)


def run_study(
    runs: int = 500,
    seed: int = 0,
    cfg: ControlConfig | None = None,
    params: StudyParams | None = None,
    *,
    cases: tuple[DelayCase, ...] = CASES,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Run the whole study: every case, CP and VP.

    Parameters
    ----------
    runs : int
        Runs per scheme and case (>= 1).
    seed : int
        Seed; equal seeds give equal results.
    progress : callable, optional
        Called with the number of control periods simulated since its last call (all
        cases together make :func:`study_steps` periods); none by default.

    Returns
    -------
    dict
        ``{"seed", "runs", "duration_s", "dt_s", "cases": [...]}`` (JSON-serialisable).
    """
    if runs < 1:
        raise ValueError(f"runs = {runs}: allowed: >= 1")
    cfg = cfg or ControlConfig()
    params = params or StudyParams()
    chooser = OnlineChooser(cfg)
    results = []
    for case in cases:
        res = run_case(case, runs, seed, cfg, params, chooser, progress=progress)
        res.pop("_runs")
        results.append(res)
    return {"seed": seed, "runs": runs, "duration_s": params.duration_s, "dt_s": params.dt, "cases": results}


# ----------------------------------------------------------------------------- sensitivity

#: The settings the paper does not give, one change at a time from the defaults:
#: (label, ``[control]`` overrides).
SENSITIVITY: tuple[tuple[str, dict[str, Any]], ...] = (
    ("defaults", {}),
    ("k_wt = 0.01", {"k_wt": 0.01}),
    ("dp_turn = 0.7", {"dp_turn": 0.7}),
    ("(29) over 1 s in (30)", {"equivalent_period": "fixed", "equivalent_period_s": 1.0}),
    ("beta_e = 1.5 s", {"beta_e": [1.5, 1.5]}),
    ("margin of (40) = 1", {"margin": 1.0}),
    ("speed-loop model", {"hybrid_model": "speed-loop"}),
)


def run_sensitivity(
    runs: int = 100,
    seed: int = 0,
    cfg: ControlConfig | None = None,
    params: StudyParams | None = None,
    *,
    settings: tuple[tuple[str, dict[str, Any]], ...] = SENSITIVITY,
    cases: tuple[DelayCase, ...] = CASES,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Compare CP and VP for every setting of ``settings`` (each one a change of ``cfg``).

    Returns
    -------
    dict
        ``{"seed", "runs", "duration_s", "settings": [{"label", "overrides", "cases"}]}``;
        each ``cases`` is what :func:`run_study` returns for that configuration.
    """
    import dataclasses

    base = cfg or ControlConfig()
    params = params or StudyParams()
    out = []
    for label, overrides in settings:
        try:
            c = dataclasses.replace(base, **overrides)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"sensitivity setting {label!r}: {exc}") from None
        res = run_study(runs, seed, c, params, cases=cases, progress=progress)
        out.append({"label": label, "overrides": overrides, "cases": res["cases"]})
        LOG.info("sensitivity: %s done", label)
    return {"seed": seed, "runs": runs, "duration_s": params.duration_s, "settings": out}


def _fmt_ci(s: dict[str, Any], channel: str) -> str:
    lo, hi = s[f"{channel}_ci95"]
    return f"{s[f'{channel}_error']:.2f} [{lo:.2f}, {hi:.2f}]"


def sensitivity_markdown(result: dict[str, Any]) -> str:
    """Return one markdown table of a sensitivity run.

    Per setting and case: CP and VP errors with 95 % CIs per channel, the periodic-orbit
    offsets, and VP's chosen ``(sigma_r, T)`` (time means over the case).
    """
    lines = [
        f"{result['runs']} CP + {result['runs']} VP runs per case, {result['duration_s']:g} s each, "
        f"seed {result['seed']}. Errors: mean of the time-mean |eq. (6)| [cm/s] and |eq. (10)| [deg/s] "
        "with 95 % CI; offset: periodic-orbit offset (same units); sigma_e off floor: channels where (40) "
        "lifted sigma_e (f = forward, t = turn).",
        "",
        "| setting | case | sigma_e off floor | CP forward | VP forward | CP turn | VP turn "
        "| offset fwd CP / VP | VP sigma_r | VP T [s] |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for st in result["settings"]:
        for c in st["cases"]:
            cp, vp = c["cp"], c["vp"]
            off = "".join(ch for ch, on in zip("ft", c["s_e"]["floor_left"], strict=True) if on) or "-"
            s_r = ", ".join(f"{v:.2f}" for v in vp["mean_s_r"])
            lines.append(
                f"| {st['label']} | {c['name']} | {off} | {_fmt_ci(cp, 'forward')} | "
                f"{_fmt_ci(vp, 'forward')} | {_fmt_ci(cp, 'turn')} | {_fmt_ci(vp, 'turn')} | "
                f"{cp['forward_orbit_offset']:.2f} / {vp['forward_orbit_offset']:.2f} | [{s_r}] | {vp['mean_T_s']:.2f} |"
            )
    return "\n".join(lines) + "\n"


def study_markdown(result: dict[str, Any]) -> str:
    """Return a markdown table of a study (reduced or walker).

    Per case: CP and VP errors with 95 % CIs per channel, VP's mean choice, and the
    failures (diverged runs; falls on the walker).
    """
    lines = [
        f"{result['runs']} CP + {result['runs']} VP runs per case, {result['duration_s']:g} s each, "
        f"seed {result['seed']}. Mean of the time-mean |eq. (6)| [cm/s] and |eq. (10)| [deg/s], 95 % CI.",
        "",
        "| case | h1 / h2 [ms] | CP forward | VP forward | CP turn | VP turn | VP sigma_r | VP T [s] | failed CP / VP |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for c in result["cases"]:
        cp, vp = c["cp"], c["vp"]
        s_r = ", ".join(f"{v:.2f}" for v in vp["mean_s_r"])
        fail = f"{cp.get('falls', cp['diverged'])} / {vp.get('falls', vp['diverged'])}"
        lines.append(
            f"| {c['name']} | {c['h1_ms']:.0f} / {c['h2_ms']:.0f} | {_fmt_ci(cp, 'forward')} | "
            f"{_fmt_ci(vp, 'forward')} | {_fmt_ci(cp, 'turn')} | {_fmt_ci(vp, 'turn')} | "
            f"[{s_r}] | {vp['mean_T_s']:.2f} | {fail} |"
        )
    return "\n".join(lines) + "\n"
