"""The walker-map surrogate of (30): the shipped table, the chooser on it, its regeneration, Newton."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bipedtele.cli import main
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser, WalkerSolver, solve_exact
from bipedtele.control.walker_map import (
    TABLE_FORMAT,
    WalkerTable,
    interp_weights,
    load_walker_table,
    parse_walker_table,
)

pytestmark = pytest.mark.compute  # CPU-bound and deterministic: run beside the other unit tests (scripts/test.sh)

WALKER = ControlConfig(hybrid_model="walker")
# equivalent damping from the scheduler's floor to well past the walker's turn limit cycle
S_E = [[a, b] for a in (0.05, 0.5, 1.0, 2.5, 4.0, 7.0) for b in (0.05, 0.5, 1.5, 2.5, 3.2, 3.75, 5.0, 8.0)]


def _synthetic(limit_tau: float = 3.5) -> dict[str, Any]:
    """A table shaped like the walker's: radius rising with damping, limit cycle at high tau."""
    sigma, tau, T = [0.0, 2.5, 5.0], [0.0, 1.0, 2.0, 3.0, 3.5, 5.0], [0.8, 1.2]
    rho = [[[0.7 + 0.03 * s + 0.04 * t - 0.05 * (c - 0.8) for c in T] for t in tau] for s in sigma]
    lc = [[[t >= limit_tau for _ in T] for t in tau] for _ in sigma]
    fallen = [[[False for _ in T] for _ in tau] for _ in sigma]
    return {
        "format": TABLE_FORMAT,
        "sigma": sigma,
        "tau": tau,
        "T": T,
        "eps": 0.05,
        "rho": rho,
        "limit_cycle": lc,
        "fallen": fallen,
    }


def _check_choices(table: WalkerTable, cfg: ControlConfig) -> int:
    chooser = OnlineChooser(cfg, walker_table=table)
    feasible = 0
    for s_e in S_E:
        c = chooser.choose(s_e)
        assert not table.in_unstable_region(float(c.s_r[0]), float(c.s_r[1]), c.T), (s_e, c)
        assert math.isfinite(c.rho_hybrid) and c.eps == table.eps
        assert table.T[0] <= c.T <= table.T[-1]
        if c.feasible:
            feasible += 1
            assert abs(c.residual) <= cfg.tolerance, (s_e, c)
    return feasible


@pytest.mark.timeout(30)
def test_shipped_table_is_well_formed() -> None:
    tab = load_walker_table()
    assert tab.source == "bipedtele.data/walker_map.json" and tab.command.startswith("bipedtele poincare --table")
    shape = (tab.sigma.size, tab.tau.size, tab.T.size)
    assert tab.rho.shape == tab.limit_cycle.shape == tab.unstable.shape == shape
    assert min(shape) >= 2 and tab.eps > 0
    assert np.all(np.diff(tab.sigma) > 0) and np.all(np.diff(tab.tau) > 0) and np.all(np.diff(tab.T) > 0)
    assert np.all(np.isfinite(tab.rho[~tab.fallen]))
    # the grid straddles the turn limit cycle (tau ~ 3): tau values on both sides of 3
    assert tab.tau.min() < 3.0 < tab.tau.max()
    assert tab.limit_cycle.any() and not tab.unstable.all()
    raw = json.loads((Path(__file__).parents[2] / "common/data/walker_map.json").read_text())
    assert len(raw["turn_std"]) == shape[0] and raw["settings"]["turn_ref"] > 0
    # a limit-cycle node oscillates in turn by more than the reference it is asked to walk
    ts = np.asarray(raw["turn_std"])
    assert np.all(ts[tab.limit_cycle] > raw["settings"]["turn_ref"])


@pytest.mark.timeout(30)
def test_table_checks_name_what_is_wrong(tmp_path: Path) -> None:
    good = _synthetic()
    parse_walker_table(good)
    with pytest.raises(ValueError, match="format"):
        parse_walker_table({**good, "format": "x"})
    with pytest.raises(ValueError, match="strictly increasing"):
        parse_walker_table({**good, "tau": [0.0, 2.0, 1.0, 3.0, 3.5, 5.0]})
    with pytest.raises(ValueError, match="shape"):
        parse_walker_table({**good, "rho": good["rho"][:2]})
    with pytest.raises(ValueError, match="eps"):
        parse_walker_table({**good, "eps": -1})
    with pytest.raises(ValueError, match="cannot read"):
        load_walker_table(tmp_path / "missing.json")
    tab = parse_walker_table(good)
    with pytest.raises(ValueError, match="eps_range"):
        WalkerSolver(ControlConfig(hybrid_model="walker", eps_range=[0.1, 1.0]), tab)
    with pytest.raises(ValueError, match="overlapping"):
        WalkerSolver(ControlConfig(hybrid_model="walker", T_range=[2.0, 5.0]), tab)


