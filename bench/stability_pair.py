"""Where stability matters: the torque walker with settings held constant against the online choice (30).

One command, deterministic (simulated time, the real follower loop, the reduced study's
operator and leader; :func:`~bipedtele.studies.walker_study.walker_run`):

    .venv/bin/python bench/stability_pair.py [--seconds 30] [--case intercontinental]

The torque walker (``--robot sim-torque``: the paper's joint law (15) on a 20 % wrong model,
``W_hat`` and the torso-mass estimate) walks the same run (the case's delays, the same
operator's intentions) three times:

1. ``(30)``: the paper's scheme, ``(sigma_r, T, eps)`` chosen online at every impact on the
   reduced model (20)-(23) with this walker's identified ``dp`` and ``k_v``
   (``bipedtele calibrate --robot sim-torque``: 1.0 and 1.336), not a table;
2. the turn and forward damping held at ``sigma_r = 5`` (``T = 0.8 s``, ``eps = 0.05 s``);
3. the joint servo held at ``eps = 0.5 s`` (``sigma_r = 0``, ``T = 0.8 s``).

Printed per run: whether the robot fell (the follower's fall detector, as the demo's report
counts falls), the forward and turn coordination errors per follower tick (eqs. 6 and 10,
over the run up to a fall), the mean cycle and damping applied.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from bipedtele.config.profile import load_config
from bipedtele.control.config import ControlConfig
from bipedtele.control.reduced import StudyParams
from bipedtele.follower.config import FollowerConfig
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.torque_config import TorqueConfig
from bipedtele.studies.study import CASES, case_inputs
from bipedtele.studies.walker_study import WalkerRun, walker_run

#: The torque walker's reduced model, identified by ``bipedtele calibrate --robot sim-torque`` (docs/method.md).
TORQUE_DP, TORQUE_K_V = 1.0, 1.3356

HELD: list[tuple[str, tuple[list[float], float, float] | None]] = [
    ("(30) online", None),
    ("held sigma_r = 5", ([5.0, 5.0], 0.8, 0.05)),
    ("held eps = 0.5 s", ([0.0, 0.0], 0.8, 0.5)),
]


def runs(seconds: float, case_name: str, names: tuple[str, ...] | None = None) -> dict[str, WalkerRun]:
    """Walk the case's run 0 once per setting of :data:`HELD` (those in ``names``; default all)."""
    cfg = load_config("localhost-delay", [])
    control = dataclasses.replace(
        cfg.get(ControlConfig), hybrid_model="speed-loop", calibrated_dp=TORQUE_DP, calibrated_k_v=TORQUE_K_V
    )
    params = StudyParams(duration_s=seconds)
    case = next(c for c in CASES if c.name == case_name)
    inp = case_inputs(case, 1, 0, control, params)
    out: dict[str, WalkerRun] = {}
    for name, hold in HELD:
        if names is not None and name not in names:
            continue
        cp = None if hold is None else (np.array(hold[0], dtype=float), hold[1], hold[2])
        out[name] = walker_run(
            switch=inp.switch,
            intent=inp.intent,
            h1=inp.h1,
            h2=inp.h2,
            control=control,
            follower=cfg.get(FollowerConfig),
            sim=cfg.get(SimConfig),
            params=params,
            cp=cp,
            torque=TorqueConfig(),
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per run (default 30)")
    ap.add_argument(
        "--case",
        default="intercontinental",
        choices=[c.name for c in CASES],
        help="delay case (default intercontinental: the shipped trace)",
    )
    args = ap.parse_args()
    case = next(c for c in CASES if c.name == args.case)
    print(
        f"torque walker, 20 % wrong model, case {case.name} ({case.description}), {args.seconds:.0f} s, "
        f"(30) on the reduced model with dp {TORQUE_DP}, k_v {TORQUE_K_V}"
    )
    print(f"{'setting':>18s} {'fell':>5s} {'fwd err cm/s':>12s} {'turn err deg/s':>14s} {'T s':>5s} {'sigma_r':>12s}")
    for name, r in runs(args.seconds, args.case).items():
        s_r = "/".join(f"{v:.2f}" for v in r.mean_s_r)
        print(
            f"{name:>18s} {'yes' if r.fell else 'no':>5s} {r.forward_error:12.2f} {r.turn_error:14.2f} "
            f"{r.mean_T:5.2f} {s_r:>12s}"
        )


if __name__ == "__main__":
    main()
