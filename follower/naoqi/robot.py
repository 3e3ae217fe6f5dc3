"""``NaoqiRobot``: the follower-robot contract over a real NAO's NAOqi services.

Services used (NAOqi 2.x names and signatures):

- ``ALMotion``: ``wakeUp()``, ``move(x, y, theta, moveConfig)`` (SI units, FRAME_ROBOT),
  ``stopMove()``, ``moveIsActive()``, ``getRobotVelocity()`` -> [vx m/s, vy m/s, w rad/s],
  ``getRobotPosition(useSensors)`` -> [x m, y m, theta rad] (odometry).
- ``ALRobotPosture``: ``goToPosture("StandInit", speed)`` -> bool.
- ``ALMemory``: ``getListData(keys)`` for the two sonar ranges [m]
  (``Device/SubDeviceList/US/{Left,Right}/Sensor/Value``) and the torso angles [rad]
  (``Device/SubDeviceList/InertialSensor/Angle{X,Y}/Sensor/Value``).
- ``ALSonar``: ``subscribe(name)`` / ``unsubscribe(name)`` (the sonars only update while
  someone is subscribed).
- ``ALVideoDevice``: ``subscribeCamera(name, 0, 1, 11, fps)`` (top camera, kQVGA,
  kRGBColorSpace), ``getImageRemote(handle)``, ``unsubscribe(handle)``.

Every call waits at most ``call_timeout_s``; a call that fails or answers garbage raises
:class:`RobotError` with a message saying what happened and what to do. A call that
*times out* is not a lost link (NAOqi may be busy, the network slow): the link counts as
lost only when the qi session says it is disconnected. ``stop()`` never raises once
connected. A vanished robot cannot be stopped through the dead session: ``disconnect()``
then tries ``stopMove`` over a fresh session, and ``connect()`` / ``reconnect()`` stop it
first thing when the link is back.

NAO keeps its last ``move`` when nobody stops it (NAOqi has no client watchdog), so the
bridge heartbeats the ``BipedteleGuard`` service (:mod:`.guardlink`, :mod:`.nao_guard`),
which calls ``stopMove`` when the heartbeats stop, and refuses to walk
(:class:`WalkRefusedError`, the robot stands) while no guard answers, unless
``allow_unguarded`` (``--unguarded-robot-may-keep-walking``).
"""

from __future__ import annotations

import logging
import math
import os
import socket
import threading
import time
from typing import Any, ClassVar

import numpy as np
from bipedtele.config.profile import Config, resolve_section
from bipedtele.follower.naoqi.answers import as_bool, as_floats, decode_image
from bipedtele.follower.naoqi.config import NaoqiConfig
from bipedtele.follower.naoqi.gait import move_config_for, walk_limits
from bipedtele.follower.naoqi.guardlink import GuardLink
from bipedtele.follower.naoqi.session import open_session
from bipedtele.follower.odometry import StepSampler
from bipedtele.follower.robot import (
    Camera,
    FollowerRobot,
    Footfall,
    RobotError,
    RobotNotConnectedError,
    RobotObservation,
    WalkCommand,
    WalkRefusedError,
)

__all__ = ["MEMORY_KEYS", "NaoqiRobot"]

LOG = logging.getLogger(__name__)

#: ALMemory keys read by :meth:`NaoqiRobot.observe`, in this order.
MEMORY_KEYS = (
    "Device/SubDeviceList/US/Left/Sensor/Value",
    "Device/SubDeviceList/US/Right/Sensor/Value",
    "Device/SubDeviceList/InertialSensor/AngleX/Sensor/Value",
    "Device/SubDeviceList/InertialSensor/AngleY/Sensor/Value",
)

_REQUIRED = ("ALMotion", "ALMemory", "ALRobotPosture")
_OPTIONAL = ("ALSonar", "ALVideoDevice")
_TOP_CAMERA, _K_QVGA, _K_RGB = 0, 1, 11


