"""The comparison's runner: one scheme over one regime's inputs on the reduced closed loop.

Every registered scheme (:mod:`bipedtele.control.schemes`) runs the same ``runs`` operators
(intentions, hand) over the same delays and losses of a regime, so run ``i`` of one scheme
and run ``i`` of another differ only by the scheme: the differences are paired. Each run
draws its own realisation of the regime's delay process and losses (:func:`regime_inputs`),
so the runs spread over the delays as well as over the operators; everything that follows
from the delays (the channel, the delay estimate, the damping, the online choice (30) and
the impact times) is each run's own. The loop is
the study's (:mod:`bipedtele.studies.study`: simulated operator and handle (1), (31)-(32);
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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.follower_step import FollowerCommand, FollowerController, equivalent_steps
from bipedtele.control.leader_step import LeaderController, LeaderFeedback, LeaderHandle
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import SimulatedLeader, StudyParams, channel, hybrid_zoh
from bipedtele.control.schemes import Scheme
from bipedtele.link.delaymodels import DelayModel, NormalDelay, TraceDelay, UniformDelay, parse_delay_model
from bipedtele.studies.regimes import CompareParams, Regime
from bipedtele.studies.study import DelayCase, case_inputs

__all__ = ["RegimeInputs", "controllers", "regime_inputs", "simulate"]


@dataclass(frozen=True)
class RegimeInputs:
    """What one regime feeds every scheme: delays, losses and the operators, drawn per run (paired).

    Attributes
    ----------
    h1, h2 : numpy.ndarray
        One-way delay of the message sent at each step [s], shape (runs, K): run ``i``'s own
        realisation of the regime's delay process.
    lost1, lost2 : numpy.ndarray
        Whether that message is lost, shape (runs, K), bool.
    switch, intent : numpy.ndarray
        The operators (:class:`~bipedtele.studies.study.CaseInputs`), one per run.
    seed : int
        The seed every draw came from (run ``i``'s delays and losses from ``(seed, i)``).
    """

    h1: np.ndarray
    h2: np.ndarray
    lost1: np.ndarray
    lost2: np.ndarray
    switch: np.ndarray
    intent: np.ndarray
    seed: int = 0


#: Tag of the per-run delay and loss streams (``default_rng([seed, tag, run])``), apart
#: from the operators' stream.
_DELAY_STREAM = 35


def regime_inputs(regime: Regime, runs: int, seed: int, cfg: ControlConfig, params: StudyParams) -> RegimeInputs:
    """Draw a regime's delays, losses and operators, each run its own (seeded; equal for every scheme).

    Run ``i`` draws its delays and losses from ``(seed, i)``, so the draws differ across runs,
    are the same for every scheme given the same inputs (the pairing) and repeat with the
    seed. A random delay model (``uniform``, ``normal``) draws every message's delay afresh
    per run; a trace (``trace:intercontinental:h1``) is one recording, so run ``i`` reads it
    from its own random starting offset, uniform over the trace's loop period in whole steps (its ``h1``
    and ``h2`` columns from the same offset: one path, both directions); a step regime is
    the same deterministic step in every run. The operators are drawn per run as the
    study draws them (:func:`~bipedtele.studies.study.case_inputs`).
    """
    case = DelayCase(regime.name, regime.h1, regime.h2, regime.description)
    inp = case_inputs(case, runs, seed, cfg, params)
    k_steps = round(params.duration_s / params.dt)
    t_grid = np.arange(k_steps) * params.dt
    h1, h2 = np.empty((runs, k_steps)), np.empty((runs, k_steps))
    lost1, lost2 = np.empty((runs, k_steps), bool), np.empty((runs, k_steps), bool)
    models = (parse_delay_model(regime.h1), parse_delay_model(regime.h2))
    for i in range(runs):
        rng = np.random.default_rng([seed, _DELAY_STREAM, i])
        if regime.step_s is not None:
            before, after = regime.step_s
            h1[i] = np.where(np.arange(k_steps) >= k_steps // 2, after, before)
            h2[i] = h1[i]
        else:
            offset = float(rng.uniform(0.0, 1.0))  # a trace's start, as a fraction of its loop
            h1[i] = _draw_delays(models[0], rng, t_grid, offset) * regime.scale
            h2[i] = _draw_delays(models[1], rng, t_grid, offset) * regime.scale
        lost1[i] = rng.random(k_steps) < regime.loss
        lost2[i] = rng.random(k_steps) < regime.loss
    return RegimeInputs(h1, h2, lost1, lost2, inp.switch, inp.intent, seed)


def _draw_delays(model: DelayModel, rng: np.random.Generator, t_grid: np.ndarray, offset: float) -> np.ndarray:
    """One realisation of a delay model at the send times ``t_grid`` [s].

    A trace is read from ``offset`` (a fraction of its loop period, rounded down to a whole
    number of steps ``t_grid[1]``) on, looped and linearly interpolated (:class:`~bipedtele.link.delaymodels.TraceDelay`); a random model draws
    each message's delay from ``rng`` with the model's distribution (uniform: clipped at 0;
    normal: redrawn while negative); another model (constant) is asked one message at a time.
    """
    n = t_grid.size
    if isinstance(model, TraceDelay):
        t0, period = model.t[0], model.period
        dt = float(t_grid[1] - t_grid[0]) if n > 1 else 1.0
        start = np.floor(offset * period / dt) * dt
        tau = t0 + (start + t_grid) % period
        return np.interp(tau, [*model.t, t0 + period], [*model.d, model.d[0]])
    if isinstance(model, UniformDelay):
        return np.maximum(0.0, rng.uniform(model.mean - model.half_width, model.mean + model.half_width, n))
    if isinstance(model, NormalDelay):
        d = rng.normal(model.mean, model.std, n)
        for _ in range(64):
            neg = d < 0.0
            if not neg.any():
                break
            d[neg] = rng.normal(model.mean, model.std, int(neg.sum()))
        return np.maximum(d, 0.0)
    return np.array([model.delay_s(float(t)) for t in t_grid])


def _equivalent_steps(s_e_k: np.ndarray, cfg: ControlConfig, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact ZOH of (29) for every distinct ``sigma_e`` of the runs, and which one each run and step uses.

    ``s_e_k`` has shape (runs, K, 2); the index returned has shape (runs, K).
    """
    # unique over the pairs read as complex numbers: a sort of one key, not of rows (the same set)
    pairs = np.ascontiguousarray(s_e_k.reshape(-1, 2), dtype=float)
    uniq, inverse = np.unique(pairs.view(np.complex128).ravel(), return_inverse=True)
    phi, gam = equivalent_steps(np.column_stack([uniq.real, uniq.imag]), cfg, dt)
    return phi, gam, inverse.reshape(s_e_k.shape[:2])


