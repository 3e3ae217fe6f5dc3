"""Parity: the real loops and the comparison's runner run the same controller steps.

For a recorded command/feedback sequence (generated here, deterministically), the follower's
real loop (:class:`~bipedtele.follower.loop.FollowerLoop` around a robot that replays
recorded observations) and the leader's real loop (:class:`~bipedtele.leader.loop.LeaderLoop`
around a handle that replays recorded positions) give the same outputs, to 1e-12, as the
steps the comparison builds (:func:`~bipedtele.studies.compare_kernel.controllers`) fed the
same sequence, for every registered scheme and the toy plugin's; and the comparison gives
the numbers its runner gave before it ran these steps. What each runner measures
itself (the received-wave gain, the delay estimate behind ``sigma_e``) is read from the real
loop and given to the comparison's step: the parity is the step's, not the estimators'.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.control.config import ControlConfig
from bipedtele.control.follower_step import FollowerCommand, FollowerObservation
from bipedtele.control.leader_law import leader_force
from bipedtele.control.leader_step import LeaderFeedback, LeaderHandle
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import StudyParams
from bipedtele.control.schemes import scheme_class, scheme_names
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.follower.robot import FollowerRobot, RobotObservation, WalkCommand
from bipedtele.leader.device import HandleState, LeaderDevice
from bipedtele.leader.loop import LeaderLoop
from bipedtele.link.inbox import FeedbackInbox
from bipedtele.link.messages import Command, Feedback
from bipedtele.studies.compare_kernel import _equivalent_steps, controllers, regime_inputs, simulate
from bipedtele.studies.regimes import CompareParams, Regime

PLUGIN = Path(__file__).resolve().parents[1] / "plugins" / "toy"
T0 = 1_700_000_000.0
TOL = 1e-12


@pytest.fixture
def every_scheme(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every registered scheme, the toy plugin's included (its folder on the path)."""
    monkeypatch.syspath_prepend(str(PLUGIN))
    names = scheme_names()
    assert "toy-damped" in names and "paper" in names and "wave" in names and "tdpa" in names
    return names


# ----------------------------------------------------------------------------- follower


class ReplayRobot(FollowerRobot):
    """A follower robot that replays recorded observations, one per period, and accepts every walk."""

    name = "replay"

    def __init__(self, observations: list[RobotObservation]) -> None:
        self.observations, self.k = observations, 0
        self.walks: list[WalkCommand] = []
        self._connected = False

    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def observe(self) -> RobotObservation:
        return self.observations[self.k]

    def send_walk(self, cmd: WalkCommand) -> WalkCommand:
        sent = cmd.clamped(self.limits)
        self.walks.append(sent)
        return sent

    def stop(self) -> None:
        return None

    def advance(self, dt: float) -> None:
        self.k += 1


def _follower_sequence(k_steps: int, dt: float) -> tuple[list[tuple[float, Command]], list[RobotObservation]]:
    """Commands (arrival time, message), one per period, 0.155 s on the way; and the robot's observations."""
    t = np.arange(k_steps) * dt
    commands = []
    energy = np.zeros(2)
    for k in range(k_steps):
        energy = energy + 2e-4 * np.array([1.0 + math.sin(0.3 * k), 1.0 + math.cos(0.2 * k)])  # small: it limits
        ref = [3.0 + 2.0 * math.sin(1.1 * t[k]), 6.0 * math.sin(0.7 * t[k])]
        wave = [1.5 * math.sin(0.9 * t[k]), 2.0 * math.cos(0.5 * t[k])]
        msg = Command(sid=7, seq=k + 1, t=T0 + t[k], ref=ref, h2_s=0.1, wave=wave, energy=energy.tolist())
        commands.append((T0 + t[k] + 0.155, msg))
    observations = [
        RobotObservation(
            t=T0 + t[k],
            v_hip_m_s=0.01 * (2.5 + 1.5 * math.sin(0.8 * t[k] + 0.3)),
            turn_rate_rad_s=math.radians(4.0 * math.sin(0.6 * t[k])),
            pose=(0.0, 0.0, 0.0),
            sonar_m=(1.0 - 0.6 * k / k_steps, 0.9),
            tilt_rad=0.0,
            fallen=False,
            walking=True,
        )
        for k in range(k_steps)
    ]
    return commands, observations


