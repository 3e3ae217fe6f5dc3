"""Stability surfaces (Fig. 6): ``max|l_hybrid|`` over ``sigma_r`` x ``T`` for several ``dp``.

``sigma_r`` is applied to both channels (``[sigma, sigma]``) and ``eps`` is the configured
value, as in the paper's figure. Besides the full ``max|l_hybrid|`` (``rho``) the forward
(hip) block alone is returned (``rho_forward``): it is the only block the reset factor
``dp`` acts on, while the turn block (no reset by default) can dominate the maximum.
The figures are drawn by :mod:`bipedtele.tools.plots`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.hybrid import rho_blocks

__all__ = ["compute_surfaces"]


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
