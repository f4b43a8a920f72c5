"""The network's Flax linen modules as they run: `ActorCritic`, the network that trains: the function of the
tests' reference in plain Flax layers (`PaperActorCritic`, tests/reference_network.py), with the same params
tree, computed faster. Its `Encoder` and `Decoder` (the auxiliary frame head) run their convolutions
(`Conv`) in frame batches and in the kernel `conv_impl` picks (`fast/`); `Embed` maps symbolic views; `LSTM`,
`MLP` and `Dense` are `layers`'. `network` applies them to a params dict.

Conventions: conv kernels are HWIO ``[3, 3, C_in, C_out]``, and the conv layers take and return HWNC
activations (`conv`); deconv kernels are ``[3, 3, C_in, C_out]`` with torch ConvTranspose2d (scatter)
semantics. Every layer creates its params with `initialisers.param`, with the distributions its docstring
states (`Conv`, `Embed`) or `layers` states.
"""

from __future__ import annotations

import math

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

from jaxsocial.agents.fast import conv
from jaxsocial.agents.fast.conv import KERNEL
from jaxsocial.agents.fast.frame_batches import SAVED, leaky_relu, leaky_relu_unsaved, map_frame_batches
from jaxsocial.agents.initialisers import ZEROS, Init, param
from jaxsocial.agents.layers import LSTM, MLP, Carry, Dense, Output
from jaxsocial.agents.network_config import ATTENTION_CLASSES, OBS_SHAPE, STRIDES, NetworkConfig
from jaxsocial.agents.symbolic import PREDICTED_VOCAB, SYMBOLIC_VOCAB, symbolic_classes, symbolic_errors


class Conv(nn.Module):
    """3x3 VALID convolution of HWNC activations f32[h, w, n, c_in] -> f32[h', w', n, features] (`conv.conv`;
    transpose: `conv.deconv`), PyTorch's default uniform init with fan-in c_in * 9 (/ stride^2 transposed)."""

    features: int
    stride: int
    impl: str
    transpose: bool = False
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        c_in = x.shape[-1]
        bound = 1.0 / math.sqrt(c_in * KERNEL * KERNEL / (self.stride**2 if self.transpose else 1))
        kernel = param(self, "kernel", Init("uniform", bound), (KERNEL, KERNEL, c_in, self.features))
        bias = param(self, "bias", Init("uniform", bound), (self.features,))
        layer = conv.deconv if self.transpose else conv.conv
        return layer(x, kernel, bias, self.stride, self.impl, self.dtype)


class Embed(nn.Module):
    """Symbolic view cells int8[..., 4] -> f32[..., features]: the sum of one learned vector per channel value
    (the concatenated per-channel embeddings times a linear map), plus a bias. N(0, 1) init like
    ``torch.nn.Embedding``, zero bias."""

    features: int

    @nn.compact
    def __call__(self, cells: jax.Array) -> jax.Array:
        kernel = param(self, "kernel", Init("normal", 1.0), (SYMBOLIC_VOCAB, self.features))
        return kernel[symbolic_classes(cells)].sum(-2) + param(self, "bias", ZEROS, (self.features,))


class Encoder(nn.Module):
    """Frames uint8[N, 21, 21, 3] -> features f32[N, hidden]: three leaky-ReLU convs, FC, tanh. Symbolic
    views int8[N, 7, 7, 4] (`NetworkConfig.obs`): an `Embed` per cell in place of conv1 (7x7 cells either
    way).

    The convolutions run in batches of `NetworkConfig.frame_batch` frames (`map_frame_batches`), up to conv3's
    pre-activation; its activation and the FC layer run on all N frames at once, as large matrix products.
    """

    net_cfg: NetworkConfig

    def setup(self):
        (c1, c2, c3), impl, dtype = (
            self.net_cfg.conv_channels,
            self.net_cfg.impl_for,
            self.net_cfg.compute_dtype,
        )
        if self.net_cfg.symbolic:
            self.embed = Embed(c1)
        else:
            self.conv1 = Conv(c1, STRIDES[0], impl("conv1"), dtype=dtype)
        self.conv2 = Conv(c2, STRIDES[1], impl("conv2"), dtype=dtype)
        self.conv3 = Conv(c3, STRIDES[2], impl("conv3"), dtype=dtype)
        self.fc = Dense(self.net_cfg.hidden, math.sqrt(2.0), dtype)

    def __call__(self, obs: jax.Array) -> jax.Array:
        chex.assert_shape(obs, (None, *self.net_cfg.obs_shape))
        chex.assert_type(obs, self.net_cfg.obs_dtype)
        x = leaky_relu(map_frame_batches(Encoder.conv_features, self, (obs,), self.net_cfg.frame_batch))
        return jnp.tanh(self.fc(x))

    def conv_features(self, obs: jax.Array) -> jax.Array:
        """uint8[n, 21, 21, 3] (or int8[n, 7, 7, 4]) -> conv3's pre-activation f32[n, feature_size], flattened
        (h, w, c)."""
        if self.net_cfg.symbolic:
            x = self.embed(conv.to_hwnc(obs))
        else:
            x = self.conv1(conv.to_hwnc(obs).astype(jnp.float32) * (1.0 / 255.0))
        # conv1's activation is recomputed from obs, not saved (+0.6% FLOPs, 6 KB less memory per frame)
        x = leaky_relu_unsaved(x)
        x = leaky_relu(self.conv2(x))
        x = self.conv3(x)
        return conv.to_nhwc(x).reshape(x.shape[2], -1)


