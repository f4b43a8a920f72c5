"""The plain Flax layers the network is built of: `Dense`, `MLP` and `LSTM` (in the `modules.ActorCritic` that
runs, and in the tests' reference `PaperActorCritic`, tests/reference_network.py), and the LSTM state `Carry`
and per-step `Output` they pass on.

LSTM gates are ordered (i, f, g, o) like PyTorch, with one bias. Initialisation: dense layers orthogonal with
a gain (sqrt(2) hidden, 1 for the value output, 0.01 for the policy and attention outputs) and zero bias; LSTM
N(0, 1/n_in) input weights, orthogonal recurrent weights per gate, zero bias. Products run in `dtype`
(`precision.matmul`; params and outputs stay float32).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax import lax

from jaxsocial.agents.fast.precision import matmul
from jaxsocial.agents.initialisers import ZEROS, Init, param


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
