"""``cvae-filter``: P2's baseline, the CVAE through the same one-pass projection as ``vqvae`` (issue 14)."""

from __future__ import annotations

import dataclasses
import warnings

import jax
import numpy as np
import pytest

from driveopt.cli import main
from driveopt.planner import PlanStatus, plan
from driveopt.priors.cvae import CVAEPrior, shipped_weights
from driveopt.problem import build_problem
from driveopt.registry import get_optimiser, list_planners
from driveopt.row_sharing import DistinctRows, EveryRow
from driveopt.scene import load_scene


@pytest.fixture(scope="module")
def shipped_prior():
    """The cvae-filter prior for a four-lane road: the shipped CVAE, with no Gaussian fallback notice."""
    assert shipped_weights(4) is not None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return get_optimiser("cvae-filter").prior(4)


def test_cvae_filter_is_listed(capsys):
    assert "cvae-filter" in list_planners()
    assert main(["planners"]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert "P1's CVAE through P2's pipeline" in next(row for row in rows if row.split()[:1] == ["cvae-filter"])
    assert "P2's CVAE baseline" in next(row for row in rows if row.split()[:1] == ["cvae-multipliers"])


def test_cvae_filter_differs_from_vqvae_only_in_the_prior(shipped_prior):
    cvae_filter, vqvae = get_optimiser("cvae-filter"), get_optimiser("vqvae")
    assert cvae_filter.config == vqvae.config
    sampler, projection = cvae_filter.config.sampler, cvae_filter.config.projection
    assert (sampler.num_samples, sampler.num_iterations, sampler.num_constraint_elites) == (1000, 1, 150)
    assert projection.barrier  # its iterations: tests/core/test_registry.py
    same = dataclasses.replace(cvae_filter, name=vqvae.name, description=vqvae.description, make_prior=vqvae.make_prior,
                               method=vqvae.method)
    assert same == vqvae  # warm start, fallback, prediction, replanning: all vqvae's
    assert cvae_filter.make_prior is not vqvae.make_prior
    # and how repeated rows are projected: the CVAE's samples (continuous latent noise) never repeat, the VQ-VAE's do;
    # the projection's maths is the same either way (tests/core/test_row_sharing.py)
    assert cvae_filter.method.row_sharing == EveryRow() and isinstance(vqvae.method.row_sharing, DistinctRows)
    assert dataclasses.replace(vqvae.method, row_sharing=EveryRow()) == cvae_filter.method
    assert isinstance(shipped_prior, CVAEPrior)  # the shipped four-lane CVAE


def test_cvae_filter_plans_a_feasible_trajectory_on_the_static_blockage(shipped_prior):
    spec = get_optimiser("cvae-filter").with_samples(120)
    problem = build_problem(load_scene("static-blockage"), spec.config.basis)
    result = plan(problem, spec.config, key=jax.random.PRNGKey(0), prior=shipped_prior)
    assert result.status == PlanStatus.SUCCESS, result.message
    assert result.residuals["total"] <= spec.config.sampler.residual_tolerance
    assert result.history.best_score.shape == (1,)  # one pass, no adaptation
    assert np.all(np.isfinite(result.trajectory.x)) and np.all(np.isfinite(result.trajectory.y))
