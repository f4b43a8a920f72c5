"""Recurrent actor-critic network of Ndousse et al. (2021), appendix "Network architecture details".

The front door: `NetworkConfig` and the functions the learners call (`init`, `initial_carry`, `unroll`,
`step`, `decode`, `aux_loss`, `attention_loss`, `param_count`), which apply the Flax linen `ActorCritic` to a
params dict. Linen, because its params are plain nested dicts of float32 arrays: independent agents stack them
on a leading axis (``jax.vmap(unroll, in_axes=(0, None, 0, 0, 0))``), seeds ``lax.map`` over them, and orbax
saves them as they are. ``ActorCritic(net_cfg).init(key, carry, obs, resets)`` and ``.apply`` are the same
model for use with other Flax code (`init` draws the same distributions from two random buffers, which
compiles ~10x faster than one draw per tensor).

The parts, one job each:

* here, `PaperActorCritic`: the network in plain Flax layers, the reference to read (``nn.Conv`` and
  ``lax.conv_transpose`` on NHWC frames, float32 products, every parameter drawn from its own `Init`;
  convolutions take PyTorch's default U(-1/sqrt(fan_in), 1/sqrt(fan_in)), transposed: the effective fan-in
  C_in * 9 / stride^2; pixel views only).
* `network_config`: `NetworkConfig` and the shapes that follow from it.
* `layers`: the plain layers both networks are built of (`Dense`, `MLP`, `LSTM`).
* `modules`: the Flax modules that run (`ActorCritic`, `Encoder`, `Decoder`, `Conv`, `Embed`): the same
  function of the same params as `PaperActorCritic` (tested: tests/test_network.py), faster.
* `initialisers`: each parameter's distribution, and the params drawn from two random buffers.
* `aux_loss`: the auxiliary frame loss of a decoder, fused with its gradient (`aux_loss` here applies it).
* `symbolic`: the symbolic views' vocabulary and their masked cross-entropy.
* `fast`: how it runs fast on CPUs, not what it computes (conv kernels, batches of frames, bfloat16
  products, the machine's own choice among them), selected by `conv_impl`, `frame_batch` and `dtype`.

The params tree is flat: ``conv1, conv2, conv3, fc`` (`Encoder`), ``lstm`` (``wi, wh, b``), ``policy`` and
``value`` (``dense0, dense1, out``), ``attention`` and ``aux_fc, deconv1, deconv2, deconv3`` (`Decoder`);
every layer holds ``kernel`` and ``bias``. Symbolic views (``NetworkConfig(obs="symbolic")``, int8[7, 7, 4]
per step: tile, agent, heading, colour; `observe.symbolic`) swap the two layers that map pixels to view
cells: ``embed`` (one learned vector per channel value, summed per cell: `modules.Embed`) replaces
``conv1``, and ``cell_logits`` (per-cell logits over each channel's values, trained by a masked
cross-entropy: `symbolic_errors`) replaces ``deconv3``.

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

Conventions (kernel layouts, LSTM gate order, initialisation): `modules`. `NetworkConfig.conv_impl`,
`frame_batch` and `dtype` change how, not what, the network computes (`network_config`; docs/performance.md).
"""

from __future__ import annotations

import functools
import math

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
from jax import lax

from jaxsocial.agents import initialisers
from jaxsocial.agents.aux_loss import fused_aux_loss
from jaxsocial.agents.fast.conv import KERNEL
from jaxsocial.agents.fast.frame_batches import LEAKY_SLOPE
from jaxsocial.agents.initialisers import Init, Params, param
from jaxsocial.agents.layers import LSTM, MLP, Carry, Dense, Output
from jaxsocial.agents.modules import ActorCritic, Decoder
from jaxsocial.agents.network_config import (
    ATTENTION_CLASSES,
    CONV_IMPLS,
    DECODER_PARAMS,
    DTYPES,
    OBS_SHAPE,
    STRIDES,
    NetworkConfig,
)
from jaxsocial.agents.symbolic import (
    PREDICTED_CLASSES,
    PREDICTED_VOCAB,
    SYMBOLIC_CLASSES,
    SYMBOLIC_SHAPE,
    SYMBOLIC_SHIFT,
    SYMBOLIC_VOCAB,
    offsets,
    symbolic_errors,
)

