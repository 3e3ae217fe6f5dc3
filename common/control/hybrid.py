"""The reduced hybrid follower (20)-(23), its Poincare map (24) and Jacobian (26).

Between impacts (no disturbances, ``f_v = 0``, constant references), per (20)-(23) with
(12), the error state (the paper's order, eq. 19)::

    e = [y1', y2 (6 joints), y2' (6 joints), y3', y4v, y4d]

    y1'' = -(k_v/M) y1' + sigma/(M beta_r) y4v                 forward speed error (20)
    y2'' = -(1/eps) y2' - (1/eps^2) y2                         joint servo (21)
    y3'' = -(k_d/I) y3' + tau/(I beta_r) y4d                   turn speed error (22)
    y4v' =  (k_v/M) y1' - (sigma/M + 1) y4v / beta_r           (23)
    y4d' =  (k_d/I) y3' - (tau/I + 1) y4d / beta_r

with ``y1' = v_ref - v_hip``, ``y3' = turn_ref - v_delta``, ``y4 = eta - z_r`` and
``sigma_r = [sigma, tau]``. (Eq. (19) prints ``+1/eps^2, +1/eps`` in the joint row, which
would be unstable; we use (21), which is what the text derives.)

At the impact the hip speed is scaled by ``dp`` (the turn speed by ``dp_turn``, 1 by
default); the observer state ``z_r`` and the joint errors are continuous (the leg swap
permutes identical joint channels, which leaves the spectrum unchanged, so we keep the
identity). In error coordinates the reset is affine::

    y1'+ = dp y1'- + (1 - dp) v_ref
    y4v+ = y4v- + (1 - dp) (y1'- - v_ref)

The Poincare map is taken just after the impact: ``P(e) = R Phi(T) e + c`` with
``Phi(T) = exp(A T)``; its fixed point is ``e* = (I - R Phi)^{-1} c`` (non-zero: the robot
loses speed at every impact and regains it in the cycle) and its Jacobian is ``R Phi(T)``
for every perturbation size, so the paper's ``dq = 1``, ``dqdot = 0.375`` are usable and
central differences are exact up to the integrator's error.

Units: forward channel cm/s, turn channel deg/s, joint errors rad (rad/s), times s.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.linalg import eig2, expm2, mat2
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp
from scipy.linalg import expm

__all__ = [
    "N_JOINTS",
    "STATE_NAMES",
    "T_min",
    "analytic_jacobian",
    "beta_e_def3",
    "continuous_matrix",
    "fixed_point",
    "jacobian_central",
    "orbit_speed_deficit",
    "perturbation_sizes",
    "poincare_map",
    "reset_map",
    "rho_blocks",
    "rho_hybrid",
    "rho_hybrid_grid",
    "rho_joint",
    "rho_speed_block",
    "s_r_min",
    "speed_block_matrix",
]

N_JOINTS = 6
_Y1, _Y3, _Y4V, _Y4D = 0, 1 + 2 * N_JOINTS, 2 + 2 * N_JOINTS, 3 + 2 * N_JOINTS
N_STATES = 4 + 2 * N_JOINTS
STATE_NAMES = (
    ["y1dot"]
    + [f"y2[{i}]" for i in range(N_JOINTS)]
    + [f"y2dot[{i}]" for i in range(N_JOINTS)]
    + ["y3dot", "y4v", "y4d"]
)


def _pair(x: ArrayLike) -> np.ndarray:
    return np.broadcast_to(np.asarray(x, dtype=float), (2,))


# ----------------------------------------------------------------------------- full model


def continuous_matrix(s_r: ArrayLike, eps: float, cfg: ControlConfig) -> np.ndarray:
    """Return the matrix ``A`` of ``e' = A e`` between impacts (16 x 16), eqs. (20)-(23)."""
    sig, tau = _pair(s_r)
    (m, i_), (kv, kd), (bv, bd) = _pair(cfg.D), _pair(cfg.k_s), _pair(cfg.beta_r)
    a = np.zeros((N_STATES, N_STATES))
    a[_Y1, _Y1] = -kv / m
    a[_Y1, _Y4V] = sig / (m * bv)
    a[_Y4V, _Y1] = kv / m
    a[_Y4V, _Y4V] = -(sig / m + 1.0) / bv
    a[_Y3, _Y3] = -kd / i_
    a[_Y3, _Y4D] = tau / (i_ * bd)
    a[_Y4D, _Y3] = kd / i_
    a[_Y4D, _Y4D] = -(tau / i_ + 1.0) / bd
    for j in range(N_JOINTS):
        q, qd = 1 + j, 1 + N_JOINTS + j
        a[q, qd] = 1.0
        a[qd, q] = -1.0 / eps**2
        a[qd, qd] = -1.0 / eps
    return a


