"""The ``[leader]`` section: device, operator model, loop rates, safety and the cockpit.

The pilot's course (``pilot_obstacles``) is plain data in world coordinates (the frame of
``Feedback.pose``, the robot starting at the origin facing +x). When it is empty (the
default) the pilot reads the ``obstacles`` of the profile's ``[world]`` section, the same
obstacles the simulated robot meets, as plain data; see
:func:`bipedtele.leader.operators.pilot.course_from_config`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from bipedtele.config.profile import param
from bipedtele.leader.device import device_names
from bipedtele.leader.operator import operator_names

__all__ = ["LeaderConfig"]


def _default_script() -> list[list[float]]:
    # t [s], forward [cm/s], turn [deg/s]: stand, walk, walk and turn left, right, stop.
    return [
        [0.0, 0.0, 0.0],
        [2.0, 5.0, 0.0],
        [10.0, 5.0, 0.0],
        [12.0, 4.0, 6.0],
        [18.0, 4.0, 6.0],
        [20.0, 4.0, -6.0],
        [26.0, 4.0, -6.0],
        [28.0, 0.0, 0.0],
        [30.0, 0.0, 0.0],
    ]


@dataclass(frozen=True)
class LeaderConfig:
    """Leader program settings (see leader/loop.py and leader/app.py)."""

    device: str = param(
        "sim-falcon", doc="leader device: sim-falcon, falcon, joystick (the bipedtele.devices entry points)"
    )
    operator: str = param(
        "scripted",
        doc="who moves a simulated device: scripted profile, obstacle pilot, browser joystick (the bipedtele.operators entry points)",
    )
    realtime: bool = param(True, doc="pace the haptic loop in real time (off: as fast as possible)")
    haptic_rate_hz: float = param(1000.0, lo=50.0, hi=5000.0, unit="Hz", doc="haptic loop rate")
    cmd_rate_hz: float = param(100.0, lo=1.0, hi=1000.0, unit="Hz", doc="command publish rate")
    status_rate_hz: float = param(2.0, lo=0.1, hi=50.0, unit="Hz", doc="status publish rate")
    rt_priority: int = param(
        0, lo=0, hi=99, doc="SCHED_FIFO priority of the haptic loop thread (0: normal; needs CAP_SYS_NICE)"
    )
    spin_s: float = param(0.0003, lo=0.0, hi=0.005, unit="s", doc="pacing: busy-wait this long before each deadline")
    feedback_timeout_s: float = param(
        0.5, lo=0.01, hi=30.0, unit="s", doc="no new feedback for this long -> fade the force out"
    )
    fade_s: float = param(0.2, lo=0.0, hi=10.0, unit="s", doc="duration of the force fade out/in")
    # twice the largest age of the newest feedback on the paper's path (h2 up to 0.644 s,
    # 50 Hz feedback, a burst of 3 lost: 0.72 s), rounded up to half a second
    blind_stop_s: float = param(
        1.5, lo=0.1, hi=60.0, unit="s", doc="newest feedback older than this -> commands stop the robot"
    )
    force_rate_max_n_s: float = param(
        80.0,
        lo=1.0,
        hi=100000.0,
        unit="N/s",
        doc="largest change of the handle force per axis (8 N in 0.1 s: no step the hand cannot meet)",
    )
    g_m: list[float] = param(
        default_factory=lambda: [0.0, 0.0], unit="N", doc="gravity compensation g_m of eq. (31) per axis"
    )
    duration_s: float = param(0.0, lo=0.0, unit="s", doc="stop after this long (0: until the operator is done)")
    # ---- simulated Falcon (eq. 1)
    mass_kg: float = param(0.15, lo=0.0, lo_open=True, hi=10.0, unit="kg", doc="sim-falcon effective mass")
    viscous_n_s_m: float = param(0.2, lo=0.0, hi=50.0, unit="N s/m", doc="sim-falcon viscous friction")
    coulomb_n: float = param(0.05, lo=0.0, hi=5.0, unit="N", doc="sim-falcon Coulomb friction")
    gravity_n: list[float] = param(
        default_factory=lambda: [0.0, 0.0], unit="N", doc="sim-falcon gravity load per axis (0: horizontal)"
    )
    # ---- simulated hand (all operator models)
    hand_stiffness_n_m: float = param(300.0, lo=0.0, lo_open=True, hi=5000.0, unit="N/m", doc="hand stiffness")
    hand_damping_n_s_m: float = param(8.0, lo=0.0, hi=200.0, unit="N s/m", doc="hand damping")
    hand_force_max_n: float = param(15.0, lo=0.0, lo_open=True, hi=100.0, unit="N", doc="largest hand force")
    hand_tau_s: float = param(0.15, lo=0.0, hi=5.0, unit="s", doc="hand target smoothing (reaction) time constant")
    # ---- scripted operator
    script: list[list[float]] = param(
        default_factory=_default_script, doc="scripted profile: [t s, forward cm/s, turn deg/s] points"
    )
    script_interp: Literal["linear", "step"] = param("linear", doc="interpolation between script points")
    # ---- pilot operator (Sec. 5, Fig. 10)
    pilot_passes: int = param(10, lo=1, hi=1000, doc="obstacle passes (sides alternate, left first)")
    pilot_obstacles: list[list[float]] = param(
        default_factory=list,
        unit="m",
        doc="course: [x, y, radius] per obstacle, passed in order then back (empty: [world] obstacles)",
    )
    pilot_clearance_m: float = param(0.35, lo=0.05, hi=5.0, unit="m", doc="lateral clearance from an obstacle's edge")
    pilot_approach_m: float = param(0.7, lo=0.1, hi=10.0, unit="m", doc="waypoint distance before/after an obstacle")
    pilot_lookahead_m: float = param(0.5, lo=0.05, hi=5.0, unit="m", doc="pure-pursuit look-ahead distance")
    pilot_speed_cm_s: float = param(8.0, lo=0.0, lo_open=True, hi=100.0, unit="cm/s", doc="cruise forward speed")
    pilot_turn_max_deg_s: float = param(
        20.0, lo=0.0, lo_open=True, hi=360.0, unit="deg/s", doc="largest turn speed asked"
    )
    pilot_slow_range_m: float = param(0.45, lo=0.0, hi=5.0, unit="m", doc="slow down when a sonar reads below this")
    pilot_predict: Literal["off", "now", "h1"] = param(
        "h1",
        doc="pilot steers on: the reported pose (off), the predicted present pose (now), the pose predicted h1 ahead",
    )
    pilot_predict_tau_s: float = param(
        0.5,
        lo=0.0,
        hi=5.0,
        unit="s",
        doc="predictor: time constant of the robot's speed response to its reference",
    )
    # ---- cockpit
    cockpit: bool = param(True, doc="serve the browser cockpit")
    cockpit_host: str = param("127.0.0.1", doc="cockpit listen address")
    cockpit_port: int = param(8080, lo=0, hi=65535, doc="cockpit port (0: any free port)")
    cockpit_rate_hz: float = param(20.0, lo=1.0, hi=100.0, unit="Hz", doc="cockpit sample rate")
    cockpit_allowed_hosts: list[str] = param(
        default_factory=list,
        doc="names accepted in the cockpit's Host header besides cockpit_host, localhost, 127.0.0.1, [::1]",
    )
    cockpit_max_clients: int = param(4, lo=1, hi=100, doc="most browser connections to the cockpit at once")

    def __post_init__(self) -> None:
        if self.device not in device_names():
            raise ValueError(f"device: {self.device!r}: allowed: {', '.join(repr(n) for n in device_names())}")
        if self.operator not in operator_names():
            raise ValueError(f"operator: {self.operator!r}: allowed: {', '.join(repr(n) for n in operator_names())}")
        for name in ("g_m", "gravity_n"):
            if len(getattr(self, name)) != 2:
                raise ValueError(f"{name} = {getattr(self, name)!r}: allowed: a list of exactly 2 numbers [N]")
        if len(self.script) < 1:
            raise ValueError("script: allowed: at least one [t, forward, turn] point")
        last_t = -1.0
        for i, pt in enumerate(self.script):
            if len(pt) != 3:
                raise ValueError(f"script[{i}] = {pt!r}: allowed: [t s, forward cm/s, turn deg/s]")
            if pt[0] < 0 or pt[0] < last_t:
                raise ValueError(f"script[{i}] t = {pt[0]!r}: allowed: times >= 0 and non-decreasing")
            last_t = pt[0]
        for i, ob in enumerate(self.pilot_obstacles):
            if len(ob) != 3 or ob[2] < 0:
                raise ValueError(f"pilot_obstacles[{i}] = {ob!r}: allowed: [x m, y m, radius m >= 0]")
        for i, name in enumerate(self.cockpit_allowed_hosts):
            if not isinstance(name, str) or not name.strip() or any(c in name for c in "/?#@ "):
                raise ValueError(f"cockpit_allowed_hosts[{i}] = {name!r}: allowed: a host name or address")
        if self.viscous_n_s_m * 0.001 / self.mass_kg >= 1.0:
            raise ValueError("viscous_n_s_m / mass_kg: allowed: below 1000 1/s (1 ms integration)")
