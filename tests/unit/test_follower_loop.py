"""The follower loop's logic in simulated time, around a kinematic robot at the hardware
boundary: tracking, watchdog stop and resume, stale commands, release, falls, collisions,
delay estimate and the online parameters. The pybullet NAO runs the same loop in
tests/integration/test_follower_sim.py."""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.follower.feedbackplan import FeedbackPlan
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.follower.robot import RobotError
from bipedtele.follower.supervisor import RobotSupervisor
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import MAX_COUNTERS, Command, Feedback, Status, decode, encode
from fakes.kinematic_robot import KinematicRobot

pytestmark = pytest.mark.timeout(60)


class Harness:
    """Drives a FollowerLoop in simulated time with a scripted leader and a delay h1."""

    def __init__(self, robot: KinematicRobot, h1: float = 0.0, **overrides: str) -> None:
        sets = [f"{k.replace('__', '.')}={v}" for k, v in overrides.items()]
        cfg = load_config("default", sets)
        self.t = 1000.0
        self.robot = robot
        self.h1 = h1
        self.sent: list[tuple[float, Command]] = []  # (arrival time, command)
        self.published: list[object] = []
        self.events: list[tuple[str, dict]] = []
        self.seq = 0
        self._taken: Command | None = None
        robot.connect()
        self.loop = FollowerLoop(
            robot,
            cfg.section("control"),
            cfg.section("follower"),
            command_inbox(cfg.section("follower"), source=self.latest),
            self.published.append,
            now=lambda: self.t,
            on_event=lambda n, d: self.events.append((n, d)),
        )

    def latest(self) -> tuple[Command, float] | None:
        """The newest arrived command not taken before (as the receiver's latest-slot gives it)."""
        arrived = [(ta, c) for ta, c in self.sent if ta <= self.t]
        if not arrived or arrived[-1][1] is self._taken:
            return None
        self._taken = arrived[-1][1]
        return arrived[-1][1], arrived[-1][0]

    def command(self, v: float, w: float, enable: bool = True, sent_at: float | None = None) -> None:
        self.seq += 1
        t_sent = self.t if sent_at is None else sent_at
        self.sent.append(
            (t_sent + self.h1, Command(sid=7, seq=self.seq, t=t_sent, ref=[v, w], h2_s=0.2, enable=enable))
        )

    def run(self, seconds: float, v: float | None = None, w: float = 0.0, cmd_every: float = 0.01) -> list:
        tels = []
        next_cmd = self.t
        for _ in range(round(seconds / self.loop.dt)):
            if v is not None and self.t >= next_cmd:
                self.command(v, w)
                next_cmd += cmd_every
            tels.append(self.loop.tick())
            self.robot.advance(self.loop.dt)
            self.t += self.loop.dt
        return tels


def test_tracks_forward_and_turn_speed() -> None:
    h = Harness(KinematicRobot())
    h.run(30.0, v=5.0, w=4.0)
    obs = h.robot.observe()
    assert obs.v_hip_m_s * 100 == pytest.approx(5.0, abs=0.2)
    assert math.degrees(obs.turn_rate_rad_s) == pytest.approx(4.0, abs=0.2)
    fb = [m for m in h.published if isinstance(m, Feedback)]
    assert fb[-1].state == "walking"
    np.testing.assert_allclose(fb[-1].z_e, [5.0, 4.0], atol=0.3)


def test_watchdog_stops_then_resumes() -> None:
    h = Harness(KinematicRobot())
    h.run(10.0, v=5.0)
    assert h.robot.v > 0.03
    tels = h.run(5.0, v=None)  # leader gone: no new command
    assert h.loop.counters["watchdog_stops"] == 1
    assert h.robot.stops >= 1 and h.robot.v == 0.0
    assert tels[-1].state == "standing"
    assert [e for e, _ in h.events] == ["watchdog_stop"]
    h.run(10.0, v=5.0)  # leader back (same or new session): walks again
    assert h.robot.v > 0.03 and h.loop.telemetry.state == "walking"


