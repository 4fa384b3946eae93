"""VQ-VAE + PixelCNN prior: multi-modal demonstrations (schema 2, v1 still readable), quantisation,
loss, codebook re-seeding, PixelCNN masking and sampling, training and checkpoints, the planners."""

from __future__ import annotations

import dataclasses
import json
import warnings

import h5py
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from learned_data import SCENARIO, file_fixture, synthetic_rows, write_modes

from driveopt.basis import make_basis
from driveopt.cli import main
from driveopt.config import BasisConfig, QPConfig
from driveopt.data.demonstrations import (
    EPISODE_FIELDS,
    ROW_FIELDS,
    DatasetError,
    DemonstrationWriter,
    describe,
    load_demonstrations,
)
from driveopt.data.modes import SPEED_GAP, lanes_per_row, plan_features, select_modes
from driveopt.data.replay import mode_lanes
from driveopt.experiments.collect import collect
from driveopt.learned import pixelcnn as px
from driveopt.learned import vqvae as vq
from driveopt.learned.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from driveopt.planner import PlanStatus, RowKind, Snapshot, plan
from driveopt.priors.vqvae import VQVAEPrior, load_prior, prior_for
from driveopt.problem import build_problem
from driveopt.qp import make_model, qp_layer
from driveopt.registry import get_optimiser
from driveopt.scene import load_scene
from driveopt.training.cvae import make_batch
from driveopt.training.harness import training_rows
from driveopt.training.pixelcnn import train_pixelcnn
from driveopt.training.vqvae import TrainConfig, mode_batch, mode_examples, train_vqvae

# What the `trained` fixture's commands train (the tests' own calls with these settings reuse its compilations).
VQ_CFG = vq.VQVAEConfig(decoder_hidden=(32, 32))
PX_CFG = px.PixelCNNConfig(channels=16, layers=2, kernel_size=7)
TCFG = TrainConfig(epochs=6, batch_size=64, learning_rate=3e-3)
VQ_ARGS = ["--hidden", "32", "32", "--epochs", "6", "--batch-size", "64", "--lr", "3e-3"]
PX_ARGS = ["--channels", "16", "--layers", "2", "--kernel", "7", "--epochs", "6", "--batch-size", "64", "--lr", "3e-3"]


# ------------------------------------------------------------------------------------------- data


def write_v1(path, episodes: int = 2, rows: int = 16, seed: int = 0):
    """A schema-version-1 file exactly as driveopt wrote it before it stored modes (no mode datasets)."""
    rng = np.random.default_rng(seed)
    shapes = {"observation": (55,), "init_x": (3,), "init_y": (3,), "lane_bounds": (2,), "setpoints": (8,), "coeffs": (22,),
              "trajectory": (100, 2), "status": (), "time": ()}
    episode_dtypes = {"seed": np.int64, "episode": np.int32, "env_seed": np.int64, "collided": np.bool_, "duration": np.float32,
                      "first_row": np.int64, "num_rows": np.int64}
    with h5py.File(path, "w") as f:
        f.attrs["format"], f.attrs["schema_version"], f.attrs["expert"] = "driveopt-demonstrations", 1, "synthetic"
        for name in ROW_FIELDS:
            f.create_dataset(name, shape=(0, *shapes[name]), maxshape=(None, *shapes[name]),
                             dtype=np.int8 if name == "status" else np.float32, chunks=(256, *shapes[name]))
        f.create_dataset("episode", shape=(0,), maxshape=(None,), dtype=np.int32, chunks=(256,))
        group = f.create_group("episodes")
        for name in EPISODE_FIELDS:
            dtype = h5py.string_dtype() if name == "scenario" else episode_dtypes[name]
            group.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(64,))
        for e in range(episodes):
            data, start = synthetic_rows(rng, rows), e * rows
            for name in (*ROW_FIELDS, "episode"):
                f[name].resize(start + rows, axis=0)
                f[name][start:] = data[name] if name != "episode" else np.full(rows, e, np.int32)
            entry = {"scenario": SCENARIO, "seed": seed, "episode": e, "env_seed": e, "collided": False,
                     "duration": rows / 10.0, "first_row": start, "num_rows": rows}
            for name in EPISODE_FIELDS:
                group[name].resize(e + 1, axis=0)
                group[name][e] = entry[name]
    return path


