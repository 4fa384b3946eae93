"""Evaluate a declared claim on bench records: per-arm statistics, paired tests on the same episodes, a verdict on
the paper's stated effect at the level the claim's figure and look allow.

Pairs are episodes both arms ran (same scenario, seed and episode: the same traffic). For every claim row:

* each arm's collision rate with its 95% Wilson interval, its mean speed over collision-free episodes [m/s] with a
  95% percentile-bootstrap interval (fixed seed), and its mean wall time per episode (planning plus simulation) [s];
* collisions, paired: the episodes only the arm collided in and only the baseline collided in, and the exact
  McNemar p-value;
* speed, paired over the episodes both finish without collision: how often the arm is faster, the exact sign-test
  p-value, the mean difference arm - baseline [m/s] and its Student t interval;
* plan time, paired over the episodes both planned in on one machine: both records name the same processor model
  (``cpu_model``) and the same device where they name one; a pair where a record names no processor is left out and
  counted (``plan_pairs_unnamed``), as is a pair of two processors (``plan_pairs_mixed``). The median plan time per
  call of each episode [ms], the same sign test and t interval.

**Verdict** (:func:`judge_at`), at a level ``L``, two-sided:

* collisions with a stated ratio (:class:`~driveopt.experiments.effects.PaperEffect`, e.g. "4-10x fewer"):
  :func:`~driveopt.experiments.effects.judge_ratio` (McNemar for the direction, a conservative rate-ratio interval for
  the size; its ``max_pairs`` the full protocol's pairs);
* collisions with stated levels ("0% for every baseline", "a mere 3%"): each stated arm by
  :func:`~driveopt.experiments.effects.judge_level`; the claim is reproduced when every stated arm is, higher or lower
  when one arm is;
* a direction ("fewer", "slower"; BETTER or WORSE): :func:`~driveopt.experiments.effects.judge_direction` on the
  metric's paired test (McNemar, sign tests);
* NO_WORSE without a stated size (non-inferiority, margin δ): the (1 - L) interval of the paired difference, oriented
  so that positive is better, against -δ: lower bound above -δ **reproduced**, upper bound below -δ
  **contradicted**, else inconclusive (none below :data:`MIN_PAIRS` compared pairs), and **not decidable here** from
  20 pairs on when the measured rates need more than the protocol's pairs (:func:`_futile`). Collisions: δ = :data:`COLLISION_MARGIN`
  and the conservative interval of :func:`~driveopt.experiments.paired_stats.paired_risk_difference_interval`; speed
  and plan time: δ = :data:`RELATIVE_MARGIN` x the baseline's mean over the pairs and the t interval.

**Levels** (:func:`decide_claim`, :func:`control_figure`): each figure reads its claims at pre-declared looks (pairs,
``FigureProtocol.look_pairs``); a claim is judged at the O'Brien-Fleming nominal level of the last look its pairs
reached (:func:`~driveopt.experiments.error_control.obrien_fleming_levels`, overall α = :data:`ALPHA`), and is
**interim** until it reaches the full protocol; below the first look it is inconclusive with the pairs needed. The
figure's primary claim takes that level; each other claim's p-value (:func:`decision_p`: the smallest level at which
its rule decides) enters Holm's step-down over the figure's non-primary claims
(:func:`~driveopt.experiments.error_control.holm_adjusted`) and the claim is judged at the level at which its own
p-value decides exactly when its adjusted p-value is below its look's level.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from driveopt.experiments import effects
from driveopt.experiments.effects import LEVEL, RATIO, Judgement, PaperEffect
from driveopt.experiments.error_control import holm_adjusted, obrien_fleming_levels
from driveopt.experiments.paired_stats import (
    bootstrap_mean_interval,
    mcnemar_exact,
    mcnemar_pairs_needed,
    paired_risk_difference_interval,
    sign_test,
    t_interval,
)
from driveopt.experiments.protocols import BETTER, COLLISIONS, NO_WORSE, PLAN_TIME, SPEED, WORSE, Arm, Claim
from driveopt.experiments.summary import wilson_interval

ALPHA = 0.05  # two-sided family-wise level of each figure's claims over all its looks
COLLISION_MARGIN = 0.10  # [rate points] non-inferiority margin on the paired collision-rate difference
RELATIVE_MARGIN = 0.10  # [-] non-inferiority margin on speed and plan time, as a share of the baseline's mean
MIN_PAIRS = 20  # [-] pairs below which a non-inferiority interval gives no verdict
POWER = effects.POWER  # [-] the power the pairs still needed are estimated for
MAX_PAIRS_ESTIMATE = 100_000  # [-] beyond this the pairs needed are reported as unbounded
REPRODUCED = effects.REPRODUCED_IN_DIRECTION  # a direction shown
NO_WORSE_SHOWN = effects.REPRODUCED  # non-inferiority shown, or a stated size met
CONTRADICTED, INCONCLUSIVE, NOT_RUN = effects.CONTRADICTED, effects.INCONCLUSIVE, effects.NOT_RUN
UNDECIDED = (INCONCLUSIVE, NOT_RUN, effects.NOT_DECIDABLE)  # verdicts that more pairs may still change
# answers of a pooled question (protocols.Question) on one metric
CHANGES_BETTER, CHANGES_WORSE, NO_CHANGE, TOO_FEW_PAIRS = ("changes it: better", "changes it: worse",
                                                           "no change detected", "too few pairs yet")

Episode = tuple[int, int]  # (seed, episode)


@dataclass(frozen=True)
class ArmStats:
    """One arm's records on the claim's scenario. Rates in [0, 1], speeds [m/s], plan time [ms], wall time [s]."""

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
    episode_seconds: float = math.nan  # mean wall time of one episode, planning plus simulation (compilation aside)


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
    speed_difference_low: float  # 95% t interval
    speed_difference_high: float
    plan_pairs: int  # compared: both planned, on one processor model (and device)
    arm_quicker: int  # episodes with the arm's median plan time below the baseline's
    plan_sign_n: int
    plan_sign_p: float
    plan_difference: float  # mean of arm - baseline [ms]
    plan_difference_low: float  # 95% t interval
    plan_difference_high: float
    collision_difference_low: float  # conservative 95% interval of rate(arm) - rate(baseline)
    collision_difference_high: float
    verdict: str
    explanation: str = ""  # why a contradiction may arise, and what settles it (protocols.Claim.explanation)
    claim_id: str = ""  # protocols.claim_ids
    primary: bool = False  # the figure's primary claim (not Holm-adjusted)
    effect: PaperEffect = PaperEffect("the paper states a direction, no value")
    speed_difference_sd: float = math.nan  # standard deviation of the paired speed differences [m/s]
    plan_difference_sd: float = math.nan  # of the paired plan-time differences [ms]
    margin: float = math.nan  # non-inferiority margin δ in the metric's units (collisions: rate points)
    plan_pairs_unnamed: int = 0  # pairs left out of plan time: a record names no processor
    plan_pairs_mixed: int = 0  # pairs left out of plan time: two processor models or devices
    processors: tuple[str, ...] = ()  # the processor models (and devices) of the compared plan-time pairs
    test_p: float = math.nan  # the smallest level at which the claim's rule decides (decision_p); Holm's input
    holm_p: float = math.nan  # Holm-adjusted over the figure's non-primary claims (NaN: primary or alone)
    look: int = 0  # pairs of the last look reached (0: below the first)
    level: float = math.nan  # the two-sided level the verdict was reached at
    interim: bool = False  # judged at a look before the full protocol
    verdict_low: float = math.nan  # the interval the verdict rests on (ratio, rate, or oriented difference)
    verdict_high: float = math.nan
    pairs_needed: float = math.nan  # pairs still needed for a decision (NaN: none, or not estimable)
    detail: str = ""  # one line beside the verdict
    test_key: str = ""  # the same key for rows that are one test (the same arms, scenario, metric and rule)
    records: dict[str, Any] = field(default_factory=dict)  # where the paired records come from (reproduce.provenance)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def same_processor(x: dict[str, Any], y: dict[str, Any]) -> bool:
    """Whether two records' plan times are comparable: both name one processor model, and the same device where
    either names one, and both planned alone or in lock-step calls of one size (``lockstep``)."""
    return (x.get("cpu_model") is not None and x.get("cpu_model") == y.get("cpu_model")
            and x.get("device") == y.get("device") and x.get("lockstep") == y.get("lockstep"))


def processor_of(record: dict[str, Any]) -> str:
    """A record's processor model, with its device when it names one other than ``cpu``."""
    device = record.get("device")
    return record["cpu_model"] + (f" ({device})" if device and device != "cpu" else "")


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
    seconds = [float(r["plan_seconds"]) + float(r["sim_seconds"]) for r in records]
    return ArmStats(arm.label, arm.planner, arm.version, arm.note, n, crashed, crashed / n if n else math.nan, low, high,
                    float(np.mean(free)) if free else math.nan, speed_low, speed_high,
                    float(np.median(plans)) if plans else math.nan, float(np.mean(seconds)) if seconds else math.nan)


