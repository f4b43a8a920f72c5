"""3x3 convolutions of the network (`modules.Conv`): fast matrix-product kernels and the XLA reference.

Activations are HWNC ``f32[h, w, n, c]`` (spatial axes first: a linear map over the pixels of every frame and
channel is one matrix product with ``x.reshape(h * w, n * c)``, a product over the channels of every pixel a
batched product over the h * w pixels); kernels are HWIO ``f32[3, 3, c_in, c_out]``; biases ``f32[c_out]``.

* `conv`: VALID cross-correlation, like torch Conv2d: ``out[i, j] = sum_{di, dj} x[s*i + di, s*j + dj] @
  kernel[di, dj] + bias``.
* `deconv`: VALID transposed convolution with scatter semantics, like torch ConvTranspose2d:
  ``out[s*i + di, s*j + dj] += x[i, j] @ kernel[di, dj]``, plus the bias.

Implementations (`IMPLS`; the same function of the same arguments):

* "matmul": matrix products only (XLA:CPU's convolutions and their gradients are slow for these small
  images). Stride 1 in float32: Winograd's minimal filtering with one tile per frame, F(m x m, 3 x 3) for an
  m x m output (`winograd_transforms`; m <= 5); the transposed convolution is its adjoint. Stride 1 in
  bfloat16: "im2col" (Winograd's transforms amplify the rounding of their inputs: bfloat16 F(5 x 5, 3 x 3)
  measured 5% of a layer's largest output off, a direct product 0.2%). Stride 3 (= kernel size,
  non-overlapping 3x3 blocks): a reshape/transpose into blocks and one matrix product.
* "im2col": stride 1 as one matrix product of the 3x3 patches (K = 9 c_in); the transposed convolution as one
  product followed by the sum of its 9 shifted outputs. Stride 3 as "matmul".
* "xla": ``lax.conv_general_dilated`` / ``lax.conv_transpose`` in NHWC (exact reference).

`dtype` (`options.DTYPES`): the products' input dtype; they accumulate in float32 (`precision.matmul`).
Measurements behind these choices: docs/performance.md.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxsocial.agents.fast.options import IMPLS, KERNEL
from jaxsocial.agents.fast.precision import matmul


def formulation(impl: str, stride: int, dtype: str = "float32") -> str:
    """The computation `impl` runs for a layer of `stride` in `dtype`: "winograd", "im2col", "blocks" (stride
    3) or "xla". Implementations with one formulation compute alike (the autotune measures one of them)."""
    if impl not in IMPLS:
        raise ValueError(f"unknown convolution implementation {impl!r}; choose from {IMPLS}")
    if impl == "xla":
        return "xla"
    _check_stride(stride)
    if stride == KERNEL:
        return "blocks"
    return "winograd" if impl == "matmul" and dtype == "float32" else "im2col"


def conv(
    x: jax.Array, kernel: jax.Array, bias: jax.Array, stride: int, impl: str, dtype: str = "float32"
) -> jax.Array:
    """VALID cross-correlation: x f32[h, w, n, c_in] -> f32[(h - 3) // s + 1, (w - 3) // s + 1, n, c_out]."""
    fn = {"matmul": _conv_matmul, "im2col": _conv_im2col, "xla": _conv_xla}[impl]
    return fn(x, kernel, bias, stride, dtype)


def deconv(
    x: jax.Array, kernel: jax.Array, bias: jax.Array, stride: int, impl: str, dtype: str = "float32"
) -> jax.Array:
    """VALID transposed convolution: x f32[h, w, n, c_in] -> f32[s (h - 1) + 3, s (w - 1) + 3, n, c_out]."""
    fn = {"matmul": _deconv_matmul, "im2col": _deconv_im2col, "xla": _deconv_xla}[impl]
    return fn(x, kernel, bias, stride, dtype)


def to_hwnc(images: jax.Array) -> jax.Array:
    """Frames [n, h, w, c] -> [h, w, n, c] (the conv layers' layout)."""
    return images.transpose(1, 2, 0, 3)


def to_nhwc(x: jax.Array) -> jax.Array:
    """HWNC [h, w, n, c] -> frames [n, h, w, c]."""
    return x.transpose(2, 0, 1, 3)


def blocks(x: jax.Array) -> jax.Array:
    """HWNC [3h, 3w, n, c] -> its non-overlapping 3x3 blocks [h, w, n, 9c], entries in (di, dj, c) order (the
    rows of an HWIO kernel)."""
    h, w, n, c = x.shape
    k = KERNEL
    return (
        x.reshape(h // k, k, w // k, k, n, c)
        .transpose(0, 2, 4, 1, 3, 5)
        .reshape(h // k, w // k, n, k * k * c)
    )


# ---------------------------------------------------------------------------------------------- matmul


@functools.cache
def winograd_transforms(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Single-tile Winograd F(m x m, 3 x 3): float32 matrices data [a^2, a^2], filter [a^2, 9] and output
    [m^2, a^2], a = m + 2, such that the VALID 3x3 cross-correlation of one a x a input tile d with a kernel g
    (one channel pair) is ``output @ ((filter @ vec(g)) * (data @ vec(d)))``: a^2 multiplies, not 9 m^2.

    Toom-Cook construction (Lavin & Gray 2016) in float64 with interpolation points 0, 1, -1, 2, -2, 1/2 (the
    first a - 1 of them) and infinity: the 1D output (A^T) and filter (G) matrices from the points, the data
    matrix (B^T) solved from the identity ``sum_j At[i, j] G[j, k] Bt[j, l] = [l == i + k]``; the 2D
    transforms are Kronecker products.
    """
    points = (0.0, 1.0, -1.0, 2.0, -2.0, 0.5)[: m + 1]
    if len(points) != m + 1:
        raise NotImplementedError(f"Winograd transforms are defined for output sizes up to 5, got {m}")
    a = m + KERNEL - 1
    out_1d, filter_1d = np.zeros((m, a)), np.zeros((a, KERNEL))
    for j, p in enumerate(points):
        out_1d[:, j] = [p**i for i in range(m)]
        filter_1d[j] = [p**k / math.prod(p - q for q in points if q != p) for k in range(KERNEL)]
    out_1d[m - 1, a - 1] = filter_1d[a - 1, KERNEL - 1] = 1.0  # the point at infinity
    # Equation (i, k, l) in the unknowns Bt[j, q]: sum_j At[i, j] G[j, k] Bt[j, q] [q == l] = [l == i + k].
    system = np.einsum("ij,jk,lq->ikljq", out_1d, filter_1d, np.eye(a)).reshape(-1, a * a)
    target = np.arange(a)[None, None, :] == np.arange(m)[:, None, None] + np.arange(KERNEL)[None, :, None]
    data_1d = np.linalg.lstsq(system, target.ravel().astype(np.float64), rcond=None)[0].reshape(a, a)
    data_1d[np.abs(data_1d) < 1e-12] = 0.0  # the solver's noise: exact zeros (so the transforms stay sparse)
    assert np.abs(system @ data_1d.ravel() - target.ravel()).max() < 1e-9, "inconsistent Winograd system"
    return tuple(np.kron(t, t).astype(np.float32) for t in (data_1d, filter_1d, out_1d))


def _winograd_kernel(kernel: jax.Array, m: int) -> jax.Array:
    """HWIO kernel [3, 3, c_in, c_out] -> its F(m x m, 3 x 3) transform [(m + 2)^2, c_in, c_out]."""
    _, filter_, _ = winograd_transforms(m)
    return (filter_ @ kernel.reshape(KERNEL * KERNEL, -1)).reshape(-1, *kernel.shape[2:])


def transformed_pixels(transform: np.ndarray, x: jax.Array) -> jax.Array:
    """x f32[h, w, n, c] through a Winograd pixel transform [a^2, h w] -> f32[a^2, n, c]: one product.
    Recomputed in the backward pass, not saved (saving it measured slower: docs/performance.md)."""
    h, w, n, c = x.shape
    return (transform @ x.reshape(h * w, -1)).reshape(transform.shape[0], n, c)


def _winograd_conv(x, kernel, bias):
    """VALID stride-1 cross-correlation of x f32[m+2, m+2, n, c_in] -> f32[m, m, n, c_out]: a transform of the
    pixels, a batched product over the (m+2)^2 transformed pixels, an output transform."""
    a, n = x.shape[0], x.shape[2]
    m = a - KERNEL + 1
    data, _, out = winograd_transforms(m)
    y = out @ jnp.matmul(transformed_pixels(data, x), _winograd_kernel(kernel, m)).reshape(a * a, -1)
    return y.reshape(m, m, n, -1) + bias


def _winograd_deconv(x, kernel, bias):
    """Stride-1 transposed convolution of x f32[m, m, n, c_in] -> f32[m+2, m+2, n, c_out]: `_winograd_conv`'s
    adjoint (transposed transforms)."""
    m, n = x.shape[0], x.shape[2]
    a = m + KERNEL - 1
    data, _, out = winograd_transforms(m)
    y = data.T @ jnp.matmul(transformed_pixels(out.T, x), _winograd_kernel(kernel, m)).reshape(a * a, -1)
    return y.reshape(a, a, n, -1) + bias


def _check_stride(stride: int) -> None:
    if stride not in (1, KERNEL):
        raise NotImplementedError(
            f"matmul convolutions support stride 1 or {KERNEL} (kernel size), got {stride}"
        )


def _conv_matmul(x, kernel, bias, stride: int, dtype: str):
    _check_stride(stride)
    if stride == 1:
        return _winograd_conv(x, kernel, bias) if dtype == "float32" else _im2col_conv(x, kernel, bias, dtype)
    h, w, _, c = x.shape
    k = KERNEL
    return matmul(blocks(x[: h // k * k, : w // k * k]), kernel.reshape(k * k * c, -1), dtype) + bias


def _deconv_matmul(x, kernel, bias, stride: int, dtype: str):
    _check_stride(stride)
    if stride == 1:
        if dtype == "float32":
            return _winograd_deconv(x, kernel, bias)
        return _im2col_deconv(x, kernel, bias, dtype)
    h, w, n, c = x.shape
    k, c_out = KERNEL, kernel.shape[-1]
    # (the bias is added before the transpose: its gradient then reduces [*, k*k*c_out], not a 3-wide axis)
    cols = _kernel_columns(x, kernel, dtype) + jnp.tile(bias, k * k)
    return cols.reshape(h, w, n, k, k, c_out).transpose(0, 3, 1, 4, 2, 5).reshape(h * k, w * k, n, c_out)


def _kernel_columns(x, kernel, dtype: str):
    """x f32[..., c_in] times every kernel tap: f32[..., 9 c_out] in (di, dj, c_out) order."""
    return matmul(x, kernel.transpose(2, 0, 1, 3).reshape(kernel.shape[2], -1), dtype)


# ---------------------------------------------------------------------------------------------- im2col


def _im2col_conv(x, kernel, bias, dtype: str):
    """Stride-1 cross-correlation: one product of the 3x3 patches f32[m, m, n, 9 c_in] ((di, dj, c) order)."""
    h, w, _, c = x.shape
    oh, ow = h - KERNEL + 1, w - KERNEL + 1
    taps = [x[di : di + oh, dj : dj + ow] for di in range(KERNEL) for dj in range(KERNEL)]
    return matmul(jnp.concatenate(taps, axis=-1), kernel.reshape(KERNEL * KERNEL * c, -1), dtype) + bias


def _im2col_deconv(x, kernel, bias, dtype: str):
    """Stride-1 transposed convolution: every tap's product at once, then their 9 shifted sums (col2im)."""
    h, w, n, _ = x.shape
    cols = _kernel_columns(x, kernel, dtype).reshape(h, w, n, KERNEL, KERNEL, -1)
    pad = KERNEL - 1
    out = sum(
        jnp.pad(cols[:, :, :, di, dj], [(di, pad - di), (dj, pad - dj), (0, 0), (0, 0)])
        for di in range(KERNEL)
        for dj in range(KERNEL)
    )
    return out + bias


def _conv_im2col(x, kernel, bias, stride: int, dtype: str):
    _check_stride(stride)
    if stride == 1:
        return _im2col_conv(x, kernel, bias, dtype)
    return _conv_matmul(x, kernel, bias, stride, dtype)


def _deconv_im2col(x, kernel, bias, stride: int, dtype: str):
    _check_stride(stride)
    if stride == 1:
        return _im2col_deconv(x, kernel, bias, dtype)
    return _deconv_matmul(x, kernel, bias, stride, dtype)


# ------------------------------------------------------------------------------------------------- xla

# XLA:CPU's convolutions run NHWC (its HWNC convolutions measured 12x slower): transposes around them.
_NHWC = ("NHWC", "HWIO", "NHWC")


def _conv_xla(x, kernel, bias, stride: int, dtype: str):
    out = lax.conv_general_dilated(
        to_nhwc(x).astype(dtype),
        kernel.astype(dtype),
        (stride, stride),
        "VALID",
        dimension_numbers=_NHWC,
        preferred_element_type=jnp.float32,
    )
    return to_hwnc(out + bias)


def _deconv_xla(x, kernel, bias, stride: int, dtype: str):
    # lax.conv_transpose (transpose_kernel=False) correlates the dilated, padded input with the kernel;
    # flipping the kernel spatially gives the scatter semantics.
    out = lax.conv_transpose(
        to_nhwc(x).astype(dtype),
        kernel[::-1, ::-1].astype(dtype),
        (stride, stride),
        "VALID",
        dimension_numbers=_NHWC,
        preferred_element_type=jnp.float32,
    )
    return to_hwnc(out + bias)
