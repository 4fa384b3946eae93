"""driveopt reproduce: paired statistics against hand-computed values, the verdict rule, the declared protocols, the
report's rows, resuming from the bench store, bad input, and one small real run."""

import argparse
import json
import math
import time
from dataclasses import replace

import numpy as np
import pytest

from driveopt.errors import DriveoptError
from driveopt.experiments import paired_stats as ps
from driveopt.experiments.protocols import (
    BETTER,
    COLLISIONS,
    DRIVEOPT_ROW,
    FAITHFUL,
    FAITHFUL_ROW,
    MIXED_ROW,
    NO_WORSE,
    PLAN_TIME,
    REFERENCE,
    SPEED,
    STRENGTHENED,
    WORSE,
    Arm,
    Claim,
    FigureProtocol,
    ProtocolError,
    figures_of,
)
from driveopt.experiments.reproduce import RunSlice, answer_questions, reproduce, run_figures
from driveopt.experiments.reproduce_report import markdown
from driveopt.experiments.runner import cpu_model
from driveopt.experiments.summary import wilson_interval
from driveopt.experiments import effects
from driveopt.experiments.effects import PaperEffect
from driveopt.experiments.error_control import obrien_fleming_levels
from driveopt.experiments.verdicts import (
    ALPHA,
    CHANGES_BETTER,
    CHANGES_WORSE,
    CONTRADICTED,
    INCONCLUSIVE,
    NO_CHANGE,
    NO_WORSE_SHOWN,
    NOT_RUN,
    REPRODUCED,
    TOO_FEW_PAIRS,
    answer,
    control_figure,
    evaluate,
)
from driveopt.registry import get_planner

# ---------------------------------------------------------------------------------------------- statistics


def test_binomial_and_mcnemar_match_hand_computed_values():
    assert ps.binomial_two_sided(2, 10) == pytest.approx(2 * (1 + 10 + 45) / 1024)
    assert ps.binomial_two_sided(8, 10) == pytest.approx(2 * (1 + 10 + 45) / 1024)  # symmetric
    assert ps.binomial_two_sided(5, 10) == 1.0  # capped
    assert ps.binomial_two_sided(0, 0) == 1.0
    assert ps.mcnemar_exact(0, 5) == pytest.approx(2 / 32)  # 0.0625: five discordant pairs cannot reach 0.05
    assert ps.mcnemar_exact(0, 6) == pytest.approx(2 / 64)
    assert ps.mcnemar_exact(1, 9) == pytest.approx(2 * 11 / 1024)
    assert ps.mcnemar_exact(9, 1) == ps.mcnemar_exact(1, 9)
    assert ps.mcnemar_exact(3, 3) == 1.0
    with pytest.raises(ValueError):
        ps.binomial_two_sided(4, 3)


def test_mcnemar_agrees_with_the_binomial_definition_by_enumeration():
    for b in range(8):
        for c in range(8):
            n = b + c
            probs = [math.comb(n, i) / 2**n for i in range(n + 1)]
            # two-sided exact: the total probability of outcomes no more likely than the observed one
            expected = min(1.0, sum(p for p in probs if p <= probs[b] * (1 + 1e-12))) if n else 1.0
            assert ps.mcnemar_exact(b, c) == pytest.approx(expected)


def test_sign_test_drops_ties():
    assert ps.sign_test([1.0, -1.0, 0.0, 2.0, 3.0]) == (3, 4, pytest.approx(2 * (1 + 4) / 16))
    assert ps.sign_test([0.0, 0.0]) == (0, 0, 1.0)
    positive, n, p = ps.sign_test([0.5] * 10)
    assert (positive, n) == (10, 10) and p == pytest.approx(2 / 1024)


def test_wilson_intervals_at_the_edges_and_the_simultaneous_z():
    low, high = wilson_interval(0, 50)
    assert low == 0.0 and high == pytest.approx(1.959964**2 / (50 + 1.959964**2))
    low, high = wilson_interval(0, 50, z=ps.Z_97_5)
    assert high == pytest.approx(ps.Z_97_5**2 / (50 + ps.Z_97_5**2))
    low, high = ps.paired_risk_difference_interval(0, 0, 50)
    assert low == pytest.approx(-high) and 0.0 < high < 0.10
    low, high = ps.paired_risk_difference_interval(10, 0, 50)  # only the first collided, 10 times: the difference is 0.2
    assert low > 0.0 and low < 0.2 < high
    assert all(math.isnan(v) for v in ps.paired_risk_difference_interval(0, 0, 0))


def test_bootstrap_interval_is_fixed_and_holds_the_mean():
    x = np.random.default_rng(3).normal(5.0, 1.0, 40)
    a, b = ps.bootstrap_mean_interval(x), ps.bootstrap_mean_interval(x)
    assert a == b and a[0] < x.mean() < a[1]
    half = 1.959964 * x.std(ddof=1) / math.sqrt(x.size)  # the normal-theory interval, for scale
    assert a[1] - a[0] == pytest.approx(2 * half, rel=0.15)
    assert all(math.isnan(v) for v in ps.bootstrap_mean_interval([1.0]))


# ---------------------------------------------------------------------------------------------- verdict rule


def _record(planner, seed, episode, collided, speed, plan_ms=None, scenario="s", **extra):
    return {"scenario": scenario, "planner": planner, "seed": seed, "episode": episode, "collided": collided,
            "off_road": False, "mean_speed": speed, "sim_seconds": 1.0, "plan_seconds": 0.1,
            **({"plan_ms": plan_ms} if plan_ms else {}), **extra}


ARM, BASE = Arm("bilevel", STRENGTHENED, 250), Arm("grid", STRENGTHENED, 250)


def _collisions(n, arm_collided, base_collided, speed=lambda e: 8.0):
    """n paired episodes: the arm collides in the episodes of ``arm_collided``, the baseline in ``base_collided``."""
    a = {(42, e): _record("bilevel", 42, e, e in arm_collided, speed(e)) for e in range(n)}
    b = {(42, e): _record("grid", 42, e, e in base_collided, 8.0) for e in range(n)}
    return a, b


def _judged(effect, a, b, expect=BETTER, metric=COLLISIONS, full=100, looks=None):
    claim = Claim("s", ARM, BASE, metric, expect, "paper", effect=effect)
    return evaluate("fig", claim, a, b, (42,), full, False, looks=looks)


FOUR_TO_TEN = PaperEffect.times_fewer(4, 10, "text")


def test_a_stated_ratio_is_judged_on_its_size_through_evaluate():
    # 100 pairs, arm 2 collisions, baseline 20 (ratio 0.1, inside 4-10x fewer): reproduced with the interval
    r = _judged(FOUR_TO_TEN, *_collisions(100, {0, 1}, set(range(20))))
    assert r.verdict == effects.REPRODUCED and r.verdict_low < 0.1 < r.verdict_high and r.level == ALPHA
    assert "rate ratio 0.10" in r.detail and r.test_p == pytest.approx(r.mcnemar_p)
    # 14 against 30 in 100: significant, the interval [0.19, 1.13] still meets 0.25: reproduced; at 400 pairs, 120
    # against 200, the interval lies above 0.25: smaller than the paper's
    assert _judged(FOUR_TO_TEN, *_collisions(100, set(range(14)), set(range(30)))).verdict == effects.REPRODUCED
    r = _judged(FOUR_TO_TEN, *_collisions(400, set(range(120)), set(range(200))), full=400)
    assert r.verdict == effects.SMALLER and r.verdict_low > 0.25
    # the arm collides more, significantly: contradicted
    assert _judged(FOUR_TO_TEN, *_collisions(100, set(range(25)), set(range(5)))).verdict == CONTRADICTED
    # the same rate on both sides: the paper's size excluded
    r = _judged(FOUR_TO_TEN, *_collisions(100, set(range(30)), set(range(30))))
    assert r.verdict == effects.SIZE_EXCLUDED and r.verdict_low > 0.25
    # no baseline collision in 100 pairs: even its upper rate cannot show 4x in the protocol's 100
    r = _judged(FOUR_TO_TEN, *_collisions(100, set(), set()))
    assert r.verdict == effects.NOT_DECIDABLE and "needs" in r.detail
    # a few pairs, a few collisions: inconclusive with the pairs still needed
    r = _judged(FOUR_TO_TEN, *_collisions(40, set(), {0, 1, 2, 3}), full=400)
    assert r.verdict == INCONCLUSIVE and 0 < r.pairs_needed < math.inf