def test_released_device_stops_the_robot() -> None:
    h = Harness(KinematicRobot())
    h.run(8.0, v=5.0)
    for _ in range(100):
        h.command(5.0, 0.0, enable=False)
        h.loop.tick()
        h.robot.advance(h.loop.dt)
        h.t += h.loop.dt
    assert h.robot.stopping and h.loop.telemetry.state in ("stopping", "standing")
    # a normal end, not a watchdog stop (issue 19)
    assert h.loop.counters["operator_stops"] == 1 and h.loop.counters["watchdog_stops"] == 0
    assert [e for e, _ in h.events] == ["operator_stop"]
    assert h.loop.status(h.t).counters["operator_stops"] == 1


def test_commands_older_than_the_age_limit_are_dropped() -> None:
    h = Harness(KinematicRobot(), follower__max_cmd_age_s="1.0")
    h.command(5.0, 0.0, sent_at=h.t - 2.0)
    h.run(2.0)
    assert h.loop.counters["cmd_too_old"] == 1
    assert h.loop.counters["cmd_accepted"] == 0
    assert h.robot.sent == []


def test_h1_estimate_follows_the_forward_delay() -> None:
    h = Harness(KinematicRobot(), h1=0.25)
    h.run(5.0, v=3.0)
    assert h.loop.telemetry.h1_s == pytest.approx(0.25, abs=1e-6)
    fb = [m for m in h.published if isinstance(m, Feedback)][-1]
    assert fb.h1_s == pytest.approx(0.25, abs=1e-6)


def test_fall_stops_and_is_reported_once() -> None:
    h = Harness(KinematicRobot(fall_at=5.0))  # robot time [s] starts at 0
    h.run(8.0, v=5.0)
    assert h.loop.counters["falls"] == 1
    assert h.loop.telemetry.state == "fallen"
    st = [m for m in h.published if isinstance(m, Status)][-1]
    assert st.counters["falls"] == 1 and st.state == "fallen"


def test_obstacle_slows_the_robot_before_contact() -> None:
    h = Harness(KinematicRobot(wall_x=1.2))
    h.run(60.0, v=5.0)
    assert h.loop.counters["collisions"] == 0
    assert h.robot.x < 1.2 - 0.25
    assert h.loop.telemetry.f_v[0] > 0


def test_walk_parameters_come_from_the_online_choice() -> None:
    h = Harness(KinematicRobot())
    h.run(3.0, v=5.0)
    sent = h.robot.sent[-1]
    lim = h.robot.limits
    assert lim.cycle_s[0] <= sent.cycle_s <= lim.cycle_s[1]
    fb = [m for m in h.published if isinstance(m, Feedback)][-1]
    assert pytest.approx(sent.cycle_s) == fb.T and fb.eps == pytest.approx(sent.eps_s)
    assert all(v > 0 for v in fb.s_e)


def test_conservative_split_uses_the_round_trip_for_both_delays() -> None:
    robot = KinematicRobot()
    robot.connect()
    cfg = load_config("default")
    seen: list[tuple[float, float]] = []
    loop = FollowerLoop(
        robot,
        cfg.section("control"),
        cfg.section("follower"),
        command_inbox(cfg.section("follower")),
        lambda m: None,
        now=lambda: 0.0,
        conservative_rtt=lambda: 0.4,
    )
    original = loop._update_parameters

    def spy(h1: float, h2: float) -> None:
        seen.append((h1, h2))
        original(h1, h2)

    loop._update_parameters = spy  # type: ignore[method-assign]
    loop.tick()
    assert seen == [(0.4, 0.4)]


# ---------------------------------------------------------------- time sanity (issue 10 item 3)


def test_a_command_slightly_ahead_within_the_tolerance_is_a_zero_delay() -> None:
    h = Harness(KinematicRobot())
    for _ in range(100):  # every command stamped 0.1 s (jitter) ahead of its arrival
        h.command(5.0, 0.0, sent_at=h.t + 0.1)
        h.sent[-1] = (h.t, h.sent[-1][1])
        tel = h.loop.tick()
        h.robot.advance(h.loop.dt)
        h.t += h.loop.dt
    assert h.loop.counters["cmd_accepted"] == 100
    assert tel.h1_s == 0.0 and tel.state == "walking"