def reset_map(dp: float, cfg: ControlConfig) -> tuple[np.ndarray, np.ndarray]:
    """Affine reset ``e+ = R e- + c`` at impact (hip speed scaled by ``dp``).

    Returns
    -------
    (R, c)
        ``R`` (16 x 16) and ``c`` (16,) [cm/s, deg/s].
    """
    r = np.eye(N_STATES)
    c = np.zeros(N_STATES)
    for y, y4, f, ref in ((_Y1, _Y4V, dp, cfg.v_ref), (_Y3, _Y4D, cfg.dp_turn, cfg.turn_ref)):
        r[y, y] = f
        r[y4, y] = 1.0 - f
        c[y] = (1.0 - f) * ref
        c[y4] = -(1.0 - f) * ref
    return r, c


def poincare_map(
    e: ArrayLike,
    s_r: ArrayLike,
    T: float,
    eps: float,
    dp: float,
    cfg: ControlConfig,
    *,
    method: str = "ivp",
) -> np.ndarray:
    """One walking cycle: integrate (20)-(23) over ``T`` [s], then apply the reset.

    Parameters
    ----------
    e : array_like, shape (16,)
        Error state just after an impact (order :data:`STATE_NAMES`).
    s_r : array_like, shape (2,)
        Real damping ``[sigma, tau]``.
    T : float
        Walking cycle time [s].
    eps : float
        Joint servo time constant [s] (bandwidth ``1/eps``).
    dp : float
        Hip-speed factor of the reset, in (0, 1].
    method : {"ivp", "expm"}
        ``ivp``: numerical integration (``scipy.integrate.solve_ivp``, DOP853, rtol 1e-11);
        ``expm``: the exact state-transition matrix.
    """
    a = continuous_matrix(s_r, eps, cfg)
    e0 = np.asarray(e, dtype=float)
    if method == "ivp":
        sol = solve_ivp(lambda _t, y: a @ y, (0.0, T), e0, method="DOP853", rtol=1e-11, atol=1e-12)
        if not sol.success:
            raise RuntimeError(f"Poincare map integration failed: {sol.message}")
        e_minus = sol.y[:, -1]
    elif method == "expm":
        e_minus = expm(a * T) @ e0
    else:
        raise ValueError(f"method = {method!r}: allowed: ivp, expm")
    r, c = reset_map(dp, cfg)
    return np.asarray(r @ e_minus + c)


def analytic_jacobian(s_r: ArrayLike, T: float, eps: float, dp: float, cfg: ControlConfig) -> np.ndarray:
    """``DP = R exp(A T)``: reset matrix times the cycle's state-transition matrix."""
    r, _ = reset_map(dp, cfg)
    return np.asarray(r @ expm(continuous_matrix(s_r, eps, cfg) * T))


def fixed_point(s_r: ArrayLike, T: float, eps: float, dp: float, cfg: ControlConfig) -> np.ndarray:
    """Return the fixed point ``e* = P(e*)`` (the periodic orbit at the impact surface)."""
    _, c = reset_map(dp, cfg)
    j = analytic_jacobian(s_r, T, eps, dp, cfg)
    return np.asarray(np.linalg.solve(np.eye(N_STATES) - j, c))


