"""Recurrent actor-critic network of Ndousse et al. (2021), appendix "Network architecture details".

The front door: `NetworkConfig` and the functions the learners call (`init`, `initial_carry`, `unroll`,
`step`, `decode`, `aux_loss`, `attention_loss`, `param_count`), which apply the Flax linen `ActorCritic` to a
params dict. Linen, because its params are plain nested dicts of float32 arrays: independent agents stack them
on a leading axis (``jax.vmap(unroll, in_axes=(0, None, 0, 0, 0))``), seeds ``lax.map`` over them, and orbax
saves them as they are. ``ActorCritic(net_cfg).init(key, carry, obs, resets)`` and ``.apply`` are the same
model for use with other Flax code (`init` draws the same distributions from two random buffers, which
compiles ~10x faster than one draw per tensor).

The parts, one job each:

* `modules`: the Flax modules that run (`ActorCritic`, `Encoder`, `Decoder`, `Conv`, `Embed`), the network
  that trains. The tests hold it to the same function of the same params in plain Flax layers
  (`PaperActorCritic` in tests/reference_network.py: ``nn.Conv`` on NHWC frames, float32, in one piece).
* `network_config`: `NetworkConfig` and the shapes that follow from it.
* `layers`: the plain layers the network is built of (`Dense`, `MLP`, `LSTM`).
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
import jax
import jax.numpy as jnp

from jaxsocial.agents import initialisers
from jaxsocial.agents.aux_loss import fused_aux_loss
from jaxsocial.agents.fast.conv import KERNEL
from jaxsocial.agents.initialisers import Params
from jaxsocial.agents.layers import Carry, Output
from jaxsocial.agents.modules import ActorCritic, Decoder
from jaxsocial.agents.network_config import (
    ATTENTION_CLASSES,
    CONV_IMPLS,
    DECODER_PARAMS,
    DTYPES,
    OBS_SHAPE,
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
    vmapped over keys. Every parameter is a slice of one of two flat random buffers
    (`initialisers.sample_params`): a separate `jax.random` call per tensor costs ~0.4 s of XLA:CPU compile
    time each (11 s for the whole network).
    """
    return initialisers.sample_params(key, _initialisers(net_cfg))


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