def test_the_future_check_is_the_receivers_alone() -> None:
    """Issue 22: a command stamped too far ahead was checked twice, by the node's receiver
    (``drop_future``) and again by the loop (``cmd_future``): two counters for one event. The
    receiver is the one place (tests/integration/test_transport.py); the loop takes a small lead
    as a zero delay (above) and has no counter of its own for it."""
    h = Harness(KinematicRobot())
    assert "cmd_future" not in h.loop.counters
    assert "max_future_s" not in inspect.signature(FollowerLoop).parameters


# ---------------------------------------------------------------- falls latch (issue 10 item 5)


def _release(h: Harness, seconds: float) -> None:
    for _ in range(round(seconds / h.loop.dt)):
        h.command(0.0, 0.0, enable=False)
        h.loop.tick()
        h.robot.advance(h.loop.dt)
        h.t += h.loop.dt


def test_every_fall_stops_the_robot_is_counted_and_latches_until_the_operator_rearms() -> None:
    robot = KinematicRobot(fall_at=5.0)  # robot time [s] starts at 0
    h = Harness(robot)
    h.run(8.0, v=5.0)
    assert h.loop.counters["falls"] == 1 and robot.stops == 1
    robot.fall_at = math.inf  # stood up again
    n_sent = len(robot.sent)
    tels = h.run(5.0, v=5.0)  # the operator still holds forward: no walking without a re-arm
    assert all(t.state == "fallen" for t in tels) and robot.v == 0.0
    assert len(robot.sent) == n_sent
    _release(h, 0.5)  # re-arm: release ...
    assert len(robot.sent) == n_sent
    h.run(5.0, v=5.0)  # ... then enable again
    assert h.loop.telemetry.state == "walking" and robot.v > 0.03
    stops = robot.stops
    robot.fall_at = robot.t + 1.0  # a second fall
    h.run(3.0, v=5.0)
    assert h.loop.counters["falls"] == 2
    assert robot.stops == stops + 1
    assert [e for e, _ in h.events].count("fall") == 2
    assert h.loop.telemetry.state == "fallen"


def test_a_release_while_the_robot_lies_does_not_rearm() -> None:
    robot = KinematicRobot(fall_at=2.0)
    h = Harness(robot)
    h.run(3.0, v=5.0)
    _release(h, 0.5)  # released while lying on the floor ...
    h.run(1.0, v=5.0)  # ... and enabled again, still lying
    robot.fall_at = math.inf  # now it is stood up: it must not walk off by itself
    tels = h.run(3.0, v=5.0)
    assert all(t.state == "fallen" for t in tels) and robot.v == 0.0
    _release(h, 0.5)
    h.run(3.0, v=5.0)
    assert h.loop.telemetry.state == "walking"


# ---------------------------------------------------------------- faults (issue 10 item 1)


def test_a_fault_stops_the_robot_reports_an_error_and_walking_resumes() -> None:
    robot = KinematicRobot()
    h = Harness(robot)
    h.run(8.0, v=5.0)
    assert robot.v > 0.03
    stops = robot.stops
    h.loop.fault(RuntimeError("getRobotVelocity timed out"))
    assert robot.stops == stops + 1
    assert h.loop.counters["robot_faults"] == 1 and h.loop.telemetry.state == "error"
    assert np.all(h.loop.reference.eta == 0.0)
    h.run(8.0, v=5.0)
    assert h.loop.telemetry.state == "walking" and robot.v > 0.03


def test_after_a_fault_the_robot_is_stopped_again_when_no_command_is_fresh() -> None:
    robot = KinematicRobot()
    h = Harness(robot)
    h.run(5.0, v=5.0)
    h.loop.fault(RuntimeError("the stop may not have reached the robot"))
    stops = robot.stops
    h.t += 2.0  # commands went stale while the robot did not answer
    h.loop.tick()
    assert robot.stops == stops + 1
    h.loop.tick()
    assert robot.stops == stops + 1  # once


# ---------------------------------------------------------------- eq. (33) (issue 11 item 1)


