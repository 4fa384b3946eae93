"""How often a campaign may be wrong: Holm's step-down within a figure, O'Brien-Fleming boundaries across looks.

A figure of a paper makes several claims, and a campaign looks at each claim's data several times as episodes
accumulate. Tested naively at α each, some claim would pass by chance and a claim looked at six times would be
declared at the first lucky look. Two standard corrections keep the family's error at α:

* :func:`holm_adjusted` -- Holm's step-down: the i-th smallest of m p-values is compared with α / (m - i + 1);
  adjusted p-values make that one comparison with α per claim.
* :func:`obrien_fleming_levels` -- the nominal two-sided levels of a group-sequential test with O'Brien-Fleming
  boundaries at pre-declared looks: strict early (a look at 10 of 80 pairs passes only at p < 0.00005), close to α at
  the last, the overall type-I error exactly α. Computed by numerical integration of the test statistic's
  Brownian-motion path (Armitage, McPherson and Rowe's recursion), for any information fractions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from scipy import optimize, stats

STEPS_PER_SD = 20  # [-] grid nodes per standard deviation of the smallest increment between looks: levels to ~1e-6


def holm_adjusted(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p-values, in the input's order: sorted ascending, the i-th (from 0) of m becomes
    max over j <= i of min(1, (m - j) p_(j)). A claim passes at family-wise level α when its adjusted p < α."""
    p = np.asarray(p_values, float)
    if np.any((p < 0) | (p > 1)):
        raise ValueError(f"p-values must lie in [0, 1], got {list(p_values)}")
    order = np.argsort(p, kind="stable")
    scaled = np.minimum(1.0, (len(p) - np.arange(len(p))) * p[order])
    adjusted = np.empty_like(p)
    adjusted[order] = np.maximum.accumulate(scaled) if len(p) else scaled
    return [float(v) for v in adjusted]


def _continue_probability(boundary: float, fractions: tuple[float, ...]) -> float:
    """P(|S(t_k)| < boundary at every look t_k) for a standard Brownian motion S, the O'Brien-Fleming region
    (on the score scale S = Z sqrt(t) the boundary is one constant)."""
    smallest = math.sqrt(min(b - a for a, b in zip((0.0, *fractions), fractions)))
    points = 2 * math.ceil(boundary * STEPS_PER_SD / smallest) + 1
    s = np.linspace(-boundary, boundary, points)
    weights = np.where(np.arange(points) % 2 == 1, 4.0, 2.0) * (s[1] - s[0]) / 3.0
    weights[[0, -1]] = (s[1] - s[0]) / 3.0  # Simpson's rule (an odd number of nodes)
    gaps = s[:, None] - s[None, :]
    density = stats.norm.pdf(s, scale=math.sqrt(fractions[0]))
    for before, after in zip(fractions, fractions[1:]):
        sd = math.sqrt(after - before)
        kernel = np.exp(-0.5 * (gaps / sd) ** 2) / (sd * math.sqrt(2.0 * math.pi))
        density = kernel @ (density * weights)
    return float(np.sum(density * weights))


@lru_cache(maxsize=64)
def _boundary(fractions: tuple[float, ...], alpha: float) -> float:
    return optimize.brentq(lambda c: 1.0 - _continue_probability(c, fractions) - alpha, 0.5, 10.0, xtol=1e-8)


def obrien_fleming_levels(looks: Sequence[float], alpha: float = 0.05) -> list[float]:
    """Nominal two-sided levels at each look of an O'Brien-Fleming group-sequential test of overall level ``alpha``.

    ``looks``: the information at each look, increasing (for a paired test, the pairs, or the discordant pairs, at
    which it is read: 10, 20, 40, 80). The z boundary at look k is C / sqrt(t_k), t_k = looks[k] / looks[-1], with C
    such that a null path crosses at some look with probability ``alpha``. A test read at look k rejects when its
    two-sided p-value is below the k-th level."""
    if len(looks) == 0 or any(b <= a for a, b in zip(looks, looks[1:])) or looks[0] <= 0:
        raise ValueError(f"looks must be positive and increasing, got {list(looks)}")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    fractions = tuple(float(v) / float(looks[-1]) for v in looks)
    boundary = _boundary(fractions, float(alpha)) if len(looks) > 1 else float(stats.norm.isf(alpha / 2.0))
    return [float(2.0 * stats.norm.sf(boundary / math.sqrt(t))) for t in fractions]
