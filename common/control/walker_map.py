"""The walker's step-to-step map as a table: the surrogate of ``hybrid_model = "walker"``.

The online choice (30) matches ``max|l_hybrid|`` of a model of the walker against the
equivalent follower's radius. The reduced models (the paper's, and the follower's own
speed loop that ``bipedtele calibrate`` identifies) miss what the simulated walker does;
this table holds what its own Poincare map measured (``bipedtele poincare --table``,
:mod:`bipedtele.follower.sim.poincare`, docs/walker_map.md) over a grid of forward
damping ``sigma``, turn damping ``tau`` and walking cycle ``T`` at one joint servo ``eps``:

``rho``
    The spectral radius of the central-difference Jacobian (26) of the walker's map at its
    fixed point (the averaged touchdown state).
``limit_cycle``
    The walker oscillates by more than it is asked to walk (the per-tick forward or turn
    speed's standard deviation over the averaging cycles exceeds the reference): the turn
    loop's limit cycle at high ``tau``. The section can see a fixed point there (the
    oscillation is periodic in ``T``), so its radius alone does not flag it.
``fallen``
    The walker fell in some evaluation.

A grid node is *stable* when none of these flags it and ``rho < 1``. The surrogate's radius
at a point is the trilinear interpolation of ``rho``; a point whose interpolation gives
weight to an unstable node is in the unstable region (NaN). The core reads the shipped
table from package data (``bipedtele.data/walker_map.json``); it never imports the
follower that makes it.
"""

from __future__ import annotations

import bisect
import functools
import json
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["TABLE_FORMAT", "WalkerTable", "interp_weights", "load_walker_table", "parse_walker_table", "weights1"]

#: Format tag written by ``bipedtele poincare --table``.
TABLE_FORMAT = "bipedtele.walker_map/1"
#: The shipped table, in the package ``bipedtele.data``.
RESOURCE = "walker_map.json"


@dataclass(frozen=True, eq=False)  # array fields
class WalkerTable:
    """The tabulated walker map (arrays read-only).

    Attributes
    ----------
    sigma, tau : numpy.ndarray
        Forward and turn real damping of the grid (units of ``D``: cm/s and deg/s channels),
        strictly increasing.
    T : numpy.ndarray
        Walking cycles of the grid [s], strictly increasing.
    eps : float
        Joint servo time constant of every grid point [s].
    rho : numpy.ndarray, shape (len(sigma), len(tau), len(T))
        Radius of (26) at each node.
    limit_cycle, fallen : numpy.ndarray of bool, same shape
        The markers (module docstring).
    unstable : numpy.ndarray of bool, same shape
        ``limit_cycle | fallen | ~(rho < 1)``.
    source : str
        Where the table was read from.
    command : str
        The command that made it.
    """

    sigma: np.ndarray
    tau: np.ndarray
    T: np.ndarray
    eps: float
    rho: np.ndarray
    limit_cycle: np.ndarray
    fallen: np.ndarray
    unstable: np.ndarray
    source: str
    command: str

    def radius(self, sigma: float, tau: float, T: float) -> float:
        """Return the surrogate's radius at one point (trilinear; NaN in the unstable region or outside the grid)."""
        w = [weights1(ax, v) for ax, v in ((self.sigma, sigma), (self.tau, tau), (self.T, T))]
        if any(x is None for x in w):
            return float("nan")
        ws, wt, wc = (x for x in w if x is not None)
        full = ws[:, None, None] * wt[None, :, None] * wc[None, None, :]
        if np.any((full > 0) & self.unstable):
            return float("nan")
        return float(np.sum(full * np.where(self.unstable, 0.0, self.rho)))

    def in_unstable_region(self, sigma: float, tau: float, T: float) -> bool:
        """Whether the point's interpolation touches an unstable node (or lies outside the grid)."""
        return not np.isfinite(self.radius(sigma, tau, T))


def weights1(nodes: np.ndarray, x: float) -> np.ndarray | None:
    """Linear-interpolation weights of one point over ``nodes`` (None outside them); as :func:`interp_weights`."""
    n = nodes.size
    lo, hi = float(nodes[0]), float(nodes[-1])
    if not lo - 1e-12 <= x <= hi + 1e-12:
        return None
    w = np.zeros(n)
    if n == 1:
        w[0] = 1.0
        return w
    i = min(max(bisect.bisect_right(nodes.tolist(), x) - 1, 0), n - 2)
    a, b = float(nodes[i]), float(nodes[i + 1])
    frac = (x - a) / (b - a)
    frac = 0.0 if abs(frac) <= 1e-12 else 1.0 if abs(frac - 1.0) <= 1e-12 else frac
    w[i] = 1.0 - frac
    w[i + 1] += frac
    return w


