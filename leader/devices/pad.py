"""``gamepad`` and ``keyboard``: the handle read from the cockpit's browser page, on any OS.

The page reads a game controller through the browser's Gamepad API (any standard
controller, any OS), or the keyboard, and sends its state over the cockpit's websocket
(``{"type": "pad", "src": "gamepad"|"keyboard", "x", "y", "held", "stop"}``,
docs/cockpit.md). This device turns the newest state into a handle position as the other
devices give it: the left stick (arrows) up is the handle forward, right is a right turn,
full deflection 0.98 of the workspace, so ``k_g`` maps it to speed as for the Falcon. The
dead-man button (a shoulder button LB/RB; the space bar) is button 0: the robot walks only
while it is held. The stop button (B; Escape) releases it until it is let go and pressed
again (the page latches it).

Capability flags: a person holds it (not simulated), and the force does not reach the hand
(``force_output`` False): :meth:`PadDevice.apply_force` keeps the clamped force, which the
leader puts in its samples, and the page renders it as the controller's dual rumble
(strong motor: forward axis, weak motor: turn axis, strength ``|f| / force_max_n``) and as a
gauge. A state older than ``timeout_s`` (the page went away, the tab was hidden) reads as
the stick centred and the dead-man let go.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
from bipedtele.leader.device import DeviceError, DeviceNotConnectedError, HandleState, LeaderDevice, PadInput

__all__ = ["KeyboardDevice", "PadDevice"]


class PadDevice(LeaderDevice):
    """A game controller in the cockpit's page (see the module docstring).

    Parameters
    ----------
    config : Config, optional
        The profile (``[pad]``: ``deadzone``, ``timeout_s``).
    clock : callable
        Time of the states [s] (``time.time``).
    """

    name: ClassVar[str] = "gamepad"
    source: ClassVar[str] = "gamepad"
    force_output: ClassVar[bool] = False
    needs_cockpit: ClassVar[bool] = True

    def __init__(self, config: Any = None, *, clock: Callable[[], float] = time.time) -> None:
        from bipedtele.leader.parts import PadConfig

        pc = config.get(PadConfig) if config is not None else PadConfig()
        self.deadzone, self.timeout_s = float(pc.deadzone), float(pc.timeout_s)
        self._clock = clock
        self._pad: Callable[[], PadInput | None] | None = None
        self._connected = False
        self._x = np.zeros(2)
        self._t_last: float | None = None
        #: The last force asked for, clamped [N]: what the page renders as rumble.
        self.force = np.zeros(2)

    @property
    def is_connected(self) -> bool:
        """True between ``connect()`` and ``disconnect()``."""
        return self._connected

    def attach_cockpit(self, pad: Any) -> None:
        """Read the page's controller from ``pad() -> PadInput | None`` (the cockpit)."""
        self._pad = pad

    def connect(self) -> None:
        """Start reading the page (the cockpit must be attached)."""
        if self._pad is None:
            raise DeviceError(f"device {self.name!r} reads the cockpit's page: set leader.cockpit = true")
        self._connected = True

    def disconnect(self) -> None:
        """Zero the force and stop reading. Idempotent."""
        self.force = np.zeros(2)
        self._connected = False

    def _need(self) -> None:
        if not self._connected:
            raise DeviceNotConnectedError(f"device {self.name!r}: connect() first")

    def _axis(self, v: float) -> float:
        if not math.isfinite(v):
            return 0.0
        v = min(max(v, -1.0), 1.0)
        if abs(v) <= self.deadzone:
            return 0.0
        return math.copysign((abs(v) - self.deadzone) / (1.0 - self.deadzone), v)

    def read(self) -> HandleState:
        """Return the handle from the page's newest state (centred, dead-man let go when stale)."""
        self._need()
        now = self._clock()
        st = self._pad() if self._pad is not None else None
        fresh = st is not None and st.src == self.source and now - st.t <= self.timeout_s
        if fresh and st is not None:
            w = 0.98 * self.limits.workspace_m
            x = np.array([self._axis(st.y) * w, -self._axis(st.x) * w])
            held = bool(st.held)
        else:
            x, held = np.zeros(2), False
        dt = now - self._t_last if self._t_last is not None else 0.0
        dx = (x - self._x) / dt if dt > 1e-6 else np.zeros(2)
        self._x, self._t_last = x, now
        return HandleState(t=now, x_m=x, dx_m=dx, buttons=(held,))

    def apply_force(self, force_n: np.ndarray) -> np.ndarray:
        """Keep the clamped force for the page's rumble; return it (nothing pushes the hand)."""
        self._need()
        self.force = self.clamp_force(force_n)
        return self.force

    def advance(self, dt: float) -> None:
        """Nothing to service: the page sends its state (the loop paces)."""
        self._need()


class KeyboardDevice(PadDevice):
    """The keyboard in the cockpit's page: arrows, space as the dead-man, Escape to stop."""

    name: ClassVar[str] = "keyboard"
    source: ClassVar[str] = "keyboard"
