"""P2's learned safety filter: barrier configuration, 0 projection iterations, the filter network in the
planner, the eq. 9 loss and its gradient, training (loss, checkpoints, resume), the vqvae-filter planner and options.

The trainings share one setting (``CFG``, ``TCFG``, the ``vqvae-filter`` projection), so their jitted steps compile
once; the planning tests share the ``PLAN`` configuration, which ``driveopt plan`` below also plans with."""

from __future__ import annotations

import dataclasses
import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from learned_data import file_fixture, trained_fixture, write_scenes

from driveopt.checks import ConfigError
from driveopt.cli import main
from driveopt.cli.common import config_overrides
from driveopt.config import BasisConfig, ProjectionConfig, QPConfig
from driveopt.data.demonstrations import load_demonstrations
from driveopt.learned import filter as fl
from driveopt.learned.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from driveopt.planner import PlanStatus, plan, project_batch, setpoint_batch
from driveopt.problem import build_problem
from driveopt.projection import constraint_residuals, project
from driveopt.qp import boundary_values, make_model, solve_setpoint_qp
from driveopt.registry import get_optimiser, list_planners
from driveopt.safety import FilterError, FilterInit, LearnedFilter, check_filter_init, load_filter
from driveopt.sampler import GaussianPrior
from driveopt.scene import load_scene
from driveopt.sim.scenarios import get_scenario
from driveopt.training.filter import (
    TrainConfig,
    draw_setpoints,
    row_problems,
    scenario_config,
    selection_key,
    train_filter,
    training_config,
    value_and_grad,
)

CFG = fl.FilterConfig(hidden=(16, 16))
TCFG = TrainConfig(epochs=4, batch_size=4, samples=8, unroll=1, samples_from="gaussian", learning_rate=1e-2,
                   validation_fraction=0.34)
TRAIN_ARGS = ["--samples-from", "gaussian", "--epochs", "4", "--batch-size", "4", "--samples", "8", "--unroll", "1",
              "--lr", "1e-2", "--hidden", "16", "16", "--validation", "0.34"]  # TCFG and CFG on the command line
PLANNER = get_optimiser("vqvae-filter")
PLAN = PLANNER.with_samples(16).with_overrides(projection={"max_iterations": 6})  # what `driveopt plan` below runs


data_file = file_fixture(write_scenes, "scenes.h5")
trained = trained_fixture(lambda data, out: train_filter(data, out, CFG, TCFG, config=PLANNER.config, progress=False))


def small_batch(num: int = 8):
    """(problem, qp coefficients, b_x, b_y) of ``num`` QP trajectories on the dense snapshot, with PLAN's basis and QP."""
    config = PLAN.config
    problem = build_problem(load_scene("dense-snapshot"), config.basis)
    key = jax.random.PRNGKey(3)
    p = jnp.concatenate([16 + 4 * jax.random.normal(key, (num, 4)), 6 + 4 * jax.random.normal(jax.random.fold_in(key, 1), (num, 4))], 1)
    qp_coeffs, b_x, b_y = setpoint_batch(make_model(config.basis, config.qp), problem, config, p)
    return problem, qp_coeffs, b_x, b_y


# ------------------------------------------------------------------------------------------ configuration


def test_barrier_gammas_are_validated_configuration_and_default_to_the_plain_constraints():
    cfg = ProjectionConfig()
    assert (cfg.gamma_obs, cfg.gamma_lane, cfg.barrier) == (1.0, 1.0, False)
    assert ProjectionConfig(barrier=True, gamma_obs=0.98, gamma_lane=0.9).gamma_lane == 0.9
    for bad in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(ConfigError, match="gamma_obs"):
            ProjectionConfig(barrier=True, gamma_obs=bad)
    with pytest.raises(ConfigError, match="needs projection.barrier"):
        ProjectionConfig(gamma_lane=0.9)  # the plain constraints have no gamma: refused, not silently ignored
    assert ProjectionConfig(max_iterations=0).max_iterations == 0
    with pytest.raises(ConfigError, match=r"max_iterations must be in \[0, 10000\]"):
        ProjectionConfig(max_iterations=-1)
    # The configured gammas are what the projection uses without a filter.
    problem, target, b_x, b_y = small_batch()
    barrier = ProjectionConfig(max_iterations=3, tolerance=0.0, barrier=True)
    configured = project(make_model(), problem, target, b_x, b_y, dataclasses.replace(barrier, gamma_obs=0.9, gamma_lane=0.7))
    given = project(make_model(), problem, target, b_x, b_y, barrier, gamma_obs=0.9, gamma_lane=0.7)
    np.testing.assert_array_equal(configured.coeffs, given.coeffs)


