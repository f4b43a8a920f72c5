"""Rounding-error bounds of float32 computations, from which the tests' tolerances are derived (not from what
one machine gave: XLA:CPU's summation order, blocking and FMA use differ between vector units).

u = 2^-24 is float32's unit roundoff. A sum of n terms (products) computed in any order, with or without FMA,
is off by at most gamma_n = n u / (1 - n u) times the sum of the terms' magnitudes (Higham, "Accuracy and
Stability of Numerical Algorithms", 2nd ed., 3.1), so two float32 computations of one sum differ by at most
2 gamma_n of it. For a direct convolution or dense layer the magnitude is the layer applied to |x|, |w|, |b|.

Winograd's F(m x m, 3 x 3) (`conv.winograd_transforms`) computes the same sums through transforms: its error
is bounded likewise with n the summation lengths of the data, filter and output transforms plus the channel
sum (and 3 for the rounding of the transforms' constants to float32), and the magnitude the layer computed
with the transforms' absolute values (Barabasz et al., "Error analysis and improving the accuracy of Winograd
convolution", 2020). For inputs of one sign that magnitude exceeds the direct one by `winograd_amplification`:
66 for F(3 x 3, 3 x 3) and 474 for F(5 x 5, 3 x 3).

Through a network, to first order, each layer's error is carried to the outputs with the gain of the layers
after it: the activations (tanh, sigmoid, leaky ReLU) have slopes <= 1, and with weights of order 1 the bounds
of the layers on the path add up (`network_error`, relative to an output's largest magnitude, assuming no
layer's terms cancel to far below its output). A gradient runs that path forward and back again: twice the
bound, plus the sum over frames and pixels of a weight gradient. These are worst-case bounds: the differences
seen are far smaller (the Winograd amplification assumes every term has one sign).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxsocial.agents.fast import conv
from jaxsocial.agents.network import NetworkConfig

U = 2.0**-24
"""float32 unit roundoff."""


def gamma(n: int) -> float:
    """Bound on the relative error of an n-term float32 sum, relative to the sum of its terms' magnitudes."""
    return n * U / (1 - n * U)


@functools.cache
def winograd_terms(m: int, c_in: int) -> int:
    """Summation length of one output of a Winograd F(m x m, 3 x 3) layer (or its adjoint) with c_in input
    channels: the longest row or column of each transform, the channel sum, the bias, and 3 for the
    transforms' constants rounded to float32."""
    nonzero = [t != 0 for t in conv.winograd_transforms(m)]
    lengths = [max(int(t.sum(0).max()), int(t.sum(1).max())) for t in nonzero]
    return sum(lengths) + c_in + 1 + 3


@functools.cache
def winograd_amplification(m: int) -> float:
    """Largest ratio of the magnitude of an F(m x m, 3 x 3) output (computed with the transforms' absolute
    values) to the magnitude of the direct 3x3 correlation (9 terms), for inputs and kernel of one sign."""
    data, filter_, out = (np.abs(t.astype(np.float64)) for t in conv.winograd_transforms(m))
    ones_data, ones_kernel = np.ones(data.shape[1]), np.ones(conv.KERNEL**2)
    return float((out @ ((filter_ @ ones_kernel) * (data @ ones_data))).max() / conv.KERNEL**2)


def winograd_layer(m: int, c_in: int) -> float:
    """Relative error bound of one float32 Winograd layer: gamma_n times the amplification."""
    return gamma(winograd_terms(m, c_in)) * winograd_amplification(m)


def dense_layer(n_in: int) -> float:
    """Relative error bound of one float32 dense layer or direct convolution with n_in terms per output (and a
    bias)."""
    return gamma(n_in + 1)


def _stride1(cfg: NetworkConfig, layer: str, m: int, c_in: int) -> float:
    """A stride-1 3x3 layer's bound as `cfg` computes `layer` in float32 (Winograd for "matmul")."""
    winograd = cfg.impl_for(layer) == "matmul"
    return winograd_layer(m, c_in) if winograd else dense_layer(conv.KERNEL**2 * c_in)


