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
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np
from bipedtele.follower.robot import Camera, FollowerRobot
from bipedtele.messages import VideoFrame, new_session_id

__all__ = ["VideoStreamer"]

LOG = logging.getLogger(__name__)

_LOG_EVERY_S = 10.0  # at most one camera-error line per this many seconds


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
    ) -> None:
        self.robot = robot
        self.cameras = list(cameras)
        self.period = 1.0 / fps if fps > 0 else 0.0
        self._publish = publish
        self._now = now
        self._quality = int(jpeg_quality)
        self._sid = new_session_id()
        self._seq = 0
        self._next = {cam: -float("inf") for cam in self.cameras}
        self._slot: tuple[str, np.ndarray, float] | None = None
        self._cv = threading.Condition()
        self._stop = False
        self._thread: threading.Thread | None = None
        self.stats: dict[str, Any] = {
            "captured": 0, "published": 0, "dropped": 0, "errors": 0, "capture_s": 0.0, "encode_s": 0.0,
        }
        self._next_log = -float("inf")
        self._unlogged = 0

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
        """Capture the cameras that are due at loop time ``t`` [s] (cheap when none is)."""
        if not self.period:
            return
        for cam in self.cameras:
            if t < self._next[cam]:
                continue
            self._next[cam] = max(t, self._next[cam] + self.period)
            t0 = time.perf_counter()
            try:
                image = self.robot.capture(cam)
                if image is not None:
                    _check_image(image)
            except Exception as exc:  # a camera fault costs this frame, never the loop
                self.stats["capture_s"] += time.perf_counter() - t0
                self._error(cam, exc)
                continue
            self.stats["capture_s"] += time.perf_counter() - t0
            if image is None:
                continue
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
            try:
                ok, buf = cv2.imencode(
                    ".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self._quality]
                )
            except cv2.error as exc:
                ok, buf = False, None
                LOG.debug("JPEG encoding: %s", exc)
            self.stats["encode_s"] += time.perf_counter() - t0
            if not ok or buf is None:
                self._error(cam, RuntimeError("JPEG encoding failed"))
                continue
            self._seq += 1
            frame = VideoFrame(
                sid=self._sid,
                seq=self._seq,
                t=self._now(),
                camera=cam,
                width=int(image.shape[1]),
                height=int(image.shape[0]),
                t_capture=t_capture,
                jpeg=buf.tobytes(),
            )
            try:
                self._publish(frame)
                self.stats["published"] += 1
            except Exception:  # a transport hiccup must not kill the video thread
                LOG.exception("publishing a video frame failed")


def _check_image(image: Any) -> None:
    """Raise ValueError unless ``image`` is an H x W x 3 uint8 array."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape:
        what = f"{type(image).__name__} {getattr(image, 'shape', '')} {getattr(image, 'dtype', '')}".strip()
        raise ValueError(f"the robot gave {what}: expected an H x W x 3 uint8 image")
