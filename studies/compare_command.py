"""``bipedtele compare``: the factorial grid of control schemes, paired, over delay regimes.

The computing is :mod:`bipedtele.studies.compare` (pure) and its tables
:mod:`bipedtele.studies.compare_report`; this module parses the arguments, writes the JSON,
markdown and figure, shows a progress bar and prints the time it took.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config.profile import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.studies.control_commands import progress_bar, save_figure, write_json, write_text
from bipedtele.tools.backends import walker_backend
from bipedtele.tools.plots import require_matplotlib

__all__ = ["add_compare_parser"]

#: Walker cells of the default set: the named schemes (the walker runs registered schemes).
WALKER_SCHEMES = ("paper", "paper-constant", "pd-measured", "pd-worst-case", "wave", "tdpa")


def _names(given: list[str] | None, allowed: list[str], flag: str) -> tuple[str, ...] | None:
    if not given:
        return None
    for name in given:
        if name not in allowed:
            raise ConfigError(f"{flag} {name}: allowed: {', '.join(allowed)}")
    return tuple(given)


def _cells(chosen: tuple[str, ...] | None) -> dict[str, Any] | None:
    """Return the grid cells named on the command line (a named scheme stands for its cell); None: all."""
    from bipedtele.control.schemes import scheme_class
    from bipedtele.control.schemes.factorial import NAMED_CELLS, cell_name, grid

    if chosen is None:
        return None
    full = grid()
    names = [cell_name(NAMED_CELLS[n]) if n in NAMED_CELLS else n for n in chosen]
    # a registered scheme that is no cell of the grid (another distribution's) runs as itself
    return {n: full[n] if n in full else scheme_class(n) for n in names}


def _run_compare(args: argparse.Namespace) -> int:
    from bipedtele.control.reduced import StudyParams
    from bipedtele.control.schemes import scheme_names
    from bipedtele.control.schemes.factorial import grid
    from bipedtele.studies.compare import attach_power, compare_steps, run_compare
    from bipedtele.studies.compare_report import compare_markdown
    from bipedtele.studies.regimes import MARGIN_SCALES, REGIMES, CompareParams

    if args.runs < 2:
        raise ConfigError(f"--runs {args.runs}: allowed: >= 2")
    if args.walker_runs != 0 and args.walker_runs < 2:
        raise ConfigError(f"--walker-runs {args.walker_runs}: allowed: 0 (none) or >= 2")
    if not args.walker_duration >= 2.0:
        raise ConfigError(f"--walker-duration {args.walker_duration}: allowed: >= 2 s")
    if args.jobs < 1:
        raise ConfigError(f"--jobs {args.jobs}: allowed: >= 1")
    if not args.duration >= 1.0:
        raise ConfigError(f"--duration {args.duration}: allowed: >= 1 s")
    registered = scheme_names()  # the named schemes and any other distribution's
    cells = _cells(_names(args.schemes, [*registered, *grid()], "--schemes"))
    walker_schemes = _names(args.walker_schemes, list(registered), "--walker-schemes") or WALKER_SCHEMES
    by_name = {r.name: r for r in REGIMES}
    regime_names = _names(args.regimes, list(by_name), "--regimes")
    regimes = REGIMES if regime_names is None else tuple(by_name[n] for n in regime_names)
    margin = () if args.no_margin else MARGIN_SCALES
    if args.plot:
        require_matplotlib("--plot")
        if cells is not None:
            raise ConfigError("--plot: allowed only with every cell (the main effects need the whole grid)")
    control = config_from_args(args).get(ControlConfig)
    cp = CompareParams(study=StudyParams(duration_s=args.duration))
    n_cells = len(set(cells or grid()) | {"scheduled/ze"})
    total = compare_steps(round(args.duration / cp.study.dt), n_cells, len(regimes), len(margin))
    started = time.monotonic()
    with progress_bar(total, "compare") as update:
        result = run_compare(
            args.runs,
            args.seed,
            control,
            cp,
            cells=cells,
            regimes=regimes,
            margin_scales=margin,
            jobs=args.jobs,
            progress=update,
        )
    if args.walker_runs > 0:
        result["walker"] = _walker_cells(args, config_from_args(args), walker_schemes, regimes)
        attach_power(result, result["walker"])
    result["wall_s"] = time.monotonic() - started
    if args.json:
        write_json(args.json, result)
    table = compare_markdown(result)
    if args.markdown:
        write_text(args.markdown, table, "--markdown")
    if args.plot:
        from bipedtele.studies.compare_report import plot_effects

        save_figure(plot_effects(result), args.plot)
    if args.json != "-" and args.markdown != "-":
        sys.stdout.write(table)
        sys.stdout.write(f"compare: {result['wall_s']:.0f} s\n")
    return 0


def _walker_cells(args: argparse.Namespace, cfg: Any, schemes: tuple[str, ...], regimes: Any) -> Any:
    """Run the walker cells through the backend the follower package registers (the core never imports it)."""
    backend = walker_backend("bipedtele.compare_backends", "--walker-runs", "0, or with the follower package")
    names = set(schemes) | {"paper"}
    total = args.walker_runs * len(regimes) * len(names)
    with progress_bar(total, "walker") as update:
        return backend(
            cfg,
            runs=args.walker_runs,
            seed=args.seed,
            duration_s=args.walker_duration,
            schemes=schemes,
            regimes=regimes,
            jobs=args.jobs,
            progress=update,
        )


def add_compare_parser(sub: Any) -> None:
    """Add ``bipedtele compare [--runs N] [--schemes ...] [--regimes ...] [--json F] [--markdown F] [--plot F]``."""
    p = sub.add_parser("compare", help="the factorial grid of control schemes, paired, over delay regimes")
    p.add_argument("--runs", type=int, default=30, help="paired runs per cell and regime (default 30)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds per run (default 60)")
    p.add_argument(
        "--schemes",
        nargs="+",
        metavar="NAME",
        help="grid cells (damping/feedback[/pc]) or named schemes to run (default: the whole grid)",
    )
    p.add_argument("--regimes", nargs="+", metavar="NAME", help="delay regimes (default: all)")
    p.add_argument("--no-margin", action="store_true", help="skip the released-handle runs")
    p.add_argument(
        "--walker-runs",
        type=int,
        default=0,
        help="paired runs per cell on the pybullet walker (default 0: none; docs/schemes.md gives the longer set)",
    )
    p.add_argument("--walker-schemes", nargs="+", metavar="NAME", help="named schemes on the walker (default: all six)")
    p.add_argument("--walker-duration", type=float, default=12.0, help="simulated seconds per walker run (default 12)")
    p.add_argument(
        "--jobs", type=int, default=2, help="processes for the reduced cells and the walker runs (default 2)"
    )
    p.add_argument("--json", metavar="FILE", help="write the result as JSON ('-' for stdout)")
    p.add_argument("--markdown", metavar="FILE", help="write the table as markdown ('-' for stdout)")
    p.add_argument("--plot", metavar="FILE.png", help="write the axes' main effects as a figure")
    add_config_args(p)
    p.set_defaults(func=_run_compare)