def decoder_error(cfg: NetworkConfig) -> float:
    """Error bound of the decoder's output (`network.decode`) relative to its largest magnitude, for exact
    inputs: aux FC, deconv1, deconv2, then deconv3 (or the symbolic cell logits)."""
    c1, c2, c3 = cfg.conv_channels
    last = dense_layer(c1) if cfg.symbolic else dense_layer(conv.KERNEL**2 * c1)
    deconvs = [_stride1(cfg, "deconv1", 3, c3), _stride1(cfg, "deconv2", 5, c2)]
    layers = [dense_layer(cfg.hidden + cfg.n_actions), *deconvs, last]
    return sum(layers)


def network_error(cfg: NetworkConfig, steps: int, decoder: bool = True) -> float:
    """Error bound of one float32 computation of `cfg`'s outputs over `steps` LSTM steps, relative to an
    output's largest magnitude: the sum of the bounds of the layers on the longest path (the encoder, the LSTM
    input projection and `steps` recurrent products, then the deeper of the MLP heads and, with `decoder`,
    `decoder_error`)."""
    c1, c2, _ = cfg.conv_channels
    first = dense_layer(4) if cfg.symbolic else dense_layer(conv.KERNEL**2 * 3)  # embedding sum or conv1
    convs = [_stride1(cfg, "conv2", 5, c1), _stride1(cfg, "conv3", 3, c2)]
    encoder = [first, *convs, dense_layer(cfg.feature_size)]
    lstm = [dense_layer(cfg.hidden)] * (1 + steps)
    heads = [dense_layer(cfg.hidden), dense_layer(cfg.mlp), dense_layer(cfg.mlp)]
    return sum(encoder) + sum(lstm) + max(sum(heads), decoder_error(cfg) if decoder else 0.0)


def assert_within(actual, expected, bound: float, what: str = "") -> None:
    """Every element of `actual` within `bound` times `expected`'s largest magnitude of `expected`."""
    actual, expected = np.asarray(actual, np.float64), np.asarray(expected, np.float64)
    error = np.abs(actual - expected).max(initial=0.0)
    scale = np.abs(expected).max(initial=0.0)
    assert error <= bound * scale, f"{what}: error {error:.3g} > bound {bound:.3g} x largest {scale:.3g}"


def assert_trees_within(actual, expected, bound: float) -> None:
    """`assert_within` for every leaf of two pytrees of one structure."""
    leaves, structure = jax.tree_util.tree_flatten_with_path(expected)
    assert jax.tree_util.tree_structure(actual) == structure
    for (path, leaf), other in zip(leaves, jax.tree_util.tree_leaves(actual), strict=True):
        assert_within(other, leaf, bound, jax.tree_util.keystr(path))


@functools.partial(jax.jit, static_argnums=(3, 4, 5))
def conv_magnitude(x, kernel, bias, stride: int, transpose: bool, winograd: bool):
    """The magnitude the error of a 3x3 layer is relative to, per output: the layer of |x| f32[h, w, n, c_in],
    |kernel|, |bias| (HWNC, `conv` layouts), direct, or with the Winograd transforms' absolute values."""
    x, kernel, bias = jnp.abs(x), jnp.abs(kernel), jnp.abs(bias)
    if not winograd:
        dims = ("NHWC", "HWIO", "NHWC")
        nhwc = conv.to_nhwc(x)
        if transpose:
            flipped = kernel[::-1, ::-1]
            out = lax.conv_transpose(nhwc, flipped, (stride, stride), "VALID", dimension_numbers=dims)
        else:
            out = lax.conv_general_dilated(nhwc, kernel, (stride, stride), "VALID", dimension_numbers=dims)
        return conv.to_hwnc(out) + bias
    size, _, n, c_in = x.shape
    m = size if transpose else size - conv.KERNEL + 1
    a = m + conv.KERNEL - 1
    data, filter_, out = (jnp.asarray(np.abs(t)) for t in conv.winograd_transforms(m))
    kernel_t = (filter_ @ kernel.reshape(conv.KERNEL**2, -1)).reshape(a * a, c_in, -1)
    first, last = (out.T, data.T) if transpose else (data, out)
    v = (first @ x.reshape(size * size, -1)).reshape(a * a, n, c_in)
    y = last @ jnp.matmul(v, kernel_t).reshape(a * a, -1)
    side = a if transpose else m
    return y.reshape(side, side, n, -1) + bias
