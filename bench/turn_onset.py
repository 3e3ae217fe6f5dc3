"""Benchmark: the walker's turn limit-cycle onset against the turn loop closed through the gait's latency.

    .venv/bin/python bench/turn_onset.py [--T 0.8,1.0,1.2] [--scan 1,1.5,2,2.5,3,3.5,4]
        [--resolution 0.05] [--warmup 60] [--json docs/method_latency.json]

Issue 31, item 4 (docs/method_latency.md). Per walking cycle ``T``, in simulated time on the
pybullet walker (one process):

1. **latency** (:func:`~bipedtele.follower.sim.turn_onset.step_latency`): open loop, a step
   of the turn command (4 -> 8 deg/s) at every other control tick of one gait step; the
   lag of the accumulated yaw behind an immediate step, and the within-step profile of
   the turn rate;
2. **onset** (:func:`~bipedtele.follower.sim.turn_onset.find_onset`): the walker map's
   limit-cycle marker from standing under the constant reference (5 cm/s, 4 deg/s),
   ``sigma = 0``, ``eps = 0.05 s``, a scan of the turn damping ``tau`` then bisection to
   ``--resolution``; the oscillation period at the first marked ``tau``;
3. **checks**: the bracket's two ends again with other warm-ups (``--checks``), and the
   lower end started from the limit cycle (the first half of the warm-up at ``above + 1``:
   hysteresis);
4. **growth** (:func:`~bipedtele.follower.sim.turn_onset.flip_growth`): the measured growth
   per cycle of the step-to-step turn alternation (the flip mode) at ``below - 0.1``,
   ``below``, ``above``, ``above + 0.1``, against the model's flip eigenvalue; where it
   crosses 1 (linear interpolation): the onset without the marker's finite warm-up;
5. **models** (:mod:`bipedtele.control.latency`): the onset predicted by the turn block
   closed through a pure delay ``T/2`` (the issue's hypothesis) and the measured mean
   latency, and through the gait's latch (a hold of ``T/2``, continuous and 50 Hz servo),
   each with the gain on the robot's speed (22) ("paper") and on the observer (28)
   ("servo", what the walker's servo runs); the predicted period.

Prints the tables and writes everything to ``--json``. Figures are what they are; a
prediction is "inside" when it lies in the measured bracket.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.latency import delay_onset, latched_onset, latched_step_map_discrete
from bipedtele.follower.sim.turn_onset import OnsetSettings, constant_run, find_onset, flip_growth, step_latency


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


def models(T: float, latency_s: float, cfg: ControlConfig, dt: float) -> list[dict[str, Any]]:
    """Predicted onsets and periods at cycle ``T`` [s] for every model variant."""
    out: list[dict[str, Any]] = []
    for form in ("paper", "servo"):
        for name, L in (("delay T/2", T / 2.0), ("delay measured", latency_s)):
            tau, w = delay_onset(L, cfg, form)
            out.append({"model": name, "form": form, "L_s": L, "tau": tau, "period_s": 2.0 * math.pi / w})
        for name, step in (("latched", None), ("latched 50 Hz", dt)):
            tau, lam = latched_onset(T, cfg, form, dt=step)
            # an eigenvalue -1 of the step map: period two steps = T; +1 would be no oscillation
            period = (
                T
                if lam.real < 0 and abs(lam.imag) < 1e-6
                else 2.0 * (T / 2.0) * math.pi / abs(math.atan2(lam.imag, lam.real))
            )
            out.append(
                {
                    "model": name,
                    "form": form,
                    "L_s": None,
                    "tau": tau,
                    "period_s": period,
                    "eigenvalue": [lam.real, lam.imag],
                }
            )
    return out


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--T", type=_floats, default=[0.8, 1.0, 1.2], help="walking cycles [s]")
    ap.add_argument("--scan", type=_floats, default=[1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0], help="turn dampings scanned")
    ap.add_argument("--resolution", type=float, default=0.05, help="bracket width the bisection stops at")
    ap.add_argument("--warmup", type=float, default=60.0, help="warm-up before the window [s]")
    ap.add_argument("--checks", type=_floats, default=[120.0], help="warm-ups of the bracket check [s]")
    ap.add_argument("--stride", type=int, default=2, help="latency step times every N control ticks")
    ap.add_argument("--json", type=Path, default=Path("docs/method_latency.json"))
    ap.add_argument("-v", "--verbose", action="store_true")
    return ap


def _print_table(rows: list[dict[str, Any]]) -> None:
    print()
    print("| model | form | " + " | ".join(f"T = {r['T']:g} s: tau* (period [s])" for r in rows) + " | inside all |")
    print("| --- | --- | " + " | ".join("---" for _ in rows) + " | --- |")
    print(
        "| **walker, measured** | | "
        + " | ".join(
            f"({r['onset']['below']:g}, {r['onset']['above']:g}] "
            f"({next(x['period_s'] for x in r['onset']['runs'] if x['tau'] == r['onset']['above']):.2f})"
            for r in rows
        )
        + " | |"
    )
    print("| **walker, growth = 1** | | " + " | ".join(f"{r['growth_crossing']:.3f}" for r in rows) + " | |")
    for i, p in enumerate(rows[0]["models"]):
        cells = []
        for r in rows:
            q = r["models"][i]
            cells.append(f"{q['tau']:.3f} ({q['period_s']:.2f}){' in' if q['inside'] else ''}")
        ok = all(r["models"][i]["inside"] for r in rows)
        print(f"| {p['model']} | {p['form']} | " + " | ".join(cells) + f" | {'yes' if ok else 'no'} |")


def _growth(
    T: float, onset: Any, st: OnsetSettings, cfg: ControlConfig, dt: float
) -> tuple[list[dict[str, Any]], float]:
    growth = []
    for tau in (onset.below - 0.1, onset.below, onset.above, onset.above + 0.1):
        g = flip_growth(round(tau, 6), T, st)
        lam = np.linalg.eigvals(latched_step_map_discrete(tau, T / 2.0, cfg, "servo", dt))
        g["model_latched_servo_50hz"] = float(abs(lam[np.argmin(lam.real)]) ** 2)
        growth.append(g)
        print(
            f"  growth T {T:.2f} tau {tau:.4f}: {g['radius']:.3f} per cycle ({g['steps_fitted']} steps, "
            f"{g['start']}); latched servo model {g['model_latched_servo_50hz']:.3f}",
            flush=True,
        )
    crossing = math.nan
    for g0, g1 in itertools.pairwise(growth):
        r0, r1 = g0["radius"], g1["radius"]
        if math.isfinite(r0) and math.isfinite(r1) and r0 < 1.0 <= r1:
            crossing = g0["tau"] + (1.0 - r0) * (g1["tau"] - g0["tau"]) / (r1 - r0)
            break
    print(f"  growth crosses 1 at tau {crossing:.3f}", flush=True)
    return growth, crossing


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    cfg = ControlConfig()
    st = OnsetSettings(warmup_s=args.warmup)
    dt = 1.0 / st.control_rate_hz
    t_start = time.monotonic()
    rows = []
    for T in args.T:
        t0 = time.monotonic()
        lat = step_latency(T, stride=args.stride, control_rate_hz=st.control_rate_hz)
        prof = lat["profile"]
        print(
            f"T {T:.2f} s latency: mean {lat['mean_s']:.3f} s, min {lat['min_s']:.3f}, max {lat['max_s']:.3f} "
            f"(T/4 = {T / 4:.3f}, T/2 = {T / 2:.3f}); profile {min(prof):.2f}-{max(prof):.2f} of the mean "
            f"({time.monotonic() - t0:.0f} s wall)",
            flush=True,
        )
        t0 = time.monotonic()
        onset = find_onset(T, args.scan, args.resolution, st)
        first = next(r for r in sorted(onset.runs, key=lambda r: r.tau) if r.tau == onset.above)
        print(
            f"T {T:.2f} s onset: tau in ({onset.below:g}, {onset.above:g}]; period at {onset.above:g}: "
            f"{first.period_s:.3f} s; turn std below {next(r.turn_std for r in onset.runs if r.tau == onset.below):.2f}, "
            f"above {first.turn_std:.2f} deg/s ({time.monotonic() - t0:.0f} s wall)",
            flush=True,
        )
        checks = []
        for w in args.checks:
            cs = OnsetSettings(warmup_s=w)
            for tau in (onset.below, onset.above):
                checks.append({"warmup_s": w, **constant_run(tau, T, cs).__dict__})
        hyst = constant_run(onset.below, T, st, start_tau=onset.above + 1.0)
        checks.append({"warmup_s": st.warmup_s, "start_tau": onset.above + 1.0, **hyst.__dict__})
        for c in checks:
            print(
                f"  check T {T:.2f} tau {c['tau']:g} warm-up {c['warmup_s']:g} s"
                + (f" from tau {c['start_tau']:g}" if "start_tau" in c else "")
                + f": turn std {c['turn_std']:.2f} deg/s, limit cycle {c['limit_cycle']}",
                flush=True,
            )
        growth, crossing = _growth(T, onset, st, cfg, dt)
        preds = models(T, lat["mean_s"], cfg, dt)
        for p in preds:
            p["inside"] = bool(onset.below < p["tau"] <= onset.above)
        rows.append(
            {
                "T": T,
                "latency": lat,
                "onset": onset.as_dict(),
                "checks": checks,
                "growth": growth,
                "growth_crossing": crossing,
                "models": preds,
            }
        )
    _print_table(rows)
    wall = time.monotonic() - t_start
    print(f"\nwall {wall:.0f} s")
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=False).stdout.strip()
    out = {
        "commit": commit,
        "command": "bench/turn_onset.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "settings": {
            "onset": st.__dict__,
            "scan": args.scan,
            "resolution": args.resolution,
            "check_warmups_s": args.checks,
            "control": {"D": cfg.D, "k_s": cfg.k_s, "beta_r": cfg.beta_r},
        },
        "wall_s": wall,
        "rows": rows,
    }
    args.json.write_text(json.dumps(out, indent=1, default=float) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