__all__ = [
    # the functional API
    "NetworkConfig",
    "Params",
    "Carry",
    "Output",
    "ActorCritic",
    "init",
    "initial_carry",
    "param_count",
    "unroll",
    "step",
    "decode",
    "aux_loss",
    "attention_loss",
    # the reference to read
    "PaperActorCritic",
    # shapes and vocabularies
    "OBS_SHAPE",
    "KERNEL",
    "ATTENTION_CLASSES",
    "DECODER_PARAMS",
    "CONV_IMPLS",
    "DTYPES",
    "SYMBOLIC_SHAPE",
    "SYMBOLIC_SHIFT",
    "SYMBOLIC_CLASSES",
    "SYMBOLIC_VOCAB",
    "PREDICTED_CLASSES",
    "PREDICTED_VOCAB",
    "offsets",
    "symbolic_errors",
]


# What the network computes: the paper's network in plain Flax layers (tests hold `ActorCritic` to it).


def paper_conv(features: int, stride: int, c_in: int, name: str) -> nn.Conv:
    """3x3 VALID convolution of NHWC frames (like torch Conv2d), PyTorch's default uniform init."""
    bound = 1.0 / math.sqrt(c_in * KERNEL * KERNEL)
    init = Init("uniform", bound)
    return nn.Conv(features, (KERNEL, KERNEL), stride, "VALID", kernel_init=init, bias_init=init, name=name)


class PaperDeconv(nn.Module):
    """3x3 VALID transposed convolution of NHWC frames with torch ConvTranspose2d's scatter semantics:
    ``out[s*i + di, s*j + dj] += x[i, j] @ kernel[di, dj]``, f32[n, h, w, c_in] -> f32[n, s (h - 1) + 3,
    s (w - 1) + 3, features]; kernel ``[3, 3, c_in, features]``."""

    features: int
    stride: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        c_in = x.shape[-1]
        init = Init("uniform", 1.0 / math.sqrt(c_in * KERNEL * KERNEL / self.stride**2))
        kernel = param(self, "kernel", init, (KERNEL, KERNEL, c_in, self.features))
        # lax.conv_transpose correlates the dilated, padded input with the kernel; flipped, it scatters.
        out = lax.conv_transpose(
            x, kernel[::-1, ::-1], (self.stride,) * 2, "VALID", dimension_numbers=("NHWC", "HWIO", "NHWC")
        )
        return out + param(self, "bias", init, (self.features,))