def test_stated_levels_are_judged_per_arm_through_evaluate():
    both_zero = PaperEffect("text", arm_level=(0.0, 0.0), baseline_level=(0.0, 0.0))
    r = _judged(both_zero, *_collisions(100, set(), set()), expect=NO_WORSE)
    assert r.verdict == effects.REPRODUCED and r.verdict_high < 0.05
    r = _judged(both_zero, *_collisions(100, set(), {3, 9}), expect=NO_WORSE)
    assert r.verdict == effects.HIGHER and r.detail.startswith("baseline 2/100")
    r = _judged(both_zero, *_collisions(20, set(), set()), expect=NO_WORSE)
    assert r.verdict == INCONCLUSIVE and r.pairs_needed > 0  # 0/20: the upper bound is still above 5%
    three = PaperEffect("text", arm_level=(0.03, 0.03))
    six = set(range(0, 200, 34))  # 6 of 200: the Wilson upper bound 6.4% is within the tolerance of 8%
    assert _judged(three, *_collisions(200, six, set(range(40))), expect=NO_WORSE, full=200).verdict == effects.REPRODUCED
    assert _judged(three, *_collisions(100, set(range(20)), set()), expect=NO_WORSE).verdict == effects.HIGHER


def test_directions_and_non_inferiority_through_evaluate():
    direction = PaperEffect("text")
    assert _judged(direction, *_collisions(20, set(), set(range(8)))).verdict == REPRODUCED
    assert _judged(direction, *_collisions(20, set(range(8)), set())).verdict == CONTRADICTED
    assert _judged(direction, *_collisions(20, set(), set(range(5)))).verdict == INCONCLUSIVE  # p = 0.0625
    # speed "no worse" on a t interval: none below 20 pairs, reproduced at 30 within 10%, contradicted when far slower
    close = lambda e: 8.0 + 0.05 * ((e % 5) - 2)  # noqa: E731
    r = _judged(direction, *_collisions(19, set(), set(), close), expect=NO_WORSE, metric=SPEED)
    assert r.verdict == INCONCLUSIVE and "below 20" in r.detail
    r = _judged(direction, *_collisions(30, set(), set(), close), expect=NO_WORSE, metric=SPEED)
    assert r.verdict == NO_WORSE_SHOWN and r.verdict_low > -0.8
    r = _judged(direction, *_collisions(30, set(), set(), lambda e: 6.0 + 0.01 * e), expect=NO_WORSE, metric=SPEED)
    assert r.verdict == CONTRADICTED and r.verdict_high < -0.8
    # a baseline colliding in all but 2 of 40 pairs leaves no speeds to compare: not decidable here, not inconclusive
    r = _judged(direction, *_collisions(40, set(), set(range(38)), close), expect=NO_WORSE, metric=SPEED)
    assert r.verdict == effects.NOT_DECIDABLE and "the protocol runs 100" in r.detail
    # ... while 19 such pairs are too few to say so
    r = _judged(direction, *_collisions(19, set(), set(range(17)), close), expect=NO_WORSE, metric=SPEED)
    assert r.verdict == INCONCLUSIVE


def test_a_claim_passing_at_alpha_but_not_at_its_look_is_interim_inconclusive():
    looks = (10, 20, 40, 100)
    a, b = _collisions(20, set(), set(range(7)))  # McNemar p = 2/128 = 0.016 < 0.05
    once = _judged(PaperEffect("text"), a, b)
    assert once.verdict == REPRODUCED and not once.interim
    at_look = _judged(PaperEffect("text"), a, b, looks=looks)
    assert at_look.look == 20 and at_look.level == pytest.approx(obrien_fleming_levels(looks)[1])
    assert at_look.verdict == INCONCLUSIVE and at_look.interim and at_look.pairs_needed == 20  # the next look, at 40
    assert "not at this look's" in at_look.detail
    # far below the look's level it passes, still interim
    strong = _judged(PaperEffect("text"), *_collisions(40, set(), set(range(25))), looks=looks)
    assert strong.verdict == REPRODUCED and strong.interim and strong.look == 40
    # at the full protocol it is final
    final = _judged(PaperEffect("text"), *_collisions(100, set(), set(range(9))), looks=looks)
    assert final.verdict == REPRODUCED and not final.interim and final.look == 100
    # below the first look: inconclusive with the pairs to it
    early = _judged(PaperEffect("text"), *_collisions(6, set(), set(range(6))), looks=looks)
    assert early.verdict == INCONCLUSIVE and early.look == 0 and early.pairs_needed == 4


def test_holm_adjusts_the_figure_s_other_claims_but_not_its_primary():
    direction = PaperEffect("text")
    measured = []
    for only_base, primary in ((8, True), (8, False), (8, False), (2, False)):  # p = 2/256 each, then 0.5
        a, b = _collisions(100, set(), set(range(only_base)))
        claim = Claim("s", ARM, BASE, COLLISIONS, BETTER, "paper", effect=direction)
        measured.append(evaluate("fig", claim, a, b, (42,), 100, False, primary=primary))
    judged = control_figure(measured, (100,))
    assert judged[0].verdict == REPRODUCED and math.isnan(judged[0].holm_p)  # p 0.0078 at α
    # the others: Holm over (0.0078, 0.0078, 0.5): 0.0234, 0.0234, 0.5; both pass, at a level scaled to their p; the
    # last, 2 against none in the protocol's 100 pairs, would need far more: not decidable here
    assert [r.verdict for r in judged[1:]] == [REPRODUCED, REPRODUCED, effects.NOT_DECIDABLE]
    assert "the protocol runs 100" in judged[3].detail
    assert judged[1].holm_p == pytest.approx(3 * 2 / 256) and judged[1].level == pytest.approx(ALPHA / 3)
    # six discordant pairs pass alone (p = 0.031) but not among three claims (Holm 0.094)
    a, b = _collisions(100, set(), set(range(6)))
    claim = Claim("s", ARM, BASE, COLLISIONS, BETTER, "paper", effect=direction)
    alone = evaluate("fig", claim, a, b, (42,), 100, False)
    assert alone.verdict == REPRODUCED
    family = control_figure([replace(alone, primary=True), alone, alone, alone], (100,))
    # (and, at the protocol's end, more pairs than it runs would be needed to show it at Holm's level)
    assert family[0].verdict == REPRODUCED and [r.verdict for r in family[1:]] == [effects.NOT_DECIDABLE] * 3


