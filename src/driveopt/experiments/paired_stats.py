"""Exact and resampling statistics for paired closed-loop comparisons (numpy, math and scipy's distributions).

Two planners driven through the same episodes (same scenario, seed and episode: the same traffic) give paired
outcomes. The functions here test them without distributional assumptions:

* :func:`binomial_two_sided` -- the exact two-sided binomial test of ``k`` successes in ``n`` trials at p = 1/2
  (the smaller tail doubled, capped at 1);
* :func:`mcnemar_exact` -- McNemar's exact test on a paired binary outcome (collided or not): the binomial test on
  the discordant pairs;
* :func:`sign_test` -- the exact sign test of paired differences (zero differences dropped);
* :func:`bootstrap_mean_interval` -- a percentile bootstrap interval of a mean with a fixed seed, so a report is the
  same every time it is written;
* :func:`paired_risk_difference_interval` -- a conservative 95% interval of a paired difference of rates from two
  simultaneous 97.5% Wilson intervals of the discordant shares;
* :func:`rate_ratio_interval` -- a conservative interval of the ratio of two paired rates (what "4x fewer
  collisions" states), from two simultaneous Wilson intervals of the marginal rates (97.5% each for 95%);
* :func:`t_mean_interval` -- Student's t interval of a mean (paired differences of speed), which holds its level at
  small samples where the percentile bootstrap covers too little;
* :func:`mcnemar_pairs_needed` -- the pairs McNemar's test needs to show a rate ratio with a given power.

All p-values are two-sided; intervals are returned as ``(low, high)``, NaN where there is no data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import stats

from driveopt.experiments.summary import wilson_interval

BOOTSTRAP_RESAMPLES = 10_000  # [-] resamples of a bootstrap interval
BOOTSTRAP_SEED = 0  # fixed: the same records give the same interval
Z_97_5 = 2.241403  # standard normal quantile at 1 - 0.025 / 2: two simultaneous 97.5% intervals cover at 95%


def binomial_two_sided(k: int, n: int) -> float:
    """Exact two-sided p-value of ``k`` successes in ``n`` fair trials: 2 x P(X <= min(k, n - k)), at most 1;
    1.0 for ``n`` = 0 (no evidence)."""
    if n < 0 or not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(k, n - k) + 1)) / 2**n
    return min(1.0, 2.0 * tail)


def mcnemar_exact(only_first: int, only_second: int) -> float:
    """Exact McNemar p-value for a paired binary outcome: ``only_first`` pairs where the event happened to the first
    member only, ``only_second`` to the second only (concordant pairs carry no information)."""
    return binomial_two_sided(only_first, only_first + only_second)


def sign_test(differences: Sequence[float]) -> tuple[int, int, float]:
    """(positive, non-zero, p): the exact sign test of paired differences; zero differences are dropped."""
    d = np.asarray(differences, float)
    positive, negative = int(np.sum(d > 0)), int(np.sum(d < 0))
    return positive, positive + negative, binomial_two_sided(positive, positive + negative)


def bootstrap_mean_interval(values: Sequence[float], level: float = 0.95, resamples: int = BOOTSTRAP_RESAMPLES,
                            seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``values`` (same units); (NaN, NaN) with fewer than 2 values."""
    x = np.asarray(values, float)
    if x.size < 2:
        return (math.nan, math.nan)
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, size=(resamples, x.size))].mean(axis=1)
    tail = (1.0 - level) / 2.0
    low, high = np.quantile(means, [tail, 1.0 - tail])
    return (float(low), float(high))


def paired_risk_difference_interval(only_first: int, only_second: int, pairs: int,
                                    level: float = 0.95) -> tuple[float, float]:
    """Conservative ``level`` interval (95% by default) of rate(first) - rate(second) over ``pairs`` paired episodes.

    The difference is p10 - p01, the shares of pairs where only the first (only the second) had the event; each
    share gets a Wilson interval at 1 - (1 - level) / 2 (97.5% for 95%) and the difference takes the extreme
    combinations, so by Bonferroni the interval covers with at least ``level``. (NaN, NaN) for no pairs."""
    if pairs == 0:
        return (math.nan, math.nan)
    z = Z_97_5 if level == 0.95 else float(stats.norm.isf((1.0 - level) / 4.0))
    low10, high10 = wilson_interval(only_first, pairs, z=z)
    low01, high01 = wilson_interval(only_second, pairs, z=z)
    return (low10 - high01, high10 - low01)


def rate_ratio_interval(arm_events: int, baseline_events: int, pairs: int, level: float = 0.95) -> tuple[float, float]:
    """Conservative ``level`` interval of rate(arm) / rate(baseline) over ``pairs`` paired episodes, with
    ``arm_events`` and ``baseline_events`` the episodes each collided in (both collided counts in each).

    Each marginal rate gets a Wilson interval at (1 + ``level``) / 2 and the ratio takes the extreme combinations, so
    by Bonferroni it covers with at least ``level`` whatever the pairing's correlation. A baseline that never
    collided leaves the upper end infinite. (NaN, NaN) for no pairs."""
    if pairs == 0:
        return (math.nan, math.nan)
    z = float(stats.norm.isf((1.0 - level) / 4.0))
    arm_low, arm_high = wilson_interval(arm_events, pairs, z=z)
    base_low, base_high = wilson_interval(baseline_events, pairs, z=z)
    return (arm_low / base_high, arm_high / base_low if base_low > 0 else math.inf)


def t_mean_interval(values: Sequence[float], level: float = 0.95) -> tuple[float, float]:
    """Student's t interval of the mean of ``values`` (same units); (NaN, NaN) with fewer than 2 values. Exact for
    normal data; unlike the percentile bootstrap it keeps close to its level at 10-20 paired differences."""
    x = np.asarray(values, float)
    if x.size < 2:
        return (math.nan, math.nan)
    return t_interval(float(x.mean()), float(x.std(ddof=1)), int(x.size), level)


def t_interval(mean: float, sd: float, n: int, level: float = 0.95) -> tuple[float, float]:
    """:func:`t_mean_interval` from a sample's mean, standard deviation (ddof 1) and size; (NaN, NaN) below 2."""
    if n < 2 or not (math.isfinite(mean) and math.isfinite(sd)):
        return (math.nan, math.nan)
    half = stats.t.ppf(0.5 + level / 2.0, n - 1) * sd / math.sqrt(n)
    return (mean - half, mean + half)


def mcnemar_pairs_needed(baseline_rate: float, ratio: float, alpha: float = 0.05, power: float = 0.8) -> float:
    """Pairs for McNemar's two-sided test at ``alpha`` to detect, with ``power``, an arm colliding at ``ratio`` x the
    baseline's ``baseline_rate`` (Connor's formula, the two arms' outcomes in a pair taken as independent, which
    overstates the discordant pairs when they are positively correlated). inf when the rates are equal or zero."""
    if not 0.0 <= baseline_rate <= 1.0 or ratio < 0.0:
        raise ValueError(f"need a rate in [0, 1] and a ratio >= 0, got {baseline_rate}, {ratio}")
    arm_rate = min(1.0, ratio * baseline_rate)
    only_arm, only_baseline = arm_rate * (1.0 - baseline_rate), baseline_rate * (1.0 - arm_rate)
    discordant, shift = only_arm + only_baseline, only_arm - only_baseline
    if shift == 0.0:
        return math.inf
    z_alpha, z_power = stats.norm.ppf(1.0 - alpha / 2.0), stats.norm.ppf(power)
    return (z_alpha * math.sqrt(discordant) + z_power * math.sqrt(discordant - shift**2)) ** 2 / shift**2
