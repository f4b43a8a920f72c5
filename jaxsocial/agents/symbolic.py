"""The symbolic views' vocabulary: how the network reads and predicts int8[7, 7, 4] views.

Each cell of a view (`observe.symbolic`) holds four channels: tile, agent index + 1, heading and colour.
The network turns each channel value into a class index of one shared vocabulary (`symbolic_classes`): the
encoder's `modules.Embed` sums one learned vector per class (`SYMBOLIC_VOCAB` rows), the decoder predicts
logits over `PREDICTED_CLASSES` per cell (`PREDICTED_VOCAB`, the colour merged into 16 bins), trained by a
masked cross-entropy (`symbolic_errors`). The vocabulary is plain numbers (a `NetworkConfig` reads it before
JAX is imported); `symbolic_classes` and `symbolic_errors` import JAX.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from jaxsocial.env.params import MAX_AGENTS, NUM_TILE_TYPES

if TYPE_CHECKING:
    import jax

SYMBOLIC_SHAPE = (7, 7, 4)  # per view cell: tile, agent index + 1, heading, colour (`observe.symbolic`)
SYMBOLIC_SHIFT = (1, 0, 1, 0)  # added to each channel's value to make a class index (tile and heading use -1)
SYMBOLIC_CLASSES = (NUM_TILE_TYPES + 1, MAX_AGENTS + 1, 5, 128)  # classes per channel (colour: 0-127)
SYMBOLIC_VOCAB = sum(SYMBOLIC_CLASSES)  # rows of the embedding table
PREDICTED_CLASSES = (*SYMBOLIC_CLASSES[:3], 16)  # the decoder's classes: colour in 16 bins of 8 levels
PREDICTED_VOCAB = sum(PREDICTED_CLASSES)  # logits per view cell of the decoder


def symbolic_classes(cells: jax.Array, classes: tuple[int, ...] = SYMBOLIC_CLASSES) -> jax.Array:
    """int8[..., 4] symbolic cells -> int32[..., 4] each channel's class, offset into a shared vocabulary of
    ``sum(classes)`` (channel k's classes are ``offsets(classes)[k] + [0, classes[k])``); `classes` with fewer
    classes than `SYMBOLIC_CLASSES` merge neighbouring values (`PREDICTED_CLASSES`: colour levels 8 by 8)."""
    import jax.numpy as jnp

    merge = np.asarray(SYMBOLIC_CLASSES) // np.asarray(classes)
    return (cells.astype(jnp.int32) + jnp.asarray(SYMBOLIC_SHIFT)) // merge + jnp.asarray(offsets(classes))


def offsets(classes: tuple[int, ...]) -> tuple[int, ...]:
    """Where each channel's classes start in a vocabulary of ``sum(classes)``."""
    return tuple(sum(classes[:k]) for k in range(len(classes)))


def symbolic_errors(logits: jax.Array, target: jax.Array) -> jax.Array:
    """Masked cross-entropy of symbolic views, f32[N]: logits f32[7, 7, N, PREDICTED_VOCAB] and target
    int8[7, 7, N, 4] (HWNC). Each channel's classes (`PREDICTED_CLASSES`: the colour in 16 bins, which keeps
    the output 4.4x smaller than all 128 levels would) get a softmax of their own; the negative
    log-likelihood of the target class is averaged over the 4 channels and 49 cells, where heading and colour
    count only in cells that hold an agent (elsewhere they are zero terms: no agent, nothing to predict)."""
    import jax
    import jax.numpy as jnp

    classes = symbolic_classes(target, PREDICTED_CLASSES)
    has_agent = target[..., 1] > 0
    total = 0.0
    for k, (offset, size) in enumerate(zip(offsets(PREDICTED_CLASSES), PREDICTED_CLASSES, strict=True)):
        channel = logits[..., offset : offset + size]
        picked = jnp.take_along_axis(channel, classes[..., k, None] - offset, -1)[..., 0]
        nll = jax.nn.logsumexp(channel, -1) - picked
        total = total + (jnp.where(has_agent, nll, 0.0) if k >= 2 else nll)
    h, w, n = total.shape
    return jnp.ones(h * w) @ total.reshape(h * w, n) / (h * w * len(PREDICTED_CLASSES))