def _run_real_follower(control: ControlConfig, k_steps: int) -> dict[str, Any]:
    cfg = load_config("default").section("follower")
    dt = 1.0 / cfg.control_rate_hz
    commands, observations = _follower_sequence(k_steps, dt)
    robot = ReplayRobot(observations)
    robot.connect()
    clock = [T0]
    taken: list[Command | None] = [None]

    def latest() -> tuple[Command, float] | None:
        arrived = [(ta, c) for ta, c in commands if ta <= clock[0]]
        if not arrived or arrived[-1][1] is taken[0]:
            return None
        taken[0] = arrived[-1][1]
        return arrived[-1][1], arrived[-1][0]

    published: list[Any] = []
    loop = FollowerLoop(robot, control, cfg, command_inbox(cfg, source=latest), published.append, now=lambda: clock[0])
    laws: list[tuple[int, np.ndarray]] = []
    port_command = loop.port.command

    def spy(*args: Any) -> np.ndarray:  # what the loop's port gave the reference model (28)
        c = port_command(*args)
        laws.append((len(rows), np.array(c)))
        return c

    loop.port.command = spy  # type: ignore[method-assign]
    rows: list[dict[str, Any]] = []
    for k in range(k_steps):
        clock[0] = T0 + k * dt
        tel = loop.tick()
        rows.append(
            {
                "cmd": taken[0],
                "obs": observations[k],
                "s_e": np.array(tel.s_e),
                "f_hold": np.array([tel.f_v[0], 0.0]) if tel.sent is not None else np.zeros(2),
                "gain": loop.port.wave_gain.gain,
                "z_e": np.array(tel.z_e),
                "state": loop.port.state,
            }
        )
        robot.advance(dt)
    feedback = {round((m.t - T0) / dt): m for m in published if isinstance(m, Feedback)}
    return {"rows": rows, "laws": dict(laws), "feedback": feedback, "dt": dt, "eta_max": loop.eta_max}


@pytest.mark.timeout(240)
def test_the_follower_loop_and_the_comparison_run_the_same_step(every_scheme: list[str]) -> None:
    k_steps = 150
    for name in every_scheme:
        control = ControlConfig(scheme=name)
        real = _run_real_follower(control, k_steps)
        scheme = scheme_class(name)(control, tuple(control.worst_delays_s))
        _, ctl = controllers(scheme, control)
        ctl.eta_max = real["eta_max"]  # the robot's limits: the real robot's
        dt, rows = real["dt"], real["rows"]
        phi, gam, index = _equivalent_steps(np.stack([r["s_e"] for r in rows])[None], control, dt)
        state = ctl.initial(1)
        counts = scheme.energy_sent(np.zeros(2)) is not None
        assert len(real["laws"]) > k_steps // 2 and len(real["feedback"]) > k_steps // 2, name
        for k, row in enumerate(rows):
            msg, obs = row["cmd"], row["obs"]
            eta = np.array([[obs.v_hip_m_s * 100.0, math.degrees(obs.turn_rate_rad_s)]])
            cmd = None
            if k in real["laws"]:
                cmd = FollowerCommand(
                    np.array([msg.ref]), np.array([msg.wave]), np.array([msg.energy]), np.array([[row["gain"]]])
                )
            zoh = (phi[index[:, k]], gam[index[:, k]])
            state, walk, fb, _ = ctl.step(state, cmd, FollowerObservation(eta, zoh, row["f_hold"][None], dt))
            if cmd is not None:
                np.testing.assert_allclose(walk[0], real["laws"][k], rtol=0, atol=TOL, err_msg=f"{name} law {k}")
            np.testing.assert_allclose(state.eq[0, :, 1], row["z_e"], rtol=0, atol=TOL, err_msg=f"{name} z_e {k}")
            if counts:
                np.testing.assert_allclose(state.e_in, row["state"].e_in, rtol=0, atol=TOL, err_msg=name)
                np.testing.assert_allclose(state.min_observer, row["state"].min_observer, rtol=0, atol=TOL)
            sent = real["feedback"].get(k)
            if sent is not None:
                np.testing.assert_allclose(sent.z_e, state.eq[0, :, 1], rtol=0, atol=TOL, err_msg=f"{name} fb {k}")
                assert (sent.wave is None) == (fb.wave is None), name
                if fb.wave is not None:
                    np.testing.assert_allclose(sent.wave, fb.wave[0], rtol=0, atol=TOL, err_msg=f"{name} wave {k}")
                # what the leader reads from the message is what the comparison's follower sends
                got = scheme.read_feedback(np.array(sent.z_e), np.array(sent.eta), np.asarray(sent.wave or [0.0, 0.0]))
                np.testing.assert_allclose(got, fb.signal[0], rtol=0, atol=TOL, err_msg=f"{name} signal {k}")
                if counts:
                    np.testing.assert_allclose(sent.energy, fb.energy[0], rtol=0, atol=TOL)


