"""The factorial grid of schemes (bipedtele.control.schemes.factorial): 24 cells, the named schemes among them."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import StudyParams
from bipedtele.control.schemes import scheme_class, scheme_names
from bipedtele.control.schemes.check import check_scheme
from bipedtele.control.schemes.factorial import (
    DAMPINGS,
    FEEDBACKS,
    FIXED_RATIO,
    HANDLE_MASS_KG,
    NAMED_CELLS,
    PASSIVITY,
    Cell,
    cell_name,
    grid,
)
from bipedtele.control.schemes.passivity import Passivity
from bipedtele.studies.compare_kernel import regime_inputs, simulate
from bipedtele.studies.regimes import CompareParams, Regime

CFG = ControlConfig()


@pytest.mark.timeout(60)
def test_the_grid_composes_24_cells_one_per_combination_of_the_three_axes() -> None:
    cells = grid()
    assert len(cells) == 24 == len(DAMPINGS) * len(FEEDBACKS) * len(PASSIVITY)
    seen = {cls.cell for cls in cells.values()}  # type: ignore[attr-defined]
    assert seen == {Cell(*c) for c in itertools.product(DAMPINGS, FEEDBACKS, PASSIVITY)}
    for name, cls in cells.items():
        assert cls.name == name == cell_name(cls.cell)  # type: ignore[attr-defined]
        assert cls.adapts == (cls.cell.damping == "scheduled")  # type: ignore[attr-defined]
        check_scheme(cls, CFG)  # every cell keeps the scheme contract


@pytest.mark.timeout(60)
def test_every_named_scheme_is_a_cell_of_the_grid() -> None:
    assert set(NAMED_CELLS) == set(scheme_names())
    cells = grid()
    rng = np.random.default_rng(3)
    h1, h2 = rng.uniform(0.1, 2.0, 50), rng.uniform(0.1, 2.0, 50)
    k_m = np.asarray(CFG.k_m, dtype=float)
    r, s, eta = rng.normal(size=(3, 4, 2))
    for name, cell in NAMED_CELLS.items():
        named, point = scheme_class(name)(CFG, (1.5, 1.2)), cells[cell_name(cell)](CFG, (1.5, 1.2))
        for a, b in zip(named.damping(h1, h2), point.damping(h1, h2), strict=True):
            assert np.array_equal(a, b), name
        assert np.array_equal(named.leader_force(r, s, 0.9, k_m).force, point.leader_force(r, s, 0.9, k_m).force)
        assert np.array_equal(named.follower_command(r, s, 0.9, eta, k_m), point.follower_command(r, s, 0.9, eta, k_m))
        assert np.array_equal(named.feedback_signal(lambda: s, eta, k_m), point.feedback_signal(lambda: s, eta, k_m))
        coupling = FEEDBACKS[cell.feedback]
        assert isinstance(named, coupling) and isinstance(point, coupling), name
        assert isinstance(point, Passivity) == isinstance(named, Passivity) == PASSIVITY[cell.passivity], name


@pytest.mark.compute
@pytest.mark.timeout(240)
def test_a_named_scheme_and_its_cell_give_the_same_runs() -> None:
    cp = CompareParams(study=StudyParams(duration_s=6.0))
    inp = regime_inputs(Regime("s", "step", step_s=(0.3, 1.5), loss=0.05), 3, 4, CFG, cp.study)
    chooser, cells = OnlineChooser(CFG), grid()
    worst = (float(np.max(inp.h1)), float(np.max(inp.h2)))
    for name, cell in NAMED_CELLS.items():
        a = simulate(scheme_class(name)(CFG, worst), inp, CFG, cp, chooser, release=True)
        b = simulate(cells[cell_name(cell)](CFG, worst), inp, CFG, cp, chooser, release=True)
        for metric in a:
            assert np.array_equal(a[metric], b[metric]), (name, metric)


@pytest.mark.timeout(30)
def test_the_ratio_damping_gives_the_handle_its_damping_ratio_and_the_others_keep_their_rules() -> None:
    cells = grid()
    h = np.array([0.2, 0.4, 3.0])
    k_pos = np.asarray(CFG.k_m) * np.asarray(CFG.k_g)
    alpha, s_e = cells["ratio/ze"](CFG).damping(h, h)
    assert alpha.shape == (3, 2) and np.allclose(alpha / (2.0 * np.sqrt(k_pos * HANDLE_MASS_KG)), FIXED_RATIO)
    assert np.all(s_e == CFG.s_e_min)
    floor, _ = cells["floor/wave"](CFG).damping(h, h)
    assert np.all(floor == CFG.alpha_m_min)
    sched, _ = cells["scheduled/speed/pc"](CFG).damping(h, h)
    assert sched[2, 0] > sched[0, 0]  # (40) grows with the delay
    worst, _ = cells["worst/ze"](CFG, (3.0, 3.0)).damping(h, h)
    assert np.all(worst == worst[0]) and np.allclose(worst[0], sched[2])  # (40) at the worst delays, held