def _difference(a: list[float], b: list[float]) -> tuple[float, float, float, float]:
    """(mean, t low, t high, sd) of the paired differences a - b; NaN where too few."""
    d = np.asarray(a, float) - np.asarray(b, float)
    if d.size == 0:
        return (math.nan, math.nan, math.nan, math.nan)
    sd = float(d.std(ddof=1)) if d.size >= 2 else math.nan
    low, high = t_interval(float(d.mean()), sd, int(d.size))
    return (float(d.mean()), low, high, sd)


def evaluate(figure: str, claim: Claim, arm_records: dict[Episode, dict[str, Any]],
             baseline_records: dict[Episode, dict[str, Any]], seeds: tuple[int, ...], full_pairs: int,
             reduced: bool, *, looks: tuple[int, ...] | None = None, claim_id: str = "",
             primary: bool = False) -> ClaimResult:
    """``claim`` measured on the records of its two arms, each keyed by (seed, episode), and judged
    (:func:`decide_claim`): at the O'Brien-Fleming level of its last look when ``looks`` (pairs) are given, else once
    at :data:`ALPHA`. Holm's adjustment among a figure's claims is :func:`control_figure`'s."""
    keys = sorted(set(arm_records) & set(baseline_records))
    a = [arm_records[k] for k in keys]
    b = [baseline_records[k] for k in keys]
    only_arm = sum(bool(x["collided"]) and not y["collided"] for x, y in zip(a, b))
    only_base = sum(bool(y["collided"]) and not x["collided"] for x, y in zip(a, b))
    free = [(float(x["mean_speed"]), float(y["mean_speed"])) for x, y in zip(a, b) if not x["collided"] and not y["collided"]]
    faster, speed_n, speed_p = sign_test([x - y for x, y in free])
    speed_diff = _difference([x for x, _ in free], [y for _, y in free])
    planned = [(x, y) for x, y in zip(a, b) if math.isfinite(plan_ms_of(x)) and math.isfinite(plan_ms_of(y))]
    unnamed = sum(x.get("cpu_model") is None or y.get("cpu_model") is None for x, y in planned)
    compared = [(x, y) for x, y in planned if same_processor(x, y)]
    processors = tuple(sorted({processor_of(x) for x, _ in compared}))
    plans = [(plan_ms_of(x), plan_ms_of(y)) for x, y in compared]
    slower_plans, plan_n, plan_p = sign_test([x - y for x, y in plans])
    plan_diff = _difference([x for x, _ in plans], [y for _, y in plans])
    risk_low, risk_high = paired_risk_difference_interval(only_arm, only_base, len(keys))
    if claim.metric == COLLISIONS:
        margin = COLLISION_MARGIN
    elif claim.metric == SPEED:
        margin = RELATIVE_MARGIN * float(np.mean([y for _, y in free])) if free else math.nan
    elif claim.metric == PLAN_TIME:
        margin = RELATIVE_MARGIN * float(np.mean([y for _, y in plans])) if plans else math.nan
    else:
        raise ValueError(f"unknown metric {claim.metric!r}")
    result = ClaimResult(
        figure, claim.scenario, claim.metric, claim.expect, claim.paper, claim.like_for_like, claim.kind,
        arm_stats(claim.arm, a if keys else list(arm_records.values())),
        arm_stats(claim.baseline, b if keys else list(baseline_records.values())),
        tuple(seeds), len(keys), full_pairs, reduced or len(keys) < full_pairs,
        only_arm, only_base, mcnemar_exact(only_arm, only_base),
        len(free), faster, speed_n, speed_p, *speed_diff[:3],
        len(plans), plan_n - slower_plans, plan_n, plan_p, *plan_diff[:3],
        risk_low, risk_high, NOT_RUN, claim.explanation,
        claim_id=claim_id, primary=primary, effect=claim.effect, speed_difference_sd=speed_diff[3],
        plan_difference_sd=plan_diff[3], margin=margin, plan_pairs_unnamed=unnamed,
        plan_pairs_mixed=len(planned) - unnamed - len(compared), processors=processors)
    result = replace(result, test_p=decision_p(result))
    return decide_claim(result, looks)