# ----------------------------------------------------------------------------- leader


class ReplayHandle(LeaderDevice):
    """A leader handle that replays recorded positions and speeds, one per period; forces are taken, not rendered."""

    name = "replay-handle"
    simulated = True

    def __init__(self, x: np.ndarray, dx: np.ndarray) -> None:
        self.x, self.dx, self.k, self._connected = x, dx, 0, False

    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def read(self) -> HandleState:
        return HandleState(t=self.k * 1e-3, x_m=self.x[self.k].copy(), dx_m=self.dx[self.k].copy(), buttons=())

    def apply_force(self, force_n: np.ndarray) -> np.ndarray:
        return np.asarray(force_n, dtype=float)

    def advance(self, dt: float) -> None:
        self.k += 1


def _feedback_sequence(scheme: Any, k_m: np.ndarray, n: int, period: float) -> list[tuple[float, Feedback]]:
    """Feedback (arrival time, message) every ``period`` [s], 0.1234 s on the way, as the scheme's follower sends it."""
    out = []
    energy = np.zeros(2)
    for j in range(n):
        s = j * period
        z_e = np.array([4.0 * math.sin(0.7 * s), 6.0 * math.cos(0.3 * s)])
        eta = np.array([0.5 * z_e[0] + 1.0, 0.5 * z_e[1] - 1.0])
        energy = energy + 5e-4 * np.array([1.0 + math.sin(j), 1.0 + math.cos(j)])  # small: the controllers act
        wave = scheme.feedback_wave(eta[None], k_m)
        fb = Feedback(
            sid=7,
            seq=j + 1,
            t=T0 + s,
            z_e=z_e.tolist(),
            eta=eta.tolist(),
            h1_s=0.1,
            state="walking",
            wave=None if wave is None else wave[0].tolist(),
            energy=energy.tolist(),
        )
        out.append((T0 + s + 0.1234, fb))
    return out


