"""The odometry speed metric (per step, between footfalls) against synthetic recordings with
known answers; the instantaneous metric kept beside it; passes counted; footfalls from the
step sampler (NAOqi) and from the pybullet NAO through the follower loop."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from bipedtele.cli import main
from bipedtele.config.profile import load_config
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.follower.odometry import StepSampler
from bipedtele.link.messages import Command, Feedback
from bipedtele.recording.format import Record, read_records
from bipedtele.recording.recorder import Recorder
from bipedtele.tools.report import compute_report

pytestmark = pytest.mark.timeout(120)

STEP = 0.5  # step time T/2 [s]
PHI = 0.3  # double-support fraction of a step
RATE = 20.0  # feedback rate [Hz]
REF = (5.0, 15.0)  # applied reference [cm/s, deg/s]
V = 4.5  # the robot's real forward speed [cm/s]: per-step error 0.5 cm/s


def _pulsed_walk(t: float, t_start: float) -> tuple[tuple[float, float, float], float]:
    """Pose [m, m, rad] and instantaneous turn rate [deg/s] of a robot that turns exactly
    REF[1] per step, all of it in single support, and advances V along each step's mean heading."""
    k, tau = divmod(t - t_start, STEP)
    turn = math.radians(REF[1]) * STEP  # per step
    frac = min(max((tau - PHI * STEP) / ((1 - PHI) * STEP), 0.0), 1.0)
    yaw = k * turn + frac * turn
    rate = REF[1] / (1 - PHI) if PHI * STEP <= tau < STEP else 0.0
    # straight chords along each step's mean heading: x, y summed over the finished steps
    heads = (np.arange(int(k)) + 0.5) * turn
    x = V / 100 * STEP * float(np.cos(heads).sum()) + V / 100 * tau * math.cos((k + 0.5) * turn)
    y = V / 100 * STEP * float(np.sin(heads).sum()) + V / 100 * tau * math.sin((k + 0.5) * turn)
    return (x, y, yaw), rate


def _moved(pose: tuple[float, float, float], origin: np.ndarray) -> tuple[float, float, float]:
    """``pose`` given relative to ``origin`` (x, y, yaw), in the world frame."""
    c, s = math.cos(origin[2]), math.sin(origin[2])
    return (origin[0] + c * pose[0] - s * pose[1], origin[1] + s * pose[0] + c * pose[1], origin[2] + pose[2])


def _write_run(folder: Path, pause: bool = False) -> None:
    """leader.mcap (task, passes, feedback with poses) and follower.mcap (footfalls).

    The robot walks 10 s from t = 100 s (20 steps); with ``pause`` it stands 3 s after
    step 8 (state standing, reference 0, no footfalls) and walks 12 more steps.
    """
    folder.mkdir()
    h = 0.1  # feedback delay [s]
    segments = [(100.0, 20)] if not pause else [(100.0, 8), (107.0, 12)]
    end = segments[-1][0] + segments[-1][1] * STEP
    with Recorder(folder / "leader.mcap") as lead, Recorder(folder / "follower.mcap") as fol:
        lead.write("events", {"event": "pass", "n": 0}, 99.0)  # an earlier run's pass: not counted
        lead.write("events", {"event": "start", "operator": "pilot"}, 100.0)
        n_ff = 0
        offset = np.zeros(3)
        for s, (t_start, steps) in enumerate(segments):
            for i in range(round(steps * STEP * RATE) + 1):
                t = t_start + i / RATE
                pose, rate = _pulsed_walk(t, t_start)
                pose = _moved(pose, offset)
                fb = Feedback(
                    sid=3, seq=i, t=t, ref=list(REF), eta=[V, rate], pose=list(pose), T=2 * STEP, state="walking"
                )
                lead.write("feedback/recv", fb, t + h)
                if i % round(STEP * RATE) == 0:  # a touchdown ends every step
                    n_ff += 1
                    ff = {"event": "footfall", "t": t, "n": n_ff, "pose": list(pose), "step_s": STEP, "ref": list(REF)}
                    fol.write("events", ff, t)
            if pause and s == 0:
                offset = np.asarray(_moved(_pulsed_walk(t_start + steps * STEP, t_start)[0], offset))
                for i in range(round(3.0 * RATE) - 10):
                    t = t_start + steps * STEP + 0.5 + i / RATE
                    fb = Feedback(
                        sid=3,
                        seq=1000 + i,
                        t=t,
                        ref=[0.0, 0.0],
                        eta=[0.0, 0.0],
                        pose=list(offset),
                        T=2 * STEP,
                        state="standing",
                    )
                    lead.write("feedback/recv", fb, t + h)
        for n, t in enumerate((102.0, 105.0, end - 0.1), start=1):
            lead.write("events", {"event": "pass", "n": n}, t)
        lead.write("events", {"event": "done"}, end)
        lead.write("cmd/sent", Command(seq=1, t=100.0, ref=list(REF)), 100.0)


