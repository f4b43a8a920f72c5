"""Recurrent actor-critic network of Ndousse et al. (2021), appendix "Network architecture details".

Flax linen modules: `ActorCritic` (encoder -> LSTM -> policy and value heads, plus the auxiliary heads the
config asks for), built from `Encoder`, `LSTM`, `MLP`, `Decoder` (the auxiliary frame head), `Conv` and
`Dense`. Linen, because its params are plain nested dicts of float32 arrays: independent agents stack them on
a leading axis (``jax.vmap(unroll, in_axes=(0, None, 0, 0, 0))``), seeds ``lax.map`` over them, and orbax
saves them as they are. The module-level functions (`init`, `unroll`, `step`, `decode`, `aux_loss`,
`attention_loss`) apply the modules to such a params dict; ``ActorCritic(cfg).init(key, carry, obs, resets)``
and ``.apply`` are the same model for use with other Flax code (`init` draws the same distributions from two
random buffers, which compiles ~10x faster than one draw per tensor).

The params tree is flat: ``conv1, conv2, conv3, fc`` (`Encoder`), ``lstm`` (``wi, wh, b``), ``policy`` and
``value`` (``dense0, dense1, out``), ``attention`` and ``aux_fc, deconv1, deconv2, deconv3`` (`Decoder`);
every layer holds ``kernel`` and ``bias``. Symbolic views (``NetworkConfig(obs="symbolic")``, int8[7, 7, 4]
per step: tile, agent, heading, colour; `observe.symbolic`) swap the two layers that map pixels to view
cells: ``embed`` (one learned vector per channel value, summed per cell: `Embed`) replaces ``conv1``, and
``cell_logits`` (per-cell logits over each channel's values, trained by a masked cross-entropy:
`symbolic_errors`) replaces ``deconv3``.

Architecture (paper widths; every width is a `NetworkConfig` field)::

    obs uint8[T, B, 21, 21, 3] / 255
      -> Conv(3->32, 3x3, stride 3) -> leaky ReLU       21x21 -> 7x7
      -> Conv(32->64, 3x3, stride 1) -> leaky ReLU      7x7 -> 5x5
      -> Conv(64->64, 3x3, stride 1) -> leaky ReLU      5x5 -> 3x3, flattened (h, w, c) to 576
      -> FC(576->192) -> tanh -> LSTM(192)               hidden h f32[T, B, 192]
    value  = MLP(192->64->64->1), tanh hidden layers     f32[T, B]
    logits = MLP(192->64->64->7), tanh hidden layers     f32[T, B, 7]
    aux    = FC(192+7 -> 576) on concat(h, one_hot(action)) -> tanh -> reshape (3, 3, 64)
      -> DeConv(64->64, 3x3, s1) -> leaky ReLU -> DeConv(64->32, 3x3, s1) -> leaky ReLU
      -> DeConv(32->3, 3x3, stride 3)                    3x3 -> 5x5 -> 7x7 -> f32[21, 21, 3], linear output
         (compared by the learner with an MAE against obs / 255: the current frame for aux="rec",
          the next frame for aux="pred"; both build the same decoder)
    attention = FC(192 -> K * 50), K = n_others          with aux "attention", "rec+attention" or
         "pred+attention" (an addition after Bhoopchand et al. 2023, not in the paper): for each other
         agent slot, logits over its cell in the 7x7 view plus "not in view" (`attention_loss`)

Parameter count: 667,787 for the paper configuration. The PyTorch reference
(benchmarks/pytorch_paper_net.py) has 668,555 = 667,787 + 768 because ``torch.nn.LSTM`` keeps two
bias vectors (``b_ih`` and ``b_hh``, 4 * 192 each) of which only the sum matters; here the LSTM has one.
Without the auxiliary decoder (aux="none"): 496,328. The attention head adds 193 * 50 * n_others.

Conventions: conv kernels are HWIO ``[3, 3, C_in, C_out]``, and the conv layers take and return HWNC
activations (`conv`); deconv kernels are ``[3, 3, C_in, C_out]`` with torch ConvTranspose2d (scatter)
semantics; LSTM gates are ordered (i, f, g, o) like PyTorch: ``gates = x @ wi + h @ wh + b``. Initialisation:
convs PyTorch's default U(-1/sqrt(fan_in), 1/sqrt(fan_in)) (deconvs with the effective fan-in C_in * 9 /
stride^2), dense layers orthogonal with gain sqrt(2) (hidden), 1 (value output) or 0.01 (policy and attention
outputs) and zero bias, LSTM N(0, 1/hidden) input weights, orthogonal recurrent weights per gate, zero bias.

`NetworkConfig.conv_impl` and `NetworkConfig.chunk` change how, not what, the network computes: the conv
kernels (`conv.IMPLS`), and the frames per chunk in which the conv encoder and the decoder run (`_map_chunks`,
saving only each layer's activation for the backward pass). `NetworkConfig.dtype` "bfloat16" rounds the inputs
of every matrix product and convolution to bfloat16 and accumulates in float32 (`precision.matmul`); the
params tree, the LSTM state and every output stay float32. Why and how fast: docs/performance.md.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import traverse_util
from jax import lax
from jax.ad_checkpoint import checkpoint_name

from jaxsocial.agents import conv, precision
from jaxsocial.agents.conv import KERNEL
from jaxsocial.agents.precision import matmul
from jaxsocial.env.types import MAX_AGENTS, NUM_TILE_TYPES

Params = dict[str, Any]

OBS_SHAPE = (21, 21, 3)  # 7x7 grid cells of 3x3 pixels (marlgrid tile size 3)
OBS_KINDS = ("rgb", "symbolic")  # `NetworkConfig.obs`: the environment's `EnvParams.observation`
SYMBOLIC_SHAPE = (7, 7, 4)  # per view cell: tile, agent index + 1, heading, colour (`observe.symbolic`)
SYMBOLIC_SHIFT = (1, 0, 1, 0)  # added to each channel's value to make a class index (tile and heading use -1)
SYMBOLIC_CLASSES = (NUM_TILE_TYPES + 1, MAX_AGENTS + 1, 5, 128)  # classes per channel (colour: 0-127)
SYMBOLIC_VOCAB = sum(SYMBOLIC_CLASSES)  # rows of the embedding table
PREDICTED_CLASSES = (*SYMBOLIC_CLASSES[:3], 16)  # the decoder's classes: colour in 16 bins of 8 levels
PREDICTED_VOCAB = sum(PREDICTED_CLASSES)  # logits per view cell of the decoder
STRIDES = (3, 1, 1)  # encoder strides; the decoder mirrors them in reverse order
LEAKY_SLOPE = 0.01  # torch.nn.functional.leaky_relu default
AUX_KINDS = ("none", "rec", "pred", "attention", "rec+attention", "pred+attention")
ATTENTION_CLASSES = (OBS_SHAPE[0] // KERNEL) ** 2 + 1  # the 7x7 view cells, then "not in view"
CONV_IMPLS = conv.IMPLS
DTYPES = precision.DTYPES
DECODER_PARAMS = ("aux_fc", "deconv1", "deconv2", "deconv3")  # the `Decoder`'s entries of the params tree
_SAVED = "activation"  # checkpoint name of the layer outputs saved for the backward pass (`_map_chunks`)
_INITS = "intermediates"  # collection where `_param` records each initialiser (see `init`)


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Widths of the network; the defaults are the paper's."""

    conv_channels: tuple[int, int, int] = (32, 64, 64)
    """Output channels of the three convolutions."""
    hidden: int = 192
    """Width of the FC layer and the LSTM."""
    mlp: int = 64
    """Hidden width of the value and policy MLPs."""
    aux: str = "pred"
    """Auxiliary loss: "none", "rec" (reconstruct the current frame), "pred" (predict the next frame),
    "attention" (locate the other agents in the view), "rec+attention" or "pred+attention"."""
    n_actions: int = 7
    """Actions of the policy output."""
    conv_impl: str = "matmul"
    """How convolutions are computed (same result, different speed): "matmul" (matrix products: Winograd in
    float32, im2col in bfloat16; fastest measured on CPU and GPU), "im2col" (one product of the 3x3 patches
    per layer) or "xla" (XLA's convolutions)."""
    chunk: int = 512
    """Frames processed at a time by the conv encoder and decoder (speed and memory only)."""
    n_others: int = 2
    """Other agents the attention auxiliary head locates (the environment's agents - 1)."""
    obs: str = "rgb"
    """Observations the network takes: "rgb" frames or "symbolic" views (set from the environment)."""
    dtype: str = "float32"
    """Input dtype of matrix products and convolutions: "float32", or "bfloat16" (float32 accumulation;
    params, optimiser state, LSTM state and losses stay float32). Whether it is faster depends on the
    hardware (docs/performance.md)."""

    def __post_init__(self):
        channels = tuple(self.conv_channels)
        if len(channels) != 3:
            raise ValueError(f"conv_channels must have 3 entries, got {self.conv_channels!r}")
        object.__setattr__(self, "conv_channels", channels)

        def positive_int(value) -> bool:
            return isinstance(value, int) and not isinstance(value, bool) and value > 0

        if not all(positive_int(c) for c in channels):
            raise ValueError(f"conv_channels must be positive integers, got {self.conv_channels!r}")
        for name in ("hidden", "mlp", "n_actions", "chunk", "n_others"):
            if not positive_int(getattr(self, name)):
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")
        if self.aux not in AUX_KINDS:
            raise ValueError(f"unknown aux {self.aux!r}; choose from {AUX_KINDS}")
        if self.conv_impl not in CONV_IMPLS:
            raise ValueError(f"unknown conv_impl {self.conv_impl!r}; choose from {CONV_IMPLS}")
        if self.obs not in OBS_KINDS:
            raise ValueError(f"unknown obs {self.obs!r}; choose from {OBS_KINDS}")
        if self.dtype not in DTYPES:
            raise ValueError(f"unknown dtype {self.dtype!r}; choose from {DTYPES}")

    @property
    def symbolic(self) -> bool:
        return self.obs == "symbolic"

    @property
    def obs_shape(self) -> tuple[int, int, int]:
        """One observation's shape: (21, 21, 3) RGB or (7, 7, 4) symbolic."""
        return SYMBOLIC_SHAPE if self.symbolic else OBS_SHAPE

    @property
    def obs_dtype(self):
        return jnp.int8 if self.symbolic else jnp.uint8

    @property
    def decoded_shape(self) -> tuple[int, int, int]:
        """`decode`'s output per step: frames (21, 21, 3), or logits (7, 7, PREDICTED_VOCAB) per view cell."""
        return (*SYMBOLIC_SHAPE[:2], PREDICTED_VOCAB) if self.symbolic else OBS_SHAPE

    @property
    def decoder_params(self) -> tuple[str, ...]:
        """The `Decoder`'s entries of the params tree."""
        return (*DECODER_PARAMS[:-1], "cell_logits") if self.symbolic else DECODER_PARAMS

    @property
    def frame_aux(self) -> str:
        """The frame loss: "none", "rec" or "pred" (what the decoder is trained on; "none": no decoder)."""
        return "none" if self.aux == "attention" else self.aux.removesuffix("+attention")

    @property
    def attention(self) -> bool:
        """The network has the attention head (`attention_loss`)."""
        return self.aux.endswith("attention")

    @property
    def feature_shape(self) -> tuple[int, int, int]:
        """Shape of the last conv feature map (3, 3, C3)."""
        # symbolic: the embedding is per cell, in place of conv1 (which maps 3x3 pixel blocks to cells)
        size, strides = (SYMBOLIC_SHAPE[0], STRIDES[1:]) if self.symbolic else (OBS_SHAPE[0], STRIDES)
        for stride in strides:
            size = (size - KERNEL) // stride + 1
        return (size, size, self.conv_channels[-1])

    @property
    def feature_size(self) -> int:
        return math.prod(self.feature_shape)


