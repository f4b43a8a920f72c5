"""Frame batches and saved activations: how the conv encoder and the decoder run fast (speed, not results).

The conv layers run over `NetworkConfig.frame_batch` frames at a time, which keeps each layer's activations in
cache (`map_frame_batches`), and their backward pass keeps only each hidden layer's activation, the output of
`leaky_relu` (checkpoint name `SAVED`); the rest is recomputed from it. Measurements: docs/performance.md.

* `leaky_relu`: f32[...] -> f32[...], its output saved as the residual of its own gradient.
* `leaky_relu_unsaved`: the same function, recomputed in the backward pass.
* `map_frame_batches`: a row-wise ``fn(module, *rows)`` on rows [N, ...], `frame_batch` rows at a time.
* `split_frame_batches`: rows [N, ...] -> [ceil(N / frame_batch), frame_batch, ...], zero-padded.
"""

from __future__ import annotations

from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

LEAKY_SLOPE = 0.01  # torch.nn.functional.leaky_relu default
SAVED = "activation"  # checkpoint name of the layer outputs saved for the backward pass (`map_frame_batches`)


def leaky_relu_unsaved(x: jax.Array) -> jax.Array:
    return jnp.where(x >= 0, x, LEAKY_SLOPE * x)


@jax.custom_vjp
def leaky_relu(x: jax.Array) -> jax.Array:
    """Leaky ReLU whose output is the residual saved for the backward pass (named `SAVED`)."""
    return leaky_relu_unsaved(x)


def _leaky_relu_fwd(x):
    y = checkpoint_name(leaky_relu(x), SAVED)
    return y, y


# The derivative from the output (the sign is preserved), so the backward pass needs only the activation.
leaky_relu.defvjp(_leaky_relu_fwd, lambda y, g: (jnp.where(y >= 0, g, LEAKY_SLOPE * g),))


def map_frame_batches(
    fn: Callable, module: nn.Module, args: tuple[jax.Array, ...], frame_batch: int
) -> jax.Array:
    """``fn(module, *args)`` for a row-wise `fn` (row i of each arg -> row i of the output), `frame_batch`
    rows at a time.

    An ``nn.scan`` over frame batches (params broadcast) keeps each layer's activations in cache; for the
    backward pass (``nn.remat``) only the values `fn` names `SAVED` (each hidden layer's activation) are
    stored, the rest (e.g. the Winograd layers' transformed inputs) is recomputed from them. Rows are
    zero-padded to a multiple of `frame_batch`.
    """
    n = args[0].shape[0]
    if n <= frame_batch:
        return fn(module, *args)
    policy = jax.checkpoint_policies.save_only_these_names(SAVED)
    body = nn.remat(lambda mdl, carry, rows: (carry, fn(mdl, *rows)), policy=policy, prevent_cse=False)
    scan = nn.scan(body, variable_broadcast="params", split_rngs={"params": False})
    _, out = scan(module, None, split_frame_batches(args, frame_batch))
    return out.reshape(-1, *out.shape[2:])[:n]


def split_frame_batches(args: tuple[jax.Array, ...], frame_batch: int) -> tuple[jax.Array, ...]:
    """Rows [N, ...] -> [ceil(N / frame_batch), frame_batch, ...], zero-padded to a multiple of
    `frame_batch`."""
    n = args[0].shape[0]
    pad = -n % frame_batch
    args = tuple(jnp.pad(x, [(0, pad)] + [(0, 0)] * (x.ndim - 1)) if pad else x for x in args)
    return tuple(x.reshape(-1, frame_batch, *x.shape[1:]) for x in args)
