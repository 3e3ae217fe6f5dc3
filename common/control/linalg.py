"""Closed-form 2x2 matrix functions, vectorised over leading axes.

The controllers of the paper are decoupled per channel into 2x2 linear blocks, so grids of
stability figures and the study's per-run discretisations reduce to many 2x2 matrix
exponentials and eigenvalue problems. These helpers do them in closed form with numpy
broadcasting (``...`` = any leading shape).
"""

from __future__ import annotations

import numpy as np

__all__ = ["eig2", "expm2", "mat2", "mul2", "zoh2"]


def mat2(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Stack entries into matrices ``[[a, b], [c, d]]`` of shape ``(..., 2, 2)``."""
    a, b, c, d = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (a, b, c, d)))
    return np.stack([np.stack([a, b], -1), np.stack([c, d], -1)], -2)


def mul2(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Batched 2x2 matrix product ``x @ y``."""
    return np.asarray(np.asarray(x) @ np.asarray(y))


def eig2(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both eigenvalues of ``(..., 2, 2)`` matrices (complex arrays of shape ``(...)``)."""
    m = np.asarray(m, dtype=float)
    half_tr = 0.5 * (m[..., 0, 0] + m[..., 1, 1])
    det = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] * m[..., 1, 0]
    root = np.sqrt((half_tr * half_tr - det).astype(complex))
    return half_tr + root, half_tr - root


def expm2(a: np.ndarray, t: np.ndarray | float = 1.0) -> np.ndarray:
    """``exp(a t)`` for ``(..., 2, 2)`` matrices ``a`` and times ``t`` broadcast to ``(...)``.

    Uses ``exp(A t) = e^{m t} (cosh(q t) I + sinh(q t)/q (A - m I))`` with
    ``m = tr(A)/2`` and ``q^2 = m^2 - det(A)`` (``q`` complex when the eigenvalues are).
    """
    a = np.asarray(a, dtype=float)
    t = np.asarray(t, dtype=float)
    m = 0.5 * (a[..., 0, 0] + a[..., 1, 1])
    det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    q = np.sqrt((m * m - det).astype(complex))
    qt = q * t
    small = np.abs(qt) < 1e-6
    # sinh(qt)/q, with its series where qt is tiny (repeated eigenvalue).
    q_safe = np.where(small, 1.0, q)
    shq = np.where(small, t * (1.0 + qt * qt / 6.0), np.sinh(qt) / q_safe)
    ch = np.cosh(qt)
    em = np.exp(m * t)
    c0 = (em * (ch - m * shq)).real
    c1 = (em * shq).real
    eye = np.eye(2)
    return np.asarray(c0[..., None, None] * eye + c1[..., None, None] * a)


def zoh2(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of ``x' = A x + B u`` for 2x2 ``A``.

    Parameters
    ----------
    a : array, shape (..., 2, 2)
        System matrices; must be invertible (all blocks in this package are Hurwitz).
    b : array, shape (..., 2, m)
        Input matrices.
    dt : float
        Sample period [s].

    Returns
    -------
    (Phi, Gamma)
        ``x[k+1] = Phi x[k] + Gamma u[k]`` with ``Gamma = A^{-1} (Phi - I) B``.
    """
    phi = expm2(a, dt)
    gam = np.linalg.solve(a, (phi - np.eye(2)) @ np.asarray(b, dtype=float))
    return phi, gam