def test_without_a_filter_the_projection_gives_the_numbers_recorded_before_learned_filters():
    """Residuals of 8 samples after 5 iterations, recorded with the code before the barrier gammas, 0 iterations and
    per-sample filters were added (plain and barrier mode agree at gamma = 1); no course bound, which came later."""
    model = make_model()
    problem = build_problem(load_scene("dense-snapshot"))
    key = jax.random.PRNGKey(3)
    p = jnp.concatenate([16 + 4 * jax.random.normal(key, (8, 4)), 6 + 4 * jax.random.normal(jax.random.fold_in(key, 1), (8, 4))], 1)
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
    target = solve_setpoint_qp(model, p, b_x, b_y)
    before = [8.476986, 9.641378, 18.704754, 11.369852, 8.389954, 17.534994, 1.9567223, 9.972218]
    # Recorded on another machine: XLA's float32 CPU code differs between processor generations (an AVX-512 AMD EPYC
    # gave 1.3e-4 relative on the last sample), far below what a change to the projection's logic moves.
    for barrier in (False, True):
        out = project(model, problem, target, b_x, b_y, ProjectionConfig(max_iterations=5, tolerance=0.0, barrier=barrier,
                                                                             course_max=0.0))
        np.testing.assert_allclose(out.residuals.total, before, rtol=1e-3)


# ------------------------------------------------------------------------------------------ 0 iterations


class RefusingFilter:
    """A filter that must not be consulted."""

    def initialise(self, problem, coeffs):
        raise AssertionError("the filter was consulted")


def test_zero_projection_iterations_return_the_sampled_trajectories_unchanged():
    problem, qp_coeffs, b_x, b_y = small_batch()
    model = make_model(PLAN.config.basis, PLAN.config.qp)
    config = PLAN.config.replace(projection={"max_iterations": 0})
    out = project_batch(model, problem, config, qp_coeffs, b_x, b_y, RefusingFilter())
    np.testing.assert_array_equal(out.coeffs, qp_coeffs)
    assert int(out.iterations) == 0
    # Given a first iterate anyway, project() still returns the samples (the initialisation is not used).
    direct = project(model, problem, qp_coeffs, b_x, b_y, config.projection, init_coeffs=qp_coeffs + 5.0,
                     init_multipliers=jnp.ones_like(qp_coeffs))
    np.testing.assert_array_equal(direct.coeffs, qp_coeffs)
    plain = constraint_residuals(model, problem, qp_coeffs, config.projection)
    np.testing.assert_allclose(out.residuals.total, plain.total, rtol=1e-5, atol=1e-4)  # ranked by their own residuals
    assert float(jnp.max(out.residuals.total)) > 0.1  # these samples do violate constraints: nothing was corrected
    # The planner ranks every row of the batch as the set-point QP made it (P2 Fig. 9's "no filter").
    result = plan(problem, config, key=jax.random.PRNGKey(0), prior=PLAN.prior(4))
    np.testing.assert_array_equal(result.first.projected_coeffs, result.first.qp_coeffs)
    assert list(result.history.projection_iterations) == [0]


# ------------------------------------------------------------------------------------------ the filter in the planner


