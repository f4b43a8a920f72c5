"""`NetworkConfig`, the network's widths and options, and the shapes that follow from them.

`conv_impl`, `chunk` and `dtype` change how, not what, the network computes: the conv kernels (`conv.IMPLS`),
the frames per chunk in which the conv encoder and the decoder run (`chunks.map_chunks`), and the input
dtype of every matrix product and convolution (`precision.matmul`; params, LSTM state and outputs stay
float32). Why and how fast: docs/performance.md.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp

from jaxsocial.agents import conv, precision
from jaxsocial.agents.conv import KERNEL
from jaxsocial.agents.symbolic import PREDICTED_VOCAB, SYMBOLIC_SHAPE

OBS_SHAPE = (21, 21, 3)  # 7x7 grid cells of 3x3 pixels (marlgrid tile size 3)
OBS_KINDS = ("rgb", "symbolic")  # `NetworkConfig.obs`: the environment's `EnvParams.observation`
STRIDES = (3, 1, 1)  # encoder strides; the decoder mirrors them in reverse order
AUX_KINDS = ("none", "rec", "pred", "attention", "rec+attention", "pred+attention")
ATTENTION_CLASSES = (OBS_SHAPE[0] // KERNEL) ** 2 + 1  # the 7x7 view cells, then "not in view"
CONV_IMPLS = conv.IMPLS
DTYPES = precision.DTYPES
DECODER_PARAMS = ("aux_fc", "deconv1", "deconv2", "deconv3")  # the `Decoder`'s entries of the params tree


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Widths of the network; the defaults are the paper's."""

    conv_channels: tuple[int, int, int] = (32, 64, 64)
    """Output channels of the three convolutions."""
    hidden: int = 192
    """Width of the FC layer and the LSTM."""
    mlp: int = 64
    """Hidden width of the value and policy MLPs."""
    aux: str = "pred"
    """Auxiliary loss: "none", "rec" (reconstruct the current frame), "pred" (predict the next frame),
    "attention" (locate the other agents in the view), "rec+attention" or "pred+attention"."""
    n_actions: int = 7
    """Actions of the policy output."""
    conv_impl: str = "matmul"
    """How convolutions are computed (same result, different speed): "matmul" (matrix products: Winograd in
    float32, im2col in bfloat16; fastest measured on CPU and GPU), "im2col" (one product of the 3x3 patches
    per layer) or "xla" (XLA's convolutions)."""
    chunk: int = 512
    """Frames processed at a time by the conv encoder and decoder (speed and memory only)."""
    n_others: int = 2
    """Other agents the attention auxiliary head locates (the environment's agents - 1)."""
    obs: str = "rgb"
    """Observations the network takes: "rgb" frames or "symbolic" views (set from the environment)."""
    dtype: str = "float32"
    """Input dtype of matrix products and convolutions: "float32", or "bfloat16" (float32 accumulation;
    params, optimiser state, LSTM state and losses stay float32). Whether it is faster depends on the
    hardware (docs/performance.md)."""

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
        if self.obs not in OBS_KINDS:
            raise ValueError(f"unknown obs {self.obs!r}; choose from {OBS_KINDS}")
        if self.dtype not in DTYPES:
            raise ValueError(f"unknown dtype {self.dtype!r}; choose from {DTYPES}")

    @property
    def symbolic(self) -> bool:
        return self.obs == "symbolic"

    @property
    def obs_shape(self) -> tuple[int, int, int]:
        """One observation's shape: (21, 21, 3) RGB or (7, 7, 4) symbolic."""
        return SYMBOLIC_SHAPE if self.symbolic else OBS_SHAPE

    @property
    def obs_dtype(self):
        return jnp.int8 if self.symbolic else jnp.uint8

    @property
    def decoded_shape(self) -> tuple[int, int, int]:
        """`decode`'s output per step: frames (21, 21, 3), or logits (7, 7, PREDICTED_VOCAB) per view cell."""
        return (*SYMBOLIC_SHAPE[:2], PREDICTED_VOCAB) if self.symbolic else OBS_SHAPE

    @property
    def decoder_params(self) -> tuple[str, ...]:
        """The `Decoder`'s entries of the params tree."""
        return (*DECODER_PARAMS[:-1], "cell_logits") if self.symbolic else DECODER_PARAMS

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
        # symbolic: the embedding is per cell, in place of conv1 (which maps 3x3 pixel blocks to cells)
        size, strides = (SYMBOLIC_SHAPE[0], STRIDES[1:]) if self.symbolic else (OBS_SHAPE[0], STRIDES)
        for stride in strides:
            size = (size - KERNEL) // stride + 1
        return (size, size, self.conv_channels[-1])

    @property
    def feature_size(self) -> int:
        return math.prod(self.feature_shape)

    def check_decoder(self) -> None:
        """Raises ValueError if the config builds no auxiliary decoder (`frame_aux` "none")."""
        if self.frame_aux == "none":
            raise ValueError(f"decoding needs an auxiliary decoder, but cfg.aux == {self.aux!r} built none")