def test_plan_times_pair_only_records_of_one_processor():
    a = {(42, e): _record("bilevel", 42, e, False, 8.0, [50.0], cpu_model="A", device="cpu") for e in range(30)}
    b = {(42, e): _record("grid", 42, e, False, 8.0, [10.0], cpu_model="A", device="cpu") for e in range(30)}
    for e in range(5):  # other processor
        b[(42, e)]["cpu_model"] = "B"
    for e in range(5, 8):  # a record naming none
        del a[(42, e)]["cpu_model"]
    b[(42, 8)]["device"] = "gpu"  # same model, other device
    r = _judged(PaperEffect("text"), a, b, expect=NO_WORSE, metric=PLAN_TIME, full=30)
    assert (r.pairs, r.plan_pairs, r.plan_pairs_unnamed, r.plan_pairs_mixed) == (30, 21, 3, 6)
    assert r.processors == ("A",) and r.verdict == CONTRADICTED  # 50 ms against 10
    assert answer(r, 22) == TOO_FEW_PAIRS and answer(r, 21) == CHANGES_WORSE  # a question counts compared pairs


def test_evaluate_pairs_episodes_and_counts():
    arm, base = ARM, BASE
    a = {(42, e): _record("bilevel", 42, e, False, 8.0 + 0.01 * e, [50.0]) for e in range(20)}
    b = {(42, e): _record("grid", 42, e, e < 8, 7.0, [10.0]) for e in range(20)}
    b[(42, 99)] = _record("grid", 42, 99, True, 1.0)  # unpaired: not counted
    fewer = evaluate("fig", Claim("s", arm, base, COLLISIONS, BETTER, "fewer"), a, b, (42,), 100, False)
    assert (fewer.pairs, fewer.only_arm_collided, fewer.only_baseline_collided) == (20, 0, 8)
    assert fewer.mcnemar_p == pytest.approx(2 / 256) and fewer.verdict == REPRODUCED
    assert fewer.reduced and fewer.full_pairs == 100  # 20 pairs of 100: says so
    assert fewer.arm.collisions == 0 and fewer.baseline.collisions == 8 and fewer.baseline.episodes == 20
    assert fewer.arm.episode_seconds == pytest.approx(1.1)  # plan 0.1 s + simulation 1.0 s
    faster = evaluate("fig", Claim("s", arm, base, SPEED, BETTER, "faster"), a, b, (42,), 20, False)
    assert (faster.speed_pairs, faster.arm_faster) == (12, 12) and faster.verdict == REPRODUCED
    assert faster.speed_difference == pytest.approx(np.mean([1.0 + 0.01 * e for e in range(8, 20)]))
    d = [1.0 + 0.01 * e for e in range(8, 20)]
    assert (faster.speed_difference_low, faster.speed_difference_high) == pytest.approx(ps.t_mean_interval(d))
    slower = evaluate("fig", Claim("s", base, arm, SPEED, BETTER, "faster"), b, a, (42,), 20, False)
    assert slower.verdict == CONTRADICTED
    # plan times of records naming no processor are not compared
    plan = evaluate("fig", Claim("s", arm, base, PLAN_TIME, NO_WORSE, "minimal"), a, b, (42,), 20, False)
    assert plan.plan_pairs == 0 and plan.plan_pairs_unnamed == 20 and plan.verdict == INCONCLUSIVE
    none = evaluate("fig", Claim("s", arm, base, COLLISIONS, BETTER, "fewer"), {}, b, (42,), 20, False)
    assert none.pairs == 0 and none.verdict == NOT_RUN


# ---------------------------------------------------------------------------------------------- protocols


def test_every_figure_of_both_papers_is_declared_with_registered_planners():
    p1 = figures_of("p1")
    p2 = figures_of("p2")
    assert [f.figure for f in p1] == ["fig7", "fig8", "fig9", "fig10", "fig11", "fig12"]
    assert [f.figure for f in p2] == ["fig1", "fig7", "fig8a", "fig8b", "fig9"]
    for figure in p1 + p2:
        assert bool(figure.not_run) != bool(figure.claims), figure.figure  # either claims or a reason
        for claim in figure.claims:
            for arm in (claim.arm, claim.baseline):
                get_planner(arm.planner)
                assert arm.version in (FAITHFUL, STRENGTHENED, REFERENCE)
            assert claim.paper and claim.expect in (BETTER, WORSE, NO_WORSE)
            assert claim.like_for_like == (claim.kind != MIXED_ROW)
    # every figure with claims compares the faithful methods and driveopt's side by side (the RL agents of Figs. 8
    # and 12 are P1's own, so driveopt's optimiser meets them in mixed rows)
    for figure in p1 + p2:
        if figure.claims:
            kinds = {c.kind for c in figure.claims}
            assert FAITHFUL_ROW in kinds and kinds & {DRIVEOPT_ROW, MIXED_ROW}, figure.figure
    # P1 Fig. 7: driveopt's bilevel against driveopt's baselines, the faithful MPC-Bi-Level against the faithful ones
    fig7 = p1[0]
    for baseline in ("random", "grid", "batch", "vanilla"):
        strong = [c for c in fig7.claims if c.baseline.planner == baseline]
        faithful = [c for c in fig7.claims if c.baseline.planner == f"{baseline}-faithful"]
        assert len(strong) == len(faithful) == 8  # 4 roads x (collisions, speed)
        assert all(c.arm.planner == "bilevel" and c.kind == DRIVEOPT_ROW for c in strong)
        assert all(c.arm.planner == "cvae-faithful" and c.kind == FAITHFUL_ROW for c in faithful)
        assert all(c.baseline.samples == 1000 and c.arm.samples == 250 for c in faithful)  # the authors' batches
    # P2 Fig. 7 also judges the learned filter against the plain one on its episodes, every metric
    learned = [c for c in p2[1].claims if (c.arm.planner, c.baseline.planner) == ("vqvae-filter", "vqvae")]
    assert {(c.scenario, c.metric) for c in learned} == {(c.scenario, m) for c in p2[1].claims for m in (COLLISIONS, SPEED, PLAN_TIME)}
    assert all(c.expect == NO_WORSE and c.kind == DRIVEOPT_ROW for c in learned)
    # P2's CVAE baseline is its reference [5], driveopt's and as its authors ran it, with P1's CVAE through P2's filter
    # beside it, with and without the filter in Fig. 9
    for figure in (p2[1], p2[-1]):
        for planner in ("cvae-multipliers", "cvae-multipliers-faithful", "cvae-filter", "cvae-filter-faithful"):
            compared = [c for c in figure.claims if planner in (c.arm.planner, c.baseline.planner)]
            assert compared and all(c.like_for_like for c in compared), (figure.figure, planner)
    assert {c.baseline.config for c in p2[-1].claims if c.baseline.planner.startswith("cvae-multipliers")} == {
        (("projection.max_iterations", 0),)}
    # P2 Fig. 9's no-filter under P2's ranking: the faithful pipelines at 0 filter iterations
    fig9 = p2[-1]
    assert any(c.kind == FAITHFUL_ROW and c.baseline.planner == "vqvae-filter-faithful"
               and c.baseline.config == (("projection.max_iterations", 0),) for c in fig9.claims)