def test_gamma_one_and_zero_initialisation_reproduce_the_plain_projection_exactly(trained):
    learned = load_filter(trained[0] / "filter.ckpt")
    plain = LearnedFilter(fl.plain_params(learned.params, learned.config), learned.normaliser, learned.config)
    problem, qp_coeffs, b_x, b_y = small_batch()
    init = plain.initialise(problem, qp_coeffs)
    assert np.all(np.asarray(init.gamma_obs) == 1.0) and np.all(np.asarray(init.gamma_lane) == 1.0)
    np.testing.assert_array_equal(init.coeffs, qp_coeffs)
    np.testing.assert_array_equal(init.multipliers, np.zeros_like(qp_coeffs))
    # Through the whole planner: every row of the batch, the choice, its residuals.
    problem = build_problem(load_scene("static-blockage"), PLAN.config.basis)
    without = plan(problem, PLAN.config, key=jax.random.PRNGKey(0), prior=PLAN.prior(4))
    with_filter = plan(problem, PLAN.config, key=jax.random.PRNGKey(0), prior=PLAN.prior(4), safety_filter=plain)
    for a, b in zip(jax.tree_util.tree_leaves(without.first), jax.tree_util.tree_leaves(with_filter.first)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(without.coeffs, with_filter.coeffs)
    assert without.residuals == with_filter.residuals
    # The trained filter moves away from it: per-sample gammas below 1, its own first iterate.
    moved = plan(problem, PLAN.config, key=jax.random.PRNGKey(0), prior=PLAN.prior(4), safety_filter=learned)
    assert not np.array_equal(moved.first.projected_coeffs, without.first.projected_coeffs)
    assert np.all(np.isfinite(moved.first.projected_coeffs))


def test_per_sample_gammas_project_each_sample_as_alone():
    """One batch with a gamma per sample gives each sample the projection it gets alone with its gamma."""
    problem, qp_coeffs, b_x, b_y = small_batch(4)
    model = make_model(PLAN.config.basis, PLAN.config.qp)
    cfg = ProjectionConfig(max_iterations=3, tolerance=0.0, barrier=True)
    g_obs, g_lane = jnp.array([0.5, 0.8, 0.95, 1.0]), jnp.array([0.3, 0.6, 0.9, 1.0])
    run = jax.jit(lambda coeffs, g_obs, g_lane: project(model, problem, coeffs, b_x, b_y, cfg, gamma_obs=g_obs, gamma_lane=g_lane))
    batch = run(qp_coeffs, g_obs, g_lane)
    for i in range(4):
        alone = run(qp_coeffs[i:i + 1], g_obs[i], g_lane[i])  # one number for the batch of one
        np.testing.assert_allclose(batch.coeffs[i], alone.coeffs[0], rtol=1e-4, atol=2e-3)
        np.testing.assert_allclose(batch.residuals.total[i], alone.residuals.total[0], rtol=1e-3, atol=1e-3)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ShapeFilter:
    """A filter whose outputs have the given shapes (a pytree without leaves)."""

    gamma_shape: tuple = dataclasses.field(default=(), metadata=dict(static=True))
    coeffs_rows: int | None = dataclasses.field(default=None, metadata=dict(static=True))

    def initialise(self, problem, coeffs):
        rows = coeffs.shape[0] if self.coeffs_rows is None else self.coeffs_rows
        return FilterInit(jnp.ones(self.gamma_shape), jnp.float32(1.0), coeffs[:rows], jnp.zeros_like(coeffs[:rows]))


def test_malformed_filters_and_filters_for_another_basis_are_refused(trained):
    problem = build_problem(load_scene("static-blockage"), PLAN.config.basis)
    with pytest.raises(FilterError, match=r"gamma_obs has shape \(3,\)"):
        plan(problem, PLAN.config, key=jax.random.PRNGKey(0), prior=PLAN.prior(4), safety_filter=ShapeFilter((3,)))
    with pytest.raises(FilterError, match="coeffs has shape"):
        plan(problem, PLAN.config, key=jax.random.PRNGKey(0), prior=PLAN.prior(4), safety_filter=ShapeFilter(coeffs_rows=2))
    with pytest.raises(FilterError, match="must return a FilterInit"):
        check_filter_init((1.0, 1.0), (4, 22))
    learned = load_filter(trained[0] / "filter.ckpt")
    order8 = fl.FilterConfig(hidden=(16, 16), basis=BasisConfig(order=8))
    other = LearnedFilter(fl.init_params(order8, jax.random.PRNGKey(0)), fl.Normaliser(*learned.normaliser), order8)
    with pytest.raises(FilterError, match="trained for 18 coefficients"):
        plan(problem, PLAN.config, key=jax.random.PRNGKey(0), prior=PLAN.prior(4), safety_filter=other)


# ------------------------------------------------------------------------------------------ the loss and training


def test_the_filter_trains_through_p2s_plain_map_whatever_pass_the_planner_runs():
    from driveopt.registry import get_optimiser

    for name in ("vqvae-filter", "vqvae-filter-faithful"):
        projection = training_config(get_optimiser(name).config, TCFG).projection
        assert (projection.max_iterations, projection.anderson_window, projection.derivative_bounds) == (
            TCFG.unroll, 0, "nodes")
        assert projection.barrier and training_config(get_optimiser(name).config, TCFG).sampler.num_iterations == 1


def test_grad_of_the_eq9_loss_is_finite_and_matches_finite_differences(trained, data_file):
    learned = load_filter(trained[0] / "filter.ckpt")
    data = load_demonstrations(data_file)
    rows = np.arange(TCFG.batch_size)
    planner, v_des = scenario_config(data, rows, PLANNER.config)
    config = training_config(planner, TCFG)
    problems = row_problems(data, rows, v_des, config)
    problems = jax.tree_util.tree_map(jnp.asarray, problems)
    prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    setpoints = draw_setpoints(prior, problems, jax.random.split(jax.random.PRNGKey(5), len(rows)), TCFG.samples)
    weight = jnp.float32(TCFG.residual_weight)

    def evaluate(params):  # the training step's own compiled function
        return value_and_grad(params, learned.normaliser, problems, setpoints, weight, learned.config, config)

    (value, terms), grad = evaluate(learned.params)
    leaves = jax.tree_util.tree_leaves(grad)
    assert np.isfinite(float(value)) and all(np.all(np.isfinite(np.asarray(g))) for g in leaves)
    assert float(terms["correction"]) > 0 and float(terms["residual"]) > 0
    assert any(float(jnp.max(jnp.abs(g))) > 0 for g in leaves)
    # Direction: the unit gradient plus a unit random vector (the derivative along a random direction alone is ~1/40
    # of the gradient's norm here, near the float32 noise of the difference quotient).
    unit = lambda tree: jax.tree_util.tree_map(  # noqa: E731
        lambda a: a / jnp.sqrt(sum(jnp.sum(b ** 2) for b in jax.tree_util.tree_leaves(tree))), tree)
    keys = jax.random.split(jax.random.PRNGKey(7), len(leaves))
    random = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(grad), [jax.random.normal(k, g.shape) for k, g in zip(keys, leaves)])
    direction = unit(jax.tree_util.tree_map(jnp.add, unit(grad), unit(random)))
    analytic = float(sum(jnp.vdot(g, d) for g, d in zip(leaves, jax.tree_util.tree_leaves(direction))))
    eps = 3e-3  # float32, unit step in parameter space: the projection's clips bend the loss above, rounding below
    shifted = lambda s: jax.tree_util.tree_map(lambda p, d: p + s * eps * d, learned.params, direction)  # noqa: E731
    numeric = (float(evaluate(shifted(1.0))[0][0]) - float(evaluate(shifted(-1.0))[0][0])) / (2 * eps)
    assert analytic > 1.0, (analytic, numeric)
    assert analytic == pytest.approx(numeric, rel=3e-2), (analytic, numeric)


