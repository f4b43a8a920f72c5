"""Parameter initialisers, and a params tree drawn from two random buffers instead of one draw per tensor.

Modules create each parameter with `param` and an `Init` (its distribution), which it notes;
`param_inits(module, *args)` collects every parameter's path -> (shape, `Init`) from an abstract
``module.init``, and `sample_params(key, specs)` builds the params tree (float32 arrays) from one
standard-normal and one U(-1, 1) buffer: a `jax.random` call per tensor costs ~0.4 s of XLA:CPU compile time
each. Orthogonal matrices come from Gram-Schmidt (`_gram_schmidt` says why not ``jnp.linalg.qr``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import traverse_util
from jax import lax

Params = dict[str, Any]
_INITS = "intermediates"  # collection where `param` notes each initialiser (see `param_inits`)


@jax.tree_util.register_static
@dataclasses.dataclass(frozen=True)
class Init:
    """A parameter's initialiser, usable as a Flax initialiser ``(key, shape, dtype) -> array``.

    kind: "uniform" (U(-arg, arg)), "normal" (N(0, arg^2)), "orthogonal" (gain arg; `blocks` independent
    orthogonal blocks side by side along the last axis) or "zeros". A static pytree (no leaves), so `param`
    can note it in a collection that `jax.eval_shape` passes through.
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


ZEROS = Init("zeros")

Specs = dict[tuple[str, ...], tuple[tuple[int, ...], Init]]  # parameter path -> (shape, `Init`)


def param(module: nn.Module, name: str, init: Init, shape: tuple[int, ...]) -> jax.Array:
    """``module.param(name, init, shape)``, noting `init` in the `_INITS` collection when it is mutable
    (only `param_inits` asks: Flax's own ``Module.init`` leaves that collection immutable).

    Where the parameter exists (every apply), it is returned after a check of its shape: Flax's own check
    traces the initialiser abstractly (an orthogonal one's Gram-Schmidt loop too) on every apply of every
    layer. `param_inits` needs shapes only, so it gets `ZEROS`."""
    if module.has_variable("params", name):
        value = module.get_variable("params", name)
        if value.shape != shape:
            where = "/".join((*module.path, name))
            raise ValueError(f"{where}: the params hold {value.shape}, the network {shape}")
        return value
    if module.sow(_INITS, name, init):
        init = ZEROS
    return module.param(name, init, shape)


def param_inits(module: nn.Module, *args) -> Specs:
    """Every parameter's path -> (shape, `Init`) of ``module.init(key, *args)``, from an abstract call."""
    variables = jax.eval_shape(
        lambda key: module.init(key, *args, mutable=["params", _INITS]), jax.random.key(0)
    )
    shapes = traverse_util.flatten_dict(variables["params"])
    inits = traverse_util.flatten_dict(variables[_INITS])
    return {path: (shapes[path].shape, inits[path][0]) for path in shapes}


def sample_params(key: jax.Array, specs: Specs) -> Params:
    """The params tree of `specs` (nested dict of float32 arrays); pure, so it can be vmapped over keys.

    Every parameter is a slice of one of two flat random buffers (standard normal and U(-1, 1)), in the
    params' sorted path order.
    """
    specs = sorted(specs.items())
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
