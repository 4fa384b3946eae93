"""Incremental PixelCNN sampling (``px.sample_codes``): the same draws as re-running the whole network per
position (``px.sample_codes_reference``), logits equal to the full network's on the drawn codes, whatever the chunks
of distinct prefixes it computes them in and however many samples share a prefix, one compilation per configuration
and count, and the observation's condition computed outside the loop."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt.learned import pixelcnn as px
from driveopt.learned.cvae import FEATURE_DIM

CONFIGS = {
    "tiny": px.PixelCNNConfig(channels=16, layers=2, kernel_size=7),  # test_vqvae's PX_CFG
    "default": px.PixelCNNConfig(),  # P2's: 1 A + 5 B layers, 64 channels, kernel 7
    "short-kernel": px.PixelCNNConfig(num_latents=6, codebook_size=5, channels=8, layers=1, kernel_size=3, condition_hidden=(16,)),
    "kernel-1": px.PixelCNNConfig(num_latents=3, channels=8, layers=0, kernel_size=1, condition_hidden=()),  # sees no code
}
NUM = 64
_reference = jax.jit(px.sample_codes_reference, static_argnames=("cfg", "num"))
_full_logits = jax.jit(px.code_logits, static_argnames="cfg")


def _check_draws(params, cfg, feats, key, chunk=px.ROWS_PER_CHUNK):
    """The sampler's codes are the reference's and its logits the full network's on them; returns the codes."""
    codes, logits = px.sample_codes_and_logits(params, cfg, feats, key, NUM, chunk=chunk)
    assert codes.shape == (NUM, cfg.num_latents) and codes.dtype == jnp.int32
    assert logits.shape == (NUM, cfg.num_latents, cfg.codebook_size) and logits.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(codes), np.asarray(_reference(params, cfg, feats, key, NUM)))
    full = _full_logits(params, cfg, codes, jnp.broadcast_to(feats, (NUM, FEATURE_DIM)))
    np.testing.assert_allclose(np.asarray(logits), np.asarray(full), rtol=1e-5, atol=1e-5)
    return np.asarray(codes)


def _distinct(codes, position):
    return len(np.unique(codes[:, :position], axis=0))


@pytest.mark.parametrize("name", CONFIGS)
@pytest.mark.parametrize("chunk", [px.ROWS_PER_CHUNK, 3])  # 3: many chunks, large (4 x 3) and small, the last partly used
@jax.default_matmul_precision("float32")  # two orders of the same products agree to 1e-5 only at full float32 (not TF32)
def test_incremental_sampling_draws_what_the_full_network_draws(name, chunk):
    cfg = CONFIGS[name]
    params = px.init_params(cfg, jax.random.PRNGKey(0))
    for seed in range(3):
        feats = jax.random.normal(jax.random.PRNGKey(100 + seed), (FEATURE_DIM,))
        codes = _check_draws(params, cfg, feats, jax.random.PRNGKey(seed), chunk)
    assert len(np.unique(codes, axis=0)) > NUM // 2  # nearly uniform at initialisation: a real comparison


@jax.default_matmul_precision("float32")
def test_samples_sharing_prefixes_draw_what_the_full_network_draws():
    """A peaked network (scaled logits) gives many samples the same prefix, so each position computes a few distinct
    prefixes that many samples read, and the later positions more of them: the draws are still the reference's."""
    cfg = CONFIGS["tiny"]
    params = px.init_params(cfg, jax.random.PRNGKey(0))
    params = {**params, "out": {"kernel": 16.0 * params["out"]["kernel"], "bias": params["out"]["bias"]}}
    feats = jax.random.normal(jax.random.PRNGKey(7), (FEATURE_DIM,))
    codes = _check_draws(params, cfg, feats, jax.random.PRNGKey(3), chunk=4)
    counts = [_distinct(codes, position) for position in range(1, cfg.num_latents + 1)]
    assert counts[0] < cfg.codebook_size and counts[-1] <= NUM // 2, counts  # shared prefixes: a real test of sharing
    assert counts[-2] > 4 * 4, counts  # and, at the last position, more of them than one large chunk of 4 x 4 holds


def test_distinct_prefixes_are_numpy_unique():
    rng = np.random.default_rng(0)
    rows, codes = rng.integers(0, 5, 50), rng.integers(0, 16, 50)
    distinct, count, index = px._distinct_prefixes(jnp.asarray(rows), jnp.asarray(codes), 16, 64)
    keys = rows * 16 + codes
    unique, inverse = np.unique(keys, return_inverse=True)
    assert int(count) == len(unique)
    np.testing.assert_array_equal(np.asarray(distinct)[:len(unique)], unique)
    np.testing.assert_array_equal(np.asarray(index), inverse.ravel())


def test_sampler_compiles_once_per_configuration_and_count():
    cfg = CONFIGS["tiny"]
    params = px.init_params(cfg, jax.random.PRNGKey(0))
    other = px.init_params(cfg, jax.random.PRNGKey(1))
    codes = px.sample_codes(params, cfg, jnp.zeros(FEATURE_DIM), jax.random.PRNGKey(0), 7)
    before = px.sample_codes._cache_size()
    np.testing.assert_array_equal(codes, px.sample_codes_and_logits(params, cfg, jnp.zeros((1, FEATURE_DIM)), jax.random.PRNGKey(0), 7)[0])
    px.sample_codes(other, cfg, jnp.ones(FEATURE_DIM), jax.random.PRNGKey(1), 7)  # other weights, observation, key
    assert px.sample_codes._cache_size() == before
    px.sample_codes(params, cfg, jnp.zeros(FEATURE_DIM), jax.random.PRNGKey(0), 8)
    assert px.sample_codes._cache_size() == before + 1


def _inner(eqn):
    """The jaxprs an equation calls (jit, scan, custom derivatives ...)."""
    for value in eqn.params.values():
        for item in value if isinstance(value, (tuple, list)) else (value,):
            inner = getattr(item, "jaxpr", item)
            if hasattr(inner, "eqns"):
                yield inner


def _scan_bodies(jaxpr):
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "scan":
            yield from _inner(eqn)
        else:
            for sub in _inner(eqn):
                yield from _scan_bodies(sub)


def _dot_operands(jaxpr):
    """Shapes of the left operands of every matrix product in a jaxpr, nested calls included."""
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            yield eqn.invars[0].aval.shape
        for sub in _inner(eqn):
            yield from _dot_operands(sub)


def test_condition_is_computed_once_outside_the_loop():
    cfg = CONFIGS["tiny"]
    params = px.init_params(cfg, jax.random.PRNGKey(0))
    jaxpr = jax.make_jaxpr(lambda p, f, k: px.sample_codes_and_logits(p, cfg, f, k, NUM))(
        params, jnp.zeros(FEATURE_DIM), jax.random.PRNGKey(0))
    bodies = list(_scan_bodies(jaxpr.jaxpr))
    assert len(bodies) == 1
    shapes = list(_dot_operands(bodies[0]))
    # per mask-B layer the window's and the new column's taps and the 1 x 1; first layer's 1 x 1; head; output; in each
    # of the two chunk loops
    assert len(shapes) == 2 * (3 * cfg.layers + 3)
    rows = min(px.ROWS_PER_CHUNK, NUM)  # per chunk of distinct prefixes: no (1, .) condition work per position
    assert all(shape[0] in (rows, px.LARGE_CHUNKS * rows) for shape in shapes), shapes
