"""Checkpoints are checked for usable values when loaded: a checksum only proves the file is the one written, so
NaN, absurd magnitudes and zero normaliser scales (a trainer that diverged) are refused in one line, as is a header
whose ``meta`` is not an object; the shipped weights load. Network widths are within a memory estimate."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from driveopt.checks import ConfigError
from driveopt.learned import cvae, cvae_multipliers, pixelcnn, vqvae
from driveopt.learned import filter as learned_filter
from driveopt.learned.checkpoint import CheckpointError, load_checkpoint, parameter_shapes, save_checkpoint

WEIGHTS = Path(__file__).resolve().parents[2] / "src" / "driveopt" / "weights"
SHIPPED = sorted(WEIGHTS.glob("*.ckpt"))
LOADERS = {cvae.CHECKPOINT_KIND: cvae.load_cvae, pixelcnn.CHECKPOINT_KIND: pixelcnn.load_vqvae_prior,
           learned_filter.CHECKPOINT_KIND: learned_filter.load_filter, vqvae.CHECKPOINT_KIND: vqvae.load_vqvae,
           cvae_multipliers.CHECKPOINT_KIND: cvae_multipliers.load_model}


def _kind(path: Path) -> str:
    with open(path, "rb") as f:
        return json.loads(f.readline())["kind"]


def test_weights_are_shipped_for_every_learned_kind():
    assert {_kind(path) for path in SHIPPED} == {cvae.CHECKPOINT_KIND, pixelcnn.CHECKPOINT_KIND,
                                                learned_filter.CHECKPOINT_KIND, cvae_multipliers.CHECKPOINT_KIND}


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_every_shipped_checkpoint_loads(path):
    kind = _kind(path)
    loaded = LOADERS[kind](path)
    assert loaded


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_loading_a_checkpoint_again_reuses_its_network_structure_and_gives_the_same_weights(path):
    """A benchmark builds the same planners' priors hundreds of times: the network's structure is traced once."""
    import jax

    load = LOADERS[_kind(path)]
    first = load(path)
    misses = parameter_shapes.cache_info().misses
    again = load(path)
    assert parameter_shapes.cache_info().misses == misses
    for a, b in zip(jax.tree_util.tree_leaves(first), jax.tree_util.tree_leaves(again), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def _shipped(kind: str) -> tuple[dict, dict]:
    """(meta, state) of a shipped checkpoint of ``kind``; the VQ-VAE's is the one a PixelCNN checkpoint embeds."""
    if kind == vqvae.CHECKPOINT_KIND:
        meta, state = load_checkpoint(WEIGHTS / "vqvae-two-lane.ckpt", pixelcnn.CHECKPOINT_KIND)
        return {"config": meta["vqvae_config"], "lanes": meta["lanes"]}, state["vqvae"]
    path = next(p for p in SHIPPED if _kind(p) == kind)
    return load_checkpoint(path, kind)


def _normaliser(kind: str, state: dict) -> dict:
    return state["vqvae"]["normaliser"] if kind == pixelcnn.CHECKPOINT_KIND else state["normaliser"]


def _first_kernel(tree: dict) -> np.ndarray:
    while isinstance(tree, dict):
        tree = tree["kernel"] if "kernel" in tree else tree[min(tree)]
    return tree


def _nan_weight(kind: str, state: dict) -> None:
    _first_kernel(state["params"]).flat[0] = np.nan


def _huge_weight(kind: str, state: dict) -> None:
    _first_kernel(state["params"]).flat[-1] = 1e30


def _infinite_mean(kind: str, state: dict) -> None:
    norm = _normaliser(kind, state)
    norm["mean" if "mean" in norm else "feature_mean"][0] = np.inf


def _zero_std(kind: str, state: dict) -> None:
    norm = _normaliser(kind, state)
    norm["std" if "std" in norm else "trajectory_std"].flat[3] = 0.0


@pytest.mark.parametrize("kind", sorted(LOADERS))
@pytest.mark.parametrize("damage, needle", [(_nan_weight, "NaN or infinite values"), (_huge_weight, "beyond +-1e+06"),
                                            (_infinite_mean, "NaN or infinite values"), (_zero_std, "normaliser scale")])
def test_a_checkpoint_with_unusable_values_is_refused(tmp_path, kind, damage, needle):
    meta, state = _shipped(kind)
    state = copy.deepcopy(state)
    damage(kind, state)
    path = save_checkpoint(tmp_path / "damaged.ckpt", kind, state, meta)  # a valid checksum of bad values
    with pytest.raises(CheckpointError) as info:
        LOADERS[kind](path)
    assert needle in str(info.value) and str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("meta", ["a string", [1, 2], 3, None])
def test_a_header_whose_meta_is_not_an_object_is_refused(tmp_path, meta):
    _, state = _shipped(cvae.CHECKPOINT_KIND)
    path = save_checkpoint(tmp_path / "meta.ckpt", cvae.CHECKPOINT_KIND, state, meta)
    with pytest.raises(CheckpointError, match="'meta' must be an object"):
        cvae.load_cvae(path)


def test_a_header_with_a_huge_number_is_refused(tmp_path):
    meta, state = _shipped(cvae.CHECKPOINT_KIND)
    path = save_checkpoint(tmp_path / "big.ckpt", cvae.CHECKPOINT_KIND, state, {**meta, "epoch": 10**400})
    with pytest.raises(CheckpointError, match="not a driveopt checkpoint"):
        cvae.load_cvae(path)


def test_a_special_file_is_not_read_as_a_checkpoint(tmp_path):
    """A directory here; a device (/dev/zero: endless) or a FIFO (blocks) is refused by the same check before reading."""
    with pytest.raises(CheckpointError, match="not a regular file"):
        cvae.load_cvae(tmp_path)


@pytest.mark.parametrize(
    "make",
    [
        lambda: cvae.CVAEConfig(hidden=(100_000_000,)),
        lambda: cvae.CVAEConfig(latent_dim=10**9),
        lambda: vqvae.VQVAEConfig(codebook_size=10**9),
        lambda: vqvae.VQVAEConfig(decoder_hidden=(10**5, 10**5)),
        lambda: pixelcnn.PixelCNNConfig(channels=100_000),
        lambda: learned_filter.FilterConfig(hidden=(10**6,)),
    ],
)
def test_networks_beyond_the_memory_estimate_are_refused(monkeypatch, make):
    monkeypatch.delenv("DRIVEOPT_ALLOW_LARGE", raising=False)
    with pytest.raises(ConfigError, match=r"parameter count .* GB of float32 weights.*DRIVEOPT_ALLOW_LARGE=1"):
        make()


def test_the_widest_paper_network_is_within_the_estimate():
    assert cvae.CVAEConfig(hidden=(1024, 1024, 1024, 1024, 256)).parameter_count < 10_000_000  # P1's widths