def test_every_p2_arm_filters_with_the_pass_p2s_comparisons_share():
    """vqvae-filter runs a faster pass of its own by default; in P2's comparisons every driveopt arm runs the shared
    pass (registry.P2_PASS_PROJECTION: 100 plain iterations at the nodes, or the sweep's iterations), so the pipelines
    compared differ only in the prior or the filter; the faithful pipelines run P2's own (the same pass), unnamed.
    Fig. 8a's points at 100 are Fig. 7's arms; Fig. 8b sweeps samples at 100."""
    from driveopt.registry import get_optimiser

    def projection(arm):
        overrides = {key.rpartition(".")[2]: value for key, value in arm.config}
        return {field: overrides.get(field, getattr(get_optimiser(arm.planner).config.projection, field))
                for field in ("max_iterations", "anderson_window", "derivative_bounds")}

    fig7, fig8a, fig8b, fig9 = figures_of("p2", ["fig7", "fig8a", "fig8b", "fig9"])
    for figure in (fig7, fig8a, fig8b, fig9):
        for claim in figure.claims:
            if claim.arm.planner.startswith(("vqvae", "cvae-filter")) and claim.baseline.planner.startswith(("vqvae", "cvae")):
                passes = [projection(arm) for arm in (claim.arm, claim.baseline)]
                assert {p["anderson_window"] for p in passes} == {0} and {p["derivative_bounds"] for p in passes} == {"nodes"}
                if (claim.arm.planner, claim.baseline.planner) == ("vqvae-filter", "vqvae"):  # learned against plain filter
                    assert passes[0] == passes[1], claim.arm.label
    assert {projection(c.arm)["max_iterations"] for c in fig8a.claims if c.arm.planner == "vqvae-filter"} == {10, 25, 50, 100}

    def runs(arms):  # the bench folder and planner an arm's episodes are recorded under
        return {(arm.folder(None), arm.planner) for arm in arms}

    fig7_runs = runs(arm for claim in fig7.claims for arm in (claim.arm, claim.baseline))
    assert runs(arm for claim in fig8a.claims for arm in (claim.arm, claim.baseline)
                if projection(arm)["max_iterations"] == 100) <= fig7_runs
    assert all(arm.planner != "vqvae-filter" or projection(arm)["max_iterations"] == 100
               for claim in fig8b.claims for arm in (claim.arm, claim.baseline))
    assert not any(arm.config for claim in fig8b.claims for arm in (claim.arm, claim.baseline)
                   if arm.planner in ("vqvae", "vqvae-filter-faithful"))


def test_the_faithful_arms_replan_with_one_period_like_driveopts():
    """The bi-level optimiser and its baselines plan with the same period in every comparison: no arm overrides it,
    and every registered planner an arm names plans every policy period."""
    for figure in figures_of("p1") + figures_of("p2"):
        for claim in figure.claims:
            for arm in (claim.arm, claim.baseline):
                assert arm.replan_every is None
                spec = get_planner(arm.planner)
                if spec.is_optimiser:
                    assert spec.loop.replan_every == 1, arm.planner


def test_quick_variants_and_overrides():
    for figure in figures_of("p2", quick=True):
        assert figure.reduced and figure.episodes == 2 and figure.seeds == (42,) and (figure.duration or 0) <= 5
        for claim in figure.claims:
            for arm in (claim.arm, claim.baseline):
                assert arm.samples is None or arm.samples <= 100
    (fig9,) = figures_of("p1", ["fig9"], seeds=(1, 2), episodes=50)
    assert fig9.seeds == (1, 2) and not fig9.reduced
    (fig9,) = figures_of("p1", ["fig9"], episodes=10)
    assert fig9.reduced


def test_arm_options_and_folders():
    arm = Arm("vqvae", STRENGTHENED, 100, replan_every=5, config=(("projection.max_iterations", 0),))
    assert arm.options(4.0) == {"samples": 100, "replan_every": 5, "config": {"projection": {"max_iterations": 0}},
                                "duration": 4.0}
    assert arm.folder(4.0) == "n100-r5-maxiterations0-t4s" and arm.folder(None) == "n100-r5-maxiterations0"
    assert Arm("idm", REFERENCE).options(None) == {} and Arm("idm", REFERENCE).folder(None) == "nown"
    assert arm.quick().samples == 10 and Arm("x", STRENGTHENED, 50).quick().samples == 10
    (fig9,) = figures_of("p1", ["fig9"])
    runs = fig9.runs()
    assert set(runs) == {"n250", "n1000"}
    assert runs["n250"][:2] == (("four-lane-d3.0",), ("cvae", "bilevel-p1", "cvae-faithful", "bilevel-faithful"))


@pytest.mark.parametrize("paper, names", [("p3", None), ("p1", ["fig99"]), ("p2", ["fig7", "fig7"])])
def test_unknown_paper_or_figure(paper, names):
    with pytest.raises(ProtocolError):
        figures_of(paper, names)


# ---------------------------------------------------------------------------------------------- runs and report

CALLS = {"n": 0}


def fake_episode(job, options):
    """The proposed methods at their full filter budget never collide and drive 9 m/s; the others collide in even
    episodes and drive 7 m/s."""
    CALLS["n"] += 1
    iterations = options.get("config", {}).get("projection", {}).get("max_iterations", 100)
    proposed = job.planner in ("bilevel", "bilevel-p1", "cvae", "cvae-faithful", "bilevel-faithful", "vqvae-filter", "vqvae",
                               "vqvae-filter-faithful") and iterations == 100
    collided = (not proposed) and job.episode % 2 == 0
    return {"collided": collided, "off_road": False, "mean_speed": 9.0 if proposed else 7.0 + 0.01 * job.episode,
            "plan_ms": [20.0, 21.0], "sim_seconds": 0.01, "plan_seconds": 0.01, "steps": 2, "cpu_model": "fake CPU"}


@pytest.fixture
def cheap_bench(monkeypatch):
    """No bench summary plots, and no loading of the RL policies (torch) to check them: the fake episodes need neither."""
    from driveopt.drivers.rl import RLSpec
    from driveopt.experiments import bench

    monkeypatch.setattr(bench, "plot_summary", lambda rows, path: path)
    monkeypatch.setattr(RLSpec, "check", lambda self, scenario: None)


def test_report_has_every_claim_row_and_resume_reuses_records(tmp_path, cheap_bench):
    CALLS["n"] = 0
    figures, results = reproduce("p1", tmp_path, episodes=3, seeds=(42,), workers=1, episode_fn=fake_episode,
                                 progress=False)
    first = CALLS["n"]
    claims = sum(len(f.claims) for f in figures)
    assert first > 0 and len(results) == claims
    report = (tmp_path / "report.md").read_text()
    rows = [line for line in report.splitlines() if line.startswith("| ") and " pairs, seeds " in line]
    assert len(rows) == claims
    assert "Not run: an illustration" in report and "reduced: the full protocol has 100" in report
    kinds = {r.kind for r in results}
    assert kinds == {FAITHFUL_ROW, DRIVEOPT_ROW, MIXED_ROW}
    assert all(f"| {r.scenario} | {r.kind} | {r.metric}" in report for r in results)  # every row says which it is
    assert "- faithful rows: " in report and "- driveopt rows: " in report
    data = json.loads((tmp_path / "report.json").read_text())
    assert sum(len(f["claims"]) for f in data["figures"]) == claims
    assert {c["kind"] for f in data["figures"] for c in f["claims"]} == kinds
    assert {f["figure"] for f in data["figures"]} == {"fig7", "fig8", "fig9", "fig10", "fig11", "fig12"}
    for figure in ("fig7", "fig8", "fig9", "fig10", "fig12"):
        assert (tmp_path / f"{figure}.png").stat().st_size > 0
    assert not (tmp_path / "fig11.png").exists()
    by_name = {(r.figure, r.scenario, r.arm.label, r.baseline.label, r.metric): r for r in results}
    grid = by_name[("fig7", "four-lane-d3.0", "bilevel n250", "grid n250", COLLISIONS)]
    assert (grid.pairs, grid.only_baseline_collided, grid.verdict) == (3, 2, INCONCLUSIVE)
    # a second run finds every episode recorded; fewer episodes judge only those
    CALLS["n"] = 0
    _, again = reproduce("p1", tmp_path, episodes=2, seeds=(42,), workers=1, episode_fn=fake_episode, progress=False)
    assert CALLS["n"] == 0
    assert {r.pairs for r in again} == {2}
    # more episodes run only the missing ones
    _, more = reproduce("p1", tmp_path, figures=["fig9"], episodes=4, seeds=(42,), workers=1, episode_fn=fake_episode,
                        progress=False)
    assert CALLS["n"] == 4 * 2  # (cvae, bilevel-p1, cvae-faithful, bilevel-faithful) x (n250, n1000), one new episode each
    assert {r.pairs for r in more} == {4}


