"""Holm's step-down, O'Brien-Fleming levels, and the new paired intervals against hand-computed and published values."""

import math

import numpy as np
import pytest

from driveopt.experiments.error_control import holm_adjusted, obrien_fleming_levels
from driveopt.experiments.paired_stats import mcnemar_pairs_needed, rate_ratio_interval, t_mean_interval


def test_holm_by_hand():
    # sorted 0.01, 0.03, 0.04, 0.5 -> 4 x 0.01, 3 x 0.03, max(0.09, 2 x 0.04), max(0.09, 0.5)
    assert holm_adjusted([0.01, 0.04, 0.03, 0.5]) == pytest.approx([0.04, 0.09, 0.09, 0.5])
    assert holm_adjusted([0.3, 0.6]) == pytest.approx([0.6, 0.6])
    assert holm_adjusted([0.02]) == [0.02]
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        holm_adjusted([1.2])


# Jennison and Turnbull (2000), Table 2.3: O'Brien-Fleming C_B(K, 0.05) = 1.977, 2.004, 2.024 for K = 2, 3, 4 equal
# looks; the nominal two-sided level at look k is 2 (1 - Phi(C_B sqrt(K / k))).
@pytest.mark.parametrize("looks, constant", [(2, 1.977), (3, 2.004), (4, 2.024)])
def test_obrien_fleming_equal_looks_match_the_published_constants(looks, constant):
    from scipy import stats

    levels = obrien_fleming_levels(range(1, looks + 1))
    boundaries = [stats.norm.isf(level / 2) * math.sqrt(k / looks) for k, level in enumerate(levels, 1)]
    assert boundaries == pytest.approx([constant] * looks, abs=6e-4)  # the table's three decimals


def test_obrien_fleming_unequal_looks_spend_exactly_alpha():
    levels = obrien_fleming_levels([10, 20, 40, 80])
    assert levels == sorted(levels) and levels[-1] < 0.05
    # simulated null paths of a standard Brownian motion cross the boundary at some look with probability alpha
    rng = np.random.default_rng(1)
    fractions = np.array([10, 20, 40, 80]) / 80
    paths = np.cumsum(rng.normal(size=(400_000, 4)) * np.sqrt(np.diff(fractions, prepend=0.0)), axis=1)
    from scipy import stats

    z = np.abs(paths) / np.sqrt(fractions)
    crossed = np.any(2 * stats.norm.sf(z) < np.array(levels), axis=1).mean()
    assert crossed == pytest.approx(0.05, abs=0.0015)
    assert obrien_fleming_levels([7]) == pytest.approx([0.05])
    with pytest.raises(ValueError, match="increasing"):
        obrien_fleming_levels([20, 10])


def test_rate_ratio_interval_is_conservative_and_covers():
    low, high = rate_ratio_interval(2, 10, 50)
    assert low < 0.2 < high
    assert rate_ratio_interval(0, 0, 20)[1] == math.inf
    assert all(math.isnan(v) for v in rate_ratio_interval(0, 0, 0))
    rng = np.random.default_rng(3)  # coverage at a true ratio of 0.25 (rates 0.05 and 0.2), 60 pairs
    arm = rng.random((4000, 60)) < 0.05
    base = rng.random((4000, 60)) < 0.2
    covered = [lo <= 0.25 <= hi for lo, hi in (rate_ratio_interval(a, b, 60) for a, b in zip(arm.sum(1), base.sum(1)))]
    assert np.mean(covered) >= 0.95


def test_t_interval_by_hand_and_its_coverage_at_ten_pairs():
    low, high = t_mean_interval([1.0, 2.0, 3.0, 4.0])  # mean 2.5, sd 1.29099, t_{0.975, 3} = 3.182446
    assert (low, high) == pytest.approx((2.5 - 3.182446 * 1.290994 / 2, 2.5 + 3.182446 * 1.290994 / 2), rel=1e-5)
    rng = np.random.default_rng(4)
    samples = rng.normal(0.3, 1.0, size=(4000, 10))
    assert np.mean([lo <= 0.3 <= hi for lo, hi in map(t_mean_interval, samples)]) == pytest.approx(0.95, abs=0.012)


def test_mcnemar_pairs_needed_by_hand():
    # baseline 0.2, ratio 0.25: p10 = 0.05 x 0.8 = 0.04, p01 = 0.2 x 0.95 = 0.19, psi = 0.23, delta = -0.15
    n = (1.959964 * math.sqrt(0.23) + 0.841621 * math.sqrt(0.23 - 0.0225)) ** 2 / 0.0225
    assert mcnemar_pairs_needed(0.2, 0.25) == pytest.approx(n, rel=1e-5)
    assert mcnemar_pairs_needed(0.0, 0.25) == math.inf
    assert mcnemar_pairs_needed(0.02, 0.25) > mcnemar_pairs_needed(0.2, 0.25)