mode_file = file_fixture(write_modes, "modes.h5")


def test_select_modes_keeps_distinct_feasible_samples_lowest_cost_first():
    basis = make_basis(BasisConfig())
    model = make_model(BasisConfig(), QPConfig())
    problem = build_problem(load_scene("dense-snapshot"))  # 4 lanes centred at 0, 4, 8, 12; ego in lane 1
    init_x, init_y = np.asarray(problem.init_x)[None], np.asarray(problem.init_y)[None]
    plans = [(10.0, 4.0), (10.5, 4.0), (13.0, 4.0), (10.0, 8.0), (10.0, 0.0), (20.0, 8.0), (10.0, 8.0)]
    sp = np.array([[v] * 4 + [y] * 4 for v, y in plans], np.float32)
    coeffs = np.asarray(qp_layer(model, QPConfig(), sp, np.repeat(init_x, len(sp), 0), np.repeat(init_y, len(sp), 0))[0])
    cost = np.array([1.0, 0.5, 3.0, 2.0, 9.0, 4.0, 0.1], np.float32)
    residual = np.array([0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.5], np.float32)  # the cheapest plan is infeasible
    kind = np.array([RowKind.SAMPLE] * 4 + [RowKind.COMFORTABLE_STOP] + [RowKind.SAMPLE] * 2)
    snapshot = Snapshot(sp, coeffs, coeffs, residual, np.arange(3), kind, cost)
    modes = select_modes([snapshot], problem, basis, tolerance=0.05, max_modes=8)
    assert modes.mask.tolist() == [True] * 4 + [False] * 4
    # 10.5 m/s in lane 1 first (cost 0.5); 10 m/s in lane 1 is not distinct from it; lane 2; 13 m/s in lane 1; 20 m/s in lane 2
    np.testing.assert_allclose(modes.cost[:4], [0.5, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(modes.setpoints[:4], sp[[1, 3, 2, 5]])
    np.testing.assert_array_equal(modes.coeffs[4:], 0.0)
    lanes, speeds = plan_features(modes.coeffs[:4], basis, 0.0, 4.0, 4)
    assert lanes.tolist() == [1, 2, 1, 2]
    assert lanes_per_row(modes.coeffs[None], modes.mask[None], basis, [0.0], [4.0], [4]).tolist() == [2]
    assert lanes_per_row(modes.coeffs[None], np.zeros((1, 8), bool), basis, [0.0], [4.0], [4]).tolist() == [0]
    for i in range(4):
        for j in range(i):
            assert lanes[i] != lanes[j] or np.max(np.abs(speeds[i] - speeds[j])) > SPEED_GAP
    assert select_modes([snapshot], problem, basis, 0.05, max_modes=2).mask.tolist() == [True, True]
    assert not select_modes([snapshot], problem, basis, tolerance=-1.0, max_modes=3).mask.any()
    # several batches (collect: the first and the final one): a plan seen in both counts once, and a feasible plan
    # that only the other batch holds (here 10 m/s to lane 0, the comfortable stop's row above) is a mode of its own
    twice = select_modes([snapshot, snapshot], problem, basis, tolerance=0.05, max_modes=8)
    np.testing.assert_array_equal(twice.setpoints, modes.setpoints)
    other = snapshot._replace(kind=np.full(len(kind), RowKind.SAMPLE), residual=np.where(kind == RowKind.SAMPLE, 1.0, 0.0))
    both = select_modes([snapshot, other], problem, basis, tolerance=0.05, max_modes=8)
    assert both.mask.sum() == 5 and both.cost[4] == 9.0 and np.array_equal(both.setpoints[4], sp[4])


def test_collect_writes_schema_2_modes(tmp_path, capsys):
    out = tmp_path / "demo.h5"
    summary = collect(out, ["two-lane-d1.0"], episodes=1, seed=3, samples=40, iterations=1, duration=0.3, workers=1,
                      modes=3, progress=False)
    data = load_demonstrations(out)
    assert data.attrs["schema_version"] == 2 and data.attrs["modes"] == 3 and len(data) == 3
    modes = data.modes
    assert modes.setpoints.shape == (3, 3, 8) and modes.coeffs.shape == (3, 3, 22) and modes.mask.dtype == bool
    counts = modes.counts()
    assert summary["modes_per_row"] == {str(k): int(np.sum(counts == k)) for k in range(int(counts.max()) + 1)}
    assert describe(data)["modes_per_row"] == summary["modes_per_row"]
    assert counts.max() >= 1  # light traffic: feasible samples in the final batch
    basis = make_basis(BasisConfig())
    for row in range(len(data)):
        valid = modes.mask[row]
        assert np.all(valid[:counts[row]]) and not np.any(valid[counts[row]:])  # real modes first, then padding
        assert np.all(np.diff(modes.cost[row, valid]) >= 0) and np.all(modes.residual[row, valid] <= 0.05)
        np.testing.assert_array_equal(modes.coeffs[row, ~valid], 0.0)
        c = modes.coeffs[row, valid]
        np.testing.assert_allclose(c[:, :11] @ basis.W[0], 0.0, atol=1e-3)  # each mode starts at the ego
        np.testing.assert_allclose(c[:, 11:] @ basis.W[0], data.init_y[row, 0], atol=1e-3)
        end_lanes = np.clip(np.round(c[:, 11:] @ basis.W[-1] / 4.0), 0, 1)  # two lanes centred at 0 and 4 m
        assert mode_lanes(data)[row] == len(set(end_lanes.tolist()))
    with pytest.raises(DatasetError, match="3 modes per row, not 8"):
        DemonstrationWriter(out, {}, 100, 22, 55)


def test_version_1_files_stay_readable_for_the_cvae(tmp_path):
    old = write_v1(tmp_path / "v1.h5")
    data = load_demonstrations(old)
    assert data.modes is None and len(data) == 32 and describe(data)["modes_per_row"] is None
    with pytest.raises(DatasetError, match="no modes"):
        mode_lanes(data)
    batch = make_batch(data, training_rows(data, 3.0))
    assert batch.trajectory.shape == (32, 100, 2)
    np.testing.assert_array_equal(batch.observation, data.observation)
    # The same rows written by this driveopt (schema 2, no modes) are the same episodes: fingerprints agree.
    rng = np.random.default_rng(0)
    writer = DemonstrationWriter(tmp_path / "v2.h5", {"expert": "synthetic"}, 100, 22, 55)
    for e in range(2):
        writer.append_episode({"scenario": SCENARIO, "seed": 0, "episode": e, "env_seed": e, "collided": False, "duration": 1.6},
                              synthetic_rows(rng, 16))
    new = load_demonstrations(tmp_path / "v2.h5")
    assert new.fingerprint() == data.fingerprint() and not new.modes.mask.any()
    mixed = load_demonstrations([old, tmp_path / "v2.h5"])
    assert mixed.modes.mask.shape == (64, 8) and not mixed.modes.mask[:32].any()
    with pytest.raises(DatasetError, match="schema version 1"):
        DemonstrationWriter(old, {"expert": "synthetic"}, 100, 22, 55)  # appending to v1 is refused
    with pytest.raises(DatasetError, match="no modes"):
        train_vqvae(old, tmp_path / "vq", VQ_CFG, TCFG, progress=False)


def test_demonstrations_table_counts_modes_and_lanes_and_refuses_bad_files(mode_file, tmp_path, capsys):
    from benchmarks.studies import demonstrations_table as table

    demo = tmp_path / "demo.h5"
    collect(demo, ["two-lane-d1.0"], episodes=1, seed=3, samples=40, iterations=1, duration=0.3, workers=1, modes=3,
            progress=False)
    assert table.main([str(demo), "--json", str(tmp_path / "t.json")]) == 0
    summary = json.loads((tmp_path / "t.json").read_text())[str(demo)]
    data = load_demonstrations(demo)
    assert summary["modes_per_row"] == describe(data)["modes_per_row"]
    lanes = mode_lanes(data)
    assert summary["mode_lanes_per_row"] == {str(k): int(np.sum(lanes == k)) for k in range(int(lanes.max()) + 1)}
    assert sum(summary["mode_lanes_per_row"].values()) == len(data) and summary["mode_lanes_per_row"]["0"] == int(np.sum(data.modes.counts() == 0))
    assert table.main([str(write_v1(tmp_path / "v1.h5"))]) == 2
    assert "no modes" in capsys.readouterr().err
    assert table.main([str(mode_file)]) == 2  # synthetic rows whose lane bounds fit no road
    assert "fit no whole number" in capsys.readouterr().err


def test_examples_are_every_real_mode_as_a_trajectory(mode_file):
    data = load_demonstrations(mode_file)
    rows, modes = mode_examples(data, np.arange(10))
    assert len(rows) == int(data.modes.counts()[:10].sum()) and np.all(data.modes.mask[rows, modes])
    batch = mode_batch(data, rows, modes, BasisConfig())
    _, positions = qp_layer(make_model(BasisConfig(), QPConfig()), QPConfig(), data.modes.setpoints[rows, modes],
                            data.init_x[rows], data.init_y[rows])
    np.testing.assert_allclose(batch.trajectory, np.asarray(positions), atol=1e-3)
    np.testing.assert_array_equal(batch.observation, data.observation[rows])


# ------------------------------------------------------------------------------------------ VQ-VAE


def test_quantise_picks_the_nearest_code_and_passes_gradients_straight_through():
    codebook = jnp.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    z = jnp.array([[[0.1, -0.2], [0.8, 0.3], [0.2, 1.4], [0.6, 0.0]]])  # (1, 4, 2)
    st, z_q, idx = vq.quantise(z, codebook)
    assert idx.tolist() == [[0, 1, 2, 1]]
    np.testing.assert_array_equal(st, z_q)
    np.testing.assert_array_equal(z_q, codebook[idx])
    weights = jnp.arange(8.0).reshape(1, 4, 2)
    grad = jax.grad(lambda z: jnp.sum(weights * vq.quantise(z, codebook)[0]))(z)
    np.testing.assert_array_equal(grad, weights)  # identity backward
    assert float(jnp.sum(jnp.abs(jax.grad(lambda c: jnp.sum(vq.quantise(z, c)[0]))(codebook)))) == 0.0


def test_reseeding_changes_only_dead_codes():
    codebook = jnp.arange(32.0).reshape(16, 2)
    counts = jnp.array([3, 0, 1, 0] + [2] * 10 + [0, 5])
    candidates = -1.0 - jnp.arange(40.0).reshape(20, 2)
    new = np.asarray(vq.reseed_dead_codes(codebook, counts, candidates, jax.random.PRNGKey(0)))
    dead = np.asarray(counts) == 0
    np.testing.assert_array_equal(new[~dead], np.asarray(codebook)[~dead])
    assert all(any(np.array_equal(row, c) for c in np.asarray(candidates)) for row in new[dead])
    assert len({tuple(r) for r in new[dead]}) == int(dead.sum())  # distinct encoder outputs
    assert vq.perplexity([4, 4, 4, 4]) == pytest.approx(4.0) and vq.perplexity([7, 0, 0]) == pytest.approx(1.0)


# ---------------------------------------------------------------------------------------- PixelCNN


def test_pixelcnn_logits_depend_only_on_earlier_codes():
    params = px.init_params(PX_CFG, jax.random.PRNGKey(0))
    base = jax.random.randint(jax.random.PRNGKey(1), (10,), 0, 16)
    # Sequence i redraws the codes at positions >= i; sequence 10 + i changes only the code at i - 1.
    later = jnp.stack([jnp.where(jnp.arange(10) >= i, (base + 1 + i) % 16, base) for i in range(10)])
    earlier = jnp.stack([base.at[i - 1].set((base[i - 1] + 7) % 16) for i in range(1, 10)])
    codes = jnp.concatenate([base[None], later, earlier])
    feats = jnp.broadcast_to(jax.random.normal(jax.random.PRNGKey(2), (vq.FEATURE_DIM,)), (len(codes), vq.FEATURE_DIM))
    logits = np.asarray(jax.jit(px.code_logits, static_argnames="cfg")(params, PX_CFG, codes, feats))
    for i in range(10):  # logits at 0..i never see codes at i or later
        np.testing.assert_array_equal(logits[1 + i, :i + 1], logits[0, :i + 1])
        assert not np.allclose(logits[1 + i, i + 1:], logits[0, i + 1:]) or i == 9
    for i in range(1, 10):  # ... and the logits at i see the code at i - 1 (the reach of 1 A + 2 B layers of width 7 is 9)
        assert not np.allclose(logits[10 + i, i], logits[0, i])
        np.testing.assert_array_equal(logits[10 + i, :i], logits[0, :i])


def test_sampling_returns_valid_indices_of_any_count():
    params = px.init_params(PX_CFG, jax.random.PRNGKey(0))
    feats = jnp.zeros(vq.FEATURE_DIM)
    sample = jax.jit(px.sample_codes, static_argnames=("cfg", "num"))
    for num in (1, 300):
        codes = np.asarray(sample(params, PX_CFG, feats, jax.random.PRNGKey(num), num))
        assert codes.shape == (num, 10) and codes.dtype == np.int32
        assert codes.min() >= 0 and codes.max() < 16
    assert len(np.unique(codes)) > 8  # an untrained model draws from nearly uniform logits
    again = np.asarray(sample(params, PX_CFG, feats, jax.random.PRNGKey(300), 300))
    np.testing.assert_array_equal(codes, again)


# --------------------------------------------------------------------------- training and checkpoints


@pytest.fixture(scope="module")
def trained(mode_file, tmp_path_factory):
    """``driveopt train vqvae`` then ``driveopt train pixelcnn`` on the synthetic modes: (root, VQ-VAE history, PixelCNN history)."""
    root = tmp_path_factory.mktemp("vq")
    assert main(["train", "vqvae", "--data", str(mode_file), "--out", str(root / "vq"), *VQ_ARGS]) == 0
    assert main(["train", "pixelcnn", "--data", str(mode_file), "--vqvae", str(root / "vq" / "vqvae.ckpt"),
                 "--out", str(root / "px"), *PX_ARGS]) == 0
    histories = [json.loads((root / name / "history.json").read_text()) for name in ("vq", "px")]
    return root, *histories


def test_vqvae_loss_falls_on_a_tiny_dataset(trained):
    _, history, _ = trained
    steps = 5  # 3 training episodes x 48 rows x 2.5 modes / 64 per step
    assert len(history) * steps >= 30
    assert history[-1]["train_loss"] < 0.5 * history[0]["train_loss"], (history[0]["train_loss"], history[-1]["train_loss"])
    assert history[-1]["train_reconstruction"] < 0.5 * history[0]["train_reconstruction"]


def test_training_records_codebook_usage_and_writes_weights(trained, capsys):
    root, history, px_history = trained
    meta = load_checkpoint(root / "vq" / "vqvae.ckpt", "vqvae")[0]
    assert meta["rows"]["train_modes"] > meta["rows"]["train"] and meta["lanes"] == [4]
    for record in history:
        assert 1.0 <= record["train_perplexity"] <= 16.0 and 0 <= record["train_dead_codes"] < 16
        assert np.isfinite(record["val_loss"]) and "val_perplexity" in record and "reseeded" in record
    assert px_history[-1]["train_loss"] < px_history[0]["train_loss"] and "val_accuracy" in px_history[-1]
    px_meta = load_checkpoint(root / "px" / "pixelcnn.ckpt", "pixelcnn")[0]
    assert px_meta["codes_used"]["train"] >= 2 and px_meta["vqvae_config"] == json.loads(json.dumps(VQ_CFG.to_dict()))


# A prior is a pytree handed through jit as solve() takes it: weights as leaves, configurations static.
_propose = jax.jit(lambda prior, problem, key: prior.propose(problem, key, 100))


def test_checkpoint_round_trip_gives_identical_samples(trained, tmp_path):
    weights = trained[0] / "px" / "pixelcnn.ckpt"
    problem = build_problem(load_scene("dense-snapshot"))
    a = _propose(load_prior(weights), problem, jax.random.PRNGKey(5))
    copy = tmp_path / "copy.ckpt"
    copy.write_bytes(weights.read_bytes())
    b = _propose(load_prior(copy), problem, jax.random.PRNGKey(5))
    np.testing.assert_array_equal(np.asarray(a.samples), np.asarray(b.samples))
    samples = np.asarray(a.samples)
    assert np.all(np.isfinite(samples)) and np.all((samples[:, :4] >= 0) & (samples[:, :4] <= 30.0))
    assert np.all((samples[:, 4:] >= float(problem.y_lb)) & (samples[:, 4:] <= float(problem.y_ub)))


@pytest.mark.parametrize("damage", ["truncate", "flip", "header"])
def test_corrupted_or_mismatched_checkpoints_are_refused(trained, tmp_path, damage):
    raw = (trained[0] / "px" / "pixelcnn.ckpt").read_bytes()
    bad = {"truncate": raw[: len(raw) // 2], "flip": raw[:-10] + bytes(b ^ 0xFF for b in raw[-10:]), "header": b"junk\n" + raw}[damage]
    (tmp_path / "bad.ckpt").write_bytes(bad)
    with pytest.raises(CheckpointError):
        load_prior(tmp_path / "bad.ckpt")
    with pytest.raises(CheckpointError, match="'vqvae' model, expected 'pixelcnn'"):
        load_prior(trained[0] / "vq" / "vqvae.ckpt")
    with pytest.raises(CheckpointError, match="4-lane roads, not this 2-lane road"):
        prior_for(2, 30.0, trained[0] / "px" / "pixelcnn.ckpt", None)


def test_training_resumes_and_refuses_other_data_or_vqvae(mode_file, trained, tmp_path):
    root = trained[0]
    train_vqvae(mode_file, tmp_path / "vq", VQ_CFG, TCFG, progress=False, stop_after=1)
    resumed = train_vqvae(mode_file, tmp_path / "vq", VQ_CFG, TCFG, progress=False)
    assert [r["train_loss"] for r in resumed["history"]] == pytest.approx([r["train_loss"] for r in trained[1]], rel=1e-4)
    other = write_modes(tmp_path / "other.h5", episodes=3, seed=9)
    with pytest.raises(CheckpointError, match="other demonstrations"):
        train_vqvae(other, root / "vq", VQ_CFG, TCFG, progress=False)
    meta, state = load_checkpoint(root / "vq" / "vqvae.ckpt", "vqvae")
    state["params"]["codebook"] = np.asarray(state["params"]["codebook"]) + 0.5
    save_checkpoint(tmp_path / "moved.ckpt", "vqvae", state, meta)  # another VQ-VAE: other codes
    with pytest.raises(CheckpointError, match="another VQ-VAE"):  # the PixelCNN of root/px learned root/vq's codes
        train_pixelcnn(mode_file, tmp_path / "moved.ckpt", root / "px", PX_CFG, dataclasses.replace(TCFG, epochs=4), progress=False)


def test_train_command_errors_are_one_line_and_write_nothing(mode_file, trained, tmp_path, capsys):
    vq_out, px_out = trained[0] / "vq", trained[0] / "px"
    v1 = write_v1(tmp_path / "v1.h5")
    for bad in (["train", "vqvae", "--data", str(mode_file), "--out", str(tmp_path / "x"), "--lr", "nan"],
                ["train", "vqvae", "--data", str(mode_file), "--out", str(tmp_path / "x"), "--codes", "1"],
                ["train", "pixelcnn", "--data", str(mode_file), "--vqvae", str(px_out / "pixelcnn.ckpt"), "--out", str(tmp_path / "x")],
                ["train", "pixelcnn", "--data", str(mode_file), "--vqvae", str(vq_out / "vqvae.ckpt"), "--out", str(tmp_path / "x"),
                 "--kernel", "4"],
                ["train", "vqvae", "--data", str(v1), "--out", str(tmp_path / "x")]):
        assert main(bad) == 2
        err = capsys.readouterr().err
        assert err.startswith("driveopt: error: ") and err.count("\n") == 1
    assert not (tmp_path / "x").exists()


# ---------------------------------------------------------------------------------------- planners


def test_vqvae_planners_without_weights_warn_and_plan():
    problem = build_problem(load_scene("static-blockage"))
    for name in ("vqvae", "vqvae-cem"):
        spec = get_optimiser(name)
        with pytest.warns(UserWarning, match="no VQ-VAE weights shipped for 3-lane roads: using the Gaussian start"):
            prior = spec.prior(3)
        assert not isinstance(prior, VQVAEPrior)
    spec = get_optimiser("vqvae")
    assert spec.config.sampler.num_iterations == 1 and spec.config.sampler.num_samples == 1000
    assert spec.config.projection.barrier  # its iterations: tests/core/test_registry.py
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fallback = spec.prior(3)  # the Gaussian start
    config = spec.config.with_samples(100)
    result = plan(problem, config, key=jax.random.PRNGKey(0), prior=fallback)
    assert result.status in (PlanStatus.SUCCESS, PlanStatus.INFEASIBLE) and result.history.best_score.shape == (1,)
    assert np.all(np.isfinite(result.trajectory.x)) and np.all(np.isfinite(result.fallback.x))


@pytest.mark.parametrize("lanes, problem_name", [(4, "slow-leader-four-lane"), (2, None)])
def test_shipped_vqvae_weights_load_by_default_and_plan_feasibly(lanes, problem_name):
    spec = get_optimiser("vqvae")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no fallback notice: weights ship for two- and four-lane roads
        prior = spec.prior(lanes)
    assert isinstance(prior, VQVAEPrior)
    if problem_name is None:
        return
    problem = build_problem(load_scene(problem_name))
    result = plan(problem, spec.config.with_samples(200), key=jax.random.PRNGKey(0), prior=prior)
    assert result.status == PlanStatus.SUCCESS and np.all(np.isfinite(result.trajectory.x))


def test_vqvae_prior_in_the_planner(trained):
    weights = str(trained[0] / "px" / "pixelcnn.ckpt")
    problem = build_problem(load_scene("static-blockage"))
    spec = get_optimiser("vqvae").with_weights(weights)
    prior = spec.prior(4)
    assert isinstance(prior, VQVAEPrior)
    proposal = _propose(prior, problem, jax.random.PRNGKey(0))
    samples = np.asarray(proposal.samples)
    assert samples.shape == (100, 8) and np.all(np.isfinite(samples)) and np.all(np.isfinite(proposal.cov))
    assert np.all(samples[:, 4:] >= float(problem.y_lb)) and np.all(samples[:, 4:] <= float(problem.y_ub))
    np.testing.assert_allclose(proposal.mean, samples.mean(0), atol=1e-4)
    with pytest.raises(CheckpointError, match="4-lane roads, not this 3-lane road"):
        spec.prior(3)
