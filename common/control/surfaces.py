"""Stability surfaces (Fig. 6): ``max|l_hybrid|`` over ``sigma_r`` x ``T`` for several ``dp``.

``sigma_r`` is applied to both channels (``[sigma, sigma]``) and ``eps`` is the configured
value, as in the paper's figure. Besides the full ``max|l_hybrid|`` (``rho``) the forward
(hip) block alone is returned (``rho_forward``): it is the only block the reset factor
``dp`` acts on, while the turn block (no reset by default) can dominate the maximum.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.hybrid import rho_blocks

__all__ = ["compute_surfaces", "plot_surfaces"]


def compute_surfaces(
    dps: Sequence[float],
    cfg: ControlConfig,
    *,
    n_sigma: int = 41,
    n_T: int = 46,
) -> dict[str, Any]:
    """Surfaces over ``s_r_range`` x ``T_range``.

    Returns
    -------
    dict
        ``{"dp": [...], "sigma_r": [...], "T": [...], "eps": eps, "rho": [[[...]]],
        "rho_forward": [[[...]]]}``, ``rho`` indexed ``[dp][sigma_r][T]``.
    """
    sigma = np.linspace(cfg.s_r_range[0], cfg.s_r_range[1], n_sigma)
    T = np.linspace(cfg.T_range[0], cfg.T_range[1], n_T)
    rho, fwd = [], []
    for dp in dps:
        if not 0.0 < dp <= 1.0:
            raise ValueError(f"dp = {dp}: allowed: 0 < dp <= 1")
        f, t, j = rho_blocks(sigma[:, None], sigma[:, None], T[None, :], cfg.eps, dp, cfg)
        rho.append(np.maximum(np.maximum(f, t), j))
        fwd.append(f)
    return {
        "dp": [float(d) for d in dps],
        "sigma_r": sigma.tolist(),
        "T": T.tolist(),
        "eps": cfg.eps,
        "rho": np.array(rho).tolist(),
        "rho_forward": np.array(fwd).tolist(),
    }


def plot_surfaces(data: dict[str, Any]) -> Any:
    """3-D surfaces of ``rho`` (top row) and of the forward block (bottom row) per ``dp``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    n = len(data["dp"])
    fig = Figure(figsize=(4.0 * n, 7.0), layout="constrained")
    s, t = np.meshgrid(np.asarray(data["sigma_r"]), np.asarray(data["T"]), indexing="ij")
    for row, key, label in ((0, "rho", "max|l_hybrid|"), (1, "rho_forward", "forward block")):
        for i, dp in enumerate(data["dp"]):
            ax = fig.add_subplot(2, n, row * n + i + 1, projection="3d")
            ax.plot_surface(s, t, np.asarray(data[key][i]), cmap="viridis", linewidth=0)
            ax.set_xlabel("sigma_r")
            ax.set_ylabel("T [s]")
            ax.set_zlabel(label)
            ax.set_zlim(0.0, 1.0)
            ax.set_title(f"{label}, dp = {dp:g}")
    return fig


def plot_equivalent_trend(cfg: ControlConfig, periods: Sequence[float] = (0.5, 1.0, 2.0)) -> Any:
    """``max|l_equivalent|`` per channel against ``sigma_e`` for several periods [s].

    The figure behind docs/method.md's check of the claim "sigma_e up => max|l_equivalent|
    down" (Sec. 3.3, Fig. 7).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from bipedtele.control.equivalent import equivalent_max_real
    from matplotlib.figure import Figure

    s = np.linspace(0.0, 10.0, 401)
    fig = Figure(figsize=(8.0, 3.4), layout="constrained")
    axes = fig.subplots(1, 2)
    for c, (ax, name) in enumerate(zip(axes, ("forward (D = M)", "turn (D = I)"), strict=True)):
        se = np.zeros((s.size, 2))
        se[:, c] = s
        re = equivalent_max_real(se, cfg)[:, c]
        for dt in periods:
            ax.plot(s, np.exp(dt * re), label=f"period {dt:g} s")
        d = cfg.D[c]
        crit = 2.0 * np.sqrt(cfg.k_s[c] * d * cfg.beta_e[c]) - d
        if crit > 0:
            ax.axvline(crit, color="k", lw=0.8, ls="--", label=f"critical sigma_e = {crit:.3f}")
        ax.set_xlabel("sigma_e")
        ax.set_ylabel("max|l_equivalent|")
        ax.set_title(name)
        ax.legend(fontsize=8)
    return fig
