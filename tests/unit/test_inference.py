"""Paired intervals, Holm's correction and TOST (bipedtele.studies.inference) against hand-computed examples.

The t distribution with 4 degrees of freedom has a closed form, used here instead of a
library: ``F(t) = 1/2 + (3/4) a (1 - a^2/3)`` with ``a = t / sqrt(t^2 + 4)``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from bipedtele.studies.inference import holm, judge_family, paired_difference, tost_p

pytestmark = pytest.mark.timeout(30)

X = [3.0, 4.0, 5.0, 6.0, 7.0]
Y = [2.0] * 5  # differences 1..5: mean 3, sd sqrt(2.5), standard error sqrt(0.5)


def _t4_cdf(t: float) -> float:
    a = t / math.sqrt(t * t + 4.0)
    return 0.5 + 0.75 * a * (1.0 - a * a / 3.0)


def test_paired_difference_by_hand() -> None:
    d = paired_difference(X, Y)
    se = math.sqrt(0.5)
    assert d.n == 5 and d.mean == 3.0 and d.sd == pytest.approx(math.sqrt(2.5))
    # t(0.975, 4) = 2.776445 (tables): the interval 3 -+ 2.776445 * sqrt(0.5)
    assert d.ci95 == pytest.approx((3.0 - 2.776445 * se, 3.0 + 2.776445 * se), abs=1e-6)
    assert d.p == pytest.approx(2.0 * (1.0 - _t4_cdf(3.0 / se)), rel=1e-9)  # 0.013236
    assert d.d_z == pytest.approx(3.0 / math.sqrt(2.5))
    # pairing: NaN runs are left out of both sides; unpaired lengths are refused
    assert paired_difference([*X, math.nan], [*Y, 1.0]).n == 5
    with pytest.raises(ValueError, match="paired"):
        paired_difference(X, Y[:4])


def test_tost_by_hand() -> None:
    se = math.sqrt(0.5)
    # margin 5: the upper one-sided test decides, t = (3 - 5)/se = -2.828
    assert tost_p(X, Y, 5.0) == pytest.approx(_t4_cdf((3.0 - 5.0) / se), rel=1e-9)  # 0.02371
    assert tost_p(X, Y, 5.0) < 0.05 < tost_p(X, Y, 4.0)  # within 5, not shown within 4
    # a zero-mean difference: the two one-sided tests are symmetric
    zero = [-2.0, -1.0, 0.0, 1.0, 2.0]
    assert tost_p(zero, [0.0] * 5, 3.0) == pytest.approx(_t4_cdf(-3.0 / se), rel=1e-9)
    with pytest.raises(ValueError, match="margin"):
        tost_p(X, Y, 0.0)


def test_holm_by_hand() -> None:
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1: 0.02, 0.03, 0.06, 0.04 -> made monotone 0.06
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])  # capped at 1
    out = holm([0.01, math.nan, 0.02])  # NaN is not a test: m = 2
    assert out[0] == pytest.approx(0.02) and math.isnan(out[1]) and out[2] == pytest.approx(0.02)


def test_a_family_tells_differs_equivalent_and_inconclusive() -> None:
    rng = np.random.default_rng(7)
    base = rng.normal(0.0, 1.0, 400)
    fam = {
        "shifted": (base + 1.0 + rng.normal(0.0, 0.1, 400), base),  # a clear difference of 1
        "same": (base + rng.normal(0.0, 0.1, 400), base),  # none, tightly measured: within 0.1
        "noisy": (base + rng.normal(0.0, 5.0, 400)[:400], base),  # none shown, none excluded
    }
    v = judge_family(fam, margin=0.1)
    assert v["shifted"].verdict == "differs" and v["same"].verdict == "equivalent"
    assert v["noisy"].verdict == "inconclusive"
    ps = [v[n].diff.p for n in fam]
    assert [v[n].p_holm for n in fam] == pytest.approx(holm(ps))
    d = v["shifted"].to_dict()
    assert d["verdict"] == "differs" and d["margin"] == 0.1 and len(d["ci95"]) == 2 and d["n"] == 400


def test_pairs_for_power_match_the_published_tables() -> None:
    from bipedtele.studies.inference import n_for_power

    # Paired (one-sample) t-test, two-sided alpha 0.05, power 0.80: the tabulated sample sizes
    # (Cohen 1988, table 2.4.1, one-sample case; G*Power gives the same) are 34 for d = 0.5,
    # 15 for d = 0.8 and 199 for d = 0.2.
    assert n_for_power(0.5) == 34
    assert n_for_power(0.8) == 15
    assert n_for_power(-0.2) == 199
    # A stricter level needs more pairs; no effect needs infinitely many.
    assert n_for_power(0.5, 0.05 / 5) > 34
    assert n_for_power(0.0) is None and n_for_power(math.nan) is None
    with pytest.raises(ValueError, match="allowed"):
        n_for_power(0.5, alpha=1.5)


def test_the_family_interval_by_hand() -> None:
    from bipedtele.studies.inference import family_interval

    # Differences 1..5, a family of 2 at alpha 0.05: the t interval at 1 - 0.05/2,
    # t(0.9875, 4) = 3.4954 (tables): 3 -+ 3.4954 * sqrt(0.5)
    lo, hi = family_interval(paired_difference(X, Y), 2)
    assert lo == pytest.approx(3.0 - 3.4954 * math.sqrt(0.5), abs=1e-3)
    assert hi == pytest.approx(3.0 + 3.4954 * math.sqrt(0.5), abs=1e-3)
    # one member: the plain 95 % interval; judge_family gives each member its family's interval
    assert family_interval(paired_difference(X, Y), 1) == pytest.approx(paired_difference(X, Y).ci95)
    fam = judge_family({"a": (X, Y), "b": (Y, X)}, margin=1.0)
    assert fam["a"].ci_family == pytest.approx((lo, hi), abs=1e-9)