def _per_run_damping(scheme: Scheme, est1: np.ndarray, est2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the scheme's damping for each run's own delay estimates (``(runs, K)``): two ``(runs, K, 2)`` arrays."""
    pairs = [scheme.damping(est1[i], est2[i]) for i in range(est1.shape[0])]
    return np.stack([a for a, _ in pairs]), np.stack([s for _, s in pairs])


def controllers(scheme: Scheme, cfg: ControlConfig) -> tuple[LeaderController, FollowerController]:
    """Return the leader's and the follower's steps as the comparison runs them.

    The real loops' steps (:mod:`bipedtele.control.leader_step`,
    :mod:`bipedtele.control.follower_step`) with every port's energy counted, whatever the
    scheme (the comparison reports each port's passivity observer), and no speed limit.
    """
    k_m = np.asarray(cfg.k_m, dtype=float)
    return (
        LeaderController(scheme, k_m, observe_every_port=True),
        FollowerController(scheme, k_m, observe_every_port=True),
    )


class _Loop:
    """State of ``n`` paired runs of one scheme on one regime."""

    def __init__(self, scheme: Scheme, inp: RegimeInputs, cfg: ControlConfig, cp: CompareParams) -> None:
        p = cp.study
        self.scheme, self.cfg, self.dt = scheme, cfg, p.dt
        self.n = n = inp.switch.shape[0]
        self.ch1 = channel(inp.h1, p.dt, p.window_s, inp.lost1)
        self.ch2 = channel(inp.h2, p.dt, p.window_s, inp.lost2)
        self.alpha_k, self.s_e_k = _per_run_damping(scheme, self.ch1.estimate, self.ch2.estimate)
        self.phi_eq, self.gam_eq, self.eq_index = _equivalent_steps(self.s_e_k, cfg, p.dt)
        w = round(cfg.wave_window_s / p.dt)  # every runner's window, passed to the scheme (docs/schemes.md)
        self.gain1 = np.stack([scheme.received_gains(row, w) for row in self.ch1.idx])[..., None]
        self.gain2 = np.stack([scheme.received_gains(row, w) for row in self.ch2.idx])[..., None]
        self.leader = SimulatedLeader(inp.switch, inp.intent, cfg, p)
        self.k_g = np.asarray(cfg.k_g, dtype=float)
        self.k_m = np.asarray(cfg.k_m, dtype=float)
        self.dp = np.array([cfg.dp, cfg.dp_turn])
        self.lead_ctl, self.foll_ctl = controllers(scheme, cfg)
        self.lead_state, self.foll_state = self.lead_ctl.initial(n), self.foll_ctl.initial(n)
        self.eq_k = -1  # the period the equivalent follower was last advanced to
        self.hy = np.zeros((n, 2, 2))  # [eta, z_r] per channel
        self.cmd_buf = np.zeros((self.ch1.ring, n, 2))  # k_g x_m sent
        self.wave_buf = np.zeros((self.ch1.ring, n, 2))  # u_m sent
        self.ein_m_buf = np.zeros((self.ch1.ring, n, 2))  # leader port's input energy sent
        self.fb_buf = np.zeros((self.ch2.ring, n, 2))  # z_e, eta or v_s sent back
        self.ein_s_buf = np.zeros((self.ch2.ring, n, 2))
        self.sums = {m: np.zeros((n, 2)) for m in ("error", "intent", "force2", "effort")}
        self.peak = np.zeros(n)
        self.late_from = round(0.75 * inp.h1.shape[1])
        self.rows = np.arange(n)
        self.late_v2 = np.zeros((n, 2))

    def _received(self, buf: np.ndarray, idx: np.ndarray, ring: int) -> np.ndarray:
        """Each run's newest message arrived (``idx`` per run, -1: none yet: zeros)."""
        return np.where((idx >= 0)[:, None], buf[idx % ring, self.rows], 0.0)

    def leader_tick(self, k: int, t: float) -> None:
        """Advance the leader: the step's force from what arrived, the handle moves, the command it sends."""
        i2, ring2 = self.ch2.idx[:, k], self.ch2.ring
        k_m = self.k_m
        r_now = self.k_g * self.leader.x
        fb = LeaderFeedback(
            self._received(self.fb_buf, i2, ring2), self._received(self.ein_s_buf, i2, ring2), self.gain2[:, k]
        )
        self.lead_state, law = self.lead_ctl.force(self.lead_state, LeaderHandle(r_now, self.dt), fb)
        f_m = law.force
        eta = self.hy[..., 0]
        self.sums["force2"] += (f_m - k_m * (r_now - eta)) ** 2
        # the simulated handle renders the force: it follows r - F/k_m (law.followed(), to rounding)
        x = self.leader.step(t, r_now - f_m / k_m, self.alpha_k[:, k])
        self.sums["effort"] += np.abs(self.leader.f_h)
        if k >= self.late_from:
            self.late_v2 += self.leader.v**2
        r_m = self.k_g * x
        slot = k % self.ch1.ring
        self.cmd_buf[slot] = r_m
        cmd = self.lead_ctl.command(self.lead_state, r_m)  # sent once the handle moved
        self.ein_m_buf[slot] = cmd.energy
        if cmd.wave is not None:
            self.wave_buf[slot] = cmd.wave

    def _equivalent(self, k: int, ref: np.ndarray) -> np.ndarray:
        """Advance the step's equivalent follower (29) to period ``k`` on ``ref``; return ``z_e``.

        Advanced once per period however often the scheme asks (and never for a scheme that
        does not ask: it is the comparison's costliest step).
        """
        if self.eq_k != k:
            self.eq_k = k
            j = self.eq_index[:, k]
            self.foll_state = self.foll_ctl.equivalent(self.foll_state, ref, (self.phi_eq[j], self.gam_eq[j]), None)
        return np.asarray(self.foll_state.eq[:, :, 1])

    def follower_tick(self, k: int, hybrid: tuple[np.ndarray, np.ndarray]) -> None:
        """Advance the follower: the step's command from the newest arrived, the robot moves, the feedback it sends."""
        i1, ring1 = self.ch1.idx[:, k], self.ch1.ring
        ref = self._received(self.cmd_buf, i1, ring1)
        eta = self.hy[..., 0]
        cmd = FollowerCommand(
            ref, self._received(self.wave_buf, i1, ring1), self._received(self.ein_m_buf, i1, ring1), self.gain1[:, k]
        )
        self.foll_state, c, _ = self.foll_ctl.command(self.foll_state, cmd, eta, self.dt)
        phi_h, gam_h = hybrid
        h0 = phi_h[..., 0, 0] * self.hy[..., 0] + phi_h[..., 0, 1] * self.hy[..., 1] + gam_h[..., 0] * c
        h1 = phi_h[..., 1, 0] * self.hy[..., 0] + phi_h[..., 1, 1] * self.hy[..., 1] + gam_h[..., 1] * c
        self.hy = np.stack([h0, h1], -1)
        fb = self.foll_ctl.feedback(self.foll_state, self.hy[..., 0], lambda: self._equivalent(k, ref))
        self.fb_buf[k % self.ch2.ring] = fb.signal
        self.ein_s_buf[k % self.ch2.ring] = fb.energy
        self.sums["error"] += np.abs(ref - self.hy[..., 0])
        lead = self.leader
        self.sums["intent"] += np.abs(lead.intent[lead.rows, lead.seg] - self.hy[..., 0])
        self.peak = np.maximum(self.peak, np.abs(self.hy[..., 0]).max(axis=1))


class _Cycles:
    """Each run's walking cycle: the online choice (30) for its own ``sigma_e``, taken at its impacts.

    Every run's impacts and choices are planned before the runs start: a run's cycle
    depends only on its own ``sigma_e`` over time, so the runs advance impact by impact side
    by side and each round's choices are solved together
    (:meth:`~bipedtele.control.online.OnlineChooser.choose_many`); the phase's arithmetic is
    the one a tick-by-tick runner does, so the impacts fall on the same steps.

    Parameters
    ----------
    chooser : OnlineChooser
        Solves (30).
    s_e_k : numpy.ndarray
        Each run's equivalent damping per step, (runs, K, 2).
    cfg : ControlConfig
        The follower's gains.
    dt : float
        Control period [s].
    """

    def __init__(self, chooser: OnlineChooser, s_e_k: np.ndarray, cfg: ControlConfig, dt: float) -> None:
        self.cfg, self.dt = cfg, dt
        self.s_r, T = chooser.choose_many(s_e_k[:, 0])
        self.phi, self.gam = hybrid_zoh(self.s_r, cfg, dt)
        self._plan = _plan_impacts(chooser, s_e_k, T, dt)

    def advance(self, k: int) -> np.ndarray:
        """Advance one period after step ``k``; return which runs hit an impact (their next cycle taken)."""
        hit = np.zeros(self.s_r.shape[0], dtype=bool)
        due = self._plan.get(k)
        if due is not None:
            rows, s_r = due
            hit[rows] = True
            self.s_r[rows] = s_r
            self.phi[hit], self.gam[hit] = hybrid_zoh(self.s_r[hit], self.cfg, self.dt)
        return hit


def _plan_impacts(
    chooser: OnlineChooser, s_e_k: np.ndarray, T: np.ndarray, dt: float
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Return step -> (the runs that hit an impact after it, ascending; the ``s_r`` each takes there).

    Each run's phase grows by ``dt`` a step and wraps at its cycle ``T`` (an impact: the
    next cycle chosen for ``sigma_e`` at that step); all runs advance to their next impact
    side by side, and that round's choices are solved together.
    """
    n, k_steps = s_e_k.shape[:2]
    T = np.array(T, dtype=float)
    phase = np.zeros(n)
    k_next = np.zeros(n, dtype=np.intp)  # each run's next step to advance
    rounds: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    live = k_next < k_steps
    while live.any():
        hit_at = np.full(n, -1, dtype=np.intp)
        moving = live.copy()
        while moving.any():
            phase[moving] += dt
            hit = moving & (phase >= T - 1e-9)
            hit_at[hit] = k_next[hit]
            phase[hit] -= T[hit]
            k_next[moving] += 1
            moving &= ~hit & (k_next < k_steps)
        rows = np.flatnonzero(hit_at >= 0)
        if rows.size:
            s_r, T[rows] = chooser.choose_many(s_e_k[rows, hit_at[rows]])
            rounds.append((hit_at[rows], rows, s_r))
        live = k_next < k_steps
    plan: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for ks, rows, s_r in rounds:
        for k in np.unique(ks):
            at = ks == k
            plan.setdefault(int(k), []).append((rows[at], s_r[at]))
    out = {}
    for k, parts in plan.items():
        rows = np.concatenate([r for r, _ in parts])
        order = np.argsort(rows, kind="stable")
        out[k] = (rows[order], np.concatenate([s for _, s in parts])[order])
    return out


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
    k_steps = inp.h1.shape[1]
    loop = _Loop(scheme, inp, cfg, cp)
    if release:
        loop.leader.release_t = cp.release_fraction * k_steps * p.dt
    cycle = _Cycles(chooser, loop.s_e_k, cfg, p.dt)
    report_every = max(1, k_steps // 50)
    for k in range(k_steps):
        loop.leader_tick(k, k * p.dt)
        loop.follower_tick(k, (cycle.phi, cycle.gam))
        hit = cycle.advance(k)
        if hit.any():  # impact: reset; those runs take the next cycle's parameters (30)
            loop.hy[hit, :, 0] *= loop.dp
        if progress is not None and (k + 1) % report_every == 0:
            progress(report_every)
    out: dict[str, np.ndarray] = {}
    for c, ch in enumerate(("forward", "turn")):
        out[f"{ch}_error"] = loop.sums["error"][:, c] / k_steps
        out[f"{ch}_intent_error"] = loop.sums["intent"][:, c] / k_steps
        out[f"{ch}_force_error"] = np.sqrt(loop.sums["force2"][:, c] / k_steps)
        out[f"{ch}_effort"] = loop.sums["effort"][:, c] / k_steps
        out[f"{ch}_po_leader"] = loop.lead_state.min_observer[:, c]
        out[f"{ch}_po_follower"] = loop.foll_state.min_observer[:, c]
    out["peak"] = loop.peak
    limit = cp.unstable_factor * max(p.forward_range[1], p.turn_max)
    out["unstable"] = ~np.isfinite(loop.peak) | (loop.peak > limit)
    out["released_motion"] = np.sqrt(loop.late_v2 / max(1, k_steps - loop.late_from)).max(axis=1)
    out["oscillating"] = out["unstable"] | ~(out["released_motion"] <= cp.oscillation_m_s)
    return out
