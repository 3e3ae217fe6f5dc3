"""The comparison's tables and figure, from the JSON that :func:`~bipedtele.studies.compare.run_compare` returns.

Every difference is shown with its 95 % interval, its effect size ``d_z``, its Holm-adjusted
p-value within its family and the verdict (``differs``, ``equivalent`` within the margin
stated before the run, ``inconclusive``); docs/schemes.md reads them.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["compare_markdown", "plot_effects"]

_TABLE_METRICS = (
    ("forward_error", "coordination fwd [cm/s]"),
    ("turn_error", "coordination turn [deg/s]"),
    ("forward_intent_error", "intent fwd [cm/s]"),
    ("turn_intent_error", "intent turn [deg/s]"),
)
_VERDICT = {"differs": "differs", "equivalent": "equiv.", "inconclusive": "?"}


def _num(x: float, fmt: str = "+.3f") -> str:
    return format(x, fmt) if math.isfinite(x) else "-"


def _mean(v: dict[str, Any]) -> str:
    lo, hi = v["ci95"]
    return f"{_num(v['mean'], '.3f')} [{_num(lo, '.3f')}, {_num(hi, '.3f')}]"


def _judged(d: dict[str, Any] | None, alpha: float = 0.05) -> str:
    """Return a difference as ``mean [lo, hi]; d_z; p_Holm; verdict``.

    ``differs, within margin``: the difference is real (Holm p below ``alpha``) and the
    TOST puts it inside the equivalence margin too.
    """
    if not d:
        return "(baseline)"
    lo, hi = d.get("ci_family") or d["ci95"]
    p = d["p_holm"]
    p_txt = f"{p:.1g}" if math.isfinite(p) else "-"
    verdict = _VERDICT.get(d["verdict"], d["verdict"])
    if d["verdict"] == "differs" and d["tost_p_holm"] < alpha:
        verdict = "differs, within margin"
    return f"{_num(d['mean'])} [{_num(lo)}, {_num(hi)}]; d_z {_num(d['d_z'], '+.2f')}; p_H {p_txt}; {verdict}"


def _header(result: dict[str, Any]) -> list[str]:
    d = result["design"]
    margins = ", ".join(f"{m} {v:g}" for m, v in d["margins"].items())
    named = ", ".join(f"`{n}` = `{c}`" for n, c in d["named"].items())
    return [
        f"Reduced model, {result['runs']} paired runs per cell and regime, {result['duration_s']:g} s each, "
        f"seed {result['seed']}, wave gain window {result.get('wave_window_s', 0.5):g} s; each run its own "
        f"operator and delays, shared by every cell. Factorial cells `damping/feedback[/pc]`: damping "
        f"{', '.join(d['axes']['damping'])}; fed back {', '.join(d['axes']['feedback'])}; `/pc`: passivity "
        f"controllers at both ports. Named schemes: {named}.",
        "",
        f"Differences against the baseline `{d['baseline']}` (the Δ columns; negative: lower error than the paper's), "
        f"as mean [family-corrected 95 % CI: Bonferroni over the family, so that all of a family's intervals "
        f"hold together]; d_z (mean over SD of the paired differences); p_H, the Holm-adjusted p within "
        f"the family (per regime and metric, every other cell); the verdict at alpha {d['alpha']:g}: "
        f"`differs`, `differs, within margin` (real and inside the margin: both tests reject), `equiv.` (TOST "
        f"within the margin, Holm-adjusted), `?` (neither). Margins, stated before "
        f"the runs: {margins} (cm/s, deg/s, N); released handle {1e3 * d['released_margin_m_s']:g} mm/s.",
    ]


def _diff_head() -> str:
    """Return the difference columns' labels (a cell's paired difference against the baseline)."""
    return " | ".join(f"Δ {label}" for _, label in _TABLE_METRICS)


def _regime_table(regime: str, per: dict[str, Any]) -> list[str]:
    head = _diff_head()
    lines = [
        f"### {regime}",
        "",
        f"| cell | named | n (unstable) | coordination fwd [cm/s]: mean [95 % CI] | {head} "
        "| force error fwd [N]: mean [95 % CI] |",
        "| --- | --- | --- | --- |" + " --- |" * len(_TABLE_METRICS) + " --- |",
    ]
    for name, c in per.items():
        diffs = " | ".join(_judged(c[m].get("vs_baseline")) for m, _ in _TABLE_METRICS)
        lines.append(
            f"| `{name}` | {c.get('named') or ''} | {c['n']} ({c['unstable']}) | {_mean(c['forward_error'])} | "
            f"{diffs} | {_mean(c['forward_force_error'])} |"
        )
    return lines


def _named_table(result: dict[str, Any]) -> list[str]:
    """Return the named schemes' cells against the baseline, every regime (a selection of the regime tables)."""
    head = _diff_head()
    named = result["design"]["named"]
    lines = [
        "The named schemes, each a cell of the grid, against `paper` (a selection of the regime tables below).",
        "",
        f"| regime | scheme (cell) | {head} |",
        "| --- | --- |" + " --- |" * len(_TABLE_METRICS),
    ]
    for regime, per in result["cells"].items():
        for n, cell in named.items():
            c = per.get(cell)
            if c is None or "vs_baseline" not in c["forward_error"]:
                continue
            row = " | ".join(_judged(c[m]["vs_baseline"]) for m, _ in _TABLE_METRICS)
            lines.append(f"| {regime} | {n} (`{cell}`) | {row} |")
    return lines