def interp_weights(nodes: np.ndarray, x: ArrayLike) -> np.ndarray:
    """Linear-interpolation weights of the points ``x`` over ``nodes``, shape ``(len(x), len(nodes))``.

    Rows of points outside ``[nodes[0], nodes[-1]]`` are NaN. A point on a node has weight
    exactly 1 there (and 0 on its neighbours).
    """
    xs = np.atleast_1d(np.asarray(x, dtype=float))
    n = nodes.size
    w = np.zeros((xs.size, n))
    if n == 1:
        w[:, 0] = np.where(np.abs(xs - nodes[0]) <= 1e-12, 1.0, np.nan)
        return w
    i = np.clip(np.searchsorted(nodes, xs, side="right") - 1, 0, n - 2)
    frac = (xs - nodes[i]) / (nodes[i + 1] - nodes[i])
    frac = np.where(np.abs(frac) <= 1e-12, 0.0, np.where(np.abs(frac - 1.0) <= 1e-12, 1.0, frac))
    rows = np.arange(xs.size)
    w[rows, i] = 1.0 - frac
    w[rows, i + 1] += frac
    outside = (xs < nodes[0] - 1e-12) | (xs > nodes[-1] + 1e-12)
    w[outside] = np.nan
    return w


def _axis(data: Mapping[str, Any], key: str) -> np.ndarray:
    try:
        ax = np.asarray(data[key], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"walker table: {key!r} missing or not numbers") from None
    if ax.ndim != 1 or ax.size < 1 or not np.all(np.isfinite(ax)) or np.any(np.diff(ax) <= 0):
        raise ValueError(f"walker table: {key!r} = {ax.tolist()}: allowed: a strictly increasing list of numbers")
    ax.flags.writeable = False
    return ax


def parse_walker_table(data: Mapping[str, Any], source: str = "<data>") -> WalkerTable:
    """Check and convert the JSON of ``bipedtele poincare --table``.

    Raises
    ------
    ValueError
        One line naming what is wrong (format tag, axes, field shapes, markers).
    """
    if data.get("format") != TABLE_FORMAT:
        raise ValueError(f"walker table {source}: format {data.get('format')!r}: allowed: {TABLE_FORMAT!r}")
    sigma, tau, T = (_axis(data, k) for k in ("sigma", "tau", "T"))
    shape = (sigma.size, tau.size, T.size)
    fields: dict[str, np.ndarray] = {}
    for key, kind in (("rho", float), ("limit_cycle", bool), ("fallen", bool)):
        try:
            arr = np.asarray(data[key], dtype=kind)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"walker table {source}: {key!r} missing or malformed") from None
        if arr.shape != shape:
            raise ValueError(f"walker table {source}: {key!r} has shape {arr.shape}: allowed: {shape} (sigma, tau, T)")
        arr.flags.writeable = False
        fields[key] = arr
    eps = data.get("eps")
    if not isinstance(eps, int | float) or not eps > 0:
        raise ValueError(f"walker table {source}: eps = {eps!r}: allowed: a number > 0 (s)")
    rho = fields["rho"]
    with np.errstate(invalid="ignore"):
        unstable = fields["limit_cycle"] | fields["fallen"] | ~(rho < 1.0)
    unstable.flags.writeable = False
    if np.any(~np.isfinite(rho) & ~unstable):  # pragma: no cover - ~(rho < 1) already covers NaN
        raise ValueError(f"walker table {source}: a non-finite rho at a node not marked unstable")
    return WalkerTable(
        sigma=sigma,
        tau=tau,
        T=T,
        eps=float(eps),
        rho=rho,
        limit_cycle=fields["limit_cycle"],
        fallen=fields["fallen"],
        unstable=unstable,
        source=source,
        command=str(data.get("command", "")),
    )


@functools.lru_cache(maxsize=1)
def _shipped() -> WalkerTable:
    ref = resources.files("bipedtele.data").joinpath(RESOURCE)
    return parse_walker_table(json.loads(ref.read_text(encoding="utf-8")), f"bipedtele.data/{RESOURCE}")


def load_walker_table(path: str | Path | None = None) -> WalkerTable:
    """Read a walker table: ``path``, or the shipped one (package data, read once).

    Raises
    ------
    ValueError
        When the file is missing, not JSON or malformed (one line).
    """
    if path is None:
        try:
            return _shipped()
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"walker table bipedtele.data/{RESOURCE}: cannot read ({exc})") from None
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"walker table {path}: cannot read ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"walker table {path}: allowed: a JSON object")
    return parse_walker_table(data, str(path))
