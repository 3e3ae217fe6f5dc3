"""The MCAP recorder: round trip, thread safety, video thinning, truncation and SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from bipedtele.messages import Command, Feedback, VideoFrame
from bipedtele.recording import (
    Recorder,
    RecordingError,
    read_metadata,
    read_records,
)


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
    from bipedtele.recording import Recorder
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
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True
    )
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