def test_the_equivalent_follower_feels_the_fictitious_force() -> None:
    h = Harness(KinematicRobot(wall_x=1.2))
    tels = h.run(60.0, v=5.0)
    f_t = tels[-1].f_v[0]
    assert f_t > 1.0
    cfg = load_config("default").section("control")
    # At rest (33) gives z_e = ref - k_z f_v / k_s, like the robot's own speed.
    assert tels[-1].z_e[0] == pytest.approx(5.0 - cfg.k_z[0] * f_t / cfg.k_s[0], abs=0.2)
    assert tels[-1].z_e[0] == pytest.approx(h.robot.v * 100, abs=0.3)


def test_new_leader_sessions_call_the_hook_once_each() -> None:
    robot = KinematicRobot()
    robot.connect()
    cfg = load_config("default")
    t = [0.0]
    cmds = [Command(sid=1, seq=1, t=0.0, ref=[5.0, 0.0])]
    seen: list[int] = []
    loop = FollowerLoop(
        robot,
        cfg.section("control"),
        cfg.section("follower"),
        command_inbox(cfg.section("follower"), source=lambda: (cmds[-1], t[0])),
        lambda m: None,
        now=lambda: t[0],
        on_new_leader=lambda sid: seen.append(sid) or True,
    )
    for k in range(2, 6):
        loop.tick()
        t[0] += loop.dt
        cmds.append(Command(sid=1 if k < 4 else 2, seq=k, t=t[0], ref=[5.0, 0.0]))
    loop.tick()
    assert seen == [1, 2]
    assert loop.counters["leader_sessions"] == 2 and loop.counters["resets"] == 2


# ---------------------------------------------------------------- supervisor (issue 10 item 1)


class FlakyRobot(KinematicRobot):
    """Observations time out while ``timeouts`` is set; the link drops while ``down`` is set."""

    def __init__(self) -> None:
        super().__init__()
        self.timeouts = False
        self.down = False
        self.connects = 0

    @property
    def is_connected(self) -> bool:
        return self._connected and not self.down

    def connect(self) -> None:
        if self.down:
            raise RobotError("cannot reach the robot")
        self.connects += 1
        self.stop()  # as the NAOqi bridge does first thing
        super().connect()

    def observe(self):  # type: ignore[no-untyped-def]
        if self.timeouts:
            raise RobotError("NAOqi call ALMotion.getRobotVelocity timed out after 2000 ms")
        return super().observe()


def test_the_supervisor_stops_the_robot_on_a_fault_and_walks_again_when_it_answers() -> None:
    robot = FlakyRobot()
    h = Harness(robot)
    mono = [0.0]
    sup = RobotSupervisor(robot, h.loop, backoff_s=(0.2, 1.0), monotonic=lambda: mono[0])

    def run(seconds: float) -> list:
        out = []
        for _ in range(round(seconds / h.loop.dt)):
            h.command(5.0, 0.0)
            out.append(sup.tick())
            sup.advance(h.loop.dt)
            h.t += h.loop.dt
            mono[0] += h.loop.dt
        return out

    run(8.0)
    assert robot.v > 0.03
    robot.timeouts = True
    tels = run(3.0)
    assert all(t is None for t in tels) and sup.faults == len(tels)
    assert robot.stopping and robot.v == 0.0  # stopped, and the process goes on
    robot.timeouts = False
    tels = run(8.0)
    assert tels[-1] is not None and tels[-1].state == "walking" and robot.v > 0.03
    # the link drops: reconnect tries with back-off, then walking again
    robot.down, robot._connected = True, False
    tels = run(3.0)
    assert all(t is None for t in tels)
    robot.down = False
    tels = run(8.0)
    assert sup.reconnects == 1 and robot.connects == 2
    assert tels[-1] is not None and tels[-1].state == "walking"
    st = [m for m in h.published if isinstance(m, Status)]
    assert any(m.state == "error" for m in st)


def test_an_unexpected_error_in_a_tick_is_a_fault_too() -> None:
    robot = KinematicRobot()
    h = Harness(robot)
    sup = RobotSupervisor(robot, h.loop)
    h.run(5.0, v=5.0)
    h.loop.equivalent = None  # type: ignore[assignment]  # a bug
    assert sup.tick() is None
    assert sup.faults == 1 and robot.stopping


# ---------------------------------------------------------------- issue 13: one intake, pickup on arrival