# ------------------------------------------------------------------------------------------------ the rules


def information(r: ClaimResult) -> int:
    """The pairs a claim's test rests on: compared plan-time pairs for plan time, else every pair."""
    return r.plan_pairs if r.metric == PLAN_TIME else r.pairs


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


def _rule(r: ClaimResult) -> str:
    """Which rule judges ``r``: RATIO, LEVEL (collisions with a stated size), "direction" or "no worse"."""
    if r.metric == COLLISIONS and r.effect.kind in (RATIO, LEVEL):
        return r.effect.kind
    return "direction" if r.expect in (BETTER, WORSE) else "no worse"


def _oriented_difference(r: ClaimResult) -> tuple[float, float, int]:
    """(mean, sd, n) of the paired speed or plan-time differences, oriented so that positive favours the arm."""
    if r.metric == SPEED:
        return r.speed_difference, r.speed_difference_sd, r.speed_pairs
    return -r.plan_difference, r.plan_difference_sd, r.plan_pairs


def _risk_interval(r: ClaimResult, level: float) -> tuple[float, float]:
    """The conservative (1 - level) interval of rate(baseline) - rate(arm): positive favours the arm."""
    low, high = paired_risk_difference_interval(r.only_arm_collided, r.only_baseline_collided, r.pairs, 1.0 - level)
    return (-high, -low)


