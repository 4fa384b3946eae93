"""The cvae-multipliers planner (P2's CVAE baseline, its reference [5]): registered with a faithful version, loads the
shipped four-lane weights by default, warns and plans without weights, and with weights plans finite trajectories whose
batch starts from the model's multipliers."""

from __future__ import annotations

import warnings

import jax
import numpy as np
import pytest
from tiny_models import tiny_cvae_multipliers

from driveopt.planner import PlanStatus, plan
from driveopt.priors.cvae_multipliers import MultiplierCVAEPrior
from driveopt.problem import build_problem
from driveopt.registry import get_optimiser, list_planners
from driveopt.safety.cvae_multipliers import CVAEMultipliers
from driveopt.sampler import GaussianPrior
from driveopt.scene import load_scene

SPEC = get_optimiser("cvae-multipliers").with_samples(24).with_overrides(projection={"max_iterations": 6})


def test_registered_with_the_authors_settings_and_a_faithful_version():
    assert {"cvae-multipliers", "cvae-multipliers-faithful"} <= set(list_planners())
    config = get_optimiser("cvae-multipliers").config
    assert (config.sampler.num_samples, config.sampler.num_iterations, config.projection.max_iterations) == (1000, 1, 75)
    assert get_optimiser("cvae-multipliers-faithful").loop.executes_infeasible


def test_without_weights_it_warns_and_plans_from_the_gaussian_with_zero_multipliers():
    with pytest.warns(UserWarning, match="no cvae-multipliers weights shipped for 2-lane roads .* zero multipliers"):
        prior = SPEC.prior(2)
    assert isinstance(prior, GaussianPrior) and SPEC.safety_filter(2) is None


def test_shipped_four_lane_weights_load_by_default_and_their_multipliers_change_the_plan():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no fallback notice: weights ship for four-lane roads
        prior, head = SPEC.prior(4), SPEC.safety_filter(4)
    assert isinstance(prior, MultiplierCVAEPrior) and isinstance(head, CVAEMultipliers)
    problem = build_problem(load_scene("slow-leader-four-lane"), SPEC.config.basis)
    config = SPEC.config.with_samples(200)
    result = plan(problem, config, key=jax.random.PRNGKey(0), prior=prior, safety_filter=head, method=SPEC.method)
    assert result.status == PlanStatus.SUCCESS and result.residuals["total"] <= config.sampler.residual_tolerance
    zero = plan(problem, config, key=jax.random.PRNGKey(0), prior=prior, method=SPEC.method)
    assert not np.allclose(result.trajectory.x, zero.trajectory.x)  # the predicted multipliers change the projection


def test_with_weights_it_plans_a_finite_trajectory_or_offers_the_fallback(tmp_path):
    spec = SPEC.with_weights(str(tiny_cvae_multipliers(tmp_path / "m.ckpt")))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        prior, head = spec.prior(4), spec.safety_filter(4)
    assert isinstance(prior, MultiplierCVAEPrior) and isinstance(head, CVAEMultipliers)
    problem = build_problem(load_scene("dense-snapshot"), spec.config.basis)
    result = plan(problem, spec.config, key=jax.random.PRNGKey(0), prior=prior, safety_filter=head, method=spec.method)
    assert result.status in (PlanStatus.SUCCESS, PlanStatus.INFEASIBLE)
    chosen = result.safe_trajectory
    assert all(np.all(np.isfinite(np.asarray(getattr(chosen, f)))) for f in ("x", "y", "speed"))
    if result.status == PlanStatus.SUCCESS:
        assert result.residuals["total"] <= spec.config.sampler.residual_tolerance
    with pytest.raises(Exception, match="trained for 4-lane roads"):
        spec.prior(2)