def test_the_episodes_to_run_are_counted_before_they_run(tmp_path, cheap_bench, capsys):
    def run(episodes):
        CALLS["n"] = 0
        reproduce("p1", tmp_path, figures=["fig9"], episodes=episodes, seeds=(42,), workers=1, episode_fn=fake_episode)
        return capsys.readouterr().out

    assert "8 episodes to run in 2 bench runs" in run(1) and CALLS["n"] == 8  # 4 planners x (n250, n1000)
    assert "0 episodes to run" in run(1) and CALLS["n"] == 0
    assert "8 episodes to run" in run(2) and CALLS["n"] == 8


def test_enough_episodes_reproduce_the_fake_direction(tmp_path, cheap_bench):
    figure = FigureProtocol("p1", "figX", "fake", (
        Claim("four-lane-d3.0", Arm("bilevel", STRENGTHENED, 25), Arm("grid", STRENGTHENED, 25), COLLISIONS, BETTER, "x"),
        Claim("four-lane-d3.0", Arm("bilevel", STRENGTHENED, 25), Arm("grid", STRENGTHENED, 25), SPEED, BETTER, "y"),
    ), seeds=(42, 123), episodes=8, full_episodes=16)
    results = run_figures("p1", (figure,), tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    assert [r.verdict for r in results] == [REPRODUCED, REPRODUCED]  # 8 only-baseline collisions: p = 2/256
    assert not results[0].reduced and results[0].seeds == (42, 123)


def test_a_contradicted_claim_is_explained_or_flagged(tmp_path, cheap_bench):
    speed_claim = Claim("four-lane-d3.0", Arm("grid", STRENGTHENED, 25), Arm("bilevel", STRENGTHENED, 25), SPEED, BETTER,
                        "grid faster")
    figure = FigureProtocol("p1", "figX", "fake", (
        speed_claim, replace(speed_claim, metric=COLLISIONS, paper="grid safer", explanation="grid is fake; see X.md")),
        seeds=(42,), episodes=16, full_episodes=16)
    results = run_figures("p1", (figure,), tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    assert [r.verdict for r in results] == [CONTRADICTED, CONTRADICTED]  # slower in 16 of 16, 8 collisions to none
    assert results[1].to_dict()["explanation"] == "grid is fake; see X.md"
    report = markdown("p1", (figure,), results)
    assert "**1 contradicted without an explanation yet**" in report
    assert "- four-lane-d3.0, speed, `grid n25` against `bilevel n25`: **not explained yet**" in report
    assert "- four-lane-d3.0, collisions, `grid n25` against `bilevel n25`: grid is fake; see X.md" in report
    # P2 Fig. 9's speed rows, driveopt's and the faithful ones, carry why their no-filter arm differs from P2's
    fig9 = figures_of("p2", ["fig9"])[0]
    speed_rows = [c for c in fig9.claims if c.metric == SPEED]
    assert {c.kind for c in speed_rows} == {DRIVEOPT_ROW, FAITHFUL_ROW} and all(c.explanation for c in speed_rows)


def test_chosen_scenarios_and_planners_run_alone_and_the_report_keeps_every_claim(tmp_path, cheap_bench):
    CALLS["n"] = 0
    _, results = reproduce("p1", tmp_path, figures=["fig7"], episodes=2, seeds=(42,), workers=1, episode_fn=fake_episode,
                           only=RunSlice(scenarios=("four-lane-d3.0",), planners=("bilevel", "grid")), progress=False)
    assert CALLS["n"] == 2 * 2  # bilevel and grid, two episodes each, nothing else
    ran = [r for r in results if r.pairs]
    assert [(r.scenario, r.arm.planner, r.baseline.planner) for r in ran] == [("four-lane-d3.0", "bilevel", "grid")] * 2
    assert {r.verdict for r in results if not r.pairs} == {NOT_RUN}
    assert len(results) == len(figures_of("p1", ["fig7"])[0].claims)
    report = (tmp_path / "report.md").read_text()
    assert report.count(f"**{NOT_RUN}**") == len(results) - 2
    assert "Records: 4 episodes, 4 without a code digest." in report  # the fake episodes name no code
    # the report alone: nothing runs, the same rows
    CALLS["n"] = 0
    (tmp_path / "report.md").unlink()
    reproduce("p1", tmp_path, figures=["fig7"], episodes=2, seeds=(42,), report_only=True, episode_fn=fake_episode,
              progress=False)
    assert CALLS["n"] == 0 and (tmp_path / "report.md").read_text() == report


def test_chosen_sample_counts_run_alone(tmp_path, cheap_bench):
    """P2 Fig. 8b's learned against plain filter at 250 samples only: two planners in one of its four bench folders."""
    CALLS["n"] = 0
    _, results = reproduce("p2", tmp_path, figures=["fig8b"], episodes=1, seeds=(42,), workers=1, episode_fn=fake_episode,
                           only=RunSlice(planners=("vqvae-filter", "vqvae"), samples=(250,)), progress=False)
    shared = "max_iterations=100 anderson_window=0 derivative_bounds=nodes"  # the pass P2's comparisons share
    assert CALLS["n"] == 2 and sorted(p.name for p in (tmp_path / "runs").iterdir()) == [
        "n250", "n250-maxiterations100-andersonwindow0-derivativeboundsnodes"]
    judged = [(r.arm.label, r.baseline.label, r.metric) for r in results if r.pairs]
    assert judged == [(f"vqvae-filter n250 {shared}", "vqvae n250", metric) for metric in (COLLISIONS, SPEED, PLAN_TIME)]


def test_the_learned_filter_question_pools_every_pair_once(tmp_path, cheap_bench):
    """P2's question whether the learned filter changes anything, on fake episodes where it is faster and slower to
    plan: P2 Fig. 7's four settings and Fig. 8b's four sample counts, whose 1000-sample point is Fig. 7's density-3
    arm pair (counted once)."""
    def episode(job, options):
        record = fake_episode(job, options)
        if job.planner == "vqvae-filter":
            record.update(mean_speed=record["mean_speed"] + 0.5, plan_ms=[30.0, 31.0])
        return record

    figures, _ = reproduce("p2", tmp_path, figures=["fig7", "fig8b"], episodes=2, seeds=(42,), workers=1,
                           episode_fn=episode, only=RunSlice(planners=("vqvae-filter", "vqvae")), progress=False)
    answers = answer_questions("p2", figures, tmp_path)
    assert [r.metric for r in answers] == [COLLISIONS, SPEED, PLAN_TIME]
    assert {r.pairs for r in answers} == {(4 + 3) * 2}
    assert {r.verdict for r in answers} == {TOO_FEW_PAIRS}  # the question needs 150 pairs
    collisions, speed, plan = answers
    assert (speed.arm_faster, speed.speed_sign_n) == (14, 14) and (plan.arm_quicker, plan.plan_sign_n) == (0, 14)
    assert [answer(r, 14) for r in answers] == [NO_CHANGE, CHANGES_BETTER, CHANGES_WORSE]
    assert answer(replace(speed, arm_faster=8, speed_sign_p=ps.binomial_two_sided(8, 14)), 14) == NO_CHANGE  # p = 0.79
    report = (tmp_path / "report.md").read_text()
    assert "### The learned filter against the plain one" in report and report.count(f"**{TOO_FEW_PAIRS}**") == 3
    assert [q["pairs"] for q in json.loads((tmp_path / "report.json").read_text())["questions"]] == [14] * 3
    assert answer_questions("p1", figures_of("p1"), tmp_path) == []
    # episodes beyond a figure's count (the cheapest point run longer, as the campaign does) count for the question
    reproduce("p2", tmp_path, figures=["fig8b"], episodes=3, seeds=(42,), workers=1, episode_fn=episode,
              only=RunSlice(planners=("vqvae-filter", "vqvae"), samples=(250,)), progress=False)
    assert {r.pairs for r in answer_questions("p2", figures, tmp_path)} == {(4 + 3) * 2 + 1}


def test_figures_share_an_arm_s_episodes_and_an_old_layout_is_merged(tmp_path, cheap_bench):
    """P1 Fig. 8 compares Fig. 7's `bilevel` and `cvae-faithful` (250 samples, the same roads) with the RL agents: with
    Fig. 7 recorded only the agents run. A folder laid out by figure is merged into the shared one first."""
    CALLS["n"] = 0
    reproduce("p1", tmp_path, figures=["fig7"], episodes=1, seeds=(42,), workers=1, episode_fn=fake_episode, progress=False)
    CALLS["n"] = 0
    _, results = reproduce("p1", tmp_path, figures=["fig8"], episodes=1, seeds=(42,), workers=1, episode_fn=fake_episode,
                           progress=False)
    assert CALLS["n"] == 2 * 2  # dqn and ppo on two roads; bilevel's and cvae-faithful's episodes were Fig. 7's
    assert all(r.pairs == 1 for r in results)
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["n1000", "n250", "nown"]
    # the layout by figure: Fig. 8's agents and one episode recorded twice, under runs/fig7 and runs/fig8
    shared = tmp_path / "runs" / "nown"
    (tmp_path / "runs" / "fig8").mkdir()
    shared.rename(tmp_path / "runs" / "fig8" / "nown")
    (tmp_path / "runs" / "fig7").mkdir()
    (tmp_path / "runs" / "n250").rename(tmp_path / "runs" / "fig7" / "n250")
    (tmp_path / "runs" / "fig8" / "n250").mkdir()
    lines = (tmp_path / "runs" / "fig7" / "n250" / "episodes.jsonl").read_text().splitlines()
    (tmp_path / "runs" / "fig8" / "n250" / "episodes.jsonl").write_text(lines[0] + "\n")
    (tmp_path / "runs" / "fig8" / "n250" / "spec.json").write_text((tmp_path / "runs" / "fig7" / "n250" / "spec.json").read_text())
    CALLS["n"] = 0
    _, again = reproduce("p1", tmp_path, figures=["fig7", "fig8"], episodes=1, seeds=(42,), workers=1,
                         episode_fn=fake_episode, progress=False)
    assert CALLS["n"] == 0 and all(r.pairs == 1 for r in again)
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["n1000", "n250", "nown"]
    assert len((tmp_path / "runs" / "n250" / "episodes.jsonl").read_text().splitlines()) == len(lines)  # none twice


@pytest.mark.parametrize("kwargs, message", [
    ({"only": RunSlice(scenarios=("two-way",))}, "no scenarios two-way"),
    ({"only": RunSlice(planners=("bilevel", "ppo"))}, "no planners ppo"),
    ({"only": RunSlice(samples=(300,))}, "no samples 300; theirs: 250, 1000"),
    ({"report_only": True}, "holds no runs"),
    ({"report_only": True, "only": RunSlice(planners=("bilevel",))}, "runs nothing"),
])
def test_bad_choices_of_what_to_run_fail_before_anything_is_written(tmp_path, kwargs, message):
    out = tmp_path / "out"
    with pytest.raises(DriveoptError, match=message):
        reproduce("p1", out, figures=["fig7"], episode_fn=fake_episode, progress=False, **kwargs)
    assert not out.exists()


@pytest.mark.parametrize("kwargs", [
    {"figures": ["fig99"]},
    {"seeds": (-1,)},
    {"backend": "slurm"},
    {"workers": 0},
])
def test_bad_input_fails_before_anything_is_written(tmp_path, kwargs):
    out = tmp_path / "out"
    with pytest.raises(DriveoptError):
        reproduce("p1", out, episode_fn=fake_episode, progress=False, **kwargs)
    assert not out.exists()


def test_output_folder_that_is_a_file(tmp_path):
    out = tmp_path / "file"
    out.write_text("x")
    with pytest.raises(DriveoptError, match="existing file"):
        reproduce("p1", out, figures=["fig9"], episode_fn=fake_episode, progress=False)


def test_cli_parses_and_reports_bad_input_as_a_driveopt_error(tmp_path):
    from driveopt.cli.reproduce import register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["reproduce", "p2", "--figures", "fig8c", "--quick", "--out", str(tmp_path / "o")])
    assert args.quick and args.paper == "p2"
    with pytest.raises(DriveoptError, match="fig8c"):
        args.func(args)
    assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit):
        parser.parse_args(["reproduce", "p3", "--out", "x"])