def test_the_kept_epoch_is_the_one_with_most_samples_feasible_then_the_lowest_loss():
    """Eq. 9's loss can fall while fewer samples end feasible; filter.ckpt keeps the epoch the planner's pick needs."""
    lower_loss = {"epoch": 1, "val_feasible": 0.586, "val_loss": 1248.0}
    more_feasible = {"epoch": 2, "val_feasible": 0.621, "val_loss": 1347.0}
    tie_lower_loss = {"epoch": 3, "val_feasible": 0.621, "val_loss": 1300.0}
    assert selection_key(more_feasible) > selection_key(lower_loss)
    assert selection_key(tie_lower_loss) > selection_key(more_feasible)
    assert selection_key({"epoch": 1, "train_feasible": 0.5, "train_loss": 9.0}) < selection_key(
        {"epoch": 2, "train_feasible": 0.5, "train_loss": 8.0})  # without validation rows: the training epoch's


def test_the_eq9_loss_falls_on_a_small_dataset(trained):
    out, summary = trained
    history = summary["history"]
    assert [r["epoch"] for r in history] == list(range(1, TCFG.epochs + 1))
    assert summary["rows"] == {"train": 12, "validation": 6}
    baseline = summary["baseline"]  # the plain filter on the validation samples
    assert history[-1]["val_loss"] < history[0]["val_loss"]
    assert history[-1]["val_loss"] < 0.99 * baseline["loss"]
    best = max(history, key=lambda r: (r["val_feasible"], -r["val_loss"]))  # most samples feasible, then lowest loss
    assert summary["kept"] == best
    assert load_checkpoint(out / "filter.ckpt", fl.CHECKPOINT_KIND)[0]["epoch"] == best["epoch"]
    assert {"val_correction", "val_residual", "val_feasible", "train_correction", "train_residual"} <= set(history[-1])
    assert json.loads((out / "history.json").read_text()) == history
    learned = load_filter(out / "filter.ckpt", lanes=4)
    problem, qp_coeffs, _, _ = small_batch()
    init = learned.initialise(problem, qp_coeffs)
    gammas = np.concatenate([np.asarray(init.gamma_obs), np.asarray(init.gamma_lane)])
    assert init.gamma_obs.shape == (8,) and np.all((gammas > CFG.gamma_min) & (gammas < 1.0))


