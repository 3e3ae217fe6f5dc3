"""The equivalent follower, eq. (29), per channel, discretised exactly (zero-order hold).

Eq. (29) with the fictitious-force term of (33)::

    D eta' = k_s (k_g x_m(t - h1) - z_e) - sigma_e z_e' - k_z f_v
    z_e    = eta - beta_e z_e'            (so z_e' = (eta - z_e) / beta_e)

State per channel ``[eta, z_e]``, inputs ``[ref, f_v]`` with ``ref = k_g x_m(t - h1)``::

    A = [[-s/(D b), (s/b - k)/D],      B = [[k/D, -k_z/D],
         [ 1/b,     -1/b       ]]           [0,    0     ]]

(``s = sigma_e``, ``b = beta_e``, ``k = k_s``). Its characteristic polynomial is
``l^2 + (s + D)/(D b) l + k/(D b)``: Hurwitz for every ``s >= 0``. ``z_e`` is a state, so it
is continuous whatever the input does: the leader feels no impact jumps.

Units: forward channel cm/s, turn channel deg/s, times s.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from bipedtele.control.config import ControlConfig
from numpy.typing import ArrayLike
from scipy.linalg import expm

__all__ = [
    "EquivalentFollower",
    "equivalent_matrices",
    "equivalent_max_real",
    "equivalent_spectral_radius",
    "equivalent_zoh",
]


def equivalent_matrices(
    s_e: ArrayLike, D: ArrayLike, k_s: ArrayLike, beta_e: ArrayLike, k_z: ArrayLike = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``(A, B)`` of (29) for each channel: shapes ``(..., 2, 2)`` and ``(..., 2, 2)``."""
    s, d, k, b, kz = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (s_e, D, k_s, beta_e, k_z)))
    z = np.zeros_like(s)
    a = np.stack([np.stack([-s / (d * b), (s / b - k) / d], -1), np.stack([1.0 / b, -1.0 / b], -1)], -2)
    bm = np.stack([np.stack([k / d, -kz / d], -1), np.stack([z, z], -1)], -2)
    return a, bm


def _zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    n, m = a.shape[0], b.shape[1]
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = a
    aug[:n, n:] = b
    e = expm(aug * dt)
    return e[:n, :n], e[:n, n:]


@lru_cache(maxsize=4096)
def _zoh_cached(key: tuple[float, ...], dt: float) -> tuple[np.ndarray, np.ndarray]:
    s_e, d, k, b, kz = (np.asarray(key[i : i + 2]) for i in range(0, 10, 2))
    a, bm = equivalent_matrices(s_e, d, k, b, kz)
    phis, gams = zip(*(_zoh(a[c], bm[c], dt) for c in range(2)), strict=True)
    phi, gam = np.stack(phis), np.stack(gams)
    phi.flags.writeable = False
    gam.flags.writeable = False
    return phi, gam


