"""The paper's network in plain Flax layers: the reference that `modules` computes faster.

Ndousse et al. (2021), appendix "Network architecture details": three convolutions and a dense layer encode
the egocentric view, an LSTM carries memory, two MLP heads give the policy's logits and the value, and the
auxiliary decoder maps the LSTM output and the action back to a frame (reconstruction or next-view
prediction). Read this file for what the network computes; `modules.ActorCritic` computes the same function
with the same params tree (tested: tests/test_network.py), with the convolutions in fast kernels and frame
batches (`NetworkConfig.conv_impl`, `frame_batch`, `dtype`; `fast/`), and `network` applies it.

Here every frame is NHWC, the convolutions are ``flax.linen.Conv`` and ``lax.conv_transpose``, and products
are float32. ``PaperActorCritic(net_cfg).init(key, carry, obs, resets)`` draws every parameter from its own
`Init` (the distributions `network.init` draws from two random buffers); pixel views only.

`Dense`, `MLP` and `LSTM` are plain already and shared with `modules`; LSTM gates are ordered (i, f, g, o)
like PyTorch, with one bias. Initialisation: convs PyTorch's default U(-1/sqrt(fan_in), 1/sqrt(fan_in))
(transposed: the effective fan-in C_in * 9 / stride^2), dense layers orthogonal with gain sqrt(2) (hidden),
1 (value output) or 0.01 (policy and attention outputs) and zero bias, LSTM N(0, 1/n_in) input weights,
orthogonal recurrent weights per gate, zero bias.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax import lax

from jaxsocial.agents.fast.conv import KERNEL
from jaxsocial.agents.fast.frame_batches import LEAKY_SLOPE
from jaxsocial.agents.fast.precision import matmul
from jaxsocial.agents.initialisers import ZEROS, Init, param
from jaxsocial.agents.network_config import ATTENTION_CLASSES, OBS_SHAPE, STRIDES, NetworkConfig


class Carry(NamedTuple):
    """LSTM state, float32[*batch, hidden] each."""

    c: jax.Array
    h: jax.Array


class Output(NamedTuple):
    """Per-step network outputs: logits f32[T, B, A], value f32[T, B], LSTM output hidden f32[T, B, H]."""

    logits: jax.Array
    value: jax.Array
    hidden: jax.Array


class Dense(nn.Module):
    """``x @ kernel + bias``: f32[..., n_in] -> f32[..., features]; orthogonal kernel (gain), zero bias; the
    product's inputs in `dtype` (`precision.matmul`)."""

    features: int
    gain: float
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = param(self, "kernel", Init("orthogonal", self.gain), (x.shape[-1], self.features))
        return matmul(x, kernel, self.dtype) + param(self, "bias", ZEROS, (self.features,))


class MLP(nn.Module):
    """f32[..., n_in] -> f32[..., n_out]: two tanh hidden layers of `width` (gain sqrt 2), a linear output."""

    width: int
    n_out: int
    out_gain: float
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = jnp.tanh(Dense(self.width, math.sqrt(2.0), self.dtype, name="dense0")(x))
        x = jnp.tanh(Dense(self.width, math.sqrt(2.0), self.dtype, name="dense1")(x))
        return Dense(self.n_out, self.out_gain, self.dtype, name="out")(x)


class LSTM(nn.Module):
    """LSTM over T steps of B sequences: carry `Carry` f32[B, features] x 2, x f32[T, B, n_in], resets
    bool[T, B] (before step t, the carry of every sequence with resets[t, b] is zeroed) -> (final `Carry`,
    h f32[T, B, features]). The input projection ``x @ wi + b`` runs on all T * B rows at once, only
    ``h @ wh`` and the gates inside the `lax.scan` over T."""

    features: int
    dtype: str = "float32"

    @nn.compact
    def __call__(self, carry: Carry, x: jax.Array, resets: jax.Array) -> tuple[Carry, jax.Array]:
        n_in, gates = x.shape[-1], 4 * self.features
        wi = param(self, "wi", Init("normal", 1.0 / math.sqrt(n_in)), (n_in, gates))
        wh = param(self, "wh", Init("orthogonal", 1.0, blocks=4), (self.features, gates))
        xproj = matmul(x, wi, self.dtype) + param(self, "b", ZEROS, (gates,))

        def cell(carry, inputs):
            xp, reset = inputs
            keep = ~reset[:, None]
            c = jnp.where(keep, carry.c, 0.0)
            h = jnp.where(keep, carry.h, 0.0)
            i, f, g, o = jnp.split(xp + matmul(h, wh, self.dtype), 4, axis=-1)
            c = jax.nn.sigmoid(f) * c + jax.nn.sigmoid(i) * jnp.tanh(g)
            h = jax.nn.sigmoid(o) * jnp.tanh(c)
            return Carry(c=c, h=h), h

        return lax.scan(cell, carry, (xproj, resets))


def conv(features: int, stride: int, c_in: int, name: str) -> nn.Conv:
    """3x3 VALID convolution of NHWC frames (like torch Conv2d), PyTorch's default uniform init."""
    bound = 1.0 / math.sqrt(c_in * KERNEL * KERNEL)
    init = Init("uniform", bound)
    return nn.Conv(features, (KERNEL, KERNEL), stride, "VALID", kernel_init=init, bias_init=init, name=name)


