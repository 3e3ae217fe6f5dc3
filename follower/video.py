"""Camera streaming that never stalls the control loop.

The loop calls :meth:`VideoStreamer.maybe_capture` every tick; at the configured rate it
grabs an RGB image from the robot (on the loop's thread: pybullet is single-threaded per
client) and hands it to a worker thread that encodes JPEG and publishes. The hand-over is
a slot of one: if the worker is still busy with the previous frame, the new one replaces
it and the older is dropped (counted). Latest-only, like the video key's QoS.
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
        self.stats: dict[str, Any] = {"captured": 0, "published": 0, "dropped": 0, "capture_s": 0.0, "encode_s": 0.0}

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
            image = self.robot.capture(cam)
            self.stats["capture_s"] += time.perf_counter() - t0
            if image is None:
                continue
            self.stats["captured"] += 1
            with self._cv:
                if self._slot is not None:
                    self.stats["dropped"] += 1
                self._slot = (cam, image, self._now())
                self._cv.notify()

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
            ok, buf = cv2.imencode(
                ".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self._quality]
            )
            self.stats["encode_s"] += time.perf_counter() - t0
            if not ok:
                LOG.warning("JPEG encoding failed for a %s frame", cam)
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