class PaperActorCritic(nn.Module):
    """``PaperActorCritic(net_cfg).apply({"params": params}, carry, obs, resets)`` -> (final `Carry`,
    `Output`), the function ``modules.ActorCritic(net_cfg)`` computes with the same params.

    carry: `Carry` f32[B, hidden] x 2; obs uint8[T, B, 21, 21, 3]; resets bool[T, B] (before step t, the carry
    of every sequence with resets[t, b] is zeroed: a reset step starts a fresh episode). ``init`` with the
    same arguments also creates the auxiliary heads' params (`decode`, `attention_logits`).
    """

    net_cfg: NetworkConfig

    def setup(self):
        cfg = self.net_cfg
        if cfg.symbolic:
            raise ValueError("PaperActorCritic reads pixel views; symbolic views run in modules.ActorCritic")
        (c1, c2, c3), pixels = cfg.conv_channels, OBS_SHAPE[-1]
        self.conv1 = paper_conv(c1, STRIDES[0], pixels, "conv1")
        self.conv2 = paper_conv(c2, STRIDES[1], c1, "conv2")
        self.conv3 = paper_conv(c3, STRIDES[2], c2, "conv3")
        self.fc = Dense(cfg.hidden, math.sqrt(2.0))
        self.lstm = LSTM(cfg.hidden)
        self.policy = MLP(cfg.mlp, cfg.n_actions, 0.01)
        self.value = MLP(cfg.mlp, 1, 1.0)
        if cfg.attention:
            self.attention = Dense(cfg.n_others * ATTENTION_CLASSES, 0.01)
        if cfg.frame_aux != "none":
            self.aux_fc = Dense(cfg.feature_size, math.sqrt(2.0))
            self.deconv1 = PaperDeconv(c2, STRIDES[2])
            self.deconv2 = PaperDeconv(c1, STRIDES[1])
            self.deconv3 = PaperDeconv(pixels, STRIDES[0])

    def __call__(self, carry: Carry, obs: jax.Array, resets: jax.Array) -> tuple[Carry, Output]:
        t, b = obs.shape[:2]
        x = obs.reshape(t * b, *OBS_SHAPE).astype(jnp.float32) / 255.0  # 21x21
        x = nn.leaky_relu(self.conv1(x), LEAKY_SLOPE)  # 7x7
        x = nn.leaky_relu(self.conv2(x), LEAKY_SLOPE)  # 5x5
        x = nn.leaky_relu(self.conv3(x), LEAKY_SLOPE)  # 3x3
        x = jnp.tanh(self.fc(x.reshape(t, b, -1)))
        carry, hidden = self.lstm(carry, x, resets)
        out = Output(logits=self.policy(hidden), value=self.value(hidden)[..., 0], hidden=hidden)
        if self.is_initializing():  # create the auxiliary heads' params too
            if self.net_cfg.attention:
                self.attention_logits(hidden)
            if self.net_cfg.frame_aux != "none":
                self.decode(hidden, jnp.zeros((t, b), jnp.int32))
        return carry, out

    def decode(self, hidden: jax.Array, action: jax.Array) -> jax.Array:
        """The auxiliary decoder: LSTM outputs f32[..., H], actions int[...] -> frames f32[..., 21, 21, 3]
        (linear output, compared with obs / 255: `frame_errors`)."""
        self.net_cfg.check_decoder()
        batch = hidden.shape[:-1]
        z = jnp.concatenate([hidden, jax.nn.one_hot(action, self.net_cfg.n_actions)], axis=-1)
        x = jnp.tanh(self.aux_fc(z)).reshape(-1, *self.net_cfg.feature_shape)  # 3x3
        x = nn.leaky_relu(self.deconv1(x), LEAKY_SLOPE)  # 5x5
        x = nn.leaky_relu(self.deconv2(x), LEAKY_SLOPE)  # 7x7
        return self.deconv3(x).reshape(*batch, *OBS_SHAPE)  # 21x21

    def frame_errors(self, hidden: jax.Array, action: jax.Array, target: jax.Array) -> jax.Array:
        """The auxiliary loss per frame, f32[...]: the mean absolute error of `decode` against target / 255
        (target uint8[..., 21, 21, 3]: the current view for aux "rec", the next one for "pred"; `aux_loss`
        weights and sums it)."""
        return jnp.abs(self.decode(hidden, action) - target / 255.0).mean(axis=(-3, -2, -1))

    def attention_logits(self, hidden: jax.Array) -> jax.Array:
        """LSTM outputs f32[..., H] -> logits f32[..., n_others, 50] over each other slot's view cell."""
        logits = self.attention(hidden)
        return logits.reshape(*hidden.shape[:-1], self.net_cfg.n_others, ATTENTION_CLASSES)


# The functional API the learners call: it applies `modules.ActorCritic`, the same function, faster.


@functools.cache
def _initialisers(net_cfg: NetworkConfig) -> initialisers.Specs:
    """Every parameter's path -> (shape, `Init`) of ``ActorCritic(net_cfg)``."""
    b = 1
    obs = jnp.zeros((1, b, *net_cfg.obs_shape), net_cfg.obs_dtype)
    return initialisers.param_inits(
        ActorCritic(net_cfg), initial_carry(net_cfg, (b,)), obs, jnp.zeros((1, b), bool)
    )


def init(key: jax.Array, net_cfg: NetworkConfig) -> Params:
    """Initial params of ``ActorCritic(net_cfg)`` (a nested dict of float32 arrays); pure, so it can be
    vmapped over keys. Every parameter is a slice of one of two flat random buffers (`initialisers.draw`): a
    separate `jax.random` call per tensor costs ~0.4 s of XLA:CPU compile time each (11 s for the whole
    network).
    """
    return initialisers.draw(key, _initialisers(net_cfg))


