"""Online choice (30): exact solver, table, brute force, infeasible case."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.control.equivalent import equivalent_spectral_radius
from bipedtele.control.hybrid import rho_blocks
from bipedtele.control.online import Choice, OnlineChooser, choice_cost
from bipedtele.control.online import solve_exact as _solve_exact

pytestmark = pytest.mark.compute  # CPU-bound and deterministic: run beside the other unit tests (scripts/test.sh)

CFG = ControlConfig()


@cache
def _exact_cached(s_e: tuple[float, float]) -> Choice:
    return _solve_exact(list(s_e), CFG)


def solve_exact(s_e: list[float], cfg: ControlConfig) -> Choice:
    if cfg is CFG:
        return _exact_cached((s_e[0], s_e[1]))
    return _solve_exact(s_e, cfg)


S_E = [[0.05, 0.05], [0.5, 0.05], [2.0, 1.0], [0.05, 3.0], [6.0, 6.0]]


@pytest.fixture(scope="module")
def chooser() -> OnlineChooser:
    return OnlineChooser(CFG)


def _brute(s_e: list[float], cfg: ControlConfig) -> float:
    sig = np.linspace(0, 10, 41)[:, None, None, None]
    tau = np.linspace(0, 10, 41)[None, :, None, None]
    T = np.linspace(0.5, 5, 19)[None, None, :, None]
    eps = np.linspace(0.05, 1.0, 20)[None, None, None, :]
    rh = np.maximum.reduce(np.broadcast_arrays(*rho_blocks(sig, tau, T, eps, cfg.dp, cfg)))
    re = equivalent_spectral_radius(np.asarray(s_e), cfg, T)
    ok = np.abs(rh - re) <= cfg.tolerance
    cost = cfg.k_sigma * (np.abs(sig - s_e[0]) + np.abs(tau - s_e[1])) + cfg.k_wt * T + cfg.k_eps * eps
    cost = np.broadcast_to(cost, ok.shape)
    assert ok.any()
    return float(cost[ok].min())


@pytest.mark.timeout(60)
@pytest.mark.parametrize("s_e", S_E)
def test_exact_is_no_worse_than_brute_force_and_in_tolerance(s_e: list[float]) -> None:
    ex = solve_exact(s_e, CFG)
    assert ex.feasible
    assert abs(ex.residual) <= CFG.tolerance
    assert ex.cost <= _brute(s_e, CFG) + 1e-9
    # Choice fields are consistent with the model
    assert ex.cost == pytest.approx(choice_cost(ex.s_r, ex.T, ex.eps, s_e, CFG))
    assert ex.rho_equivalent == pytest.approx(equivalent_spectral_radius(s_e, CFG, ex.T))
    lo, hi = CFG.s_r_range
    assert np.all((ex.s_r >= lo) & (ex.s_r <= hi)) and CFG.T_range[0] <= ex.T <= CFG.T_range[1]


@pytest.mark.parametrize("s_e", S_E)
def test_table_agrees_with_exact(chooser: OnlineChooser, s_e: list[float]) -> None:
    on = chooser.choose(s_e)
    ex = solve_exact(s_e, CFG)
    assert on.feasible
    assert abs(on.residual) <= CFG.tolerance  # exact residual of the tabulated answer
    assert on.cost >= ex.cost - 1e-9
    # same optimum up to the table's T step and its narrowed band
    assert on.cost - ex.cost <= CFG.k_wt * (chooser.T[1] - chooser.T[0]) + 0.05
    assert abs(on.rho_hybrid - ex.rho_hybrid) <= 2 * CFG.tolerance


def test_other_weights_move_the_optimum(chooser: OnlineChooser) -> None:
    cfg = ControlConfig(k_wt=0.0, k_sigma=1.0, k_eps=0.1)
    on = OnlineChooser(cfg).choose([0.05, 0.05])
    ex = solve_exact([0.05, 0.05], cfg)
    assert abs(on.residual) <= cfg.tolerance and abs(ex.residual) <= cfg.tolerance
    assert on.cost == pytest.approx(ex.cost, abs=0.05)
    assert ex.cost <= _brute([0.05, 0.05], cfg) + 1e-9


def test_infeasible_is_flagged_with_nearest_rho(chooser: OnlineChooser) -> None:
    # huge equivalent damping: max|l_equivalent| above anything the hybrid reaches in bounds
    on = chooser.choose([60.0, 60.0])
    ex = solve_exact([60.0, 60.0], CFG)
    for c in (on, ex):
        assert not c.feasible
        assert c.residual < -CFG.tolerance
        np.testing.assert_allclose(c.s_r, CFG.s_r_range[1])
    assert on.residual == pytest.approx(ex.residual, abs=1e-9)


def test_fixed_discretisation_period_lets_T_follow_the_delay() -> None:
    from bipedtele.control.damping import schedule_damping

    cycle = OnlineChooser(CFG)
    fixed_cfg = ControlConfig(equivalent_period="fixed", equivalent_period_s=1.0)
    fixed = OnlineChooser(fixed_cfg)
    Ts_cycle, Ts_fixed = [], []
    for h in (0.002, 1.5, 3.5):
        s_e = schedule_damping(h, h, CFG).s_e
        Ts_cycle.append(cycle.choose(s_e).T)
        c = fixed.choose(s_e)
        assert c.feasible and abs(c.residual) <= fixed_cfg.tolerance
        assert c.rho_equivalent == pytest.approx(equivalent_spectral_radius(s_e, fixed_cfg, 1.0))
        Ts_fixed.append(c.T)
    assert Ts_cycle == [CFG.T_range[0]] * 3  # with the cycle as period T stays at its bound
    assert Ts_fixed[0] < Ts_fixed[1] < Ts_fixed[2]  # over a fixed period it grows with the delay


def test_speed_loop_model_switch(caplog: pytest.LogCaptureFixture) -> None:
    cal = ControlConfig(hybrid_model="speed-loop", calibrated_dp=0.95, calibrated_k_v=2.0)
    hm = cal.hybrid()
    assert hm.dp == 0.95 and hm.k_s == [2.0, CFG.k_s[1]] and cal.k_s == CFG.k_s
    assert CFG.hybrid() is CFG
    with caplog.at_level("INFO", logger="bipedtele.control.online"):
        chooser = OnlineChooser(cal)
    assert chooser.model == "speed-loop"
    assert any("speed-loop reduced model" in r.getMessage() and "dp 0.950" in r.getMessage() for r in caplog.records)
    c = chooser.choose([0.05, 0.05])
    ex = solve_exact([0.05, 0.05], cal)
    # both sides of (30) are evaluated with the speed-loop model
    assert c.rho_hybrid == pytest.approx(float(np.max(np.stack(rho_blocks(*c.s_r, c.T, c.eps, 0.95, hm)))))
    assert abs(c.residual) <= cal.tolerance and abs(ex.residual) <= cal.tolerance
    paper = OnlineChooser(CFG)
    assert not np.allclose(chooser._tab[0], paper._tab[0])  # the forward block is the identified one
    np.testing.assert_allclose(chooser._tab[1], paper._tab[1])  # the turn block is the paper's


def test_old_model_name_fails_with_the_allowed_values() -> None:
    from bipedtele.config.profile import ConfigError, load_config

    with pytest.raises(ConfigError) as err:
        load_config("default", ['control.hybrid_model="calibrated"'])
    msg = str(err.value)
    assert "\n" not in msg and all(v in msg for v in ("paper", "speed-loop", "walker"))


def test_choose_many_gives_the_answers_of_choose_one_by_one(chooser: OnlineChooser) -> None:
    """The batched solve (the comparison's per-run cycles) is the one-by-one solve, to the bit,
    across (40)'s range, its floor, and dampings out of the table (the infeasible fallback)."""
    rng = np.random.default_rng(7)
    s_e = np.vstack([np.array(S_E), rng.uniform(0.0, 8.0, (200, 2)), [[0.0, 0.0], [1e3, 0.05]]])
    s_r, T = chooser.choose_many(s_e)
    one = [chooser.choose(s) for s in s_e]
    assert np.array_equal(s_r, np.array([c.s_r for c in one]))
    assert np.array_equal(T, np.array([c.T for c in one]))
    assert not all(c.feasible for c in one)  # the fallback was exercised
    # a full memo starts again with the batch's answers (keys it held are solved again)
    chooser._many.clear()
    chooser.choose_many(s_e[:10])  # some of the batch held, the memo then nearly full
    chooser._many.update({(-1.0, float(i)): (np.zeros(2), 1.0) for i in range(65530 - len(chooser._many))})
    again_s_r, again_T = chooser.choose_many(s_e)
    assert np.array_equal(again_s_r, s_r) and np.array_equal(again_T, T)
    assert len(chooser._many) == len({tuple(row) for row in s_e})
    empty_s_r, empty_T = chooser.choose_many(np.zeros((0, 2)))
    assert empty_s_r.shape == (0, 2) and empty_T.shape == (0,)
