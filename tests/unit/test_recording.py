"""The MCAP recorder: round trip, maps copied at write(), thread safety, video thinning,
truncation and SIGKILL, unique never-overwritten file names, no empty files, no secrets in
the metadata. The channels' schemas: tests/unit/test_recording_schemas.py."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.link.messages import Command, Feedback, VideoFrame
from bipedtele.recording.files import new_recording_path, open_recording
from bipedtele.recording.format import RecordingError, read_metadata, read_records
from bipedtele.recording.recorder import Recorder


def test_round_trip_messages_dicts_and_metadata(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    fb = Feedback(sid=7, seq=3, t=100.0, z_e=[1.5, -2.0], eta=[4.0, 1.0], h1_s=0.12)
    with Recorder(path, metadata={"role": "leader", "rate_hz": 100}) as rec:
        assert rec.write("cmd/sent", Command(seq=1, t=99.0, ref=[5.0, 4.0]), 99.0)
        assert rec.write("feedback/recv", fb, 100.25, t_log=100.3)
        assert rec.write("estimates", {"h1_s": np.float64(0.1), "alpha_m": np.array([2.0, 3.0])}, 101.0)
        assert rec.write("events", {"event": "task_start"}, 102.0)
    records = list(read_records(path))
    assert [r.topic for r in records] == ["cmd/sent", "feedback/recv", "estimates", "events"]
    cmd, fbr, est, ev = records
    assert cmd.data["k"] == "cmd" and cmd.data["ref"] == [5.0, 4.0] and cmd.t_recv == 99.0
    assert fbr.t_recv == pytest.approx(100.25) and fbr.t_log == pytest.approx(100.3)
    assert fbr.data["z_e"] == [1.5, -2.0] and fbr.data["sid"] == 7 and fbr.data["seq"] == 3
    assert fbr.data["h1_s"] == pytest.approx(0.12) and fbr.data["state"] == "starting"
    assert est.data == {"h1_s": 0.1, "alpha_m": [2.0, 3.0]}
    assert ev.data == {"event": "task_start"}
    meta = read_metadata(path)
    assert meta["role"] == "leader" and meta["rate_hz"] == "100"


def test_unencodable_values_are_dropped_and_counted(tmp_path: Path) -> None:
    with Recorder(tmp_path / "r.mcap") as rec:
        assert not rec.write("events", {"x": object()}, 1.0)
        assert rec.write("events", {"event": "ok"}, 2.0)
    assert rec.stats["dropped_unencodable"] == 1
    assert not rec.write("events", {"event": "late"}, 3.0)  # after close: dropped, no raise
    assert rec.stats["dropped_closed"] == 1
    assert [r.data["event"] for r in read_records(tmp_path / "r.mcap")] == ["ok"]


def test_a_map_may_be_reused_after_write(tmp_path: Path) -> None:
    """The writer thread encodes later: write() must have taken its own copy."""
    path = tmp_path / "reuse.mcap"
    flat = {"t": 1.0, "x": 2.0, "state": "ok"}
    nested = {"pose": [1.0, 2.0], "inner": {"n": 1}, "arr": np.array([3.0, 4.0])}
    with Recorder(path) as rec:
        assert rec.write("leader/state", flat, 1.0)
        assert rec.write("events", nested, 1.0)
        flat["x"] = 99.0
        flat["new"] = 1
        nested["pose"].append(3.0)
        nested["inner"]["n"] = 2
        nested["arr"][0] = -1.0
    got = [r.data for r in read_records(path)]
    assert got == [{"t": 1.0, "x": 2.0, "state": "ok"}, {"pose": [1.0, 2.0], "inner": {"n": 1}, "arr": [3.0, 4.0]}]


def test_video_keeps_every_nth_jpeg(tmp_path: Path) -> None:
    path = tmp_path / "v.mcap"
    with Recorder(path, jpeg_every=3) as rec:
        for i in range(7):
            rec.write("video/recv", VideoFrame(seq=i, t=1.0 + i, jpeg=b"\xff\xd8jpeg"), 1.0 + i)
    frames = [r.data for r in read_records(path)]
    assert [f["seq"] for f in frames] == list(range(7))
    assert [bool(f["jpeg"]) for f in frames] == [True, False, False, True, False, False, True]
    assert all(f.get("jpeg_skipped") for f in frames if not f["jpeg"])


def test_concurrent_writers_lose_nothing(tmp_path: Path) -> None:
    path = tmp_path / "c.mcap"
    n = 2000
    with Recorder(path, flush_s=0.2) as rec:

        def writer(k: int) -> None:
            for i in range(n):
                rec.write(f"w{k}", {"i": i}, float(i))

        threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    by_topic: dict[str, list[int]] = {}
    for r in read_records(path):
        by_topic.setdefault(r.topic, []).append(r.data["i"])
    assert sorted(by_topic) == ["w0", "w1", "w2", "w3"]
    for seq in by_topic.values():
        assert seq == list(range(n))  # each writer's messages complete and in order


def test_missing_or_foreign_file_raises(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot open"):
        list(read_records(tmp_path / "nope.mcap"))
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file at all")
    with pytest.raises(RecordingError, match="not an MCAP"):
        list(read_records(junk))
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError):
        list(read_records(empty))


def test_truncated_file_reads_up_to_the_cut(tmp_path: Path) -> None:
    path = tmp_path / "t.mcap"
    with Recorder(path, flush_s=0.05) as rec:
        for i in range(3000):
            rec.write("feedback/recv", {"i": i, "pad": "x" * 200}, float(i))
            if i % 500 == 499:
                time.sleep(0.15)  # let the writer close a chunk
    full = [r.data["i"] for r in read_records(path)]
    assert full == list(range(3000))
    blob = path.read_bytes()
    counts = []
    for frac in (0.3, 0.6, 0.9):
        cut = tmp_path / f"cut{frac}.mcap"
        cut.write_bytes(blob[: int(len(blob) * frac)])
        got = [r.data["i"] for r in read_records(cut)]
        assert got == list(range(len(got)))  # a prefix, nothing invented
        counts.append(len(got))
    assert 0 < counts[0] < counts[1] < 3000  # (0.9 may cut only the summary at the end)


CHILD = textwrap.dedent(
    """
    import sys, time
    from bipedtele.recording.recorder import Recorder
    rec = Recorder(sys.argv[1], flush_s=0.5, metadata={"role": "child"})
    i = 0
    while True:
        rec.write("cmd/sent", {"i": i}, time.time())
        i += 1
        if i == 50:
            print("running", flush=True)
        time.sleep(0.002)
    """
)


@pytest.mark.timeout(60)
def test_sigkilled_writer_keeps_all_but_the_last_flush_interval(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "running"
        time.sleep(2.5)
        t_kill = time.time()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    records = list(read_records(path))
    seq = [r.data["i"] for r in records]
    assert seq == list(range(len(seq)))  # complete prefix
    assert len(seq) > 50
    lost_s = t_kill - records[-1].t_recv
    assert 0 <= lost_s < 2.0  # flush_s=0.5: at most one flush interval (+ scheduling) is lost
    assert read_metadata(path)["role"] == "child"


# ----------------------------------------------------------------- names, no overwrite, no empties


def _write_run(rec: Recorder, who: int, n: int = 20) -> None:
    for i in range(n):
        rec.write("cmd/sent", {"who": who, "i": i}, 1000.0 + i)


def test_recordings_started_in_the_same_second_do_not_overwrite_each_other(tmp_path: Path) -> None:
    """Issue 15 item 7: three leaders started in one second; the survivor read back 0 records."""
    t = time.time()
    recs = [Recorder(new_recording_path(tmp_path, "leader", now=t)) for _ in range(3)]
    for who, rec in enumerate(recs):
        _write_run(rec, who)
    for rec in recs:
        rec.close()
    paths = [rec.path for rec in recs]
    assert len(set(paths)) == 3
    for who, path in enumerate(paths):
        data = [r.data for r in read_records(path)]
        assert data == [{"who": who, "i": i} for i in range(20)]


def test_an_existing_file_is_never_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with Recorder(path) as rec:
        _write_run(rec, 1)
    before = path.read_bytes()
    with pytest.raises(FileExistsError):
        Recorder(path)
    assert path.read_bytes() == before
    assert [r.data["who"] for r in read_records(path)] == [1] * 20


def test_recording_names_have_milliseconds_and_a_counter(tmp_path: Path) -> None:
    t = time.mktime((2026, 3, 4, 5, 6, 7, 0, 0, -1)) + 0.0891
    first = new_recording_path(tmp_path / "runs", "leader", now=t)
    assert first == tmp_path / "runs" / "leader-20260304-050607-089.mcap"
    assert re.fullmatch(r"follower-\d{8}-\d{6}-\d{3}\.mcap", new_recording_path(tmp_path, "follower").name)
    (tmp_path / "runs").mkdir()
    first.write_bytes(b"taken")
    second = new_recording_path(tmp_path / "runs", "leader", now=t)
    assert second.name == "leader-20260304-050607-089-1.mcap"
    second.write_bytes(b"taken")
    assert new_recording_path(tmp_path / "runs", "leader", now=t).name == "leader-20260304-050607-089-2.mcap"
    for bad in ("", "../x", "a/b", "leader.mcap", "-x"):
        with pytest.raises(ValueError, match="role"):
            new_recording_path(tmp_path, bad)


def test_a_recorder_that_recorded_nothing_leaves_no_file(tmp_path: Path) -> None:
    path = tmp_path / "failed-start.mcap"
    rec = Recorder(path, metadata={"role": "leader"})
    assert path.exists()  # created (exclusively) at once
    rec.close()
    assert not path.exists() and rec.removed
    with Recorder(tmp_path / "all-dropped.mcap") as rec:
        assert not rec.write("events", {"x": object()}, 1.0)  # dropped: nothing recorded
    assert not (tmp_path / "all-dropped.mcap").exists()
    with Recorder(tmp_path / "one.mcap") as rec:
        assert rec.write("events", {"event": "start"}, 1.0)
    assert not rec.removed and rec.written == 1
    assert [r.data for r in read_records(tmp_path / "one.mcap")] == [{"event": "start"}]
    assert list(tmp_path.iterdir()) == [tmp_path / "one.mcap"]


SAME_MOMENT = textwrap.dedent(
    """
    import sys, time
    from bipedtele.recording.files import open_recording
    folder, who, start = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    time.sleep(max(0.0, start - time.time()))
    with open_recording(folder, "leader", metadata={"role": "leader"}) as rec:
        for i in range(50):
            rec.write("cmd/sent", {"who": who, "i": i}, time.time())
    print(rec.path, flush=True)
    """
)


@pytest.mark.timeout(60)
def test_three_processes_starting_together_leave_three_readable_recordings(tmp_path: Path) -> None:
    folder = tmp_path / "runs"
    start = time.time() + 1.5  # all three open their recording at this moment
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", SAME_MOMENT, str(folder), str(k), repr(start)], stdout=subprocess.PIPE, text=True
        )
        for k in range(3)
    ]
    outs = [p.communicate(timeout=30)[0].strip() for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0]
    files = sorted(folder.iterdir())
    assert len(files) == 3 and sorted(Path(o) for o in outs) == files
    seen = set()
    for f in files:
        data = [r.data for r in read_records(f)]
        who = data[0]["who"]
        assert data == [{"who": who, "i": i} for i in range(50)]
        seen.add(who)
    assert seen == {0, 1, 2}


def test_open_recording_creates_the_folder_and_a_fresh_name(tmp_path: Path) -> None:
    with open_recording(tmp_path / "a" / "b", "follower", flush_s=0.5) as rec:
        rec.write("events", {"event": "start"}, 1.0)
    assert rec.path.parent == tmp_path / "a" / "b" and rec.path.name.startswith("follower-")
    assert read_metadata(rec.path)["bipedtele_version"]


def test_inline_password_never_reaches_the_metadata(tmp_path: Path) -> None:
    """Issue 10 item 11: a password set inline was written into every MCAP's metadata."""
    cfg = load_config("default", ['network.password="hunter2"', 'network.user="leader"'])
    path = tmp_path / "run.mcap"
    with Recorder(path, metadata={"role": "leader", "config": cfg.to_dict()}) as rec:
        rec.write("events", {"event": "start"}, 1.0)
    assert b"hunter2" not in path.read_bytes()
    meta = read_metadata(path)
    assert '"password": "***"' in meta["config"] and '"user": "leader"' in meta["config"]