def test_per_step_speed_from_footfalls_has_the_known_answer(tmp_path: Path) -> None:
    """Each step turns exactly as asked (error 0) although the instantaneous turn rate
    pulses (error 9 deg/s); the forward speed is 4.5 for 5 cm/s (error 0.5 both ways)."""
    _write_run(tmp_path / "run")
    leader = list(read_records(tmp_path / "run" / "leader.mcap"))
    follower = list(read_records(tmp_path / "run" / "follower.mcap"))
    report = compute_report(leader, follower=follower)
    assert report["odometry_source"] == "footfalls"
    assert report["turn_error_deg_s"] == pytest.approx(0.0, abs=1e-6)
    assert report["forward_error_cm_s"] == pytest.approx(0.5, abs=1e-6)
    # instantaneous: |15 - 0| over 30 % of each step, |15 - 15/0.7| over 70 %: 4.5 + 4.5
    assert report["turn_error_instant_deg_s"] == pytest.approx(9.0, abs=0.5)
    assert report["forward_error_instant_cm_s"] == pytest.approx(0.5, abs=1e-6)
    assert report["passes"] == 3  # the pass before the task start is not counted


def test_without_footfalls_feedback_windows_of_one_step_give_the_same(tmp_path: Path) -> None:
    """A leader's file alone: windows of T/2 over the feedback poses, whatever their phase,
    turn by one step's worth at a steady command."""
    _write_run(tmp_path / "run")
    report = compute_report(read_records(tmp_path / "run" / "leader.mcap"))
    assert report["odometry_source"] == "feedback"
    assert report["turn_error_deg_s"] == pytest.approx(0.0, abs=1e-6)
    assert report["forward_error_cm_s"] == pytest.approx(0.5, abs=1e-6)
    assert report["turn_error_instant_deg_s"] > 8.0


def test_a_pause_between_footfalls_is_not_a_step(tmp_path: Path) -> None:
    """Footfalls 3.5 s apart around a stop are not consecutive steps: counted, the pose
    jump would make both errors large."""
    _write_run(tmp_path / "run", pause=True)
    leader = list(read_records(tmp_path / "run" / "leader.mcap"))
    for follower in (list(read_records(tmp_path / "run" / "follower.mcap")), None):
        report = compute_report(leader, follower=follower)
        assert report["odometry_source"] == ("footfalls" if follower else "feedback")
        assert report["turn_error_deg_s"] == pytest.approx(0.0, abs=1e-6)
        assert report["forward_error_cm_s"] == pytest.approx(0.5, abs=1e-6)


