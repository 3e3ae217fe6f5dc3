"""The operator feels the obstacle: eq. (33)'s ``k_z f_v`` at run time (issue 11 item 1).

The pybullet NAO (real physics, simulated time) walks through the follower loop towards
a box whose near face is 0.8 m ahead, under a constant 5 cm/s forward command. Each
feedback the follower publishes goes, as it is, to a leader loop (sim Falcon, a hand
holding the handle at 5 cm/s), which renders eq. (31) at 1 kHz.

At rest (33) gives ``z_e = k_g x_m - k_z f_v / k_s``: the tangential force's *share* of
the command is ``k_z f_t / k_s``, the same speed the real follower's reference model (28)
takes off the robot. So:

- with the obstacle, the robot stops short of it, and ``z_e`` has already fallen below
  the command by at least half of that share at the moment the robot first comes to rest
  (the operator feels it while the robot stops, not afterwards), and by the whole share
  (within settling) once the robot rests; the force on the handle rises towards ``k_m``
  times that share (more than half of it: the simulated hand yields a little) and
  pushes the hand back;
- without the obstacle, ``z_e`` stays on the command and the handle force stays near 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.follower.robot import make_robot
from bipedtele.leader.devices.sim_falcon import SimFalcon
from bipedtele.leader.loop import LeaderLoop
from bipedtele.leader.operators.scripted import ScriptedOperator
from bipedtele.link.inbox import FeedbackInbox
from bipedtele.link.messages import Command, Feedback

pytestmark = [pytest.mark.slow, pytest.mark.compute, pytest.mark.timeout(300)]  # compute: deterministic, simulated time

REF = 5.0  # cm/s
RUN_S = 40.0
# A box 0.3 m deep, 0.6 m wide; near face 0.8 m ahead of the robot's start.
OBSTACLE = 'world.obstacles=[{shape="box", position=[0.95, 0.0, 0.25], size=[0.3, 0.6, 0.5]}]'


@dataclass
class Sample:
    t: float
    z_e: float
    f_t: float
    speed: float  # robot's ground speed over the last cycle [cm/s]
    x: float
    contact: bool
    force: float  # leader's force on the handle, forward axis [N]
    handle: float  # the handle's speed reference k_g x_m, forward axis [cm/s]


def drive(obstacle: bool) -> tuple[list[Sample], dict]:
    cfg = load_config("default", [OBSTACLE] if obstacle else [])
    robot = make_robot("sim", config=cfg)
    robot.connect()
    t = [0.0]
    seq = [0]
    cmd: list[Command] = []
    feedback: list[tuple[Feedback, float]] = []

    def publish(msg: object) -> None:
        if isinstance(msg, Feedback):
            feedback.append((msg, t[0]))

    loop = FollowerLoop(
        robot,
        cfg.section("control"),
        cfg.section("follower"),
        command_inbox(cfg.section("follower"), source=lambda: (cmd[-1], t[0]) if cmd else None),
        publish,
        now=lambda: t[0],
    )
    control = cfg.section("control")
    lcfg = cfg.section("leader")
    device = SimFalcon()
    device.connect()
    hand = ScriptedOperator([[0.0, REF, 0.0], [RUN_S + 10, REF, 0.0]], k_g=control.k_g, interp="step")
    leader = LeaderLoop(
        device,
        hand,
        control,
        lambda c: None,
        FeedbackInbox(source=lambda: feedback[-1] if feedback else None),
        cfg=lcfg,
        clock=lambda: t[0],
    )
    n_haptic = round(loop.dt / leader.dt)
    out: list[Sample] = []
    try:
        for _ in range(round(RUN_S / loop.dt)):
            seq[0] += 1
            cmd.append(Command(sid=3, seq=seq[0], t=t[0], ref=[REF, 0.0], h2_s=0.0))
            del cmd[:-1]
            tel = loop.tick()
            for k in range(n_haptic):
                leader.tick(now=t[0] + k * leader.dt)
            out.append(
                Sample(
                    t[0],
                    float(tel.z_e[0]),
                    float(tel.f_v[0]),
                    robot.cycle_speed() * 100,
                    tel.obs.pose[0],
                    tel.obs.in_contact,
                    float(leader.force[0]),
                    float(control.k_g[0] * leader.x_m[0]),
                )
            )
            robot.advance(loop.dt)
            t[0] += loop.dt
    finally:
        robot.disconnect()
    share = {"k_z": control.k_z[0], "k_s": control.k_s[0], "k_m": control.k_m[0]}
    return out, share


@pytest.fixture(scope="module")
def with_obstacle() -> tuple[list[Sample], dict]:
    return drive(True)


@pytest.fixture(scope="module")
def without_obstacle() -> tuple[list[Sample], dict]:
    return drive(False)


def test_z_e_falls_by_the_tangential_force_share_before_the_robot_stops(with_obstacle) -> None:
    s, g = with_obstacle
    assert not any(x.contact for x in s), "the robot touched the obstacle"
    walked = next(i for i, x in enumerate(s) if x.speed > 0.6 * REF)
    stop = next((i for i in range(walked, len(s)) if s[i].speed < 0.5), None)
    assert stop is not None, "the robot never came to rest"
    first = s[stop]
    share = g["k_z"] * first.f_t / g["k_s"]
    assert share > 0.5 * REF, f"the fictitious force hardly acted ({first.f_t:.2f})"
    assert REF - first.z_e >= 0.5 * share, (
        f"when the robot first rests (t = {first.t:.1f} s): command - z_e = {REF - first.z_e:.2f}, share {share:.2f}"
    )
    rest = [x for x in s if x.t > s[-1].t - 5.0]
    assert max(abs(x.speed) for x in rest) < 0.5  # at rest before the obstacle
    for x in rest:
        share = g["k_z"] * x.f_t / g["k_s"]
        assert REF - x.z_e >= 0.9 * share, f"t = {x.t:.1f}: command - z_e = {REF - x.z_e:.2f}, share {share:.2f}"


def test_the_leader_feels_the_obstacle_as_a_rising_handle_force(with_obstacle) -> None:
    s, g = with_obstacle
    before = next(i for i, x in enumerate(s) if x.f_t > 0.0)  # the force starts acting
    f_before = np.mean([x.force for x in s[before - 25 : before]])
    rest = [x for x in s if x.t > s[-1].t - 5.0]
    f_rest = np.mean([x.force for x in rest])
    share = np.mean([g["k_z"] * x.f_t / g["k_s"] for x in rest])
    # (31): f_m = -k_m (k_g x_m - z_e): a hand that held the handle rigidly would feel
    # k_m times the share; the simulated hand is an impedance and yields (the handle is
    # pushed back), so it feels less, but well over half of it.
    assert f_rest < f_before - 0.5 * g["k_m"] * share, (f_before, f_rest, share)
    h_before = np.mean([x.handle for x in s[before - 25 : before]])
    h_rest = np.mean([x.handle for x in rest])
    assert h_rest < h_before, (h_before, h_rest)  # the operator's hand is pushed back


def test_without_the_obstacle_z_e_stays_on_the_command_and_the_handle_is_not_pushed(without_obstacle) -> None:
    s, _ = without_obstacle
    late = [x for x in s if x.t > 20.0]
    assert all(x.f_t == 0.0 for x in s)
    assert max(abs(REF - x.z_e) for x in late) < 0.3
    assert max(abs(x.force) for x in late) < 0.2
