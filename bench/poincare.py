"""Benchmark of the simulated walker's Poincare map (``bipedtele poincare``).

Prints, for the follower's operating point at zero delay: wall time of the warm-up, of the
central-difference Jacobian (26) (100 map evaluations) and of the measured contraction;
simulated seconds, physics steps and control ticks per wall second; the cost of one
save/restore of the whole simulation. With ``--grid`` also the wall time of the default
``bipedtele poincare`` grid (3 x 3 points plus the operating point).

Usage: ``.venv/bin/python bench/poincare.py [--grid]``
"""

from __future__ import annotations

import argparse
import os
import time

from bipedtele.control.config import ControlConfig
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.poincare import MapSettings, WalkerMap, operating_point, poincare_grid


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--grid", action="store_true", help="also time the default grid")
    args = ap.parse_args()
    control, sim, st = ControlConfig(), SimConfig(), MapSettings()
    op = operating_point(control, sim, st.control_rate_hz)
    print(f"load average {os.getloadavg()[0]:.1f}; operating point sigma_r {op['sigma_r']}, T {op['T']} s")
    with WalkerMap(op["sigma_r"], op["T"], op["eps"], control=control, sim=sim, settings=st) as m:
        t0 = time.perf_counter()
        x0 = m.steady()
        t1 = time.perf_counter()
        sim0 = m.sim_seconds
        m.jacobian(x0)
        t2 = time.perf_counter()
        sim1 = m.sim_seconds
        c = m.contraction(x0)
        t3 = time.perf_counter()
        sim2 = m.sim_seconds
        n = 200
        snap = m._snap
        tr = time.perf_counter()
        for _ in range(n):
            m.servo.restore(snap)
        restore_us = (time.perf_counter() - tr) / n * 1e6
    for name, wall, simsec in (
        ("warm-up to the fixed point", t1 - t0, sim0),
        ("Jacobian (100 evaluations)", t2 - t1, sim1 - sim0),
        ("contraction (30 cycles)", t3 - t2, sim2 - sim1),
    ):
        print(
            f"{name:<28}: {wall:6.2f} s wall, {simsec:6.1f} s simulated, {simsec / wall:5.1f} sim-s/s, "
            f"{simsec * sim.physics_hz / wall:7.0f} physics steps/s, {simsec * st.control_rate_hz / wall:6.0f} ticks/s"
        )
    print(
        f"map evaluations per second: {100 / (t2 - t1):.2f}; save/restore of the whole simulation: {restore_us:.0f} us"
    )
    print(f"contraction at the operating point: {c:.3f}")
    if args.grid:
        t = time.perf_counter()
        data = poincare_grid([0.0, 2.5, 5.0], [0.8, 1.2, 1.6], control=control, sim=sim, settings=st)
        wall = time.perf_counter() - t
        simsec = sum(p["sim_seconds"] for p in [*data["points"], data["operating_point"]])
        print(
            f"default grid (10 points): {wall:.1f} s wall, {simsec:.0f} s simulated, "
            f"{simsec * sim.physics_hz / wall:.0f} physics steps/s"
        )


if __name__ == "__main__":
    main()