@pytest.mark.timeout(240)
def test_the_leader_loop_and_the_comparison_run_the_same_step(every_scheme: list[str]) -> None:
    cfg = load_config("default")
    k_steps, dt = 600, 1.0 / cfg.leader.haptic_rate_hz
    t = np.arange(k_steps + 1) * dt
    x = np.stack([0.02 * np.sin(2.0 * t), 0.015 * np.cos(1.3 * t)], -1)
    dx = np.stack([0.04 * np.cos(2.0 * t), -0.0195 * np.sin(1.3 * t)], -1)
    for name in every_scheme:
        control = ControlConfig(scheme=name)
        scheme = scheme_class(name)(control, tuple(control.worst_delays_s))
        k_m, k_g = np.asarray(control.k_m, dtype=float), np.asarray(control.k_g, dtype=float)
        messages = _feedback_sequence(scheme, k_m, 40, 0.02)
        clock = [T0]

        def latest(
            messages: list[tuple[float, Feedback]] = messages, clock: list[float] = clock
        ) -> tuple[Feedback, float] | None:
            arrived = [(fb, ta) for ta, fb in messages if ta <= clock[0]]
            return arrived[-1] if arrived else None

        sent: list[Command] = []
        loop = LeaderLoop(ReplayHandle(x, dx), None, control, sent.append, FeedbackInbox(source=latest), cfg=cfg.leader)
        lead, _ = controllers(scheme, control)
        state = lead.initial(1)
        counts = scheme.energy_sent(np.zeros(2)) is not None
        rendered = 0
        for k in range(k_steps):
            clock[0] = T0 + k * dt
            n_sent = len(sent)
            loop.tick(now=clock[0])
            r_m = (k_g * x[k])[None]
            fb_msg = loop.feedback
            if fb_msg is None:
                continue
            signal = scheme.feedback_signal(lambda m=fb_msg: np.array([m.z_e]), np.array([fb_msg.eta]), k_m)
            fb = LeaderFeedback(signal, np.array([fb_msg.energy]), loop.port.wave_gain.gain)
            # the comparison's leader: the step's force, the handle follows r - F / k_m
            state, law = lead.force(state, LeaderHandle(r_m, dt), fb)
            follow = r_m[0] - law.force[0] / k_m
            want = loop.gain * leader_force(
                x[k], dx[k], follow, k_m=k_m, k_g=k_g, alpha_m=loop.alpha_m, g_m=np.asarray(cfg.leader.g_m)
            )
            np.testing.assert_allclose(loop.force_cmd, want, rtol=0, atol=TOL, err_msg=f"{name} force {k}")
            rendered += bool(np.any(loop.force_cmd != 0.0))
            if counts:
                np.testing.assert_allclose(loop.port.state.e_in, state.e_in, rtol=0, atol=TOL, err_msg=name)
                np.testing.assert_allclose(loop.port.state.min_observer, state.min_observer, rtol=0, atol=TOL)
            if len(sent) > n_sent:  # a command this tick: what it carries (for the reference it carries)
                cmd = lead.command(state, np.array([sent[-1].ref]))
                assert (sent[-1].wave is None) == (cmd.wave is None), name
                if cmd.wave is not None:
                    np.testing.assert_allclose(sent[-1].wave, cmd.wave[0], rtol=0, atol=TOL, err_msg=f"{name} {k}")
                if counts:
                    np.testing.assert_allclose(sent[-1].energy, cmd.energy[0], rtol=0, atol=TOL, err_msg=name)
        assert rendered > k_steps // 2, name


# ----------------------------------------------------------------------------- the comparison's numbers

#: ``simulate`` per regime/scheme/hold-or-release, every metric per run, computed by the
#: comparison's runner before it ran the controller steps (3 runs, seed 11, 5 s; the wave
#: gain's window 0.1 s, the comparison's value then). Written with ``json.dump`` of
#: ``{f"{regime}/{scheme}/{'release' if release else 'hold'}": {metric: list}}``.
REFERENCE = Path(__file__).resolve().parent / "data" / "compare_runner_reference.json"
REFERENCE_REGIMES = (
    Regime("trace-x4", "the shipped trace, delays x4", scale=4.0),
    Regime("satellite", "1.5 s +- 0.2 s each way", "uniform:1500ms:200ms", "uniform:1500ms:200ms"),
)


@pytest.mark.compute  # CPU-bound (scripts/test.sh)
@pytest.mark.timeout(240)
def test_the_comparison_gives_the_numbers_it_gave_before_it_ran_the_steps(every_scheme: list[str]) -> None:
    reference = json.loads(REFERENCE.read_text())
    control = ControlConfig(wave_window_s=0.1)
    cp = CompareParams(
        study=StudyParams(duration_s=5.0), unstable_factor=3.0, release_fraction=0.5, oscillation_m_s=0.002
    )
    checked = 0
    for regime in REFERENCE_REGIMES:
        inp = regime_inputs(regime, 3, 11, control, cp.study)
        worst = (float(inp.h1.max()), float(inp.h2.max()))
        for name in every_scheme:
            for release in (False, True):
                got = simulate(
                    scheme_class(name)(control, worst), inp, control, cp, OnlineChooser(control), release=release
                )
                want = reference[f"{regime.name}/{name}/{'release' if release else 'hold'}"]
                assert set(got) == set(want), name
                for metric, values in want.items():
                    np.testing.assert_allclose(
                        np.asarray(got[metric], dtype=float), values, rtol=0, atol=TOL, err_msg=f"{name} {metric}"
                    )
                checked += 1
    assert checked == len(reference) == 2 * 2 * len(every_scheme)