def _effects_table(effects: dict[str, Any]) -> list[str]:
    head = _diff_head()
    lines = [
        "Main effects: each axis level against the baseline's (damping `scheduled`, feedback `ze`, passivity "
        "`off`), each run's metric averaged over the other axes' cells; one Holm family per regime and metric.",
        "",
        f"| regime | contrast | {head} |",
        "| --- | --- |" + " --- |" * len(_TABLE_METRICS),
    ]
    for regime, per_metric in effects.items():
        contrasts = list(next(iter(per_metric.values())))
        for k in contrasts:
            row = " | ".join(_judged(per_metric[m][k]) for m, _ in _TABLE_METRICS)
            lines.append(f"| {regime} | {k} vs {per_metric['forward_error'][k]['reference']} | {row} |")
    return lines


def _released_table(margin: dict[str, Any]) -> list[str]:
    scales = list(next(iter(margin.values()))["oscillating_by_scale"])
    lines = [
        "Handle released mid-run: share of runs still oscillating over the last quarter (released handle's RMS "
        "speed above the threshold) per delay scale of the shipped trace (x0: no delay), the median RMS "
        "[mm/s], and the paired difference of the RMS against the baseline [mm/s] (Holm per scale).",
        "",
        "| cell | margin (largest scale, <= 5 % oscillating) | oscillating | median [mm/s] | "
        + " | ".join(f"- baseline x{s}" for s in scales)
        + " |",
        "| --- | --- | --- | --- |" + " --- |" * len(scales),
    ]
    for name, m in margin.items():
        share = ", ".join(f"x{s}: {100 * v:.0f} %" for s, v in m["oscillating_by_scale"].items())
        med = ", ".join(f"x{s}: {1e3 * v:.1f}" for s, v in m["released_motion_median_m_s"].items())
        scale = f"x{m['scale']:g}" if m["scale"] is not None else "none"
        tests = []
        for s in scales:
            d = m["vs_baseline_by_scale"].get(s)
            tests.append(_judged(_in_mm(d)) if d else "(baseline)")
        lines.append(f"| `{name}` | {scale} | {share} | {med} | {' | '.join(tests)} |")
    return lines


def _in_mm(d: dict[str, Any]) -> dict[str, Any]:
    out = {**d, "mean": 1e3 * d["mean"], "ci95": [1e3 * v for v in d["ci95"]]}
    if d.get("ci_family"):
        out["ci_family"] = [1e3 * v for v in d["ci_family"]]
    return out


