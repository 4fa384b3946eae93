"""[5]'s CVAE (learned.cvae_multipliers): its multipliers reach the projection, stay paired with their rows, its loss
has finite gradients, its checkpoints round-trip, and bad input is refused with a clear error."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny_models import MULTIPLIERS_CFG, random_params, tiny_cvae_multipliers

from driveopt.checks import ConfigError
from driveopt.filtering import FilterError
from driveopt.learned import cvae_multipliers as cm
from driveopt.learned.checkpoint import CheckpointError
from driveopt.planner import project_batch, setpoint_batch
from driveopt.problem import build_problem
from driveopt.projection import project
from driveopt.qp import make_model
from driveopt.registry import get_optimiser
from driveopt.safety.cvae_multipliers import CVAEMultipliers, load_multipliers
from driveopt.scene import load_scene

CONFIG = get_optimiser("cvae-multipliers").config.replace(projection={"max_iterations": 4})
MODEL = make_model(CONFIG.basis, CONFIG.qp)


@jax.jit
def _plain(problem, coeffs, b_x, b_y, init_multipliers=None):
    return project(MODEL, problem, coeffs, b_x, b_y, CONFIG.projection, init_multipliers=init_multipliers).coeffs


@jax.jit
def _filtered(problem, coeffs, b_x, b_y, head):
    return project_batch(MODEL, problem, CONFIG, coeffs, b_x, b_y, head).coeffs


def _identity_normaliser(cfg=MULTIPLIERS_CFG) -> cm.Normaliser:
    unit = lambda n: (jnp.zeros(n, jnp.float32), jnp.ones(n, jnp.float32))  # noqa: E731
    return cm.Normaliser(*unit(cm.cvae.FEATURE_DIM), *unit(cfg.cvae.trajectory_features), *unit(cfg.num_coeffs))


def _batch(num: int = 6):
    problem = build_problem(load_scene("dense-snapshot"), CONFIG.basis)
    key = jax.random.PRNGKey(1)
    p = jnp.concatenate([14 + 3 * jax.random.normal(key, (num, 4)), 6 + 3 * jax.random.normal(jax.random.fold_in(key, 1), (num, 4))], 1)
    coeffs, b_x, b_y = setpoint_batch(MODEL, problem, CONFIG, p)
    return problem, coeffs, b_x, b_y


def test_the_untrained_head_gives_zero_multipliers_and_the_plain_projection_exactly():
    problem, coeffs, b_x, b_y = _batch()
    params = cm.init_params(MULTIPLIERS_CFG, jax.random.PRNGKey(0))
    head = CVAEMultipliers(params, _identity_normaliser(), MULTIPLIERS_CFG)
    assert np.all(np.asarray(head.initialise(problem, coeffs).multipliers) == 0.0)
    np.testing.assert_array_equal(np.asarray(_filtered(problem, coeffs, b_x, b_y, head)),
                                  np.asarray(_plain(problem, coeffs, b_x, b_y, jnp.zeros_like(coeffs))))
    np.testing.assert_array_equal(np.asarray(_plain(problem, coeffs, b_x, b_y, jnp.zeros_like(coeffs))),
                                  np.asarray(jax.jit(lambda *a: project(MODEL, *a, CONFIG.projection).coeffs)(problem, coeffs, b_x, b_y)))


def test_predicted_multipliers_reach_the_projection_and_stay_paired_with_their_rows():
    problem, coeffs, b_x, b_y = _batch()
    params = random_params(cm.init_params, MULTIPLIERS_CFG, seed=3)
    head = CVAEMultipliers(params, _identity_normaliser(), MULTIPLIERS_CFG)
    lam = np.asarray(head.initialise(problem, coeffs).multipliers)
    assert np.all(np.isfinite(lam)) and np.abs(lam).max() > 0
    filtered = np.asarray(_filtered(problem, coeffs, b_x, b_y, head))
    assert np.abs(filtered - np.asarray(_plain(problem, coeffs, b_x, b_y, jnp.zeros_like(coeffs)))).max() > 1e-4
    # the same as passing those multipliers to the projection directly
    np.testing.assert_allclose(filtered, np.asarray(_plain(problem, coeffs, b_x, b_y, jnp.asarray(lam))), rtol=1e-5, atol=1e-5)
    # a row's multipliers depend on its own trajectory only: reordering the batch reorders them
    order = np.array([3, 0, 5, 1, 4, 2])
    np.testing.assert_allclose(np.asarray(head.initialise(problem, coeffs[order]).multipliers), lam[order], rtol=1e-5, atol=1e-5)


def _loss_batch(rows: int = 3) -> cm.Batch:
    problem, coeffs, _, _ = _batch(rows)
    trajectory = jnp.stack([MODEL.W @ coeffs[:, :11].T, MODEL.W @ coeffs[:, 11:].T], -1).transpose(1, 0, 2)
    stacked = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (rows, *jnp.shape(a))), problem)
    return cm.Batch(stacked, trajectory)


def test_gradients_of_the_loss_are_finite_and_reach_every_part():
    batch = _loss_batch()
    params = random_params(cm.init_params, MULTIPLIERS_CFG, seed=1)
    grad = jax.jit(jax.grad(lambda p, b: cm.loss(p, MULTIPLIERS_CFG, _identity_normaliser(), b, jax.random.PRNGKey(0),
                                                 CONFIG, 0.1, 1.0, 5e-4), has_aux=True))
    grads, terms = grad(params, batch)
    assert all(np.isfinite(float(v)) for v in terms.values())
    for part in ("encoder", "decoder", cm.MULTIPLIER_HEAD):
        leaves = [np.asarray(g) for g in jax.tree_util.tree_leaves(grads[part])]
        assert all(np.all(np.isfinite(g)) for g in leaves), part
        assert max(np.abs(g).max() for g in leaves) > 0, part


def test_checkpoints_round_trip_and_load_as_prior_and_filter(tmp_path):
    from driveopt.priors.cvae_multipliers import load_prior

    path = tiny_cvae_multipliers(tmp_path / "m.ckpt", seed=2)
    cfg, params, norm, meta = cm.load_model(path, lanes=4)
    assert cfg == MULTIPLIERS_CFG and meta["lanes"] == [4]
    expected = random_params(cm.init_params, MULTIPLIERS_CFG, 2)
    for got, want in zip(jax.tree_util.tree_leaves(params), jax.tree_util.tree_leaves(expected)):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    prior, head = load_prior(path, lanes=4), load_multipliers(path, CONFIG, lanes=4)
    problem, coeffs, _, _ = _batch()
    samples = prior.propose(problem, jax.random.PRNGKey(0), 5).samples
    assert samples.shape == (5, 8) and np.all(np.isfinite(np.asarray(samples)))
    assert head.initialise(problem, coeffs).multipliers.shape == coeffs.shape
    with pytest.raises(CheckpointError, match="trained for 4-lane roads"):
        cm.load_model(path, lanes=2)


def test_bad_input_is_refused_with_a_clear_error(tmp_path):
    from tiny_models import tiny_cvae

    with pytest.raises(ConfigError, match="multiplier_hidden"):
        cm.MultiplierCVAEConfig(multiplier_hidden=())
    with pytest.raises(ConfigError, match="multiplier_scale"):
        dataclasses.replace(MULTIPLIERS_CFG, multiplier_scale=float("nan"))
    head = CVAEMultipliers(cm.init_params(MULTIPLIERS_CFG, jax.random.PRNGKey(0)), _identity_normaliser(), MULTIPLIERS_CFG)
    problem, coeffs, _, _ = _batch()
    with pytest.raises(FilterError, match="22 coefficients"):
        head.initialise(problem, coeffs[:, :20])
    with pytest.raises(CheckpointError, match="holds a 'cvae' model, expected 'cvae-multipliers'"):
        cm.load_model(tiny_cvae(tmp_path / "cvae.ckpt"))
