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
