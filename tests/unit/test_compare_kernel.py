"""The comparison's runner draws each run its own delays and losses, paired across schemes."""

from __future__ import annotations

import numpy as np
import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import StudyParams
from bipedtele.control.schemes import scheme_class
from bipedtele.link.delaymodels import parse_delay_model
from bipedtele.studies.compare_kernel import RegimeInputs, regime_inputs, simulate
from bipedtele.studies.regimes import CompareParams, Regime

pytestmark = pytest.mark.compute  # CPU-bound and deterministic (scripts/test.sh)

CFG = ControlConfig()
PARAMS = StudyParams(duration_s=6.0)
TRACE = Regime("trace", "the shipped trace")
LOSSY = Regime("lossy", "uniform, lossy", "uniform:300ms:100ms", "normal:200ms:80ms", loss=0.1)


@pytest.mark.timeout(60)
@pytest.mark.parametrize("regime", [TRACE, LOSSY], ids=["trace", "random"])
def test_every_run_draws_its_own_delays_and_losses(regime: Regime) -> None:
    inp = regime_inputs(regime, 5, 3, CFG, PARAMS)
    k_steps = round(PARAMS.duration_s / PARAMS.dt)
    for a in (inp.h1, inp.h2, inp.lost1, inp.lost2):
        assert a.shape == (5, k_steps)
    assert inp.seed == 3
    for i in range(5):
        for j in range(i + 1, 5):
            assert not np.array_equal(inp.h1[i], inp.h1[j])
            assert not np.array_equal(inp.h2[i], inp.h2[j])
            if regime.loss > 0:
                assert not np.array_equal(inp.lost1[i], inp.lost1[j])
    if regime.loss > 0:
        assert 0.05 < inp.lost1.mean() < 0.15 and 0.05 < inp.lost2.mean() < 0.15
        assert abs(inp.h1.mean() - 0.3) < 0.01 and inp.h1.min() >= 0.2 - 1e-12 and inp.h1.max() <= 0.4 + 1e-12
        assert abs(inp.h2.mean() - 0.2) < 0.01 and inp.h2.min() >= 0.0
    else:
        assert not inp.lost1.any() and not inp.lost2.any()


@pytest.mark.timeout(60)
def test_a_trace_run_reads_the_trace_from_its_own_offset() -> None:
    inp = regime_inputs(Regime("x2", "x2", scale=2.0), 4, 1, CFG, PARAMS)
    t_grid = np.arange(inp.h1.shape[1]) * PARAMS.dt
    offsets = []
    for col, h in (("h1", inp.h1), ("h2", inp.h2)):
        model = parse_delay_model(f"trace:intercontinental:{col}")
        # every run is the recording (scaled) read from some start: find it on a 0.01 s grid
        starts = np.arange(0.0, model.period, PARAMS.dt)
        heads = np.array([model.delay_s(s) for s in starts])
        run_offsets = []
        for row in h:
            candidates = starts[np.abs(2.0 * heads - row[0]) < 1e-9]
            match = [s for s in candidates if np.allclose(row[:50], [2.0 * model.delay_s(s + t) for t in t_grid[:50]])]
            assert match, col
            run_offsets.append(match[0])
        offsets.append(run_offsets)
        assert len({round(s, 6) for s in run_offsets}) == 4
    assert np.allclose(offsets[0], offsets[1])  # both directions read from the same start


@pytest.mark.timeout(60)
def test_the_same_seed_gives_the_same_draws_and_another_seed_others() -> None:
    for regime in (TRACE, LOSSY):
        a, b = regime_inputs(regime, 3, 7, CFG, PARAMS), regime_inputs(regime, 3, 7, CFG, PARAMS)
        c = regime_inputs(regime, 3, 8, CFG, PARAMS)
        for f in ("h1", "h2", "lost1", "lost2", "switch", "intent"):
            assert np.array_equal(getattr(a, f), getattr(b, f)), f
        assert not np.array_equal(a.h1, c.h1) and not np.array_equal(a.h2, c.h2)
    # run i's draws do not depend on how many runs there are
    few, many = regime_inputs(LOSSY, 2, 7, CFG, PARAMS), regime_inputs(LOSSY, 4, 7, CFG, PARAMS)
    assert np.array_equal(few.h1, many.h1[:2]) and np.array_equal(few.lost2, many.lost2[:2])