def test_checkpoint_round_trip_and_corrupted_or_mismatched_checkpoints(trained, tmp_path):
    params = fl.init_params(CFG, jax.random.PRNGKey(3))
    params = jax.tree_util.tree_map(lambda p: p + 0.01 * jax.random.normal(jax.random.PRNGKey(4), p.shape), params)
    norm = fl.Normaliser(jnp.arange(CFG.input_dim, dtype=jnp.float32), jnp.full(CFG.input_dim, 2.0, jnp.float32))
    path = save_checkpoint(tmp_path / "f.ckpt", fl.CHECKPOINT_KIND, {"params": params, "normaliser": norm},
                           {"config": CFG.to_dict(), "lanes": [4]})
    loaded = load_filter(path, lanes=4)
    assert loaded.config == CFG
    for a, b in zip(jax.tree_util.tree_leaves((params, norm)), jax.tree_util.tree_leaves((loaded.params, loaded.normaliser))):
        np.testing.assert_array_equal(a, b)
    problem, qp_coeffs, _, _ = small_batch(4)
    original = LearnedFilter(params, norm, CFG).initialise(problem, qp_coeffs)
    for a, b in zip(original, loaded.initialise(problem, qp_coeffs)):
        np.testing.assert_array_equal(a, b)

    header, body = path.read_bytes().split(b"\n", 1)
    damaged = tmp_path / "damaged.ckpt"
    damaged.write_bytes(header + b"\n" + body[:-10] + bytes(b ^ 0xFF for b in body[-10:]))
    with pytest.raises(CheckpointError, match="corrupted"):
        load_filter(damaged)
    damaged.write_bytes(header + b"\n" + body[: len(body) // 2])
    with pytest.raises(CheckpointError, match="corrupted"):
        load_filter(damaged)
    with pytest.raises(CheckpointError, match="trained for 4-lane roads, not this 2-lane road"):
        load_filter(path, lanes=2)
    wrong_shape = save_checkpoint(tmp_path / "shape.ckpt", fl.CHECKPOINT_KIND, {"params": params, "normaliser": norm},
                                  {"config": dataclasses.replace(CFG, hidden=(32,)).to_dict()})
    with pytest.raises(CheckpointError, match="does not match|shape"):
        load_filter(wrong_shape)
    nan = jax.tree_util.tree_map(lambda p: p.at[(0,) * p.ndim].set(jnp.nan), params)
    with pytest.raises(CheckpointError, match="NaN"):
        load_filter(save_checkpoint(tmp_path / "nan.ckpt", fl.CHECKPOINT_KIND, {"params": nan, "normaliser": norm},
                                    {"config": CFG.to_dict()}))
    other_kind = save_checkpoint(tmp_path / "cvae.ckpt", "cvae", {"params": params}, {})
    with pytest.raises(CheckpointError, match="expected 'safety-filter'"):
        load_filter(other_kind)
    with pytest.raises(CheckpointError, match="invalid safety-filter config"):
        load_filter(save_checkpoint(tmp_path / "cfg.ckpt", fl.CHECKPOINT_KIND, {"params": params, "normaliser": norm},
                                    {"config": {"hidden": [16], "gamma_min": 2.0}}))
    with pytest.raises(CheckpointError, match="cannot read"):
        load_filter(tmp_path / "missing.ckpt")


def test_training_resumes_without_repeating_epochs_and_refuses_other_settings(data_file, trained, tmp_path):
    first = train_filter(data_file, tmp_path, CFG, TCFG, config=PLANNER.config, progress=False, stop_after=2)
    assert [r["epoch"] for r in first["history"]] == [1, 2]
    resumed = train_filter(data_file, tmp_path, CFG, TCFG, config=PLANNER.config, progress=False)
    assert [r["epoch"] for r in resumed["history"]] == [1, 2, 3, 4]
    for a, b in zip(resumed["history"], trained[1]["history"]):  # the same run as uninterrupted
        assert a == pytest.approx(b, rel=1e-5)
    again = train_filter(data_file, tmp_path, CFG, TCFG, config=PLANNER.config, progress=False)  # nothing left to do
    assert again["history"] == resumed["history"]
    meta, state = load_checkpoint(tmp_path / "last.ckpt", fl.CHECKPOINT_KIND)
    del meta["projection"]["course_min_speed"]  # written before that setting existed, so it ran at its default
    save_checkpoint(tmp_path / "last.ckpt", fl.CHECKPOINT_KIND, state, meta)
    assert train_filter(data_file, tmp_path, CFG, TCFG, config=PLANNER.config, progress=False)["history"] == resumed["history"]
    with pytest.raises(CheckpointError, match="other settings"):
        train_filter(data_file, tmp_path, CFG, dataclasses.replace(TCFG, residual_weight=1.0), config=PLANNER.config, progress=False)
    with pytest.raises(CheckpointError, match="another network configuration"):
        train_filter(data_file, tmp_path, dataclasses.replace(CFG, gamma_min=0.2), TCFG, config=PLANNER.config, progress=False)
    with pytest.raises(CheckpointError, match="another projection"):
        train_filter(data_file, tmp_path, CFG, TCFG, config=PLANNER.config.replace(projection={"rho_lane": 2.0}), progress=False)


def test_training_resumes_inside_an_epoch_taking_the_same_steps(data_file, trained, tmp_path):
    first = train_filter(data_file, tmp_path, CFG, TCFG, config=PLANNER.config, progress=False, stop_after_steps=2)
    meta, _ = load_checkpoint(tmp_path / "last.ckpt", fl.CHECKPOINT_KIND)
    assert first["history"] == [] and first["weights"] is None  # stopped inside epoch 1 (3 steps of 4 of 12 rows)
    assert meta["partial"]["epoch"] == 1 and meta["partial"]["steps"] == 2
    second = train_filter(data_file, tmp_path, CFG, TCFG, config=PLANNER.config, progress=False, stop_after_steps=3)
    assert [r["epoch"] for r in second["history"]] == [1]  # its last step, then 2 of epoch 2
    partial = load_checkpoint(tmp_path / "last.ckpt", fl.CHECKPOINT_KIND)[0]["partial"]
    assert (partial["epoch"], partial["steps"]) == (2, 2)
    final = train_filter(data_file, tmp_path, CFG, TCFG, config=PLANNER.config, progress=False)
    assert len(final["history"]) == len(trained[1]["history"]) == 4
    for a, b in zip(final["history"], trained[1]["history"]):  # the same run as uninterrupted
        assert a == pytest.approx(b, rel=1e-5)
    resumed = load_filter(tmp_path / "filter.ckpt")
    reference = load_filter(trained[0] / "filter.ckpt")
    for a, b in zip(jax.tree_util.tree_leaves(resumed), jax.tree_util.tree_leaves(reference)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)


def test_train_filter_command_resumes_and_reports_bad_input_in_one_line(data_file, tmp_path, capsys, monkeypatch):
    out = tmp_path / "cli"
    assert main(["train", "filter", "--data", str(data_file), "--out", str(out), *TRAIN_ARGS]) == 0
    assert "trained 4 epochs on 12 observations (6 validation)" in capsys.readouterr().out
    assert main(["train", "filter", "--data", str(data_file), "--out", str(out), *TRAIN_ARGS]) == 0  # resumes: nothing to do
    assert len(json.loads((out / "history.json").read_text())) == 4
    monkeypatch.setattr("driveopt.priors.vqvae.SHIPPED", {})  # as for a road without shipped weights
    for args, message in (
        (["--samples-from", "vqvae"], "no VQ-VAE weights shipped for 4-lane roads"),
        (["--samples-from", "gaussian", "--prior-weights", str(data_file)], "--prior-weights is for --samples-from vqvae or cvae"),
        (["--lr", "-1"], "learning_rate must be a finite number > 0"),
        (["--residual-weight", "nan"], "residual_weight must be a finite number"),
        (["--gamma-min", "1.5"], "gamma_min must be a finite number > 0 and < 1, got 1.5"),
        (["--planner", "idm"], "does not plan with the optimiser"),
    ):
        code = main(["train", "filter", "--data", str(data_file), "--out", str(tmp_path / "bad"), *args])
        assert code == 2
        assert message in capsys.readouterr().err
        assert not (tmp_path / "bad").exists()  # nothing written
    with pytest.raises(SystemExit) as exc:  # a save period of 0 s would write the checkpoint after every step
        main(["train", "filter", "--data", str(data_file), "--out", str(tmp_path / "bad"), "--save-every", "0"])
    assert exc.value.code == 2 and "--save-every: expected an integer >= 1, got 0" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------ planners and options


def test_vqvae_filter_is_p2s_pipeline_and_warns_without_weights():
    assert "vqvae-filter" in list_planners()
    from driveopt.registry import P2_PASS_PROJECTION

    vqvae = get_optimiser("vqvae")
    assert PLANNER.learned_filter and not vqvae.learned_filter
    assert PLANNER.config.replace(projection=P2_PASS_PROJECTION) == vqvae.config  # its own pass is faster
    same = dataclasses.replace(PLANNER, name="vqvae", description=vqvae.description, make_prior=vqvae.make_prior,
                               learned_filter=False, config=vqvae.config)
    assert same == vqvae  # samples, the rest of the projection, ranking, fallback: all vqvae's
    with pytest.warns(UserWarning, match="no safety-filter weights shipped for 3-lane roads"):
        assert PLANNER.safety_filter(3) is None  # the plain barrier filter of its configuration
    assert vqvae.safety_filter(4) is None


@pytest.mark.parametrize("lanes, problem_name", [(4, "slow-leader-four-lane"), (2, None)])
def test_shipped_filter_weights_load_by_default_and_plan_feasibly(lanes, problem_name):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no fallback notice: filter weights ship for two- and four-lane roads
        learned = PLANNER.safety_filter(lanes)
        prior = PLANNER.prior(lanes)
    assert isinstance(learned, LearnedFilter) and learned.config.gamma_min == 0.5
    if problem_name is None:
        return
    problem = build_problem(load_scene(problem_name))
    config = PLANNER.config.with_samples(200)
    result = plan(problem, config, key=jax.random.PRNGKey(0), prior=prior, safety_filter=learned)
    assert result.status == PlanStatus.SUCCESS and np.all(np.isfinite(result.trajectory.x))
    plain = plan(problem, config, key=jax.random.PRNGKey(0), prior=prior)
    assert not np.allclose(result.trajectory.x, plain.trajectory.x)  # the filter changes the projection


def test_any_optimiser_takes_a_filter_checkpoint_and_wrong_roads_are_refused(trained, tmp_path):
    weights = str(trained[0] / "filter.ckpt")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert isinstance(PLANNER.with_filter_weights(weights).safety_filter(4), LearnedFilter)
    with pytest.warns(UserWarning, match="barrier mode"):  # bilevel's projection is plain: only the initialisation acts
        assert isinstance(get_optimiser("bilevel").with_filter_weights(weights).safety_filter(4), LearnedFilter)
    with pytest.raises(CheckpointError, match="not this 2-lane road"):
        PLANNER.with_filter_weights(weights).check(get_scenario("two-lane-d1.0"))
    with pytest.raises(CheckpointError, match="cannot read"):
        get_optimiser("random").with_filter_weights(str(tmp_path / "none.ckpt")).safety_filter(4)
    # --config carries it too ({"safety_filter": {"weights": FILE}}), and --filter-weights writes that section.
    spec = get_optimiser("random").with_overrides(safety_filter={"weights": weights}, sampler={"temperature": 0.5})
    assert spec.filter_weights == weights and spec.config.sampler.temperature == 0.5
    with pytest.raises(ConfigError, match="safety_filter"):
        get_optimiser("random").with_overrides(safety_filter={"weight": weights})
    assert config_overrides(None, weights) == {"safety_filter": {"weights": weights}}
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"projection": {"barrier": True}, "safety_filter": {"weights": weights}}))
    assert config_overrides(str(config)) == {"projection": {"barrier": True}, "safety_filter": {"weights": weights}}
    config.write_text(json.dumps({"safety_filter": {"weights": 3}}))
    with pytest.raises(ConfigError, match="safety_filter.weights"):
        config_overrides(str(config))
    assert get_optimiser("random").filter_weights is None  # the copies leave the registered planners alone


