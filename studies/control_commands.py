"""Sub-commands over the control core: ``surfaces`` (Fig. 6) and ``study`` (Fig. 8).

The computing is :mod:`bipedtele.control` (pure); this module parses the arguments, writes
the JSON, markdown and figures (:mod:`bipedtele.tools.plots`) and shows a progress bar
(tqdm, when installed and stderr is a terminal).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config.profile import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.tools.backends import walker_backend
from bipedtele.tools.plots import require_matplotlib

__all__ = ["add_study_parser", "add_surfaces_parser", "progress_bar", "save_figure", "write_json", "write_text"]


def write_json(path: str, data: Any) -> None:
    """Write ``data`` as JSON to ``path`` (``-``: stdout); an unwritable path is a config error."""
    text = json.dumps(data, indent=1)
    if path == "-":
        sys.stdout.write(text + "\n")
        return
    try:
        Path(path).write_text(text + "\n", encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"--json {path}: cannot write ({exc.strerror})") from None


def save_figure(fig: Any, path: str) -> None:
    """Save a figure to ``path``; an unwritable path is a config error naming ``--plot``."""
    try:
        fig.savefig(path, dpi=90)
    except OSError as exc:
        raise ConfigError(f"--plot {path}: cannot write ({exc.strerror})") from None


def _run_surfaces(args: argparse.Namespace) -> int:
    from bipedtele.control.surfaces import compute_surfaces

    for dp in args.dp:
        if not 0.0 < dp <= 1.0:
            raise ConfigError(f"--dp {dp}: allowed: 0 < dp <= 1")
    if args.plot:
        require_matplotlib("--plot")
    cfg = config_from_args(args).get(ControlConfig)
    data = compute_surfaces(args.dp, cfg, n_sigma=args.n_sigma, n_T=args.n_T)
    if args.json:
        write_json(args.json, data)
    if args.plot:
        from bipedtele.tools.plots import plot_surfaces

        save_figure(plot_surfaces(data), args.plot)
    if args.json != "-":
        for i, dp in enumerate(data["dp"]):
            flat = [v for row in data["rho"][i] for v in row]
            sys.stdout.write(f"dp={dp:g}: max|l_hybrid| in [{min(flat):.4f}, {max(flat):.4f}] over sigma_r x T\n")
    return 0


def write_text(path: str, text: str, flag: str) -> None:
    """Write ``text`` to ``path`` (``-``: stdout); an unwritable path is a config error naming ``flag``."""
    if path == "-":
        sys.stdout.write(text)
        return
    try:
        Path(path).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{flag} {path}: cannot write ({exc.strerror})") from None


@contextlib.contextmanager
def progress_bar(total: int, desc: str = "study") -> Iterator[Callable[[int], None] | None]:
    """Yield a tqdm bar's ``update`` when stderr is a terminal and tqdm is installed, else None."""
    if not sys.stderr.isatty():
        yield None
        return
    try:
        from tqdm import tqdm
    except ImportError:  # the optional extra is not installed: no bar
        yield None
        return
    with tqdm(total=total, unit="step", desc=desc, leave=False, file=sys.stderr) as bar:
        yield bar.update


