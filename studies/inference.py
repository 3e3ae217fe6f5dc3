"""Inference for paired comparisons: intervals, Holm's correction and equivalence tests.

A comparison runs every scheme on the same draws (operators, delays, losses), so the
difference of two schemes is taken run by run (paired). For a family of such differences
(for example every scheme against the paper's on one regime and one metric) this module
gives, per difference: the mean with its Student-t 95 % interval, the two-sided p-value,
Holm's step-down adjusted p-value within the family (it controls the family-wise error
rate at ``alpha`` whatever the dependence between the tests), the effect size ``d_z``
(mean over standard deviation of the differences), and the two one-sided tests (TOST) of
equivalence within a margin stated before the run: the difference is declared
*equivalent* when both one-sided nulls ``mean <= -margin`` and ``mean >= +margin`` are
rejected, i.e. when the (1 - 2 alpha) interval lies inside ``(-margin, +margin)``; TOST
p-values are Holm-adjusted within the family too.

A verdict is one of ``differs`` (Holm-adjusted p < alpha), ``equivalent`` (Holm-adjusted
TOST p < alpha) or ``inconclusive`` (neither: the runs cannot tell). Both can hold for a
difference that is real but smaller than the margin; ``differs`` is then reported, with
``equivalent`` beside it.

Examples
--------
>>> d = paired_difference([3.0, 4.0, 5.0, 6.0, 7.0], [2.0, 2.0, 2.0, 2.0, 2.0])
>>> round(d.mean, 3), [round(v, 3) for v in d.ci95], round(d.p, 4)
(3.0, [1.037, 4.963], 0.0132)
>>> holm([0.01, 0.04, 0.03, 0.005])
[0.03, 0.06, 0.06, 0.02]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import stats

__all__ = [
    "PairedDifference",
    "Verdict",
    "family_interval",
    "holm",
    "judge_family",
    "n_for_power",
    "paired_difference",
    "tost_p",
]


@dataclass(frozen=True)
class PairedDifference:
    """One paired difference ``x - y`` over the runs where both are finite.

    Attributes
    ----------
    n : int
        Pairs used.
    mean : float
        Mean difference (in the metric's unit).
    ci95 : tuple of float
        Student-t 95 % interval of the mean difference.
    sd : float
        Standard deviation of the differences (ddof 1).
    p : float
        Two-sided p-value of ``mean = 0`` (one-sample t-test on the differences).
    d_z : float
        Effect size: ``mean / sd`` (NaN when ``sd`` is 0 or ``n < 2``).
    """

    n: int
    mean: float
    ci95: tuple[float, float]
    sd: float
    p: float
    d_z: float


def _finite_pairs(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray) -> np.ndarray:
    a, b = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"x and y: allowed: the same shape (paired runs), got {a.shape} and {b.shape}")
    d = a - b
    return np.asarray(d[np.isfinite(d)], dtype=float)


def paired_difference(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray) -> PairedDifference:
    """Return the paired difference ``x - y`` (run ``i`` of ``x`` against run ``i`` of ``y``).

    Raises
    ------
    ValueError
        ``x`` and ``y`` of different shapes (not paired).
    """
    d = _finite_pairs(x, y)
    n = int(d.size)
    if n == 0:
        return PairedDifference(0, math.nan, (math.nan, math.nan), math.nan, math.nan, math.nan)
    mean = float(d.mean())
    if n < 2:
        return PairedDifference(n, mean, (mean, mean), math.nan, math.nan, math.nan)
    sd = float(d.std(ddof=1))
    se = sd / math.sqrt(n)
    if se == 0.0:  # every pair differs by the same amount: no spread to test against
        p = 1.0 if mean == 0.0 else 0.0
        return PairedDifference(n, mean, (mean, mean), 0.0, p, math.nan)
    half = float(stats.t.ppf(0.975, n - 1)) * se
    p = float(2.0 * stats.t.sf(abs(mean) / se, n - 1))
    return PairedDifference(n, mean, (mean - half, mean + half), sd, p, mean / sd)


def tost_p(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, margin: float) -> float:
    """Return the TOST p-value of equivalence of ``x`` and ``y`` (paired) within ``+-margin``.

    The larger of the two one-sided p-values (``mean <= -margin``, ``mean >= margin``);
    equivalence is declared at level ``alpha`` when it is below ``alpha``.

    Raises
    ------
    ValueError
        ``margin`` not positive, or ``x``, ``y`` not paired.
    """
    if not margin > 0.0:
        raise ValueError(f"margin = {margin!r}: allowed: a positive number in the metric's unit")
    d = _finite_pairs(x, y)
    n = int(d.size)
    if n < 2:
        return math.nan
    mean, se = float(d.mean()), float(d.std(ddof=1)) / math.sqrt(n)
    if se == 0.0:
        return 0.0 if abs(mean) < margin else 1.0
    p_low = float(stats.t.sf((mean + margin) / se, n - 1))  # H0: mean <= -margin
    p_high = float(stats.t.cdf((mean - margin) / se, n - 1))  # H0: mean >= +margin
    return max(p_low, p_high)


def family_interval(d: PairedDifference, m: int, alpha: float = 0.05) -> tuple[float, float]:
    """Return the Bonferroni-corrected interval of ``d`` for a family of ``m`` differences.

    The Student-t interval at level ``1 - alpha / m``: the ``m`` intervals of a family cover
    their true differences together with probability at least ``1 - alpha`` (an interval
    consistent with Holm's first step; NaN bounds where ``d`` has fewer than two pairs).
    """
    if d.n < 2 or not math.isfinite(d.sd):
        return (math.nan, math.nan)
    half = float(stats.t.ppf(1.0 - alpha / (2.0 * max(1, m)), d.n - 1)) * d.sd / math.sqrt(d.n)
    return (d.mean - half, d.mean + half)


def holm(p: Sequence[float]) -> list[float]:
    """Return Holm's step-down adjusted p-values, in the order given (NaN stays NaN, not counted).

    The ``k``-th smallest of ``m`` p-values is multiplied by ``m - k + 1``, made
    non-decreasing along the sorted order and capped at 1.
    """
    vals = [float(v) for v in p]
    idx = sorted((i for i, v in enumerate(vals) if math.isfinite(v)), key=lambda i: vals[i])
    m = len(idx)
    out = [math.nan] * len(vals)
    running = 0.0
    for k, i in enumerate(idx):
        running = max(running, min(1.0, (m - k) * vals[i]))
        out[i] = running
    return out


@dataclass(frozen=True)
class Verdict:
    """A paired difference judged within its family (module docstring).

    Attributes
    ----------
    diff : PairedDifference
    p_holm : float
        Holm-adjusted two-sided p-value within the family.
    margin : float
        The equivalence margin, stated before the run (metric's unit).
    tost_p : float
        TOST p-value (uncorrected).
    tost_p_holm : float
        Holm-adjusted TOST p-value within the family.
    verdict : str
        ``differs``, ``equivalent`` or ``inconclusive``.
    ci_family : tuple of float
        The family-corrected (Bonferroni, level ``1 - alpha / m``) interval of the mean
        difference (:func:`family_interval`).
    """

    diff: PairedDifference
    p_holm: float
    margin: float
    tost_p: float
    tost_p_holm: float
    verdict: str
    ci_family: tuple[float, float] = (math.nan, math.nan)

    def to_dict(self) -> dict[str, Any]:
        """Return the verdict as a JSON-ready map (the difference's fields flattened)."""
        out = asdict(self.diff)
        out["ci95"] = list(self.diff.ci95)
        out.update(
            p_holm=self.p_holm,
            margin=self.margin,
            tost_p=self.tost_p,
            tost_p_holm=self.tost_p_holm,
            verdict=self.verdict,
            ci_family=list(self.ci_family),
        )
        return out


def judge_family(
    pairs: Mapping[str, tuple[Sequence[float] | np.ndarray, Sequence[float] | np.ndarray]],
    margin: float,
    alpha: float = 0.05,
) -> dict[str, Verdict]:
    """Judge every paired difference of one family, Holm-corrected within it.

    Parameters
    ----------
    pairs : mapping
        Name -> ``(x, y)``: the runs of the two sides, paired run by run.
    margin : float
        Equivalence margin in the metric's unit (for example 0.1 cm/s or 0.3 deg/s),
        stated before the runs.
    alpha : float
        Family-wise error rate of each of the two families of tests (differences,
        equivalences).

    Raises
    ------
    ValueError
        ``alpha`` outside (0, 1), a non-positive ``margin`` or unpaired runs.
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha = {alpha!r}: allowed: 0 < alpha < 1")
    names = list(pairs)
    diffs = {n: paired_difference(*pairs[n]) for n in names}
    tosts = {n: tost_p(*pairs[n], margin) for n in names}
    p_adj = dict(zip(names, holm([diffs[n].p for n in names]), strict=True))
    t_adj = dict(zip(names, holm([tosts[n] for n in names]), strict=True))
    out: dict[str, Verdict] = {}
    for n in names:
        if p_adj[n] < alpha:
            verdict = "differs"
        elif t_adj[n] < alpha:
            verdict = "equivalent"
        else:
            verdict = "inconclusive"
        ci_family = family_interval(diffs[n], len(names), alpha)
        out[n] = Verdict(diffs[n], p_adj[n], float(margin), tosts[n], t_adj[n], verdict, ci_family)
    return out


def n_for_power(d_z: float, alpha: float = 0.05, power: float = 0.8, n_max: int = 100_000) -> int | None:
    """Return the smallest number of pairs at which a paired t-test detects effect ``d_z``.

    Two-sided one-sample t-test on the differences at level ``alpha`` (pass ``alpha / m``
    for a Holm family of ``m``: its first step, the most demanding), power from the
    noncentral t distribution with noncentrality ``d_z sqrt(n)``.

    Returns
    -------
    int or None
        Pairs needed (at least 2); None when ``d_z`` is 0 or not finite, or more than
        ``n_max`` would be needed.

    Raises
    ------
    ValueError
        ``alpha`` or ``power`` outside (0, 1).
    """
    if not (0.0 < alpha < 1.0 and 0.0 < power < 1.0):
        raise ValueError(f"alpha = {alpha!r}, power = {power!r}: allowed: both in (0, 1)")
    if not math.isfinite(d_z) or d_z == 0.0:
        return None

    def achieved(n: int) -> float:
        crit = float(stats.t.ppf(1.0 - alpha / 2.0, n - 1))
        nc = abs(d_z) * math.sqrt(n)
        return float(stats.nct.sf(crit, n - 1, nc) + stats.nct.cdf(-crit, n - 1, nc))

    lo, hi = 2, 2
    while achieved(hi) < power:
        if hi >= n_max:
            return None
        lo, hi = hi, min(n_max, 2 * hi)
    while lo < hi:  # power grows with n: the first n that reaches it
        mid = (lo + hi) // 2
        if achieved(mid) >= power:
            hi = mid
        else:
            lo = mid + 1
    return hi
