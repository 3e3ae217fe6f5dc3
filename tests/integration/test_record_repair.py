"""A recording cut by ``kill -9`` is made readable by the standard MCAP reader (issue 32, item 8).

A real writer process (the :class:`~bipedtele.recording.recorder.Recorder`, flushing every 0.1 s)
records commands until it is killed with SIGKILL mid-run. The standard reader (the ``mcap``
package's ``make_reader``, as Foxglove and other tools read) gets no summary from the cut
file; ``bipedtele record repair`` rewrites it, and the standard reader then reads every
message the project's own reader reads, with the summary, the channels, the schemas and the
run's metadata.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from bipedtele.recording.recorder import read_metadata, read_records
from mcap.reader import make_reader

pytestmark = pytest.mark.timeout(120)

WRITER = textwrap.dedent(
    """
    import sys, time
    from bipedtele.link.messages import Command
    from bipedtele.recording.recorder import Recorder
    rec = Recorder(sys.argv[1], flush_s=0.1, metadata={"role": "b32b-writer"})
    seq = 0
    while True:  # until killed
        seq += 1
        now = time.time()
        rec.write("cmd/sent", Command(sid=7, seq=seq, t=now, ref=[0.05, 0.01 * (seq % 7)]), now)
        rec.write("events", {"event": "tick", "n": seq}, now)
        if seq == 200:
            print("writing", flush=True)
        time.sleep(0.002)
    """
)


def _standard(path: Path) -> tuple[int, object]:
    """Messages the standard reader yields (0 when it gives up) and its summary (None without)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        try:
            summary = reader.get_summary()
        except Exception:  # what a tool meets on a cut file
            summary = None
        n = 0
        with contextlib.suppress(Exception):
            for _ in reader.iter_messages():
                n += 1
    return n, summary


def test_a_recording_cut_by_kill_9_opens_in_the_standard_reader_after_repair(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    writer = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert writer.stdout is not None and writer.stdout.readline().strip() == "writing"
        time.sleep(1.5)
        os.kill(writer.pid, signal.SIGKILL)
    finally:
        writer.wait(10)
    ours = list(read_records(path))
    assert len(ours) > 200, len(ours)
    n_cut, summary_cut = _standard(path)
    assert summary_cut is None, "the cut file had a summary: nothing cut"
    print(f"cut file: the standard reader reads {n_cut} messages, ours {len(ours)}")

    proc = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "record", "repair", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "cut.mcap.cut").exists() and "written to" in proc.stdout, proc.stdout
    n, summary = _standard(path)
    assert summary is not None and summary.statistics is not None, "no summary after repair"
    assert n == len(ours) == summary.statistics.message_count, (n, len(ours))
    assert {c.topic for c in summary.channels.values()} == {"cmd/sent", "events"}
    assert [r.data for r in read_records(path)] == [r.data for r in ours]  # the same messages, in order
    assert read_metadata(path)["role"] == "b32b-writer"
    # a complete file is left alone
    again = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "record", "repair", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert again.returncode == 0 and "nothing to repair" in again.stdout, again.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "record", "repair", str(tmp_path / "none.mcap")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