def _t_decides(mean: float, sd: float, n: int, margin: float) -> float:
    """The smallest two-sided level at which the t interval of a mean lies wholly above or below -margin."""
    if n < MIN_PAIRS or not all(math.isfinite(v) for v in (mean, sd, margin)):
        return 1.0
    if sd == 0.0:
        return 0.0 if mean != -margin else 1.0
    return float(min(1.0, 2.0 * stats.t.sf(abs(mean + margin) / (sd / math.sqrt(n)), n - 1)))


def _smallest_level(decides: Callable[[float], bool]) -> float:
    """The smallest level in [1e-12, 1) at which ``decides`` holds (it holds at every larger level), by bisection on
    the log scale; 1.0 when it holds at none."""
    low, high = 1e-12, 1.0 - 1e-9
    if not decides(high):
        return 1.0
    if decides(low):
        return low
    for _ in range(60):
        middle = math.sqrt(low * high)
        low, high = (low, middle) if decides(middle) else (middle, high)
    return high


def _level_arms(r: ClaimResult) -> list[tuple[str, ArmStats, tuple[float, float]]]:
    return [(name, stats_, bounds) for name, stats_, bounds in (("arm", r.arm, r.effect.arm_level),
                                                                 ("baseline", r.baseline, r.effect.baseline_level))
            if bounds is not None]