def _plan_lines(plan: dict[str, Any]) -> list[str]:
    head = " | ".join(label for _, label in _TABLE_METRICS)
    lines = [
        "Walker runs per cell the claims need: pairs for 80 % power at the walker family's first Holm step "
        "(0.05 / 5) to detect the reduced model's effect size of the same contrast (`-`: no effect to detect).",
        "",
        f"| regime | scheme | {head} |",
        "| --- | --- |" + " --- |" * len(_TABLE_METRICS),
    ]
    for regime, per in plan.items():
        for name, need in per.items():
            row = " | ".join(str(need.get(m) or "-") for m, _ in _TABLE_METRICS)
            lines.append(f"| {regime} | {name} | {row} |")
    return lines


def _walker_lines(walker: dict[str, Any]) -> list[str]:
    lines = [
        f"The pybullet walker (the real follower loop), {walker['runs']} paired runs per cell, "
        f"{walker['duration_s']:g} s each, {walker['wall_s']:.0f} s wall; errors per follower tick, differences "
        "against `paper` judged as above (one family per regime and metric over the named schemes); "
        "`n needed`: pairs for 80 % power at the family's first Holm step from the reduced model's effect "
        "size of the same contrast; fallen runs left out and counted.",
        "",
    ]
    for regime, per in walker["cells"].items():
        head = _diff_head()
        lines += [
            f"#### walker, {regime}",
            "",
            f"| scheme | n (falls) | coordination turn [deg/s]: mean [95 % CI] | {head} "
            "| n needed (fwd, turn, intent fwd, intent turn) |",
            "| --- | --- | --- |" + " --- |" * len(_TABLE_METRICS) + " --- |",
        ]
        for name, c in per.items():
            diffs = " | ".join(_judged(c[m].get("vs_baseline")) for m, _ in _TABLE_METRICS)
            need = ", ".join(str(c[m].get("n_needed", "-")) for m, _ in _TABLE_METRICS)
            lines.append(f"| {name} | {c['n']} ({c['unstable']}) | {_mean(c['turn_error'])} | {diffs} | {need} |")
        lines.append("")
    return lines


def compare_markdown(result: dict[str, Any]) -> str:
    """Return the comparison as markdown.

    Per regime every cell judged against the baseline, the main effects, the released handle
    and the walker cells.
    """
    lines = _header(result)
    if all(c in next(iter(result["cells"].values()), {}) for c in result["design"]["named"].values()):
        lines += ["", "### Named schemes", "", *_named_table(result)]
    for regime, per in result["cells"].items():
        lines += ["", *_regime_table(regime, per)]
    if result.get("main_effects"):
        lines += ["", "### Main effects", "", *_effects_table(result["main_effects"])]
    if result.get("margin"):
        lines += ["", "### Released handle", "", *_released_table(result["margin"])]
    if result.get("walker_plan"):
        lines += ["", "### Walker runs needed", "", *_plan_lines(result["walker_plan"])]
    if result.get("walker"):
        lines += ["", "### Walker", "", *_walker_lines(result["walker"])]
    return "\n".join(lines) + "\n"


def plot_effects(result: dict[str, Any]) -> Figure:
    """Draw the axes' main effects per regime (mean and 95 % interval), with each metric's margin shaded.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    effects = result["main_effects"]
    regimes = list(effects)
    contrasts = list(effects[regimes[0]]["forward_error"])
    fig = Figure(figsize=(12.0, 8.0), layout="constrained")
    width = 0.8 / max(1, len(contrasts))
    x = np.arange(len(regimes))
    for i, (metric, label) in enumerate(_TABLE_METRICS):
        ax = fig.add_subplot(2, 2, i + 1)
        margin = result["design"]["margins"][metric]
        ax.axhspan(-margin, margin, color="0.9", label="equivalence margin")
        for j, k in enumerate(contrasts):
            ds = [effects[r][metric][k] for r in regimes]
            mean = np.array([d["mean"] for d in ds])
            err = np.abs(np.array([d["ci95"] for d in ds]).T - mean)
            ax.bar(x + (j - (len(contrasts) - 1) / 2) * width, mean, width, yerr=err, capsize=2, label=k)
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_xticks(x, regimes, rotation=15)
        ax.set_ylabel(f"{label}, level - reference")
        if i == 0:
            ax.set_title(f"Main effects against the paper's levels ({result['runs']} paired runs, reduced model)")
            ax.legend(ncol=2, fontsize="small")
    return fig
