"""Figures of the control core's analyses: Fig. 6 surfaces, the eq. (29) trend, Fig. 8, the schemes.

Each function takes what :mod:`bipedtele.control` computes and returns a
:class:`matplotlib.figure.Figure` (no pyplot: nothing shown or written); the caller saves it.
matplotlib is the ``plots`` extra, imported by the functions that draw (this module
imports without it: :func:`require_matplotlib` checks for it up front).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from bipedtele.config.profile import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.control.equivalent import equivalent_max_real

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["plot_compare", "plot_equivalent_trend", "plot_study", "plot_surfaces", "require_matplotlib"]


def require_matplotlib(flag: str) -> None:
    """Raise a config error naming ``flag`` when matplotlib (the ``plots`` extra) is missing.

    Parameters
    ----------
    flag : str
        The command-line option that asked for a figure (``--plot``, ``--plots``).
    """
    try:
        import matplotlib.figure  # noqa: F401 (only whether it imports)
    except ImportError:
        raise ConfigError(f"{flag}: matplotlib is missing: allowed: pip install 'bipedtele[plots]'") from None


def plot_surfaces(data: dict[str, Any]) -> Figure:
    """Draw 3-D surfaces of ``rho`` (top row) and of the forward block (bottom row) per ``dp``.

    Returns
    -------
    matplotlib.figure.Figure
    """
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


def plot_equivalent_trend(cfg: ControlConfig, periods: Sequence[float] = (0.5, 1.0, 2.0)) -> Figure:
    """Draw ``max|l_equivalent|`` per channel against ``sigma_e`` for several periods [s].

    The figure behind docs/method.md's check of the claim "sigma_e up => max|l_equivalent|
    down" (Sec. 3.3, Fig. 7).

    Returns
    -------
    matplotlib.figure.Figure
    """
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


def plot_study(result: dict[str, Any]) -> Figure:
    """Draw Fig. 8: mean coordination errors per case, CP vs VP, with 95 % CIs.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 3.6), layout="constrained")
    axes = fig.subplots(1, 2)
    names = [c["name"] for c in result["cases"]]
    xs = np.arange(len(names))
    for ax, key, unit in ((axes[0], "forward", "cm/s"), (axes[1], "turn", "deg/s")):
        for off, scheme, color in ((-0.2, "cp", "tab:gray"), (0.2, "vp", "tab:blue")):
            means = np.array([c[scheme][f"{key}_error"] for c in result["cases"]])
            ci = np.array([c[scheme][f"{key}_ci95"] for c in result["cases"]])
            err = np.abs(np.stack([means - ci[:, 0], ci[:, 1] - means]))
            ax.bar(xs + off, means, 0.4, yerr=err, capsize=3, color=color, label=scheme.upper())
        ax.set_xticks(xs, names, rotation=15)
        ax.set_ylabel(f"mean |{key} error| [{unit}]")
        ax.set_title(f"({'a' if key == 'forward' else 'b'}) {key} speed")
        ax.legend()
    fig.suptitle(f"Coordination errors, {result['runs']} runs per scheme, seed {result['seed']}")
    return fig


def plot_compare(result: dict[str, Any]) -> Figure:
    """Draw the scheme comparison: paired differences against ``paper`` per regime and channel.

    One panel per channel; per regime a group of bars (one per scheme but ``paper``) with the
    95 % interval of the paired difference (below zero: better than the paper).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    regimes = list(result["cells"])
    schemes = [n for n in result["schemes"] if n != "paper"]
    fig = Figure(figsize=(11.0, 6.5), layout="constrained")
    width = 0.8 / max(1, len(schemes))
    x = np.arange(len(regimes))
    for row, (key, unit) in enumerate((("forward_error", "cm/s"), ("turn_error", "deg/s"))):
        ax = fig.add_subplot(2, 1, row + 1)
        for j, name in enumerate(schemes):
            diffs = [result["cells"][r][name][key]["diff"] for r in regimes]
            mean = np.array([d["mean"] for d in diffs])
            ci = np.array([d["ci95"] for d in diffs])
            err = np.abs(ci.T - mean)
            ax.bar(x + (j - (len(schemes) - 1) / 2) * width, mean, width, yerr=err, capsize=2, label=name)
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_xticks(x, regimes, rotation=15)
        ax.set_ylabel(f"{key.split('_')[0]} error - paper [{unit}]")
        if row == 0:
            ax.set_title(f"Paired difference against the paper ({result['runs']} runs per cell, reduced model)")
            ax.legend(ncol=min(5, len(schemes)), fontsize="small")
    return fig