def decision_p(r: ClaimResult) -> float:
    """The p-value of ``r``'s rule: the smallest two-sided level at which it decides (McNemar's p for a ratio or a
    collision direction, the sign test's for a speed or plan-time direction; for levels and non-inferiority, where
    the verdict reads an interval, the level at which the interval first decides). 1.0 without pairs."""
    if r.pairs == 0:
        return 1.0
    rule = _rule(r)
    if rule == RATIO:
        return r.mcnemar_p
    if rule == "direction":
        better, worse, p = oriented_counts(r)
        return p if better != worse else 1.0
    if rule == LEVEL:
        return max(_smallest_level(lambda level, s=s, b=b: effects.judge_level(s.collisions, s.episodes, b, level).verdict
                                   != INCONCLUSIVE) for _, s, b in _level_arms(r))
    if r.metric == COLLISIONS:
        if r.pairs < MIN_PAIRS:
            return 1.0

        def decides(level: float) -> bool:
            low, high = _risk_interval(r, level)
            return low > -r.margin or high < -r.margin

        return _smallest_level(decides)
    mean, sd, n = _oriented_difference(r)
    return _t_decides(mean, sd, n, r.margin)


def _pairs_for_t(mean: float, sd: float, margin: float, level: float) -> float:
    """Pairs at which a t interval of a mean ``mean`` with spread ``sd`` clears -margin with :data:`POWER` (normal
    approximation), at least :data:`MIN_PAIRS`; inf when the mean is not above -margin."""
    if not all(math.isfinite(v) for v in (mean, sd, margin)) or mean + margin <= 0.0:
        return math.inf
    z = stats.norm.isf(level / 2.0) + stats.norm.ppf(POWER)
    return float(max(MIN_PAIRS, math.ceil((z * sd / (mean + margin)) ** 2)))


def _pairs_for_risk(only_arm_share: float, only_baseline_share: float, margin: float, level: float) -> float:
    """Pairs at which the conservative interval of a paired rate difference with these discordant shares lies above
    -margin with about :data:`POWER` (normal approximation); inf when it never does (within
    :data:`MAX_PAIRS_ESTIMATE`)."""
    if only_arm_share - only_baseline_share >= margin:
        return math.inf
    # the interval's z widened by the power's quantile: it clears -margin with about POWER at these shares
    z = stats.norm.isf(level / 4.0) + stats.norm.ppf(POWER)
    powered = 4.0 * float(stats.norm.sf(z))
    n = MIN_PAIRS
    while n <= MAX_PAIRS_ESTIMATE:
        low, high = paired_risk_difference_interval(round(only_arm_share * n), round(only_baseline_share * n), n,
                                                    1.0 - powered)
        if -high > -margin:
            return float(n)
        n = math.ceil(n * 1.1)
    return math.inf


def _judge_levels(r: ClaimResult, level: float) -> Judgement:
    judged = [(name, s, b, effects.judge_level(s.collisions, s.episodes, b, level)) for name, s, b in _level_arms(r)]
    for name, s, b, j in judged:
        if j.verdict in (effects.HIGHER, effects.LOWER):
            return Judgement(j.verdict, j.interval, detail=f"{name} {s.collisions}/{s.episodes} collided, the paper "
                                                           f"states {_percent(b)}")
    if all(j.verdict == effects.REPRODUCED for *_, j in judged):
        return Judgement(effects.REPRODUCED, judged[0][3].interval,
                         detail="; ".join(f"{name} {s.collisions}/{s.episodes} collided, the paper states {_percent(b)}"
                                          for name, s, b, _ in judged))
    open_ = [(name, j) for name, _, _, j in judged if j.verdict == INCONCLUSIVE]
    needed = max(j.needed for _, j in open_)
    return Judgement(INCONCLUSIVE, open_[0][1].interval, needed, "; ".join(f"{name}: {j.detail}" for name, j in open_))


