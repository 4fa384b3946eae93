"""Tiny, untrained CVAE and PixelCNN (+ VQ-VAE) checkpoints in the shipped format, for the tests of what uses learned
priors (plots, metrics), not of what they learn. Parameters are drawn with numpy into the shapes that the networks'
``init_params`` trace (``jax.eval_shape``: nothing is compiled, so a checkpoint takes a second, not ten). And
:func:`with_meta`: a checkpoint whose header says something else, for the tests of what is refused."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.learned import cvae, cvae_multipliers, pixelcnn, vqvae
from driveopt.learned.checkpoint import save_checkpoint

CVAE_CFG = cvae.CVAEConfig(hidden=(16,))
VQVAE_CFG = vqvae.VQVAEConfig(decoder_hidden=(16,), encoder_channels=(8, 8))
PIXELCNN_CFG = pixelcnn.PixelCNNConfig(channels=8, layers=1, kernel_size=3, condition_hidden=(16,))
MULTIPLIERS_CFG = cvae_multipliers.MultiplierCVAEConfig(cvae=CVAE_CFG, multiplier_hidden=(16,))


def random_params(init, cfg, seed: int):
    """Parameters of ``init(cfg, key)``'s shapes: kernels ~ N(0, 1 / fan_in), LayerNorm scales 1, everything else ~ N(0, 0.1)."""
    rng = np.random.default_rng(seed)
    shapes = jax.eval_shape(lambda key: init(cfg, key), jax.random.PRNGKey(0))

    def draw(path, leaf):
        name = str(getattr(path[-1], "key", path[-1]))
        if name == "scale":
            return jnp.ones(leaf.shape, jnp.float32)
        if name == "kernel":
            fan_in = int(np.prod(leaf.shape[:-1]))
            return jnp.asarray(rng.normal(0.0, fan_in ** -0.5, leaf.shape), jnp.float32)
        return jnp.asarray(rng.normal(0.0, 0.1, leaf.shape), jnp.float32)

    return jax.tree_util.tree_map_with_path(draw, shapes)


def _unit(n: int) -> tuple[jnp.ndarray, jnp.ndarray]:
    return jnp.zeros(n, jnp.float32), jnp.ones(n, jnp.float32)


def tiny_cvae(path: str | Path, lanes: tuple[int, ...] = (4,), seed: int = 0) -> Path:
    """A freshly initialised CVAE with an identity normaliser, recorded as trained for ``lanes``-lane roads."""
    normaliser = cvae.Normaliser(*_unit(cvae.FEATURE_DIM), *_unit(CVAE_CFG.trajectory_features))
    state = {"params": random_params(cvae.init_params, CVAE_CFG, seed), "normaliser": normaliser}
    return save_checkpoint(path, cvae.CHECKPOINT_KIND, state, {"config": CVAE_CFG.to_dict(), "lanes": list(lanes)})


def tiny_pixelcnn(path: str | Path, lanes: tuple[int, ...] = (4,), seed: int = 0) -> Path:
    """A freshly initialised PixelCNN embedding a freshly initialised VQ-VAE (codebook spread over [-1, 1] so that the
    codes decode to different set-points), recorded as trained for ``lanes``-lane roads."""
    params = dict(random_params(vqvae.init_params, VQVAE_CFG, seed))
    params["codebook"] = jnp.asarray(np.random.default_rng(seed).uniform(-1.0, 1.0, params["codebook"].shape), jnp.float32)
    nodes = VQVAE_CFG.basis.num_nodes
    normaliser = vqvae.Normaliser(*_unit(cvae.FEATURE_DIM), jnp.zeros((nodes, 2)), jnp.ones((nodes, 2)))
    state = {"params": random_params(pixelcnn.init_params, PIXELCNN_CFG, seed + 1), "vqvae": {"params": params, "normaliser": normaliser}}
    meta = {"config": PIXELCNN_CFG.to_dict(), "vqvae_config": VQVAE_CFG.to_dict(), "lanes": list(lanes)}
    return save_checkpoint(path, pixelcnn.CHECKPOINT_KIND, state, meta)


def tiny_cvae_multipliers(path: str | Path, lanes: tuple[int, ...] = (4,), seed: int = 0) -> Path:
    """A freshly drawn cvae-multipliers model (its multiplier head not zero, so its multipliers are not) with an
    identity normaliser, recorded as trained for ``lanes``-lane roads."""
    n2 = MULTIPLIERS_CFG.num_coeffs
    normaliser = cvae_multipliers.Normaliser(*_unit(cvae.FEATURE_DIM), *_unit(CVAE_CFG.trajectory_features), *_unit(n2))
    state = {"params": random_params(cvae_multipliers.init_params, MULTIPLIERS_CFG, seed), "normaliser": normaliser}
    return save_checkpoint(path, cvae_multipliers.CHECKPOINT_KIND, state, {"config": MULTIPLIERS_CFG.to_dict(), "lanes": list(lanes)})


def with_meta(path: Path, dest: Path, change: Callable[[dict[str, Any]], None]) -> Path:
    """Copy of the checkpoint ``path`` at ``dest`` whose header meta went through ``change`` (the body is kept)."""
    header, body = path.read_bytes().split(b"\n", 1)
    doc = json.loads(header)
    change(doc["meta"])
    dest.write_bytes(json.dumps(doc).encode() + b"\n" + body)
    return dest
