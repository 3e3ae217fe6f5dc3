"""A fake NAO: ALMotion, ALMemory, ALRobotPosture, ALSonar and ALVideoDevice over real libqi.

Run as a program (``python fake_naoqi.py --port N``) it listens standalone on
``tcp://127.0.0.1:N``, registers the services with the NAOqi 2.x method names, signatures
and answer shapes the bridge uses, prints ``FAKE_NAOQI_URL <url>`` and serves until killed.
Tests run it in a subprocess (:class:`FakeNaoqi`) so they can kill it (the robot vanishes)
and start it again on the same port (the robot comes back).

Model: a kinematic walker. ``move(x, y, theta, config)`` sets the walk velocity, saturated
by the move config like NAO's walk (speed <= MaxStepX / step period, step period from
MaxStepFrequency between 0.6 s and 0.4 s); odometry integrates that velocity in wall time;
the sonars see cylinders (``set_obstacles``) inside 60-degree cones yawed +-22 degrees,
and update only while ALSonar has a subscriber, as on the real robot. Every call is
recorded with its wall-clock time (``time.time()``, the same clock as the test's and the
other processes'); ``FakeNaoControl`` (test-only, not a NAOqi service) sets the world,
injects bad answers and returns the record.

Like NAOqi's own modules the services answer calls concurrently (``qi.multiThreaded``):
a hung ``getRobotVelocity`` does not hold up ``stopMove``. A ``hang`` fault holds the
answer until the fault is cleared (at most 30 s). ``--image-data string`` serves
``getImageRemote`` with a dynamic signature, so the image data reaches the client as a
string instead of raw bytes (as a NAOqi service that typed it so did). Other programs
(the NAO guard) can register their own services on it, as on a robot.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import qi

MIN_STEP_PERIOD_S, MAX_STEP_PERIOD_S = 0.40, 0.60
SONAR_YAW_RAD, SONAR_HALF_CONE_RAD = math.radians(22.0), math.radians(30.0)
SONAR_NO_ECHO_M = 5.0
QVGA = (320, 240)
US_LEFT = "Device/SubDeviceList/US/Left/Sensor/Value"
US_RIGHT = "Device/SubDeviceList/US/Right/Sensor/Value"
ANGLE_X = "Device/SubDeviceList/InertialSensor/AngleX/Sensor/Value"
ANGLE_Y = "Device/SubDeviceList/InertialSensor/AngleY/Sensor/Value"

# NAOqi's ranges of the move-config parameters (ALMotion documentation).
MOVE_CONFIG_RANGES = {
    "MaxStepX": (0.001, 0.08),
    "MaxStepY": (0.101, 0.16),
    "MaxStepTheta": (0.001, 0.524),
    "MaxStepFrequency": (0.0, 1.0),
    "StepHeight": (0.005, 0.04),
    "TorsoWx": (-0.122, 0.122),
    "TorsoWy": (-0.122, 0.122),
}
MOVE_DEFAULTS = {"MaxStepX": 0.04, "MaxStepY": 0.14, "MaxStepTheta": 0.349, "MaxStepFrequency": 1.0, "StepHeight": 0.02}


class World:
    """The robot's state, shared by all services (one lock)."""

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.t_last = time.monotonic()
        self.pose = [0.0, 0.0, 0.0]
        self.vel = [0.0, 0.0, 0.0]
        self.awake = False
        self.posture = "Crouch"
        self.obstacles: list[tuple[float, float, float]] = []
        self.memory: dict[str, Any] = {US_LEFT: SONAR_NO_ECHO_M, US_RIGHT: SONAR_NO_ECHO_M, ANGLE_X: 0.0, ANGLE_Y: 0.0}
        self.sonar_subscribers: set[str] = set()
        self.video_subscribers: dict[str, tuple[int, int, int]] = {}
        self.frame = 0
        self.faults: dict[str, str] = {}
        self.calls: list[list[Any]] = []
        self.last_move_config: dict[str, float] = dict(MOVE_DEFAULTS)

    def record(self, service: str, method: str, *args: Any) -> None:
        with self.lock:
            self.calls.append([service, method, [_plain(a) for a in args], time.time()])

    def update(self) -> None:
        """Integrate the walk up to now and refresh the sonars (if subscribed)."""
        with self.lock:
            now = time.monotonic()
            dt, self.t_last = now - self.t_last, now
            vx, vy, w = self.vel
            th = self.pose[2]
            self.pose[0] += (vx * math.cos(th) - vy * math.sin(th)) * dt
            self.pose[1] += (vx * math.sin(th) + vy * math.cos(th)) * dt
            self.pose[2] = math.atan2(math.sin(th + w * dt), math.cos(th + w * dt))
            if self.sonar_subscribers:
                self.memory[US_LEFT] = self.sonar(+SONAR_YAW_RAD)
                self.memory[US_RIGHT] = self.sonar(-SONAR_YAW_RAD)

    def sonar(self, yaw: float) -> float:
        """Range [m] to the nearest obstacle surface inside the cone yawed ``yaw`` from the heading."""
        x, y, th = self.pose
        best = SONAR_NO_ECHO_M
        for ox, oy, r in self.obstacles:
            d = math.hypot(ox - x, oy - y)
            if d <= r:
                return 0.0
            bearing = math.atan2(oy - y, ox - x) - (th + yaw)
            bearing = math.atan2(math.sin(bearing), math.cos(bearing))
            if abs(bearing) - math.asin(min(1.0, r / d)) <= SONAR_HALF_CONE_RAD:
                best = min(best, d - r)
        return best

    def fault(self, method: str) -> str | None:
        with self.lock:
            return self.faults.get(method)


