"""The leader program against a follower stub process over real Zenoh (loopback).

The stub (``leader_stub_follower.py``) answers commands with feedback whose z_e follows
the command with a first-order lag, delayed by 50 ms, then by 400 ms, then silent. From
the leader's own MCAP recording we check that the force follows (31) with the delayed
z_e, that alpha_m and h2 follow the delay, and that the force fades to zero when the
feedback stops.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.control.damping import schedule_damping
from bipedtele.recording.format import read_records

HERE = Path(__file__).parent
D1, D2, SWITCH, SILENT, TOTAL = 0.05, 0.4, 3.5, 6.5, 9.0
LEADER_S = 8.5


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_leader_against_a_follower_stub(tmp_path):
    port = free_port()
    robot = f"lt{os.getpid()}"
    rec = tmp_path / "leader.mcap"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    leader = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "--log-level",
            "WARNING",
            "leader",
            "--operator",
            "scripted",
            "--duration",
            str(LEADER_S),
            "--record",
            str(rec),
            "--set",
            f'robot.id="{robot}"',
            "--set",
            f'network.listen=["tcp/127.0.0.1:{port}"]',
            "--set",
            "leader.cockpit=false",
            "--set",
            "leader.script=[[0, 4, 3], [100, 4, 3]]",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    stub = subprocess.Popen(
        [
            sys.executable,
            str(HERE / "leader_stub_follower.py"),
            robot,
            f"tcp/127.0.0.1:{port}",
            str(D1),
            str(D2),
            str(SWITCH),
            str(SILENT),
            str(TOTAL),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        out, err = leader.communicate(timeout=60)
    finally:
        leader.kill()
        stub_out = stub.communicate(timeout=30)
    assert leader.returncode == 0, err
    assert stub.returncode == 0, stub_out[1]
    assert out.startswith("leader: operator scripted") and "commands sent" in out

    records = list(read_records(rec))
    fbs = [r for r in records if r.topic == "feedback/recv"]
    snaps = [r.data for r in records if r.topic == "leader/state"]
    cmds = [r.data for r in records if r.topic == "cmd/sent"]
    assert len(fbs) > 100 and len(snaps) > 500 and len(cmds) > 500
    fb_recv = np.array([r.t_recv for r in fbs])
    fb_sent = np.array([r.data["t"] for r in fbs])
    delays = fb_recv - fb_sent
    # The stub really delayed its feedback: ~50 ms first, ~400 ms later.
    assert np.median(delays[:20]) == pytest.approx(D1, abs=0.03)
    assert np.median(delays[-20:]) == pytest.approx(D2, abs=0.03)

    cfg = load_config("default")
    c = cfg.control
    k_m, k_g = np.array(c.k_m), np.array(c.k_g)
    checked = 0
    for s in snaps:
        if s.get("z_e_v") is None or s["gain"] != 1.0:
            continue
        # (31) with g_m = 0, then the 8 N clamp, on the loop's own values.
        x, dx = np.array([s["x_v"], s["x_w"]]), np.array([s["dx_v"], s["dx_w"]])
        z = np.array([s["z_e_v"], s["z_e_w"]])
        a = np.array([s["alpha_m_v"], s["alpha_m_w"]])
        want = np.clip(-k_m * (k_g * x - z) - a * dx, -8.0, 8.0)
        assert [s["force_v"], s["force_w"]] == pytest.approx(want.tolist(), rel=1e-9, abs=1e-9)
        # The z_e in use is that of one of the last feedback messages received: z_e(t - h2).
        i = int(np.searchsorted(fb_recv, s["t"], side="right"))
        recent = [fbs[j].data["z_e"] for j in range(max(0, i - 2), i)]
        assert [s["z_e_v"], s["z_e_w"]] in recent
        checked += 1
    assert checked > 300
    forces = np.array([abs(s["force_v"]) + abs(s["force_w"]) for s in snaps if s["gain"] == 1.0])
    assert forces.max() > 0.1  # the lagging z_e produced a real force

    # h2 and alpha_m follow the delay (1 s window): compare the last second of each phase.
    t_switch = fb_recv[np.argmax(delays > (D1 + D2) / 2)]
    t_last = fb_recv[-1]
    early = [s for s in snaps if t_switch - 1.0 < s["t"] < t_switch - 0.1 and s["h2_ms"] is not None]
    late = [s for s in snaps if t_last - 1.0 < s["t"] < t_last and s["h2_ms"] is not None]
    assert early and late
    assert np.median([s["h2_ms"] for s in early]) == pytest.approx(1000 * D1, abs=25)
    assert np.median([s["h2_ms"] for s in late]) == pytest.approx(1000 * D2, abs=25)
    a_early = np.median([s["alpha_m_v"] for s in early])
    a_late = np.median([s["alpha_m_v"] for s in late])
    assert a_late > a_early
    h1 = late[-1]["h1_ms"] / 1000.0
    want_late = schedule_damping(h1, late[-1]["h2_ms"] / 1000.0, c).alpha_m[0]
    # (40) is recomputed when h1 or h2 moved by more than 0.5 ms.
    assert late[-1]["alpha_m_v"] == pytest.approx(want_late, abs=(1 + c.margin) * k_m[0] * k_g[0] * 1.25 * 5e-4)
    # Commands carry h2 and alpha_m.
    late_cmds = [m for m in cmds if t_last - 0.5 < m["t"] < t_last]
    assert late_cmds and all(m["h2_s"] > 0.3 for m in late_cmds)

    # Stale feedback: full force until the timeout, zero once the fade is over.
    lc = cfg.leader
    after = [s for s in snaps if s["t"] > t_last + lc.feedback_timeout_s + lc.fade_s + 0.02]
    assert after, "the leader ran past the fade"
    assert all(s["gain"] == 0.0 and s["force_v"] == 0.0 and s["force_w"] == 0.0 for s in after)
    assert all(s["leader_state"] == "feedback_stale" for s in after)
    before = [s for s in snaps if t_last + 0.02 < s["t"] < t_last + lc.feedback_timeout_s - 0.02]
    assert before and all(s["gain"] == 1.0 for s in before)
    # The program ends by asking the robot to stop.
    assert cmds[-1]["enable"] is False


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_leader_exits_on_its_own_when_the_operator_is_done(tmp_path):
    port = free_port()
    robot = f"ld{os.getpid()}"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    stub = subprocess.Popen(
        [
            sys.executable,
            str(HERE / "leader_stub_follower.py"),
            robot,
            f"tcp/127.0.0.1:{port}",
            "0.02",
            "0.02",
            "100",
            "100",
            "12",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        leader = subprocess.run(
            [
                sys.executable,
                "-m",
                "bipedtele.cli",
                "--log-level",
                "WARNING",
                "leader",
                "--operator",
                "scripted",
                "--record",
                str(tmp_path / "l.mcap"),
                "--set",
                f'robot.id="{robot}"',
                "--set",
                f'network.listen=["tcp/127.0.0.1:{port}"]',
                "--set",
                "leader.cockpit=false",
                "--set",
                "leader.script=[[0, 3, 0], [1.0, 3, 0]]",
            ],
            capture_output=True,
            text=True,
            env=env,
            timeout=40,
        )
    finally:
        stub.kill()
        stub.communicate(timeout=10)
    assert leader.returncode == 0, leader.stderr
    assert ", done," in leader.stdout and leader.stdout.count("\n") == 1
    events = [r.data["event"] for r in read_records(tmp_path / "l.mcap") if r.topic == "events"]
    assert events[0] == "start" and events[-1] == "done"


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_duration_governs_a_shorter_script(tmp_path):
    """--duration 4 with a script that ends after 1 s: the run lasts the duration and the
    last point's speed is held to the end (it used to end when the script did)."""
    port = free_port()
    robot = f"lh{os.getpid()}"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    stub = subprocess.Popen(
        [
            sys.executable,
            str(HERE / "leader_stub_follower.py"),
            robot,
            f"tcp/127.0.0.1:{port}",
            "0.02",
            "0.02",
            "100",
            "100",
            "20",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        leader = subprocess.run(
            [
                sys.executable,
                "-m",
                "bipedtele.cli",
                "--log-level",
                "WARNING",
                "leader",
                "--operator",
                "scripted",
                "--duration",
                "4",
                "--record",
                str(tmp_path / "l.mcap"),
                "--set",
                f'robot.id="{robot}"',
                "--set",
                f'network.listen=["tcp/127.0.0.1:{port}"]',
                "--set",
                "leader.cockpit=false",
                "--set",
                "leader.script=[[0, 3, 2], [1.0, 3, 2]]",
                "--set",
                'leader.script_interp="step"',
            ],
            capture_output=True,
            text=True,
            env=env,
            timeout=40,
        )
    finally:
        stub.kill()
        stub.communicate(timeout=10)
    assert leader.returncode == 0, leader.stderr
    assert ", stopped, 4." in leader.stdout, leader.stdout
    recs = list(read_records(tmp_path / "l.mcap"))
    events = [r.data["event"] for r in recs if r.topic == "events"]
    assert events[0] == "start" and events[-1] == "stop"
    cmds = [r.data for r in recs if r.topic == "cmd/sent"]
    t_end = cmds[-1]["t"]
    held = [c for c in cmds if t_end - 1.5 < c["t"] < t_end - 0.1]
    assert len(held) > 50 and all(c["enable"] for c in held)  # still driving, 3 s after the script
    snaps = [r.data for r in recs if r.topic == "leader/state" and r.data["t"] > t_end - 1.5]
    assert snaps and all(s["intended_v"] == 3.0 and s["intended_w"] == 2.0 for s in snaps)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--set", "leader.cmd_rate_hz=0"], "leader.cmd_rate_hz"),
        (["--device", "nope"], "sim-falcon"),
        (["--operator", "browser", "--set", "leader.cockpit=false"], "cockpit"),
        (["--duration", "-1"], "--duration"),
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(args, needle, tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "leader", "--set", "record.enabled=false", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], res.stderr
