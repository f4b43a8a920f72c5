"""`NetworkConfig`, the network's widths and options, and the shapes that follow from them.

`conv_impl`, `frame_batch` and `dtype` change how, not what, the network computes: the conv kernels
(`options.IMPLS`), the frames at a time the conv encoder and the decoder run on
(`frame_batches.map_frame_batches`), and the input dtype of every matrix product and convolution
(`precision.matmul`; params, LSTM state and outputs stay float32). Why and how fast: docs/performance.md.

`conv_impl` names one implementation for every conv layer ("matmul"), or one per layer
("conv1=xla,conv2=matmul,..."; `CONV_LAYERS`, `parse_conv_impl`). "auto" (for every layer, or for some:
"conv2=auto") and ``dtype="auto"`` are choices left to the machine: `jaxsocial.run.autotune.resolve`
replaces them with concrete ones (measured, and cached), which is what a run's config.json records.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal, get_args

from jaxsocial import syntax
from jaxsocial.agents.fast import options
from jaxsocial.agents.fast.options import KERNEL
from jaxsocial.agents.symbolic import PREDICTED_VOCAB, SYMBOLIC_SHAPE

OBS_SHAPE = (21, 21, 3)  # 7x7 grid cells of 3x3 pixels (marlgrid tile size 3)
Obs = Literal["rgb", "symbolic"]
"""`NetworkConfig.obs`: the environment's `EnvParams.observation`."""
OBS_KINDS = get_args(Obs)
STRIDES = (3, 1, 1)  # encoder strides; the decoder mirrors them in reverse order
Aux = Literal["none", "rec", "pred", "attention", "rec+attention", "pred+attention"]
"""`NetworkConfig.aux`: a frame loss ("rec", "pred"), the attention head, both, or neither."""
AUX_KINDS = get_args(Aux)
ATTENTION_CLASSES = (OBS_SHAPE[0] // KERNEL) ** 2 + 1  # the 7x7 view cells, then "not in view"
CONV_IMPLS = options.IMPLS
"""The concrete convolution implementations (`NetworkConfig.conv_impl`, for all layers or per layer)."""
DTYPES = options.DTYPES
"""The concrete compute dtypes (`NetworkConfig.dtype`)."""
AUTO = "auto"
"""The `conv_impl` and `dtype` value (also of one layer's `conv_impl`) that `autotune.resolve` replaces with
the machine's choice."""
CONV_LAYERS = ("conv1", "conv2", "conv3", "deconv1", "deconv2", "deconv3")
"""The conv layers a per-layer `conv_impl` names: the encoder's (conv1: RGB only) and the decoder's (deconv3:
RGB only; the decoder only with a frame auxiliary loss). `NetworkConfig.conv_layers`: those a config has."""
UNRESOLVED_IMPL = "matmul"
"""What a layer still set to "auto" computes with when the network is built unresolved (the formulation
measured fastest on CPU and GPU for the paper network; the same function as every other)."""
DECODER_PARAMS = ("aux_fc", "deconv1", "deconv2", "deconv3")  # the `Decoder`'s entries of the params tree
LEGACY_KEYS = {"chunk": "frame_batch"}
"""Fields of saved network configs (a policy's metadata, config.json's "net") renamed since: old -> new
(`modern_net_keys`)."""


def renamed_keys(values: dict[str, Any], renames: dict[str, str]) -> dict[str, Any]:
    """`values` (a copy, in its order) with each key of `renames` under its new name; where both names are
    present, the new one's value."""
    return {renames.get(k, k): v for k, v in values.items() if not (k in renames and renames[k] in values)}


def modern_net_keys(net: dict[str, Any]) -> dict[str, Any]:
    """A saved network config's fields (JSON) under today's names (`LEGACY_KEYS`): what `NetworkConfig(**...)`
    takes, also for policies and runs written before the renames."""
    return renamed_keys(net, LEGACY_KEYS)


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Widths of the network; the defaults are the paper's."""

    conv_channels: tuple[int, int, int] = (32, 64, 64)
    """Output channels of the three convolutions."""
    hidden: int = 192
    """Width of the FC layer and the LSTM."""
    mlp: int = 64
    """Hidden width of the value and policy MLPs."""
    aux: Aux = "pred"
    """Auxiliary loss: "none", "rec" (reconstruct the current frame), "pred" (predict the next frame),
    "attention" (locate the other agents in the view), "rec+attention" or "pred+attention"."""
    n_actions: int = 7
    """Actions of the policy output."""
    conv_impl: str = "matmul"
    """How convolutions are computed (same result, different speed): "matmul" (matrix products: Winograd in
    float32, im2col in bfloat16; fastest measured on CPU and GPU), "im2col" (one product of the 3x3 patches
    per layer) or "xla" (XLA's convolutions), for every layer; or per layer, comma-separated ``layer=impl``
    entries of `CONV_LAYERS` ("conv1=xla,conv2=matmul"), with at most one bare impl as the default of the
    layers not named (without one: "matmul"). "auto", for all layers or as a layer's impl: measured on this
    machine at start-up (`autotune.resolve`, which writes the per-layer choice here)."""
    frame_batch: int = 512
    """Frames processed at a time by the conv encoder and decoder (speed and memory only)."""
    n_others: int = 2
    """Other agents the attention auxiliary head locates (the environment's agents - 1)."""
    obs: Obs = "rgb"
    """Observations the network takes: "rgb" frames or "symbolic" views (set from the environment)."""
    dtype: str = "float32"
    """Input dtype of matrix products and convolutions: "float32", or "bfloat16" (float32 accumulation;
    params, optimiser state, LSTM state and losses stay float32). Whether it is faster depends on the
    hardware (docs/performance.md). "auto": bfloat16 on GPUs and on CPUs with AMX, float32 otherwise
    (`autotune.auto_dtype`)."""

    def __post_init__(self):
        channels = tuple(self.conv_channels)
        if len(channels) != 3:
            raise ValueError(f"conv_channels must have 3 entries, got {self.conv_channels!r}")
        object.__setattr__(self, "conv_channels", channels)

        def positive_int(value) -> bool:
            return isinstance(value, int) and not isinstance(value, bool) and value > 0

        if not all(positive_int(c) for c in channels):
            raise ValueError(f"conv_channels must be positive integers, got {self.conv_channels!r}")
        for name in ("hidden", "mlp", "n_actions", "frame_batch", "n_others"):
            if not positive_int(getattr(self, name)):
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")
        if self.aux not in AUX_KINDS:
            raise ValueError(f"unknown aux {self.aux!r}; choose from {AUX_KINDS}")
        object.__setattr__(self, "_impls", parse_conv_impl(self.conv_impl))  # parsed once; raises ValueError
        if self.obs not in OBS_KINDS:
            raise ValueError(f"unknown obs {self.obs!r}; choose from {OBS_KINDS}")
        if self.dtype not in (*DTYPES, AUTO):
            raise ValueError(f"unknown dtype {self.dtype!r}; choose from {(*DTYPES, AUTO)}")

    @property
    def symbolic(self) -> bool:
        return self.obs == "symbolic"

    @property
    def conv_layers(self) -> tuple[str, ...]:
        """The conv layers of this network (`CONV_LAYERS` less conv1 and deconv3 for symbolic views, less the
        decoder's without a frame auxiliary loss)."""
        layers = ("conv2", "conv3") if self.symbolic else ("conv1", "conv2", "conv3")
        if self.frame_aux != "none":
            layers += ("deconv1", "deconv2") if self.symbolic else ("deconv1", "deconv2", "deconv3")
        return layers

    @property
    def impls(self) -> dict[str, str]:
        """Every layer of `CONV_LAYERS` -> its `conv_impl` entry (`parse_conv_impl`, parsed once)."""
        return dict(self._impls)

    @property
    def layer_impls(self) -> dict[str, str]:
        """`conv_layers` -> their `conv_impl` entry (a `CONV_IMPLS` value or "auto")."""
        return {layer: self._impls[layer] for layer in self.conv_layers}

    def impl_for(self, layer: str) -> str:
        """The implementation `layer` computes with (`UNRESOLVED_IMPL` for one still "auto")."""
        impl = self._impls[layer]
        return UNRESOLVED_IMPL if impl == AUTO else impl

    @property
    def compute_dtype(self) -> str:
        """The dtype the products compute in; ValueError for "auto", which `autotune.resolve` (run by the
        trainer at start-up) replaces with the machine's choice first."""
        if self.dtype == AUTO:
            raise ValueError(
                'net.dtype="auto" is chosen by autotune.resolve(net, batch) before the network is built'
            )
        return self.dtype

    def check_env(self, params, where: str) -> None:
        """ValueError unless the network takes the observations that environment `params` (`EnvParams`) gives
        (`obs`, and their shape: the networks see a 7x7 view); `where` names the check's context."""
        if self.obs != params.observation:
            raise ValueError(
                f"{where}: the environment gives {params.observation!r} observations, but the network takes "
                f"{self.obs!r} ones (net.obs={self.obs!r}; a policy trained on one kind cannot act on the "
                "other)"
            )
        if tuple(params.obs_shape) != self.obs_shape:
            raise ValueError(
                f"{where}: the network takes observations of shape {self.obs_shape} (view_size=7), the "
                f"environment gives {tuple(params.obs_shape)}"
            )

    def check_others(self, n_agents: int) -> None:
        """ValueError unless the attention head (if any) locates the other agents of an environment of
        `n_agents`: `n_others` = n_agents - 1."""
        if self.attention and self.n_others != n_agents - 1:
            raise ValueError(
                f"net.aux={self.aux!r}: the attention loss locates the {n_agents - 1} other agent slots, so "
                f"it needs net.n_others {n_agents - 1} (got net.n_others {self.n_others})"
            )

    @property
    def unresolved(self) -> bool:
        """Some choice is still "auto" (`autotune.resolve` makes it concrete)."""
        return self.dtype == AUTO or AUTO in self.layer_impls.values()

    @property
    def obs_shape(self) -> tuple[int, int, int]:
        """One observation's shape: (21, 21, 3) RGB or (7, 7, 4) symbolic."""
        return SYMBOLIC_SHAPE if self.symbolic else OBS_SHAPE

    @property
    def obs_dtype(self):
        import jax.numpy as jnp  # a config reads without JAX

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


def parse_conv_impl(value: str) -> dict[str, str]:
    """`NetworkConfig.conv_impl` -> every layer of `CONV_LAYERS` -> its impl (a `CONV_IMPLS` value or "auto").

    "xla" (every layer), "conv1=xla,conv2=matmul" (the layers not named: "matmul") or "xla,conv2=auto" (the
    bare entry is the default). Raises ValueError for an unknown impl or layer, a layer named twice, two
    defaults or an empty entry.
    """
    choices = (*CONV_IMPLS, AUTO)
    if not isinstance(value, str):
        raise ValueError(f"conv_impl must be a string, got {value!r}")
    default, named = None, {}
    for layer, impl in syntax.parse_assignments(value, bare=True):
        if impl not in choices:
            raise ValueError(f"conv_impl {value!r}: unknown implementation {impl!r}; choose from {choices}")
        if layer is None:
            if default is not None:
                raise ValueError(f"conv_impl {value!r}: two defaults ({default!r}, {impl!r})")
            default = impl
        elif layer not in CONV_LAYERS:
            raise ValueError(f"conv_impl {value!r}: unknown layer {layer!r}; choose from {CONV_LAYERS}")
        elif layer in named:
            raise ValueError(f"conv_impl {value!r}: layer {layer!r} named twice")
        else:
            named[layer] = impl
    return {layer: named.get(layer, default or "matmul") for layer in CONV_LAYERS}


def format_conv_impl(impls: dict[str, str]) -> str:
    """{layer: impl} -> the per-layer `conv_impl` string in `CONV_LAYERS` order ("conv1=xla,conv2=matmul")."""
    if unknown := set(impls) - set(CONV_LAYERS):
        raise ValueError(f"unknown conv layers {sorted(unknown)}; choose from {CONV_LAYERS}")
    return syntax.format_assignments((layer, impls[layer]) for layer in CONV_LAYERS if layer in impls)
