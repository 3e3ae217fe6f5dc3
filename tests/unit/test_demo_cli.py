"""`bipedtele demo`: --delay-scale, and the live status line read from a growing recording."""

from __future__ import annotations

import io
import time
from pathlib import Path

import pytest
from bipedtele.cli import main
from bipedtele.config.profile import ConfigError
from bipedtele.link.delaymodels import parse_delay_model
from bipedtele.link.messages import Feedback
from bipedtele.recording.recorder import Recorder
from bipedtele.tools.demo import parse_delay_scale, scale_delay_spec
from bipedtele.tools.demostatus import LiveStatus, RecordingTail, StatusPrinter, format_status

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize("bad", ["abc", "-1", "11", "nan", "inf", ""])
def test_a_bad_delay_scale_is_one_line_and_exit_2(bad: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError, match="--delay-scale"):
        parse_delay_scale(bad)
    assert main(["demo", "--dry-run", "--delay-scale", bad]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--delay-scale" in err and "allowed" in err


def test_scaled_models_have_every_delay_multiplied(tmp_path: Path) -> None:
    assert scale_delay_spec("const:150ms", 2.0, tmp_path, "f") == "const:300ms"
    assert scale_delay_spec("uniform:150ms:30ms", 0.5, tmp_path, "f") == "uniform:75ms:15ms"
    assert scale_delay_spec("normal:100ms:20ms", 3, tmp_path, "f") == "normal:300ms:60ms"
    for column in ("h1", "h2"):
        spec = scale_delay_spec(f"trace:intercontinental:{column}", 2.0, tmp_path, column)
        assert spec.startswith("trace:") and spec.endswith(":h1")
        old, new = parse_delay_model(f"trace:intercontinental:{column}"), parse_delay_model(spec)
        for t in (0.0, 3.3, 17.25, 250.0, 1234.5):
            assert new.delay_s(t) == pytest.approx(2.0 * old.delay_s(t), abs=1e-6)
    with pytest.raises(ConfigError, match="60"):
        scale_delay_spec("const:10s", 7.0, tmp_path, "f")


def test_dry_run_starts_the_proxy_with_the_scaled_delays(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run_dir = tmp_path / "run"
    assert (
        main(
            [
                "demo",
                "--dry-run",
                "--run-dir",
                str(run_dir),
                "--delay",
                "const:150ms,uniform:200ms:20ms",
                "--delay-scale",
                "2",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    proxy = next(line for line in out.splitlines() if line.startswith("# process proxy"))
    assert "--forward const:300ms" in proxy and "--backward uniform:400ms:40ms" in proxy
    assert main(["demo", "--dry-run", "--run-dir", str(run_dir), "--delay-scale", "2"]) == 0
    proxy = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("# process proxy"))
    assert str(run_dir.resolve() / "delay-forward-x2.csv") in proxy


def test_status_line_format() -> None:
    st = LiveStatus(passes_total=10)
    assert format_status(st, 3.2) == "passes 0/10 | 3 s | h1+h2 - | falls 0 | contacts 0 | err -"
    st.add("events", {"event": "start"})
    st.add("events", {"event": "pass", "n": 3, "side": "left"})
    st.add("leader/state", {"t": 1.0, "h1_ms": 160.4, "h2_ms": 211.9, "falls": 1, "collisions": 2})
    st.add("feedback/recv", {"ref": [8.0, 10.0], "eta": [7.0, 4.0]})
    st.add("feedback/recv", {"ref": [8.0, -10.0], "eta": [8.5, -12.0]})
    st.add("feedback/recv", {"ref": [8.0, None], "eta": [8.5, -12.0]})  # not a number: skipped
    assert format_status(st, 64.6) == (
        "passes 3/10 | 65 s | h1+h2 372 ms | falls 1 | contacts 2 | err fwd 0.75 cm/s, turn 4.00 deg/s"
    )
    assert format_status(LiveStatus(), 0.0).startswith("passes 0/? |")


def test_status_line_tells_the_link_in_words() -> None:
    st = LiveStatus(passes_total=10)
    st.add(
        "leader/state",
        {
            "t": 1.0,
            "link": "ok",
            "fb_age_ms": 312.4,
            "loss_pct": 0.04,
            "rx_kbps": 850.2,
            "video_fps": 9.8,
            "video_quality": 60,
        },
    )
    assert format_status(st, 5.0).endswith(
        "| err - | link ok: fb age 312 ms, loss 0.0 %, 850 kbit/s, video 9.8 fps q60"
    )
    st.add("leader/state", {"t": 2.0, "link": "lost", "link_lost_s": 3.24, "fb_age_ms": 4100.0, "loss_pct": 12.5})
    assert format_status(st, 6.0).endswith("| link lost for 3.2 s: fb age 4100 ms, loss 12.5 %, -, video -")
    st.add("leader/state", {"t": 3.0, "link": "capacity-limited", "rx_kbps": 400.0})
    assert "| link capacity-limited: fb age -, loss -, 400 kbit/s, video -" in format_status(st, 7.0)
    st.add("leader/state", {"t": 4.0, "h1_ms": 100.0})  # a sample without the link keeps the last one
    assert "capacity-limited" in format_status(st, 8.0)
    st.add("leader/state", {"t": 5.0, "link": "ok", "control_link": "udp"})  # split layout: control on UDP
    assert format_status(st, 9.0).endswith("video -, control udp")
    st.add("leader/state", {"t": 6.0, "link": "ok", "control_link": "tls (shared)"})
    assert format_status(st, 10.0).endswith(", control tls (shared)")


def _wait_records(tail: RecordingTail, n: int, timeout_s: float = 10.0) -> list[tuple[str, dict]]:
    got: list[tuple[str, dict]] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        got += tail.poll()
        time.sleep(0.05)
    return got


def test_the_tail_reads_a_recording_while_it_is_written(tmp_path: Path) -> None:
    path = tmp_path / "leader.mcap"
    tail = RecordingTail(path)
    assert tail.poll() == []  # no file yet
    with Recorder(path, flush_s=0.1) as rec:
        rec.write("events", {"event": "start"}, 1.0)
        for i in range(5):
            rec.write("feedback/recv", Feedback(seq=i + 1, t=1.0 + i, ref=[8.0, 0.0], eta=[7.0, 1.0]), 1.0 + i)
        first = _wait_records(tail, 6)
        assert [t for t, _ in first] == ["events"] + ["feedback/recv"] * 5
        rec.write("events", {"event": "pass", "n": 1, "side": "left"}, 7.0)
        second = _wait_records(tail, 1)
        assert second == [("events", {"event": "pass", "n": 1, "side": "left"})]  # only what is new
    assert tail.poll() == []  # the summary written at close holds no new message


def test_printer_rewrites_one_line_on_a_terminal_and_writes_plain_lines_otherwise(tmp_path: Path) -> None:
    now = [0.0]
    tty, plain = io.StringIO(), io.StringIO()
    p_tty = StatusPrinter(tmp_path / "none.mcap", 10, out=tty, tty=True, clock=lambda: now[0])
    p_plain = StatusPrinter(tmp_path / "none.mcap", 10, out=plain, tty=False, plain_every_s=5.0, clock=lambda: now[0])
    for _ in range(48):  # 12 s in steps of 0.25 s
        now[0] += 0.25
        p_tty.update()
        p_plain.update()
    p_tty.finish()
    assert tty.getvalue().count("\r") == 12 and tty.getvalue().endswith("\x1b[K\n")
    assert "\r" not in tty.getvalue().split("\x1b[K")[-1].strip()
    lines = plain.getvalue().splitlines()
    assert len(lines) == 2 and lines[0].startswith("passes 0/10 | 5 s |") and "\r" not in plain.getvalue()


def test_the_demo_scheme_goes_to_both_sides_and_a_bad_one_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["demo", "--dry-run", "--scheme", "nope", "--run-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--scheme nope: allowed: paper, " in err
    assert main(["demo", "--dry-run", "--scheme", "tdpa", "--run-dir", str(tmp_path / "r")]) == 0
    out = capsys.readouterr().out.splitlines()
    for role in ("follower", "leader"):
        line = next(x for x in out if x.startswith(f"# process {role}"))
        assert 'control.scheme="tdpa"' in line


def test_foxglove_serves_the_leader_on_port_and_the_follower_on_the_next(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 24: ``bipedtele demo --foxglove 8765``: each program its live view."""
    assert main(["demo", "--dry-run", "--run-dir", str(tmp_path / "run"), "--foxglove", "8765"]) == 0
    lines = capsys.readouterr().out.splitlines()
    leader = next(x for x in lines if x.startswith("# process leader:"))
    follower = next(x for x in lines if x.startswith("# process follower:"))
    assert "--foxglove 8765" in leader and "--foxglove 127.0.0.1:8766" in follower, (leader, follower)
    assert main(["demo", "--dry-run", "--foxglove", "8765", "--delay-backend", "packet"]) == 2
