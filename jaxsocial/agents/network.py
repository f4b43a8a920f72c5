"""Recurrent actor-critic network of Ndousse et al. (2021), appendix "Network architecture details".

Pure functions over a plain params pytree (nested dicts of float32 arrays), so independent agents can stack
params on a leading axis and ``jax.vmap(unroll, in_axes=(0, None, 0, 0, 0))``.

Architecture (paper widths; every width is a `NetworkConfig` field)::

    obs uint8[21, 21, 3] / 255
      -> Conv(3->32, 3x3, stride 3) -> leaky ReLU       21x21 -> 7x7
      -> Conv(32->64, 3x3, stride 1) -> leaky ReLU      7x7 -> 5x5
      -> Conv(64->64, 3x3, stride 1) -> leaky ReLU      5x5 -> 3x3, flattened to 576
      -> FC(576->192) -> tanh -> LSTM(192)               hidden h
    value  = MLP(192->64->64->1), tanh hidden layers
    logits = MLP(192->64->64->7), tanh hidden layers
    aux    = FC(192+7 -> 576) on concat(h, one_hot(action)) -> tanh -> reshape (3, 3, 64)
      -> DeConv(64->64, 3x3, s1) -> leaky ReLU -> DeConv(64->32, 3x3, s1) -> leaky ReLU
      -> DeConv(32->3, 3x3, stride 3)                    3x3 -> 5x5 -> 7x7 -> 21x21x3, linear output
         (compared by the learner with an MAE against obs / 255: the current frame for aux="rec",
          the next frame for aux="pred"; both build the same decoder)
    attention = FC(192 -> K * 50), K = n_others          with aux "attention", "rec+attention" or
         "pred+attention" (an addition after Bhoopchand et al. 2023, not in the paper): for each other
         agent slot, logits over its cell in the 7x7 view plus "not in view" (`attention_loss`)

Parameter count: 667,787 for the paper configuration. The PyTorch reference
(benchmarks/pytorch_paper_net.py) has 668,555 = 667,787 + 768 because ``torch.nn.LSTM`` keeps two
bias vectors (``b_ih`` and ``b_hh``, 4 * 192 each) of which only the sum matters; here the LSTM has one.
Without the auxiliary decoder (aux="none"): 496,328. The attention head adds 193 * 50 * n_others.

Layouts and conventions:
  * frames are [n, h, w, c] at the interface (uint8 observations, decoded predictions); inside, the conv
    layers take and return HWNC activations [h, w, n, c] (see "matmul" below); conv kernels are HWIO
    ``[3, 3, C_in, C_out]`` (cross-correlation, like torch Conv2d);
  * deconv kernels are ``[3, 3, C_in, C_out]`` with torch ConvTranspose2d (scatter) semantics:
    ``out[s*i + di, s*j + dj, :] += x[i, j, :] @ kernel[di, dj]``;
  * LSTM gates are ordered (i, f, g, o) like PyTorch: ``gates = x @ wi + h @ wh + b``.

Convolution implementations (``NetworkConfig.conv_impl``; same function of the same params):
  * "matmul": matrix products only; XLA's CPU convolutions, and especially their gradients, are slow for
    these small images, matrix products are not. The stride-1 layers (conv2, conv3, deconv1, deconv2) use
    Winograd's minimal filtering with one tile per image: F(5x5, 3x3) on the 7x7 maps and F(3x3, 3x3) on the
    5x5 maps (`_winograd_transforms`), 49 and 25 multiplies per channel pair instead of 225 and 81. With HWNC
    activations each layer is a transform of the pixels (one matrix product ``[a^2, a^2] @ [a^2, n * C]``),
    a batched product over the a^2 transformed pixels (``[n, C_in] @ [C_in, C_out]`` each) and an output
    transform; the deconvolutions are the adjoints (transposed transforms). The matrix-product FLOPs of a
    paper-network gradient sample drop from 13.2 M to 7.8 M, and the step ran ~1.35x faster than the im2col
    formulation it replaced (patch concatenation + one product with K = 9 * C_in; interleaved A/B in one
    process). float32 error: ~5e-6 of a layer's largest output for F(5x5, 3x3), against ~1e-7 for a direct
    product; the tests hold outputs and gradients to 1e-5 of the exact "xla" implementation's. conv1 and
    deconv3 (stride 3 = kernel size) have non-overlapping 3x3 blocks: a transpose and one matrix product.
  * "xla": ``lax.conv_general_dilated`` / ``lax.conv_transpose`` (exact reference; slow gradients on CPU).

CPU performance (benchmarks/train_sps.py): besides the matrix-product convolutions, the conv encoder and the
decoder run in chunks of `NetworkConfig.chunk` frames under `lax.map` (`_map_chunks`), which keeps
activations in cache, and save only each layer's activation for the backward pass; the encoder's dense
layers run on the whole batch. The learner's auxiliary loss (`aux_loss`) goes further: the decoder's backward
pass runs right after its forward pass, chunk by chunk, so no decoder activation or predicted frame of the
whole batch is ever stored. Together 10-20% faster than chunked layers with every decoder activation saved.
``jax.default_matmul_precision`` has no effect on CPU (float32 throughout), and no XLA flag tried
(XNNPACK/YNNPACK fusion types, oneDNN, vector width, fast math) helped; none is set here. Tried with the
im2col formulation and slower: im2col and col2im as gathers with constant indices; no faster: conv1's
patches and deconv3's output kept in the 3x3-block layout (no float32 transposes), and (per layer) a
batch-minor [C, H, W, N] layout. With Winograd: chunks of 256 or 512 frames measure alike, 128 and 1024
slower; no faster: separable (two 1D) pixel transforms instead of the Kronecker products (measured per
transform), and the batched products' weight gradients as explicitly transposed products (whole step;
XLA:CPU runs those gradients, which contract the batch rows, outside YNNPACK).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.ad_checkpoint import checkpoint_name

Params = dict[str, Any]

OBS_SHAPE = (21, 21, 3)  # 7x7 grid cells of 3x3 pixels (marlgrid tile size 3)
KERNEL = 3
STRIDES = (3, 1, 1)  # encoder strides; the decoder mirrors them in reverse order
LEAKY_SLOPE = 0.01  # torch.nn.functional.leaky_relu default
AUX_KINDS = ("none", "rec", "pred", "attention", "rec+attention", "pred+attention")
ATTENTION_CLASSES = (OBS_SHAPE[0] // KERNEL) ** 2 + 1  # the 7x7 view cells, then "not in view"
CONV_IMPLS = ("matmul", "xla")
_SAVED = "activation"  # checkpoint name of the layer outputs saved for the backward pass (`_map_chunks`)


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Widths of the network; the defaults are the paper's."""

    conv_channels: tuple[int, int, int] = (32, 64, 64)
    hidden: int = 192  # FC and LSTM width
    mlp: int = 64  # hidden width of the value and policy MLPs
    aux: str = "pred"  # one of AUX_KINDS: a frame loss ("rec", "pred") and/or "attention"
    n_actions: int = 7
    conv_impl: str = "matmul"  # "matmul" (patches + dot, fast on CPU) | "xla" (lax.conv / conv_transpose)
    chunk: int = 512  # frames per chunk of the conv encoder and decoder (speed only, see `_map_chunks`)
    n_others: int = 2  # other agent slots the attention head locates (n_agents - 1; aux with "attention")

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
        size = OBS_SHAPE[0]
        for stride in STRIDES:
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


