"""Mixed-precision matrix products: inputs rounded to a compute dtype, products accumulated in float32.

`NetworkConfig.dtype` names the compute dtype (`options.DTYPES`). With "bfloat16" every matrix product and
convolution of the network takes bfloat16 inputs (an 8-bit significand: each input is rounded with a
relative error of at most 2^-8, its unit roundoff) and accumulates in float32 (``preferred_element_type``);
everything else, params, optimiser state, LSTM cell state, nonlinearities, losses and advantages, stays
float32.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp


def matmul(x: jax.Array, kernel: jax.Array, dtype: str) -> jax.Array:
    """``x @ kernel`` for x f32[..., k] and kernel f32[k, n] -> f32[..., n], with inputs rounded to `dtype`.

    float32: the plain product. bfloat16: inputs cast to bfloat16, accumulation in float32, and the backward
    pass likewise (the incoming gradient is rounded to bfloat16, the gradients accumulate in float32 and are
    returned in float32), as PyTorch's autocast does; the saved residuals are the bfloat16 inputs.
    """
    if dtype == "float32":
        return x @ kernel
    return _low_precision_matmul(x, kernel, jnp.dtype(dtype))


def _dot(a: jax.Array, b: jax.Array, contract: tuple[int, int]) -> jax.Array:
    """a and b contracted over axes `contract`, float32 accumulation."""
    dims = (((contract[0],), (contract[1],)), ((), ()))
    return jax.lax.dot_general(a, b, dims, preferred_element_type=jnp.float32)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _low_precision_matmul(x, kernel, dtype):
    return _dot(x.astype(dtype), kernel.astype(dtype), (x.ndim - 1, 0))


def _low_precision_matmul_fwd(x, kernel, dtype):
    xc, kc = x.astype(dtype), kernel.astype(dtype)
    return _dot(xc, kc, (x.ndim - 1, 0)), (xc, kc)


def _low_precision_matmul_bwd(dtype, residuals, g):
    xc, kc = residuals
    gc = g.astype(dtype)
    d_x = _dot(gc, kc, (gc.ndim - 1, 1))  # [..., n] . [k, n] -> [..., k]
    rows = xc.reshape(-1, xc.shape[-1])
    d_kernel = _dot(rows, gc.reshape(-1, gc.shape[-1]), (0, 0))  # [r, k] . [r, n] -> [k, n]
    return d_x, d_kernel


_low_precision_matmul.defvjp(_low_precision_matmul_fwd, _low_precision_matmul_bwd)