class Carry(NamedTuple):
    """LSTM state, float32[*batch, hidden] each."""

    c: jax.Array
    h: jax.Array


class Output(NamedTuple):
    """Per-step network outputs: logits f32[T, B, A], value f32[T, B], LSTM output hidden f32[T, B, H]."""

    logits: jax.Array
    value: jax.Array
    hidden: jax.Array


# ------------------------------------------------------------------------------------------ initialisers


@jax.tree_util.register_static
@dataclasses.dataclass(frozen=True)
class Init:
    """A parameter's initialiser, usable as a Flax initialiser ``(key, shape, dtype) -> array``.

    kind: "uniform" (U(-arg, arg)), "normal" (N(0, arg^2)), "orthogonal" (gain arg; `blocks` independent
    orthogonal blocks side by side along the last axis) or "zeros". A static pytree (no leaves), so `_param`
    can record it in a collection that `jax.eval_shape` passes through.
    """

    kind: str
    arg: float = 0.0
    blocks: int = 1

    @property
    def noise(self) -> str | None:
        """The random buffer this initialiser transforms: "uniform" (U(-1, 1)), "normal" or None."""
        return {"uniform": "uniform", "normal": "normal", "orthogonal": "normal"}.get(self.kind)

    def __call__(self, key: jax.Array, shape: tuple[int, ...], dtype=jnp.float32) -> jax.Array:
        size = math.prod(shape)
        if self.noise == "uniform":
            return self.from_noise(jax.random.uniform(key, (size,), dtype, -1.0, 1.0), shape)
        return self.from_noise(jax.random.normal(key, (size,), dtype) if self.noise else None, shape)

    def from_noise(self, z: jax.Array | None, shape: tuple[int, ...]) -> jax.Array:
        """The parameter f32[shape] from flat noise z f32[prod(shape)] drawn from `noise` (None: "zeros")."""
        if self.kind == "zeros":
            return jnp.zeros(shape, jnp.float32)
        if self.kind != "orthogonal":
            return self.arg * z.reshape(shape)
        *lead, n_in, n_out = shape
        q = _orthogonal(z.reshape(*lead, self.blocks, n_in, n_out // self.blocks), self.arg)
        return jnp.concatenate(jnp.unstack(q, axis=-3), axis=-1)


def _param(module: nn.Module, name: str, init: Init, shape: tuple[int, ...]) -> jax.Array:
    """``module.param(name, init, shape)``, recording `init` in the `_INITS` collection when it is mutable
    (only `init` asks: Flax's own ``Module.init`` leaves that collection immutable)."""
    module.sow(_INITS, name, init)
    return module.param(name, init, shape)


def _gram_schmidt(z: jax.Array) -> jax.Array:
    """Orthonormal columns from z [n, m] (n >= m) by Gram-Schmidt with re-orthogonalisation: the Q of z's QR
    decomposition with a positive diagonal of R, so Haar-distributed for Gaussian z.

    Not ``jnp.linalg.qr``: under ``vmap`` (stacked agents) it becomes a batched LAPACK call that fans out into
    XLA:CPU's intra-op thread pool and blocks waiting for it; two such calls running concurrently on a 2-core
    machine deadlock (jaxlib 0.10.2: ``jax::ParallelBatchMap`` in ``lapack_sgeqrf_ffi``).
    """

    def add_column(j, q):
        v = lax.dynamic_index_in_dim(z, j, axis=1, keepdims=False)
        for _ in range(2):  # columns >= j of q are still zero
            v = v - q @ (q.T @ v)
        return lax.dynamic_update_index_in_dim(q, v / jnp.linalg.norm(v), j, axis=1)

    return lax.fori_loop(0, z.shape[1], add_column, jnp.zeros_like(z))


def _orthogonal(z: jax.Array, gain: float) -> jax.Array:
    """Orthogonal matrices (batched over leading axes) from standard-normal `z` [..., n_in, n_out]."""
    transpose = z.shape[-2] < z.shape[-1]
    if transpose:
        z = jnp.swapaxes(z, -1, -2)
    q = jnp.vectorize(_gram_schmidt, signature="(n,m)->(n,m)")(z)
    return gain * (jnp.swapaxes(q, -1, -2) if transpose else q)


# ------------------------------------------------------------------------------------------------ layers


def _leaky_relu_unsaved(x):
    return jnp.where(x >= 0, x, LEAKY_SLOPE * x)


@jax.custom_vjp
def _leaky_relu(x):
    """Leaky ReLU whose output is the residual saved for the backward pass (named `_SAVED`)."""
    return _leaky_relu_unsaved(x)


def _leaky_relu_fwd(x):
    y = checkpoint_name(_leaky_relu(x), _SAVED)
    return y, y


# The derivative from the output (the sign is preserved), so the backward pass needs only the activation.
_leaky_relu.defvjp(_leaky_relu_fwd, lambda y, g: (jnp.where(y >= 0, g, LEAKY_SLOPE * g),))


def _map_chunks(fn: Callable, module: nn.Module, args: tuple[jax.Array, ...], chunk: int) -> jax.Array:
    """``fn(module, *args)`` for a row-wise `fn` (row i of each arg -> row i of the output), `chunk` rows at a
    time.

    An ``nn.scan`` over chunks (params broadcast) keeps each layer's activations in cache; for the backward
    pass (``nn.remat``) only the values `fn` names `_SAVED` (each hidden layer's activation) are stored, the
    rest (e.g. the Winograd layers' transformed inputs) is recomputed from them. Rows are zero-padded to a
    multiple of `chunk`.
    """
    n = args[0].shape[0]
    if n <= chunk:
        return fn(module, *args)
    policy = jax.checkpoint_policies.save_only_these_names(_SAVED)
    body = nn.remat(lambda mdl, carry, rows: (carry, fn(mdl, *rows)), policy=policy, prevent_cse=False)
    scan = nn.scan(body, variable_broadcast="params", split_rngs={"params": False})
    _, out = scan(module, None, _split_chunks(args, chunk))
    return out.reshape(-1, *out.shape[2:])[:n]


def _split_chunks(args: tuple[jax.Array, ...], chunk: int) -> tuple[jax.Array, ...]:
    """Rows [N, ...] -> [ceil(N / chunk), chunk, ...], zero-padded to a multiple of `chunk`."""
    n = args[0].shape[0]
    pad = -n % chunk
    args = tuple(jnp.pad(x, [(0, pad)] + [(0, 0)] * (x.ndim - 1)) if pad else x for x in args)
    return tuple(x.reshape(-1, chunk, *x.shape[1:]) for x in args)


class Dense(nn.Module):
    """``x @ kernel + bias``: f32[..., n_in] -> f32[..., features]; orthogonal kernel (gain), zero bias; the
    product's inputs in `dtype` (`precision.matmul`)."""

    features: int
    gain: float
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = _param(self, "kernel", Init("orthogonal", self.gain), (x.shape[-1], self.features))
        return matmul(x, kernel, self.dtype) + _param(self, "bias", Init("zeros"), (self.features,))


class MLP(nn.Module):
    """f32[..., n_in] -> f32[..., n_out]: two tanh hidden layers of `width` (gain sqrt 2), a linear output."""

    width: int
    n_out: int
    out_gain: float
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = jnp.tanh(Dense(self.width, math.sqrt(2.0), self.dtype, name="dense0")(x))
        x = jnp.tanh(Dense(self.width, math.sqrt(2.0), self.dtype, name="dense1")(x))
        return Dense(self.n_out, self.out_gain, self.dtype, name="out")(x)


class Conv(nn.Module):
    """3x3 VALID convolution of HWNC activations f32[h, w, n, c_in] -> f32[h', w', n, features] (`conv.conv`;
    transpose: `conv.deconv`), PyTorch's default uniform init with fan-in c_in * 9 (/ stride^2 transposed)."""

    features: int
    stride: int
    impl: str
    transpose: bool = False
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        c_in = x.shape[-1]
        bound = 1.0 / math.sqrt(c_in * KERNEL * KERNEL / (self.stride**2 if self.transpose else 1))
        kernel = _param(self, "kernel", Init("uniform", bound), (KERNEL, KERNEL, c_in, self.features))
        bias = _param(self, "bias", Init("uniform", bound), (self.features,))
        layer = conv.deconv if self.transpose else conv.conv
        return layer(x, kernel, bias, self.stride, self.impl, self.dtype)


class Embed(nn.Module):
    """Symbolic view cells int8[..., 4] -> f32[..., features]: the sum of one learned vector per channel value
    (the concatenated per-channel embeddings times a linear map), plus a bias. N(0, 1) init like
    ``torch.nn.Embedding``, zero bias."""

    features: int

    @nn.compact
    def __call__(self, cells: jax.Array) -> jax.Array:
        kernel = _param(self, "kernel", Init("normal", 1.0), (SYMBOLIC_VOCAB, self.features))
        return kernel[symbolic_classes(cells)].sum(-2) + _param(self, "bias", Init("zeros"), (self.features,))


def symbolic_classes(cells: jax.Array, classes: tuple[int, ...] = SYMBOLIC_CLASSES) -> jax.Array:
    """int8[..., 4] symbolic cells -> int32[..., 4] each channel's class, offset into a shared vocabulary of
    ``sum(classes)`` (channel k's classes are ``offsets(classes)[k] + [0, classes[k])``); `classes` with fewer
    classes than `SYMBOLIC_CLASSES` merge neighbouring values (`PREDICTED_CLASSES`: colour levels 8 by 8)."""
    merge = np.asarray(SYMBOLIC_CLASSES) // np.asarray(classes)
    return (cells.astype(jnp.int32) + jnp.asarray(SYMBOLIC_SHIFT)) // merge + jnp.asarray(offsets(classes))


def offsets(classes: tuple[int, ...]) -> tuple[int, ...]:
    """Where each channel's classes start in a vocabulary of ``sum(classes)``."""
    return tuple(sum(classes[:k]) for k in range(len(classes)))


class Encoder(nn.Module):
    """Frames uint8[N, 21, 21, 3] -> features f32[N, hidden]: three leaky-ReLU convs, FC, tanh. Symbolic
    views int8[N, 7, 7, 4] (`NetworkConfig.obs`): an `Embed` per cell in place of conv1 (7x7 cells either
    way).

    The convolutions run in chunks of `NetworkConfig.chunk` frames (`_map_chunks`), up to conv3's
    pre-activation; its activation and the FC layer run on all N frames at once, as large matrix products.
    """

    cfg: NetworkConfig

    def setup(self):
        (c1, c2, c3), impl, dtype = self.cfg.conv_channels, self.cfg.conv_impl, self.cfg.dtype
        if self.cfg.symbolic:
            self.embed = Embed(c1)
        else:
            self.conv1 = Conv(c1, STRIDES[0], impl, dtype=dtype)
        self.conv2 = Conv(c2, STRIDES[1], impl, dtype=dtype)
        self.conv3 = Conv(c3, STRIDES[2], impl, dtype=dtype)
        self.fc = Dense(self.cfg.hidden, math.sqrt(2.0), dtype)

    def __call__(self, obs: jax.Array) -> jax.Array:
        chex.assert_shape(obs, (None, *self.cfg.obs_shape))
        chex.assert_type(obs, self.cfg.obs_dtype)
        x = _leaky_relu(_map_chunks(Encoder.conv_features, self, (obs,), self.cfg.chunk))
        return jnp.tanh(self.fc(x))

    def conv_features(self, obs: jax.Array) -> jax.Array:
        """uint8[n, 21, 21, 3] (or int8[n, 7, 7, 4]) -> conv3's pre-activation f32[n, feature_size], flattened
        (h, w, c)."""
        if self.cfg.symbolic:
            x = self.embed(conv.to_hwnc(obs))
        else:
            x = self.conv1(conv.to_hwnc(obs).astype(jnp.float32) * (1.0 / 255.0))
        # conv1's activation is recomputed from obs, not saved (+0.6% FLOPs, 6 KB less memory per frame)
        x = _leaky_relu_unsaved(x)
        x = _leaky_relu(self.conv2(x))
        x = self.conv3(x)
        return conv.to_nhwc(x).reshape(x.shape[2], -1)


class LSTM(nn.Module):
    """LSTM over T steps of B sequences: carry `Carry` f32[B, features] x 2, x f32[T, B, n_in], resets
    bool[T, B] (before step t, the carry of every sequence with resets[t, b] is zeroed) -> (final `Carry`,
    h f32[T, B, features]). The input projection ``x @ wi + b`` runs on all T * B rows at once, only
    ``h @ wh`` and the gates inside the `lax.scan` over T."""

    features: int
    dtype: str = "float32"

    @nn.compact
    def __call__(self, carry: Carry, x: jax.Array, resets: jax.Array) -> tuple[Carry, jax.Array]:
        n_in, gates = x.shape[-1], 4 * self.features
        wi = _param(self, "wi", Init("normal", 1.0 / math.sqrt(n_in)), (n_in, gates))
        wh = _param(self, "wh", Init("orthogonal", 1.0, blocks=4), (self.features, gates))
        xproj = matmul(x, wi, self.dtype) + _param(self, "b", Init("zeros"), (gates,))

        def cell(carry, inputs):
            xp, reset = inputs
            keep = ~reset[:, None]
            c = jnp.where(keep, carry.c, 0.0)
            h = jnp.where(keep, carry.h, 0.0)
            i, f, g, o = jnp.split(xp + matmul(h, wh, self.dtype), 4, axis=-1)
            c = jax.nn.sigmoid(f) * c + jax.nn.sigmoid(i) * jnp.tanh(g)
            h = jax.nn.sigmoid(o) * jnp.tanh(c)
            return Carry(c=c, h=h), h

        return lax.scan(cell, carry, (xproj, resets))


class Decoder(nn.Module):
    """The auxiliary frame head: LSTM outputs f32[..., H] and actions int[...] -> frames f32[..., 21, 21, 3].

    Unbounded (linear output layer); the learner compares it with obs / 255 (`aux_loss`). Runs in chunks of
    `NetworkConfig.chunk` frames (`_map_chunks`). Symbolic views: ``cell_logits``, a dense layer per view
    cell, in place of deconv3 gives logits f32[..., 7, 7, PREDICTED_VOCAB] (`symbolic_errors`).
    """

    cfg: NetworkConfig

    def setup(self):
        (c1, c2, _), impl, dtype = self.cfg.conv_channels, self.cfg.conv_impl, self.cfg.dtype
        self.aux_fc = Dense(self.cfg.feature_size, math.sqrt(2.0), dtype)
        self.deconv1 = Conv(c2, STRIDES[2], impl, transpose=True, dtype=dtype)
        self.deconv2 = Conv(c1, STRIDES[1], impl, transpose=True, dtype=dtype)
        if self.cfg.symbolic:
            self.cell_logits = Dense(PREDICTED_VOCAB, 1.0, dtype)
        else:
            self.deconv3 = Conv(OBS_SHAPE[-1], STRIDES[0], impl, transpose=True, dtype=dtype)

    def __call__(self, hidden: jax.Array, action: jax.Array) -> jax.Array:
        batch = hidden.shape[:-1]
        chex.assert_shape(hidden, (*batch, self.cfg.hidden))
        chex.assert_shape(action, batch)
        rows = (hidden.reshape(-1, hidden.shape[-1]), jnp.asarray(action).reshape(-1))
        frames = _map_chunks(
            lambda mdl, *rows: conv.to_nhwc(mdl.frames_hwnc(*rows)), self, rows, self.cfg.chunk
        )
        return frames.reshape(*batch, *self.cfg.decoded_shape)

    def frames_hwnc(self, hidden: jax.Array, action: jax.Array) -> jax.Array:
        """Rows hidden f32[N, H], action int[N] -> frames f32[21, 21, N, 3] (HWNC), in one piece (symbolic:
        logits f32[7, 7, N, PREDICTED_VOCAB])."""
        z = jnp.concatenate([hidden, jax.nn.one_hot(action, self.cfg.n_actions, dtype=hidden.dtype)], axis=-1)
        x = checkpoint_name(jnp.tanh(self.aux_fc(z)), _SAVED)
        x = conv.to_hwnc(x.reshape(-1, *self.cfg.feature_shape))
        x = _leaky_relu(self.deconv1(x))
        x = _leaky_relu(self.deconv2(x))
        return self.cell_logits(x) if self.cfg.symbolic else self.deconv3(x)  # linear output

    def frame_errors(self, hidden: jax.Array, action: jax.Array, target: jax.Array) -> jax.Array:
        """Mean absolute error of each frame's prediction against target / 255, f32[N], for rows hidden
        f32[N, H], action int[N], target uint8[N, 21, 21, 3], in one piece (symbolic: `symbolic_errors`)."""
        if self.cfg.symbolic:
            return symbolic_errors(self.frames_hwnc(hidden, action), conv.to_hwnc(target))
        # Compared in 3x3 blocks, the layout of deconv3's matrix product: XLA then cancels the deconvolution's
        # transpose to HWNC with this one, here and in the backward pass (+12% for the small training preset).
        prediction = conv.blocks(self.frames_hwnc(hidden, action))
        error = jnp.abs(prediction - conv.blocks(conv.to_hwnc(target)).astype(jnp.float32) / 255.0)
        h, w, n, c = error.shape
        # The sum over pixels as a matrix-vector product: XLA:CPU's reduction over axes (0, 1, 3) took 10x
        # longer.
        return (jnp.ones(h * w) @ error.reshape(h * w, n * c)).reshape(n, c).sum(axis=-1) / (h * w * c)

    def errors(self, hidden: jax.Array, action: jax.Array, target: jax.Array) -> jax.Array:
        """`frame_errors` of rows f32[N, H], int[N], uint8[N, 21, 21, 3] (or int8[N, 7, 7, 4]) -> f32[N], in
        chunks."""
        return _map_chunks(Decoder.frame_errors, self, (hidden, action, target), self.cfg.chunk)


def symbolic_errors(logits: jax.Array, target: jax.Array) -> jax.Array:
    """Masked cross-entropy of symbolic views, f32[N]: logits f32[7, 7, N, PREDICTED_VOCAB] and target
    int8[7, 7, N, 4] (HWNC). Each channel's classes (`PREDICTED_CLASSES`: the colour in 16 bins, which keeps
    the output 4.4x smaller than all 128 levels would) get a softmax of their own; the negative
    log-likelihood of the target class is averaged over the 4 channels and 49 cells, where heading and colour
    count only in cells that hold an agent (elsewhere they are zero terms: no agent, nothing to predict)."""
    classes = symbolic_classes(target, PREDICTED_CLASSES)
    has_agent = target[..., 1] > 0
    total = 0.0
    for k, (offset, size) in enumerate(zip(offsets(PREDICTED_CLASSES), PREDICTED_CLASSES, strict=True)):
        channel = logits[..., offset : offset + size]
        picked = jnp.take_along_axis(channel, classes[..., k, None] - offset, -1)[..., 0]
        nll = jax.nn.logsumexp(channel, -1) - picked
        total = total + (jnp.where(has_agent, nll, 0.0) if k >= 2 else nll)
    h, w, n = total.shape
    return jnp.ones(h * w) @ total.reshape(h * w, n) / (h * w * len(PREDICTED_CLASSES))


class ActorCritic(nn.Module):
    """The recurrent actor-critic: ``ActorCritic(cfg).apply({"params": params}, carry, obs, resets)`` runs it
    over T steps of B sequences and returns the final `Carry` and per-step `Output`s.

    carry: `Carry` f32[B, hidden] x 2; obs uint8[T, B, 21, 21, 3] (int8[T, B, 7, 7, 4] symbolic); resets
    bool[T, B] (before step t, the carry of every sequence with resets[t, b] is zeroed: a reset step starts a
    fresh episode). ``init`` with the same arguments also creates the auxiliary heads' params (`decode`,
    `attention_logits`).
    """

    cfg: NetworkConfig

    def setup(self):
        cfg = self.cfg
        self.encoder = Encoder(cfg)
        nn.share_scope(self, self.encoder)  # its layers are top-level entries of the params tree
        self.lstm = LSTM(cfg.hidden, cfg.dtype)
        self.policy = MLP(cfg.mlp, cfg.n_actions, 0.01, cfg.dtype)
        self.value = MLP(cfg.mlp, 1, 1.0, cfg.dtype)
        if cfg.attention:
            self.attention = Dense(cfg.n_others * ATTENTION_CLASSES, 0.01, cfg.dtype)
        if cfg.frame_aux != "none":
            self.decoder = Decoder(cfg)
            nn.share_scope(self, self.decoder)

    def __call__(self, carry: Carry, obs: jax.Array, resets: jax.Array) -> tuple[Carry, Output]:
        cfg = self.cfg
        t, b = obs.shape[:2]
        chex.assert_shape(obs, (t, b, *cfg.obs_shape))
        chex.assert_shape(resets, (t, b))
        chex.assert_shape([carry.c, carry.h], (b, cfg.hidden))
        chex.assert_type([resets, carry.c, carry.h], [bool, jnp.float32, jnp.float32])
        x = self.encoder(obs.reshape(t * b, *cfg.obs_shape)).reshape(t, b, -1)
        carry, hidden = self.lstm(carry, x, resets)
        out = Output(logits=self.policy(hidden), value=self.value(hidden)[..., 0], hidden=hidden)
        if self.is_initializing():  # create the auxiliary heads' params too
            if cfg.attention:
                self.attention_logits(hidden)
            if cfg.frame_aux != "none":
                self.decode(hidden, jnp.zeros((t, b), jnp.int32))
        return carry, out

    def attention_logits(self, hidden: jax.Array) -> jax.Array:
        """LSTM outputs f32[..., H] -> logits f32[..., n_others, 50] over each other slot's view cell."""
        if not self.cfg.attention:
            raise ValueError(f"cfg.aux == {self.cfg.aux!r} has no attention head")
        logits = self.attention(hidden)
        return logits.reshape(*hidden.shape[:-1], self.cfg.n_others, ATTENTION_CLASSES)

    def decode(self, hidden: jax.Array, action: jax.Array) -> jax.Array:
        """`Decoder`: hidden f32[..., H], action int[...] -> f32[..., *cfg.decoded_shape]."""
        _check_decoder(self.cfg)
        return self.decoder(hidden, action)


def _check_decoder(cfg: NetworkConfig) -> None:
    if cfg.frame_aux == "none":
        raise ValueError(f"decoding needs an auxiliary decoder, but cfg.aux == {cfg.aux!r} built none")


# ------------------------------------------------------------------------------------ functional API


@functools.cache
def _initialisers(cfg: NetworkConfig) -> dict[tuple[str, ...], tuple[tuple[int, ...], Init]]:
    """Every parameter's path -> (shape, `Init`), from an abstract ``ActorCritic.init`` that records them."""
    b = 1
    obs = jnp.zeros((1, b, *cfg.obs_shape), cfg.obs_dtype)
    args = (initial_carry(cfg, (b,)), obs, jnp.zeros((1, b), bool))
    variables = jax.eval_shape(
        lambda key: ActorCritic(cfg).init(key, *args, mutable=["params", _INITS]), jax.random.key(0)
    )
    shapes = traverse_util.flatten_dict(variables["params"])
    inits = traverse_util.flatten_dict(variables[_INITS])
    return {path: (shapes[path].shape, inits[path][0]) for path in shapes}


def init(key: jax.Array, cfg: NetworkConfig) -> Params:
    """Initial params of ``ActorCritic(cfg)`` (a nested dict of float32 arrays); pure, so it can be vmapped
    over keys.

    Every parameter is a slice of one of two flat random buffers (standard normal and U(-1, 1)), in the
    params' sorted path order: a separate `jax.random` call per tensor costs ~0.4 s of XLA:CPU compile time
    each (11 s for the whole network).
    """
    specs = sorted(_initialisers(cfg).items())
    sizes = {"normal": 0, "uniform": 0}
    for _, (shape, initialiser) in specs:
        if initialiser.noise:
            sizes[initialiser.noise] += math.prod(shape)
    k_normal, k_uniform = jax.random.split(key)
    buffers = {
        "normal": jax.random.normal(k_normal, (sizes["normal"],), jnp.float32),
        "uniform": jax.random.uniform(k_uniform, (sizes["uniform"],), jnp.float32, -1.0, 1.0),
    }
    offsets = {"normal": 0, "uniform": 0}
    params = {}
    for path, (shape, initialiser) in specs:
        noise = None
        if initialiser.noise:
            start, size = offsets[initialiser.noise], math.prod(shape)
            offsets[initialiser.noise] += size
            noise = buffers[initialiser.noise][start : start + size]
        params[path] = initialiser.from_noise(noise, shape)
    return traverse_util.unflatten_dict(params)


def initial_carry(cfg: NetworkConfig, batch_shape: tuple[int, ...]) -> Carry:
    """Zero LSTM state for a batch of shape `batch_shape`."""
    zeros = jnp.zeros((*batch_shape, cfg.hidden), jnp.float32)
    return Carry(c=zeros, h=zeros)


def param_count(params: Params) -> int:
    """Total number of scalars in `params` (works on arrays and on `jax.ShapeDtypeStruct`s)."""
    return sum(math.prod(leaf.shape) for leaf in jax.tree_util.tree_leaves(params))


def unroll(
    params: Params, cfg: NetworkConfig, carry: Carry, obs: jax.Array, resets: jax.Array
) -> tuple[Carry, Output]:
    """`ActorCritic` over T steps of B sequences: carry `Carry` f32[B, H] x 2, obs uint8[T, B, 21, 21, 3]
    (symbolic: int8[T, B, 7, 7, 4]), resets bool[T, B] -> (final `Carry`, `Output` with T and B axes)."""
    return ActorCritic(cfg).apply({"params": params}, carry, obs, resets)


def step(
    params: Params, cfg: NetworkConfig, carry: Carry, obs: jax.Array, reset: jax.Array
) -> tuple[Carry, Output]:
    """One step for acting: obs uint8[B, 21, 21, 3] (or int8[B, 7, 7, 4]), reset bool[B]; `Output` fields
    have no T axis."""
    carry, out = unroll(params, cfg, carry, obs[None], reset[None])
    return carry, jax.tree_util.tree_map(lambda x: x[0], out)


def attention_loss(params: Params, cfg: NetworkConfig, hidden: jax.Array, target: jax.Array, weight):
    """Weighted attention loss ``sum(weight * mean_k CE(logits_k, target_k))``, f32[].

    hidden f32[..., H]; target int[..., K] each other slot's view cell (`observe.attention_targets`:
    row * 7 + col, or 49 when not in view); weight f32[...]. Raises ValueError without the attention head.
    """
    chex.assert_shape(target, (*hidden.shape[:-1], cfg.n_others))
    logits = ActorCritic(cfg).apply({"params": params}, hidden, method=ActorCritic.attention_logits)
    log_probs = jax.nn.log_softmax(logits)
    nll = -jnp.take_along_axis(log_probs, target[..., None].astype(jnp.int32), -1)[..., 0]
    return jnp.sum(weight * jnp.mean(nll, -1))


def decode(params: Params, cfg: NetworkConfig, hidden: jax.Array, action: jax.Array) -> jax.Array:
    """Auxiliary prediction f32[..., 21, 21, 3] from LSTM outputs f32[..., H] and actions int[...].

    Unbounded (linear output layer); the learner compares it with obs / 255 (see `aux_loss`, which
    computes that comparison and its gradient faster). Symbolic views: logits f32[..., 7, 7, PREDICTED_VOCAB]
    (`symbolic_errors`). Raises ValueError without a decoder.
    """
    return ActorCritic(cfg).apply({"params": params}, hidden, action, method=ActorCritic.decode)


def aux_loss(
    params: Params,
    cfg: NetworkConfig,
    hidden: jax.Array,
    action: jax.Array,
    target: jax.Array,
    weight: jax.Array,
    axis_name: str | None = None,
) -> jax.Array:
    """Weighted auxiliary loss ``sum(weight * mean|decode(hidden, action) - target / 255|)``, f32[] (symbolic
    views: ``sum(weight * symbolic_errors(...))``, the masked cross-entropy per view).

    hidden f32[..., H]; action int[...]; target uint8[..., 21, 21, 3] (or int8[..., 7, 7, 4]); weight f32[...]
    (the mean absolute error of each frame over its pixels is weighted). `axis_name`: called inside
    `jax.shard_map` with params replicated and every other argument the device's share of the rows, the mesh
    axis the rows are split over (the params' gradient is then summed over it). Raises ValueError without a
    decoder.

    Differentiable in params, hidden and weight, with the value and gradients of writing it with `decode`,
    but faster: as only a scalar leaves the decoder, the forward pass of a differentiated call runs the
    decoder's backward pass too, chunk by chunk (`NetworkConfig.chunk` frames) while each chunk's
    activations are in cache. It keeps the gradients (of the decoder params, and f32[N, H] of hidden) rather
    than every frame's activations; the backward pass only scales them by the incoming cotangent.
    """
    _check_decoder(cfg)
    batch = hidden.shape[:-1]
    chex.assert_shape([hidden, target], [(*batch, cfg.hidden), (*batch, *cfg.obs_shape)])
    chex.assert_type(target, cfg.obs_dtype)
    decoder = {name: params[name] for name in cfg.decoder_params}
    if axis_name is not None:  # per-device gradients; pcast's transpose sums them over the devices
        decoder = lax.pcast(decoder, axis_name, to="varying")
    n = math.prod(batch)
    rows = (
        hidden.reshape(n, hidden.shape[-1]),
        jnp.asarray(action).reshape(n),
        target.reshape(n, *cfg.obs_shape),
        jnp.broadcast_to(jnp.asarray(weight, jnp.float32), batch).reshape(n),
    )
    return _aux_loss(cfg, decoder, *rows)


def _decoder_apply(cfg: NetworkConfig, decoder: Params, method: Callable, *args) -> jax.Array:
    """A `Decoder` method applied to the decoder's entries of the params tree (`DECODER_PARAMS`)."""
    return Decoder(cfg).apply({"params": decoder}, *args, method=method)


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _aux_loss(cfg: NetworkConfig, decoder: Params, hidden, action, target, weight) -> jax.Array:
    return jnp.sum(weight * _decoder_apply(cfg, decoder, Decoder.errors, hidden, action, target))


def _aux_loss_fwd(cfg: NetworkConfig, decoder: Params, hidden, action, target, weight):
    """The loss and its gradients, chunk by chunk: a `lax.scan` over chunks of rows (padded with weight 0)
    that sums the decoder params' gradients and stacks those of hidden and weight (= the frame errors)."""
    n = hidden.shape[0]
    rows = _split_chunks((hidden, action, target, weight), min(cfg.chunk, n))

    def chunk_grads(d_decoder, inputs):
        hidden, action, target, weight = inputs

        def weighted_error(decoder, hidden):
            errors = _decoder_apply(cfg, decoder, Decoder.frame_errors, hidden, action, target)
            return jnp.sum(weight * errors), errors

        (d_chunk, d_hidden), errors = jax.grad(weighted_error, argnums=(0, 1), has_aux=True)(decoder, hidden)
        return jax.tree.map(jnp.add, d_decoder, d_chunk), (d_hidden, errors)

    d_decoder, (d_hidden, errors) = lax.scan(chunk_grads, jax.tree.map(jnp.zeros_like, decoder), rows)
    d_hidden, errors = d_hidden.reshape(-1, hidden.shape[-1])[:n], errors.reshape(-1)[:n]
    return jnp.sum(weight * errors), (d_decoder, d_hidden, errors)


def _aux_loss_bwd(cfg: NetworkConfig, residuals, g):
    del cfg
    d_decoder, d_hidden, errors = residuals
    return jax.tree.map(lambda x: g * x, d_decoder), g * d_hidden, None, None, g * errors


_aux_loss.defvjp(_aux_loss_fwd, _aux_loss_bwd)