# ----------------------------------------------------------------------------------------------- init


# Every parameter is drawn from one of two flat random buffers (standard normal and U(-1, 1)): a separate
# `jax.random` call per tensor costs ~0.4 s of XLA:CPU compile time each (11 s for the whole network).
# Specs: (shape, kind, arg) with kind "uniform" (arg = bound), "orthogonal" (arg = gain; a leading axis of
# independent blocks is concatenated along the output axis), "normal" (arg = std) or "zeros".
_Spec = tuple[tuple[int, ...], str, float]


def _conv_spec(c_in: int, c_out: int, fan_in: float) -> dict[str, _Spec]:
    """PyTorch's default conv init: weight and bias ~ U(-1/sqrt(fan_in), 1/sqrt(fan_in))."""
    bound = 1.0 / math.sqrt(fan_in)
    return {"kernel": ((KERNEL, KERNEL, c_in, c_out), "uniform", bound), "bias": ((c_out,), "uniform", bound)}


def _dense_spec(n_in: int, n_out: int, gain: float) -> dict[str, _Spec]:
    """Orthogonal weight with gain `gain`, zero bias (the usual actor-critic initialisation)."""
    return {"kernel": ((n_in, n_out), "orthogonal", gain), "bias": ((n_out,), "zeros", 0.0)}