def test_interpolation_weights_and_unstable_region() -> None:
    nodes = np.array([0.0, 1.0, 3.0])
    w = interp_weights(nodes, [0.0, 0.5, 1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(w[:5], [[1, 0, 0], [0.5, 0.5, 0], [0, 1, 0], [0, 0.5, 0.5], [0, 0, 1]])
    assert np.all(np.isnan(w[5]))
    tab = parse_walker_table(_synthetic())
    assert tab.radius(0.0, 3.0, 0.8) == pytest.approx(0.7 + 0.12)  # a stable node next to the limit cycle
    assert tab.in_unstable_region(0.0, 3.01, 0.8) and tab.in_unstable_region(2.0, 4.0, 1.0)
    assert tab.radius(1.25, 0.5, 1.0) == pytest.approx(0.7 + 0.03 * 1.25 + 0.04 * 0.5 - 0.05 * 0.2)


@pytest.mark.timeout(60)
def test_walker_chooser_avoids_the_limit_cycle_on_a_synthetic_table() -> None:
    tab = parse_walker_table(_synthetic())
    feasible = _check_choices(tab, WALKER)
    assert feasible >= len(S_E) // 2
    # a high equivalent turn damping is met elsewhere, never in tau > 3
    c = OnlineChooser(WALKER, walker_table=tab).choose([0.05, 5.0])
    assert c.s_r[1] <= 3.0 + 1e-9
    ex = WalkerSolver(WALKER, tab, n_fine=1001, n_T=201).choose([0.05, 5.0])
    assert ex.s_r[1] <= 3.0 + 1e-9 and ex.cost <= c.cost + 1e-9  # the finer grid is never worse


@pytest.mark.timeout(60)
def test_walker_chooser_on_the_shipped_table() -> None:
    tab = load_walker_table()
    feasible = _check_choices(tab, WALKER)
    assert feasible > 0
    # the offline solver on the same table agrees with the online one within a grid step
    for s_e in ([0.05, 0.05], [0.53, 3.75]):
        on, ex = OnlineChooser(WALKER).choose(s_e), solve_exact(s_e, WALKER)
        assert not tab.in_unstable_region(float(ex.s_r[0]), float(ex.s_r[1]), ex.T)
        if on.feasible and ex.feasible:
            assert ex.cost <= on.cost + 1e-9
            assert on.cost - ex.cost <= WALKER.k_sigma * 0.05 + WALKER.k_wt * 0.02 + 1e-9


@pytest.mark.timeout(60)
def test_walker_chooser_is_fast() -> None:
    """Under a millisecond per call on an idle machine; on a loaded one, no slower than the paper's chooser.

    The paper's reduced-model chooser is the reference measured in the same process and
    the same conditions (it costs well under a millisecond on an idle machine).
    """
    walker, paper = OnlineChooser(WALKER), OnlineChooser(ControlConfig())
    rng = np.random.default_rng(0)
    times: dict[str, list[float]] = {"walker": [], "paper": []}
    for s_e in rng.uniform(0.05, 8.0, size=(200, 2)):
        for name, chooser in (("walker", walker), ("paper", paper)):
            t0 = time.perf_counter()
            chooser._choose(tuple(s_e))  # not memoised
            times[name].append(time.perf_counter() - t0)
    w, p = float(np.median(times["walker"])), float(np.median(times["paper"]))
    assert w < max(1e-3, 1.5 * p), f"walker {w * 1e3:.3f} ms, paper {p * 1e3:.3f} ms per call"


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_table_command_regenerates_a_tiny_table(tmp_path: Path) -> None:
    out = tmp_path / "t.json"
    rc = main(
        ["poincare", "--table", str(out), "--sigma", "0", "--tau", "0,4", "--T", "0.8", "--warmup", "6", "--jobs", "2"]
    )
    assert rc == 0
    data = json.loads(out.read_text())
    tab = load_walker_table(out)
    assert tab.rho.shape == (1, 2, 1) and data["command"].startswith("bipedtele poincare --table")
    # tau = 4 is past the turn limit cycle (the servo swings to its +-25 deg/s bound)
    assert not tab.limit_cycle[0, 0, 0] and tab.limit_cycle[0, 1, 0]
    assert data["turn_std"][0][1][0] > 10 * data["turn_std"][0][0][0]


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_newton_reduces_the_fixed_point_residual() -> None:
    from bipedtele.follower.sim.poincare import MapSettings, WalkerMap

    st = MapSettings(warmup_s=6.0, average_cycles=2, newton_iterations=1, newton_scales=(1.0,), contraction=False)
    with WalkerMap([0.05, 2.0], 0.8, 0.05, settings=st) as m:
        x0 = m.steady()
        res = m.newton(x0)
    assert len(res.residual_rms) == 2, res.as_dict()  # the step was accepted
    assert res.residual_rms[1] < res.residual_rms[0]
    assert math.isfinite(res.rho_by_scale["1"]) and not res.fallen
