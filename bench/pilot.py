"""The pilot on a model of the follower: how the reduced model in (30) sets the turn error.

Runs the demo's pilot (``leader/operators/pilot.py``, default settings of the ``localhost-delay``
profile) against a kinematic robot that walks the follower's reference model, eq. (28)
closed through the observer (12), with the damping ``sigma_r`` that the online choice (30)
picks for the standing delays (``solve_exact``, T clipped to the walker's 0.8-2.0 s), under
the shipped intercontinental trace (and the trace doubled). Prints, per reduced model (the
paper's ``dp``/``k_v`` or the walker-calibrated ones): (30)'s choice, completion time, and
the per-step (0.4 s windows) mean speed errors ``|ref(t - h1) - eta|``.

The model is not the simulated NAO (no gait, no sonar slow-down, exact speeds), so its times
are shorter than the demo's; it isolates what (28) + (12) + (30) do to a slalom's turn
reference. Usage: ``.venv/bin/python bench/pilot.py``.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time

import numpy as np
from bipedtele.config.profile import load_config
from bipedtele.control.online import solve_exact
from bipedtele.leader.operator import make_operator
from bipedtele.leader.operators.pilot import course_from_config
from bipedtele.link.delaymodels import parse_delay_model
from bipedtele.link.messages import Feedback
from bipedtele.telemetry import LeaderSample


class ReferenceModelRobot:
    """A unicycle whose speeds are the follower's commanded ``eta`` of (28) + (12)."""

    def __init__(self, cfg, s_r, h1, h2, v_max=10.0, w_max=25.0) -> None:
        self.D, self.k_s = np.array(cfg.D), np.array(cfg.k_s)
        self.beta = np.array(cfg.beta_r)
        self.s_r = np.asarray(s_r, dtype=float)
        self.h1f, self.h2f = h1, h2
        self.lim = np.array([v_max, w_max])
        self.eta = np.zeros(2)
        self.z = np.zeros(2)
        self.ref = np.zeros(2)
        self.x = self.y = self.yaw = 0.0
        self.cmds: collections.deque = collections.deque()
        self.fbs: collections.deque = collections.deque()
        self.cmd_at = self.fb_at = -math.inf
        self.seq = 0
        self.log: list[tuple[float, float, float, float, float]] = []
        self.min_clear = math.inf

    def command(self, t: float, ref) -> None:
        self.cmd_at = max(self.cmd_at, t + self.h1f(t))  # in order, like a TCP path
        self.cmds.append((self.cmd_at, np.asarray(ref, dtype=float)))

    def step(self, t: float, dt: float, course) -> None:
        while self.cmds and self.cmds[0][0] <= t:
            self.ref = self.cmds.popleft()[1]
        z_prev = self.z.copy()
        self.z += (self.eta - self.z) * dt / self.beta
        dz = (self.z - z_prev) / dt
        deta = (self.k_s * (self.ref - self.z) - self.s_r * dz) / self.D
        self.eta = np.clip(self.eta + dt * deta, -self.lim, self.lim)
        v, w = self.eta
        self.yaw += math.radians(w) * dt
        self.x += v / 100.0 * math.cos(self.yaw) * dt
        self.y += v / 100.0 * math.sin(self.yaw) * dt
        for o in course:
            self.min_clear = min(self.min_clear, math.hypot(self.x - o.x, self.y - o.y) - o.radius)
        self.log.append((t, *self.ref, *self.eta))

    def publish(self, t: float) -> None:
        self.seq += 1
        self.fb_at = max(self.fb_at, t + self.h2f(t))
        fb = Feedback(
            seq=self.seq,
            t=t,
            eta=[float(self.eta[0]), float(self.eta[1])],
            pose=[self.x, self.y, self.yaw],
            sonar=[2.55, 2.55],
            h1_s=self.h1f(t),
        )
        self.fbs.append((self.fb_at, fb))

    def latest(self, t: float):
        out = None
        while self.fbs and self.fbs[0][0] <= t:
            out = self.fbs.popleft()
        return out


def run(model: str, scale: float) -> dict[str, float]:
    cfg = load_config("localhost-delay", [f'control.hybrid_model="{model}"'])
    ctl = dataclasses.replace(cfg.control, T_range=[0.8, 2.0])
    choice = solve_exact(np.array([ctl.s_e_min, ctl.s_e_min]), ctl)
    m1, m2 = parse_delay_model("trace:intercontinental:h1"), parse_delay_model("trace:intercontinental:h2")
    robot = ReferenceModelRobot(ctl, choice.s_r, lambda t: scale * m1.delay_s(t), lambda t: scale * m2.delay_s(t))
    course = course_from_config(cfg)
    op = make_operator("pilot", cfg)
    fb, t_recv, dt, t = None, 0.0, 0.01, 0.0
    while t < 900.0 and not op.done:
        got = robot.latest(t)
        if got is not None:
            t_recv, fb = got
        op.update(t, fb)
        robot.command(t, op.intended)
        op.observe_sample(
            LeaderSample(
                t=t,
                t_device=t,
                ref_v=float(op.intended[0]),
                ref_w=float(op.intended[1]),
                enable=True,
                h1_ms=1e3 * robot.h1f(t),
                h2_ms=1e3 * robot.h2f(t),
                feedback_age_ms=None if fb is None else 1e3 * (t - t_recv),
            )
        )
        robot.step(t, dt, course)
        robot.publish(t)
        t += dt
    log = np.array(robot.log)
    n = round(0.4 / dt)
    k = len(log) // n
    steps = log[: k * n].reshape(k, n, 5).mean(axis=1)
    moving = np.abs(steps[:, 3]) > 0.5
    err = np.abs(steps[moving, 1:3] - steps[moving, 3:5]).mean(axis=0)
    return {
        "s_r_v": float(choice.s_r[0]),
        "s_r_w": float(choice.s_r[1]),
        "T": float(choice.T),
        "done": float(op.done),
        "passes": float(op.passes_done),
        "completion_s": t,
        "forward_err": float(err[0]),
        "turn_err": float(err[1]),
        "clearance_m": robot.min_clear,
    }


def main() -> None:
    print(
        "reduced model in (30) | delays | sigma_r [fwd, turn] | T [s] | passes | completion [s] | "
        "forward err per step [cm/s] | turn err per step [deg/s] | clearance [m] | wall [s]"
    )
    for model in ("paper", "speed-loop"):
        for scale in (1.0, 2.0):
            t0 = time.perf_counter()
            r = run(model, scale)
            print(
                f"{model} | x{scale:g} | [{r['s_r_v']:.2f}, {r['s_r_w']:.2f}] | {r['T']:.2f} | "
                f"{r['passes']:.0f} | {r['completion_s']:.1f} | {r['forward_err']:.2f} | "
                f"{r['turn_err']:.2f} | {r['clearance_m']:.2f} | {time.perf_counter() - t0:.1f}"
            )


if __name__ == "__main__":
    main()
