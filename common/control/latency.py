"""The reduced turn loop (22)-(23) closed through the gait's command latency (issue 31, item 4).

The reduced model (20)-(23) lets the robot realise the commanded turn speed ``eta`` at once.
The simulated walker's gait latches commands at step boundaries (every ``h = T/2``) and
realises the latched turn rate over the whole step (docs/method_latency.md measures it).
Here the turn block is closed through that latency, in two ways.

Turn block (perturbations about a constant reference; ``v`` the robot's turn speed,
``I = D[1]``, ``k = k_s[1]``, ``beta = beta_r[1]``, ``tau`` the turn damping)::

    beta z' = v - z                                    observer (12) / (23)
    I eta'  = -k v - tau z'      form "paper"          (22): the gain acts on the robot's speed
    I eta'  = -k z - tau z'      form "servo"          (28): the follower's servo, gain on z_r

With ``v = eta`` the "paper" form is the turn block of :mod:`bipedtele.control.hybrid`
(the same characteristic polynomial). ``x = [eta, z]``, ``x' = A x + B v``.

Delay (:func:`delay_onset`, :func:`delay_radius`)
    ``v(t) = eta(t - L)``: a pure delay. The onset (the smallest ``tau`` with a root of
    the characteristic quasi-polynomial on the imaginary axis) in closed form; the radius
    per cycle by a state-augmented discretisation (the delay as a shift register of
    ``N = L/dt`` samples, the delayed speed held over ``dt``).
Latched (:func:`latched_step_map`, :func:`latched_radius`, :func:`latched_onset`)
    ``v(t) = eta(t_n)`` on ``[t_n, t_n + h)``: the gait's latch, exactly (a zero-order hold
    of the step length). The map over one step is ``M = exp(A h) + G(h) B e_eta^T`` with
    ``G(h) = int_0^h exp(A s) ds``; over one walking cycle (two steps) it is ``M^2``. The
    onset is the smallest ``tau`` where the radius of ``M`` reaches 1. With ``k = 0`` the
    "paper" form has the eigenvalues 1 and ``a - (tau/I)(1 - a)``, ``a = exp(-h/beta)``, so
    the flip (eigenvalue -1, a period of two steps: one walking cycle) comes at
    ``tau = I coth(h / (2 beta))``.

Units: turn speeds deg/s, times s, ``tau`` and ``I`` in the model's units (docs/method.md).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from bipedtele.control.config import ControlConfig
from scipy.linalg import expm
from scipy.optimize import brentq

__all__ = [
    "Form",
    "delay_onset",
    "delay_radius",
    "latched_onset",
    "latched_radius",
    "latched_step_map",
    "latched_step_map_discrete",
    "turn_block",
]

Form = Literal["paper", "servo"]


def _turn_params(cfg: ControlConfig) -> tuple[float, float, float]:
    return float(cfg.D[1]), float(cfg.k_s[1]), float(cfg.beta_r[1])


def turn_block(tau: float, cfg: ControlConfig, form: Form = "paper") -> tuple[np.ndarray, np.ndarray]:
    """Return ``(A, B)`` of the turn block ``x' = A x + B v``, ``x = [eta, z]`` [deg/s].

    Parameters
    ----------
    tau : float
        Turn damping (model units).
    form : {"paper", "servo"}
        Where the gain ``k`` acts: on the robot's speed ``v`` (22) or on the observer's
        estimate ``z`` (28).
    """
    i_, k, beta = _turn_params(cfg)
    if form == "paper":
        a = np.array([[0.0, tau / (i_ * beta)], [0.0, -1.0 / beta]])
        b = np.array([-k / i_ - tau / (i_ * beta), 1.0 / beta])
    elif form == "servo":
        a = np.array([[0.0, -k / i_ + tau / (i_ * beta)], [0.0, -1.0 / beta]])
        b = np.array([-tau / (i_ * beta), 1.0 / beta])
    else:
        raise ValueError(f"form = {form!r}: allowed: paper, servo")
    return a, b


# ------------------------------------------------------------------------------ delay


def delay_onset(L: float, cfg: ControlConfig, form: Form = "paper", *, omega_max: float = 200.0) -> tuple[float, float]:
    """Smallest ``tau >= 0`` at which the turn loop with a pure delay ``L`` [s] is marginal.

    At ``s = j w`` the characteristic equation ``I s (beta s + 1) + (k (beta s + 1) + tau s)
    e^{-s L} = 0`` ("paper"; "servo": ``k`` instead of ``k (beta s + 1)``) is linear in
    ``tau``: its real part fixes ``w``, its imaginary part gives ``tau(w)``. Every root
    ``w`` in ``(0, omega_max]`` is found (a fine scan and Brent's method) and the smallest
    ``tau(w) >= 0`` is returned with its ``w`` [rad/s]; ``(inf, nan)`` when there is none
    (the loop is stable at every ``tau``, as without delay).
    """
    i_, k, beta = _turn_params(cfg)
    if L < 0:
        raise ValueError(f"L = {L}: allowed: >= 0 s")

    def gap(w: np.ndarray | float) -> np.ndarray:
        # -I j w (1 + j beta w) e^{j w L} - k-part: what j tau w must equal
        w = np.asarray(w, dtype=float)
        k_part = k * (1.0 + 1j * beta * w) if form == "paper" else k + 0j * w
        return np.asarray(-i_ * 1j * w * (1.0 + 1j * beta * w) * np.exp(1j * w * L) - k_part)

    def re_gap(w: float) -> float:
        return float(gap(w).real)

    ws = np.linspace(1e-6, omega_max, 200_001)
    g = gap(ws).real
    best = (math.inf, math.nan)
    for j in np.nonzero(np.sign(g[1:]) != np.sign(g[:-1]))[0]:
        w = brentq(re_gap, ws[j], ws[j + 1], xtol=1e-13)
        tau = float(gap(w).imag) / w
        if tau >= 0.0 and tau < best[0]:
            best = (float(tau), float(w))
    return best


def delay_radius(tau: float, T: float, L: float, cfg: ControlConfig, form: Form = "paper", dt: float = 0.005) -> float:
    """Spectral radius over one walking cycle ``T`` [s] of the turn loop with a delay ``L`` [s].

    State-augmented: ``x`` is sampled every ``dt`` [s], the delayed speed ``eta(t - N dt)``
    (``N = round(L/dt)``) is held over each ``dt`` (exact for ``L = 0``, where the closed
    loop is integrated exactly; otherwise the hold adds about ``dt/2`` to the delay). The
    radius per cycle is the per-sample radius to the power ``T/dt``.
    """
    a, b = turn_block(tau, cfg, form)
    n = round(L / dt)
    if n == 0:
        closed = a + np.outer(b, [1.0, 0.0])
        return float(np.max(np.abs(np.linalg.eigvals(expm(closed * T)))))
    aug = np.zeros((3, 3))
    aug[:2, :2], aug[:2, 2] = a, b
    e = expm(aug * dt)
    phi, gam = e[:2, :2], e[:2, 2]
    # state [x (2), eta_{n-1}, ..., eta_{n-N}]
    m = np.zeros((2 + n, 2 + n))
    m[:2, :2] = phi
    m[:2, 1 + n] = gam
    m[2, 0] = 1.0
    for j in range(1, n):
        m[2 + j, 1 + j] = 1.0
    r = float(np.max(np.abs(np.linalg.eigvals(m))))
    return float(r ** (T / dt))


# ---------------------------------------------------------------------------- latched


def latched_step_map(tau: float, h: float, cfg: ControlConfig, form: Form = "paper") -> np.ndarray:
    """Map of ``[eta, z]`` over one gait step of ``h`` [s] with the turn latched at its start."""
    a, b = turn_block(tau, cfg, form)
    aug = np.zeros((3, 3))
    aug[:2, :2], aug[:2, 2] = a, b
    e = expm(aug * h)
    return np.asarray(e[:2, :2] + np.outer(e[:2, 2], [1.0, 0.0]))


def latched_step_map_discrete(
    tau: float, h: float, cfg: ControlConfig, form: Form = "paper", dt: float = 0.02
) -> np.ndarray:
    """Map of ``[eta, z, v]`` over one gait step of ``h`` [s] with the servo run every ``dt`` [s].

    The servo as :class:`~bipedtele.control.reference.RealFollowerReference` runs it: per
    tick the observer (12) takes the turn rate measured over the tick (the latched ``v``)
    exactly (``z <- a z + (1 - a) v``, ``a = exp(-dt/beta)``), then ``eta`` takes a forward
    Euler step of (22) ("paper") or (28) ("servo") with ``z' = (z_new - z_old)/dt``. After
    the ``h/dt`` ticks of the step the gait latches ``v <- eta`` (the command of the
    boundary's own tick). ``h`` must be a multiple of ``dt``.
    """
    i_, k, beta = _turn_params(cfg)
    n = round(h / dt)
    if abs(n * dt - h) > 1e-9 or n < 1:
        raise ValueError(f"h = {h}, dt = {dt}: allowed: h a positive multiple of dt")
    a = math.exp(-dt / beta)
    # rows: z_new, dz, then eta_new over [eta, z, v]
    z_new = np.array([0.0, a, 1.0 - a])
    dz = (z_new - np.array([0.0, 1.0, 0.0])) / dt
    gain_on = z_new if form == "servo" else np.array([0.0, 0.0, 1.0])
    if form not in ("paper", "servo"):
        raise ValueError(f"form = {form!r}: allowed: paper, servo")
    eta_new = np.array([1.0, 0.0, 0.0]) + dt / i_ * (-k * gain_on - tau * dz)
    tick = np.array([eta_new, z_new, [0.0, 0.0, 1.0]])
    latch = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    return np.asarray(latch @ np.linalg.matrix_power(tick, n))


def latched_radius(tau: float, T: float, cfg: ControlConfig, form: Form = "paper", dt: float | None = None) -> float:
    """Spectral radius over one walking cycle ``T`` [s] (two latched steps of ``T/2``).

    ``dt`` [s]: the servo's period (:func:`latched_step_map_discrete`); None: a continuous
    servo (:func:`latched_step_map`).
    """
    h = T / 2.0
    m = latched_step_map(tau, h, cfg, form) if dt is None else latched_step_map_discrete(tau, h, cfg, form, dt)
    return float(np.max(np.abs(np.linalg.eigvals(m)))) ** 2


def latched_onset(
    T: float, cfg: ControlConfig, form: Form = "paper", *, dt: float | None = None, tau_max: float = 20.0, n: int = 400
) -> tuple[float, complex]:
    """Smallest ``tau`` in ``(0, tau_max]`` where the latched loop's step radius reaches 1.

    Scan of ``n`` values, then bisection. Returns ``tau`` and the step map's eigenvalue of
    largest modulus there (real and near -1: a flip, a period of two steps, one cycle ``T``).
    ``(inf, nan)`` when the radius stays below 1.
    """
    h = T / 2.0

    def step_map(tau: float) -> np.ndarray:
        return latched_step_map(tau, h, cfg, form) if dt is None else latched_step_map_discrete(tau, h, cfg, form, dt)

    def excess(tau: float) -> float:
        return float(np.max(np.abs(np.linalg.eigvals(step_map(tau))))) - 1.0

    taus = np.linspace(tau_max / n, tau_max, n)
    g = np.array([excess(t) for t in taus])
    # the "paper" form with k = 0 has the eigenvalue 1 at every tau: excess ~ 0, ignore roundoff
    above = np.nonzero(g > 1e-9)[0]
    if above.size == 0:
        return math.inf, complex(math.nan)
    j = int(above[0])
    lo = float(taus[j - 1]) if j > 0 else 0.0
    hi = float(taus[j])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if excess(mid) > 1e-9:
            hi = mid
        else:
            lo = mid
    tau = 0.5 * (lo + hi)
    lam = np.linalg.eigvals(step_map(hi))
    return tau, complex(lam[np.argmax(np.abs(lam))])