def test_plan_command_plans_with_a_filter_checkpoint(trained, tmp_path):
    out = tmp_path / "plan.json"
    code = main(["plan", "--problem", "static-blockage", "--planner", "vqvae-filter", "--samples", "16",
                 "--projection-iterations", "6", "--filter-weights", str(trained[0] / "filter.ckpt"), "--repeats", "0",
                 "--json", str(out)])
    assert code == 0
    report = json.loads(out.read_text())
    assert report["planner"] == "vqvae-filter" and report["config"]["projection"]["gamma_obs"] == 1.0
    assert np.all(np.isfinite(report["trajectory"]["x"]))


def test_plan_and_bench_commands_refuse_a_missing_or_mismatched_filter_checkpoint(trained, tmp_path, capsys):
    missing = str(tmp_path / "missing.ckpt")
    assert main(["plan", "--problem", "static-blockage", "--filter-weights", missing]) == 2
    assert capsys.readouterr().err == f"driveopt: error: filter weights file {missing} does not exist\n"
    # bench checks the filter of every optimiser before its folder is touched (and records it with the config).
    bench = ["bench", "--scenarios", "two-lane-d1.0", "--planners", "idm", "grid", "--episodes", "1", "--out", str(tmp_path / "b")]
    assert main([*bench, "--filter-weights", missing]) == 2
    assert "cannot read checkpoint" in capsys.readouterr().err and not (tmp_path / "b").exists()
    assert main([*bench, "--filter-weights", str(trained[0] / "filter.ckpt")]) == 2  # trained for four lanes
    assert "not this 2-lane road" in capsys.readouterr().err and not (tmp_path / "b").exists()