class Deconv(nn.Module):
    """3x3 VALID transposed convolution of NHWC frames with torch ConvTranspose2d's scatter semantics:
    ``out[s*i + di, s*j + dj] += x[i, j] @ kernel[di, dj]``, f32[n, h, w, c_in] -> f32[n, s (h - 1) + 3,
    s (w - 1) + 3, features]; kernel ``[3, 3, c_in, features]``."""

    features: int
    stride: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        c_in = x.shape[-1]
        init = Init("uniform", 1.0 / math.sqrt(c_in * KERNEL * KERNEL / self.stride**2))
        kernel = param(self, "kernel", init, (KERNEL, KERNEL, c_in, self.features))
        # lax.conv_transpose correlates the dilated, padded input with the kernel; flipped, it scatters.
        out = lax.conv_transpose(
            x, kernel[::-1, ::-1], (self.stride,) * 2, "VALID", dimension_numbers=("NHWC", "HWIO", "NHWC")
        )
        return out + param(self, "bias", init, (self.features,))


class PaperActorCritic(nn.Module):
    """``PaperActorCritic(net_cfg).apply({"params": params}, carry, obs, resets)`` -> (final `Carry`,
    `Output`), the function ``modules.ActorCritic(net_cfg)`` computes with the same params.

    carry: `Carry` f32[B, hidden] x 2; obs uint8[T, B, 21, 21, 3]; resets bool[T, B] (before step t, the carry
    of every sequence with resets[t, b] is zeroed: a reset step starts a fresh episode). ``init`` with the
    same arguments also creates the auxiliary heads' params (`decode`, `attention_logits`).
    """

    net_cfg: NetworkConfig

    def setup(self):
        cfg = self.net_cfg
        if cfg.symbolic:
            raise ValueError("PaperActorCritic reads pixel views; symbolic views run in modules.ActorCritic")
        (c1, c2, c3), pixels = cfg.conv_channels, OBS_SHAPE[-1]
        self.conv1 = conv(c1, STRIDES[0], pixels, "conv1")
        self.conv2 = conv(c2, STRIDES[1], c1, "conv2")
        self.conv3 = conv(c3, STRIDES[2], c2, "conv3")
        self.fc = Dense(cfg.hidden, math.sqrt(2.0))
        self.lstm = LSTM(cfg.hidden)
        self.policy = MLP(cfg.mlp, cfg.n_actions, 0.01)
        self.value = MLP(cfg.mlp, 1, 1.0)
        if cfg.attention:
            self.attention = Dense(cfg.n_others * ATTENTION_CLASSES, 0.01)
        if cfg.frame_aux != "none":
            self.aux_fc = Dense(cfg.feature_size, math.sqrt(2.0))
            self.deconv1 = Deconv(c2, STRIDES[2])
            self.deconv2 = Deconv(c1, STRIDES[1])
            self.deconv3 = Deconv(pixels, STRIDES[0])

    def __call__(self, carry: Carry, obs: jax.Array, resets: jax.Array) -> tuple[Carry, Output]:
        t, b = obs.shape[:2]
        x = obs.reshape(t * b, *OBS_SHAPE).astype(jnp.float32) / 255.0  # 21x21
        x = nn.leaky_relu(self.conv1(x), LEAKY_SLOPE)  # 7x7
        x = nn.leaky_relu(self.conv2(x), LEAKY_SLOPE)  # 5x5
        x = nn.leaky_relu(self.conv3(x), LEAKY_SLOPE)  # 3x3
        x = jnp.tanh(self.fc(x.reshape(t, b, -1)))
        carry, hidden = self.lstm(carry, x, resets)
        out = Output(logits=self.policy(hidden), value=self.value(hidden)[..., 0], hidden=hidden)
        if self.is_initializing():  # create the auxiliary heads' params too
            if self.net_cfg.attention:
                self.attention_logits(hidden)
            if self.net_cfg.frame_aux != "none":
                self.decode(hidden, jnp.zeros((t, b), jnp.int32))
        return carry, out

    def decode(self, hidden: jax.Array, action: jax.Array) -> jax.Array:
        """The auxiliary decoder: LSTM outputs f32[..., H], actions int[...] -> frames f32[..., 21, 21, 3]
        (linear output, compared with obs / 255: `frame_errors`)."""
        self.net_cfg.check_decoder()
        batch = hidden.shape[:-1]
        z = jnp.concatenate([hidden, jax.nn.one_hot(action, self.net_cfg.n_actions)], axis=-1)
        x = jnp.tanh(self.aux_fc(z)).reshape(-1, *self.net_cfg.feature_shape)  # 3x3
        x = nn.leaky_relu(self.deconv1(x), LEAKY_SLOPE)  # 5x5
        x = nn.leaky_relu(self.deconv2(x), LEAKY_SLOPE)  # 7x7
        return self.deconv3(x).reshape(*batch, *OBS_SHAPE)  # 21x21

    def frame_errors(self, hidden: jax.Array, action: jax.Array, target: jax.Array) -> jax.Array:
        """The auxiliary loss per frame, f32[...]: the mean absolute error of `decode` against target / 255
        (target uint8[..., 21, 21, 3]: the current view for aux "rec", the next one for "pred"; `aux_loss`
        weights and sums it)."""
        return jnp.abs(self.decode(hidden, action) - target / 255.0).mean(axis=(-3, -2, -1))

    def attention_logits(self, hidden: jax.Array) -> jax.Array:
        """LSTM outputs f32[..., H] -> logits f32[..., n_others, 50] over each other slot's view cell."""
        logits = self.attention(hidden)
        return logits.reshape(*hidden.shape[:-1], self.net_cfg.n_others, ATTENTION_CLASSES)
