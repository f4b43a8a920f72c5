"""The reference network the tests hold `modules.ActorCritic` to: the recurrent actor-critic of Ndousse et al.
(2021) in plain Flax layers (`PaperActorCritic`), the network of `jaxsocial.agents.network`'s docstring
written to be read rather than run fast.

``nn.Conv`` and ``lax.conv_transpose`` on NHWC frames, float32 products, every parameter drawn from its own
`Init`; convolutions take PyTorch's default U(-1/sqrt(fan_in), 1/sqrt(fan_in)), transposed: the effective
fan-in C_in * 9 / stride^2; pixel views only. Its params tree is the one `network.init` draws, and
tests/test_network.py checks that it computes `network.unroll`, `decode` and `aux_loss` with them.
"""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax import lax

from jaxsocial.agents.fast.conv import KERNEL
from jaxsocial.agents.fast.frame_batches import LEAKY_SLOPE
from jaxsocial.agents.initialisers import Init, param
from jaxsocial.agents.layers import LSTM, MLP, Carry, Dense, Output
from jaxsocial.agents.network_config import ATTENTION_CLASSES, OBS_SHAPE, STRIDES, NetworkConfig


def paper_conv(features: int, stride: int, c_in: int, name: str) -> nn.Conv:
    """3x3 VALID convolution of NHWC frames (like torch Conv2d), PyTorch's default uniform init."""
    bound = 1.0 / math.sqrt(c_in * KERNEL * KERNEL)
    init = Init("uniform", bound)
    return nn.Conv(features, (KERNEL, KERNEL), stride, "VALID", kernel_init=init, bias_init=init, name=name)


class PaperDeconv(nn.Module):
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
        self.conv1 = paper_conv(c1, STRIDES[0], pixels, "conv1")
        self.conv2 = paper_conv(c2, STRIDES[1], c1, "conv2")
        self.conv3 = paper_conv(c3, STRIDES[2], c2, "conv3")
        self.fc = Dense(cfg.hidden, math.sqrt(2.0))
        self.lstm = LSTM(cfg.hidden)
        self.policy = MLP(cfg.mlp, cfg.n_actions, 0.01)
        self.value = MLP(cfg.mlp, 1, 1.0)
        if cfg.attention:
            self.attention = Dense(cfg.n_others * ATTENTION_CLASSES, 0.01)
        if cfg.frame_aux != "none":
            self.aux_fc = Dense(cfg.feature_size, math.sqrt(2.0))
            self.deconv1 = PaperDeconv(c2, STRIDES[2])
            self.deconv2 = PaperDeconv(c1, STRIDES[1])
            self.deconv3 = PaperDeconv(pixels, STRIDES[0])

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
        (target uint8[..., 21, 21, 3]: the current view for aux "rec", the next one for "pred";
        `network.aux_loss` weights and sums it)."""
        return jnp.abs(self.decode(hidden, action) - target / 255.0).mean(axis=(-3, -2, -1))

    def attention_logits(self, hidden: jax.Array) -> jax.Array:
        """LSTM outputs f32[..., H] -> logits f32[..., n_others, 50] over each other slot's view cell."""
        logits = self.attention(hidden)
        return logits.reshape(*hidden.shape[:-1], self.net_cfg.n_others, ATTENTION_CLASSES)