def _run_study(args: argparse.Namespace) -> int:
    from bipedtele.studies.study import (
        SENSITIVITY,
        StudyParams,
        run_sensitivity,
        run_study,
        sensitivity_markdown,
        study_steps,
    )

    runs = args.runs if args.runs is not None else (3 if args.walker else 100 if args.sensitivity else 500)
    if runs < 1:
        raise ConfigError(f"--runs {runs}: allowed: >= 1")
    duration = args.duration if args.duration is not None else (30.0 if args.walker else 60.0)
    if not duration >= 1.0:
        raise ConfigError(f"--duration {duration}: allowed: >= 1 s")
    if args.walker and args.sensitivity:
        raise ConfigError("--walker with --sensitivity: allowed: one of them")
    if args.markdown and not (args.sensitivity or args.walker):
        raise ConfigError("--markdown: allowed only with --sensitivity or --walker")
    if args.plot:
        require_matplotlib("--plot")
    cfg = config_from_args(args)
    control = cfg.get(ControlConfig)
    params = StudyParams(duration_s=duration)
    if args.walker:
        backend = walker_backend(
            "bipedtele.study_backends", "--walker", "with the follower package (bipedtele.follower)"
        )
        result = backend(cfg, runs=runs, seed=args.seed, duration_s=duration)
    elif args.sensitivity:
        total = study_steps(params) * len(SENSITIVITY)
        with progress_bar(total) as update:
            result = run_sensitivity(runs, args.seed, control, params, progress=update)
    else:
        with progress_bar(study_steps(params)) as update:
            result = run_study(runs, args.seed, control, params, progress=update)
    if args.json:
        write_json(args.json, result)
    if args.sensitivity:
        table = sensitivity_markdown(result)
        if args.markdown:
            write_text(args.markdown, table, "--markdown")
        if args.json != "-" and args.markdown != "-":
            sys.stdout.write(table)
        return 0
    if args.walker:
        from bipedtele.studies.study import study_markdown

        table = study_markdown(result)
        if args.markdown:
            write_text(args.markdown, table, "--markdown")
        if args.json != "-" and args.markdown != "-":
            sys.stdout.write(table)
        return 0
    if args.plot:
        from bipedtele.tools.plots import plot_study

        save_figure(plot_study(result), args.plot)
    if args.json != "-":
        sys.stdout.write(f"study: {runs} runs per scheme, {duration:g} s each, seed {args.seed}\n")
        for c in result["cases"]:
            for s in ("cp", "vp"):
                r = c[s]
                sys.stdout.write(
                    f"  {c['name']:<20} h1={c['h1_ms']:7.1f} ms h2={c['h2_ms']:7.1f} ms {s.upper()}: "
                    f"forward {r['forward_error']:.3f} cm/s [{r['forward_ci95'][0]:.3f}, {r['forward_ci95'][1]:.3f}] "
                    f"(orbit offset {r['forward_orbit_offset']:.3f})  "
                    f"turn {r['turn_error']:.3f} deg/s [{r['turn_ci95'][0]:.3f}, {r['turn_ci95'][1]:.3f}]  "
                    f"diverged {r['diverged']}\n"
                )
    return 0


def add_surfaces_parser(sub: Any) -> None:
    """``bipedtele surfaces --dp 0.25 0.5 0.7 [--json F] [--plot F.png]`` (Fig. 6)."""
    p = sub.add_parser("surfaces", help="stability surfaces max|l_hybrid| over sigma_r x T (Fig. 6)")
    p.add_argument("--dp", type=float, nargs="+", default=[0.25, 0.5, 0.7], help="reset factors (0 < dp <= 1)")
    p.add_argument("--json", metavar="FILE", help="write the surfaces as JSON ('-' for stdout)")
    p.add_argument("--plot", metavar="FILE.png", help="write a figure")
    p.add_argument(
        "--n-sigma", type=int, default=41, choices=range(2, 1001), metavar="N", help="sigma_r points (default 41)"
    )
    p.add_argument("--n-T", type=int, default=46, choices=range(2, 1001), metavar="N", help="T points (default 46)")
    add_config_args(p)
    p.set_defaults(func=_run_surfaces)


def add_study_parser(sub: Any) -> None:
    """Add ``bipedtele study`` (Fig. 8, Sec. 4).

    ``bipedtele study [--runs N] [--seed S] [--json F] [--plot F.png] [--sensitivity | --walker]
    [--markdown F]``.
    """
    p = sub.add_parser("study", help="CP vs VP numerical study over the delay cases (Fig. 8)")
    p.add_argument(
        "--runs",
        type=int,
        default=None,
        help="runs per scheme and case (default 500; 100 with --sensitivity; 3 with --walker)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--duration", type=float, default=None, help="simulated seconds per run (default 60; 30 with --walker)"
    )
    p.add_argument("--json", metavar="FILE", help="write the results as JSON ('-' for stdout)")
    p.add_argument("--plot", metavar="FILE.png", help="write Fig. 8")
    p.add_argument(
        "--sensitivity",
        action="store_true",
        help="repeat CP vs VP over the settings the paper leaves open and print one table",
    )
    p.add_argument(
        "--walker",
        action="store_true",
        help="CP vs VP on the pybullet follower in simulated time (needs the follower package)",
    )
    p.add_argument(
        "--markdown", metavar="FILE", help="with --sensitivity or --walker: write the table ('-' for stdout)"
    )
    add_config_args(p)
    p.set_defaults(func=_run_study)
