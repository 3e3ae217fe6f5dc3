"""``bipedtele compare`` and the paired scheme comparison on the reduced model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from bipedtele.cli import main
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import StudyParams
from bipedtele.control.schemes import scheme_class, scheme_names
from bipedtele.studies.compare import run_compare
from bipedtele.studies.compare_kernel import regime_inputs, simulate
from bipedtele.studies.regimes import REGIMES, CompareParams, Regime

pytestmark = pytest.mark.compute  # CPU-bound and deterministic: run beside the other unit tests (scripts/test.sh)

CFG = ControlConfig()


@pytest.mark.timeout(240)
def test_compare_writes_every_cell_with_paired_differences(tmp_path: Path) -> None:
    out = tmp_path / "c.json"
    md = tmp_path / "c.md"
    argv = ["compare", "--runs", "3", "--duration", "4", "--regimes", "trace", "step", "--walker-runs", "0"]
    rc = main([*argv, "--json", str(out), "--markdown", str(md)])
    assert rc == 0
    result = json.loads(out.read_text())
    assert result["plant"] == "reduced" and result["runs"] == 3
    assert set(result["cells"]) == {"trace", "step"}
    for per in result["cells"].values():
        assert set(per) == set(scheme_names())
        for name, cell in per.items():
            assert cell["n"] + cell["unstable"] == 3
            for metric in ("forward_error", "turn_error", "forward_force_error", "forward_po_leader", "peak"):
                lo, hi = cell[metric]["ci95"]
                assert lo <= cell[metric]["mean"] <= hi
                assert ("diff" in cell[metric]) == (name != "paper")
    assert set(result["margin"]) == set(scheme_names())
    text = md.read_text()
    assert "| trace | paper-constant |" in text and "stability margin" in text


@pytest.mark.timeout(120)
def test_compare_is_paired_and_deterministic_per_seed() -> None:
    cp = CompareParams(study=StudyParams(duration_s=3.0))
    kw = {"schemes": ("paper", "paper-constant"), "regimes": REGIMES[:1], "margin_scales": ()}
    a = run_compare(3, 5, CFG, cp, **kw)
    b = run_compare(3, 5, CFG, cp, **kw)
    c = run_compare(3, 6, CFG, cp, **kw)
    strip = lambda r: {k: v for k, v in r.items() if k != "elapsed_s"}  # noqa: E731
    assert strip(a) == strip(b)
    assert strip(a) != strip(c)
    # run i of every scheme sees the same delays and the same operator
    inp1 = regime_inputs(REGIMES[5], 4, 5, CFG, cp.study)
    inp2 = regime_inputs(REGIMES[5], 4, 5, CFG, cp.study)
    assert np.array_equal(inp1.intent, inp2.intent) and np.array_equal(inp1.h1, inp2.h1)
    assert inp1.h1[0] == pytest.approx(0.3) and inp1.h1[-1] == pytest.approx(3.0)


def test_the_loss_regime_loses_messages_and_the_others_do_not() -> None:
    params = StudyParams(duration_s=20.0)
    lossy = regime_inputs(next(r for r in REGIMES if r.loss > 0), 2, 1, CFG, params)
    clean = regime_inputs(REGIMES[0], 2, 1, CFG, params)
    assert 0.03 < lossy.lost1.mean() < 0.07 and 0.03 < lossy.lost2.mean() < 0.07
    assert not clean.lost1.any() and not clean.lost2.any()


@pytest.mark.timeout(240)
def test_a_released_handle_settles_with_the_scheduled_damping_and_rings_without_it() -> None:
    # The operator lets go mid-run on the shipped trace x4. (40)'s damping settles the handle;
    # the same loop with (40) held at zero delay (alpha_m at its floor) keeps it moving.
    cp = CompareParams(study=StudyParams(duration_s=40.0))
    inp = regime_inputs(Regime("x4", "x4", scale=4.0), 8, 2, CFG, cp.study)
    chooser = OnlineChooser(CFG)
    worst = (float(inp.h1.max()), float(inp.h2.max()))
    out = {
        n: simulate(scheme_class(n)(CFG, worst), inp, CFG, cp, chooser, release=True)
        for n in ("paper", "paper-constant")
    }
    assert not out["paper"]["oscillating"].any()
    assert out["paper-constant"]["oscillating"].mean() >= 0.5


@pytest.mark.timeout(240)
def test_tdpa_keeps_both_passivity_observers_non_negative_where_the_paper_does_not() -> None:
    cp = CompareParams(study=StudyParams(duration_s=20.0))
    inp = regime_inputs(REGIMES[2], 6, 3, CFG, cp.study)
    chooser = OnlineChooser(CFG)
    tdpa = simulate(scheme_class("tdpa")(CFG), inp, CFG, cp, chooser)
    paper = simulate(scheme_class("paper")(CFG), inp, CFG, cp, chooser)
    for key in ("forward_po_leader", "forward_po_follower", "turn_po_leader", "turn_po_follower"):
        assert tdpa[key].min() >= -1e-6, key
    assert paper["forward_po_follower"].max() < 0.0  # z_e is not the robot's speed: the two-port is active


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--runs", "1"], "--runs 1: allowed: >= 2"),
        (["--schemes", "nope"], "--schemes nope: allowed: paper"),
        (["--regimes", "moon"], "--regimes moon: allowed: trace"),
        (["--duration", "0.5"], "--duration 0.5: allowed: >= 1 s"),
        (["--walker-runs", "1"], "--walker-runs 1: allowed: 0 (none) or >= 2"),
        (["--walker-duration", "1"], "--walker-duration 1.0: allowed: >= 2 s"),
        (["--jobs", "0"], "--jobs 0: allowed: >= 1"),
    ],
)
def test_bad_compare_arguments_exit_2_with_one_line(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["compare", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0]


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_walker_cells_run_every_scheme_paired_on_the_pybullet_follower(tmp_path: Path) -> None:
    out = tmp_path / "w.json"
    argv = ["compare", "--runs", "2", "--duration", "2", "--regimes", "trace-loss", "--no-margin"]
    argv += ["--schemes", "paper", "wave", "tdpa", "--walker-runs", "2", "--walker-duration", "4", "--json", str(out)]
    assert main(argv) == 0
    walker = json.loads(out.read_text())["walker"]
    assert walker["plant"] == "walker" and walker["runs"] == 2
    cells = walker["cells"]["trace-loss"]
    assert set(cells) == {"paper", "wave", "tdpa"}
    for name, cell in cells.items():
        assert cell["n"] + cell["unstable"] == 2
        assert cell["forward_error"]["mean"] > 0.0  # the robot was commanded and measured
        assert ("diff" in cell["turn_intent_error"]) == (name != "paper")
