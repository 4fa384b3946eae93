"""Conditional PixelCNN over the VQ-VAE's code indices (P2 §III-B, Fig. 4; van den Oord et al. 2016).

    observation o -> standardised features (the VQ-VAE's) -> MLP -> condition c
    codes h (L,) -> one-hot -> gated masked 1-D convolution, mask A (position i sees codes < i)
                 -> ``layers`` gated masked convolutions, mask B (sees <= i, residual)
                 -> 1 x 1 layers -> logits (L, K_c)

A gated layer is ``tanh(W_f * x + V_f c) * sigmoid(W_g * x + V_g c)`` followed by a 1 x 1
projection. Only the first layer sees the codes themselves and it sees strictly earlier positions,
so the logits at position i depend on codes 0..i-1 and on the observation only (tested with
gradients). A learned position embedding is added after the first layer. Training: cross-entropy
against the codes the frozen VQ-VAE encoder assigns to the expert's modes. Sampling
(:func:`sample_codes`): position by position, any number of sequences at once for one observation,
computing at step i only each layer's output at position i from the cached outputs at earlier
positions, once per distinct prefix of codes (the network's logits up to float rounding:
:func:`sample_codes_reference` re-runs it whole per position).

P2: 1 mask-A + 5 mask-B layers, 64 channels, kernel 7 (the defaults).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from driveopt.checks import ConfigError, check_count, check_parameters, dense_parameters
from driveopt.chunks import capacity, over_chunks
from driveopt.learned.checkpoint import CheckpointError, check_scales, header_config, load_checkpoint, parameter_shapes, restore
from driveopt.learned.cvae import FEATURE_DIM, MLP, normaliser_scales
from driveopt.learned.vqvae import Normaliser, VQVAEConfig, empty_state

CHECKPOINT_KIND = "pixelcnn"


@dataclasses.dataclass(frozen=True)
class PixelCNNConfig:
    num_latents: int = 10  # [-] L: sequence length (the VQ-VAE's)
    codebook_size: int = 16  # [-] K_c: classes per position (the VQ-VAE's)
    channels: int = 64  # [-] (P2: 64)
    layers: int = 5  # [-] mask-B layers after the mask-A one (P2: 5)
    kernel_size: int = 7  # [-] odd (P2: 7)
    condition_hidden: tuple[int, ...] = (256,)  # [-] widths of the observation encoder MLP

    def __post_init__(self):
        for name in ("num_latents", "channels", "kernel_size"):
            check_count(f"PixelCNNConfig.{name}", getattr(self, name))
        check_count("PixelCNNConfig.codebook_size", self.codebook_size, 2)
        check_count("PixelCNNConfig.layers", self.layers, 0)
        if self.kernel_size % 2 != 1:
            raise ConfigError(f"PixelCNNConfig.kernel_size must be odd, got {self.kernel_size}")
        for width in self.condition_hidden:
            check_count("PixelCNNConfig.condition_hidden widths", width)
        check_parameters("PixelCNNConfig", self.parameter_count)

    @property
    def parameter_count(self) -> int:
        """[-] weights of the condition MLP, the gated layers, the position embedding and the head: what the widths
        cost in memory."""
        c, k = self.channels, self.kernel_size

        def gated(inputs: int) -> int:  # masked convolution to 2c, condition to 2c, gate output to c
            return k * inputs * 2 * c + 2 * c + dense_parameters([c, 2 * c]) + dense_parameters([c, c])

        condition = dense_parameters([FEATURE_DIM, *self.condition_hidden, c])
        head = dense_parameters([c, c, self.codebook_size])
        return condition + gated(self.codebook_size) + self.layers * gated(c) + self.num_latents * c + head

    @classmethod
    def for_vqvae(cls, vq: VQVAEConfig, **fields: Any) -> "PixelCNNConfig":
        return cls(num_latents=vq.num_latents, codebook_size=vq.codebook_size, **fields)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "PixelCNNConfig":
        data = dict(data)
        if "condition_hidden" in data:
            data["condition_hidden"] = tuple(int(w) for w in data["condition_hidden"])
        return cls(**data)


def causal_mask(kernel_size: int, mask_type: str) -> jnp.ndarray:
    """(kernel_size,) 1 where a tap may be used: offsets < 0 (mask A) or <= 0 (mask B) from the centre."""
    offsets = jnp.arange(kernel_size) - kernel_size // 2
    return (offsets < 0 if mask_type == "A" else offsets <= 0).astype(jnp.float32)


class MaskedConv1D(nn.Module):
    """1-D convolution (same length) whose taps at and after the output position (A) or after it (B) are zero."""

    features: int
    kernel_size: int
    mask_type: str  # "A" or "B"

    @nn.compact
    def __call__(self, x):  # (B, L, C_in) -> (B, L, features)
        k = self.kernel_size
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (k, x.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        kernel = kernel * causal_mask(k, self.mask_type)[:, None, None]
        y = jax.lax.conv_general_dilated(x, kernel, window_strides=(1,), padding=[(k // 2, k // 2)],
                                         dimension_numbers=("NWC", "WIO", "NWC"))
        return y + bias


class GatedLayer(nn.Module):
    channels: int
    kernel_size: int
    mask_type: str
    residual: bool

    @nn.compact
    def __call__(self, x, cond):  # x (B, L, C), cond (B or 1, H)
        h = MaskedConv1D(2 * self.channels, self.kernel_size, self.mask_type)(x)
        h = h + nn.Dense(2 * self.channels)(cond)[:, None, :]
        a, b = jnp.split(h, 2, axis=-1)
        out = nn.Dense(self.channels)(jnp.tanh(a) * jax.nn.sigmoid(b))
        return x + out if self.residual else out


class PixelCNN(nn.Module):
    cfg: PixelCNNConfig

    def setup(self):
        cfg = self.cfg
        self.condition_net = MLP(cfg.condition_hidden, cfg.channels)
        self.first = GatedLayer(cfg.channels, cfg.kernel_size, "A", residual=False)  # never sees code i itself
        self.rest = [GatedLayer(cfg.channels, cfg.kernel_size, "B", residual=True) for _ in range(cfg.layers)]
        self.position = self.param("position", nn.initializers.normal(0.02), (cfg.num_latents, cfg.channels))
        self.head = nn.Dense(cfg.channels)
        self.out = nn.Dense(cfg.codebook_size)

    def condition(self, feats):  # (B, FEATURE_DIM) -> (B, channels)
        return self.condition_net(feats)

    def logits(self, onehot, cond):  # (B, L, K_c) float, (B or 1, channels) -> (B, L, K_c)
        x = self.first(onehot, cond) + self.position
        for layer in self.rest:
            x = layer(x, cond)
        return self.out(nn.relu(self.head(nn.relu(x))))

    def __call__(self, onehot, feats):
        return self.logits(onehot, self.condition(feats))


@functools.partial(jax.jit, static_argnums=0)  # one compilation per configuration, not one per operation
def init_params(cfg: PixelCNNConfig, key: jax.Array) -> dict[str, Any]:
    onehot = jnp.zeros((1, cfg.num_latents, cfg.codebook_size))
    return PixelCNN(cfg).init(key, onehot, jnp.zeros((1, FEATURE_DIM)))["params"]


def logits_from_onehot(params, cfg: PixelCNNConfig, onehot: jnp.ndarray, feats: jnp.ndarray) -> jnp.ndarray:
    """(B, L, K_c) logits from one-hot codes (B, L, K_c) (any real values: differentiable) and features (B, F)."""
    return PixelCNN(cfg).apply({"params": params}, onehot, feats)


def code_logits(params, cfg: PixelCNNConfig, codes: jnp.ndarray, feats: jnp.ndarray) -> jnp.ndarray:
    """(B, L, K_c) logits of p(h_i | h_<i, o) for code indices (B, L) and standardised features (B, F)."""
    return logits_from_onehot(params, cfg, jax.nn.one_hot(codes, cfg.codebook_size), feats)


def loss(params, cfg: PixelCNNConfig, codes: jnp.ndarray, feats: jnp.ndarray):
    """(mean cross-entropy [nats per code], {"cross_entropy", "accuracy"}) of the codes (B, L) given the features."""
    logits = code_logits(params, cfg, codes, feats)
    ce = jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, codes))
    accuracy = jnp.mean(jnp.argmax(logits, -1) == codes)
    return ce, {"cross_entropy": ce, "accuracy": accuracy}


def _dense(p, x):  # nn.Dense's parameters {"kernel" (in, out), "bias" (out,)} applied to x (..., in)
    return x @ p["kernel"] + p["bias"]


def _gated_column(p, pre, bias):
    """A GatedLayer's output at one position, (B, C) (1 x 1 projection ``p["Dense_1"]``, no residual), from its
    masked convolution's sum over taps ``pre`` (B, 2C) and the rest of the pre-activation ``bias`` (1, 2C):
    convolution bias plus condition projection, the same at every position."""
    a, b = jnp.split(pre + bias, 2, axis=-1)
    return _dense(p["Dense_1"], jnp.tanh(a) * jax.nn.sigmoid(b))


ROWS_PER_CHUNK = 64  # [-] prefixes the sampler computes together, in one pass of its inner loop
LARGE_CHUNKS = 4  # [-] while more are left, it computes this many chunks' prefixes in one pass


def _distinct_prefixes(rows: jnp.ndarray, codes: jnp.ndarray, codebook_size: int, held: int):
    """The distinct prefixes among the samples, each known by its (prefix without its last code, that code) pair as
    (row among the previous position's prefixes, code index) (num,) each: (their keys ``row * K_c + code``,
    ascending and padded with 0 to ``held``; how many there are; each sample's index among them (num,))."""
    keys = rows * codebook_size + codes
    present = jnp.zeros(held * codebook_size, jnp.int32).at[keys].set(1)
    index = jnp.cumsum(present) - 1
    (distinct,) = jnp.nonzero(present, size=held, fill_value=0)
    return distinct.astype(jnp.int32), index[-1] + 1, index[keys]


@functools.partial(jax.jit, static_argnames=("cfg", "num", "chunk"))  # one compilation per (configuration, count)
def sample_codes_and_logits(params, cfg: PixelCNNConfig, feats: jnp.ndarray, key: jax.Array, num: int,
                            chunk: int = ROWS_PER_CHUNK):
    """(codes (num, L) int32, logits (num, L, K_c) float32) drawn autoregressively for one observation's
    features (F,) or (1, F); logits[:, i] are those code i was drawn from (= :func:`code_logits` of the codes).

    Incremental: with kernel k, the logits at position i need each mask-B layer's input only at positions
    i - k//2 .. i, and the mask-A layer the codes at i - k//2 .. i - 1; none of them changes once computed.
    So step i (one ``lax.scan`` over the L positions) computes one column per layer from a window of the last
    k//2 columns of the layer below (zeros before position 0, as the convolution's padding): about 1/L of the
    work of re-running the network over all positions per step (:func:`sample_codes_reference`). The one-hot
    mask-A convolution is a row gather from its kernel; the condition MLP and its projections into each layer
    run once, outside the loop.

    Once per distinct prefix: the logits at position i depend on the codes before i only, and a trained network
    gives many samples the same prefix (of 1000 samples for one observation, one prefix at position 0, at most
    16 at 1, a few hundred at the last position). Step i computes each distinct prefix's column once, in chunks
    of :data:`LARGE_CHUNKS` x ``chunk`` prefixes while that many are left, then of ``chunk`` (loops whose trip
    counts follow the number of distinct prefixes), and each sample reads its prefix's logits: the work follows
    the distribution's spread, up to about one column per sample when every prefix differs. The draws are the
    reference's for the same key (``categorical(fold_in(key, i), logits_i)``).
    """
    cond = PixelCNN(cfg).apply({"params": params}, jnp.reshape(feats, (1, -1)), method=PixelCNN.condition)  # (1, C)
    half, C, K = cfg.kernel_size // 2, cfg.channels, cfg.codebook_size  # taps at offsets -half..0: kernel index offset + half
    # Parameter names are flax's for PixelCNN's submodules; in a GatedLayer, MaskedConv1D_0 is the masked convolution,
    # Dense_0 the condition projection, Dense_1 the 1 x 1 output projection.
    first, rest = params["first"], [params[f"rest_{n}"] for n in range(cfg.layers)]
    first_bias, *biases = [p["MaskedConv1D_0"]["bias"] + _dense(p["Dense_0"], cond) for p in (first, *rest)]  # (1, 2C)
    # Mask-A taps (offsets -half..-1) as tables (half, K_c + 1, 2C), with a zero row for code K_c: "before position 0".
    table = jnp.pad(first["MaskedConv1D_0"]["kernel"][:half], ((0, 0), (0, 1), (0, 0)))
    kernels = [p["MaskedConv1D_0"]["kernel"][:half + 1].reshape(-1, 2 * C) for p in rest]  # ((half + 1) C, 2C) per layer
    chunk = min(chunk, num)
    sizes = (LARGE_CHUNKS * chunk, chunk)  # large chunks while many prefixes are left (fewer, larger products)
    held = capacity(num, sizes)  # prefix rows held

    def column(recent, windows, i):
        """(logits (rows, K_c) at position i, each mask-B layer's window moved on to end at i) of prefixes whose codes
        at positions i - half .. i - 1 are ``recent`` (rows, half) and whose layers' inputs there are ``windows``."""
        x = _gated_column(first, table[jnp.arange(half), recent].sum(axis=1), first_bias) + params["position"][i]
        moved = []
        for p, kernel, bias, window in zip(rest, kernels, biases, windows):
            taps = window.reshape(window.shape[0], -1) @ kernel[:half * C] + x @ kernel[half * C:]  # positions i - half .. i
            moved.append(jnp.concatenate([window[:, 1:], x[:, None]], axis=1))
            x = x + _gated_column(p, taps, bias)
        return _dense(params["out"], nn.relu(_dense(params["head"], nn.relu(x)))), moved

    def draw(i, prefix_logits, index):  # each sample's code at position i from its prefix's logits
        logits = prefix_logits[index]  # (num, K_c)
        return jax.random.categorical(jax.random.fold_in(key, i), logits).astype(jnp.int32), logits

    # Position 0: the empty prefix, shared by every sample.
    recent = jnp.full((1, half), K, jnp.int32)
    logits, windows = column(recent, [jnp.zeros((1, half, C), cond.dtype)] * cfg.layers, 0)
    first_codes, first_logits = draw(0, logits, jnp.zeros(num, jnp.int32))
    # Per prefix, the codes and layer inputs that the next position reads, in two slots: position i reads its parents
    # from slot (i - 1) % 2 and writes slot i % 2, in place.
    prefixes = [jnp.zeros((2, held, *a.shape[1:]), a.dtype).at[0, :1].set(a) for a in (recent, *windows)]

    def step(carry, i):
        index, codes, prefixes = carry  # each sample's prefix row and code at position i - 1; the prefix slots
        distinct, count, index = _distinct_prefixes(index, codes, K, held)
        read, write = (i - 1) % 2, i % 2

        def compute(rows, start, buffers):  # ``rows`` distinct prefixes from ``start``, from their parents' rows
            logits_buffer, prefixes = buffers
            keys = jax.lax.dynamic_slice_in_dim(distinct, start, rows)
            parent = keys // K
            previous = [buffer[read, parent] for buffer in prefixes]
            recent = jnp.concatenate([previous[0], (keys % K)[:, None]], axis=1)[:, 1:]
            logits, windows = column(recent, previous[1:], i)
            prefixes = [jax.lax.dynamic_update_slice(buffer, new[None], (write, start) + (0,) * (new.ndim - 1))
                        for buffer, new in zip(prefixes, (recent, *windows))]
            return jax.lax.dynamic_update_slice_in_dim(logits_buffer, logits, start, 0), prefixes

        logits, prefixes = over_chunks(count, sizes, compute, (jnp.zeros((held, K), cond.dtype), prefixes))
        code, logits = draw(i, logits, index)
        return (index, code, prefixes), (code, logits)

    init = (jnp.zeros(num, jnp.int32), first_codes, prefixes)
    _, (codes, logits) = jax.lax.scan(step, init, jnp.arange(1, cfg.num_latents))  # (L - 1, num), (L - 1, num, K_c)
    codes = jnp.concatenate([first_codes[None], codes])
    logits = jnp.concatenate([first_logits[None], logits])
    return codes.T, jnp.swapaxes(logits, 0, 1)


@functools.partial(jax.jit, static_argnames=("cfg", "num"))
def sample_codes(params, cfg: PixelCNNConfig, feats: jnp.ndarray, key: jax.Array, num: int) -> jnp.ndarray:
    """(num, L) int32 code indices drawn autoregressively for one observation's features (F,) or (1, F),
    incrementally (:func:`sample_codes_and_logits` without the logits; one compilation per configuration and count)."""
    return sample_codes_and_logits(params, cfg, feats, key, num)[0]


def sample_codes_reference(params, cfg: PixelCNNConfig, feats: jnp.ndarray, key: jax.Array, num: int) -> jnp.ndarray:
    """:func:`sample_codes` by re-running the whole network over all L positions for each position (one
    ``lax.fori_loop``; L times the work): the definition the incremental sampler is tested against."""
    model = PixelCNN(cfg)
    cond = model.apply({"params": params}, jnp.reshape(feats, (1, -1)), method=PixelCNN.condition)

    def body(i, codes):
        logits = model.apply({"params": params}, jax.nn.one_hot(codes, cfg.codebook_size), cond, method=PixelCNN.logits)
        drawn = jax.random.categorical(jax.random.fold_in(key, i), jnp.take(logits, i, axis=1))
        return codes.at[:, i].set(drawn.astype(jnp.int32))

    return jax.lax.fori_loop(0, cfg.num_latents, body, jnp.zeros((num, cfg.num_latents), jnp.int32))


def load_vqvae_prior(path: str | Path, lanes: int | None = None) -> dict[str, Any]:
    """Everything the VQ-VAE prior plans with, from a PixelCNN checkpoint (it embeds its VQ-VAE's decoder,
    codebook and normaliser): {"vqvae_config", "vqvae_params", "normaliser", "config", "params", "meta"}.
    CheckpointError when unusable, or when ``lanes`` is given and it was trained for other lane counts."""
    meta, state = load_checkpoint(path, CHECKPOINT_KIND, lanes)
    vq_cfg = header_config(meta, path, VQVAEConfig, "VQ-VAE", "vqvae_config")
    cfg = header_config(meta, path, PixelCNNConfig, "PixelCNN")
    if (cfg.num_latents, cfg.codebook_size) != (vq_cfg.num_latents, vq_cfg.codebook_size):
        raise CheckpointError(f"{path}: the PixelCNN ({cfg.num_latents} x {cfg.codebook_size} codes) does not match its "
                              f"VQ-VAE ({vq_cfg.num_latents} x {vq_cfg.codebook_size})")
    target = {"params": parameter_shapes(init_params, cfg), "vqvae": empty_state(vq_cfg)}
    restored = restore(target, {k: state.get(k) for k in target}, path, "the PixelCNN state")
    norm = Normaliser(*restored["vqvae"]["normaliser"])
    check_scales(path, "the PixelCNN state", normaliser_scales(norm))
    return {"vqvae_config": vq_cfg, "vqvae_params": restored["vqvae"]["params"],
            "normaliser": norm, "config": cfg, "params": restored["params"], "meta": meta}