def test_a_command_given_again_is_taken_again_the_gate_is_the_only_dedupe() -> None:
    robot = KinematicRobot()
    robot.connect()
    cfg = load_config("default")
    cmd = Command(sid=1, seq=1, t=100.0, ref=[5.0, 0.0])
    loop = FollowerLoop(
        robot,
        cfg.section("control"),
        cfg.section("follower"),
        command_inbox(cfg.section("follower"), source=lambda: (cmd, 100.0)),
        lambda m: None,
        now=lambda: 100.0,
    )
    loop.tick()
    loop.tick()
    assert loop.counters["cmd_accepted"] == 2


def test_h1_is_fed_once_by_the_loop_with_every_command_it_takes() -> None:
    """Issue 22: h1 was fed by the receiver or by the loop depending on whether an estimator
    was passed in. Now the loop owns it and feeds it with each command it takes, whoever
    delivers them (the follower's receiver feeds none)."""
    robot = KinematicRobot()
    robot.connect()
    cfg = load_config("default")
    cmds = iter([(Command(sid=1, seq=1, t=99.7, ref=[5.0, 0.0]), 100.0), None])
    loop = FollowerLoop(
        robot,
        cfg.section("control"),
        cfg.section("follower"),
        command_inbox(cfg.section("follower"), source=lambda: next(cmds, None)),
        lambda m: None,
        now=lambda: 100.0,
    )
    tel = loop.tick()
    assert tel.h1_s == pytest.approx(0.3)
    assert "estimator" not in inspect.signature(FollowerLoop).parameters


def _status_with_drops(drops: DropCounter, command: Command | None = None) -> Status:
    """Tick a follower loop (session 1234) that counts its drops in ``drops``, with ``command`` in its inbox; return its Status."""
    robot = KinematicRobot()
    robot.connect()
    cfg = load_config("default")
    published: list[object] = []
    loop = FollowerLoop(
        robot,
        cfg.section("control"),
        cfg.section("follower"),
        command_inbox(cfg.section("follower")),
        published.append,
        now=lambda: 100.0,
        drops=drops,
        sid=1234,
    )
    if command is not None:
        loop.inbox.put(command, 100.0)
    loop.tick()
    st = [m for m in published if isinstance(m, Status)][-1]
    assert isinstance(st, Status)
    return st


def test_status_carries_the_drop_counts_passed_in() -> None:
    drops = DropCounter("follower")
    drops.drop("bad_mac", "test")
    st = _status_with_drops(drops)
    assert st.sid == 1234 and st.counters["drop_bad_mac"] == 1 and "cmd_accepted" in st.counters


def test_a_follower_that_counted_many_kinds_of_bad_message_still_sends_a_status_its_leader_takes() -> None:
    """Each reason a message is dropped for adds a ``drop_<reason>`` counter; a Status with
    more than MAX_COUNTERS counters is refused whole by its receiver (``bad_field``). The
    follower has 48 counters of its own on the cellular rows: 17 kinds of bad message
    silenced its Status (the cockpit's view of the robot and the echo its probes wait for).
    Past the bound the rarest reasons are summed in ``drop_other``."""
    drops = DropCounter("follower", log_interval_s=0.0)
    reasons = [f"reason_{k:02d}" for k in range(MAX_COUNTERS)]
    for k, reason in enumerate(reasons):
        for _ in range(k + 1):
            drops.drop(reason)
    st = _status_with_drops(drops, Command(sid=3, seq=1, t=99.9, ref=[5.0, 0.0]))
    got = decode(encode(st), Status)
    assert isinstance(got, Status) and len(got.counters) == MAX_COUNTERS
    assert got.counters["cmd_accepted"] == 1 and got.counters[f"drop_{reasons[-1]}"] == MAX_COUNTERS
    kept = sum(v for k, v in got.counters.items() if k.startswith("drop_"))
    assert kept == drops.total  # nothing lost: the rarest are in drop_other
    assert got.counters["drop_other"] > 0 and f"drop_{reasons[0]}" not in got.counters


def _twin() -> Harness:
    h = Harness(KinematicRobot())
    h.run(3.0, v=5.0, w=2.0)  # walking, commands every 10 ms
    return h