def test_cli_module_imports_no_jax():
    import subprocess
    import sys

    code = "import sys, driveopt.cli.reproduce; print('jax' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "False"


# ---------------------------------------------------------------------------------------------- real episodes


def test_small_real_run(tmp_path):
    """idm against one optimiser through highway-env: 1 episode of 1.5 s, 20 samples (grid at 20 samples is what
    tests/drivers/test_latency.py drives too: one compilation for both)."""
    figure = FigureProtocol("p1", "tiny", "idm against grid", (
        Claim("two-lane-d1.0", Arm("grid", STRENGTHENED, 20), Arm("idm", REFERENCE), SPEED, NO_WORSE, "competitive"),
    ), seeds=(42,), episodes=1, duration=1.5, reduced=True)
    start = time.perf_counter()
    (result,) = run_figures("p1", (figure,), tmp_path, workers=1, progress=False)
    assert time.perf_counter() - start < 120
    assert result.pairs == 1 and result.verdict == INCONCLUSIVE and result.reduced
    assert result.arm.plan_ms > 0 and math.isnan(result.baseline.plan_ms)  # idm does not plan
    from driveopt.solve_export import source_digest

    code = source_digest()[:16]
    assert f"Records: 2 episodes, 2 on driveopt source `{code}`." in (tmp_path / "report.md").read_text()
    assert json.loads((tmp_path / "report.json").read_text())["figures"][0]["code"] == {code: 2}
    for folder in ("n20-t1.5s", "nown-t1.5s"):  # grid's and idm's
        (record,) = (tmp_path / "runs" / folder / "episodes.jsonl").read_text().splitlines()
        assert json.loads(record)["code"] == code and json.loads(record)["cpu_model"] == cpu_model()


@pytest.mark.slow
@pytest.mark.parametrize("paper", ["p1", "p2"])
def test_quick_reproduction_of_each_paper(tmp_path, paper):
    figures, results = reproduce(paper, tmp_path, quick=True, workers=1, progress=False)
    assert len(results) == sum(len(f.claims) for f in figures) > 0
    assert all(r.pairs == 2 for r in results)
    assert (tmp_path / "report.md").exists()