class Decoder(nn.Module):
    """The auxiliary frame head: LSTM outputs f32[..., H] and actions int[...] -> frames f32[..., 21, 21, 3].

    Unbounded (linear output layer); the learner compares it with obs / 255 (`aux_loss`). Runs in batches of
    `NetworkConfig.frame_batch` frames (`map_frame_batches`). Symbolic views: ``cell_logits``, a dense layer
    per view cell, in place of deconv3 gives logits f32[..., 7, 7, PREDICTED_VOCAB] (`symbolic_errors`).
    """

    net_cfg: NetworkConfig

    def setup(self):
        (c1, c2, _), impl, dtype = (
            self.net_cfg.conv_channels,
            self.net_cfg.impl_for,
            self.net_cfg.compute_dtype,
        )
        self.aux_fc = Dense(self.net_cfg.feature_size, math.sqrt(2.0), dtype)
        self.deconv1 = Conv(c2, STRIDES[2], impl("deconv1"), transpose=True, dtype=dtype)
        self.deconv2 = Conv(c1, STRIDES[1], impl("deconv2"), transpose=True, dtype=dtype)
        if self.net_cfg.symbolic:
            self.cell_logits = Dense(PREDICTED_VOCAB, 1.0, dtype)
        else:
            self.deconv3 = Conv(OBS_SHAPE[-1], STRIDES[0], impl("deconv3"), transpose=True, dtype=dtype)

    def __call__(self, hidden: jax.Array, action: jax.Array) -> jax.Array:
        batch = hidden.shape[:-1]
        chex.assert_shape(hidden, (*batch, self.net_cfg.hidden))
        chex.assert_shape(action, batch)
        rows = (hidden.reshape(-1, hidden.shape[-1]), jnp.asarray(action).reshape(-1))
        frames = map_frame_batches(
            lambda mdl, *rows: conv.to_nhwc(mdl.frames_hwnc(*rows)), self, rows, self.net_cfg.frame_batch
        )
        return frames.reshape(*batch, *self.net_cfg.decoded_shape)

    def frames_hwnc(self, hidden: jax.Array, action: jax.Array) -> jax.Array:
        """Rows hidden f32[N, H], action int[N] -> frames f32[21, 21, N, 3] (HWNC), in one piece (symbolic:
        logits f32[7, 7, N, PREDICTED_VOCAB])."""
        z = jnp.concatenate(
            [hidden, jax.nn.one_hot(action, self.net_cfg.n_actions, dtype=hidden.dtype)], axis=-1
        )
        x = checkpoint_name(jnp.tanh(self.aux_fc(z)), SAVED)
        x = conv.to_hwnc(x.reshape(-1, *self.net_cfg.feature_shape))
        x = leaky_relu(self.deconv1(x))
        x = leaky_relu(self.deconv2(x))
        return self.cell_logits(x) if self.net_cfg.symbolic else self.deconv3(x)  # linear output

    def frame_errors(self, hidden: jax.Array, action: jax.Array, target: jax.Array) -> jax.Array:
        """Mean absolute error of each frame's prediction against target / 255, f32[N], for rows hidden
        f32[N, H], action int[N], target uint8[N, 21, 21, 3], in one piece (symbolic: `symbolic_errors`)."""
        if self.net_cfg.symbolic:
            return symbolic_errors(self.frames_hwnc(hidden, action), conv.to_hwnc(target))
        # Compared in 3x3 blocks, the layout of deconv3's matrix product: XLA then cancels the deconvolution's
        # transpose to HWNC with this one, here and in the backward pass (+12% for the small training preset).
        prediction = conv.blocks(self.frames_hwnc(hidden, action))
        error = jnp.abs(prediction - conv.blocks(conv.to_hwnc(target)).astype(jnp.float32) / 255.0)
        h, w, n, c = error.shape
        # The sum over pixels as a matrix-vector product: XLA:CPU's reduction over axes (0, 1, 3) took 10x
        # longer.
        return (jnp.ones(h * w) @ error.reshape(h * w, n * c)).reshape(n, c).sum(axis=-1) / (h * w * c)

    def errors(self, hidden: jax.Array, action: jax.Array, target: jax.Array) -> jax.Array:
        """`frame_errors` of rows f32[N, H], int[N], uint8[N, 21, 21, 3] (or int8[N, 7, 7, 4]) -> f32[N], in
        frame batches."""
        return map_frame_batches(
            Decoder.frame_errors, self, (hidden, action, target), self.net_cfg.frame_batch
        )


