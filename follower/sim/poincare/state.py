"""The map's state vector, its perturbation sizes, the section's alignment and the operating conditions."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from bipedtele.config.profile import ConfigError
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.model import LEG_JOINTS
from bipedtele.follower.sim.robot import SimNao
from bipedtele.follower.sim.torque_config import TorqueConfig
from bipedtele.follower.sim.world import WorldConfig

CM = 100.0

#: Perturbation size per state group (units of the state).
DELTAS: dict[str, float] = {
    "base_z": 1e-4,  # m
    "base_rp": 1e-3,  # rad
    "base_v": 1e-3,  # m/s
    "base_w": 1e-2,  # rad/s
    "q": 1e-3,  # rad
    "qd": 1e-2,  # rad/s
    "servo": 1e-2,  # cm/s, deg/s
    "gait_q": 1e-3,  # rad
    "gait_sway": 1e-4,  # m
}

_JOINTS = [f"{side}{j}" for side in "LR" for j in LEG_JOINTS]
_GROUPS: list[tuple[str, list[str]]] = [
    ("base_z", ["base_z"]),
    ("base_rp", ["base_roll", "base_pitch"]),
    ("base_v", ["base_v_fwd", "base_v_left", "base_v_up"]),
    ("base_w", ["base_w_x", "base_w_y", "base_w_z"]),
    ("q", [f"q_{n}" for n in _JOINTS]),
    ("qd", [f"qd_{n}" for n in _JOINTS]),
    ("servo", ["eta_v", "eta_d", "z_r_v", "z_r_d"]),
    ("gait_q", [f"ref_{n}" for n in _JOINTS]),
    ("gait_sway", ["sway"]),
]


def state_names() -> list[str]:
    """Names of the map's state, in order (50 values)."""
    return [n for _, names in _GROUPS for n in names]


def perturbation_sizes(scale: float = 1.0) -> np.ndarray:
    """Per-state perturbation of (26), :data:`DELTAS` times ``scale``."""
    return np.array([DELTAS[g] * scale for g, names in _GROUPS for _ in names])


def check_alignment(T: float, physics_hz: float, control_rate_hz: float) -> None:
    """Raise :class:`ConfigError` unless ``T/2`` is a whole number of physics and control periods."""
    for name, hz in (("physics", physics_hz), ("control", control_rate_hz)):
        n = T / 2.0 * hz
        if abs(n - round(n)) > 1e-6:
            raise ConfigError(
                f"T = {T:g} s: allowed: T/2 a multiple of the {name} period 1/{hz:g} s "
                "(every touchdown must fall on a control tick)"
            )


def alignment_quantum(physics_hz: float, control_rate_hz: float) -> float:
    """Smallest ``T/2`` step [s] that is a whole number of physics and control periods."""
    a, b = round(physics_hz), round(control_rate_hz)
    if abs(a - physics_hz) > 1e-9 or abs(b - control_rate_hz) > 1e-9:
        raise ConfigError(
            f"physics_hz = {physics_hz:g}, control_rate_hz = {control_rate_hz:g}: allowed: whole numbers of Hz"
        )
    return 1.0 / math.gcd(a, b)


@dataclass(frozen=True)
class MapSettings:
    """Operating conditions of the walker's map.

    Attributes
    ----------
    v_ref, turn_ref : float
        Constant reference ``k_g x_m`` [cm/s, deg/s] (the paper's 5 cm/s and 4 deg/s).
    foot : {"L", "R"}
        Foot whose touchdown is the section.
    control_rate_hz : float
        The servo's rate (the follower's default 50 Hz).
    warmup_s : float
        Walking time before the fixed point is taken [s].
    average_cycles : int
        Cycles after the warm-up whose section states are averaged into the fixed point.
    delta_scale : float
        Factor on :data:`DELTAS`.
    contraction : bool
        Also measure the contraction per cycle by iterating the map (:meth:`WalkerMap.contraction`).
    newton_iterations : int
        When > 0, :meth:`WalkerMap.analyse` also solves ``P(x) = x`` by Newton from the
        averaged state (:meth:`WalkerMap.newton`), at most this many Jacobians.
    newton_scales : tuple of float
        Factors on :data:`DELTAS` at which the radius of (26) is measured at the Newton
        fixed point.
    newton_max_step : float
        Largest Newton step per state value, in perturbation sizes (a trust region: the map
        is non-smooth beyond a few sizes).
    torque : TorqueConfig or None
        None: the position walker (``--robot sim``); a ``[torque]`` section: the torque
        walker (``--robot sim-torque``, :class:`~.torque_robot.TorqueNao`), whose joint law's
        state (observer, torso-mass estimate) is kept at the fixed point's in every
        evaluation (it is not in the map's state vector).
    """

    v_ref: float = 5.0
    turn_ref: float = 4.0
    foot: Literal["L", "R"] = "L"
    control_rate_hz: float = 50.0
    warmup_s: float = 30.0
    average_cycles: int = 8
    lead_s: float = 0.1
    delta_scale: float = 1.0
    contraction: bool = True
    newton_iterations: int = 0
    newton_scales: tuple[float, ...] = (0.3, 1.0, 3.0)
    newton_max_step: float = 10.0
    torque: TorqueConfig | None = None

    def physics_hz(self, sim: SimConfig) -> float:
        """Return the walker's physics rate [Hz]: ``[torque]``'s for the torque walker, else ``[sim]``'s."""
        return self.torque.physics_hz if self.torque is not None else sim.physics_hz

    def build_robot(self, sim: SimConfig) -> SimNao:
        """Return the walker these settings name, not yet connected, on an empty floor."""
        if self.torque is None:
            return SimNao(sim, world=WorldConfig())
        from bipedtele.follower.sim.torque_robot import TorqueNao

        return TorqueNao(sim, world=WorldConfig(), torque=self.torque)