# ---------------------------------------------------------------------------------------------- claims, plan, --claim


def test_every_claim_carries_the_paper_s_effect_and_every_figure_a_primary():
    for paper in ("p1", "p2"):
        for figure in figures_of(paper) + figures_of(paper, quick=True):
            ids = figure.claim_ids()
            assert len(set(ids)) == len(ids) and (figure.primary in ids) == bool(figure.claims), figure.figure
            for claim in figure.claims:
                assert claim.effect.source
    fig7 = figures_of("p1", ["fig7"])[0]
    by_id = dict(zip(fig7.claim_ids(), fig7.claims))
    headline = by_id["fig7:four-lane-d3.0:cvae-faithful-vs-random-faithful:collisions"]
    assert headline.effect.ratio == pytest.approx((0.1, 0.25)) and fig7.primary == "fig7:four-lane-d3.0:cvae-faithful-vs-random-faithful:collisions"
    assert by_id["fig7:two-lane-d1.0:bilevel-vs-grid:collisions"].effect.baseline_level == (0.0, 0.0)
    assert by_id["fig7:two-lane-d1.0:bilevel-vs-random:collisions"].effect.arm_level == (0.0, 0.0)
    assert by_id["fig7:four-lane-d1.5:bilevel-vs-grid:collisions"].effect.kind == effects.DIRECTION
    (fig8a,) = figures_of("p2", ["fig8a"])
    assert {c.effect.arm_level for c in fig8a.claims if c.metric == COLLISIONS and not c.question} == {(0.03, 0.03)}
    (fig9,) = figures_of("p2", ["fig9"])
    eight = [c for c in fig9.claims if c.effect.kind == effects.RATIO]
    assert eight and all(c.baseline.planner.startswith("cvae-multipliers") and c.effect.ratio == (0.125, 0.125)
                         for c in eight)
    # honest labels: vanilla plans with one sample, the RL agents are under-trained references
    vanilla = next(c.baseline for c in fig7.claims if c.baseline.planner == "vanilla")
    assert vanilla.label == "vanilla n1 (asked n250)"
    dqn = next(c.baseline for c in figures_of("p1", ["fig8"])[0].claims if c.baseline.planner == "dqn")
    assert dqn.label == "dqn, under-trained reference (10,000 of 5 M steps)"


def _headline_figure(episodes):
    arm, base = Arm("cvae-faithful", FAITHFUL, 25), Arm("random-faithful", FAITHFUL, 25)
    claims = (Claim("four-lane-d3.0", arm, base, COLLISIONS, BETTER, "4x", effect=PaperEffect.times_fewer(4, 4, "t")),
              Claim("four-lane-d3.0", arm, base, SPEED, NO_WORSE, "similar"),
              Claim("two-lane-d1.0", arm, base, COLLISIONS, BETTER, "fewer"))
    return FigureProtocol("p1", "figX", "fake", claims, seeds=(42,), episodes=episodes, full_episodes=40,
                          primary="figX:four-lane-d3.0:cvae-faithful-vs-random-faithful:collisions")


def test_plan_costs_the_undecided_claims_from_the_records_alone(tmp_path, cheap_bench, monkeypatch, capsys):
    """Constructed records: the headline's baseline collides in every other episode at 100 s per episode, the arm at
    10 s; on the two-lane road the episodes cost 1 s. --plan reads them, runs nothing and orders by cost."""
    from driveopt.experiments import reproduce as rp

    def episode(job, options):
        record = fake_episode(job, options)
        record["sim_seconds"] = (1.0 if job.scenario == "two-lane-d1.0" else
                                 100.0 if job.planner == "random-faithful" else 10.0)
        return record

    figure = _headline_figure(4)
    monkeypatch.setattr(rp, "figures_of", lambda paper, names=None, **kw: (figure,))
    run_figures("p1", (figure,), tmp_path, workers=1, episode_fn=episode, progress=False)
    CALLS["n"] = 0
    rows, claims = rp.plan("p1", tmp_path)
    assert CALLS["n"] == 0 and claims == 3
    assert [row.claim_id for row in rows] == ["figX:two-lane-d1.0:cvae-faithful-vs-random-faithful:collisions",
                                              "figX:four-lane-d3.0:cvae-faithful-vs-random-faithful:collisions",
                                              "figX:four-lane-d3.0:cvae-faithful-vs-random-faithful:speed"]
    cheap, headline, speed = rows
    assert cheap.seconds_per_pair == pytest.approx(2 * (1.0 + 0.01)) and headline.seconds_per_pair == pytest.approx(110.02)
    # the headline: baseline rate 1/2, paper's ratio 1/4 -> McNemar pairs at the final level, rounded up to a look
    final = obrien_fleming_levels(figure.look_pairs)[-1]
    assert headline.paper_pairs == pytest.approx(ps.mcnemar_pairs_needed(0.5, 0.25, final))
    target = next(n for n in figure.look_pairs if n >= headline.paper_pairs)
    assert headline.cost == pytest.approx(110.02 * (target - 4))
    assert math.isnan(cheap.paper_pairs) and cheap.measured_pairs > 0  # a direction states no size
    # speed no worse, 9 against about 7 m/s: the 20 compared pairs a t interval needs, at half the pairs collision-free
    assert speed.measured_pairs == speed.paper_pairs == 40 and speed.cost == pytest.approx(110.02 * 36)
    assert [row.cost for row in rows] == sorted(row.cost for row in rows)
    text = rp.plan_text("p1", rows, claims)
    assert text.splitlines()[2].startswith("figX:two-lane-d1.0:cvae-faithful-vs-random-faithful:collisions | inconclusive")


def test_the_cli_plan_and_claim_options(tmp_path, cheap_bench, monkeypatch, capsys):
    """--claim runs one claim's two arms, only the pairs missing; --plan prints ids and runs nothing; a wrong claim
    is one line."""
    from driveopt.cli.reproduce import register
    from driveopt.experiments import reproduce as rp

    figure = _headline_figure(3)
    monkeypatch.setattr(rp, "figures_of", lambda paper, names=None, **kw: (figure,))
    ran = []

    def episode(job, options):
        ran.append((job.scenario, job.planner, job.episode))
        return fake_episode(job, options)

    real = rp.run_figures
    monkeypatch.setattr(rp, "run_figures", lambda *a, **kw: real(*a, **{**kw, "episode_fn": episode, "progress": False}))
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command"))
    out = str(tmp_path / "o")
    headline = "figX:four-lane-d3.0:cvae-faithful-vs-random-faithful:collisions"
    # one episode of the baseline recorded already: only the rest run
    rp.run_bench(rp.BenchSpec(("four-lane-d3.0",), ("random-faithful",), (42,), 1, {"samples": 25}),
                 tmp_path / "o" / "runs" / "n25", workers=1, episode_fn=episode, progress=False)
    ran.clear()
    args = parser.parse_args(["reproduce", "p1", "--claim", headline, "--workers", "1", "--out", out])
    assert args.func(args) == 0
    assert sorted(ran) == sorted([("four-lane-d3.0", "cvae-faithful", e) for e in range(3)]
                                 + [("four-lane-d3.0", "random-faithful", e) for e in (1, 2)])
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    claims = report["figures"][0]["claims"]
    assert [c["pairs"] for c in claims] == [3, 3, 0]  # every claim reported, the two-lane one not run
    assert claims[0]["records"]["arm"] == {"folder": "runs/n25", "planner": "cvae-faithful", "episodes": 3, "sources": [
        {"code": None, "jax": None, "numpy": None, "cpu_model": "fake CPU", "device": None, "episodes": 3}]}
    ran.clear()
    assert args.func(args) == 0 and ran == []  # nothing missing
    capsys.readouterr()
    args = parser.parse_args(["reproduce", "p1", "--plan", "--out", out])
    assert args.func(args) == 0 and ran == []
    printed = capsys.readouterr().out
    assert "figX:two-lane-d1.0:cvae-faithful-vs-random-faithful:collisions | not run" in printed
    args = parser.parse_args(["reproduce", "p1", "--claim", "figX:nowhere", "--out", out])
    with pytest.raises(DriveoptError, match="no claim 'figX:nowhere'.*--plan"):
        args.func(args)
    with pytest.raises(DriveoptError, match="holds no runs"):
        args = parser.parse_args(["reproduce", "p1", "--plan", "--out", str(tmp_path / "empty")])
        args.func(args)