def _mlp_spec(cfg: NetworkConfig, n_out: int, out_gain: float) -> dict[str, dict[str, _Spec]]:
    return {
        "dense0": _dense_spec(cfg.hidden, cfg.mlp, math.sqrt(2.0)),
        "dense1": _dense_spec(cfg.mlp, cfg.mlp, math.sqrt(2.0)),
        "out": _dense_spec(cfg.mlp, n_out, out_gain),
    }


def _param_specs(cfg: NetworkConfig) -> dict[str, Any]:
    c1, c2, c3 = cfg.conv_channels
    hid = cfg.hidden
    specs: dict[str, Any] = {}
    for name, (c_in, c_out) in zip(("conv1", "conv2", "conv3"), [(3, c1), (c1, c2), (c2, c3)], strict=True):
        specs[name] = _conv_spec(c_in, c_out, c_in * KERNEL * KERNEL)
    specs["fc"] = _dense_spec(cfg.feature_size, hid, math.sqrt(2.0))
    specs["lstm"] = {
        "wi": ((hid, 4 * hid), "normal", 1.0 / math.sqrt(hid)),
        "wh": ((4, hid, hid), "orthogonal", 1.0),
        "b": ((4 * hid,), "zeros", 0.0),
    }
    specs["value"] = _mlp_spec(cfg, 1, 1.0)
    specs["policy"] = _mlp_spec(cfg, cfg.n_actions, 0.01)
    if cfg.attention:
        specs["attention"] = _dense_spec(hid, cfg.n_others * ATTENTION_CLASSES, 0.01)
    if cfg.frame_aux != "none":
        specs["aux_fc"] = _dense_spec(hid + cfg.n_actions, cfg.feature_size, math.sqrt(2.0))
        for name, (c_in, c_out), stride in zip(
            ("deconv1", "deconv2", "deconv3"), [(c3, c2), (c2, c1), (c1, 3)], STRIDES[::-1], strict=True
        ):
            specs[name] = _conv_spec(c_in, c_out, c_in * KERNEL * KERNEL / stride**2)
    return specs


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


def init(key: jax.Array, cfg: NetworkConfig) -> Params:
    """Initial params (a nested dict of float32 arrays); pure, so it can be vmapped over keys.

    Convs: PyTorch's default uniform init (deconvs with the effective fan-in C_in * 9 / stride^2, the
    number of terms summed into one output pixel). Dense layers: orthogonal, gain sqrt(2) for hidden layers,
    1 for the value output and 0.01 for the policy output (near-uniform initial policy). LSTM: normal(0,
    1/hidden) input weights (LeCun), orthogonal recurrent weights per gate, zero bias.
    """
    specs = _param_specs(cfg)
    is_spec = lambda x: isinstance(x, tuple) and len(x) == 3 and isinstance(x[1], str)  # noqa: E731
    leaves, treedef = jax.tree_util.tree_flatten(specs, is_leaf=is_spec)
    sizes = {"normal": 0, "uniform": 0}
    for shape, kind, _ in leaves:
        sizes["uniform" if kind == "uniform" else "normal"] += math.prod(shape) if kind != "zeros" else 0
    k_normal, k_uniform = jax.random.split(key)
    buffers = {
        "normal": jax.random.normal(k_normal, (sizes["normal"],), jnp.float32),
        "uniform": jax.random.uniform(k_uniform, (sizes["uniform"],), jnp.float32, -1.0, 1.0),
    }
    offsets = {"normal": 0, "uniform": 0}
    params = []
    for shape, kind, arg in leaves:
        if kind == "zeros":
            params.append(jnp.zeros(shape, jnp.float32))
            continue
        source = "uniform" if kind == "uniform" else "normal"
        start, size = offsets[source], math.prod(shape)
        offsets[source] += size
        x = buffers[source][start : start + size].reshape(shape)
        if kind == "orthogonal":
            x = _orthogonal(x, arg)
            if len(shape) == 3:  # independent blocks (LSTM gates) side by side: [n_in, blocks * n_out]
                x = jnp.concatenate(list(x), axis=-1)
        else:
            x = arg * x
        params.append(x)
    return treedef.unflatten(params)