class ActorCritic(nn.Module):
    """The recurrent actor-critic: ``ActorCritic(net_cfg).apply({"params": params}, carry, obs, resets)`` runs
    it over T steps of B sequences and returns the final `Carry` and per-step `Output`s.

    carry: `Carry` f32[B, hidden] x 2; obs uint8[T, B, 21, 21, 3] (int8[T, B, 7, 7, 4] symbolic); resets
    bool[T, B] (before step t, the carry of every sequence with resets[t, b] is zeroed: a reset step starts a
    fresh episode). ``init`` with the same arguments also creates the auxiliary heads' params (`decode`,
    `attention_logits`).
    """

    net_cfg: NetworkConfig

    def setup(self):
        net_cfg, dtype = self.net_cfg, self.net_cfg.compute_dtype
        self.encoder = Encoder(net_cfg)
        nn.share_scope(self, self.encoder)  # its layers are top-level entries of the params tree
        self.lstm = LSTM(net_cfg.hidden, dtype)
        self.policy = MLP(net_cfg.mlp, net_cfg.n_actions, 0.01, dtype)
        self.value = MLP(net_cfg.mlp, 1, 1.0, dtype)
        if net_cfg.attention:
            self.attention = Dense(net_cfg.n_others * ATTENTION_CLASSES, 0.01, dtype)
        if net_cfg.frame_aux != "none":
            self.decoder = Decoder(net_cfg)
            nn.share_scope(self, self.decoder)

    def __call__(self, carry: Carry, obs: jax.Array, resets: jax.Array) -> tuple[Carry, Output]:
        net_cfg = self.net_cfg
        t, b = obs.shape[:2]
        chex.assert_shape(obs, (t, b, *net_cfg.obs_shape))
        chex.assert_shape(resets, (t, b))
        chex.assert_shape([carry.c, carry.h], (b, net_cfg.hidden))
        chex.assert_type([resets, carry.c, carry.h], [bool, jnp.float32, jnp.float32])
        x = self.encoder(obs.reshape(t * b, *net_cfg.obs_shape)).reshape(t, b, -1)
        carry, hidden = self.lstm(carry, x, resets)
        out = Output(logits=self.policy(hidden), value=self.value(hidden)[..., 0], hidden=hidden)
        if self.is_initializing():  # create the auxiliary heads' params too
            if net_cfg.attention:
                self.attention_logits(hidden)
            if net_cfg.frame_aux != "none":
                self.decode(hidden, jnp.zeros((t, b), jnp.int32))
        return carry, out

    def attention_logits(self, hidden: jax.Array) -> jax.Array:
        """LSTM outputs f32[..., H] -> logits f32[..., n_others, 50] over each other slot's view cell."""
        if not self.net_cfg.attention:
            raise ValueError(f"cfg.aux == {self.net_cfg.aux!r} has no attention head")
        logits = self.attention(hidden)
        return logits.reshape(*hidden.shape[:-1], self.net_cfg.n_others, ATTENTION_CLASSES)

    def decode(self, hidden: jax.Array, action: jax.Array) -> jax.Array:
        """`Decoder`: hidden f32[..., H], action int[...] -> f32[..., *net_cfg.decoded_shape]."""
        self.net_cfg.check_decoder()
        return self.decoder(hidden, action)
