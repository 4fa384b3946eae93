"""Evaluate a declared claim on bench records: per-arm statistics, paired tests on the same episodes, a verdict.

Pairs are episodes both arms ran (same scenario, seed and episode: the same traffic). For every claim row:

* each arm's collision rate with its 95% Wilson interval and its mean speed over collision-free episodes [m/s]
  with a 95% percentile-bootstrap interval (fixed seed);
* collisions, paired: the episodes only the arm collided in and only the baseline collided in, and the exact
  McNemar p-value;
* speed, paired over the episodes both finish without collision: how often the arm is faster, the exact sign-test
  p-value, the mean difference arm - baseline [m/s] and its bootstrap interval;
* plan time, paired over the episodes both planned in on the same processor model (pairs whose records name two
  different ``cpu_model`` values are left out; older records name none): the median plan time per call of each
  episode [ms], the same sign test and difference.

**Verdict rule** (α = 0.05, two-sided tests; "better" means fewer collisions, a higher speed, a lower plan time):

* expected BETTER (or WORSE): the metric's paired test (McNemar for collisions, the sign test for speed and plan
  time) gives p < α and the arm is better (worse) than the baseline on the pairs: **reproduced in direction**;
  p < α the other way: **contradicted**; otherwise (p >= α, or no pairs): **inconclusive at this sample size**.
* expected NO_WORSE (non-inferiority, margin δ): the interval of the paired difference, oriented so that positive
  is better, is compared with -δ. Lower bound > -δ: **reproduced in direction**; upper bound < -δ:
  **contradicted**; otherwise inconclusive. For collisions δ = :data:`COLLISION_MARGIN` (rate points) and the
  interval is the conservative one of :func:`paired_risk_difference_interval`; for speed and plan time δ =
  :data:`RELATIVE_MARGIN` x the baseline's mean over the pairs and the interval is the bootstrap one, which needs
  at least :data:`MIN_PAIRS` pairs (fewer: inconclusive).

The verdict is about the direction the paper states, never about its size: "4-10x fewer" is reproduced in
direction when the arm collides significantly less, whatever the factor (the row shows both rates).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from driveopt.experiments.paired_stats import (
    bootstrap_mean_interval,
    mcnemar_exact,
    paired_risk_difference_interval,
    sign_test,
)
from driveopt.experiments.protocols import BETTER, COLLISIONS, NO_WORSE, PLAN_TIME, SPEED, WORSE, Arm, Claim
from driveopt.experiments.summary import wilson_interval

ALPHA = 0.05  # two-sided level of the paired tests
COLLISION_MARGIN = 0.10  # [rate points] non-inferiority margin on the paired collision-rate difference
RELATIVE_MARGIN = 0.10  # [-] non-inferiority margin on speed and plan time, as a share of the baseline's mean
MIN_PAIRS = 10  # [-] pairs a bootstrap interval of a paired difference needs
REPRODUCED, CONTRADICTED, INCONCLUSIVE = "reproduced in direction", "contradicted", "inconclusive at this sample size"
NOT_RUN = "not run"  # no episode recorded for both arms
# answers of a pooled question (protocols.Question) on one metric
CHANGES_BETTER, CHANGES_WORSE, NO_CHANGE, TOO_FEW_PAIRS = ("changes it: better", "changes it: worse",
                                                           "no change detected", "too few pairs yet")

Episode = tuple[int, int]  # (seed, episode)


@dataclass(frozen=True)
class ArmStats:
    """One arm's records on the claim's scenario. Rates in [0, 1], speeds [m/s], plan time [ms]."""

    label: str
    planner: str
    version: str
    note: str
    episodes: int
    collisions: int
    collision_rate: float
    collision_low: float
    collision_high: float
    speed: float  # mean over collision-free episodes
    speed_low: float
    speed_high: float
    plan_ms: float  # median over the episodes' median plan times per call


@dataclass(frozen=True)
class ClaimResult:
    """A claim measured: both arms, the paired tests and the verdict (see the module docstring)."""

    figure: str
    scenario: str
    metric: str
    expect: str
    paper: str
    like_for_like: bool
    kind: str  # faithful, driveopt, or driveopt vs faithful (protocols.Claim.kind)
    arm: ArmStats
    baseline: ArmStats
    seeds: tuple[int, ...]
    pairs: int  # episodes both arms ran
    full_pairs: int  # episodes per claim of the full protocol
    reduced: bool  # run with fewer episodes than the full protocol
    only_arm_collided: int
    only_baseline_collided: int
    mcnemar_p: float
    speed_pairs: int  # both collision-free
    arm_faster: int  # of the speed pairs with a difference
    speed_sign_n: int
    speed_sign_p: float
    speed_difference: float  # mean of arm - baseline [m/s]
    speed_difference_low: float
    speed_difference_high: float
    plan_pairs: int
    arm_quicker: int  # episodes with the arm's median plan time below the baseline's
    plan_sign_n: int
    plan_sign_p: float
    plan_difference: float  # mean of arm - baseline [ms]
    plan_difference_low: float
    plan_difference_high: float
    collision_difference_low: float  # conservative interval of rate(arm) - rate(baseline)
    collision_difference_high: float
    verdict: str
    explanation: str = ""  # why a contradiction may arise, and what settles it (protocols.Claim.explanation)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def same_processor(x: dict[str, Any], y: dict[str, Any]) -> bool:
    """Whether two records' plan times are comparable: neither names another processor model than the other."""
    return x.get("cpu_model") is None or y.get("cpu_model") is None or x["cpu_model"] == y["cpu_model"]


