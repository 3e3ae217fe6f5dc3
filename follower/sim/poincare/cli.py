"""``bipedtele poincare``: its arguments, their checks and the printed rows."""

from __future__ import annotations

import argparse
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.follower.config import FollowerConfig
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.poincare.plot import plot_poincare
from bipedtele.follower.sim.poincare.state import MapSettings
from bipedtele.follower.sim.poincare.sweep import poincare_grid
from bipedtele.follower.sim.poincare.table import walker_table
from bipedtele.follower.sim.torque_config import TorqueConfig


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{text!r}: allowed: comma-separated numbers") from None


def _run_table(args: argparse.Namespace, cfg: Any, sigmas: list[float], Ts: list[float], st: MapSettings) -> int:
    """``bipedtele poincare --table F``: tabulate the walker's map, write it, print its rows."""
    import json
    import sys
    from pathlib import Path

    taus = _floats(args.tau)
    if not taus or min(taus) < 0:
        raise ConfigError("--tau: allowed: a non-empty list, tau >= 0")
    sim = cfg.get(SimConfig)
    table = walker_table(sigmas, taus, Ts, control=cfg.get(ControlConfig), sim=sim, settings=st, jobs=args.jobs)
    table["command"] = (
        f"bipedtele poincare --table {args.table} --sigma {args.sigma} --tau {args.tau} --T {args.T} "
        f"--warmup {args.warmup:g} --delta-scale {args.delta_scale:g} --foot {args.foot} --jobs {args.jobs}"
    )
    try:
        Path(args.table).write_text(json.dumps(table, indent=1) + "\n", encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"--table {args.table}: cannot write ({exc.strerror})") from None
    sys.stdout.write("sigma  tau    T [s]  rho_walker  turn_std  forward_std  speed  turn_rate  limit_cycle\n")
    for i, sg in enumerate(table["sigma"]):
        for j, ta in enumerate(table["tau"]):
            for k, T in enumerate(table["T"]):
                f = {key: table[key][i][j][k] for key in ("rho", "turn_std", "forward_std", "speed", "turn_rate")}
                lc = "yes" if table["limit_cycle"][i][j][k] else "no"
                sys.stdout.write(
                    f"{sg:5.2f}  {ta:5.2f}  {T:5.2f}  {f['rho']:10.3f}  {f['turn_std']:8.2f}  "
                    f"{f['forward_std']:11.2f}  {f['speed']:5.2f}  {f['turn_rate']:9.2f}  {lc}\n"
                )
    sys.stdout.write(f"({table['wall_s']:.0f} s wall)\n")
    return 0


def _run(args: argparse.Namespace) -> int:
    import json
    import sys
    from pathlib import Path

    from bipedtele.cli import config_from_args

    cfg = config_from_args(args)
    sigmas, Ts = _floats(args.sigma), _floats(args.T)
    if args.newton < 0:
        raise ConfigError(f"--newton {args.newton}: allowed: >= 0")
    if not sigmas or not Ts or min(sigmas) < 0:
        raise ConfigError("--sigma/--T: allowed: non-empty lists, sigma >= 0")
    if args.jobs < 1:
        raise ConfigError(f"--jobs {args.jobs}: allowed: >= 1")
    if not args.warmup >= 5.0:
        raise ConfigError(f"--warmup {args.warmup}: allowed: >= 5 s")
    st = MapSettings(
        foot=args.foot,
        warmup_s=args.warmup,
        delta_scale=args.delta_scale,
        control_rate_hz=cfg.get(FollowerConfig).control_rate_hz,
        contraction=not args.table,
        newton_iterations=args.newton,
        torque=walker_torque(args.robot, cfg),
    )
    sim = cfg.get(SimConfig)
    for T in Ts:
        if not sim.cycle_min_s - 1e-9 <= T <= sim.cycle_max_s + 1e-9:
            raise ConfigError(
                f"--T {T:g}: allowed: the simulated NAO's cycle range [{sim.cycle_min_s:g}, {sim.cycle_max_s:g}] s"
            )
    if args.table:
        return _run_table(args, cfg, sigmas, Ts, st)
    data = poincare_grid(sigmas, Ts, control=cfg.get(ControlConfig), sim=sim, settings=st, jobs=args.jobs)
    if args.json:
        try:
            Path(args.json).write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"--json {args.json}: cannot write ({exc.strerror})") from None
    if args.plot:
        try:
            plot_poincare(data).savefig(args.plot, dpi=90)
        except OSError as exc:
            raise ConfigError(f"--plot {args.plot}: cannot write ({exc.strerror})") from None
    out = sys.stdout
    out.write(
        "sigma_r      T [s]  rho_walker  contraction  transient  rho_reduced  rho_speed_loop  speed [cm/s]  spread  "
        "turn_std  limit_cycle\n"
    )
    for p in [*data["points"], data["operating_point"]]:
        s = "/".join(f"{v:.2f}" for v in p["sigma_r"])
        out.write(
            f"{s:<12} {p['T']:5.2f}  {p['rho_walker']:10.3f}  {p['contraction']:11.3f}  {p['transient']:9.2f}  {p['rho_reduced']:11.3f}  "
            f"{p['rho_reduced_speed_loop']:14.3f}  {p['fixed_point_speed']:12.2f}  {p['spread']:6.1f}  "
            f"{p['turn_std']:8.2f}  {'yes' if p['limit_cycle'] else 'no'}\n"
        )
    out.write("(last row: the follower's operating point at zero delay)\n")
    nw = data["operating_point"].get("newton")
    if nw is not None:
        rho = ", ".join(f"{k}x: {v:.3f}" for k, v in nw["rho_by_scale"].items())
        out.write(
            f"operating point, Newton on P(x) = x: residual max {nw['residual_max'][0]:.3g} -> {nw['residual_max'][-1]:.3g}, "
            f"rms {nw['residual_rms'][0]:.3g} -> {nw['residual_rms'][-1]:.3g} (perturbation sizes, "
            f"{len(nw['steps'])} steps); radius of (26) at the fixed point by perturbation size {rho}\n"
        )
    return 0