def _plain(value: Any) -> Any:
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, bool | int | float | str) or value is None:
        return value
    return repr(value)


def _bad(kind: str, good: Any, still: Any = None) -> Any:
    """A bad answer of ``kind`` in place of ``good`` (``still()``: the fault is still set)."""
    if kind == "string":
        return "garbage"
    if kind == "short":
        return list(good)[:1]
    if kind == "nan":
        return [float("nan")] * len(good)
    if kind == "hang":
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and (still is None or still()):
            time.sleep(0.02)
        return good
    if kind == "error":
        raise RuntimeError("injected failure")
    return good


@qi.multiThreaded()
class ALMotion:
    def __init__(self, world: World) -> None:
        self.w = world

    def wakeUp(self) -> None:
        self.w.record("ALMotion", "wakeUp")
        with self.w.lock:
            self.w.awake = True

    def rest(self) -> None:
        self.w.record("ALMotion", "rest")
        with self.w.lock:
            self.w.update()
            self.w.awake, self.w.vel, self.w.posture = False, [0.0, 0.0, 0.0], "Crouch"

    def robotIsWakeUp(self) -> bool:
        return self.w.awake

    def move(self, x: float, y: float, theta: float, config: Any) -> None:
        self.w.record("ALMotion", "move", x, y, theta, config)
        params = dict(MOVE_DEFAULTS)
        for item in config:
            name, value = item[0], float(item[1])
            if name not in MOVE_CONFIG_RANGES:
                raise RuntimeError(f"ALMotion.move: unknown move config parameter {name!r}")
            lo, hi = MOVE_CONFIG_RANGES[name]
            params[name] = min(hi, max(lo, value))
        with self.w.lock:
            self.w.update()
            self.w.last_move_config = params
            if not self.w.awake:  # NAO does not walk without stiffness
                return
            period = MAX_STEP_PERIOD_S - params["MaxStepFrequency"] * (MAX_STEP_PERIOD_S - MIN_STEP_PERIOD_S)
            vmax, wmax = params["MaxStepX"] / period, params["MaxStepTheta"] / period
            self.w.vel = [min(vmax, max(-vmax, x)), min(vmax, max(-vmax, y)), min(wmax, max(-wmax, theta))]

    def stopMove(self) -> None:
        self.w.record("ALMotion", "stopMove")
        with self.w.lock:
            self.w.update()
            self.w.vel = [0.0, 0.0, 0.0]

    def moveIsActive(self) -> Any:
        with self.w.lock:
            good = any(v != 0.0 for v in self.w.vel)
        kind = self.w.fault("moveIsActive")
        return good if kind is None else _bad(kind, [good])

    def getRobotVelocity(self) -> Any:
        with self.w.lock:
            good = list(self.w.vel)
        kind = self.w.fault("getRobotVelocity")
        return good if kind is None else _bad(kind, good, lambda: self.w.fault("getRobotVelocity") == "hang")

    def getRobotPosition(self, useSensors: bool) -> Any:
        with self.w.lock:
            self.w.update()
            good = list(self.w.pose)
        kind = self.w.fault("getRobotPosition")
        return good if kind is None else _bad(kind, good)


@qi.multiThreaded()
class ALRobotPosture:
    POSTURES = ("StandInit", "StandZero", "Stand", "Crouch", "Sit", "SitRelax", "LyingBelly", "LyingBack")

    def __init__(self, world: World) -> None:
        self.w = world

    def goToPosture(self, name: str, speed: float) -> bool:
        self.w.record("ALRobotPosture", "goToPosture", name, speed)
        with self.w.lock:
            fallen = abs(self.w.memory[ANGLE_X]) > 1.0 or abs(self.w.memory[ANGLE_Y]) > 1.0
            if name not in self.POSTURES or not self.w.awake or fallen:
                return False
            self.w.vel = [0.0, 0.0, 0.0]
            self.w.posture = name
            return True

    def getPostureFamily(self) -> str:
        return "Standing" if self.w.posture.startswith("Stand") else "Crouching"


