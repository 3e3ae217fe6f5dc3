"""Camera streaming that never stalls the control loop.

The loop calls :meth:`VideoStreamer.maybe_capture` every tick; at the configured rate it
grabs an RGB image from the robot (on the loop's thread: pybullet is single-threaded per
client) and hands it to a worker thread that encodes JPEG and publishes. The hand-over is
a slot of one: if the worker is still busy with the previous frame, the new one replaces
it and the older is dropped (counted). Latest-only, like the video key's QoS.

A camera fault costs frames, never the control loop: a capture that raises (a robot
answer the bridge cannot decode, a camera that is busy or gone) or returns something that
is not an H x W x 3 uint8 image is skipped and counted (``errors``), and logged at most
every ``_LOG_EVERY_S`` seconds; an encoding failure is counted the same way.

A budget (:meth:`VideoStreamer.set_budget`, bits/s; None: unlimited) makes the streamer
fit the uplink: it picks a level (JPEG quality and size, QVGA down to QQVGA, see
``LEVELS``; no level whose frames exceed the largest frame the uplink takes in one burst)
and a frame rate from the measured frame sizes, preferring at least
``_GOOD_FPS`` frames/s per camera before quality (fewer where the next lower level at its
most frames would leave budget unused: video sends its whole budget below the top level,
so that the uplink's capacity probe is tested as it grows), down to 1 frame/s at the lowest level,
and off only when even that does not fit; a token bucket (rate: the budget) makes sure
it never sends faster than the budget (a frame without tokens is dropped, ``throttled``).
A frame larger than the uplink takes in ``part_bits_max`` goes in parts
(``VideoFrame.part`` of ``parts``) paced at the budget, so that the feedback behind it
waits for one part, not the whole frame (the leader joins them: leader/videoparts.py);
each later part waits while the uplink does not take it (its valve: ``admit``), up to
``_PART_WAIT_S``, and then the rest of the frame is dropped (``parts_dropped``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np
from bipedtele.follower.robot import Camera, FollowerRobot
from bipedtele.link.messages import MAX_VIDEO_PARTS, VideoFrame, new_session_id

__all__ = ["VideoStreamer"]

LOG = logging.getLogger(__name__)

_LOG_EVERY_S = 10.0  # at most one camera-error line per this many seconds
_GOOD_FPS = 5.0  # frames/s per camera kept before quality is
_UNUSED = 0.1  # share of the budget a level at its most frames may leave unused (the uplink's margin)
_CHOOSE_EVERY_S = 1.0  # the level is chosen again at most this often [s]
_OVERHEAD_BYTES = 120  # a VideoFrame's fields and MAC around the JPEG [bytes]
MIN_PART_BYTES = 600  # a frame is not cut into parts smaller than this [bytes of JPEG]
_PART_WAIT_S = 0.5  # a frame's next part waits for the uplink this long at most, then the rest is dropped [s]
_PART_POLL_S = 0.01  # it asks the uplink again this often while it waits [s]

#: Levels, best first: (size scale, JPEG quality relative to the configured one, lowest
#: absolute quality) and the expected frame size relative to level 0 until measured.
#: The 0.7 size level (224 x 168) sits between QVGA and QQVGA: without it QQVGA at 10
#: frames/s per camera sent 0.2 x 10 of a QVGA frame and QVGA at 5 frames/s 0.55 x 5.
LEVELS: tuple[tuple[float, float, float], ...] = (
    (1.0, 1.0, 1.0),
    (1.0, 0.6, 0.55),
    (0.7, 0.6, 0.33),
    (0.5, 0.6, 0.2),
    (0.5, 0.3, 0.13),
    (0.5, 0.125, 0.09),
)


class VideoStreamer:
    """Capture on the loop thread, encode and publish on a worker thread.

    Parameters
    ----------
    robot : FollowerRobot
        Source of images (``capture(camera)``).
    cameras : sequence of str
        Cameras to stream (``head``, ``scene``); each at ``fps``.
    fps : float
        Frames per second per camera [Hz]; 0 disables video.
    publish : callable
        ``publish(VideoFrame)``, called on the worker thread.
    now : callable
        Clock for frame times [s].
    jpeg_quality : int
        JPEG quality (10-100).
    sid : int, optional
        The frames' session id (default: a new one).
    admit : callable, optional
        ``admit(nbytes) -> bool``: may a frame of ``nbytes`` [bytes] leave now (the uplink's
        in-flight cap, :class:`~bipedtele.follower.delivery.InFlight`, and its valve)? A
        frame refused is dropped and counted (``held``): the next one is newer. A frame's
        later parts each ask ``admit(0)`` and wait, asked again every 10 ms, up to 0.5 s;
        then the rest is dropped (``parts_dropped``). None: always.
    """

    def __init__(
        self,
        robot: FollowerRobot,
        cameras: Sequence[Camera],
        fps: float,
        publish: Callable[[VideoFrame], None],
        *,
        now: Callable[[], float] = time.time,
        jpeg_quality: int = 80,
        sid: int | None = None,
        admit: Callable[[int], bool] | None = None,
    ) -> None:
        self.robot = robot
        self.cameras = list(cameras)
        self.period = 1.0 / fps if fps > 0 else 0.0
        self._publish = publish
        self._admit = admit  # the uplink's in-flight cap: may a frame of N bytes leave now?
        self._now = now
        self._quality = int(jpeg_quality)
        self._sid = new_session_id() if sid is None else int(sid)  # the node's: the leader shows its bound peer's only
        self._seq = 0
        self._next = -float("inf")  # the next capture [s]
        self._turn = 0  # the cameras take turns
        self._slot: tuple[str, np.ndarray, float] | None = None
        self._cv = threading.Condition()
        self._stop = False
        self._thread: threading.Thread | None = None
        self.stats: dict[str, Any] = {
            "captured": 0,
            "published": 0,
            "parts": 0,
            "dropped": 0,
            "errors": 0,
            "capture_s": 0.0,
            "encode_s": 0.0,
        }
        self._next_log = -float("inf")
        self._unlogged = 0
        self.max_fps = float(fps)
        self.stats["throttled"] = 0
        self.stats["held"] = 0
        self.stats["parts_dropped"] = 0
        self._budget: float | None = None
        self._frame_bits_max: float | None = None
        self._part_bits_max: float | None = None
        self._level = 0
        self._fps = float(fps)
        self._frame_bits: dict[int, float] = {}  # measured bits per frame by level (EWMA)
        self._most_bps = self._most()  # what video sends at its most [bit/s], kept as frames are measured
        self._tokens = 0.0
        self._t_tokens: float | None = None
        self._next_choose = -float("inf")
        self._sent_times: list[float] = []
        #: Width of the last frame sent [px].
        self.width_sent = 0

    def __enter__(self) -> VideoStreamer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        """Start the encoder thread (no-op when video is disabled)."""
        if self.period and self._thread is None:
            self._thread = threading.Thread(target=self._run, name="video-encoder", daemon=True)
            self._thread.start()

    def close(self) -> None:
        """Stop the encoder thread and wait for it."""
        with self._cv:
            self._stop = True
            self._cv.notify()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def maybe_capture(self, t: float) -> None:
        """Capture the camera that is due at loop time ``t`` [s] (cheap when none is)."""
        if not self.period or not self.cameras:
            return
        if self._budget is not None and t >= self._next_choose:
            self._next_choose = t + _CHOOSE_EVERY_S
            self._choose()
        if self._fps <= 0:
            return
        if t < self._next:
            return
        # the cameras take turns, spaced evenly: two frames captured in one tick left back to
        # back, and the second found no tokens when a frame was over half the bucket
        self._next = max(t, self._next + 1.0 / (self._fps * len(self.cameras)))
        cam = self.cameras[self._turn % len(self.cameras)]
        self._turn += 1
        t0 = time.perf_counter()
        try:
            image = self.robot.capture(cam)
            if image is not None:
                _check_image(image)
        except Exception as exc:  # a camera fault costs this frame, never the loop
            self.stats["capture_s"] += time.perf_counter() - t0
            self._error(cam, exc)
            return
        self.stats["capture_s"] += time.perf_counter() - t0
        if image is None:
            return
        self.stats["captured"] += 1
        with self._cv:
            if self._slot is not None:
                self.stats["dropped"] += 1
            self._slot = (cam, image, self._now())
            self._cv.notify()

    def _error(self, cam: str, exc: BaseException) -> None:
        """Count a lost frame; log the first and then at most one line per ``_LOG_EVERY_S``."""
        self.stats["errors"] += 1
        now = time.monotonic()
        if now < self._next_log:
            self._unlogged += 1
            return
        self._next_log = now + _LOG_EVERY_S
        more = f" (+{self._unlogged} more since the last line)" if self._unlogged else ""
        self._unlogged = 0
        LOG.warning("camera %s: frame skipped: %s%s; %d frames lost so far", cam, exc, more, self.stats["errors"])

    def _run(self) -> None:
        while True:
            with self._cv:
                while self._slot is None and not self._stop:
                    self._cv.wait()
                if self._stop:
                    return
                assert self._slot is not None
                cam, image, t_capture = self._slot
                self._slot = None
            t0 = time.perf_counter()
            with self._cv:
                level = self._level
            scale, _, _ = LEVELS[level]
            quality = self.quality_at(level)
            try:
                bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
                if scale != 1.0:
                    h, w = bgr.shape[:2]
                    bgr = cv2.resize(
                        bgr, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA
                    )
                ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
            except cv2.error as exc:
                ok, buf = False, None
                LOG.debug("JPEG encoding: %s", exc)
            self.stats["encode_s"] += time.perf_counter() - t0
            if not ok or buf is None:
                self._error(cam, RuntimeError("JPEG encoding failed"))
                continue
            jpeg = buf.tobytes()
            bits = 8.0 * (len(jpeg) + _OVERHEAD_BYTES)
            if self._admit is not None and not self._admit(int(bits / 8.0)):
                self.stats["held"] += 1  # the uplink holds its cap in flight: the next frame is newer
                continue
            if not self._spend(level, bits):
                self.stats["throttled"] += 1
                continue
            with self._cv:
                cuts = _cut(jpeg, self._part_bits_max)
                pace_bps = self._budget if len(cuts) > 1 else None
            if self._send(cam, bgr.shape[1], bgr.shape[0], t_capture, cuts, pace_bps):
                self.stats["published"] += 1
                self.stats["parts"] += len(cuts)
                with self._cv:
                    self._sent_times.append(self._now())
                    self.width_sent = bgr.shape[1]
            elif self._stop:
                return

    def _send(
        self, cam: str, width: int, height: int, t_capture: float, cuts: list[bytes], pace_bps: float | None
    ) -> bool:
        """Publish a frame's parts, paced at ``pace_bps`` [bit/s], each after the uplink takes it; True when all left."""
        first = self._seq + 1
        self._seq += len(cuts)
        for i, piece in enumerate(cuts):
            if i and pace_bps:
                # paced at video's budget: the uplink's queue holds at most about one
                # part ahead of the feedback, never a whole frame
                gap = 8.0 * (len(cuts[i - 1]) + _OVERHEAD_BYTES) / pace_bps
                with self._cv:
                    if self._cv.wait_for(lambda: self._stop, timeout=gap):
                        return False
            if i and not self._part_admitted():
                self.stats["parts_dropped"] += len(cuts) - i  # the rest of a frame the uplink did not take
                return False
            frame = VideoFrame(
                sid=self._sid,
                seq=first + i,
                t=self._now(),
                camera=cam,
                width=width,
                height=height,
                t_capture=t_capture,
                jpeg=piece,
                part=i,
                parts=len(cuts),
            )
            try:
                self._publish(frame)
            except Exception:  # a transport hiccup must not kill the video thread
                LOG.exception("publishing a video frame failed")
                return False
        return True

    def _part_admitted(self) -> bool:
        """Wait until the uplink takes a frame's next part (``admit(0)``), at most ``_PART_WAIT_S``; False: it did not, or stop.

        A frame's parts were paced but not held: once a frame began, the valve closing
        (the feedback's one-way queue over 30 ms) stopped nothing of it.
        """
        if self._admit is None:
            return True
        for _ in range(round(_PART_WAIT_S / _PART_POLL_S)):
            if self._admit(0):
                return True
            with self._cv:
                if self._cv.wait_for(lambda: self._stop, timeout=_PART_POLL_S):
                    return False
        return self._admit(0)

    # ------------------------------------------------------------------ budget

    def quality_at(self, level: int) -> int:
        """JPEG quality of ``level`` (10-100)."""
        _, rel, _ = LEVELS[level]
        return int(min(100, max(10, round(self._quality * rel))))

    def set_budget(
        self, bps: float | None, frame_bits_max: float | None = None, part_bits_max: float | None = None
    ) -> None:
        """Set video's budget [bit/s] (None: unlimited, the configured rate and quality).

        ``frame_bits_max`` [bit]: levels whose frames are larger are not chosen (the
        lowest level always may be), so that one frame does not hold a slow uplink long.
        ``part_bits_max`` [bit]: a larger frame is sent in parts of at most this size
        (never under ``MIN_PART_BYTES`` of JPEG), paced at the budget (None: whole).
        """
        with self._cv:
            self._frame_bits_max = None if frame_bits_max is None else max(0.0, float(frame_bits_max))
            self._part_bits_max = None if part_bits_max is None else max(0.0, float(part_bits_max))
            was, self._budget = self._budget, (None if bps is None else max(0.0, float(bps)))
            if self._budget is None:
                self._level, self._fps = 0, self.max_fps
        now = self._budget
        if (was is None and now is not None) or (was is not None and was <= 0.0) != (now is not None and now <= 0.0):
            # a budget from none, or video paused (0) or resumed (a stall of the uplink and
            # its end): choose at the next capture, not up to a second later
            self._next_choose = -float("inf")

    def frame_bits(self, level: int) -> float:
        """Return the expected bits per frame at ``level``: measured there, else scaled from a measured level."""
        with self._cv:
            return _bits_at(level, self._frame_bits)

    def most_bps(self) -> float:
        """Return what video sends at its most [bit/s]: every camera at the configured rate at the top level (0 when off).

        Kept as frames are measured (the control loop reads it every tick, without the lock).
        """
        return self._most_bps

    def _most(self) -> float:
        """Compute :meth:`most_bps` from the measured frames (with the lock held, or before the thread starts)."""
        return self.max_fps * len(self.cameras) * _bits_at(0, self._frame_bits) if self.period else 0.0

    def _choose(self) -> None:
        """Pick the level and frame rate that fit the budget (see the module docstring)."""
        budget = self._budget
        if budget is None:
            return
        per_cam = budget / max(1, len(self.cameras))
        largest = self._frame_bits_max
        best: tuple[int, float] | None = None
        for level in range(len(LEVELS)):
            if largest is not None and self.frame_bits(level) > largest:
                continue
            fps = min(self.max_fps, per_cam / self.frame_bits(level))
            # the next lower level at its most frames would leave over _UNUSED of the budget
            # unused: this one below 5 frames/s sends it all (a budget no level can use
            # leaves the capacity probe untested, and the step to the next level comes at once)
            lower_most = self.max_fps * self.frame_bits(level + 1) if level + 1 < len(LEVELS) else math.inf
            if fps >= min(self.max_fps, _GOOD_FPS) or (lower_most < (1.0 - _UNUSED) * per_cam and fps >= 1.0):
                best = (level, fps)
                break
        if best is None:
            last = len(LEVELS) - 1
            fps = min(self.max_fps, per_cam / self.frame_bits(last))
            best = (last, fps if fps >= 1.0 else 0.0)
        with self._cv:
            self._level, self._fps = best

    def _spend(self, level: int, bits: float) -> bool:
        """Token bucket: take ``bits`` if the budget allows (always when unlimited)."""
        with self._cv:
            old = self._frame_bits.get(level)
            self._frame_bits[level] = bits if old is None else 0.7 * old + 0.3 * bits
            self._most_bps = self._most()
            budget = self._budget
            now = self._now()
            if budget is None:
                self._t_tokens = None
                return True
            # at most 0.1 s of budget at once (0.5 s queued 25 kB, 330 ms, at 600 kbit/s)
            depth = max(0.1 * budget, 1.5 * bits)
            if self._t_tokens is None:
                self._tokens = depth
            else:
                self._tokens = min(depth, self._tokens + budget * max(0.0, now - self._t_tokens))
            self._t_tokens = now
            if self._tokens < bits:
                return False
            self._tokens -= bits
            return True

    def counters(self, window_s: float = 2.0) -> dict[str, int]:
        """``video_fps_x10`` (frames/s x 10 sent over the last ``window_s``), ``video_quality``, ``video_width``."""
        now = self._now()
        with self._cv:
            self._sent_times = [t for t in self._sent_times if t > now - window_s]
            n = len(self._sent_times)
            level, fps = self._level, self._fps
            width = self.width_sent
        on = self.period > 0 and fps > 0
        return {
            "video_fps_x10": round(10 * n / window_s),
            "video_quality": self.quality_at(level) if on else 0,
            "video_width": int(width) if on else 0,
        }