def plan_ms_of(record: dict[str, Any]) -> float:
    """Median plan time per call of one episode [ms]; NaN for a driver that does not plan (idm, RL)."""
    plan_ms = record.get("plan_ms") or []
    return float(np.median(plan_ms)) if plan_ms else math.nan


def arm_stats(arm: Arm, records: list[dict[str, Any]]) -> ArmStats:
    n = len(records)
    crashed = sum(bool(r["collided"]) for r in records)
    low, high = wilson_interval(crashed, n)
    free = [float(r["mean_speed"]) for r in records if not r["collided"]]
    speed_low, speed_high = bootstrap_mean_interval(free)
    plans = [p for p in (plan_ms_of(r) for r in records) if math.isfinite(p)]
    return ArmStats(arm.label, arm.planner, arm.version, arm.note, n, crashed, crashed / n if n else math.nan, low, high,
                    float(np.mean(free)) if free else math.nan, speed_low, speed_high,
                    float(np.median(plans)) if plans else math.nan)


def _difference(a: list[float], b: list[float]) -> tuple[float, float, float]:
    d = np.asarray(a, float) - np.asarray(b, float)
    if d.size == 0:
        return (math.nan, math.nan, math.nan)
    low, high = bootstrap_mean_interval(d) if d.size >= MIN_PAIRS else (math.nan, math.nan)
    return (float(d.mean()), low, high)


