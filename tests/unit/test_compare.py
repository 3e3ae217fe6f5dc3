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
from bipedtele.control.schemes import scheme_class
from bipedtele.control.schemes.factorial import grid
from bipedtele.studies.compare import run_compare
from bipedtele.studies.compare_kernel import regime_inputs, simulate
from bipedtele.studies.inference import holm
from bipedtele.studies.regimes import EQUIVALENCE_MARGINS, MARGIN_SCALES, REGIMES, CompareParams, Regime

pytestmark = pytest.mark.compute  # CPU-bound and deterministic: run beside the other unit tests (scripts/test.sh)

CFG = ControlConfig()


VERDICT_KEYS = {
    "n",
    "mean",
    "ci95",
    "sd",
    "p",
    "d_z",
    "p_holm",
    "margin",
    "tost_p",
    "tost_p_holm",
    "verdict",
    "ci_family",
}


@pytest.mark.timeout(240)
def test_compare_json_carries_per_cell_the_axes_intervals_corrected_p_and_tost(tmp_path: Path) -> None:
    out = tmp_path / "c.json"
    md = tmp_path / "c.md"
    argv = ["compare", "--runs", "4", "--duration", "3", "--regimes", "trace", "step", "--walker-runs", "0"]
    rc = main([*argv, "--json", str(out), "--markdown", str(md)])
    assert rc == 0
    result = json.loads(out.read_text())
    design = result["design"]
    assert result["plant"] == "reduced" and result["runs"] == 4 and design["baseline"] == "scheduled/ze"
    assert design["margins"] == EQUIVALENCE_MARGINS and design["alpha"] == 0.05
    assert design["named"]["paper"] == "scheduled/ze" and design["named"]["tdpa"] == "floor/speed/pc"
    assert set(result["cells"]) == {"trace", "step"}
    for per in result["cells"].values():
        assert len(per) == 24
        for name, cell in per.items():
            assert name == f"{cell['damping']}/{cell['feedback']}" + ("/pc" if cell["passivity"] == "on" else "")
            assert cell["n"] + cell["unstable"] == 4
            for metric in ("forward_error", "turn_intent_error", "forward_force_error", "forward_po_leader", "peak"):
                lo, hi = cell[metric]["ci95"]
                assert lo <= cell[metric]["mean"] <= hi
            for metric, margin in EQUIVALENCE_MARGINS.items():
                judged = cell[metric].get("vs_baseline")
                assert (judged is None) == (name == "scheduled/ze")
                if judged:
                    assert set(judged) == VERDICT_KEYS and judged["margin"] == margin
                    assert judged["verdict"] in ("differs", "equivalent", "inconclusive")
        # the family: per regime and metric, the 23 other cells, Holm within it
        for metric in EQUIVALENCE_MARGINS:
            names = [n for n in per if n != "scheduled/ze"]
            raw = [per[n][metric]["vs_baseline"]["p"] for n in names]
            assert [per[n][metric]["vs_baseline"]["p_holm"] for n in names] == pytest.approx(holm(raw), nan_ok=True)
    effects = result["main_effects"]["step"]["forward_error"]
    assert set(effects) == {
        "damping=floor",
        "damping=ratio",
        "damping=worst",
        "feedback=speed",
        "feedback=wave",
        "passivity=on",
    }
    assert effects["damping=worst"]["reference"] == "scheduled" and set(effects["passivity=on"]) >= VERDICT_KEYS
    margin = result["margin"]
    assert set(margin) == set(result["cells"]["trace"])
    assert set(margin["floor/ze"]["vs_baseline_by_scale"]) == {f"{s:g}" for s in MARGIN_SCALES}
    plan = result["walker_plan"]["step"]
    assert set(plan) == {"paper-constant", "pd-measured", "pd-worst-case", "wave", "tdpa"}
    assert all(v is None or v >= 2 for v in plan["wave"].values())
    text = md.read_text()
    assert "| `floor/ze` | paper-constant |" in text and "Main effects" in text and "d_z" in text


@pytest.mark.timeout(120)
def test_compare_is_paired_and_deterministic_per_seed() -> None:
    cp = CompareParams(study=StudyParams(duration_s=3.0))
    cells = {n: c for n, c in grid().items() if n in ("scheduled/ze", "floor/ze")}
    kw = {"cells": cells, "regimes": REGIMES[:1], "margin_scales": ()}
    a = run_compare(3, 5, CFG, cp, **kw)
    b = run_compare(3, 5, CFG, cp, **kw)
    c = run_compare(3, 6, CFG, cp, **kw)
    strip = lambda r: {k: v for k, v in r.items() if k != "elapsed_s"}  # noqa: E731
    assert strip(a) == strip(b)
    assert strip(a) != strip(c)
    assert strip(run_compare(3, 5, CFG, cp, jobs=2, **kw)) == strip(a)  # spread over processes: the same
    # run i of every scheme sees the same delays and the same operator
    step = next(r for r in REGIMES if r.step_s)
    inp1 = regime_inputs(step, 4, 5, CFG, cp.study)
    inp2 = regime_inputs(step, 4, 5, CFG, cp.study)
    assert np.array_equal(inp1.intent, inp2.intent) and np.array_equal(inp1.h1, inp2.h1)
    assert np.ravel(inp1.h1)[0] == pytest.approx(0.3) and np.ravel(inp1.h1)[-1] == pytest.approx(3.0)


def test_the_loss_regime_loses_messages_and_the_others_do_not() -> None:
    params = StudyParams(duration_s=20.0)
    lossy = regime_inputs(next(r for r in REGIMES if r.name == "trace"), 2, 1, CFG, params)
    clean = regime_inputs(next(r for r in REGIMES if r.name == "satellite"), 2, 1, CFG, params)
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
    argv = ["compare", "--runs", "2", "--duration", "2", "--regimes", "trace", "--no-margin", "--schemes", "paper"]
    argv += ["--walker-schemes", "paper", "wave", "tdpa", "--walker-runs", "3", "--walker-duration", "4"]
    argv += ["--json", str(out)]
    assert main(argv) == 0
    walker = json.loads(out.read_text())["walker"]
    assert walker["plant"] == "walker" and walker["runs"] == 3
    cells = walker["cells"]["trace"]
    assert set(cells) == {"paper", "wave", "tdpa"}
    for name, cell in cells.items():
        assert cell["n"] + cell["unstable"] == 3
        assert cell["forward_error"]["mean"] > 0.0  # the robot was commanded and measured
        assert ("vs_baseline" in cell["turn_intent_error"]) == (name != "paper")
        assert cell["named"] == name
