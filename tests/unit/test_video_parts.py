"""A video frame sent in parts on a slow uplink (issue 19): the follower cuts each JPEG into
parts of at most ``part_bits_max`` paced at video's budget (follower/video.py), the leader
joins them (leader/videoparts.py) and counts what does not fit, never a crash."""

from __future__ import annotations

import time

import numpy as np
import pytest
from bipedtele.follower.capacity import UplinkBudget
from bipedtele.follower.video import MIN_PART_BYTES, VideoStreamer
from bipedtele.leader.videoparts import FrameAssembler
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import MAX_JPEG_BYTES, VideoFrame

pytestmark = pytest.mark.timeout(60)


class Cam:
    """A noisy QVGA image (JPEG does not shrink noise much: several kB a frame)."""

    def __init__(self) -> None:
        self.rng = np.random.default_rng(0)

    def capture(self, cam: str) -> np.ndarray:
        return self.rng.integers(0, 255, size=(240, 320, 3), dtype=np.uint8)


def _stream(budget: float, part_bits: float | None, frames: int = 3) -> list[tuple[float, VideoFrame]]:
    sent: list[tuple[float, VideoFrame]] = []
    t = [0.0]
    v = VideoStreamer(Cam(), ["head"], 5.0, lambda f: sent.append((time.monotonic(), f)), now=lambda: t[0])  # type: ignore[arg-type]
    v.set_budget(budget, None, part_bits)
    with v:
        for _ in range(frames):
            n = len(sent)
            v.maybe_capture(t[0])
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:  # the whole frame, all its parts
                if len(sent) > n and sent[-1][1].part == sent[-1][1].parts - 1:
                    break
                time.sleep(0.005)
            t[0] += 1.0
    return sent


def test_a_large_frame_goes_in_paced_parts_that_join_into_the_jpeg() -> None:
    budget, part_bits = 400_000.0, 8_000.0
    sent = _stream(budget, part_bits)
    frames = [f for _, f in sent]
    assert frames and frames[0].parts > 1
    join = FrameAssembler(DropCounter("test"))
    whole = [w for w in (join.add(f) for f in frames) if w is not None]
    assert len(whole) == 3 and join.drops.counts() == {}
    for w in whole:
        assert w.jpeg[:2] == b"\xff\xd8" and w.jpeg[-2:] == b"\xff\xd9" and w.parts == 1
    first = frames[: frames[0].parts]
    assert [f.part for f in first] == list(range(len(first)))
    assert [f.seq for f in first] == list(range(first[0].seq, first[0].seq + len(first)))
    assert all(len(f.jpeg) <= part_bits / 8 for f in first)
    # paced at the budget: each part leaves at least its own time at the budget after the last
    times = [t for t, f in sent[: len(first)]]
    for i in range(1, len(first)):
        assert times[i] - times[i - 1] >= 0.9 * 8 * (len(first[i - 1].jpeg) + 120) / budget


def test_without_a_part_limit_a_frame_goes_whole() -> None:
    sent = _stream(400_000.0, None, frames=2)
    assert [f.parts for _, f in sent] == [1, 1]


def test_parts_are_never_smaller_than_the_minimum() -> None:
    sent = _stream(400_000.0, 1.0, frames=1)
    frames = [f for _, f in sent]
    assert len(frames) > 1 and all(len(f.jpeg) >= MIN_PART_BYTES for f in frames[:-1])


def test_the_budget_gives_parts_only_where_a_frame_would_hold_the_uplink() -> None:
    t = [0.0]
    b = UplinkBudget(lambda: t[0])
    assert b.part_bits_max() == pytest.approx(64_000.0 * b.part_s)  # the start: against its budget
    b.start_budget_bps = None
    assert b.part_bits_max() is None  # a path that never queued: whole frames
    b.capacity_bps, b.ceiling_bps = 600_000.0, 500_000.0
    assert b.part_bits_max() == pytest.approx(500_000.0 * b.part_s)


def _part(seq: int, part: int, parts: int, jpeg: bytes = b"ab", **kw: object) -> VideoFrame:
    return VideoFrame(sid=7, seq=seq, t=1.0, jpeg=jpeg, part=part, parts=parts, t_capture=0.5, **kw)  # type: ignore[arg-type]


def test_the_assembler_counts_what_does_not_continue_a_frame() -> None:
    join = FrameAssembler(DropCounter("test"))
    assert join.add(_part(1, 0, 2)) is None
    assert join.add(_part(3, 0, 2)) is None  # a newer frame overtook seq 1's
    assert join.add(_part(5, 1, 2)) is None  # no first part of seq 4
    assert join.add(_part(6, 0, 2)) is None
    assert join.add(_part(7, 1, 2, width=160)) is None  # another header
    assert join.add(_part(8, 2, 2)) is None  # part not below parts
    assert join.add(_part(9, 0, 3)) is None
    assert join.add(_part(10, 2, 3)) is None  # skips part 1
    assert join.drops.counts() == {"video_incomplete": 3, "video_bad_part": 4}  # a skipped part: both
    assert join.add(_part(11, 0, 2, b"12")) is None
    whole = join.add(_part(12, 1, 2, b"34"))
    assert whole is not None and (whole.seq, whole.jpeg, whole.parts, whole.part) == (11, b"1234", 1, 0)
    whole1 = _part(13, 0, 1)
    assert join.add(whole1) is whole1


def test_the_assembler_bounds_a_frame_at_the_jpeg_limit() -> None:
    join = FrameAssembler(DropCounter("test"))
    big = b"x" * (MAX_JPEG_BYTES // 2 + 1)
    assert join.add(_part(1, 0, 3, big)) is None
    assert join.add(_part(2, 1, 3, big)) is None  # past MAX_JPEG_BYTES: the frame is dropped
    assert join.drops.counts() == {"video_bad_part": 1}
    assert join.add(_part(3, 2, 3, b"x")) is None


def _gated(open_after: int | None) -> tuple[list[VideoFrame], list[int], VideoStreamer]:
    """One frame in parts through an uplink whose valve closes once the first part left and
    opens ``open_after`` asks later (None: never)."""
    sent: list[VideoFrame] = []
    asks: list[int] = []

    def admit(nbytes: int) -> bool:
        asks.append(nbytes)
        closed = bool(sent) and (open_after is None or len([a for a in asks if a == 0]) <= open_after)
        return not closed

    v = VideoStreamer(Cam(), ["head"], 5.0, sent.append, now=lambda: 0.0, admit=admit)  # type: ignore[arg-type]
    v.set_budget(2_000_000.0, None, 8_000.0)
    with v:
        v.maybe_capture(0.0)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and v.stats["published"] + v.stats["parts_dropped"] == 0:
            time.sleep(0.005)
    return sent, asks, v


def test_a_frames_later_parts_wait_while_the_uplinks_valve_is_closed() -> None:
    """Once a frame began, the valve closing (the feedback's one-way queue over 30 ms) held
    nothing of it: every part left, paced, into the queue the valve saw. Each later part
    now asks the uplink and waits; a frame the valve holds over 0.5 s loses its rest."""
    sent, asks, v = _gated(open_after=5)
    assert v.stats["published"] == 1 and sent[0].parts > 1 and len(sent) == sent[0].parts
    assert asks[0] > 0 and asks.count(0) > 5  # the frame's size once, then each later part waited
    sent, asks, v = _gated(open_after=None)
    assert v.stats["published"] == 0 and len(sent) == 1 and v.stats["parts_dropped"] == sent[0].parts - 1
    assert 40 <= asks.count(0) <= 60  # asked every 10 ms for 0.5 s
