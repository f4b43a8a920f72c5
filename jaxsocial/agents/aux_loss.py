"""The learner's auxiliary frame loss, fused with its gradient: `aux_loss`, the weighted error of the
`modules.Decoder`'s predictions, whose forward pass runs the decoder's backward pass too, frame batch by frame
batch.

Measurements (10-20% faster than layers run in frame batches with every decoder activation saved):
docs/performance.md.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import chex
import jax
import jax.numpy as jnp
from jax import lax

from jaxsocial.agents.fast.frame_batches import split_frame_batches
from jaxsocial.agents.initialisers import Params
from jaxsocial.agents.modules import Decoder
from jaxsocial.agents.network_config import NetworkConfig


def aux_loss(
    params: Params,
    net_cfg: NetworkConfig,
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
    decoder's backward pass too, frame batch by frame batch (`NetworkConfig.frame_batch` frames) while each
    batch's activations are in cache. It keeps the gradients (of the decoder params, and f32[N, H] of hidden)
    rather than every frame's activations; the backward pass only scales them by the incoming cotangent.
    """
    net_cfg.check_decoder()
    batch = hidden.shape[:-1]
    chex.assert_shape([hidden, target], [(*batch, net_cfg.hidden), (*batch, *net_cfg.obs_shape)])
    chex.assert_type(target, net_cfg.obs_dtype)
    decoder = {name: params[name] for name in net_cfg.decoder_params}
    if axis_name is not None:  # per-device gradients; pcast's transpose sums them over the devices
        decoder = lax.pcast(decoder, axis_name, to="varying")
    n = math.prod(batch)
    rows = (
        hidden.reshape(n, hidden.shape[-1]),
        jnp.asarray(action).reshape(n),
        target.reshape(n, *net_cfg.obs_shape),
        jnp.broadcast_to(jnp.asarray(weight, jnp.float32), batch).reshape(n),
    )
    return _fused_aux_loss(net_cfg, decoder, *rows)


def _decoder_apply(net_cfg: NetworkConfig, decoder: Params, method: Callable, *args) -> jax.Array:
    """A `Decoder` method applied to the decoder's entries of the params tree (`DECODER_PARAMS`)."""
    return Decoder(net_cfg).apply({"params": decoder}, *args, method=method)


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _fused_aux_loss(net_cfg: NetworkConfig, decoder: Params, hidden, action, target, weight) -> jax.Array:
    return jnp.sum(weight * _decoder_apply(net_cfg, decoder, Decoder.errors, hidden, action, target))


def _fused_aux_loss_fwd(net_cfg: NetworkConfig, decoder: Params, hidden, action, target, weight):
    """The loss and its gradients, frame batch by frame batch: a `lax.scan` over batches of rows (padded with
    weight 0) that sums the decoder params' gradients and stacks those of hidden and weight (= the frame
    errors)."""
    n = hidden.shape[0]
    rows = split_frame_batches((hidden, action, target, weight), min(net_cfg.frame_batch, n))

    def batch_grads(d_decoder, inputs):
        hidden, action, target, weight = inputs

        def weighted_error(decoder, hidden):
            errors = _decoder_apply(net_cfg, decoder, Decoder.frame_errors, hidden, action, target)
            return jnp.sum(weight * errors), errors

        (d_batch, d_hidden), errors = jax.grad(weighted_error, argnums=(0, 1), has_aux=True)(decoder, hidden)
        return jax.tree.map(jnp.add, d_decoder, d_batch), (d_hidden, errors)

    d_decoder, (d_hidden, errors) = lax.scan(batch_grads, jax.tree.map(jnp.zeros_like, decoder), rows)
    d_hidden, errors = d_hidden.reshape(-1, hidden.shape[-1])[:n], errors.reshape(-1)[:n]
    return jnp.sum(weight * errors), (d_decoder, d_hidden, errors)


def _fused_aux_loss_bwd(net_cfg: NetworkConfig, residuals, g):
    del net_cfg
    d_decoder, d_hidden, errors = residuals
    return jax.tree.map(lambda x: g * x, d_decoder), g * d_hidden, None, None, g * errors


_fused_aux_loss.defvjp(_fused_aux_loss_fwd, _fused_aux_loss_bwd)
