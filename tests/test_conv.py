"""3x3 convolution kernels (`jaxsocial.agents.conv`): every implementation against direct sums and XLA's
convolutions, outputs and gradients; the Winograd transforms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

from jaxsocial.agents import conv


def _hwnc(x):
    return np.asarray(x).transpose(1, 2, 0, 3)


def assert_every_impl_matches(layer, x, kernel, bias, stride, expected):
    """`layer` (conv.conv or conv.deconv) in every implementation equals `expected` (NHWC, float64).
    Winograd's float32 error grows with the tile (see `conv.winograd_transforms`): relative to the largest
    output."""
    for impl in conv.IMPLS:
        np.testing.assert_allclose(
            layer(_hwnc(x), kernel, bias, stride, impl),
            _hwnc(expected),
            rtol=1e-5,
            atol=1e-5 * np.abs(expected).max(),
        )


@pytest.mark.parametrize("stride, size", [(1, 7), (1, 5), (3, 21)])
def test_conv_cross_correlation(stride, size):
    """Convolutions (HWNC activations, HWIO kernels) are PyTorch Conv2d's VALID cross-correlation:
    out[i, j] = sum over di, dj of x[s*i + di, s*j + dj] @ kernel[di, dj]; stride 1 goes through Winograd."""
    rng = np.random.default_rng(size)
    x = rng.normal(size=(2, size, size, 4)).astype(np.float32)
    kernel = rng.normal(size=(3, 3, 4, 5)).astype(np.float32)
    bias = rng.normal(size=(5,)).astype(np.float32)
    out_size = (size - 3) // stride + 1
    expected = np.zeros((2, out_size, out_size, 5), np.float64) + bias
    for di in range(3):
        for dj in range(3):
            window = x[
                :,
                di : di + stride * (out_size - 1) + 1 : stride,
                dj : dj + stride * (out_size - 1) + 1 : stride,
            ]
            expected += window.astype(np.float64) @ kernel[di, dj]
    assert_every_impl_matches(conv.conv, x, kernel, bias, stride, expected)


@pytest.mark.parametrize("stride, size", [(1, 3), (1, 5), (3, 7)])
def test_deconv_scatter_semantics(stride, size):
    """Deconvolutions follow PyTorch ConvTranspose2d: out[s*i + di, s*j + dj] += x[i, j] @ kernel[di, dj]."""
    rng = np.random.default_rng(size)
    x = rng.normal(size=(2, size, size, 4)).astype(np.float32)
    kernel = rng.normal(size=(3, 3, 4, 5)).astype(np.float32)
    bias = rng.normal(size=(5,)).astype(np.float32)
    out_size = (size - 1) * stride + 3
    expected = np.zeros((2, out_size, out_size, 5), np.float64) + bias
    for i in range(size):
        for j in range(size):
            for di in range(3):
                for dj in range(3):
                    expected[:, stride * i + di, stride * j + dj] += (
                        x[:, i, j].astype(np.float64) @ kernel[di, dj]
                    )
    assert_every_impl_matches(conv.deconv, x, kernel, bias, stride, expected)


@pytest.mark.parametrize("m", [3, 5])
def test_winograd_transforms_are_exact(m):
    """In exact arithmetic (float64 here), the Winograd transforms reproduce every output of a 3x3
    cross-correlation of one (m+2)x(m+2) tile: output @ diag(filter @ g) @ data = the correlation matrix."""
    data, filter_, out = (t.astype(np.float64) for t in conv.winograd_transforms(m))
    a = m + 2
    rng = np.random.default_rng(m)
    for _ in range(3):
        g = rng.normal(size=(3, 3))
        as_matrix = out @ np.diag(filter_ @ g.ravel()) @ data  # [m*m outputs, a*a inputs]
        expected = np.zeros((m, m, a, a))
        for i in range(m):
            for j in range(m):
                expected[i, j, i : i + 3, j : j + 3] = g
        np.testing.assert_allclose(as_matrix, expected.reshape(m * m, a * a), atol=1e-5)
    with pytest.raises(NotImplementedError, match="output sizes"):
        conv.winograd_transforms(6)


@pytest.mark.parametrize("impl", conv.IMPLS)
@pytest.mark.parametrize(
    "transpose, stride, size",
    [(False, 3, 21), (False, 1, 7), (False, 1, 5), (True, 1, 3), (True, 1, 5), (True, 3, 7)],
)
def test_impls_equal_lax_reference(impl, transpose, stride, size):
    """Each implementation equals ``lax.conv_general_dilated`` (conv) / ``lax.conv_transpose`` of the flipped
    kernel (deconv) on random inputs, in value and in the gradients of a random projection of the output."""
    rng = np.random.default_rng(size + 10 * stride)
    x = jnp.asarray(rng.normal(size=(size, size, 4, 3)), jnp.float32)  # HWNC
    kernel = jnp.asarray(rng.normal(size=(3, 3, 3, 5)), jnp.float32)
    bias = jnp.asarray(rng.normal(size=(5,)), jnp.float32)
    dims = ("NHWC", "HWIO", "NHWC")

    def reference(x, kernel, bias):
        nhwc = conv.to_nhwc(x)
        if transpose:
            out = lax.conv_transpose(
                nhwc, kernel[::-1, ::-1], (stride, stride), "VALID", dimension_numbers=dims
            )
        else:
            out = lax.conv_general_dilated(nhwc, kernel, (stride, stride), "VALID", dimension_numbers=dims)
        return conv.to_hwnc(out + bias)

    def tested(x, kernel, bias):
        return (conv.deconv if transpose else conv.conv)(x, kernel, bias, stride, impl)

    expected = reference(x, kernel, bias)
    actual = jax.jit(tested)(x, kernel, bias)
    assert actual.shape == expected.shape
    scale = float(jnp.abs(expected).max())
    np.testing.assert_allclose(actual, expected, rtol=1e-5, atol=1e-5 * scale)
    projection = jnp.asarray(rng.normal(size=expected.shape), jnp.float32)
    grads = [
        jax.jit(jax.grad(lambda *a, f=f: jnp.sum(projection * f(*a)), argnums=(0, 1, 2)))(x, kernel, bias)
        for f in (tested, reference)
    ]
    for a, b in zip(*grads, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5 * float(jnp.abs(b).max()))


def test_matmul_rejects_other_strides():
    x = jnp.zeros((9, 9, 1, 2))
    with pytest.raises(NotImplementedError, match="stride"):
        conv.conv(x, jnp.zeros((3, 3, 2, 2)), jnp.zeros(2), 2, "matmul")