def test_cli_on_a_run_folder_uses_the_follower_footfalls(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _write_run(tmp_path / "run")
    out = tmp_path / "r.json"
    assert main(["report", str(tmp_path / "run"), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["odometry_source"] == "footfalls" and data["passes"] == 3
    assert f"{'Task passes':<30} 3" in text and "footfalls from" in text
    assert f"{'Speeds per step from':<30} footfalls" in text


def test_step_sampler_reads_the_pose_once_per_step_period() -> None:
    """A NAO's odometry read at the loop rate: one footfall per step period while walking,
    a new chain after standing."""
    sampler = StepSampler()
    got = []
    for i in range(200):  # 4 s at 50 Hz
        t = i * 0.02
        walking = not (2.0 <= t < 2.5)
        ff = sampler.update(t, (0.05 * t, 0.0, 0.1 * t), walking, 0.25)
        if ff is not None and (not got or got[-1].n != ff.n):
            got.append(ff)
    steps = [(b.t - a.t, b.step_s) for a, b in itertools.pairwise(got)]
    assert [s for s in steps if s[0] == pytest.approx(s[1])]  # consecutive footfalls, one period apart
    assert all(abs(s[1] - 0.25) < 0.021 for s in steps)
    assert all(not (2.0 <= f.t < 2.5) for f in got)  # none while standing
    gap = [s for s in steps if s[0] > 1.5 * s[1]]
    assert len(gap) == 1  # the chain broke once: the report will not pair across it
    for a, b in itertools.pairwise(got):
        if b.t - a.t <= 1.5 * b.step_s:
            assert (b.pose[0] - a.pose[0]) / (b.t - a.t) == pytest.approx(0.05)
            assert (b.pose[2] - a.pose[2]) / (b.t - a.t) == pytest.approx(0.1)


def test_sim_nao_footfalls_reach_the_recording_through_the_loop() -> None:
    """The pybullet NAO driven by the follower loop: one ``footfall`` event per step, each
    half a walking cycle after the previous one, and its per-step turn rate matches the
    reference once walking is steady."""
    from bipedtele.follower.sim.robot import SimNao

    cfg = load_config("default", [])
    clock = [1000.0]
    events: list[tuple[str, dict]] = []
    seq = [0]

    def latest() -> tuple[Command, float]:
        seq[0] += 1
        return Command(sid=7, seq=seq[0], t=clock[0], ref=[5.0, 10.0], h2_s=0.1), clock[0]

    with SimNao(cfg) as robot:
        loop = FollowerLoop(
            robot,
            cfg.section("control"),
            cfg.section("follower"),
            command_inbox(cfg.section("follower"), source=latest),
            lambda m: None,
            now=lambda: clock[0],
            on_event=lambda n, d: events.append((n, d)),
        )
        sent = []  # (time, turn rate sent to the robot [deg/s])
        for _ in range(round(12.0 / loop.dt)):
            tel = loop.tick()
            if tel.sent is not None:
                sent.append((clock[0], math.degrees(tel.sent.turn_rad_s)))
            robot.advance(loop.dt)
            clock[0] += loop.dt
        T = loop.telemetry.T
    ff = [d for n, d in events if n == "footfall"]
    assert len(ff) >= 12.0 / T  # about two per cycle (the first steps start the walk)
    assert [d["n"] for d in ff] == list(range(ff[0]["n"], ff[0]["n"] + len(ff)))
    late = [d for d in ff if d["t"] > 1004.0]
    for a, b in itertools.pairwise(late):
        assert b["t"] - a["t"] == pytest.approx(b["step_s"], abs=0.03)
        assert b["step_s"] == pytest.approx(T / 2, abs=0.01)
        assert b["ref"] == pytest.approx([5.0, 10.0])
    # Every step turns the robot left, by about what it was sent (the loop's (28) raises
    # what it sends while the walker turns less than asked).
    turn = [math.degrees(b["pose"][2] - a["pose"][2]) / (b["t"] - a["t"]) for a, b in itertools.pairwise(late)]
    asked = [w for t, w in sent if late[0]["t"] - T / 2 <= t < late[-1]["t"] - T / 2]  # latched a step ahead
    assert min(turn) > 0.0
    assert float(np.mean(turn)) == pytest.approx(float(np.mean(asked)), rel=0.3)
    records = [Record("events", d["t"], {"event": "footfall", **d}) for d in late]
    records.insert(0, Record("events", 1004.0, {"event": "start"}))
    report = compute_report(records)
    assert report["odometry_source"] == "footfalls"
    steps = len(late) - 1
    assert (
        report["turn_error_deg_s"]
        == pytest.approx(
            sum(abs(10.0 - w) * (b["t"] - a["t"]) for w, (a, b) in zip(turn, itertools.pairwise(late), strict=True))
            / sum(b["t"] - a["t"] for a, b in itertools.pairwise(late))
        )
        and steps > 10
    )
