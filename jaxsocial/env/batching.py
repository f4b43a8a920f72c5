"""A `lax.cond` predicate that stays unbatched under `jax.vmap`, to skip work whose results are masked."""

from __future__ import annotations

import jax
import jax.numpy as jnp


@jax.custom_batching.custom_vmap
def any_in_batch(x: jax.Array) -> jax.Array:
    """`jnp.any(x)`, and under `vmap` the any over the vmapped axes too (an unbatched bool[]).

    For the predicate of a `lax.cond` that only skips work whose results are masked anyway (new episodes
    where none ended; minibatches after every learner's KL early stop): with a batched predicate a vmapped
    cond runs both branches every time; with this one it stays a cond, and runs its work when any member of
    the batch needs it (e.g. `env.step` vmapped over environments, or an update over learners or seeds).
    """
    return jnp.any(x)


@any_in_batch.def_vmap
def _any_in_batch_vmap(axis_size: int, in_batched: list[bool], x: jax.Array):
    return jnp.any(x), False