class NaoqiRobot(FollowerRobot):
    """A real NAO through NAOqi (``--robot naoqi``: its part is in :mod:`bipedtele.follower.naoqi.config`).

    Parameters
    ----------
    config : NaoqiConfig or Config, optional
        The ``[naoqi]`` section (or a whole profile holding it); defaults otherwise.
    **overrides
        Fields of :class:`NaoqiConfig` to change, e.g. ``url="tcp://10.0.0.5:9559"``.

    Raises
    ------
    ConfigError
        An override is not a field or not allowed.
    """

    name: ClassVar[str] = "naoqi"

    def __init__(self, config: NaoqiConfig | Config | None = None, **overrides: Any) -> None:
        cfg = resolve_section(config, NaoqiConfig, "naoqi", overrides)
        self.config = cfg
        self.limits = walk_limits(cfg)
        self._lock = threading.RLock()
        self._session: Any = None
        self._proxies: dict[str, Any] = {}
        self._lost = False
        self._origin = (0.0, 0.0, 0.0)
        self._video_handle: str | None = None
        self._sonar_subscribed = False
        self._warned: set[str] = set()
        self._guard: GuardLink | None = None
        self._refusing = False
        self._activity = time.monotonic()
        self._steps = StepSampler()
        self._step_s = 0.0  # step period of the last move sent [s]; 0 before the first
        self.owner = f"{socket.gethostname()}:{os.getpid()}"

    # ------------------------------------------------------------------ connection

    @property
    def is_connected(self) -> bool:
        """True between a successful ``connect()`` and ``disconnect()`` while the link holds."""
        return self._session is not None and not self._lost

    def connect(self) -> None:
        """Reach NAOqi, stop any walk, wake the robot up and stand it in StandInit.

        Connecting again after the robot vanished drops the dead session first.

        Raises
        ------
        RobotError
            The robot cannot be reached, lacks a service, or cannot stand.
        """
        with self._lock:
            if self.is_connected:
                return
            self._release(quiet=True)
            cfg = self.config
            session = open_session(cfg.url, cfg.user, cfg.resolved_password(), cfg.connect_timeout_s)
            self._session, self._lost = session, False
            try:
                self._proxies = {name: self._service(name, required=True) for name in _REQUIRED}
                for name in _OPTIONAL:
                    proxy = self._service(name, required=False)
                    if proxy is not None:
                        self._proxies[name] = proxy
                self._call("ALMotion", "stopMove")
                self._call("ALMotion", "wakeUp", timeout_s=cfg.posture_timeout_s)
                ok = self._call(
                    "ALRobotPosture", "goToPosture", "StandInit", cfg.posture_speed, timeout_s=cfg.posture_timeout_s
                )
                if not as_bool(ok, "ALRobotPosture.goToPosture('StandInit')"):
                    raise RobotError(
                        f"NAO at {cfg.url} could not reach StandInit: is it lying down or held? stand it up and connect again"
                    )
                if "ALSonar" in self._proxies:
                    self._call("ALSonar", "subscribe", cfg.client_name)
                    self._sonar_subscribed = True
                else:
                    self._warn_once("sonar", "NAOqi has no ALSonar service: sonar values may be stale")
                pos = as_floats(
                    self._call("ALMotion", "getRobotPosition", cfg.use_sensors), 3, "ALMotion.getRobotPosition"
                )
                self._origin = (pos[0], pos[1], pos[2])
                self._start_guard()
            except BaseException:
                self._release(quiet=True)
                raise
            LOG.info("connected to NAO at %s (standing, sonar %s m)", cfg.url, cfg.sonar_range_m)

    def _start_guard(self) -> None:
        cfg = self.config
        self._activity = time.monotonic()
        guard = GuardLink(
            self._session,
            self.owner,
            1.0 / cfg.guard_heartbeat_hz,
            min(cfg.call_timeout_s, 0.25),
            lambda: self._activity,
        )
        self._guard = guard
        if guard.probe():
            LOG.info(
                "NAO guard answers (%s): it stops NAO %.2f s after the last heartbeat",
                guard.version,
                guard.lapse_s or 0.0,
            )
        elif cfg.allow_unguarded:
            LOG.warning(
                "no BipedteleGuard answers on %s and allow_unguarded is set: if this follower dies or loses "
                "the robot's network, NAO keeps walking its last move",
                cfg.url,
            )
        else:
            LOG.error("%s", self._refusal_text())
        guard.start()

    def _refusal_text(self) -> str:
        url = self.config.url
        return (
            f"refusing to walk NAO at {url}: no BipedteleGuard answers (the watchdog beside the robot that stops it "
            f"if this follower dies); start one with `bipedtele nao-guard --naoqi-url {url}` or put "
            "nao_guard.py on the robot (docs/hardware.md), or accept the risk with --unguarded-robot-may-keep-walking"
        )

    def _guard_beat_now(self) -> bool:
        """After a stall of the loop the heartbeats paused: one now, before refusing."""
        return self._guard is not None and self._guard.beat_now()

    @property
    def guarded(self) -> bool:
        """True while a BipedteleGuard acknowledges the heartbeats."""
        return self._guard is not None and self._guard.answered

    def reconnect(self, timeout_s: float | None = None, stop: threading.Event | None = None) -> None:
        """Try ``connect()`` until it works, waiting longer between tries (doubling).

        Parameters
        ----------
        timeout_s : float, optional
            Give up after this long [s] (default: ``reconnect_timeout_s``).
        stop : threading.Event, optional
            Give up as soon as it is set (program shutdown).

        Raises
        ------
        RobotError
            Still unreachable after ``timeout_s`` (or ``stop`` was set).
        """
        limit = self.config.reconnect_timeout_s if timeout_s is None else timeout_s
        first, largest = self.config.reconnect_backoff_s
        deadline = time.monotonic() + limit
        wait, tries = first, 0
        while True:
            tries += 1
            try:
                self.connect()
                LOG.info("reconnected to NAO at %s after %d tries", self.config.url, tries)
                return
            except RobotError as exc:
                left = deadline - time.monotonic()
                if left <= 0 or (stop is not None and stop.is_set()):
                    raise RobotError(
                        f"NAO at {self.config.url} still unreachable after {tries} tries over {limit:.0f} s: {exc}"
                    ) from None
                LOG.info("NAO not back yet (%s); retrying in %.1f s", exc, min(wait, left))
                if stop is not None:
                    if stop.wait(min(wait, left)):
                        raise RobotError(f"reconnect to {self.config.url} cancelled") from None
                else:
                    time.sleep(min(wait, left))
                wait = min(largest, wait * 2.0)

    def disconnect(self) -> None:
        """Stop walking, drop the camera and sonar subscriptions, close the session. Idempotent."""
        with self._lock:
            if self._session is None:
                return
            if not self._lost:
                self.stop()
            else:
                self._stop_over_new_session()
            self._release(quiet=False)

    def _stop_over_new_session(self) -> None:
        """Try once more to reach NAOqi, just to ``stopMove`` (the link is down at exit)."""
        cfg = self.config
        try:
            session = open_session(cfg.url, cfg.user, cfg.resolved_password(), min(cfg.connect_timeout_s, 2.0))
        except RobotError as exc:
            LOG.error("cannot stop NAO at %s at exit: %s; a running BipedteleGuard stops it", cfg.url, exc)
            return
        try:
            motion = session.service("ALMotion", _async=True).value(int(cfg.call_timeout_s * 1000))
            motion.stopMove(_async=True).value(int(cfg.call_timeout_s * 1000))
            LOG.info("NAO at %s stopped at exit over a new session", cfg.url)
        except RuntimeError as exc:
            LOG.error("cannot stop NAO at %s at exit: %s", cfg.url, exc)
        finally:
            try:
                session.close()
            except RuntimeError as exc:
                LOG.debug("closing the stop session: %s", exc)

    def _release(self, quiet: bool) -> None:
        if self._session is None:
            return
        if self._guard is not None:
            # A clean goodbye releases the guard (we stopped the robot ourselves); a lost
            # link does not: the guard stops the robot.
            self._guard.close(release=not self._lost and not quiet)
            self._guard = None
        if not self._lost:
            if self._video_handle is not None:
                self._try("ALVideoDevice", "unsubscribe", self._video_handle)
            if self._sonar_subscribed:
                self._try("ALSonar", "unsubscribe", self.config.client_name)
        self._video_handle, self._sonar_subscribed = None, False
        try:
            self._session.close()
        except RuntimeError as exc:
            LOG.debug("closing the NAOqi session: %s", exc)
        self._session, self._proxies, self._lost = None, {}, False
        if not quiet:
            LOG.info("disconnected from NAO at %s", self.config.url)

    # ------------------------------------------------------------------ contract

    def observe(self) -> RobotObservation:
        """Velocity and odometry from ALMotion, sonar and torso angles from ALMemory.

        It also samples :meth:`footfall`: the odometry pose read once per step period of
        the last ``move`` while NAO walks (:class:`~bipedtele.follower.odometry.StepSampler`),
        so the report judges NAO's speed per step as it does the simulator's.

        Raises
        ------
        RobotError
            The robot is gone or answered something malformed.
        """
        with self._lock:
            self._require()
            self._activity = time.monotonic()
            t = time.time()
            futs = {
                "vel": self._start("ALMotion", "getRobotVelocity"),
                "pos": self._start("ALMotion", "getRobotPosition", self.config.use_sensors),
                "mem": self._start("ALMemory", "getListData", list(MEMORY_KEYS)),
                "active": self._start("ALMotion", "moveIsActive"),
            }
            vx, _vy, w = as_floats(
                self._wait(futs["vel"], "ALMotion", "getRobotVelocity"), 3, "ALMotion.getRobotVelocity"
            )
            pos = as_floats(self._wait(futs["pos"], "ALMotion", "getRobotPosition"), 3, "ALMotion.getRobotPosition")
            left, right, ax, ay = as_floats(
                self._wait(futs["mem"], "ALMemory", "getListData"), 4, "ALMemory.getListData(sonar, torso angles)"
            )
            walking = as_bool(self._wait(futs["active"], "ALMotion", "moveIsActive"), "ALMotion.moveIsActive")
        tilt = math.acos(max(-1.0, min(1.0, math.cos(ax) * math.cos(ay))))
        pose = self._relative_pose(pos)
        self._steps.update(t, pose, walking, self._step_s)
        return RobotObservation(
            t=t,
            v_hip_m_s=vx,
            turn_rate_rad_s=w,
            pose=pose,
            sonar_m=(self._sonar(left), self._sonar(right)),
            tilt_rad=tilt,
            fallen=tilt > self.config.fall_tilt_rad,
            walking=walking,
        )

    def footfall(self) -> Footfall | None:
        """Return the latest step-period sample of the odometry while walking (None before the first)."""
        return self._steps.footfall

    def send_walk(self, cmd: WalkCommand) -> WalkCommand:
        """``ALMotion.move`` with the move config realising the cycle T of ``cmd``.

        Returns
        -------
        WalkCommand
            What NAO was asked: speeds clipped to the step limits at the realised step
            period, cycle T = 2 step periods. ``eps_s`` is passed through (clamped): NAO's
            joint servos are its own.
        """
        with self._lock:
            self._require()
            self._activity = time.monotonic()
            if not self.config.allow_unguarded and not self.guarded and not self._guard_beat_now():
                if not self._refusing:
                    self._refusing = True
                    LOG.error("%s", self._refusal_text())
                    self._try("ALMotion", "stopMove")
                raise WalkRefusedError(self._refusal_text())
            if self._refusing:
                self._refusing = False
                LOG.warning("NAO guard answers: walking allowed again")
            move, sent = move_config_for(cmd, self.config)
            self._call("ALMotion", "move", move.x_m_s, move.y_m_s, move.theta_rad_s, move.as_naoqi())
            self._step_s = move.step_period_s
            return sent

    def stop(self) -> None:
        """``ALMotion.stopMove()``: NAO finishes its step and stands. Never raises once connected.

        Raises
        ------
        RobotNotConnectedError
            Called before ``connect()``.
        """
        with self._lock:
            if self._session is None:
                raise RobotNotConnectedError("NaoqiRobot.stop() before connect()")
            if self._lost:
                self._warn_once(
                    "stop-lost",
                    f"cannot stop NAO at {self.config.url}: the link is down; it is stopped first thing on reconnect",
                )
                return
            self._try("ALMotion", "stopMove")

    def advance(self, dt: float) -> None:
        """Return at once: a real robot's time passes by itself."""
        self._require()

    def capture(self, camera: Camera = "head") -> np.ndarray | None:
        """Return a QVGA RGB frame (240 x 320 x 3, uint8) from NAO's top camera; ``None`` for ``scene``.

        Raises
        ------
        RobotError
            The robot is gone or the image is malformed.
        """
        if camera != "head":
            return None
        with self._lock:
            self._require()
            if "ALVideoDevice" not in self._proxies:
                self._warn_once("video", "NAOqi has no ALVideoDevice service: no head camera")
                return None
            if self._video_handle is None:
                handle = self._call(
                    "ALVideoDevice",
                    "subscribeCamera",
                    self.config.client_name,
                    _TOP_CAMERA,
                    _K_QVGA,
                    _K_RGB,
                    round(self.config.camera_fps),
                )
                if not isinstance(handle, str) or not handle:
                    raise RobotError(f"ALVideoDevice.subscribeCamera answered {handle!r}: expected a subscriber name")
                self._video_handle = handle
            return decode_image(self._call("ALVideoDevice", "getImageRemote", self._video_handle))

    # ------------------------------------------------------------------ helpers

    def _require(self) -> None:
        if self._session is None:
            raise RobotNotConnectedError("NaoqiRobot: call connect() first")
        if self._lost:
            raise RobotNotConnectedError(
                f"the link to NAO at {self.config.url} is down: call connect() or reconnect() when it is back"
            )

    def _service(self, name: str, required: bool) -> Any:
        try:
            fut = self._session.service(name, _async=True)
            return fut.value(int(self.config.call_timeout_s * 1000))
        except RuntimeError as exc:
            if not self._session.isConnected():
                self._lost = True
                raise RobotError(f"NAO at {self.config.url} vanished while looking up {name}: {exc}") from None
            if required:
                raise RobotError(
                    f"NAOqi at {self.config.url} has no {name} service ({exc}): is this a NAO running NAOqi 2.x?"
                ) from None
            return None

    def _start(self, service: str, method: str, *args: Any) -> Any:
        try:
            return getattr(self._proxies[service], method)(*args, _async=True)
        except RuntimeError as exc:
            raise self._failure(service, method, exc) from None

    def _wait(self, fut: Any, service: str, method: str, timeout_s: float | None = None) -> Any:
        ms = int((self.config.call_timeout_s if timeout_s is None else timeout_s) * 1000)
        try:
            return fut.value(ms)
        except RuntimeError as exc:
            raise self._failure(service, method, exc, ms) from None

    def _call(self, service: str, method: str, *args: Any, timeout_s: float | None = None) -> Any:
        return self._wait(self._start(service, method, *args), service, method, timeout_s)

    def _try(self, service: str, method: str, *args: Any) -> None:
        """Call ``service.method``, logging a failure instead of raising it (shutdown and safety paths)."""
        try:
            self._call(service, method, *args)
        except RobotError as exc:
            LOG.warning("%s", exc)

    def _failure(self, service: str, method: str, exc: Exception, timeout_ms: int | None = None) -> RobotError:
        text = str(exc) or type(exc).__name__
        if not self._session_connected():
            self._lost = True
            return RobotError(
                f"NAO at {self.config.url} is gone ({service}.{method}: {text}); it keeps its last walk command "
                "until the link returns: stop() is safe, call connect() or reconnect() when it is back"
            )
        if "timeout" in text.lower():
            # Slow is not gone: the link stays up and the next call tries again.
            waited = f" after {timeout_ms} ms" if timeout_ms is not None else ""
            return RobotError(
                f"NAOqi call {service}.{method} timed out{waited} (NAO at {self.config.url} is slow or busy; the link is up)"
            )
        return RobotError(f"NAOqi refused {service}.{method}: {text}")

    def _session_connected(self) -> bool:
        if self._session is None:
            return False
        try:
            return bool(self._session.isConnected())
        except RuntimeError:
            return False

    def _relative_pose(self, pos: tuple[float, ...]) -> tuple[float, float, float]:
        x0, y0, th0 = self._origin
        dx, dy = pos[0] - x0, pos[1] - y0
        c, s = math.cos(th0), math.sin(th0)
        yaw = math.atan2(math.sin(pos[2] - th0), math.cos(pos[2] - th0))
        return (c * dx + s * dy, -s * dx + c * dy, yaw)

    def _sonar(self, value: float) -> float:
        lo, hi = self.config.sonar_range_m
        if value <= 0.0 or value >= hi:  # 0: no echo; beyond the reliable range: nothing seen
            return hi
        return max(lo, value)

    def _warn_once(self, key: str, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            LOG.warning("%s", message)
