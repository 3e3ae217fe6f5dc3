"""A simulated Novint Falcon: eq. (1) of the paper per Cartesian handle axis.

Per axis ``i`` the handle obeys

    m ddx_i = f_m,i + f_h,i - g_m,i - b dx_i - f_c sign(dx_i) + (wall)

with the effective moving mass ``m`` (the Falcon's handle and parallel-arm linkage
reflected to the grip: about 0.15 kg), viscous friction ``b`` and Coulomb friction
``f_c`` (both small: the Falcon is backdrivable), a constant gravity load ``g_m`` (0 for
a horizontal handle), and the inertia matrix ``M_m = m I``; the Coriolis term ``C_m`` of
eq. (1) vanishes for a constant Cartesian mass. ``f_m`` is the commanded force (clamped
to 8 N per axis) and ``f_h`` the operator's hand, from an attached :class:`OperatorHand`
(``set_operator``), evaluated at every integration step.

Integration: semi-implicit (symplectic) Euler with a fixed 1 ms step, the Falcon's servo
period; ``advance(dt)`` runs as many whole steps as fit into the accumulated time and
keeps the remainder, so device time never drifts. Coulomb friction sticks: a handle at
rest stays at rest while the net force is below ``f_c``, and friction never reverses the
velocity within a step. The workspace ends at hard stops (+-0.05 m): reaching one sets the
position to the stop and removes the velocity into the wall (a perfectly inelastic
impact, like the Falcon's mechanical end stops), so positions never leave the workspace.
With no hand and no commanded force the handle's kinetic energy never grows.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from bipedtele.leader.config import LeaderConfig
from bipedtele.leader.device import (
    DeviceLimits,
    DeviceNotConnectedError,
    HandleState,
    LeaderDevice,
    OperatorHand,
)

__all__ = ["SimFalcon", "SimFalconParams"]

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class SimFalconParams:
    """Physical parameters of the simulated handle (same on both axes).

    Attributes
    ----------
    mass_kg : float
        Effective moving mass at the grip [kg].
    viscous_n_s_m : float
        Viscous friction [N s/m].
    coulomb_n : float
        Coulomb (dry) friction [N].
    gravity_n : tuple of float
        Constant load g_m per axis [N] (0 for a horizontal handle).
    step_s : float
        Fixed integration step [s] (the servo period).
    """

    mass_kg: float = 0.15
    viscous_n_s_m: float = 0.2
    coulomb_n: float = 0.05
    gravity_n: tuple[float, float] = (0.0, 0.0)
    step_s: float = 0.001

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mass_kg) and self.mass_kg > 0):
            raise ValueError(f"mass_kg = {self.mass_kg!r}: allowed: a number > 0 kg")
        for name in ("viscous_n_s_m", "coulomb_n"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} = {v!r}: allowed: a number >= 0")
        if len(self.gravity_n) != 2 or not all(math.isfinite(g) for g in self.gravity_n):
            raise ValueError(f"gravity_n = {self.gravity_n!r}: allowed: 2 finite numbers [N]")
        if not (0 < self.step_s <= 0.01):
            raise ValueError(f"step_s = {self.step_s!r}: allowed: a number in (0, 0.01] s")
        if self.viscous_n_s_m * self.step_s / self.mass_kg >= 1.0:
            raise ValueError("viscous_n_s_m * step_s / mass_kg: allowed: < 1 (explicit friction stability)")


class SimFalcon(LeaderDevice):
    """Simulated 2-axis Falcon handle (see the module docstring for the model).

    Parameters
    ----------
    params : SimFalconParams, optional
        Mass, friction, gravity and step.
    limits : DeviceLimits, optional
        Workspace, force limit and servo rate (Falcon defaults).
    x0 : sequence of float, optional
        Initial handle position [m] (clipped to the workspace).
    config : Config, optional
        A loaded profile: ``params`` from its ``[leader]`` section (mass_kg,
        viscous_n_s_m, coulomb_n, gravity_n) when ``params`` is not given.
    """

    name: ClassVar[str] = "sim-falcon"

    #: Moved by a simulated operator's hand (operator models drive it).
    simulated: ClassVar[bool] = True

    def __init__(
        self,
        params: SimFalconParams | None = None,
        limits: DeviceLimits | None = None,
        x0: tuple[float, float] = (0.0, 0.0),
        *,
        config: Any = None,
    ) -> None:
        if params is None and config is not None:
            lc = config.get(LeaderConfig)
            params = SimFalconParams(
                mass_kg=lc.mass_kg,
                viscous_n_s_m=lc.viscous_n_s_m,
                coulomb_n=lc.coulomb_n,
                gravity_n=(lc.gravity_n[0], lc.gravity_n[1]),
            )
        self.params = params or SimFalconParams()
        self.limits = limits or DeviceLimits()
        w = self.limits.workspace_m
        self._x0 = np.clip(np.asarray(x0, dtype=float).reshape(2), -w, w)
        self._connected = False
        self._hand: OperatorHand | None = None
        self._reset()

    def _reset(self) -> None:
        self._t = 0.0
        self._steps = 0
        self._pending = 0.0
        self._x = self._x0.copy()
        self._dx = np.zeros(2)
        self._f_m = np.zeros(2)
        self._f_h = np.zeros(2)

    # ------------------------------------------------------------------ contract

    @property
    def is_connected(self) -> bool:
        """True between ``connect()`` and ``disconnect()``."""
        return self._connected

    def connect(self) -> None:
        """Start (or restart) the simulation at rest at ``x0``, time 0."""
        if not self._connected:
            self._reset()
            self._connected = True

    def disconnect(self) -> None:
        """Zero the force and stop. Idempotent."""
        self._f_m = np.zeros(2)
        self._connected = False

    def _need(self) -> None:
        if not self._connected:
            raise DeviceNotConnectedError(f"device {self.name!r}: call connect() first")

    def read(self) -> HandleState:
        """Read the handle now (button 0, the dead-man, is always held)."""
        self._need()
        return HandleState(t=self._t, x_m=self._x.copy(), dx_m=self._dx.copy(), buttons=(True,))

    def apply_force(self, force_n: np.ndarray) -> np.ndarray:
        """Command a force [N] per axis; return the force applied (clamped to the limit)."""
        self._need()
        self._f_m = self.clamp_force(force_n)
        return self._f_m.copy()

    def set_operator(self, hand: OperatorHand | None) -> None:
        """Attach the simulated operator's hand (f_h in eq. 1); ``None`` lets go."""
        self._hand = hand

    @property
    def hand_force_n(self) -> np.ndarray:
        """The operator's force f_h [N] in the last integration step."""
        return self._f_h.copy()

    def kinetic_energy(self) -> float:
        """Kinetic energy of the handle [J]."""
        return 0.5 * self.params.mass_kg * float(self._dx @ self._dx)

    def advance(self, dt: float) -> None:
        """Integrate eq. (1) for ``dt`` seconds in fixed steps (remainder carried over)."""
        self._need()
        if not (math.isfinite(dt) and dt >= 0):
            raise ValueError(f"dt = {dt!r}: allowed: a finite number >= 0 s")
        h = self.params.step_s
        self._pending += dt
        n = int((self._pending + 1e-12) // h)
        self._pending = max(0.0, self._pending - n * h)
        for _ in range(n):
            self._step(h)

    # ------------------------------------------------------------------ dynamics

    def _step(self, h: float) -> None:
        p = self.params
        t = self._t
        if self._hand is not None:
            f_h = np.asarray(self._hand.hand_force(t, self._x.copy(), self._dx.copy()), float)
            f_h = np.where(np.isfinite(f_h), f_h, 0.0).reshape(2)
        else:
            f_h = np.zeros(2)
        self._f_h = f_h
        f_ext = self._f_m + f_h - np.asarray(p.gravity_n)
        m, b, f_c = p.mass_kg, p.viscous_n_s_m, p.coulomb_n
        v = self._dx.copy()
        for i in range(2):
            vi, fi = float(v[i]), float(f_ext[i])
            if vi == 0.0:
                # Static friction holds the handle while the applied force is below f_c.
                if abs(fi) <= f_c:
                    continue
                v[i] = h * (fi - math.copysign(f_c, fi)) / m
            else:
                v_new = vi + h * (fi - b * vi - math.copysign(f_c, vi)) / m
                # Friction alone never reverses the motion within a step: it stops it.
                if v_new * vi < 0.0 and abs(fi) <= f_c:
                    v_new = 0.0
                v[i] = v_new
        # Viscous friction is explicit: stable (|v| shrinks) for h b / m < 2, which the
        # Falcon's values satisfy by orders of magnitude.
        x = self._x + h * v
        w = self.limits.workspace_m
        for i in range(2):
            if x[i] > w:
                x[i] = w
                v[i] = min(v[i], 0.0)
            elif x[i] < -w:
                x[i] = -w
                v[i] = max(v[i], 0.0)
        self._x = x
        self._dx = v
        self._steps += 1
        self._t = self._steps * h