def initial_carry(cfg: NetworkConfig, batch_shape: tuple[int, ...]) -> Carry:
    """Zero LSTM state for a batch of shape `batch_shape`."""
    zeros = jnp.zeros((*batch_shape, cfg.hidden), jnp.float32)
    return Carry(c=zeros, h=zeros)


def param_count(params: Params) -> int:
    """Total number of scalars in `params` (works on arrays and on `jax.ShapeDtypeStruct`s)."""
    return sum(math.prod(leaf.shape) for leaf in jax.tree_util.tree_leaves(params))


# ------------------------------------------------------------------------------------ convolutions


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


# Convolution layers take and return HWNC activations [h, w, n, c]: spatial axes first, so a linear map over
# the pixels of every (frame, channel) is one matrix product with ``x.reshape(h * w, n * c)`` (Winograd's
# transforms below), and a product over the channels of every pixel is a batched matrix product over h * w.


def _to_hwnc(images: jax.Array) -> jax.Array:
    """Frames [n, h, w, c] -> [h, w, n, c] (the conv layers' layout)."""
    return images.transpose(1, 2, 0, 3)


def _to_nhwc(x: jax.Array) -> jax.Array:
    """HWNC [h, w, n, c] -> frames [n, h, w, c]."""
    return x.transpose(2, 0, 1, 3)