def _percent(bounds: tuple[float, float]) -> str:
    low, high = bounds
    return f"{low:.0%}" if low == high else f"{low:.0%}-{high:.0%}"


def judge_at(r: ClaimResult, level: float) -> Judgement:
    """``r``'s verdict at the two-sided ``level`` by its rule (module docstring); ``needed``: total pairs."""
    if r.pairs == 0:
        return Judgement(NOT_RUN)
    rule = _rule(r)
    if rule == RATIO:
        judged = effects.judge_ratio(r.only_arm_collided, r.only_baseline_collided, r.arm.collisions,
                                     r.baseline.collisions, r.pairs, r.effect.ratio, level, r.full_pairs)
        measured = f"{r.arm.collisions / r.baseline.collisions:.2f}" if r.baseline.collisions else "-"
        ratio = (f"rate ratio {measured} [{judged.interval[0]:.2f}, {judged.interval[1]:.2f}], the paper's "
                 f"{r.effect.ratio[0]:.2g}-{r.effect.ratio[1]:.2g}; McNemar p {r.mcnemar_p:.3g}")
        return replace(judged, detail=f"{ratio}; {judged.detail}" if judged.detail else ratio)
    if rule == LEVEL:
        return _judge_levels(r, level)
    if rule == "direction":
        better, worse, p = oriented_counts(r)
        if r.expect == WORSE:
            better, worse = worse, better
        judged = effects.judge_direction(better, worse, p, level, pairs_to_decide(r, level)[1], r.full_pairs,
                                         information(r))
        counts = f"{better} pairs for the paper's direction, {worse} against, p {p:.3g}"
        return replace(judged, detail=f"{counts}; {judged.detail}" if judged.detail else counts)
    if r.metric == COLLISIONS:
        low, high = _risk_interval(r, level)
        shares = (r.only_arm_collided / r.pairs, r.only_baseline_collided / r.pairs)
        what = f"rate difference (baseline - arm) [{low:.2f}, {high:.2f}] against -{r.margin:.2f}"
        if r.pairs < MIN_PAIRS:
            return _futile(r, Judgement(INCONCLUSIVE, (low, high), max(MIN_PAIRS, _pairs_for_risk(*shares, r.margin, level)),
                                        f"no interval verdict below {MIN_PAIRS} pairs"))
        if low > -r.margin:
            return Judgement(NO_WORSE_SHOWN, (low, high), detail=what)
        if high < -r.margin:
            return Judgement(CONTRADICTED, (low, high), detail=what)
        return _futile(r, Judgement(INCONCLUSIVE, (low, high), _pairs_for_risk(*shares, r.margin, level), what))
    mean, sd, n = _oriented_difference(r)
    low, high = t_interval(mean, sd, n, 1.0 - level)
    unit = "m/s" if r.metric == SPEED else "ms"
    share = n / information(r) if information(r) else math.nan  # speed: the collision-free share of the pairs
    needed = _pairs_for_t(mean, sd, r.margin, level) / share if share else math.inf
    what = f"difference (positive: arm better) [{low:.2f}, {high:.2f}] {unit} against -{r.margin:.2f}"
    if n < MIN_PAIRS:
        return _futile(r, Judgement(INCONCLUSIVE, (low, high), max(needed, MIN_PAIRS / share if share else math.inf),
                                    f"{n} compared pairs: no interval verdict below {MIN_PAIRS}"))
    if low > -r.margin:
        return Judgement(NO_WORSE_SHOWN, (low, high), detail=what)
    if high < -r.margin:
        return Judgement(CONTRADICTED, (low, high), detail=what)
    return _futile(r, Judgement(INCONCLUSIVE, (low, high), needed, what))


