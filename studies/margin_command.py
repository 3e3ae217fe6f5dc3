"""``bipedtele margin``: the released handle's stability-margin map (:mod:`bipedtele.studies.margin`).

One command writes the JSON table and the figure: per channel and delay variant (constant,
jittered, drifting), the decay rate of the released handle's speed over mean round-trip
delay x leader damping, with (40)'s damping drawn on it, the small-gain verdict per damping,
and per damping rule the critical mean delay found by bisection. docs/schemes.md (The
stability-margin map) shows and reads it.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config.profile import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.studies.control_commands import save_figure, write_json
from bipedtele.tools.plots import require_matplotlib

__all__ = ["add_margin_parser", "plot_margin"]


def plot_margin(data: dict[str, Any]) -> Any:
    """Return the map's figure: a panel per channel (rows) and delay variant (columns)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    means, alphas, variants = data["means_s"], data["alphas"], data["variants"]
    fig, axes = plt.subplots(
        len(data["channels"]), len(variants), figsize=(4.4 * len(variants), 8.5), squeeze=False, layout="constrained"
    )
    x_edges = np.arange(len(means) + 1) - 0.5
    y_edges = np.arange(len(alphas) + 1) - 0.5
    mesh = None
    for r, ch in enumerate(data["channels"]):
        for c, label in enumerate(variants):
            ax = axes[r][c]
            grid = np.asarray([[np.nan if v is None else v for v in row] for row in ch["decay_per_s"][label]])
            mesh = ax.pcolormesh(x_edges, y_edges, grid, cmap="RdBu_r", vmin=-4.0, vmax=4.0, shading="flat")
            a40 = np.interp(np.log(np.maximum(ch["alpha_40_margin"], 1e-9)), np.log(alphas), np.arange(len(alphas)))
            ax.plot(np.arange(len(means)), a40, "k-", lw=1.5, label="(40) with its margin")
            for name, a in (("floor", ch["alpha_floor"]), ("ratio 0.3", ch["alpha_ratio"])):
                ax.axhline(
                    np.interp(math.log(a), np.log(alphas), np.arange(len(alphas))),
                    ls="--",
                    lw=0.8,
                    color="0.3",
                    label=name,
                )
            ax.set_title(f"{ch['name']}, {label}", fontsize=9)
            ax.set_xticks(range(len(means)), [f"{m:g}" for m in means])
            ax.set_yticks(range(len(alphas)), [f"{a:g}" for a in alphas])
            ax.set_xlabel("mean round-trip delay [s]")
            ax.set_ylabel("leader damping alpha_m [N s/m]")
            if r == 0 and c == 0:
                ax.legend(fontsize=6, loc="upper left")
    lines = []
    for ch in data["channels"]:
        sg = [a for a, ok in zip(alphas, ch["small_gain"], strict=True) if not ok]
        crit = {f"{k}/{v}" for k, by in ch["critical_mean_delay_s"].items() for v, d in by.items() if d is not None}
        hi = data["model"]["bisection_hi_s"]
        lines.append(
            f"{ch['name']}: small-gain (every constant delay) fails for alpha {sg if sg else 'none'}; "
            f"bisection: {'no critical mean delay up to ' + str(hi) + ' s' if not crit else sorted(crit)}"
        )
    fig.suptitle("\n".join(lines), fontsize=8)
    if mesh is not None:
        fig.colorbar(mesh, ax=axes, label="released-handle decay rate [1/s] (blue: settles)")
    return fig


def _floats(text: str, flag: str, lo: float) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"{flag} {text!r}: allowed: comma-separated numbers, e.g. 0,0.5,1") from None
    if not vals or any(not math.isfinite(v) or v < lo for v in vals):
        raise ConfigError(f"{flag} {text!r}: allowed: finite numbers >= {lo:g}")
    return vals


def _run_margin(args: argparse.Namespace) -> int:
    from bipedtele.studies.margin import margin_map

    for flag, v in (("--mass", args.mass), ("--hi", args.hi), ("--duration", args.duration)):
        if not (math.isfinite(v) and v > 0.0):
            raise ConfigError(f"{flag} {v!r}: allowed: a positive number")
    means = _floats(args.means, "--means", 0.0)
    alphas = _floats(args.alphas, "--alphas", 1e-6)
    if args.plot:
        require_matplotlib("--plot")
    cfg = config_from_args(args).get(ControlConfig)
    data = margin_map(
        cfg, args.mass, means, alphas, hi=args.hi, iters=args.iters, duration_s=args.duration, seed=args.seed
    )
    if args.json:
        write_json(args.json, data)
    if args.plot:
        save_figure(plot_margin(data), args.plot)
    if args.json != "-":
        for ch in data["channels"]:  # type: ignore[attr-defined]
            crit = {
                rule: {k: ("none" if v is None else f"{v:.2f} s") for k, v in by.items()}
                for rule, by in ch["critical_mean_delay_s"].items()
            }
            ok = sum(ch["small_gain"])
            sys.stdout.write(
                f"{ch['name']}: small-gain holds for {ok}/{len(ch['small_gain'])} dampings; "
                f"critical mean delay up to {args.hi:g} s: {crit}\n"
            )
    return 0


def add_margin_parser(sub: Any) -> None:
    """``bipedtele margin [--json F] [--plot F.png] [--means ...] [--alphas ...]``."""
    p = sub.add_parser("margin", help="the released handle's stability-margin map: critical delays, decay rates, (40)")
    p.add_argument("--json", metavar="FILE", help="write the map as JSON ('-' for stdout)")
    p.add_argument("--plot", metavar="FILE.png", help="write the figure")
    p.add_argument("--means", default="0,0.25,0.5,1,2,4", help="mean round-trip delays [s], comma-separated")
    p.add_argument(
        "--alphas", default="0.05,0.1,0.2,0.5,1,2,5,10,20,40", help="leader dampings alpha_m [N s/m], comma-separated"
    )
    p.add_argument("--mass", type=float, default=0.15, help="handle mass [kg] (default 0.15, the comparison's)")
    p.add_argument("--hi", type=float, default=8.0, help="largest mean delay the bisection tries [s] (default 8)")
    p.add_argument(
        "--iters", type=int, default=10, choices=range(1, 31), metavar="N", help="bisection steps (default 10)"
    )
    p.add_argument("--duration", type=float, default=30.0, help="simulated seconds per run, at least 6 round trips")
    p.add_argument("--seed", type=int, default=0, help="random seed of the delay draws (default 0)")
    add_config_args(p)
    p.set_defaults(func=_run_margin)