# ---------------------------------------------------------------------------------------------- prose from report.json


def test_the_reproduction_prose_quotes_the_committed_reports():
    """docs/reproduction/README.md's generated numbers and README.md's reproduction sentence are what the committed
    report.json files say (rewrite them with `python -m driveopt.experiments.reproduce_prose`)."""
    from pathlib import Path

    from driveopt.experiments import reproduce_prose as prose

    root = Path(__file__).resolve().parents[2]
    reports = prose.load(root / "benchmarks/results/reproduction")
    doc = (root / "docs/reproduction/README.md").read_text()
    assert set(m["name"] for m in prose.MARK.finditer(doc)) == set(prose.BLOCKS)
    assert prose.render(doc, reports) == doc
    faithful = prose._collided(reports["p2"], prose.FAITHFUL_PIPELINES)
    n, pairs = faithful[prose.FAITHFUL_PIPELINES[0]]
    assert f"`{prose.FAITHFUL_PIPELINES[0]}` {n} of {pairs}" in doc


def test_the_readme_s_reproduction_sentence_quotes_the_committed_reports():
    from pathlib import Path

    from driveopt.experiments import reproduce_prose as prose

    root = Path(__file__).resolve().parents[2]
    assert prose.readme_sentence(prose.load(root / "benchmarks/results/reproduction")) in (root / "README.md").read_text()


def test_generated_blocks_are_rewritten_and_unknown_ones_refused(tmp_path):
    from driveopt.experiments import reproduce_prose as prose

    report = {"tests": 2, "verdicts": {"inconclusive": 2}, "figures": []}
    text = "a (<!-- generated: verdict-tallies -->old<!-- end generated -->) b"
    assert prose.render(text, {"p1": report, "p2": report}) == (
        "a (<!-- generated: verdict-tallies -->P1: 2 distinct tests, 2 inconclusive; P2: 2 distinct tests, 2 "
        "inconclusive<!-- end generated -->) b")
    with pytest.raises(ValueError, match="unknown generated block 'nope'"):
        prose.render("<!-- generated: nope -->x<!-- end generated -->", {"p1": report, "p2": report})


def test_decide_runs_the_cheapest_claims_to_their_next_look_while_the_hours_last(tmp_path, cheap_bench, monkeypatch):
    """--decide: the cheapest undecided claim of --plan runs up to its next look, then the next cheapest; the slice
    keeps claims whose arms it holds; the deadline is checked before each claim."""
    from driveopt.experiments import reproduce as rp

    figure = _headline_figure(40)  # the full protocol; 4 episodes recorded first
    monkeypatch.setattr(rp, "figures_of", lambda paper, names=None, *, episodes=None, **kw:
                        (figure.with_runs(None, episodes) if episodes else figure,))
    ran = []

    def episode(job, options):
        ran.append((job.scenario, job.planner, job.episode))
        record = fake_episode(job, options)
        record["sim_seconds"] = 1.0 if job.scenario == "two-lane-d1.0" else 50.0
        return record

    run_figures("p1", (figure.with_runs(None, 4),), tmp_path, workers=1, episode_fn=episode, progress=False)
    rows = rp.plan("p1", tmp_path)[0]
    cheapest = rows[0]
    assert cheapest.claim_id.startswith("figX:two-lane-d1.0") and cheapest.target_pairs > 4
    ran.clear()
    ticks = iter([0.0, 0.0, 1e9])  # the deadline passes after the first claim
    ids = rp.decide("p1", tmp_path, hours=1.0, workers=1, episode_fn=episode, progress=False, clock=lambda: next(ticks))
    assert ids == [cheapest.claim_id]
    assert sorted(ran) == sorted(("two-lane-d1.0", planner, e) for planner in ("cvae-faithful", "random-faithful")
                                 for e in range(4, cheapest.target_pairs))
    assert json.loads((tmp_path / "report.json").read_text())["figures"][0]["claims"][2]["pairs"] == cheapest.target_pairs
    # only the four-lane road's claims: the two-lane one is left alone, the headline runs to its next look
    headline = next(row for row in rp.plan("p1", tmp_path)[0] if row.claim_id.startswith("figX:four-lane-d3.0"))
    ran.clear()
    ticks = iter([0.0, 0.0, 1e9])
    ids = rp.decide("p1", tmp_path, only=rp.RunSlice(scenarios=("four-lane-d3.0",)), hours=1.0, workers=1,
                    episode_fn=episode, progress=False, clock=lambda: next(ticks))
    assert ids == [headline.claim_id] and {scenario for scenario, _, _ in ran} == {"four-lane-d3.0"}
    assert max(e for _, _, e in ran) == headline.target_pairs - 1


def test_decide_starts_a_claim_no_arm_has_run_at_its_first_look(tmp_path, cheap_bench, monkeypatch):
    """A claim without a pair has no rates or cost to plan by: --plan targets the first look at an unknown cost, and
    --decide runs it there once the costed claims are done (here: there are none)."""
    from driveopt.experiments import reproduce as rp

    figure = _headline_figure(40)
    monkeypatch.setattr(rp, "figures_of", lambda paper, names=None, *, episodes=None, **kw:
                        (figure.with_runs(None, episodes) if episodes else figure,))
    (tmp_path / "runs").mkdir()
    rows = rp.plan("p1", tmp_path)[0]
    assert rows and all(row.pairs == 0 and row.target_pairs == figure.look_pairs[0] and math.isnan(row.cost)
                        for row in rows)
    ran = []

    def episode(job, options):
        ran.append((job.scenario, job.planner, job.episode))
        return fake_episode(job, options)

    ticks = iter([0.0, 0.0, 1e9])
    ids = rp.decide("p1", tmp_path, hours=1.0, workers=1, episode_fn=episode, progress=False, clock=lambda: next(ticks))
    assert ids == [rows[0].claim_id] and ran
    assert max(e for _, _, e in ran) == math.ceil(figure.look_pairs[0] / len(figure.seeds)) - 1


@pytest.mark.parametrize("extra", [["--claim", "figX:a"], ["--episodes", "5"], ["--plan"], ["--quick"]])
def test_decide_chooses_claims_and_episodes_itself(tmp_path, extra):
    from driveopt.cli.reproduce import register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["reproduce", "p1", "--decide", "2", *extra, "--out", str(tmp_path / "o")])
    with pytest.raises(DriveoptError, match="--decide|--plan runs nothing"):
        args.func(args)
    with pytest.raises(SystemExit):
        parser.parse_args(["reproduce", "p1", "--decide", "0", "--out", str(tmp_path / "o")])