def test_a_command_picked_up_between_ticks_acts_as_the_period_sample() -> None:
    """pickup() gives the robot what a tick would have given had the command come first."""
    early, late = _twin(), _twin()
    # early: the new command arrived just before the tick
    early.command(2.0, -3.0)
    early.loop.tick()
    # late: the tick ran without it; it arrives 7 ms into the period and is picked up
    late.loop.tick()
    sent_before = len(late.robot.sent)
    late.t += 0.007
    late.command(2.0, -3.0)
    late.sent[-1] = (late.t, late.sent[-1][1])
    late.published.clear()
    assert late.loop.pickup() is True
    assert len(late.robot.sent) == sent_before + 1  # at once, not at the next tick
    assert late.robot.sent[-1].forward_m_s == pytest.approx(early.robot.sent[-1].forward_m_s, abs=1e-12)
    assert late.robot.sent[-1].turn_rad_s == pytest.approx(early.robot.sent[-1].turn_rad_s, abs=1e-12)
    np.testing.assert_allclose(late.loop.reference.eta, early.loop.reference.eta, atol=1e-12)
    np.testing.assert_allclose(late.loop.telemetry.z_e, early.loop.telemetry.z_e, atol=1e-12)
    fb = [m for m in late.published if isinstance(m, Feedback)]
    assert len(fb) == 1 and fb[0].cmd_seq == late.seq and fb[0].ref == pytest.approx([2.0, -3.0])
    # nothing new: nothing to do
    assert late.loop.pickup() is False


def test_a_release_picked_up_between_ticks_stops_the_robot_at_once() -> None:
    h = _twin()
    h.loop.tick()
    h.command(0.0, 0.0, enable=False)
    assert h.loop.pickup() is True
    assert h.robot.stops >= 1 and h.loop.telemetry.state in ("stopping", "standing")
    assert h.loop.counters["operator_stops"] == 1 and h.loop.counters["watchdog_stops"] == 0


# ---------------------------------------------------------------- an outage's backlog (issue 19)


def _drive(h: Harness, until: float, applied: list[int]) -> None:
    """Tick every period and pick up every arrival at its own time (event-driven) until ``until``."""
    arrivals = sorted({ta for ta, _ in h.sent if h.t < ta < until})
    next_tick = h.t
    for ta in [*arrivals, until]:
        while next_tick <= ta:
            h.t = next_tick
            h.loop.tick()
            if h.loop._cmd is not None and (not applied or applied[-1] != h.loop._cmd.seq):
                applied.append(h.loop._cmd.seq)
            h.robot.advance(h.loop.dt)
            next_tick += h.loop.dt
        if ta < until:
            h.t = ta
            if h.loop.pickup():
                assert h.loop._cmd is not None
                applied.append(h.loop._cmd.seq)
    h.t = until


def test_the_backlog_of_an_outage_never_reaches_the_robot_walking_resumes_on_fresh_commands() -> None:
    """Steady commands 180 ms late, a 3 s outage, then the queued commands in a burst (0.7-3.2 s
    beyond the usual delay, all in sequence order, the youngest within ``max_cmd_age_s``),
    then fresh ones: none of the burst is applied, walking resumes on the first fresh one."""
    h = Harness(KinematicRobot(), h1=0.18)
    base = 0.18
    applied: list[int] = []
    t_out = h.t + 10.0
    t = h.t
    while t < t_out:  # steady: a command every 10 ms, 180 ms on the way
        h.command(5.0, 0.0, sent_at=t)
        t += 0.01
    # the outage: commands sent over 2.5 s are queued in the path, the rest of it lost
    burst_at = t_out + 3.17 + base
    burst: list[int] = []
    while t < t_out + 2.5:
        h.seq += 1
        burst.append(h.seq)
        h.sent.append((burst_at + 0.0002 * len(burst), Command(sid=7, seq=h.seq, t=t, ref=[5.0, 0.0], h2_s=0.2)))
        t += 0.01
    ages = [ta - c.t - base for ta, c in h.sent if c.seq in burst]
    assert min(ages) == pytest.approx(0.7, abs=0.05) and max(ages) == pytest.approx(3.2, abs=0.05)
    fresh_from = burst_at + 0.1
    first_fresh = h.seq + 1
    t = fresh_from - base
    while t < fresh_from + 5.0:
        h.command(5.0, 0.0, sent_at=t)
        t += 0.01

    _drive(h, t_out + 1.0, applied)
    assert h.loop.counters["watchdog_stops"] == 1 and h.loop.telemetry.state in ("stopping", "standing")
    n_walks = len(h.robot.sent)
    _drive(h, fresh_from - 0.001, applied)  # the burst has come and gone
    c = h.loop.counters
    assert not set(applied) & set(burst), "a command of the outage's backlog reached the robot"
    assert c["cmd_backlog"] > 0 and c["cmd_backlog"] + c["cmd_too_old"] == len(burst), c
    assert len(h.robot.sent) == n_walks, "the robot was sent a walk from the backlog"
    assert h.loop.telemetry.state == "standing"
    _drive(h, fresh_from + 0.0001, applied)  # the first fresh command, picked up
    assert applied[-1] == first_fresh and h.loop.telemetry.state == "walking"
    _drive(h, fresh_from + 5.0, applied)
    assert h.robot.v > 0.03 and h.loop.telemetry.state == "walking"
    assert c["watchdog_stops"] == 1 and c["operator_stops"] == 0 and c["cmd_reordered"] == 0
    st = h.loop.status(h.t).counters
    assert st["cmd_backlog"] == c["cmd_backlog"] and st["operator_stops"] == 0