def walker_torque(robot: str, cfg: Any) -> TorqueConfig | None:
    """``--robot``: None for the position walker (``sim``), the profile's ``[torque]`` for ``sim-torque``."""
    from bipedtele.config.profile import resolve_section

    return resolve_section(cfg, TorqueConfig, "torque") if robot == "sim-torque" else None


def add_walker_arg(p: Any) -> None:
    """``--robot {sim,sim-torque}``: the simulated walker whose map is measured."""
    p.add_argument(
        "--robot",
        choices=["sim", "sim-torque"],
        default="sim",
        help="the position walker (sim, default) or the torque walker (sim-torque: the paper's joint law (15))",
    )


def add_poincare_parser(sub: Any) -> None:
    """``bipedtele poincare [--json F] [--plot F.png] [--sigma 0,2.5,5] [--T 0.8,1.2,1.6]``."""
    from bipedtele.cli import add_config_args

    p = sub.add_parser("poincare", help="the simulated walker's own Poincare map next to the reduced model's")
    p.add_argument("--sigma", default="0,2.5,5", help="real damping values, both channels (default 0,2.5,5)")
    p.add_argument(
        "--T",
        default="0.8,1.2,1.6",
        help="walking cycles [s]; T/2 on the control and physics grid (default 0.8,1.2,1.6)",
    )
    p.add_argument("--foot", choices=["L", "R"], default="L", help="foot whose touchdown is the section (default L)")
    p.add_argument("--warmup", type=float, default=30.0, help="walking time before the fixed point [s] (default 30)")
    p.add_argument(
        "--delta-scale", type=float, default=1.0, help="factor on the perturbation sizes of (26) (default 1)"
    )
    p.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    p.add_argument(
        "--tau",
        default="0,1.5,2.5,3,3.5,5",
        help="turn damping values of --table (default 0,1.5,2.5,3,3.5,5)",
    )
    p.add_argument(
        "--table",
        metavar="FILE",
        help="tabulate the walker's map over --sigma (forward) x --tau (turn) x --T into FILE, the surrogate of "
        'hybrid_model = "walker" (shipped: common/data/walker_map.json; docs/walker_map.md); no contraction runs',
    )
    p.add_argument(
        "--newton",
        type=int,
        default=0,
        metavar="N",
        help="at the operating point, solve P(x) = x by Newton (at most N Jacobians) and measure the radius there "
        "at 0.3/1/3x the perturbation sizes (default 0: off)",
    )
    p.add_argument("--json", metavar="FILE", help="write the points as JSON")
    p.add_argument("--plot", metavar="FILE.png", help="write the surfaces (Fig. 6 counterpart)")
    add_walker_arg(p)
    add_config_args(p)
    p.set_defaults(func=_run)