def evaluate(figure: str, claim: Claim, arm_records: dict[Episode, dict[str, Any]],
             baseline_records: dict[Episode, dict[str, Any]], seeds: tuple[int, ...], full_pairs: int,
             reduced: bool) -> ClaimResult:
    """``claim`` measured on the records of its two arms, each keyed by (seed, episode)."""
    keys = sorted(set(arm_records) & set(baseline_records))
    a = [arm_records[k] for k in keys]
    b = [baseline_records[k] for k in keys]
    only_arm = sum(bool(x["collided"]) and not y["collided"] for x, y in zip(a, b))
    only_base = sum(bool(y["collided"]) and not x["collided"] for x, y in zip(a, b))
    free = [(float(x["mean_speed"]), float(y["mean_speed"])) for x, y in zip(a, b) if not x["collided"] and not y["collided"]]
    faster, speed_n, speed_p = sign_test([x - y for x, y in free])
    speed_diff = _difference([x for x, _ in free], [y for _, y in free])
    plans = [(plan_ms_of(x), plan_ms_of(y)) for x, y in zip(a, b) if same_processor(x, y)]
    plans = [(x, y) for x, y in plans if math.isfinite(x) and math.isfinite(y)]
    slower_plans, plan_n, plan_p = sign_test([x - y for x, y in plans])
    plan_diff = _difference([x for x, _ in plans], [y for _, y in plans])
    risk_low, risk_high = paired_risk_difference_interval(only_arm, only_base, len(keys))
    mcnemar_p = mcnemar_exact(only_arm, only_base)
    if claim.metric == COLLISIONS:
        # oriented: positive = the arm is better (collides less)
        better_count, worse_count, p = only_base, only_arm, mcnemar_p
        interval, margin = (-risk_high, -risk_low), COLLISION_MARGIN
    elif claim.metric == SPEED:
        better_count, worse_count, p = faster, speed_n - faster, speed_p
        interval = speed_diff[1:]
        margin = RELATIVE_MARGIN * float(np.mean([y for _, y in free])) if free else math.nan
    elif claim.metric == PLAN_TIME:
        better_count, worse_count, p = plan_n - slower_plans, slower_plans, plan_p
        interval = (-plan_diff[2], -plan_diff[1])
        margin = RELATIVE_MARGIN * float(np.mean([y for _, y in plans])) if plans else math.nan
    else:
        raise ValueError(f"unknown metric {claim.metric!r}")
    verdict = decide(claim.expect, better_count, worse_count, p, interval, margin) if keys else NOT_RUN
    return ClaimResult(
        figure, claim.scenario, claim.metric, claim.expect, claim.paper, claim.like_for_like, claim.kind,
        arm_stats(claim.arm, a if keys else list(arm_records.values())),
        arm_stats(claim.baseline, b if keys else list(baseline_records.values())),
        tuple(seeds), len(keys), full_pairs, reduced or len(keys) < full_pairs,
        only_arm, only_base, mcnemar_p,
        len(free), faster, speed_n, speed_p, *speed_diff,
        len(plans), plan_n - slower_plans, plan_n, plan_p, *plan_diff,
        risk_low, risk_high, verdict, claim.explanation)


def oriented_counts(r: ClaimResult) -> tuple[int, int, float]:
    """(pairs in the arm's favour, pairs against it, the paired test's p-value) on ``r``'s metric: collisions
    (McNemar), speed or plan time (sign test)."""
    if r.metric == COLLISIONS:
        return r.only_baseline_collided, r.only_arm_collided, r.mcnemar_p
    if r.metric == SPEED:
        return r.arm_faster, r.speed_sign_n - r.arm_faster, r.speed_sign_p
    if r.metric == PLAN_TIME:
        return r.arm_quicker, r.plan_sign_n - r.arm_quicker, r.plan_sign_p
    raise ValueError(f"unknown metric {r.metric!r}")


def answer(r: ClaimResult, min_pairs: int) -> str:
    """A pooled question's answer on ``r``'s metric: TOO_FEW_PAIRS below ``min_pairs`` pairs; else the paired test at
    ALPHA, two-sided: CHANGES_BETTER or CHANGES_WORSE (for the arm), or NO_CHANGE. Plan time counts the pairs it
    compares (both planned, on one processor model)."""
    if (r.plan_pairs if r.metric == PLAN_TIME else r.pairs) < min_pairs:
        return TOO_FEW_PAIRS
    better, worse, p = oriented_counts(r)
    if p >= ALPHA or better == worse:
        return NO_CHANGE
    return CHANGES_BETTER if better > worse else CHANGES_WORSE


def decide(expect: str, better: int, worse: int, p: float, interval: tuple[float, float], margin: float) -> str:
    """The verdict of the module docstring. better/worse: paired counts in the arm's favour and against it; p: the
    paired test's p-value; interval: the paired difference's interval oriented so that positive is better (NaN:
    none); margin: the non-inferiority margin δ (same units)."""
    if expect in (BETTER, WORSE):
        if p >= ALPHA or better == worse:
            return INCONCLUSIVE
        went_better = better > worse
        return REPRODUCED if went_better == (expect == BETTER) else CONTRADICTED
    if expect == NO_WORSE:
        low, high = interval
        if any(math.isnan(v) for v in (low, high, margin)):
            return INCONCLUSIVE
        if low > -margin:
            return REPRODUCED
        if high < -margin:
            return CONTRADICTED
        return INCONCLUSIVE
    raise ValueError(f"unknown expectation {expect!r}")
