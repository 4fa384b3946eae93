"""Each verdict on a paper's stated size is reached on a constructed case, with the numbers behind it."""

import math

import pytest

from driveopt.experiments import effects as e

FOUR_TO_TEN = e.PaperEffect.times_fewer(4, 10, "text: '4-10x fewer collisions'").ratio  # (0.1, 0.25)


def test_paper_effects_declare_their_kind_and_refuse_nonsense():
    assert FOUR_TO_TEN == pytest.approx((0.1, 0.25))
    assert e.PaperEffect("text", arm_level=(0.03, 0.03)).kind == e.LEVEL
    assert e.PaperEffect("figure only").kind == e.DIRECTION
    with pytest.raises(ValueError, match="low <= high"):
        e.PaperEffect("x", ratio=(0.5, 0.1))
    with pytest.raises(ValueError, match="not both"):
        e.PaperEffect("x", ratio=(0.1, 0.2), arm_level=(0.0, 0.0))


def test_ratio_reproduced_when_significant_and_the_interval_meets_the_range():
    # 100 pairs: arm 4 collisions, baseline 25 (ratio 0.16); discordant 2 against 23
    j = e.judge_ratio(2, 23, 4, 25, 100, FOUR_TO_TEN, 0.05, 100)
    assert j.verdict == e.REPRODUCED and j.interval[0] < 0.16 < j.interval[1]


def test_ratio_smaller_than_the_papers_when_the_interval_lies_toward_no_effect():
    # 400 pairs: arm 120, baseline 200 (ratio 0.6): significant, interval well above 0.25
    j = e.judge_ratio(20, 100, 120, 200, 400, FOUR_TO_TEN, 0.05, 400)
    assert j.verdict == e.SMALLER and j.interval[0] > 0.25


def test_ratio_larger_than_the_papers():
    j = e.judge_ratio(0, 150, 1, 151, 400, (0.5, 0.6), 0.05, 400)  # ratio ~0.007 against "2x fewer"
    assert j.verdict == e.LARGER and j.interval[1] < 0.5


def test_ratio_contradicted_when_the_arm_collides_significantly_more():
    assert e.judge_ratio(20, 2, 25, 7, 100, FOUR_TO_TEN, 0.05, 100).verdict == e.CONTRADICTED


def test_size_excluded_without_a_significant_direction():
    # 400 pairs, 60 against 62 collisions: no direction, the ratio ~1 excludes 0.1-0.25
    j = e.judge_ratio(30, 32, 60, 62, 400, FOUR_TO_TEN, 0.05, 400)
    assert j.verdict == e.SIZE_EXCLUDED and j.interval[0] > 0.25


def test_not_decidable_when_the_baseline_collides_too_rarely_for_the_protocol():
    # 20 pairs, no collision anywhere: the baseline's 95% upper rate is 16.1%; 4x fewer than that needs ~99 pairs
    j = e.judge_ratio(0, 0, 0, 0, 20, FOUR_TO_TEN, 0.05, 60)
    assert j.verdict == e.NOT_DECIDABLE and 90 < j.needed < 110 and "16.1%" in j.detail
    assert e.judge_ratio(0, 0, 0, 0, 20, FOUR_TO_TEN, 0.05, 200).verdict == e.INCONCLUSIVE


def test_inconclusive_names_the_pairs_still_needed():
    j = e.judge_ratio(1, 3, 2, 4, 10, FOUR_TO_TEN, 0.05, 1000)
    assert j.verdict == e.INCONCLUSIVE and math.isfinite(j.needed) and j.needed > 10
    assert f"{j.needed:.0f} pairs" in j.detail
    assert e.judge_ratio(0, 0, 0, 0, 0, FOUR_TO_TEN, 0.05, 100).verdict == e.NOT_RUN


def test_a_stricter_alpha_turns_a_reproduction_into_an_inconclusive_row():
    assert e.judge_ratio(2, 12, 4, 14, 60, FOUR_TO_TEN, 0.05, 100).verdict == e.REPRODUCED  # p = 0.0129
    assert e.judge_ratio(2, 12, 4, 14, 60, FOUR_TO_TEN, 0.005, 100).verdict == e.INCONCLUSIVE


def test_levels_are_judged_on_the_arm_alone():
    three = (0.03, 0.03)
    assert e.level_tolerance(three) == pytest.approx(0.08)
    assert e.judge_level(2, 100, three, 0.05).verdict == e.REPRODUCED  # 2% in [0.6%, 7.0%]
    assert e.judge_level(15, 50, three, 0.05).verdict == e.HIGHER
    assert e.judge_level(0, 400, (0.05, 0.05), 0.05).verdict == e.LOWER
    j = e.judge_level(1, 20, three, 0.05)  # 5% of 20: the interval reaches 24%
    assert j.verdict == e.INCONCLUSIVE and j.needed > 20 and "episodes" in j.detail
    assert e.judge_level(0, 0, three, 0.05).verdict == e.NOT_RUN


def test_direction_only_claims():
    assert e.judge_direction(12, 1, 0.0034, 0.05).verdict == e.REPRODUCED_IN_DIRECTION
    assert e.judge_direction(1, 12, 0.0034, 0.05).verdict == e.CONTRADICTED
    assert e.judge_direction(5, 3, 0.73, 0.05).verdict == e.INCONCLUSIVE


def test_a_direction_the_protocol_cannot_show_at_the_measured_rates_is_not_decidable():
    # 31 vs 30 discordant-style counts: far more pairs than a 100-pair protocol runs
    futile = e.judge_direction(5, 4, 1.0, 0.05, needed=4572, max_pairs=100, pairs=40)
    assert futile.verdict == e.NOT_DECIDABLE and "4572 pairs" in futile.detail and "runs 100" in futile.detail
    assert e.judge_direction(3, 3, 1.0, 0.05, needed=math.inf, max_pairs=100, pairs=40).verdict == e.NOT_DECIDABLE
    # within reach of the protocol, or too few pairs to judge futility: inconclusive
    assert e.judge_direction(5, 1, 0.22, 0.05, needed=60, max_pairs=100, pairs=40).verdict == e.INCONCLUSIVE
    assert e.judge_direction(5, 4, 1.0, 0.05, needed=4572, max_pairs=100, pairs=10).verdict == e.INCONCLUSIVE
    # a significant direction is decided whatever the estimate
    assert e.judge_direction(12, 1, 0.0034, 0.05, needed=4572, max_pairs=100, pairs=40).verdict == e.REPRODUCED_IN_DIRECTION
