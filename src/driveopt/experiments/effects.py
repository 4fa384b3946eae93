"""What a paper states about a claim, as a size that data can confirm or exclude, and the verdict rules on it.

A paper's comparison states a *ratio* ("4-10x fewer collisions": the arm's collision rate over the baseline's, here
0.1-0.25), a *level* on one or both arms ("a mere 3 %", "0 % for every baseline but MPC-Random"), or only a
*direction* where it gives no number. :class:`PaperEffect` holds which, with where the number comes from.

Verdicts on a collision claim, from the paired episodes (``only_arm``/``only_baseline``: the discordant pairs,
``arm_events``/``baseline_events``: the episodes each arm collided in) and one pre-declared level ``alpha`` per test
(after Holm's correction within its figure and the sequential boundary of its look,
:mod:`driveopt.experiments.error_control`):

* a ratio: McNemar's exact test decides the direction, :func:`~driveopt.experiments.paired_stats.rate_ratio_interval`
  at level 1 - ``alpha`` the size (so an interim look, whose ``alpha`` is the sequential boundary's, excludes a size
  only with the same protection as it declares a direction: Jennison and Turnbull's repeated confidence intervals). Direction significant the paper's way: **reproduced** when the interval meets the paper's range,
  **smaller than the paper's** when it lies wholly on the side of no effect, **larger than the paper's** on the other;
  significant the other way: **contradicted**; not significant but the interval misses the paper's range: **paper's
  size excluded**; otherwise **not decidable here** when even the baseline's 95 % upper rate would need more pairs
  than the protocol runs to show the paper's smallest effect with 80 % power, else **inconclusive** with the pairs
  still needed at the measured baseline rate.
* a level: each arm with a stated level is judged alone by its Wilson interval (at ``alpha``): **reproduced** when
  the interval holds the level and is no wider than :func:`level_tolerance` above it, **higher** / **lower than the
  paper's** when it lies wholly above / below, else **inconclusive** with the episodes still needed.
* a direction: the paired test alone: **reproduced in direction**, **contradicted**; not significant after at least
  :data:`FUTILITY_PAIRS` pairs, **not decidable here** when at the measured rates 80 % power needs more pairs than the
  protocol runs (a futility rule: it ends no error-rate guarantee, it only stops buying pairs), else **inconclusive**.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from driveopt.experiments.paired_stats import mcnemar_exact, mcnemar_pairs_needed, rate_ratio_interval
from driveopt.experiments.summary import wilson_interval

RATIO, LEVEL, DIRECTION = "ratio", "level", "direction"
REPRODUCED, SMALLER, LARGER = "reproduced", "smaller than the paper's", "larger than the paper's"
HIGHER, LOWER = "higher than the paper's", "lower than the paper's"
CONTRADICTED, SIZE_EXCLUDED = "contradicted", "paper's size excluded"
NOT_DECIDABLE, INCONCLUSIVE, NOT_RUN = "not decidable here", "inconclusive", "not run"
REPRODUCED_IN_DIRECTION = "reproduced in direction"
POWER = 0.8  # [-] the power a decision at the paper's size is planned for
MAX_EPISODES_NEEDED = 100_000  # [-] beyond this the episodes a level needs are reported as unbounded
FUTILITY_PAIRS = 20  # [-] pairs from which a direction the protocol cannot show at the measured rates is not decidable


@dataclass(frozen=True)
class PaperEffect:
    """A paper's statement about one claim. ``ratio``: (low, high) of the arm's rate over the baseline's
    (collisions; "4-10x fewer" is (0.1, 0.25)); ``arm_level``, ``baseline_level``: (low, high) rates each arm is
    stated to reach; none of them: a direction only. ``source``: where the numbers come from (the text's words, or
    how bar heights were read off a figure)."""

    source: str
    ratio: tuple[float, float] | None = None
    arm_level: tuple[float, float] | None = None
    baseline_level: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        for name in ("ratio", "arm_level", "baseline_level"):
            bounds = getattr(self, name)
            if bounds is not None and not (0.0 <= bounds[0] <= bounds[1] and (name == "ratio" or bounds[1] <= 1.0)):
                raise ValueError(f"PaperEffect.{name} must be (low, high) with 0 <= low <= high (rates <= 1), got {bounds}")
        if self.ratio is not None and (self.arm_level or self.baseline_level):
            raise ValueError("a PaperEffect states a ratio or levels, not both")

    @property
    def kind(self) -> str:
        if self.ratio is not None:
            return RATIO
        return LEVEL if self.arm_level or self.baseline_level else DIRECTION

    @classmethod
    def times_fewer(cls, low: float, high: float, source: str) -> "PaperEffect":
        """"``low``-``high`` x fewer": the arm's rate is 1/high to 1/low of the baseline's."""
        return cls(source, ratio=(1.0 / high, 1.0 / low))


@dataclass(frozen=True)
class Judgement:
    """A verdict and the numbers behind it: ``interval`` of the ratio or level judged, ``needed``: pairs (or
    episodes, for a level) the claim still needs, NaN where none are or they cannot be estimated; ``detail``: one
    line a report prints beside the verdict."""

    verdict: str
    interval: tuple[float, float] = (math.nan, math.nan)
    needed: float = math.nan
    detail: str = ""


def _overlaps(interval: tuple[float, float], bounds: tuple[float, float]) -> bool:
    return interval[0] <= bounds[1] and interval[1] >= bounds[0]


def judge_ratio(only_arm: int, only_baseline: int, arm_events: int, baseline_events: int, pairs: int,
                ratio: tuple[float, float], alpha: float, max_pairs: int) -> Judgement:
    """The verdict on a stated ratio of collision rates (arm / baseline) from ``pairs`` paired episodes (module
    docstring); ``max_pairs``: the most pairs the protocol runs."""
    if pairs == 0:
        return Judgement(NOT_RUN)
    interval = rate_ratio_interval(arm_events, baseline_events, pairs, level=1.0 - alpha)
    fewer_claimed = ratio[1] < 1.0
    if mcnemar_exact(only_arm, only_baseline) < alpha and only_arm != only_baseline:
        if (only_arm < only_baseline) != fewer_claimed:
            return Judgement(CONTRADICTED, interval)
        if _overlaps(interval, ratio):
            return Judgement(REPRODUCED, interval)
        toward_none = interval[0] > ratio[1] if fewer_claimed else interval[1] < ratio[0]
        return Judgement(SMALLER if toward_none else LARGER, interval)
    if not _overlaps(interval, ratio):
        return Judgement(SIZE_EXCLUDED, interval)
    weakest = ratio[1] if fewer_claimed else ratio[0]  # the paper's size closest to no effect
    rate_high = wilson_interval(baseline_events, pairs)[1]
    best_case = mcnemar_pairs_needed(rate_high, weakest, alpha, POWER)
    if best_case > max_pairs:
        return Judgement(NOT_DECIDABLE, interval, best_case,
                         f"the baseline's 95% upper rate {rate_high:.1%}: at the paper's ratio {weakest:.2g} even that "
                         f"needs {best_case:.0f} pairs for 80% power, the protocol runs {max_pairs}")
    needed = mcnemar_pairs_needed(baseline_events / pairs, weakest, alpha, POWER)
    return Judgement(INCONCLUSIVE, interval, needed,
                     f"{needed:.0f} pairs for 80% power at the paper's ratio {weakest:.2g} and the baseline's measured "
                     f"rate {baseline_events / pairs:.1%}" if math.isfinite(needed) else
                     "no baseline collision yet: the pairs needed cannot be estimated")


def level_tolerance(level: tuple[float, float]) -> float:
    """The highest upper bound of an arm's rate interval that still counts as reaching the stated ``level``: twice
    its upper end or 5 points above it, whichever is larger (a "3 %" is shown once the interval stays below 8 %)."""
    return max(2.0 * level[1], level[1] + 0.05)


def _episodes_for_level(rate: float, tolerance: float, z: float) -> float:
    """Episodes at which an arm colliding at ``rate`` has a Wilson upper bound below ``tolerance``."""
    if rate >= tolerance:
        return math.inf
    n = 1
    while n <= MAX_EPISODES_NEEDED:
        if wilson_interval(round(rate * n), n, z)[1] <= tolerance:
            return float(n)
        n = math.ceil(n * 1.1)
    return math.inf


def judge_level(events: int, episodes: int, level: tuple[float, float], alpha: float) -> Judgement:
    """The verdict on one arm's stated collision ``level`` (low, high) from its ``events`` in ``episodes``."""
    if episodes == 0:
        return Judgement(NOT_RUN)
    from scipy import stats

    z = float(stats.norm.isf(alpha / 2.0))
    interval = wilson_interval(events, episodes, z)
    if interval[0] > level[1]:
        return Judgement(HIGHER, interval)
    if interval[1] < level[0]:
        return Judgement(LOWER, interval)
    tolerance = level_tolerance(level)
    if interval[1] <= tolerance:
        return Judgement(REPRODUCED, interval)
    needed = _episodes_for_level(events / episodes, tolerance, z)
    return Judgement(INCONCLUSIVE, interval, needed,
                     f"{needed:.0f} episodes to bound the rate below {tolerance:.0%} at the measured "
                     f"{events / episodes:.1%}" if math.isfinite(needed) else
                     f"the measured rate {events / episodes:.1%} is near the tolerance {tolerance:.0%}")


def judge_direction(better: int, worse: int, p: float, alpha: float, needed: float = math.nan, max_pairs: int = 0,
                    pairs: int = 0) -> Judgement:
    """A direction-only claim expected in the arm's favour: the paired test at ``alpha`` (better/worse: the pairs for
    and against the arm). Undecided with at least :data:`FUTILITY_PAIRS` ``pairs``, it is **not decidable here** when
    the total pairs ``needed`` for :data:`POWER` at the measured rates exceed the ``max_pairs`` the protocol runs (the
    effect, if there is one, is too small for the protocol to show)."""
    if p < alpha and better != worse:
        return Judgement(REPRODUCED_IN_DIRECTION if better > worse else CONTRADICTED)
    if max_pairs and pairs >= FUTILITY_PAIRS and not needed <= max_pairs:
        return Judgement(NOT_DECIDABLE, needed=needed, detail=(
            f"at the measured rates a direction needs {needed:.0f} pairs for {POWER:.0%} power, the protocol runs "
            f"{max_pairs}" if math.isfinite(needed) else
            f"at the measured rates ({better} pairs for, {worse} against after {pairs}) no number of pairs shows "
            f"the paper's direction"))
    return Judgement(INCONCLUSIVE, needed=needed)
