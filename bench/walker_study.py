"""Benchmark of the closed loop on the simulated walker (``bipedtele study --walker``).

Prints wall time, follower ticks and physics steps per wall second, and simulated seconds
per wall second, for a small study (1 run per scheme, 20 s, LAN and congested-satellite
cases); with ``--full`` for the default ``study --walker`` (3 runs per scheme, 30 s, every
delay case).

Usage: ``.venv/bin/python bench/walker_study.py [--full]``
"""

from __future__ import annotations

import argparse
import os
import time

from bipedtele.config.profile import load_config
from bipedtele.control.config import ControlConfig
from bipedtele.follower.config import FollowerConfig
from bipedtele.follower.sim.config import SimConfig
from bipedtele.studies.study import CASES
from bipedtele.studies.walker_study import run_walker_study


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--full", action="store_true", help="time the default study --walker")
    args = ap.parse_args()
    cfg = load_config("default", [])
    control, follower, sim = cfg.get(ControlConfig), cfg.get(FollowerConfig), cfg.get(SimConfig)
    if args.full:
        runs, duration, cases = 3, 30.0, CASES
    else:
        by = {c.name: c for c in CASES}
        runs, duration, cases = 1, 20.0, (by["lan"], by["congested-satellite"])
    print(f"load average {os.getloadavg()[0]:.1f}; {len(cases)} cases x ({runs} CP + {runs} VP) x {duration:g} s")
    t = time.perf_counter()
    res = run_walker_study(control, follower, sim, runs=runs, duration_s=duration, cases=cases)
    wall = time.perf_counter() - t
    simsec = len(cases) * 2 * runs * duration
    print(
        f"wall {wall:.1f} s; {res['ticks_per_s']:.0f} follower ticks/s ({follower.control_rate_hz:g} Hz), "
        f"{simsec * sim.physics_hz / wall:.0f} physics steps/s, {simsec / wall:.1f} simulated s per wall s"
    )
    for c in res["cases"]:
        print(
            f"  {c['name']:<20} CP fwd {c['cp']['forward_error']:.2f} turn {c['cp']['turn_error']:.2f} | "
            f"VP fwd {c['vp']['forward_error']:.2f} turn {c['vp']['turn_error']:.2f} | falls {c['cp']['falls']}/{c['vp']['falls']}"
        )


if __name__ == "__main__":
    main()
