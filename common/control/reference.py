"""The real follower's reference model, eq. (28), closed on the measured speeds.

Eq. (28) reads ``D eta' = k_s (k_g x_m(t - h1) - z_r) - sigma_r z_r' - k_z f_v`` with the
observer (12) ``z_r' = (eta_meas - z_r) / beta_r``. We read ``eta`` as the speed the
follower *commands* to the walking robot (the gait realises it as step length and hip yaw
per cycle) and feed the observer with the *measured* speeds (v_hip of eq. 8 and the yaw
rate), so the model closes the loop on the real robot: it integrates the speed error,
``sigma_r`` damps it through the observer, and the fictitious force ``f_v`` lowers the
commanded speed near obstacles. At rest (``eta'`` = 0, ``z_r'`` = 0) the measured speed
equals ``ref - k_z f_v / k_s``. See docs/method.md for this reading of the paper.

Units: forward channel in cm/s, turn channel in deg/s, times in s.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from bipedtele.control.observer import Observer
from numpy.typing import ArrayLike

__all__ = ["RealFollowerReference", "ReferenceState"]


class ReferenceState(NamedTuple):
    """The reference model's state as a value: the commanded speed ``eta`` and the observer's ``z_r`` [cm/s, deg/s]."""

    eta: np.ndarray
    z_r: np.ndarray


class RealFollowerReference:
    """Discrete (28) + (12) for both channels at a fixed control period.

    Parameters
    ----------
    D : array_like, shape (2,)
        Reference model mass and inertia (model units; cm/s and deg/s channels).
    k_s : array_like, shape (2,)
        Proportional gains.
    k_z : array_like, shape (2,)
        Impedance on the fictitious force.
    beta_r : array_like, shape (2,)
        Observer time constants [s].
    dt : float
        Control period [s].
    """

    def __init__(self, D: ArrayLike, k_s: ArrayLike, k_z: ArrayLike, beta_r: ArrayLike, dt: float) -> None:
        self.D = np.asarray(D, dtype=float).reshape(2)
        self.k_s = np.asarray(k_s, dtype=float).reshape(2)
        self.k_z = np.asarray(k_z, dtype=float).reshape(2)
        self.beta_r = np.asarray(beta_r, dtype=float).reshape(2)
        if dt <= 0:
            raise ValueError(f"dt = {dt}: allowed: > 0 s")
        self.dt = float(dt)
        self.observer = Observer(self.beta_r, self.dt)
        self.eta = np.zeros(2)

    @property
    def z_r(self) -> np.ndarray:
        """Observer estimate of the real speeds [cm/s, deg/s] (eq. 12)."""
        return np.asarray(self.observer.z_r)

    def state(self) -> ReferenceState:
        """Return the model's state as a value (copies): :meth:`restore` runs a period again from it."""
        return ReferenceState(self.eta.copy(), self.observer.z_r.copy())

    def restore(self, state: ReferenceState) -> None:
        """Put the model back in ``state`` (taken by :meth:`state`)."""
        self.eta = state.eta.copy()
        self.observer.reset(state.z_r)

    def reset(self, eta: np.ndarray | None = None, z_r: np.ndarray | None = None) -> None:
        """Set the commanded speed ``eta`` and the observer state ``z_r`` (default zero)."""
        self.eta = np.zeros(2) if eta is None else np.asarray(eta, dtype=float).copy()
        self.observer.reset(0.0 if z_r is None else z_r)

    def step(
        self,
        ref: np.ndarray,
        eta_meas: np.ndarray,
        s_r: np.ndarray,
        f_v: np.ndarray | None = None,
        *,
        eta_max: np.ndarray | None = None,
    ) -> np.ndarray:
        """Advance one control period.

        Parameters
        ----------
        ref : array, shape (2,)
            Received reference ``k_g x_m(t - h1)`` [cm/s, deg/s].
        eta_meas : array, shape (2,)
            Measured speeds [cm/s, deg/s].
        s_r : array, shape (2,)
            Real damping sigma_r in use.
        f_v : array, shape (2,), optional
            Fictitious force components acting on each channel (model units).
        eta_max : array, shape (2,), optional
            Symmetric bound on the commanded speed (anti-windup: the integrator stops
            at the robot's limits).

        Returns
        -------
        numpy.ndarray
            The commanded speed ``eta`` [cm/s, deg/s].
        """
        ref = np.asarray(ref, dtype=float)
        eta_meas = np.asarray(eta_meas, dtype=float)
        s_r = np.asarray(s_r, dtype=float)
        fv = np.zeros(2) if f_v is None else np.asarray(f_v, dtype=float)
        z_prev = self.observer.z_r.copy()
        z_r = self.observer.step(eta_meas)
        dz_r = (z_r - z_prev) / self.dt
        deta = (self.k_s * (ref - z_r) - s_r * dz_r - self.k_z * fv) / self.D
        self.eta = self.eta + self.dt * deta
        if eta_max is not None:
            lim = np.asarray(eta_max, dtype=float)
            self.eta = np.clip(self.eta, -lim, lim)
        return self.eta.copy()