def _blocks(x: jax.Array) -> jax.Array:
    """HWNC [3h, 3w, n, c] -> its non-overlapping 3x3 blocks [h, w, n, 9c], entries in (di, dj, c) order (the
    rows of an HWIO kernel)."""
    h, w, n, c = x.shape
    k = KERNEL
    return (
        x.reshape(h // k, k, w // k, k, n, c)
        .transpose(0, 2, 4, 1, 3, 5)
        .reshape(h // k, w // k, n, k * k * c)
    )


@functools.cache
def _winograd_transforms(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Single-tile Winograd F(m x m, 3 x 3): float32 matrices data [a^2, a^2], filter [a^2, 9] and output
    [m^2, a^2], a = m + 2, such that the VALID 3x3 cross-correlation of one a x a input tile d with a kernel g
    (one channel pair) is ``output @ ((filter @ vec(g)) * (data @ vec(d)))``: a^2 multiplies, not 9 m^2.

    Toom-Cook construction (Lavin & Gray 2016) in float64 with interpolation points 0, 1, -1, 2, -2, 1/2 (the
    first a - 1 of them) and infinity: the 1D output (A^T) and filter (G) matrices from the points, the data
    matrix (B^T) solved from the identity ``sum_j At[i, j] G[j, k] Bt[j, l] = [l == i + k]``; the 2D
    transforms are Kronecker products. float32 error of a whole layer: ~1e-6 (m = 3) and ~5e-6 (m = 5)
    relative to its largest output, against ~1e-7 for a direct product.
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
    assert np.abs(system @ data_1d.ravel() - target.ravel()).max() < 1e-9, "inconsistent Winograd system"
    return tuple(np.kron(t, t).astype(np.float32) for t in (data_1d, filter_1d, out_1d))


def _winograd_kernel(kernel: jax.Array, m: int) -> jax.Array:
    """HWIO kernel [3, 3, c_in, c_out] -> its F(m x m, 3 x 3) transform [(m + 2)^2, c_in, c_out]."""
    _, filter_, _ = _winograd_transforms(m)
    return (filter_ @ kernel.reshape(KERNEL * KERNEL, -1)).reshape(-1, *kernel.shape[2:])


def _winograd_conv(x, kernel, bias):
    """VALID stride-1 3x3 cross-correlation of x f32[m+2, m+2, n, c_in] (one Winograd tile per frame and
    channel) with HWIO kernel [3, 3, c_in, c_out] -> f32[m, m, n, c_out]."""
    a, _, n, c_in = x.shape
    m = a - KERNEL + 1
    data, _, out = _winograd_transforms(m)
    v = (data @ x.reshape(a * a, -1)).reshape(a * a, n, c_in)
    y = out @ jnp.matmul(v, _winograd_kernel(kernel, m)).reshape(a * a, -1)
    return y.reshape(m, m, n, -1) + bias


def _winograd_deconv(x, kernel, bias):
    """Stride-1 transposed convolution (scatter semantics) of x f32[m, m, n, c_in] with kernel
    [3, 3, c_in, c_out] -> f32[m+2, m+2, n, c_out]: `_winograd_conv`'s adjoint (transposed transforms)."""
    m, _, n, c_in = x.shape
    a = m + KERNEL - 1
    data, _, out = _winograd_transforms(m)
    v = (out.T @ x.reshape(m * m, -1)).reshape(a * a, n, c_in)
    y = data.T @ jnp.matmul(v, _winograd_kernel(kernel, m)).reshape(a * a, -1)
    return y.reshape(a, a, n, -1) + bias


def _check_stride(stride: int) -> None:
    if stride not in (1, KERNEL):
        raise NotImplementedError(
            f"matmul convolutions support stride 1 or {KERNEL} (kernel size), got {stride}"
        )


def _conv_matmul(x, kernel, bias, stride: int):
    """VALID cross-correlation of HWNC `x` with HWIO `kernel`: Winograd for stride 1; for stride 3 (= kernel
    size, non-overlapping patches) a reshape/transpose into patches and one matrix product."""
    _check_stride(stride)
    if stride == 1:
        return _winograd_conv(x, kernel, bias)
    h, w, _, c = x.shape
    k = KERNEL
    return _blocks(x[: h // k * k, : w // k * k]) @ kernel.reshape(k * k * c, -1) + bias


def _deconv_matmul(x, kernel, bias, stride: int):
    """Transposed convolution (scatter semantics, VALID) of HWNC `x`: Winograd for stride 1; for stride 3 one
    matrix product to [*, 3 * 3 * c_out] and a transpose (the 3x3 output blocks do not overlap)."""
    _check_stride(stride)
    if stride == 1:
        return _winograd_deconv(x, kernel, bias)
    h, w, n, c = x.shape
    k, c_out = KERNEL, kernel.shape[-1]
    # (the bias is added before the transpose: its gradient then reduces [*, k*k*c_out], not a 3-wide axis)
    cols = x @ kernel.transpose(2, 0, 1, 3).reshape(c, k * k * c_out) + jnp.tile(bias, k * k)
    return cols.reshape(h, w, n, k, k, c_out).transpose(0, 3, 1, 4, 2, 5).reshape(h * k, w * k, n, c_out)


# XLA:CPU's convolutions run NHWC (its HWNC convolutions measured 12x slower): transposes around them.
_NHWC = ("NHWC", "HWIO", "NHWC")


def _conv_xla(x, kernel, bias, stride: int):
    out = lax.conv_general_dilated(_to_nhwc(x), kernel, (stride, stride), "VALID", dimension_numbers=_NHWC)
    return _to_hwnc(out + bias)


def _deconv_xla(x, kernel, bias, stride: int):
    # lax.conv_transpose (transpose_kernel=False) correlates the dilated, padded input with the kernel;
    # flipping the kernel spatially gives the scatter semantics documented above.
    out = lax.conv_transpose(
        _to_nhwc(x), kernel[::-1, ::-1], (stride, stride), "VALID", dimension_numbers=_NHWC
    )
    return _to_hwnc(out + bias)


def _conv_fns(cfg: NetworkConfig):
    if cfg.conv_impl == "matmul":
        return _conv_matmul, _deconv_matmul
    return _conv_xla, _deconv_xla


# ------------------------------------------------------------------------------------------ forward


def _dense(p, x):
    return x @ p["kernel"] + p["bias"]


def _mlp(p, x):
    x = jnp.tanh(_dense(p["dense0"], x))
    x = jnp.tanh(_dense(p["dense1"], x))
    return _dense(p["out"], x)


def _map_chunks(fn, args: tuple[jax.Array, ...], chunk: int) -> jax.Array:
    """``fn(*args)`` for a row-wise `fn` (row i of each arg -> row i of the output), `chunk` rows at a time.

    A `lax.map` over chunks keeps each layer's activations in cache: large XLA:CPU buffers are much slower
    (cache misses, and page faults on the freshly allocated memory of every call); chunking the paper
    network's gradient step makes it ~1.7x faster. For the backward pass only the values `fn` names `_SAVED`
    (each hidden layer's activation) are stored; the rest, e.g. the Winograd layers' transformed inputs, is
    recomputed from them (transforms only: no channel-mixing product is recomputed). Rows are padded to a
    multiple of `chunk`.
    """
    n = args[0].shape[0]
    if n <= chunk:
        return fn(*args)
    policy = jax.checkpoint_policies.save_only_these_names(_SAVED)
    out = lax.map(
        lambda a: jax.checkpoint(fn, policy=policy, prevent_cse=False)(*a), _split_chunks(args, chunk)
    )
    return out.reshape(-1, *out.shape[2:])[:n]


def _split_chunks(args: tuple[jax.Array, ...], chunk: int) -> tuple[jax.Array, ...]:
    """Rows [N, ...] -> [ceil(N / chunk), chunk, ...], zero-padded to a multiple of `chunk`."""
    n = args[0].shape[0]
    pad = -n % chunk
    args = tuple(jnp.pad(x, [(0, pad)] + [(0, 0)] * (x.ndim - 1)) if pad else x for x in args)
    return tuple(x.reshape(-1, chunk, *x.shape[1:]) for x in args)


def _encode(params: Params, cfg: NetworkConfig, obs: jax.Array) -> jax.Array:
    """uint8[N, 21, 21, 3] -> LSTM input projection f32[N, 4 * hidden] (convs, FC, tanh, ``@ wi + b``).

    The convolutions run in chunks (`_map_chunks`), up to conv3's pre-activation; its activation, the FC
    layer and the projection run on all N frames at once, as large matrix products."""
    conv, _ = _conv_fns(cfg)

    def encode_chunk(obs):
        x = _to_hwnc(obs).astype(jnp.float32) * (1.0 / 255.0)
        # conv1's activation is recomputed from obs, not saved (+0.6% FLOPs, 6 KB less memory per frame)
        x = _leaky_relu_unsaved(conv(x, params["conv1"]["kernel"], params["conv1"]["bias"], STRIDES[0]))
        x = _leaky_relu(conv(x, params["conv2"]["kernel"], params["conv2"]["bias"], STRIDES[1]))
        x = conv(x, params["conv3"]["kernel"], params["conv3"]["bias"], STRIDES[2])
        return _to_nhwc(x).reshape(x.shape[2], -1)  # rows, flattened in (h, w, c) order

    x = _leaky_relu(_map_chunks(encode_chunk, (obs,), cfg.chunk))
    x = jnp.tanh(_dense(params["fc"], x))
    return x @ params["lstm"]["wi"] + params["lstm"]["b"]


def _lstm_scan(p: Params, carry: Carry, xproj: jax.Array, resets: jax.Array) -> tuple[Carry, jax.Array]:
    """LSTM over T steps given the precomputed input projection xproj f32[T, B, 4H] (including the bias)."""
    wh = p["wh"]

    def cell(carry, inputs):
        xp, reset = inputs
        keep = ~reset[:, None]
        c = jnp.where(keep, carry.c, 0.0)
        h = jnp.where(keep, carry.h, 0.0)
        gates = xp + h @ wh
        i, f, g, o = jnp.split(gates, 4, axis=-1)
        c = jax.nn.sigmoid(f) * c + jax.nn.sigmoid(i) * jnp.tanh(g)
        h = jax.nn.sigmoid(o) * jnp.tanh(c)
        return Carry(c=c, h=h), h

    return lax.scan(cell, carry, (xproj, resets))


def unroll(
    params: Params, cfg: NetworkConfig, carry: Carry, obs: jax.Array, resets: jax.Array
) -> tuple[Carry, Output]:
    """Run the network over T steps of B sequences.

    obs uint8[T, B, 21, 21, 3]; resets bool[T, B]: before step t, the carry of every sequence b with
    resets[t, b] is zeroed (a reset step starts a fresh episode). Returns the final carry and per-step
    `Output`s. The conv encoder and the LSTM input projection run on all T * B frames at once (in chunks);
    only ``h @ wh`` and the gates are inside the `lax.scan` over T.
    """
    t, b = obs.shape[:2]
    xproj = _encode(params, cfg, obs.reshape(t * b, *obs.shape[2:])).reshape(t, b, -1)
    carry, hidden = _lstm_scan(params["lstm"], carry, xproj, resets)
    logits = _mlp(params["policy"], hidden)
    value = _mlp(params["value"], hidden)[..., 0]
    return carry, Output(logits=logits, value=value, hidden=hidden)


def step(
    params: Params, cfg: NetworkConfig, carry: Carry, obs: jax.Array, reset: jax.Array
) -> tuple[Carry, Output]:
    """One step for acting: obs uint8[B, 21, 21, 3], reset bool[B]; `Output` fields have no T axis."""
    carry, out = unroll(params, cfg, carry, obs[None], reset[None])
    return carry, jax.tree_util.tree_map(lambda x: x[0], out)


def attention_loss(params: Params, cfg: NetworkConfig, hidden: jax.Array, target: jax.Array, weight):
    """Weighted attention loss ``sum(weight * mean_k CE(logits_k, target_k))``, f32[].

    hidden f32[..., H]; target int[..., K] each other slot's view cell (`observe.attention_targets`:
    row * 7 + col, or 49 when not in view); weight f32[...]. Raises ValueError without the attention head.
    """
    if not cfg.attention:
        raise ValueError(f"cfg.aux == {cfg.aux!r} has no attention head")
    logits = _dense(params["attention"], hidden).reshape(*hidden.shape[:-1], cfg.n_others, ATTENTION_CLASSES)
    log_probs = jax.nn.log_softmax(logits)
    nll = -jnp.take_along_axis(log_probs, target[..., None].astype(jnp.int32), -1)[..., 0]
    return jnp.sum(weight * jnp.mean(nll, -1))


DECODER_PARAMS = ("aux_fc", "deconv1", "deconv2", "deconv3")


def _check_decoder(cfg: NetworkConfig) -> None:
    if cfg.frame_aux == "none":
        raise ValueError(f"decoding needs an auxiliary decoder, but cfg.aux == {cfg.aux!r} built none")


def _decode_hwnc(params: Params, cfg: NetworkConfig, hidden: jax.Array, action: jax.Array) -> jax.Array:
    """The decoder on rows hidden f32[N, H], action int[N] -> frames f32[21, 21, N, 3] (HWNC)."""
    _, deconv = _conv_fns(cfg)
    z = jnp.concatenate([hidden, jax.nn.one_hot(action, cfg.n_actions, dtype=hidden.dtype)], axis=-1)
    x = checkpoint_name(jnp.tanh(_dense(params["aux_fc"], z)), _SAVED)
    x = _to_hwnc(x.reshape(-1, *cfg.feature_shape))
    for name, stride in zip(("deconv1", "deconv2", "deconv3"), STRIDES[::-1], strict=True):
        x = deconv(x, params[name]["kernel"], params[name]["bias"], stride)
        x = _leaky_relu(x) if name != "deconv3" else x  # linear output
    return x


def decode(params: Params, cfg: NetworkConfig, hidden: jax.Array, action: jax.Array) -> jax.Array:
    """Auxiliary prediction f32[..., 21, 21, 3] from LSTM outputs f32[..., H] and actions int[...].

    Unbounded (linear output layer); the learner compares it with obs / 255 (see `aux_loss`, which
    computes that comparison and its gradient faster). Raises ValueError without a decoder.
    """
    _check_decoder(cfg)
    batch = hidden.shape[:-1]
    hidden, action = hidden.reshape(-1, hidden.shape[-1]), jnp.asarray(action).reshape(-1)
    fn = lambda hidden, action: _to_nhwc(_decode_hwnc(params, cfg, hidden, action))  # noqa: E731
    return _map_chunks(fn, (hidden, action), cfg.chunk).reshape(*batch, *OBS_SHAPE)


def aux_loss(
    params: Params,
    cfg: NetworkConfig,
    hidden: jax.Array,
    action: jax.Array,
    target: jax.Array,
    weight: jax.Array,
    axis_name: str | None = None,
) -> jax.Array:
    """Weighted auxiliary loss ``sum(weight * mean|decode(hidden, action) - target / 255|)``, f32[].

    hidden f32[..., H]; action int[...]; target uint8[..., 21, 21, 3]; weight f32[...] (the mean absolute
    error of each frame over its pixels is weighted). `axis_name`: called inside `jax.shard_map` with params
    replicated and every other argument the device's share of the rows, the mesh axis the rows are split
    over (the params' gradient is then summed over it). Raises ValueError without a decoder.

    Differentiable in params, hidden and weight, with the value and gradients of writing it with `decode`,
    but faster: as only a scalar leaves the decoder, the forward pass of a differentiated call runs the
    decoder's backward pass too, chunk by chunk (`NetworkConfig.chunk` frames) while each chunk's
    activations are in cache. It keeps the gradients (of the decoder params, and f32[N, H] of hidden) rather
    than every frame's activations; the backward pass only scales them by the incoming cotangent.
    """
    _check_decoder(cfg)
    decoder = {name: params[name] for name in DECODER_PARAMS}
    if axis_name is not None:  # per-device gradients; pcast's transpose sums them over the devices
        decoder = lax.pcast(decoder, axis_name, to="varying")
    n = math.prod(hidden.shape[:-1])
    rows = (
        hidden.reshape(n, hidden.shape[-1]),
        jnp.asarray(action).reshape(n),
        target.reshape(n, *OBS_SHAPE),
        jnp.broadcast_to(jnp.asarray(weight, jnp.float32), hidden.shape[:-1]).reshape(n),
    )
    return _aux_loss(cfg, decoder, *rows)


def _frame_errors(decoder: Params, cfg: NetworkConfig, hidden, action, target) -> jax.Array:
    """Mean absolute error of each frame's prediction, f32[N], for rows hidden f32[N, H], action int[N],
    target uint8[N, 21, 21, 3]."""
    # Compared in 3x3 blocks, the layout of deconv3's matrix product: XLA then cancels the deconvolution's
    # transpose to HWNC with this one, here and in the backward pass (+12% for the small training preset).
    prediction = _blocks(_decode_hwnc(decoder, cfg, hidden, action))
    error = jnp.abs(prediction - _blocks(_to_hwnc(target)).astype(jnp.float32) / 255.0)
    h, w, n, c = error.shape
    # The sum over pixels as a matrix-vector product: XLA:CPU's reduction over axes (0, 1, 3) took 10x longer.
    return (jnp.ones(h * w) @ error.reshape(h * w, n * c)).reshape(n, c).sum(axis=-1) / (h * w * c)


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _aux_loss(cfg: NetworkConfig, decoder: Params, hidden, action, target, weight) -> jax.Array:
    errors = _map_chunks(functools.partial(_frame_errors, decoder, cfg), (hidden, action, target), cfg.chunk)
    return jnp.sum(weight * errors)


def _aux_loss_fwd(cfg: NetworkConfig, decoder: Params, hidden, action, target, weight):
    """The loss and its gradients, chunk by chunk: a `lax.scan` over chunks of rows (padded with weight 0)
    that sums the decoder params' gradients and stacks those of hidden and weight (= the frame errors)."""
    n = hidden.shape[0]
    rows = _split_chunks((hidden, action, target, weight), min(cfg.chunk, n))

    def chunk_grads(d_decoder, inputs):
        hidden, action, target, weight = inputs

        def weighted_error(decoder, hidden):
            errors = _frame_errors(decoder, cfg, hidden, action, target)
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