def _run(name: str, inp: RegimeInputs) -> dict[str, np.ndarray]:
    cp = CompareParams(study=PARAMS)
    worst = (float(inp.h1.max()), float(inp.h2.max()))
    return simulate(scheme_class(name)(CFG, worst), inp, CFG, cp, OnlineChooser(CFG))


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", ["paper", "wave", "pd-measured"])
def test_each_run_of_every_scheme_runs_on_its_own_draws(name: str) -> None:
    """The runner indexes per run: changing run 0's delays changes run 0 only, for any scheme."""
    inp = regime_inputs(LOSSY, 3, 2, CFG, PARAMS)
    h1 = inp.h1.copy()
    h1[0] *= 3.0
    moved = RegimeInputs(h1, inp.h2, inp.lost1, inp.lost2, inp.switch, inp.intent, inp.seed)
    base, other = _run(name, inp), _run(name, moved)
    for metric in ("forward_error", "turn_error", "forward_force_error", "forward_effort"):
        assert base[metric][0] != other[metric][0], metric
        assert np.array_equal(base[metric][1:], other[metric][1:]), metric


@pytest.mark.timeout(120)
def test_run_i_of_every_scheme_sees_the_same_draws() -> None:
    """The pairing: run i of each scheme is run i of the regime's inputs, whoever else runs."""
    inp = regime_inputs(LOSSY, 3, 4, CFG, PARAMS)
    alone = RegimeInputs(*(a[1:2] for a in (inp.h1, inp.h2, inp.lost1, inp.lost2, inp.switch, inp.intent)), inp.seed)
    for name in ("paper", "wave"):
        together, single = _run(name, inp), _run(name, alone)
        for metric in ("forward_error", "turn_intent_error", "forward_po_follower"):
            assert together[metric][1] == pytest.approx(single[metric][0], abs=1e-12), (name, metric)


def _cycles_tick_by_tick(chooser: OnlineChooser, s_e_k: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The runner's cycles as a tick-by-tick loop advances them: which runs hit at each step, and their s_r after it."""
    n, k_steps = s_e_k.shape[:2]
    first = [chooser.choose(s) for s in s_e_k[:, 0]]
    s_r, T, phase = np.stack([c.s_r for c in first]), np.array([c.T for c in first]), np.zeros(n)
    hits, s_rs = np.zeros((n, k_steps), dtype=bool), np.zeros((n, k_steps, 2))
    for k in range(k_steps):
        phase += dt
        hit = phase >= T - 1e-9
        phase[hit] -= T[hit]
        for i in np.flatnonzero(hit):
            c = chooser.choose(s_e_k[i, k])
            s_r[i], T[i] = c.s_r, c.T
        hits[:, k], s_rs[:, k] = hit, s_r
    return hits, s_rs


def test_the_planned_cycles_are_those_of_a_tick_by_tick_runner() -> None:
    """The comparison plans every run's impacts and choices (30) ahead, solving each round
    together: the impacts fall on the same steps and take the same s_r as a loop that
    advances every run's phase tick by tick and chooses at each impact."""
    from bipedtele.studies.compare_kernel import _Cycles

    cfg, dt = ControlConfig(), 0.01
    chooser = OnlineChooser(cfg)
    rng = np.random.default_rng(3)
    # per-run sigma_e that moves (the scheduled damping of each run's own delays)
    s_e_k = np.cumsum(rng.normal(0.0, 0.02, (12, 700, 2)), axis=1) + rng.uniform(0.2, 3.0, (12, 1, 2))
    s_e_k = np.clip(s_e_k, 0.05, 6.0)
    hits, s_rs = _cycles_tick_by_tick(chooser, s_e_k, dt)
    cycles = _Cycles(chooser, s_e_k, cfg, dt)
    for k in range(s_e_k.shape[1]):
        hit = cycles.advance(k)
        assert np.array_equal(hit, hits[:, k]), k
        assert np.array_equal(cycles.s_r, s_rs[:, k]), k
    assert hits.sum() > 5 * s_e_k.shape[0]  # many impacts per run, at different steps