def _futile(r: ClaimResult, j: Judgement) -> Judgement:
    """An inconclusive non-inferiority judgement ``j`` as **not decidable here** once the claim has
    :data:`~driveopt.experiments.effects.FUTILITY_PAIRS` pairs and the pairs its interval needs at the measured
    rates exceed the protocol's (as for a direction, :func:`~driveopt.experiments.effects.judge_direction`): e.g. a
    speed compared over collision-free pairs when one arm collides in nearly every pair."""
    if information(r) < effects.FUTILITY_PAIRS or j.needed <= r.full_pairs:
        return j
    why = (f"at the measured rates the interval needs {j.needed:.0f} pairs, the protocol runs {r.full_pairs}"
           if math.isfinite(j.needed) else f"at the measured rates no number of pairs decides it")
    return Judgement(effects.NOT_DECIDABLE, j.interval, j.needed, f"{j.detail}; {why}" if j.detail else why)


def decide_claim(r: ClaimResult, looks: tuple[int, ...] | None = None, holm_p: float | None = None) -> ClaimResult:
    """``r`` with its verdict: at :data:`ALPHA` without ``looks``; with them, at the O'Brien-Fleming nominal level of
    the last look its pairs reached (interim before the last look; inconclusive below the first, with the pairs the
    first look or the rule needs, whichever is more). ``holm_p``: the claim's Holm-adjusted p-value among its
    figure's non-primary claims, which scales the level so that the claim's own p-value decides exactly when the
    adjusted one is below the look's level."""
    info = information(r)
    if r.pairs == 0:
        return replace(r, verdict=NOT_RUN, holm_p=math.nan if holm_p is None else holm_p, look=0, level=math.nan,
                       interim=False, verdict_low=math.nan, verdict_high=math.nan, pairs_needed=math.nan,
                       detail="no episode recorded for both arms")
    if looks:
        levels = obrien_fleming_levels(looks, ALPHA)
        reached = [k for k, n in enumerate(looks) if n <= info]
        if not reached:
            final = judge_at(r, _scaled(levels[-1], r.test_p, holm_p))
            total = max(looks[0], final.needed) if math.isfinite(final.needed) else float(looks[0])
            return replace(r, verdict=INCONCLUSIVE, holm_p=math.nan if holm_p is None else holm_p, look=0,
                           level=math.nan, interim=True, verdict_low=final.interval[0], verdict_high=final.interval[1],
                           pairs_needed=max(0.0, total - info),
                           detail=f"below the first look ({looks[0]} pairs): {total - info:.0f} more pairs"
                                  + (f" ({final.detail})" if final.detail and final.verdict in UNDECIDED else ""))
        look, nominal, interim = looks[reached[-1]], levels[reached[-1]], info < looks[-1]
    else:
        look, nominal, interim = info, ALPHA, False
    level = _scaled(nominal, r.test_p, holm_p)
    j = judge_at(r, level)
    if interim and j.verdict in UNDECIDED:
        # whether more pairs can decide it, and how many, is a question for the final look's level
        final = judge_at(r, _scaled(levels[-1], r.test_p, holm_p))
        upcoming = next(n for n in looks if n > info)
        if final.verdict in UNDECIDED:
            j = replace(final, interval=j.interval)
        else:
            j = Judgement(INCONCLUSIVE, j.interval, upcoming,
                          f"{final.verdict} at the final look's level, not at this look's {level:.2g}; next look at "
                          f"{upcoming} pairs" + (f" ({final.detail})" if final.detail else ""))
    needed = max(0.0, j.needed - info) if math.isfinite(j.needed) else (j.needed if j.verdict in UNDECIDED else math.nan)
    return replace(r, verdict=j.verdict, holm_p=math.nan if holm_p is None else holm_p, look=look, level=level,
                   interim=interim, verdict_low=j.interval[0], verdict_high=j.interval[1], pairs_needed=needed,
                   detail=j.detail)


def _scaled(nominal: float, p: float, holm_p: float | None) -> float:
    """The level at which a claim's own p-value ``p`` passes exactly when its Holm-adjusted ``holm_p`` is below
    ``nominal``."""
    if holm_p is None or holm_p <= 0.0 or not math.isfinite(p):
        return nominal
    return nominal * min(1.0, p / holm_p)


