"""The leader loop against a scripted feedback source, in virtual time."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.control.damping import schedule_damping
from bipedtele.control.leader_law import leader_force
from bipedtele.leader.devices.sim_falcon import SimFalcon
from bipedtele.leader.loop import LeaderLoop
from bipedtele.leader.operator import Hand
from bipedtele.leader.operators.scripted import ScriptedOperator
from bipedtele.link.inbox import FeedbackInbox
from bipedtele.link.messages import Command, Feedback

T0 = 1_700_000_000.0


class FeedbackSource:
    """Follower stand-in: sends Feedback every ``period`` with z_e = z_fn(send time) and
    h1; each message arrives ``h2_fn(send time)`` later (in order)."""

    def __init__(self, loop_now, z_fn, h2_fn, h1=0.1, period=0.02, stop_at=None):
        self.loop_now, self.z_fn, self.h2_fn, self.h1 = loop_now, z_fn, h2_fn, h1
        self.period, self.stop_at = period, stop_at
        self.seq = 0
        self.latest: tuple[Feedback, float] | None = None

    def __call__(self):
        now = self.loop_now()
        # The newest message sent at s = k * period with s + h2(s) <= now.
        k = int((now - T0) / self.period)
        while k >= 0:
            s = T0 + k * self.period
            if (self.stop_at is None or s < self.stop_at) and s + self.h2_fn(s) <= now:
                break
            k -= 1
        if k < 0:
            return self.latest
        s = T0 + k * self.period
        if self.latest is None or self.latest[0].t != s:
            self.seq = k + 1
            z = list(self.z_fn(s))
            fb = Feedback(
                sid=7, seq=self.seq, t=s, z_e=z, eta=[0.5 * z[0] + 1.0, 0.5 * z[1] - 1.0], h1_s=self.h1, state="walking"
            )
            self.latest = (fb, s + self.h2_fn(s))
        return self.latest


def make_loop(z_fn, h2_fn, *, operator=None, stop_at=None, h1=0.1, overrides=(), x0=(0.0, 0.0)):
    cfg = load_config("default", list(overrides))
    dev = SimFalcon(x0=x0)
    dev.connect()
    sent: list[Command] = []
    holder: dict = {}
    src = FeedbackSource(lambda: holder["loop"].now, z_fn, h2_fn, h1=h1, stop_at=stop_at)
    loop = LeaderLoop(
        dev, operator, cfg.control, sent.append, FeedbackInbox(source=src), cfg=cfg.leader, clock=lambda: T0
    )
    holder["loop"] = loop
    return loop, sent, cfg


def z_wave(s):
    return np.array([4.0 * np.sin(0.7 * (s - T0)), 6.0 * np.cos(0.3 * (s - T0))])


def test_force_follows_eq31_with_the_delayed_z_e():
    h2 = 0.25
    hand = Hand(stiffness_n_m=300.0, tau_s=0.1)
    hand.set_target(np.array([0.02, -0.015]))
    loop, _, cfg = make_loop(z_wave, lambda s: h2, operator=None)
    loop.device.set_operator(hand)
    c = cfg.control
    checked = 0
    for k in range(4000):
        loop.tick(now=T0 + k * 0.001)
        fb = loop.feedback
        if fb is None or loop.gain < 1.0:
            continue
        # The z_e in use was sent h2 (or up to one feedback period more) ago.
        assert loop.now - h2 - 0.02 - 1e-9 <= fb.t <= loop.now - h2 + 1e-9
        x, dx = loop.x_m, loop.dx_m
        a = loop.alpha_m
        # Hand-computed eq. (31): -k_m (k_g x - z_e(t - h2)) - alpha_m dx (g_m = 0).
        want = [-c.k_m[i] * (c.k_g[i] * x[i] - fb.z_e[i]) - a[i] * dx[i] for i in range(2)]
        assert loop.force_cmd.tolist() == pytest.approx(want, rel=1e-12, abs=1e-12)
        assert loop.force.tolist() == pytest.approx(np.clip(want, -8, 8).tolist())
        checked += 1
    assert checked > 3000
    assert np.abs(loop.force).max() > 0.1  # a real force was exercised


def test_force_law_against_hand_computed_numbers():
    f = leader_force(
        [0.01, -0.02],
        [0.1, 0.05],
        [1.0, -2.0],
        k_m=[0.4, 0.4],
        k_g=[160.0, 200.0],
        alpha_m=[20.0, 25.0],
        g_m=[0.3, 0.0],
    )
    # forward: -0.4 (1.6 - 1.0) + 0.3 - 20 * 0.1 = -1.94; turn: -0.4 (-4 + 2) - 25 * 0.05 = -0.45
    assert f.tolist() == pytest.approx([-1.94, -0.45])


def test_g_m_is_added_and_the_force_is_clamped():
    loop, _, _ = make_loop(lambda s: np.array([500.0, -500.0]), lambda s: 0.05, overrides=["leader.g_m=[0.5, -0.25]"])
    loop.run_for(1.0)
    assert loop.force_cmd[0] > 8.0 and loop.force_cmd[1] < -8.0
    assert loop.force.tolist() == [8.0, -8.0]
    loop2, _, cfg = make_loop(lambda s: np.zeros(2), lambda s: 0.05, overrides=["leader.g_m=[0.5, -0.25]"])
    loop2.run_for(1.0)
    c, x, dx, a = cfg.control, loop2.x_m, loop2.dx_m, loop2.alpha_m
    want = [-c.k_m[i] * c.k_g[i] * x[i] + [0.5, -0.25][i] - a[i] * dx[i] for i in range(2)]
    assert loop2.gain == 1.0
    assert loop2.force_cmd.tolist() == pytest.approx(want)


def test_alpha_m_follows_the_delay_estimate():
    # Backward delay 0.1 s for the first 3 s, then 0.5 s.
    h2_fn = lambda s: 0.1 if s < T0 + 3.0 else 0.5  # noqa: E731
    loop, sent, cfg = make_loop(lambda s: np.zeros(2), h2_fn, h1=0.2)
    loop.run_for(3.0)
    a_short = loop.alpha_m.copy()
    assert loop.h2 == pytest.approx(0.1, abs=1e-6)
    assert a_short.tolist() == pytest.approx(schedule_damping(0.2, 0.1, cfg.control).alpha_m.tolist())
    assert sent[-1].h2_s == pytest.approx(0.1, abs=1e-6)
    assert sent[-1].alpha_m == pytest.approx(a_short.tolist())
    loop.run_for(3.0)
    assert loop.h2 == pytest.approx(0.5, abs=1e-6)
    a_long = loop.alpha_m
    assert np.all(a_long > a_short)
    assert a_long.tolist() == pytest.approx(schedule_damping(0.2, 0.5, cfg.control).alpha_m.tolist())
    assert sent[-1].h2_s == pytest.approx(0.5, abs=1e-6)
    # h1 comes from the follower's estimate in the feedback.
    assert loop.h1 == 0.2


def test_forged_feedback_gives_no_force_step():
    """A received z_e of +999 then -999 (forged or corrupted feedback) after normal
    feedback: the force on the handle still goes to the clamp, but never faster than
    leader.force_rate_max_n_s (no 8 N step in one tick, as the clamp alone allowed)."""
    forged_at, reversed_at = T0 + 2.0, T0 + 3.0

    def z(s: float) -> np.ndarray:
        if s < forged_at:
            return np.zeros(2)
        return np.array([999.0, -999.0]) if s < reversed_at else np.array([-999.0, 999.0])

    loop, _, cfg = make_loop(z, lambda s: 0.05)
    loop.device.set_operator(Hand(stiffness_n_m=2000.0, damping_n_s_m=30.0))  # holds the handle
    rate, dt = cfg.leader.force_rate_max_n_s, loop.dt
    loop.run_for(2.0)
    assert np.abs(loop.force).max() < 0.1 and loop.gain == 1.0
    t, f = [loop.now], [loop.force.copy()]
    for _ in range(2000):
        loop.tick(now=loop.now + dt)
        t.append(loop.now)
        f.append(loop.force.copy())
    times, forces = np.array(t), np.array(f)
    assert np.abs(np.diff(forces, axis=0)).max() <= rate * dt * (1 + 1e-9)
    # The forged value is still felt (clamped), only ramped: 8 N after 8 N / rate.
    arrive = forged_at + 0.05
    at_clamp = times[np.argmax(forces[:, 0] >= 8.0)]
    assert forces[-1].tolist() == [-8.0, 8.0] and forces[:, 0].max() == 8.0
    assert at_clamp >= arrive + 8.0 / rate - 2 * dt
    flip = reversed_at + 0.05
    at_other = times[np.argmax(forces[:, 0] <= -8.0)]
    assert at_other >= flip + 16.0 / rate - 2 * dt
    assert loop.slew_limited_ticks >= 0.9 * 24.0 / rate / dt


def test_stale_feedback_fades_the_force_to_zero_and_back():
    z = lambda s: np.array([5.0, -5.0])  # noqa: E731  (error on the handle at rest: force != 0)
    loop, _, cfg = make_loop(z, lambda s: 0.1, stop_at=T0 + 2.0)
    loop.device.set_operator(Hand(stiffness_n_m=2000.0, damping_n_s_m=30.0))  # holds the handle at 0
    lc = cfg.leader
    loop.run_for(2.0)
    f_fresh = np.abs(loop.force).max()
    assert f_fresh > 0.5 and loop.gain == 1.0 and loop.state == "running"
    last_recv = T0 + 2.0 - 0.02 + 0.1
    # Until the timeout: full force.
    loop.run_for(last_recv + lc.feedback_timeout_s - loop.now - 0.005)
    assert loop.gain == 1.0
    gains, forces = [], []
    for _ in range(int((lc.fade_s + 0.05) / loop.dt)):
        loop.tick(now=loop.now + loop.dt)
        gains.append(loop.gain)
        forces.append(np.abs(loop.force_cmd).max())
    assert loop.state == "feedback_stale"
    assert np.all(np.diff(gains) <= 0)
    # Linear fade over fade_s: each tick takes dt / fade_s off the gain.
    steps = -np.diff(gains)
    steps = steps[steps > 0]
    assert steps[:-1] == pytest.approx(loop.dt / lc.fade_s, rel=1e-3)
    assert len(steps) == pytest.approx(lc.fade_s / loop.dt, abs=1.5)
    assert gains[-1] == 0.0 and forces[-1] == 0.0 and loop.force.tolist() == [0.0, 0.0]
    loop.run_for(1.0)
    assert loop.force.tolist() == [0.0, 0.0]


def test_force_rises_again_when_feedback_returns():
    z = lambda s: np.array([5.0, -5.0])  # noqa: E731
    h2 = lambda s: 0.1 if s < T0 + 1.0 or s > T0 + 3.0 else 5.0  # noqa: E731  (a 5 s hole)
    loop, _, _ = make_loop(z, h2)
    loop.device.set_operator(Hand(stiffness_n_m=2000.0, damping_n_s_m=30.0))
    loop.run_for(3.0)
    assert loop.gain == 0.0
    loop.run_for(0.5)
    assert loop.gain == 1.0 and loop.state == "running"


def test_no_force_before_the_first_feedback():
    loop, sent, _ = make_loop(lambda s: np.array([5.0, 5.0]), lambda s: 100.0)
    loop.run_for(1.0)
    assert loop.feedback is None and loop.state == "starting"
    assert loop.force.tolist() == [0.0, 0.0]
    assert sent[-1].h2_s == 0.0


def test_commands_at_the_command_rate_with_ref_k_g_x_m():
    op = ScriptedOperator([[0, 4, -5], [10, 4, -5]], k_g=[160, 200], interp="step")
    loop, sent, cfg = make_loop(lambda s: np.zeros(2), lambda s: 0.1, operator=op)
    loop.run_for(2.0)
    assert len(sent) == 200
    assert [c.seq for c in sent] == list(range(1, 201))
    assert len({c.sid for c in sent}) == 1
    for c in sent:
        assert c.ref == pytest.approx((np.asarray(cfg.control.k_g) * np.asarray(c.x_m)).tolist())
        assert c.enable
    assert sent[-1].t - sent[-2].t == pytest.approx(0.01)
    # The handle went where the scripted hand pushed it (it yields to the force feedback).
    assert sent[-1].ref[0] > 2.0 and sent[-1].ref[1] < -2.0
    sample = loop.sample
    assert sample is not None and sample.seq == sent[-1].seq and sample.t == sent[-1].t
    assert sample.ref_v == sent[-1].ref[0] and sample.ref_w == sent[-1].ref[1]
    for key in ("t", "ref_v", "ref_w", "z_e_v", "force_v", "h1_ms", "h2_ms", "alpha_m_v", "state", "link"):
        assert getattr(sample, key) is not None, key


def test_operator_done_disables_the_command():
    op = ScriptedOperator([[0, 4, 0], [0.5, 4, 0]], k_g=[160, 200])
    loop, sent, _ = make_loop(lambda s: np.zeros(2), lambda s: 0.1, operator=op)
    loop.run_for(5.0, until_done=True)
    assert loop.done
    assert sent[-1].enable is False and sent[-1].ref == [0.0, 0.0]


def test_run_in_real_time_stops_on_request():
    loop, sent, _ = make_loop(lambda s: np.zeros(2), lambda s: 0.1)
    loop._clock = __import__("time").time
    stop = threading.Event()
    timer = threading.Timer(0.3, stop.set)
    timer.start()
    loop.run(stop=stop, duration_s=30.0)
    timer.cancel()
    assert stop.is_set() and loop.ticks > 0 and len(sent) > 0
    assert loop.period_stats.summary(loop.dt)["ticks"] == loop.ticks


def test_a_pd_scheme_feels_the_robots_measured_speed_and_the_paper_feels_z_e():
    # The feedback carries z_e and eta apart; the scheme picks which one the force (31) follows.
    def run(scheme):
        loop, _, cfg = make_loop(z_wave, lambda s: 0.2, overrides=[f'control.scheme="{scheme}"'])
        for k in range(1500):
            loop.tick(now=T0 + k * 0.001)
        fb = loop.feedback
        assert fb is not None
        return loop, cfg, fb

    loop, cfg, fb = run("paper")
    c, x, dx, a = cfg.control, loop.x_m, loop.dx_m, loop.alpha_m
    want = [-c.k_m[i] * (c.k_g[i] * x[i] - fb.z_e[i]) - a[i] * dx[i] for i in range(2)]
    assert loop.force_cmd.tolist() == pytest.approx(want)
    loop, cfg, fb = run("pd-measured")
    c, x, dx, a = cfg.control, loop.x_m, loop.dx_m, loop.alpha_m
    assert fb.eta != fb.z_e
    want = [-c.k_m[i] * (c.k_g[i] * x[i] - fb.eta[i]) - a[i] * dx[i] for i in range(2)]
    assert loop.force_cmd.tolist() == pytest.approx(want)


def test_paper_constant_holds_the_zero_delay_damping_on_a_long_delay():
    loop, _, cfg = make_loop(z_wave, lambda s: 1.5, h1=1.5, overrides=['control.scheme="paper-constant"'])
    paper, _, _ = make_loop(z_wave, lambda s: 1.5, h1=1.5)
    for k in range(4000):
        loop.tick(now=T0 + k * 0.001)
        paper.tick(now=T0 + k * 0.001)
    floor = schedule_damping(0.0, 0.0, cfg.control).alpha_m
    assert loop.alpha_m.tolist() == pytest.approx(np.asarray(floor).tolist())
    assert np.all(paper.alpha_m > 5 * np.asarray(floor))  # the paper's (40) follows the 1.5 s delays


def test_the_hand_is_read_from_the_callable_given_at_construction() -> None:
    """Nothing is set on the loop after it is built: the cockpit's Release / Take is read at each command."""
    cfg = load_config("default")
    dev = SimFalcon(x0=(0.02, 0.0))
    dev.connect()
    sent: list[Command] = []
    hand = [False]
    loop = LeaderLoop(
        dev, None, cfg.control, sent.append, FeedbackInbox(), cfg=cfg.leader, clock=lambda: T0, hand=lambda: hand[0]
    )
    loop.run_for(0.05)
    assert sent and not any(c.release for c in sent) and not loop.released
    n = len(sent)
    hand[0] = True
    loop.run_for(0.05)
    assert all(c.release and not c.enable for c in sent[n:]) and loop.released
    n = len(sent)
    hand[0] = False
    loop.run_for(0.05)
    assert not any(c.release for c in sent[n:]) and not loop.released
