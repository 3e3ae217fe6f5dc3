"""Table 2 report: hand-computed values on a synthetic recording, truncation, CLI errors."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from bipedtele.cli import main
from bipedtele.link.messages import Command, Feedback, Status
from bipedtele.recording.format import read_records
from bipedtele.recording.recorder import Recorder
from bipedtele.telemetry import LeaderSample
from bipedtele.tools.report import REPORT_KEYS, compute_report, fictitious_intervals, plot_report


def _synthetic(path: Path) -> None:
    """A leader recording whose Table 2 values are worked out by hand in the test."""
    with Recorder(path, metadata={"role": "leader"}) as rec:
        rec.write("cmd/sent", Command(seq=0, t=99.0, ref=[5.0, 4.0]), 99.0)  # before the task
        rec.write("estimates", {"h1_s": 0.05, "h2_s": 0.05}, 99.5)  # before the task: ignored
        rec.write("feedback/recv", Feedback(sid=9, t=98.9, ref=[5.0, 4.0], eta=[-20.0, 0.0]), 99.0)
        rec.write("events", {"event": "task_start"}, 100.0)
        for k in range(21):  # commands every 0.5 s from 100 to 110 s
            t = 100.0 + 0.5 * k
            rec.write("cmd/sent", Command(seq=k + 1, t=t, ref=[5.0, 4.0]), t)
        for t, h1, h2 in ((100.5, 0.10, 0.15), (101.5, 0.2, 0.2), (102.5, 0.0, 0.1), (103.5, 0.12, 0.18)):
            rec.write("estimates", {"h1_s": h1, "h2_s": h2, "f_m": [0.5, -0.2]}, t)
        for t, eta, state, yaw in (
            (101.0, [4.0, 4.5], "walking", 0.0),
            (102.0, [5.5, 3.0], "walking", 0.07),
            (103.0, [5.0, 4.0], "fallen", 0.14),
            (104.0, [2.0, 4.0], "fallen", 0.21),
        ):
            fb = Feedback(sid=9, t=t - 0.1, ref=[5.0, 4.0], eta=eta, state=state, pose=[0, 0, yaw])
            rec.write("feedback/recv", fb, t)
        # Follower status: session 9 had 2 falls before the recording, then one more and two
        # obstacle contacts; it restarts as session 10 and falls once.
        for t, sid, falls, coll in ((100.2, 9, 2, 0), (103.2, 9, 3, 2), (106.0, 10, 0, 0), (107.0, 10, 1, 0)):
            st = Status(
                sid=sid,
                t=t,
                role="follower",
                state="walking",
                counters={"falls": falls, "collisions": coll, "cmd_accepted": 5},
            )
            rec.write("status/recv", st, t)
        rec.write("events", {"event": "fall"}, 103.0)
        rec.write("events", {"event": "pass_done", "n": 1}, 105.0)
        rec.write("events", {"event": "task_done"}, 108.25)


def test_table2_values_by_hand(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _synthetic(path)
    report = compute_report(read_records(path))
    assert tuple(report) == REPORT_KEYS
    # Delays inside [100, 108.25]: 250, 400, (0 + 100: not warm, left out), 300 ms.
    assert report["min_delay_ms"] == pytest.approx(250.0)
    assert report["max_delay_ms"] == pytest.approx(400.0)
    assert report["mean_delay_ms"] == pytest.approx((250 + 400 + 300) / 3)
    assert report["completion_s"] == pytest.approx(8.25)
    # |ref - eta| over the four feedbacks in the window: forward 1, 0.5, 0, 3; turn .5, 1, 0, 0.
    assert report["forward_error_instant_cm_s"] == pytest.approx(4.5 / 4)
    assert report["turn_error_instant_deg_s"] == pytest.approx(1.5 / 4)
    # Feedback 1 s apart, no T (1 s assumed): no window of T/2 holds two poses, no footfalls.
    assert report["forward_error_cm_s"] is None and report["odometry_source"] is None
    assert report["passes"] == 1
    # falls: events 1, status increase (3-2) + 1 = 2, fallen transitions 1 -> 2.
    assert report["falls"] == 2
    assert report["collisions"] == 2


def test_window_without_task_events_uses_commands(tmp_path: Path) -> None:
    path = tmp_path / "bare.mcap"
    with Recorder(path) as rec:
        for k in range(5):
            rec.write("cmd/recv", Command(seq=k, t=10.0 + k - 0.2, ref=[1.0, 0.0], h2_s=0.1), 10.0 + k)
            rec.write("feedback/sent", Feedback(t=10.0 + k, ref=[1.0, 0.0], eta=[1.5, 1.0]), 10.0 + k)
    report = compute_report(read_records(path))
    assert report["completion_s"] == pytest.approx(4.0)
    # A follower's file: h1 = t_recv - t = 0.2 s, plus the leader's h2 = 0.1 s.
    assert report["mean_delay_ms"] == pytest.approx(300.0)
    assert report["forward_error_instant_cm_s"] == pytest.approx(0.5)
    assert report["turn_error_instant_deg_s"] == pytest.approx(1.0)
    assert report["falls"] == 0 and report["collisions"] == 0
    assert report["passes"] is None  # no task events: a follower's file


@pytest.mark.parametrize("typed", [True, False], ids=["LeaderSample", "map"])
def test_leader_state_records_and_short_event_names(tmp_path: Path, typed: bool) -> None:
    """The leader program records its sample on ``leader/state`` and ``start``/``done``.

    The program writes a :class:`LeaderSample`; an older file holds the same keys as a map."""
    path = tmp_path / "leader.mcap"
    with Recorder(path) as rec:
        rec.write("events", {"event": "start", "operator": "pilot"}, 50.0)
        for k, (h1, h2) in enumerate(((None, None), (120.0, 130.0), (100.0, 200.0))):
            t = 50.0 + k
            rec.write("cmd/sent", Command(seq=k, t=t, ref=[3.0, 0.0]), t)
            state = {"t": t, "h1_ms": h1, "h2_ms": h2, "force_v": 0.1, "force_w": 0.0}
            rec.write("leader/state", LeaderSample(**state) if typed else state, t)
            rec.write("feedback/recv", Feedback(t=t - 0.1, ref=[3.0, 1.0], eta=[2.0, 1.0]), t)
        rec.write("events", {"event": "done", "elapsed_s": 2.5}, 52.5)
    records = list(read_records(path))
    report = compute_report(records)
    assert report["completion_s"] == pytest.approx(2.5)
    assert report["min_delay_ms"] == pytest.approx(250.0)
    assert report["max_delay_ms"] == pytest.approx(300.0)
    assert report["forward_error_instant_cm_s"] == pytest.approx(1.0)
    assert report["turn_error_instant_deg_s"] == pytest.approx(0.0)
    assert report["passes"] == 0
    fig11 = plot_report(records)["fig11_coordination"]
    assert len(fig11.axes[3].lines) == 2  # handle force


def test_empty_input_gives_nones() -> None:
    report = compute_report([])
    assert tuple(report) == REPORT_KEYS
    assert report["mean_delay_ms"] is None and report["completion_s"] is None
    assert report["falls"] == 0


def test_figures(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _synthetic(path)
    figs = plot_report(list(read_records(path)))
    assert set(figs) == {"fig9_delay", "fig11_coordination", "fig12_tracking"}
    assert len(figs["fig9_delay"].axes[0].lines) == 3  # h1+h2, h1, h2
    # command, measured, z_e | same for turn | f_v tangential, normal | handle force axes
    assert [len(a.lines) for a in figs["fig11_coordination"].axes] == [3, 3, 2, 2]
    turn = figs["fig12_tracking"].axes[1].lines
    assert turn[0].get_ydata()[-1] == pytest.approx(4.0 * 5.0)  # 4 deg/s, feedback 99..104 s
    assert turn[1].get_ydata()[-1] == pytest.approx(12.03, abs=0.01)  # yaw 0.21 rad


def test_cli_prints_writes_json_and_plots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.mcap"
    _synthetic(path)
    out_json, plots = tmp_path / "r.json", tmp_path / "plots"
    assert main(["report", str(path), "--json", str(out_json), "--plots", str(plots)]) == 0
    text = capsys.readouterr().out
    assert "Average delay" in text and "316.67 ms" in text and "8.25 s" in text
    assert f"{'Task passes':<30} 1" in text and "Turning speed error per tick" in text
    data = json.loads(out_json.read_text())
    assert data == compute_report(read_records(path))
    assert sorted(p.name for p in plots.iterdir()) == [
        "fig11_coordination.png",
        "fig12_tracking.png",
        "fig9_delay.png",
    ]


@pytest.mark.parametrize("content", [None, b"", b"garbage, not an mcap file"])
def test_cli_bad_file_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes | None
) -> None:
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    assert main(["report", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("bipedtele report: ")


def test_truncated_recording_reports_up_to_the_cut(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "long.mcap"
    with Recorder(path, flush_s=0.05) as rec:
        rec.write("events", {"event": "task_start"}, 0.0)
        for k in range(1, 401):
            t = 0.05 * k
            rec.write("cmd/sent", Command(seq=k, t=t, ref=[5.0, 0.0]), t)
            rec.write("estimates", {"h1_s": 0.1, "h2_s": 0.1 + 0.001 * k}, t)
            rec.write("feedback/recv", Feedback(t=t, ref=[5.0, 0.0], eta=[4.0, 0.0]), t)
            if k % 80 == 0:
                time.sleep(0.12)  # the writer closes a chunk: a cut keeps what came before
        rec.write("events", {"event": "task_done"}, 20.0)
    full = compute_report(read_records(path))
    assert full["completion_s"] == pytest.approx(20.0)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: int(path.stat().st_size * 0.6)])
    kept = list(read_records(cut))
    last_cmd = max(r.t_recv for r in kept if r.topic == "cmd/sent")
    assert 0.0 < last_cmd < 19.0
    out_json = tmp_path / "cut.json"
    assert main(["report", str(cut), "--json", str(out_json)]) == 0
    report = json.loads(out_json.read_text())
    assert tuple(report) == REPORT_KEYS
    assert report["completion_s"] == pytest.approx(last_cmd)  # no task_done: the last command
    assert report["forward_error_instant_cm_s"] == pytest.approx(1.0)
    assert report["min_delay_ms"] == pytest.approx(201.0)
    assert report["max_delay_ms"] < full["max_delay_ms"]
    capsys.readouterr()


def test_fictitious_intervals() -> None:
    t = np.arange(10.0)
    f = np.array([0, 0, 2, 3, 0, 0, 1e-9, 1, 1, 1])
    assert fictitious_intervals(t, f) == [(2.0, 4.0), (7.0, 9.0)]
    assert fictitious_intervals(t, np.zeros(10)) == []


def _span_labels(ax: object) -> list[str]:
    return [p.get_label() for p in ax.patches]  # type: ignore[attr-defined]


@pytest.mark.parametrize("source", ["feedback", "leader_state"])
def test_fig11_shades_where_the_fictitious_force_acts(tmp_path: Path, source: str) -> None:
    """Fig. 11 counterpart: f_v is drawn and the intervals where it acts are shaded on every
    panel (from the feedback's f_v, else from the leader's state samples)."""
    path = tmp_path / "obstacle.mcap"
    with Recorder(path) as rec:
        rec.write("events", {"event": "task_start"}, 0.0)
        for k in range(60):
            t = 0.1 * k
            near = 2.0 <= t < 3.5  # an obstacle in sonar range
            fv = [4.0, 1.0] if near else [0.0, 0.0]
            rec.write("cmd/sent", Command(seq=k, t=t, ref=[5.0, 0.0]), t)
            if source == "feedback":
                fb = Feedback(
                    t=t, ref=[5.0, 0.0], eta=[3.0 if near else 5.0, 0.0], z_e=[1.0 if near else 5.0, 0.0], f_v=fv
                )
                rec.write("feedback/recv", fb, t)
            state = {"t": t, "force_v": -2.0 if near else 0.0, "force_w": 0.0}
            if source == "leader_state":
                state.update(f_v_t=fv[0], f_v_n=fv[1])
            rec.write("leader/state", state, t)
        rec.write("events", {"event": "task_done"}, 6.0)
    fig = plot_report(list(read_records(path)))["fig11_coordination"]
    assert len(fig.axes) == 4
    # f_v drawn from the feedback, or from the leader's samples in a file without feedback
    assert max(fig.axes[2].lines[0].get_ydata()) == pytest.approx(4.0)
    for ax in fig.axes:
        labels = _span_labels(ax)
        assert labels.count("f_v acts") == 1  # one interval, labelled once
    span = next(p for p in fig.axes[0].patches if p.get_label() == "f_v acts")
    assert span.get_x() == pytest.approx(2.0) and span.get_x() + span.get_width() == pytest.approx(3.5)