def control_figure(results: list[ClaimResult], looks: tuple[int, ...]) -> list[ClaimResult]:
    """A figure's measured claims (in order) judged with its error control: the primary at its look's level, the
    others by Holm's step-down over their :func:`decision_p` values (a claim without pairs enters with p = 1: the
    family is the protocol's, whatever has run)."""
    others = [i for i, r in enumerate(results) if not r.primary]
    adjusted = dict(zip(others, holm_adjusted([results[i].test_p for i in others])))
    return [decide_claim(r, looks, adjusted.get(i)) for i, r in enumerate(results)]


def answer(r: ClaimResult, min_pairs: int) -> str:
    """A pooled question's answer on ``r``'s metric: TOO_FEW_PAIRS below ``min_pairs`` pairs; else the paired test at
    ALPHA, two-sided: CHANGES_BETTER or CHANGES_WORSE (for the arm), or NO_CHANGE. Plan time counts the pairs it
    compares (both planned, on one processor model)."""
    if information(r) < min_pairs:
        return TOO_FEW_PAIRS
    better, worse, p = oriented_counts(r)
    if p >= ALPHA or better == worse:
        return NO_CHANGE
    return CHANGES_BETTER if better > worse else CHANGES_WORSE


# ------------------------------------------------------------------------------------------------ planning


def pairs_to_decide(r: ClaimResult, level: float = ALPHA) -> tuple[float, float]:
    """(at the paper's size, at the measured rates): total pairs at which ``r``'s rule decides with :data:`POWER` at
    ``level``; NaN where the paper states no size (a direction, non-inferiority at no difference is used for "no
    worse"), inf where the measured rates never decide it, NaN without pairs to measure."""
    if r.pairs == 0:
        return (math.nan, math.nan)
    rule = _rule(r)
    base_rate = r.baseline.collisions / r.pairs
    if r.metric == COLLISIONS and rule in (RATIO, "direction"):
        measured = (mcnemar_pairs_needed(base_rate, (r.arm.collisions / r.pairs) / base_rate, level, POWER)
                    if base_rate > 0 else math.inf)
        if rule == RATIO:
            weakest = r.effect.ratio[1] if r.effect.ratio[1] < 1.0 else r.effect.ratio[0]
            return (mcnemar_pairs_needed(base_rate, weakest, level, POWER) if base_rate > 0 else math.inf, measured)
        return (math.nan, measured)
    if rule == LEVEL:
        z = float(stats.norm.isf(level / 2.0))
        arms = _level_arms(r)
        paper = max(effects._episodes_for_level(b[1], effects.level_tolerance(b), z) for _, _, b in arms)
        measured = max(effects._episodes_for_level(s.collisions / s.episodes, effects.level_tolerance(b), z)
                       for _, s, b in arms)
        return (paper, measured)
    if rule == "direction":
        better, worse, _ = oriented_counts(r)
        n, share = better + worse, (better + worse) / information(r) if information(r) else 0.0
        if not n or better == worse or not share:
            return (math.nan, math.inf)
        f = max(better, worse) / n
        z_a, z_b = stats.norm.isf(level / 2.0), stats.norm.ppf(POWER)
        sign_pairs = ((z_a * 0.5 + z_b * math.sqrt(f * (1.0 - f))) / (f - 0.5)) ** 2
        return (math.nan, float(math.ceil(sign_pairs / share)))
    if r.metric == COLLISIONS:
        d = (r.only_arm_collided + r.only_baseline_collided) / r.pairs
        return (_pairs_for_risk(d / 2.0, d / 2.0, r.margin, level),
                _pairs_for_risk(r.only_arm_collided / r.pairs, r.only_baseline_collided / r.pairs, r.margin, level))
    mean, sd, n = _oriented_difference(r)
    share = n / information(r) if information(r) else 0.0
    if not share:
        return (math.nan, math.nan)
    return (_pairs_for_t(0.0, sd, r.margin, level) / share, _pairs_for_t(mean, sd, r.margin, level) / share)