def test_a_lasting_change_of_the_path_delay_is_learned_after_the_backlog_window() -> None:
    """The path's delay jumps from 0.18 to 0.9 s and stays: dropped as backlog for
    ``backlog_window_s``, then the baseline is learned again and the robot walks."""
    h = Harness(KinematicRobot(), h1=0.18, follower__backlog_window_s="5.0")
    h.run(6.0, v=5.0)
    h.h1 = 0.9
    h.run(4.0, v=5.0)
    assert h.loop.counters["cmd_backlog"] > 100 and h.loop.telemetry.state == "standing"
    h.run(4.0, v=5.0)
    assert h.loop.inbox.baseline.relearned == 1
    assert h.loop.inbox.baseline.value(h.t) == pytest.approx(0.9, abs=0.02)
    assert h.loop.telemetry.state == "walking" and h.robot.v > 0.01


def test_a_command_sent_before_the_one_applied_is_never_applied() -> None:
    h = Harness(KinematicRobot())
    h.run(3.0, v=5.0)
    last = h.loop._cmd
    assert last is not None
    h.seq += 1
    h.sent.append((h.t, Command(sid=7, seq=h.seq, t=last.t - 0.05, ref=[-5.0, 0.0])))
    assert h.loop.pickup() is False
    assert h.loop.counters["cmd_reordered"] == 1 and h.loop._cmd is last


def test_a_delay_that_rises_while_commands_keep_coming_is_not_a_backlog() -> None:
    """The shipped trace's peaks: the delay climbs 0.72 s above its 10 s minimum over 3 s while
    commands keep arriving (never a silence of ``watchdog_s``): nothing is dropped as backlog
    and the robot keeps walking (the rule applies after a silence only)."""
    h = Harness(KinematicRobot(), h1=0.18)
    h.run(6.0, v=5.0)
    for _ in range(30):
        h.h1 += 0.024
        h.run(0.1, v=5.0)
    assert h.h1 == pytest.approx(0.9)
    h.run(1.0, v=5.0)
    c = h.loop.counters
    assert c["cmd_backlog"] == 0 and c["watchdog_stops"] == 0, c
    assert h.loop.telemetry.state == "walking" and h.robot.v > 0.01