def equivalent_zoh(
    s_e: ArrayLike, D: ArrayLike, k_s: ArrayLike, beta_e: ArrayLike, k_z: ArrayLike, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation of (29) for both channels (cached per parameter set).

    Uses ``scipy.linalg.expm`` of the augmented matrix ``[[A, B], [0, 0]] dt``.

    Returns
    -------
    (Phi, Gamma)
        Shapes (2, 2, 2) and (2, 2, 2) (channel, row, column); read-only arrays.
        ``x[k+1] = Phi x[k] + Gamma [ref, f_v]``.
    """
    key = tuple(
        float(v) for arr in (s_e, D, k_s, beta_e, k_z) for v in np.broadcast_to(np.asarray(arr, dtype=float), (2,))
    )
    return _zoh_cached(key, float(dt))


def equivalent_max_real(s_e: ArrayLike, cfg: ControlConfig) -> np.ndarray:
    """Largest real part of the continuous eigenvalues of (29), per channel [1/s].

    Closed form from ``l^2 + (s + D)/(D b) l + k/(D b)``; vectorised over ``s_e`` of shape
    ``(..., 2)``.
    """
    s = np.asarray(s_e, dtype=float)
    d = np.asarray(cfg.D, dtype=float)
    k = np.asarray(cfg.k_s, dtype=float)
    b = np.asarray(cfg.beta_e, dtype=float)
    half = 0.5 * (s + d) / (d * b)
    disc = half * half - k / (d * b)
    return np.asarray(np.where(disc > 0, -half + np.sqrt(np.maximum(disc, 0.0)), -half))


def equivalent_spectral_radius(s_e: ArrayLike, cfg: ControlConfig, dt: ArrayLike) -> np.ndarray | float:
    """``max|lambda_equivalent|``: spectral radius of the exactly discretised (29).

    The eigenvalues of ``exp(A dt)`` are ``exp(l dt)``, so the radius is
    ``exp(dt max_channel Re l)``.

    Parameters
    ----------
    s_e : array_like, shape (2,) or (..., 2)
        Equivalent damping per channel.
    cfg : ControlConfig
        ``D``, ``k_s``, ``beta_e``.
    dt : float or array_like
        Discretisation period [s] (broadcast against the leading shape of ``s_e``). The
        online choice (30) uses the walking cycle ``T`` (docs/method.md).
    """
    re = equivalent_max_real(s_e, cfg).max(axis=-1)
    out = np.exp(np.asarray(dt, dtype=float) * re)
    return float(out) if out.ndim == 0 else out


class EquivalentFollower:
    """Discrete (29) for both channels at a fixed control period.

    Parameters
    ----------
    D, k_s, beta_e : array_like, shape (2,)
        Reference mass/inertia, gains, filter time constants [s] (> 0).
    dt : float
        Control period [s] (> 0); any value: the discretisation is exact.
    k_z : array_like, shape (2,)
        Gain on the fictitious force ``f_v`` (eq. 33); default 0.
    """

    def __init__(self, D: ArrayLike, k_s: ArrayLike, beta_e: ArrayLike, dt: float, k_z: ArrayLike = 0.0) -> None:
        self.D = np.broadcast_to(np.asarray(D, dtype=float), (2,)).copy()
        self.k_s = np.broadcast_to(np.asarray(k_s, dtype=float), (2,)).copy()
        self.beta_e = np.broadcast_to(np.asarray(beta_e, dtype=float), (2,)).copy()
        self.k_z = np.broadcast_to(np.asarray(k_z, dtype=float), (2,)).copy()
        if np.any(self.D <= 0) or np.any(self.k_s <= 0) or np.any(self.beta_e <= 0) or not dt > 0:
            raise ValueError("D, k_s, beta_e and dt: allowed: all > 0")
        self.dt = float(dt)
        self._x = np.zeros((2, 2))

    @classmethod
    def from_config(cls, cfg: ControlConfig, dt: float) -> EquivalentFollower:
        """Build from the ``[control]`` section."""
        return cls(cfg.D, cfg.k_s, cfg.beta_e, dt, k_z=cfg.k_z)

    @property
    def state(self) -> np.ndarray:
        """``[[eta_v, z_e_v], [eta_d, z_e_d]]`` [cm/s, deg/s] (a copy)."""
        return self._x.copy()

    @property
    def z_e(self) -> np.ndarray:
        """Equivalent speeds ``[z_e_v, z_e_d]`` [cm/s, deg/s]."""
        return self._x[:, 1].copy()

    def reset(self, value: ArrayLike = 0.0) -> None:
        """Rest state at speed ``value`` (``eta = z_e = value``) [cm/s, deg/s]."""
        v = np.broadcast_to(np.asarray(value, dtype=float), (2,))
        self._x = np.stack([v, v], -1).astype(float)

    def step(self, ref: ArrayLike, s_e: ArrayLike, f_v: ArrayLike = 0.0) -> np.ndarray:
        """Advance one period and return ``z_e`` [cm/s, deg/s].

        Parameters
        ----------
        ref : array_like, shape (2,)
            ``k_g x_m(t - h1)`` as received [cm/s, deg/s], held over the period.
        s_e : array_like, shape (2,)
            Equivalent damping for this period (may change every step).
        f_v : array_like, shape (2,)
            Fictitious force per channel (held), weighted by ``k_z``.
        """
        phi, gam = equivalent_zoh(s_e, self.D, self.k_s, self.beta_e, self.k_z, self.dt)
        u = np.stack(
            [np.broadcast_to(np.asarray(ref, dtype=float), (2,)), np.broadcast_to(np.asarray(f_v, dtype=float), (2,))],
            -1,
        )
        self._x = np.einsum("cij,cj->ci", phi, self._x) + np.einsum("cij,cj->ci", gam, u)
        return self._x[:, 1].copy()