def perturbation_sizes(cfg: ControlConfig) -> np.ndarray:
    """Per-state perturbations of (26): ``dq`` on joint angles, ``dqdot`` on every rate.

    The speed states (y1', y3', y4) are rates, so they get ``dqdot`` as well (the paper's
    ``Delta p`` is used for the reset factor, see docs/method.md).
    """
    d = np.full(N_STATES, cfg.dqdot)
    d[1 : 1 + N_JOINTS] = cfg.dq
    return d


def jacobian_central(
    s_r: ArrayLike,
    T: float,
    eps: float,
    dp: float,
    cfg: ControlConfig,
    *,
    e_star: ArrayLike | None = None,
    delta: ArrayLike | None = None,
    method: str = "ivp",
) -> np.ndarray:
    """Jacobian of the Poincare map by central differences, eq. (26).

    Column ``i`` is ``(P(e* + d_i u_i) - P(e* - d_i u_i)) / (2 d_i)``, ``2 n`` evaluations of
    :func:`poincare_map`.

    Parameters
    ----------
    e_star : array_like, optional
        Linearisation point; default :func:`fixed_point`.
    delta : array_like, optional
        Perturbation per state; default :func:`perturbation_sizes` (``dq``, ``dqdot``).
    method : {"ivp", "expm"}
        How :func:`poincare_map` integrates.
    """
    e0 = fixed_point(s_r, T, eps, dp, cfg) if e_star is None else np.asarray(e_star, dtype=float)
    d = perturbation_sizes(cfg) if delta is None else np.broadcast_to(np.asarray(delta, dtype=float), (N_STATES,))
    jac = np.empty((N_STATES, N_STATES))
    for i in range(N_STATES):
        u = np.zeros(N_STATES)
        u[i] = d[i]
        jac[:, i] = (
            poincare_map(e0 + u, s_r, T, eps, dp, cfg, method=method)
            - poincare_map(e0 - u, s_r, T, eps, dp, cfg, method=method)
        ) / (2.0 * d[i])
    return jac


# ------------------------------------------------------------------ block closed forms


def speed_block_matrix(sigma: ArrayLike, D: float, k: float, beta_r: float) -> np.ndarray:
    """2x2 ``A`` of a speed channel ``[y', y4]`` (forward or turn), broadcast over ``sigma``."""
    s = np.asarray(sigma, dtype=float)
    return np.asarray(mat2(-k / D + 0.0 * s, s / (D * beta_r), k / D + 0.0 * s, -(s / D + 1.0) / beta_r))


def rho_speed_block(sigma: ArrayLike, T: ArrayLike, D: float, k: float, beta_r: float, dp: float) -> np.ndarray:
    """Spectral radius of ``R exp(A T)`` for one speed channel, broadcast over ``sigma, T``."""
    s, t = np.broadcast_arrays(np.asarray(sigma, dtype=float), np.asarray(T, dtype=float))
    phi = expm2(speed_block_matrix(s, D, k, beta_r), t)
    r = np.array([[dp, 0.0], [1.0 - dp, 1.0]])
    l1, l2 = eig2(r @ phi)
    return np.asarray(np.maximum(np.abs(l1), np.abs(l2)))


def orbit_speed_deficit(sigma: ArrayLike, T: ArrayLike, D: float, k: float, beta_r: float, dp: float) -> np.ndarray:
    """Mean speed deficit of the periodic orbit, as a fraction of a constant reference.

    For a constant reference ``r`` one speed channel (``[eta, z_r]`` with (20), (12)) walks
    on a periodic orbit: it loses ``(1 - dp)`` of its speed at every impact and regains
    it towards ``r`` between impacts. The returned ``d`` is ``1 - mean(eta)/r`` over one
    cycle of that orbit (the offset the resets cause even without delay or command
    changes); it does not depend on ``r`` (the model is linear). Broadcast over
    ``sigma`` and ``T`` [s].

    In deviations ``y = [eta, z_r] - [r, r]`` (``y' = A y`` between impacts) the reset is
    ``y+ = R y- + [(dp - 1) r, 0]``, so the post-impact fixed point is
    ``y* = (I - R Phi(T))^{-1} [(dp - 1) r, 0]`` and the cycle mean of ``eta - r`` is
    ``[A^{-1} (Phi(T) - I) y*]_0 / T``.
    """
    s, t = np.broadcast_arrays(np.asarray(sigma, dtype=float), np.asarray(T, dtype=float))
    a = mat2(-k / D - s / (D * beta_r), s / (D * beta_r), 1.0 / beta_r + 0.0 * s, -1.0 / beta_r + 0.0 * s)
    phi = expm2(a, t)
    eye = np.eye(2)
    r = np.array([[dp, 0.0], [0.0, 1.0]])
    c = np.broadcast_to(np.array([[dp - 1.0], [0.0]]), (*s.shape, 2, 1))
    y_star = np.linalg.solve(eye - r @ phi, c)
    integral = np.linalg.solve(a, (phi - eye) @ y_star)
    return np.asarray(-integral[..., 0, 0] / t)