@pytest.mark.parametrize(
    ("scheme", "scheduled"),
    [("paper", True), ("pd-measured", True), ("paper-constant", False), ("pd-worst-case", False)],
)
def test_sigma_e_and_the_walk_parameters_come_from_the_configured_scheme(scheme: str, scheduled: bool) -> None:
    from bipedtele.control.damping import schedule_damping

    # h1 = 4 s lifts the turn channel's sigma_e off its floor in (40); worst delays 3 s, more still
    h = Harness(KinematicRobot(), h1=4.0, control__scheme=f'"{scheme}"', control__worst_delays_s="[3.0, 3.0]")
    h.run(7.0, v=5.0)
    fb = [m for m in h.published if isinstance(m, Feedback)][-1]
    cfg = h.loop.control
    used = h.loop._h_used  # the delays the loop last scheduled on
    assert used is not None and used[0] > 3.0
    paper = schedule_damping(*used, cfg).s_e
    assert paper[1] > 2 * cfg.s_e_min  # the schemes differ here
    delays = used if scheduled else ((0.0, 0.0) if scheme == "paper-constant" else (3.0, 3.0))
    want = schedule_damping(*delays, cfg).s_e
    assert fb.s_e == pytest.approx(np.asarray(want).tolist(), rel=1e-9)
    assert pytest.approx(h.loop.chooser.choose(np.asarray(want)).T) == h.loop._T  # (30) at that sigma_e


def _planned_loop(plan: Callable[[], FeedbackPlan]) -> tuple[FollowerLoop, list[object], list[float]]:
    """A follower loop on the kinematic robot reading its feedback plan from ``plan``: the
    loop, what it published, and its clock (t[0], seconds)."""
    robot = KinematicRobot()
    robot.connect()
    cfg = load_config("default")
    t = [100.0]
    published: list[object] = []
    loop = FollowerLoop(
        robot,
        cfg.section("control"),
        cfg.section("follower"),
        command_inbox(cfg.section("follower")),
        published.append,
        now=lambda: t[0],
        feedback_plan=plan,
    )
    return loop, published, t


def test_the_feedback_plan_is_read_from_the_callable_given_at_construction() -> None:
    """Nothing is set on the loop after it is built: the program's plan is read at each tick and pickup."""
    plan = [FeedbackPlan(True, 50.0, math.inf)]
    loop, published, t = _planned_loop(lambda: plan[0])
    seq = 0

    def pickup() -> bool:
        nonlocal seq
        seq += 1
        loop.inbox.put(Command(sid=1, seq=seq, t=t[0], ref=[5.0, 0.0]), t[0])
        return loop.pickup()

    def feedback() -> int:
        return sum(isinstance(m, Feedback) for m in published)

    loop.tick()
    n = feedback()
    t[0] += 0.005
    assert pickup() and feedback() == n + 1  # acknowledged at once
    plan[0] = FeedbackPlan(False, 10.0, math.inf)
    t[0] += 0.005
    assert pickup() and feedback() == n + 1  # the next periodic feedback acknowledges it
    plan[0] = FeedbackPlan(False, 10.0, 0.005)
    t[0] += 0.005
    assert pickup() and feedback() == n + 2  # the previous feedback left long enough ago
    t[0] += 0.005
    loop.tick()  # the periodic feedback due since the first tick: the acknowledgement stood for it
    assert feedback() == n + 2
    t[0] += 0.09
    loop.tick()  # at the plan's 10 Hz the next is due 0.1 s after the acknowledgement
    assert feedback() == n + 2
    t[0] += 0.01
    loop.tick()
    assert feedback() == n + 3


def test_acknowledgements_and_periodic_feedback_together_keep_the_plans_least_interval() -> None:
    """A coalesced plan (50 Hz, at most one feedback per 1/52 s) with commands at 50 Hz that
    arrive just before each periodic feedback: an acknowledgement stands for the period's
    feedback. Before, the periodic feedback left on top of it and the follower sent 100
    feedback/s, twice what the plan fits (on a 300 kbit/s uplink control's rate stepped
    from 160 to 300 kbit/s and the feedback queued 0.3 s)."""
    plan = FeedbackPlan(False, 50.0, 1.0 / 52.0)
    loop, published, t = _planned_loop(lambda: plan)
    dt = loop.dt
    seq, next_cmd = 0, t[0] + 0.0195
    for _ in range(round(2.0 / dt)):
        loop.tick()
        end = t[0] + dt
        while next_cmd < end:  # commands arrive between ticks
            t[0] = next_cmd
            seq += 1
            loop.inbox.put(Command(sid=1, seq=seq, t=t[0], ref=[5.0, 0.0]), t[0])
            loop.pickup()
            next_cmd += 0.02
        t[0] = end
    sent = sum(isinstance(m, Feedback) for m in published)
    assert seq >= 99 and sent <= 2.0 * 52.0 + 2, sent
