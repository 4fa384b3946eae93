"""CVAE warm start: QP-layer gradients, training, checkpoints, the planner prior, and their errors."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from learned_data import LANES, file_fixture, trained_fixture, write_synthetic
from tiny_models import with_meta

from driveopt.checks import ConfigError
from driveopt.cli import main
from driveopt.data.demonstrations import DatasetError, load_demonstrations
from driveopt.learned.checkpoint import CheckpointError, load_checkpoint
from driveopt.learned.cvae import CVAEConfig, decode_setpoints, fit_normaliser, init_params, load_cvae, trajectory_model
from driveopt.planner import PlanStatus, plan
from driveopt.priors.cvae import CVAEPrior, load_prior, prior_for, shipped_weights
from driveopt.problem import build_problem
from driveopt.qp import qp_layer
from driveopt.scene import load_scene
from driveopt.training.cvae import TrainConfig, make_batch, train_cvae
from driveopt.training.harness import TrainingError, road_lanes, training_rows
from driveopt.xla import float32_products

CFG = CVAEConfig(hidden=(32, 32))
TCFG = TrainConfig(epochs=10, batch_size=32, learning_rate=3e-3, anneal_epochs=2)
CLI_SETTINGS = ["--hidden", "32", "32", "--batch-size", "32", "--lr", "3e-3"]  # CFG and TCFG: the same compiled steps


data_file = file_fixture(write_synthetic, "demo.h5")
trained = trained_fixture(lambda data, out: train_cvae(data, out, CFG, TCFG, progress=False))


def test_qp_layer_gradient_through_decoder_matches_finite_differences(data_file):
    data = load_demonstrations(data_file)
    batch = make_batch(data, np.arange(16))
    norm = fit_normaliser(batch, CFG)
    params = init_params(CFG, jax.random.PRNGKey(1))
    model = trajectory_model(CFG)
    z = jax.random.normal(jax.random.PRNGKey(2), (16, CFG.latent_dim))

    def reconstruction(decoder):
        sp = decode_setpoints({**params, "decoder": decoder}, CFG, norm, z, batch.observation, batch.lane_bounds)
        _, positions = qp_layer(model, CFG.qp, sp, batch.init_x, batch.init_y)
        return jnp.mean(jnp.sum((positions - batch.trajectory) ** 2, -1))

    # the direction, steps and products on the host (numpy), the model's functions jitted: a handful of compilations
    # instead of one per operation
    rng = np.random.default_rng(3)
    decoder = jax.tree_util.tree_map(np.asarray, params["decoder"])
    direction = jax.tree_util.tree_map(lambda p: rng.normal(size=p.shape).astype(np.float32), decoder)
    norm2 = sum(np.sum(d**2) for d in jax.tree_util.tree_leaves(direction))
    direction = jax.tree_util.tree_map(lambda d: d / np.sqrt(norm2), direction)  # unit step in parameter space
    reconstruction = jax.jit(float32_products(reconstruction))  # an accelerator's default (TF32) is too coarse for eps
    grad = jax.jit(jax.grad(reconstruction))(decoder)
    analytic = sum(np.vdot(g, d) for g, d in zip(jax.tree_util.tree_leaves(grad), jax.tree_util.tree_leaves(direction)))
    eps = 1e-3  # float32: curvature dominates above, rounding below (float64 agrees to 1e-8)
    shifted = lambda s: jax.tree_util.tree_map(lambda p, d: p + np.float32(s * eps) * d, decoder, direction)  # noqa: E731
    numeric = (reconstruction(shifted(1.0)) - reconstruction(shifted(-1.0))) / (2 * eps)
    assert float(analytic) == pytest.approx(float(numeric), rel=2e-2)
    # The QP layer itself: d positions / d set-points equals the QP's speed and lateral maps.
    jac = jax.jit(jax.jacobian(lambda sp: qp_layer(model, CFG.qp, sp, batch.init_x[:1], batch.init_y[:1])[1]))(jnp.asarray(data.setpoints[:1]))
    assert np.allclose(np.asarray(jac)[0, :, 1, 0, 4:], np.asarray(model.W @ model.lateral_map), atol=1e-4)


def test_loss_falls_and_bounded_setpoints(trained, data_file):
    _, summary = trained
    history = summary["history"]
    assert len(history) == TCFG.epochs
    first, last = history[0]["train_reconstruction"], history[-1]["train_reconstruction"]
    assert last < 0.3 * first, (first, last)
    assert history[-1]["val_reconstruction"] < 0.5 * history[0]["val_reconstruction"]
    prior = load_prior(trained[0] / "cvae.ckpt")
    samples = prior.propose(build_problem(load_scene("dense-snapshot")), jax.random.PRNGKey(0), 500, None).samples
    assert np.all(np.isfinite(samples))
    assert np.all((samples[:, :4] >= 0) & (samples[:, :4] <= 30.0))


def test_checkpoint_round_trip_gives_identical_samples(trained, tmp_path):
    out, _ = trained
    problem = build_problem(load_scene("dense-snapshot"))
    a = load_prior(out / "cvae.ckpt").propose(problem, jax.random.PRNGKey(5), 64, None)
    copy = tmp_path / "copy.ckpt"
    copy.write_bytes((out / "cvae.ckpt").read_bytes())
    b = load_prior(copy).propose(problem, jax.random.PRNGKey(5), 64, None)
    assert np.array_equal(np.asarray(a.samples), np.asarray(b.samples))
    assert np.array_equal(np.asarray(a.cov), np.asarray(b.cov))


@pytest.mark.parametrize("damage", ["truncate", "flip", "header", "empty"])
def test_corrupted_checkpoint_is_refused(trained, tmp_path, damage):
    raw = (trained[0] / "cvae.ckpt").read_bytes()
    bad = {"truncate": raw[: len(raw) // 2], "flip": raw[:-10] + bytes(b ^ 0xFF for b in raw[-10:]),
           "header": b"garbage\n" + raw, "empty": b""}[damage]
    path = tmp_path / "bad.ckpt"
    path.write_bytes(bad)
    with pytest.raises(CheckpointError):
        load_prior(path)
    assert main(["plot-prior", "--weights", str(path), "--out", str(tmp_path / "p.png")]) == 2


def test_checkpoint_of_another_architecture_is_refused(trained, tmp_path):
    def wider(meta):
        meta["config"]["hidden"] = [64, 64]  # header claims widths the weights do not have

    with pytest.raises(CheckpointError, match="does not match|shape"):
        load_prior(with_meta(trained[0] / "cvae.ckpt", tmp_path / "mismatch.ckpt", wider))


def test_training_resumes_to_the_same_weights(data_file, trained, tmp_path):
    train_cvae(data_file, tmp_path, CFG, TCFG, progress=False, stop_after=3)
    resumed = train_cvae(data_file, tmp_path, CFG, TCFG, progress=False)
    assert len(resumed["history"]) == TCFG.epochs
    problem = build_problem(load_scene("dense-snapshot"))
    a = load_prior(tmp_path / "last.ckpt").propose(problem, jax.random.PRNGKey(0), 8, None).samples
    b = load_prior(trained[0] / "last.ckpt").propose(problem, jax.random.PRNGKey(0), 8, None).samples
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-5)
    for name in ("cvae.ckpt", "last.ckpt", "history.json"):  # every step and draw follows from the seed: the same bytes
        assert (tmp_path / name).read_bytes() == (trained[0] / name).read_bytes(), name


def test_resume_with_other_data_or_settings_is_refused(trained, tmp_path):
    other = write_synthetic(tmp_path / "other.h5", episodes=3, seed=9)
    with pytest.raises(CheckpointError, match="other demonstrations"):
        train_cvae(other, trained[0], CFG, TCFG, progress=False)


def test_train_episodes_shrinks_training_set_and_keeps_validation(tmp_path):
    data = write_synthetic(tmp_path / "six.h5", episodes=6, seed=3)
    quick = dataclasses.replace(TCFG, epochs=1, validation_fraction=0.2)
    full = train_cvae(data, tmp_path / "all", CFG, quick, progress=False)["rows"]
    two = train_cvae(data, tmp_path / "two", CFG, dataclasses.replace(quick, train_episodes=2), progress=False)["rows"]
    assert two["validation"] == full["validation"] > 0
    assert two["train"] == 2 * full["train"] // 5  # 2 of the 5 training episodes (64 rows each)
    with pytest.raises(CheckpointError, match="other settings"):
        train_cvae(data, tmp_path / "two", CFG, dataclasses.replace(quick, train_episodes=3), progress=False)


def test_separate_validation_files_are_held_out_whole(data_file, tmp_path):
    held = write_synthetic(tmp_path / "held.h5", episodes=2, seed=5)
    quick = dataclasses.replace(TCFG, epochs=1)
    rows = train_cvae(data_file, tmp_path / "a", CFG, quick, validation_paths=[held], progress=False)["rows"]
    assert rows == {"train": 4 * 64, "validation": 2 * 64}  # all of data_file trains; all of held validates
    history = json.loads((tmp_path / "a" / "history.json").read_text())
    assert np.isfinite(history[0]["val_reconstruction"])
    with pytest.raises(ValueError, match="other files"):
        train_cvae(data_file, tmp_path / "b", CFG, quick, validation_paths=[data_file], progress=False)
    with pytest.raises(CheckpointError, match="other validation episodes"):
        train_cvae(data_file, tmp_path / "a", CFG, quick, validation_paths=[write_synthetic(tmp_path / "h2.h5", 2, seed=6)],
                   progress=False)


def test_cvae_prior_in_the_planner(trained):
    prior = load_prior(trained[0] / "cvae.ckpt")
    assert isinstance(prior, CVAEPrior)
    problem = build_problem(load_scene("static-blockage"))
    from conftest import SMALL

    for samples in (64, 300):
        config = SMALL.replace(sampler={"num_samples": samples, "num_constraint_elites": 40, "num_elites": 20})
        result = plan(problem, config, key=jax.random.PRNGKey(0), prior=prior)
        assert result.status in (PlanStatus.SUCCESS, PlanStatus.INFEASIBLE)
        assert np.all(np.isfinite(result.trajectory.x)) and np.all(np.isfinite(result.fallback.x))
    assert LANES[0] < float(problem.y_ub)


def test_missing_weights_fall_back_to_gaussian_with_notice():
    fallback = object()
    with pytest.warns(UserWarning, match="Gaussian"):
        assert prior_for(3, 30.0, None, fallback) is fallback


def test_train_cli_and_errors(data_file, tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["train", "cvae", "--data", str(data_file), "--out", str(out), "--epochs", "2", *CLI_SETTINGS]) == 0
    assert (out / "cvae.ckpt").exists() and json.loads((out / "history.json").read_text())[-1]["epoch"] == 2
    assert main(["train", "cvae", "--data", str(tmp_path / "missing.h5"), "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["plot-prior", "--weights", str(out / "cvae.ckpt"), "--out", str(tmp_path / "prior.png")]) == 0
    assert (tmp_path / "prior.png").stat().st_size > 10_000


def test_mixed_prior_keeps_gaussian_share_around_the_warm_start(trained):
    import dataclasses

    from driveopt.config import PlannerConfig
    from driveopt.sampler import GaussianPrior

    cfg = PlannerConfig()
    gaussian = dataclasses.replace(GaussianPrior.from_config(cfg.sampler, 30.0), speed_std=0.1, lateral_std=0.1, structured_fraction=0.0)
    prior = load_prior(trained[0] / "cvae.ckpt", 30.0, gaussian, 0.25)
    problem = build_problem(load_scene("dense-snapshot"))
    warm = jnp.array([29.0] * 4 + [float(problem.y_lb) + 0.5] * 4)
    proposal = prior.propose(problem, jax.random.PRNGKey(0), 200, warm)
    near = np.all(np.abs(np.asarray(proposal.samples) - np.asarray(warm)) < 0.6, axis=1)
    assert near[150:].all() and near[:150].sum() < 10  # the last quarter is the Gaussian's
    pure = load_prior(trained[0] / "cvae.ckpt").propose(problem, jax.random.PRNGKey(0), 200, warm)
    assert np.all(np.isfinite(pure.cov)) and np.allclose(pure.mean, np.mean(np.asarray(pure.samples), 0), atol=1e-4)


FLOAT_SETTINGS = [("train", f.name) for f in dataclasses.fields(TrainConfig) if f.type == "float"] + [
    ("cvae", f.name) for f in dataclasses.fields(CVAEConfig) if f.type == "float"]


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -1.0])
@pytest.mark.parametrize(("config", "name"), FLOAT_SETTINGS)
def test_non_finite_or_negative_settings_are_refused(config, name, value):
    make = {"train": TrainConfig, "cvae": CVAEConfig}[config]
    with pytest.raises(ConfigError, match=name):
        make(**{name: value})


@pytest.mark.parametrize("bad", [["--lr", "nan"], ["--lr", "inf"], ["--lr", "-0.001"], ["--beta", "nan"], ["--beta", "-1"],
                                 ["--validation", "nan"], ["--validation", "1.5"], ["--seed", "-3"]])
def test_train_cli_refuses_bad_settings_before_writing(data_file, tmp_path, capsys, bad):
    out = tmp_path / "out"
    try:  # refused by the trainer's checks, or (a seed out of range) when the command line is parsed
        status = main(["train", "cvae", "--data", str(data_file), "--out", str(out), "--epochs", "1", *bad])
    except SystemExit as exc:
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith("driveopt: error: ") and err.count("\n") == 1 and bad[1] in err
    assert not out.exists()


def test_train_into_an_existing_file_is_refused(data_file, tmp_path, capsys):
    out = tmp_path / "weights.ckpt"
    out.write_text("keep me")
    assert main(["train", "cvae", "--data", str(data_file), "--out", str(out), "--epochs", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "existing file" in err
    assert out.read_text() == "keep me" and list(tmp_path.iterdir()) == [out]


def test_diverging_training_is_an_error(data_file, tmp_path):
    with pytest.raises(TrainingError, match="diverged"):
        train_cvae(data_file, tmp_path, CFG, dataclasses.replace(TCFG, epochs=2, learning_rate=1e30), progress=False)
    assert not (tmp_path / "cvae.ckpt").exists()


def test_file_order_changes_neither_split_nor_training(tmp_path):
    a = write_synthetic(tmp_path / "a.h5", episodes=3, rows=32, seed=0)
    b = write_synthetic(tmp_path / "b.h5", episodes=3, rows=32, seed=1)
    quick = dataclasses.replace(TCFG, epochs=2, anneal_epochs=1, validation_fraction=0.34)
    ab = train_cvae([a, b], tmp_path / "ab", CFG, quick, progress=False)
    ba = train_cvae([b, a], tmp_path / "ba", CFG, quick, progress=False)
    assert ab["history"] == ba["history"] and ab["rows"] == ba["rows"] == {"train": 4 * 32, "validation": 2 * 32}
    records = [load_checkpoint(tmp_path / out / "last.ckpt", "cvae")[0]["data"] for out in ("ab", "ba")]
    assert records[0] == records[1]
    train_cvae([a, b], tmp_path / "resumed", CFG, quick, progress=False, stop_after=1)
    resumed = train_cvae([b, a], tmp_path / "resumed", CFG, quick, progress=False)  # same episodes, other order: same run
    assert resumed["history"] == ab["history"]


def test_resume_with_another_validation_split_is_refused(data_file, trained, tmp_path):
    def other_split(meta):
        meta["data"]["validation"] = "0123456789abcdef"

    def older(meta):
        meta["data"] = "2a67782b73976205"  # the record of earlier driveopt versions: no split

    for change, reason in ((other_split, "other validation episodes"), (older, "no validation split")):
        out = tmp_path / change.__name__
        out.mkdir()
        with_meta(trained[0] / "last.ckpt", out / "last.ckpt", change)
        with pytest.raises(CheckpointError, match=reason):
            train_cvae(data_file, out, CFG, TCFG, progress=False)


def test_weights_record_their_road_and_refuse_other_lane_counts(trained, tmp_path):
    weights = trained[0] / "cvae.ckpt"
    assert load_checkpoint(weights, "cvae")[0]["lanes"] == [4]  # learned_data's scenario is a four-lane road
    assert isinstance(prior_for(4, 30.0, weights, None), CVAEPrior)
    with pytest.raises(CheckpointError, match="4-lane roads, not this 2-lane road"):
        prior_for(2, 30.0, weights, None)
    older = with_meta(weights, tmp_path / "older.ckpt", lambda meta: meta.pop("lanes"))
    assert isinstance(prior_for(2, 30.0, older, None), CVAEPrior)  # no record: accepted unchecked


def test_recorded_lanes_come_from_the_scenarios(tmp_path):
    two = write_synthetic(tmp_path / "two.h5", episodes=1, rows=4, scenario="two-lane-d2.5")
    four = write_synthetic(tmp_path / "four.h5", episodes=1, rows=4, seed=1)
    data = load_demonstrations([two, four])
    assert road_lanes(data, training_rows(data, 3.0)) == [2, 4]
    unknown = load_demonstrations(write_synthetic(tmp_path / "x.h5", episodes=1, rows=4, scenario="moon-road"))
    with pytest.raises(DatasetError, match="moon-road"):
        road_lanes(unknown, training_rows(unknown, 3.0))


@pytest.mark.parametrize(("lanes", "other"), [(2, 4), (4, 2)])
def test_shipped_weights_refuse_the_other_road(lanes, other, capsys):
    path = shipped_weights(lanes)
    meta, _ = load_checkpoint(path, "cvae")
    assert meta["lanes"] == [lanes]
    _, params, _, _ = load_cvae(path, lanes)
    assert all(np.all(np.isfinite(p)) for p in jax.tree_util.tree_leaves(params))
    with pytest.raises(CheckpointError, match=f"{lanes}-lane roads, not this {other}-lane road"):
        prior_for(other, 30.0, path, None)
    scenario = {2: "two-lane-d1.0", 4: "four-lane-d1.0"}[other]
    assert main(["drive", "--planner", "cvae", "--weights", str(path), "--scenario", scenario, "--duration", "0.2", "--video", ""]) == 2
    error = capsys.readouterr().err.splitlines()[-1]  # after drive's progress bar
    assert error.startswith("driveopt: error: ") and f"{other}-lane road" in error
