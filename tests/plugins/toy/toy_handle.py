"""A toy leader device as a third-party part: a point-mass handle in one module.

Registered by one entry point (``bipedtele.devices``: ``toy-handle = toy_handle:PART``).
A simulated operator's hand moves it (``simulated=True``): m x'' = f_hand + f_feedback - c x'.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from bipedtele.config.profile import Config, param, resolve_section
from bipedtele.leader.device import (
    DeviceNotConnectedError,
    DevicePart,
    HandleState,
    LeaderDevice,
    OperatorHand,
)


@dataclass(frozen=True)
class ToyHandleConfig:
    """The ``[toy_handle]`` section."""

    mass_kg: float = param(0.2, lo=0.01, hi=5.0, unit="kg", doc="moving mass of the handle")
    damping_n_s_m: float = param(4.0, lo=0.0, hi=100.0, unit="N s/m", doc="viscous friction")


class ToyHandle(LeaderDevice):
    """A two-axis point mass (semi-implicit Euler, 1 ms steps)."""

    name: ClassVar[str] = "toy-handle"
    simulated: ClassVar[bool] = True

    def __init__(self, config: ToyHandleConfig | Config | None = None, **overrides: Any) -> None:
        self.config = resolve_section(config, ToyHandleConfig, "toy_handle", overrides)
        self._connected = False
        self._hand: OperatorHand | None = None
        self._t = 0.0
        self._x = np.zeros(2)
        self._v = np.zeros(2)
        self._f = np.zeros(2)

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._f = np.zeros(2)
        self._connected = False

    def _need(self) -> None:
        if not self._connected:
            raise DeviceNotConnectedError("toy-handle: call connect() first")

    def read(self) -> HandleState:
        self._need()
        return HandleState(self._t, self._x.copy(), self._v.copy())

    def apply_force(self, force_n: np.ndarray) -> np.ndarray:
        self._need()
        self._f = self.clamp_force(force_n)
        return self._f.copy()

    def set_operator(self, hand: OperatorHand | None) -> None:
        self._hand = hand

    def advance(self, dt: float) -> None:
        self._need()
        w, cfg, step = self.limits.workspace_m, self.config, 0.001
        end = self._t + max(0.0, float(dt))
        while self._t < end - 1e-12:
            h = min(step, end - self._t)
            f_h = np.zeros(2) if self._hand is None else np.asarray(self._hand.hand_force(self._t, self._x, self._v))
            a = (f_h + self._f - cfg.damping_n_s_m * self._v) / cfg.mass_kg
            self._v = self._v + h * a
            self._x = np.clip(self._x + h * self._v, -w, w)
            self._v = np.where(np.abs(self._x) >= w, 0.0, self._v)
            self._t += h


PART = DevicePart(
    name="toy-handle",
    doc="a point-mass handle a simulated hand moves (the plugin recipe's example)",
    build=ToyHandle,
    section="toy_handle",
    config=ToyHandleConfig,
    simulated=True,
)
