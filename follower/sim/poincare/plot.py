"""The figure of the walker's map (the counterpart of the paper's Fig. 6)."""

from __future__ import annotations

from typing import Any

import numpy as np


def plot_poincare(data: dict[str, Any]) -> Any:
    """Draw the Fig. 6 counterpart.

    ``rho_walker``, the walker's measured contraction and the reduced model's
    ``max|l_hybrid|`` (paper and speed loop) over ``sigma_r`` x ``T``; the plane at 1 marks
    the stability limit; the red dot is the follower's operating point (its ``sigma_r`` axis
    value is the forward channel's).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    pts = data["points"]
    sig = sorted({p["sigma_r"][0] for p in pts})
    Ts = sorted({p["T"] for p in pts})
    look = {(p["sigma_r"][0], p["T"]): p for p in pts}
    s, t = np.meshgrid(np.asarray(sig), np.asarray(Ts), indexing="ij")
    keys = (
        ("rho_walker", "3-D walker: radius of (26)"),
        ("contraction", "3-D walker: measured contraction"),
        ("rho_reduced", "reduced model, paper dp, k_v"),
        ("rho_reduced_speed_loop", "reduced model, speed loop"),
    )
    fig = Figure(figsize=(17.0, 4.4), layout="constrained")
    for i, (key, title) in enumerate(keys):
        ax = fig.add_subplot(1, len(keys), i + 1, projection="3d")
        z = np.array([[look[(a, b)][key] for b in Ts] for a in sig])
        if len(sig) > 1 and len(Ts) > 1:
            ax.plot_surface(s, t, z, cmap="viridis", linewidth=0, alpha=0.9)
            ax.plot_surface(s, t, np.ones_like(z), color="red", alpha=0.15, linewidth=0)
        ax.scatter(s.ravel(), t.ravel(), z.ravel(), color="k", s=8)
        if i < 2:
            op = data["operating_point"]
            ax.scatter([op["sigma_r"][0]], [op["T"]], [op[key]], color="red", s=30, label="operating point")
            ax.legend(fontsize=7)
        ax.set_xlabel("sigma_r")
        ax.set_ylabel("T [s]")
        ax.set_zlabel("spectral radius")
        ax.set_zlim(0.0, max(1.5, float(np.nanmax(z)) * 1.05))
        ax.set_title(title, fontsize=9)
    return fig