@qi.multiThreaded()
class ALMemory:
    def __init__(self, world: World) -> None:
        self.w = world

    def getData(self, key: str) -> Any:
        with self.w.lock:
            self.w.update()
            if key not in self.w.memory:
                raise RuntimeError(f"ALMemory::getData: key {key!r} does not exist")
            return self.w.memory[key]

    def getListData(self, keys: Any) -> Any:
        with self.w.lock:
            self.w.update()
            good = [self.w.memory.get(k) for k in keys]
        kind = self.w.fault("getListData")
        return good if kind is None else _bad(kind, good)

    def insertData(self, key: str, value: Any) -> None:
        with self.w.lock:
            self.w.memory[key] = value


class ALSonar:
    def __init__(self, world: World) -> None:
        self.w = world

    def subscribe(self, name: str) -> None:
        self.w.record("ALSonar", "subscribe", name)
        with self.w.lock:
            self.w.sonar_subscribers.add(name)

    def unsubscribe(self, name: str) -> None:
        self.w.record("ALSonar", "unsubscribe", name)
        with self.w.lock:
            self.w.sonar_subscribers.discard(name)


@qi.multiThreaded()
class ALVideoDevice:
    RESOLUTIONS: ClassVar[dict[int, tuple[int, int]]] = {0: (160, 120), 1: (320, 240), 2: (640, 480)}
    LAYERS: ClassVar[dict[int, int]] = {0: 1, 9: 2, 10: 3, 11: 3, 13: 3}  # kYuv, kYUV422, kYUV, kRGB, kBGR

    def __init__(self, world: World) -> None:
        self.w = world

    def subscribeCamera(self, name: str, camera: int, resolution: int, colorspace: int, fps: int) -> str:
        self.w.record("ALVideoDevice", "subscribeCamera", name, camera, resolution, colorspace, fps)
        if resolution not in self.RESOLUTIONS or colorspace not in self.LAYERS or not 1 <= fps <= 30:
            raise RuntimeError("ALVideoDevice::subscribeCamera: invalid resolution, color space or fps")
        with self.w.lock:
            handle, n = name, 0
            while handle in self.w.video_subscribers:
                n += 1
                handle = f"{name}_{n}"
            self.w.video_subscribers[handle] = (camera, resolution, colorspace)
            return handle

    # [w, h, layers, colorspace, ts_s, ts_us, data, camera, left, top, right, bottom angles]:
    # NAOqi answers a raw buffer for the data, so the method is bound to that signature.
    @qi.bind("(iiiiiiriffff)", ["s"])
    def getImageRemote(self, handle: str) -> Any:
        return self._image(handle)

    def _image(self, handle: str) -> Any:
        self.w.record("ALVideoDevice", "getImageRemote", handle)
        with self.w.lock:
            if handle not in self.w.video_subscribers:
                raise RuntimeError(f"ALVideoDevice::getImageRemote: no subscriber {handle!r}")
            camera, resolution, colorspace = self.w.video_subscribers[handle]
            self.w.frame += 1
            frame = self.w.frame
        width, height = self.RESOLUTIONS[resolution]
        layers = self.LAYERS[colorspace]
        # A gradient whose red channel moves with the frame number: frames differ.
        image = np.zeros((height, width, layers), dtype=np.uint8)
        image[:, :, 0] = ((np.arange(width) + frame) % 256).astype(np.uint8)[None, :]
        if layers == 3:
            image[:, :, 1] = (np.arange(height) % 256).astype(np.uint8)[:, None]
            image[:, :, 2] = 128
        data = image.tobytes()
        if self.w.fault("getImageRemote") == "short":
            data = data[: len(data) // 2]
        now = time.time()
        return (
            width,
            height,
            layers,
            colorspace,
            int(now),
            int((now % 1) * 1e6),
            data,
            camera,
            0.53,
            -0.41,
            -0.53,
            0.41,
        )

    def unsubscribe(self, handle: str) -> bool:
        self.w.record("ALVideoDevice", "unsubscribe", handle)
        with self.w.lock:
            return self.w.video_subscribers.pop(handle, None) is not None


class StringImageVideoDevice(ALVideoDevice):
    """ALVideoDevice whose ``getImageRemote`` has a dynamic signature: bytes go out as a string."""

    @qi.bind("m", ["s"])
    def getImageRemote(self, handle: str) -> Any:
        return self._image(handle)


class FakeNaoControl:
    """Test-only service: set the world, inject faults, read the record."""

    def __init__(self, world: World) -> None:
        self.w = world

    def set_obstacles(self, obstacles: Any) -> None:
        with self.w.lock:
            self.w.obstacles = [(float(o[0]), float(o[1]), float(o[2])) for o in obstacles]

    def set_pose(self, x: float, y: float, theta: float) -> None:
        with self.w.lock:
            self.w.update()
            self.w.pose = [float(x), float(y), float(theta)]

    def set_fault(self, method: str, kind: str) -> None:
        with self.w.lock:
            if kind:
                self.w.faults[method] = kind
            else:
                self.w.faults.pop(method, None)

    def set_memory(self, key: str, value: float) -> None:
        with self.w.lock:
            self.w.memory[key] = float(value)

    def state_json(self) -> str:
        with self.w.lock:
            self.w.update()
            return json.dumps(
                {
                    "pose": self.w.pose,
                    "vel": self.w.vel,
                    "awake": self.w.awake,
                    "posture": self.w.posture,
                    "sonar_subscribers": sorted(self.w.sonar_subscribers),
                    "video_subscribers": sorted(self.w.video_subscribers),
                    "move_config": self.w.last_move_config,
                    "memory": self.w.memory,
                }
            )

    def calls_json(self) -> str:
        with self.w.lock:
            return json.dumps(self.w.calls)


def serve(port: int, ready_file: str = "", image_data: str = "raw") -> None:
    """Serve the fake robot on ``tcp://127.0.0.1:port`` until killed."""
    world = World()
    video = StringImageVideoDevice(world) if image_data == "string" else ALVideoDevice(world)
    session = qi.Session()
    session.listenStandalone(f"tcp://127.0.0.1:{port}")
    for name, obj in (
        ("ALMotion", ALMotion(world)),
        ("ALRobotPosture", ALRobotPosture(world)),
        ("ALMemory", ALMemory(world)),
        ("ALSonar", ALSonar(world)),
        ("ALVideoDevice", video),
        ("FakeNaoControl", FakeNaoControl(world)),
    ):
        session.registerService(name, obj)
    url = session.endpoints()[0]
    if ready_file:  # written whole, then renamed: the reader never sees half a URL
        Path(ready_file + ".tmp").write_text(url)
        os.replace(ready_file + ".tmp", ready_file)
    else:
        sys.stdout.write(f"FAKE_NAOQI_URL {url}\n")
        sys.stdout.flush()
    threading.Event().wait()


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class FakeNaoqi:
    """The fake robot in a subprocess: ``start()``, ``kill()`` (vanish), ``start()`` again.

    Parameters
    ----------
    port : int, optional
        Port to listen on (the same across restarts); a free one by default.
    image_data : str
        ``raw`` (NAOqi's type) or ``string`` (image data typed as a string).
    """

    def __init__(self, port: int | None = None, image_data: str = "raw") -> None:
        self.image_data = image_data
        self.port = port or free_port()
        self.url = f"tcp://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen[bytes] | None = None
        self._control_session: Any = None

    def start(self, timeout_s: float = 20.0) -> str:
        """Start the fake robot; return its URL once it serves."""
        deadline = time.monotonic() + timeout_s
        with tempfile.TemporaryDirectory() as tmp:
            ready = Path(tmp) / "url"
            while True:
                # libqi logs to stdout/stderr: to /dev/null, so a full pipe never blocks it.
                self.proc = subprocess.Popen(
                    [
                        sys.executable,
                        __file__,
                        "--port",
                        str(self.port),
                        "--ready-file",
                        str(ready),
                        "--image-data",
                        self.image_data,
                    ],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
                while time.monotonic() < deadline and self.proc.poll() is None and not ready.exists():
                    time.sleep(0.05)
                if ready.exists():
                    return self.url
                self.kill()
                if time.monotonic() >= deadline:
                    raise RuntimeError(f"fake NAOqi did not start on port {self.port}")
                time.sleep(0.2)  # port still held by the previous process: retry

    def kill(self) -> None:
        """Kill the robot at once (no goodbye), as a pulled network cable or power would."""
        self.close_control()
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait(10)
            self.proc = None

    def control(self) -> Any:
        """A proxy to the test-only ``FakeNaoControl`` service (own qi session)."""
        if self._control_session is None:
            self._control_session = qi.Session()
            self._control_session.connect(self.url)
        return self._control_session.service("FakeNaoControl")

    def close_control(self) -> None:
        if self._control_session is not None:
            with contextlib.suppress(RuntimeError):
                self._control_session.close()
            self._control_session = None

    def state(self) -> dict[str, Any]:
        return json.loads(self.control().state_json())

    def calls(self, method: str | None = None) -> list[list[Any]]:
        calls = json.loads(self.control().calls_json())
        return [c for c in calls if method is None or c[1] == method]

    def __enter__(self) -> FakeNaoqi:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.kill()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--ready-file", default="", help="write the URL here once serving")
    parser.add_argument("--image-data", choices=["raw", "string"], default="raw", help="type of getImageRemote's data")
    args = parser.parse_args()
    serve(args.port, args.ready_file, args.image_data)