def initial_carry(net_cfg: NetworkConfig, batch_shape: tuple[int, ...]) -> Carry:
    """Zero LSTM state for a batch of shape `batch_shape`."""
    zeros = jnp.zeros((*batch_shape, net_cfg.hidden), jnp.float32)
    return Carry(c=zeros, h=zeros)


def param_count(params: Params) -> int:
    """Total number of scalars in `params` (works on arrays and on `jax.ShapeDtypeStruct`s)."""
    return sum(math.prod(leaf.shape) for leaf in jax.tree_util.tree_leaves(params))


def unroll(
    params: Params, net_cfg: NetworkConfig, carry: Carry, obs: jax.Array, resets: jax.Array
) -> tuple[Carry, Output]:
    """`ActorCritic` over T steps of B sequences: carry `Carry` f32[B, H] x 2, obs uint8[T, B, 21, 21, 3]
    (symbolic: int8[T, B, 7, 7, 4]), resets bool[T, B] -> (final `Carry`, `Output` with T and B axes)."""
    return ActorCritic(net_cfg).apply({"params": params}, carry, obs, resets)


def step(
    params: Params, net_cfg: NetworkConfig, carry: Carry, obs: jax.Array, reset: jax.Array
) -> tuple[Carry, Output]:
    """One step for acting: obs uint8[B, 21, 21, 3] (or int8[B, 7, 7, 4]), reset bool[B]; `Output` fields
    have no T axis."""
    carry, out = unroll(params, net_cfg, carry, obs[None], reset[None])
    return carry, jax.tree_util.tree_map(lambda x: x[0], out)


def aux_loss(
    params: Params,
    net_cfg: NetworkConfig,
    hidden: jax.Array,
    action: jax.Array,
    target: jax.Array,
    weight: jax.Array,
    axis_name: str | None = None,
) -> jax.Array:
    """Weighted auxiliary loss ``sum(weight * mean|decode(hidden, action) - target / 255|)``, f32[], computed
    with its gradient frame batch by frame batch (`aux_loss.fused_aux_loss`, which says how; symbolic views:
    the masked cross-entropy). hidden f32[..., H]; action int[...]; target uint8[..., 21, 21, 3] (the current
    view for aux "rec", the next one for "pred"); weight f32[...]. Raises ValueError without a decoder."""
    return fused_aux_loss(Decoder(net_cfg), params, hidden, action, target, weight, axis_name)


def attention_loss(params: Params, net_cfg: NetworkConfig, hidden: jax.Array, target: jax.Array, weight):
    """Weighted attention loss ``sum(weight * mean_k CE(logits_k, target_k))``, f32[].

    hidden f32[..., H]; target int[..., K] each other slot's view cell (`observe.attention_targets`:
    row * 7 + col, or 49 when not in view); weight f32[...]. Raises ValueError without the attention head.
    """
    chex.assert_shape(target, (*hidden.shape[:-1], net_cfg.n_others))
    logits = ActorCritic(net_cfg).apply({"params": params}, hidden, method=ActorCritic.attention_logits)
    log_probs = jax.nn.log_softmax(logits)
    nll = -jnp.take_along_axis(log_probs, target[..., None].astype(jnp.int32), -1)[..., 0]
    return jnp.sum(weight * jnp.mean(nll, -1))


def decode(params: Params, net_cfg: NetworkConfig, hidden: jax.Array, action: jax.Array) -> jax.Array:
    """Auxiliary prediction f32[..., 21, 21, 3] from LSTM outputs f32[..., H] and actions int[...].

    Unbounded (linear output layer); the learner compares it with obs / 255 (see `aux_loss`, which
    computes that comparison and its gradient faster). Symbolic views: logits f32[..., 7, 7, PREDICTED_VOCAB]
    (`symbolic_errors`). Raises ValueError without a decoder.
    """
    return ActorCritic(net_cfg).apply({"params": params}, hidden, action, method=ActorCritic.decode)