def rho_joint(T: ArrayLike, eps: ArrayLike) -> np.ndarray:
    """Spectral radius of the joint-servo block over a cycle: ``exp(-T / (2 eps))``.

    The eigenvalues of (21) are ``(-1 +- i sqrt(3)) / (2 eps)``.
    """
    return np.exp(-np.asarray(T, dtype=float) / (2.0 * np.asarray(eps, dtype=float)))


def rho_blocks(
    sigma: ArrayLike, tau: ArrayLike, T: ArrayLike, eps: ArrayLike, dp: float, cfg: ControlConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spectral radii of the forward, turn and joint blocks (broadcast)."""
    (m, i_), (kv, kd), (bv, bd) = _pair(cfg.D), _pair(cfg.k_s), _pair(cfg.beta_r)
    return (
        rho_speed_block(sigma, T, m, kv, bv, dp),
        rho_speed_block(tau, T, i_, kd, bd, cfg.dp_turn),
        rho_joint(T, eps) + 0.0 * np.asarray(sigma, dtype=float),
    )


def rho_hybrid(s_r: ArrayLike, T: float, eps: float, dp: float, cfg: ControlConfig) -> float:
    """``max|lambda_hybrid|``: spectral radius of the Poincare-map Jacobian.

    Equal to ``max(abs(eigvals(analytic_jacobian(...))))``, computed per block in closed form.
    """
    sig, tau = _pair(s_r)
    return float(np.max(np.stack(rho_blocks(sig, tau, T, eps, dp, cfg))))


def rho_hybrid_grid(
    s_r: ArrayLike, T: ArrayLike, eps: ArrayLike, dp: float, cfg: ControlConfig, *, s_r_turn: ArrayLike | None = None
) -> np.ndarray:
    """Return ``max|lambda_hybrid|``, vectorised.

    Broadcast over ``s_r`` (both channels unless ``s_r_turn`` is given), ``T`` and ``eps``.
    """
    tau = s_r if s_r_turn is None else s_r_turn
    fwd, turn, joint = rho_blocks(s_r, tau, T, eps, dp, cfg)
    return np.asarray(np.maximum(np.maximum(fwd, turn), joint))


# ---------------------------------------------------------------------- definitions 1-3


def _first_crossing(f: Callable[[float], float], lo: float, hi: float, level: float, n: int = 400) -> float | None:
    """Smallest x in [lo, hi] where ``f(x) - level`` changes sign (scan + bisection)."""
    xs = np.linspace(lo, hi, n)
    g = np.array([f(x) for x in xs]) - level
    if g[0] == 0.0:
        return lo
    idx = np.nonzero(np.sign(g[1:]) != np.sign(g[:-1]))[0]
    if idx.size == 0:
        return None
    a, b = xs[idx[0]], xs[idx[0] + 1]
    ga = g[idx[0]]
    for _ in range(60):
        mid = 0.5 * (a + b)
        gm = f(mid) - level
        if np.sign(gm) == np.sign(ga):
            a, ga = mid, gm
        else:
            b = mid
    return float(0.5 * (a + b))


def T_min(
    cfg: ControlConfig,
    *,
    dp_min: float | None = None,
    s_r_min: float | None = None,
    eps_min: float | None = None,
    level: float = 1.0,
    T_bounds: tuple[float, float] = (1e-3, 20.0),
) -> float | None:
    """Definition 1: the smallest ``T`` [s] at which ``max|lambda_hybrid|`` reaches ``level``.

    Evaluated at ``dp = dp_min`` (default ``cfg.dp``), ``sigma_r = s_r_min`` (default
    ``cfg.s_e_min``) and ``eps = eps_min`` (default the lower end of ``eps_range``). Returns
    the crossing of ``rho(T) = level`` in ``T_bounds``, ``T_bounds[0]`` if ``rho`` is already
    below ``level`` there, ``None`` if it never gets below. For the reduced linear model
    ``rho < 1`` for every ``T > 0`` (``rho -> 1`` as ``T -> 0``), so with ``level = 1`` this
    is the lower search bound; a ``level < 1`` (a required contraction per cycle) gives a
    meaningful bound. See docs/method.md.
    """
    dp = cfg.dp if dp_min is None else dp_min
    s = cfg.s_e_min if s_r_min is None else s_r_min
    e = cfg.eps_range[0] if eps_min is None else eps_min

    def f(t: float) -> float:
        return rho_hybrid([s, s], t, e, dp, cfg)

    if f(T_bounds[0]) <= level:
        return T_bounds[0]
    return _first_crossing(f, T_bounds[0], T_bounds[1], level)


def s_r_min(
    cfg: ControlConfig,
    T: float,
    *,
    dp_min: float | None = None,
    eps_min: float | None = None,
    level: float = 1.0,
) -> float | None:
    """Return Definition 2's bound: the smallest real damping where ``max|lambda_hybrid|`` is ``level``.

    For a cycle ``T`` [s]; ``None`` if it stays below ``level`` over ``s_r_range``.
    """
    dp = cfg.dp if dp_min is None else dp_min
    e = cfg.eps_range[0] if eps_min is None else eps_min
    lo, hi = cfg.s_r_range

    def f(s: float) -> float:
        return rho_hybrid([s, s], T, e, dp, cfg)

    if f(lo) >= level:
        return float(lo)
    return _first_crossing(f, lo, hi, level)


def beta_e_def3(
    cfg: ControlConfig,
    dt: float,
    *,
    method: str = "euler",
    level: float = 1.0,
    bounds: tuple[float, float] = (1e-4, 100.0),
) -> float | None:
    """Return Definition 3's bound: the smallest ``beta_e`` [s] that makes (29) stable enough.

    That is, the discretised (29) with ``sigma_e = s_e_min`` has
    ``max|lambda_equivalent| <= level``.

    ``method="euler"`` (forward Euler at ``dt``): the discrete eigenvalues ``1 + dt l`` leave
    the unit circle for small ``beta_e``, so the definition gives the stability boundary.
    ``method="zoh"`` (exact): ``exp(l dt)`` is inside the unit circle for every ``beta_e > 0``,
    so the result is the lower bound ``bounds[0]`` (the definition is vacuous).
    """
    d = np.asarray(cfg.D, dtype=float)
    k = np.asarray(cfg.k_s, dtype=float)
    s = cfg.s_e_min

    def radius(b: float) -> float:
        half = 0.5 * (s + d) / (d * b)
        root = np.sqrt((half * half - k / (d * b)).astype(complex))
        lam = np.concatenate([-half + root, -half - root])
        z = 1.0 + dt * lam if method == "euler" else np.exp(lam * dt)
        return float(np.max(np.abs(z)))

    if method not in ("euler", "zoh"):
        raise ValueError(f"method = {method!r}: allowed: euler, zoh")
    if radius(bounds[0]) <= level:
        return bounds[0]
    lo, hi = bounds
    if radius(hi) > level:
        return None
    for _ in range(200):
        mid = np.sqrt(lo * hi)
        if radius(mid) > level:
            lo = mid
        else:
            hi = mid
        if hi / lo < 1 + 1e-12:
            break
    return float(hi)
