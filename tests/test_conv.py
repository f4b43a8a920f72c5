"""3x3 convolution kernels (`jaxsocial.agents.fast.conv`): every implementation against direct sums and XLA's
convolutions, outputs and gradients; the Winograd transforms. Tolerances: per element, the float32 error bound
of `float_bounds` (summation length times the magnitude of the terms)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from float_bounds import U, conv_magnitude, gamma, winograd_terms
from jax import lax

from jaxsocial.agents.fast import conv


def _hwnc(x):
    return np.asarray(x).transpose(1, 2, 0, 3)


def _is_winograd(impl: str, stride: int) -> bool:
    return impl == "matmul" and stride == 1


def _terms(impl: str, stride: int, transpose: bool, x_hwnc) -> int:
    """Summation length of one output of the layer as `impl` computes it (see `float_bounds`)."""
    size, _, _, c_in = x_hwnc.shape
    if _is_winograd(impl, stride):
        return winograd_terms(size if transpose else size - conv.KERNEL + 1, c_in)
    return conv.KERNEL**2 * c_in + 1


def _error_bound(impl: str, stride: int, transpose: bool, x_hwnc, kernel, bias):
    """Per-element float32 error bound of `impl`'s output: gamma_n times the magnitude of its terms."""
    winograd = _is_winograd(impl, stride)
    magnitude = conv_magnitude(x_hwnc, kernel, bias, stride, transpose, winograd)
    return gamma(_terms(impl, stride, transpose, x_hwnc)) * np.asarray(magnitude, np.float64)


def _assert_within(actual, expected, bound, what):
    error = np.abs(np.asarray(actual, np.float64) - np.asarray(expected, np.float64))
    assert np.all(error <= bound), f"{what}: error / bound up to {float((error / bound).max()):.3g}"


def assert_every_impl_matches(layer, x, kernel, bias, stride, expected):
    """`layer` (conv.conv or conv.deconv) in every implementation equals `expected` (NHWC, float64, from the
    same float32 inputs) within the implementation's float32 error bound, element by element."""
    transpose = layer is conv.deconv
    for impl in conv.IMPLS:
        bound = _error_bound(impl, stride, transpose, _hwnc(x), kernel, bias)
        _assert_within(layer(_hwnc(x), kernel, bias, stride, impl), _hwnc(expected), bound, impl)


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
    cross-correlation of one (m+2)x(m+2) tile: output @ diag(filter @ g) @ data = the correlation matrix, up
    to the transforms' rounding to float32 (each of the 3 factors of a term off by at most u: 3u + O(u^2) of
    the terms' magnitudes; 4u allows for the float64 arithmetic)."""
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
        magnitude = np.abs(out) @ np.diag(np.abs(filter_) @ np.abs(g.ravel())) @ np.abs(data)
        _assert_within(as_matrix, expected.reshape(m * m, a * a), 4 * U * magnitude, f"F({m}x{m}, 3x3)")
    with pytest.raises(NotImplementedError, match="output sizes"):
        conv.winograd_transforms(6)


@pytest.mark.parametrize("impl", conv.IMPLS)
@pytest.mark.parametrize(
    "transpose, stride, size",
    [(False, 3, 21), (False, 1, 7), (False, 1, 5), (True, 1, 3), (True, 1, 5), (True, 3, 7)],
)
def test_impls_equal_lax_reference(impl, transpose, stride, size):
    """Each implementation equals ``lax.conv_general_dilated`` (conv) / ``lax.conv_transpose`` of the flipped
    kernel (deconv) on random inputs, in value and in the gradients of a random projection of the output,
    within the sum of both computations' float32 error bounds. The gradients' bounds: the backward sums'
    magnitudes are the gradients of the projection's magnitude (|projection| times `conv_magnitude`, linear in
    each argument), their summation length at most the forward one plus the frames x pixels a weight gradient
    sums over."""
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
    bound = sum(_error_bound(i, stride, transpose, x, kernel, bias) for i in (impl, "xla"))
    _assert_within(actual, expected, bound, "output")
    projection = jnp.asarray(rng.normal(size=expected.shape), jnp.float32)
    grads = [
        jax.jit(jax.grad(lambda *a, f=f: jnp.sum(projection * f(*a)), argnums=(0, 1, 2)))(x, kernel, bias)
        for f in (tested, reference)
    ]
    frames_pixels = x.shape[2] * max(x.shape[0], expected.shape[0]) ** 2
    grad_bounds = []
    for i in (impl, "xla"):
        winograd = _is_winograd(i, stride)

        def projected(*args, winograd=winograd):
            return jnp.sum(jnp.abs(projection) * conv_magnitude(*args, stride, transpose, winograd))

        absolute = (jnp.abs(x), jnp.abs(kernel), jnp.abs(bias))
        magnitude = jax.jit(jax.grad(projected, argnums=(0, 1, 2)))(*absolute)
        n = _terms(i, stride, transpose, x) + frames_pixels
        grad_bounds.append([gamma(n) * np.asarray(mag, np.float64) for mag in magnitude])
    for name, a, b, *bounds in zip(("x", "kernel", "bias"), *grads, *grad_bounds, strict=True):
        _assert_within(a, b, sum(bounds), f"gradient of {name}")


def test_matmul_rejects_other_strides():
    x = jnp.zeros((9, 9, 1, 2))
    with pytest.raises(NotImplementedError, match="stride"):
        conv.conv(x, jnp.zeros((3, 3, 2, 2)), jnp.zeros(2), 2, "matmul")


@pytest.mark.parametrize(
    "transpose, stride, size", [(False, 1, 7), (False, 3, 21), (True, 1, 5), (True, 3, 7)]
)
def test_bfloat16_impls_within_rounding_bound(transpose, stride, size):
    """In bfloat16 every implementation computes the direct sums (never Winograd, whose transforms would
    amplify the rounding): each term's inputs rounded to 8 significant bits (unit roundoff u = 2^-8:
    2u + u^2 per product), float32 accumulation (gamma_n), so within (2u + u^2 + gamma_n) of the direct
    magnitude."""
    rng = np.random.default_rng(size + stride)
    x = jnp.asarray(rng.normal(size=(size, size, 4, 3)), jnp.float32)  # HWNC
    kernel = jnp.asarray(rng.normal(size=(3, 3, 3, 5)), jnp.float32)
    bias = jnp.asarray(rng.normal(size=(5,)), jnp.float32)
    layer = conv.deconv if transpose else conv.conv
    expected = layer(x, kernel, bias, stride, "xla")  # float32: its own error bound is added
    magnitude = np.asarray(conv_magnitude(x, kernel, bias, stride, transpose, False), np.float64)
    rounding = (2 * 2.0**-8 + 2.0**-16 + gamma(conv.KERNEL**2 * x.shape[-1] + 1)) * magnitude
    bound = rounding + _error_bound("xla", stride, transpose, x, kernel, bias)
    for impl in conv.IMPLS:
        actual = jax.jit(layer, static_argnums=(3, 4, 5))(x, kernel, bias, stride, impl, "bfloat16")
        assert actual.dtype == jnp.float32
        _assert_within(actual, expected, bound, impl)
        assert not np.allclose(actual, expected, rtol=1e-6, atol=0), impl  # the inputs were rounded