def _bits_at(level: int, measured: dict[int, float]) -> float:
    """Return the expected bits per frame at ``level`` from the ``measured`` ones (by level): there, else scaled from the nearest.

    The nearest measured level, not the first: on the LTE row the first was the start's
    QQVGA at quality 10, and QVGA at quality 80 scaled from it came to 6.7 kB where
    QVGA at 48 measured 2.6 kB (0.55 of it: 4.7 kB), over the largest frame the uplink
    took, so the top level was never tried.
    """
    if level in measured:
        return measured[level]
    if measured:
        ref = min(measured, key=lambda k: (abs(k - level), k))
        return measured[ref] * LEVELS[level][2] / LEVELS[ref][2]
    return 8.0 * 12_000 * LEVELS[level][2]  # a QVGA frame at quality 80: about 12 kB


def _cut(jpeg: bytes, part_bits_max: float | None) -> list[bytes]:
    """Cut ``jpeg`` into the fewest near-equal parts of at most ``part_bits_max`` [bit] each.

    A part carries at least ``MIN_PART_BYTES`` of JPEG (each message has its own
    overhead) and a frame at most ``MAX_VIDEO_PARTS`` parts; None: one part.
    """
    if part_bits_max is None:
        return [jpeg]
    per = max(MIN_PART_BYTES, int(part_bits_max / 8.0) - _OVERHEAD_BYTES)
    n = min(MAX_VIDEO_PARTS, -(-len(jpeg) // per), len(jpeg) // MIN_PART_BYTES)
    n = max(1, n)
    step = -(-len(jpeg) // n)
    return [jpeg[i : i + step] for i in range(0, len(jpeg), step)] or [jpeg]


def _check_image(image: Any) -> None:
    """Raise ValueError unless ``image`` is an H x W x 3 uint8 array."""
    if (
        not isinstance(image, np.ndarray)
        or image.dtype != np.uint8
        or image.ndim != 3
        or image.shape[2] != 3
        or 0 in image.shape
    ):
        what = f"{type(image).__name__} {getattr(image, 'shape', '')} {getattr(image, 'dtype', '')}".strip()
        raise ValueError(f"the robot gave {what}: expected an H x W x 3 uint8 image")
