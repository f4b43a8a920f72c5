"""The machine's choices for `NetworkConfig` fields set to "auto": `resolve(net_cfg, batch)`.

* ``dtype="auto"`` (`auto_dtype`): "bfloat16" on GPUs (and TPUs) and on CPUs with AMX (`amx_bf16` in
  /proc/cpuinfo's flags), "float32" otherwise. On a CPU without AMX bfloat16 measured slower for the paper
  network (AVX512-BF16 speeds up the dense products, but bfloat16 runs the stride-1 convolutions as im2col
  instead of Winograd: docs/performance.md).
* ``conv_impl="auto"`` (for every layer, or ``layer=auto`` for some; `network_config.parse_conv_impl`): per
  conv layer and deconv layer, the fastest of the implementations (`conv.IMPLS`) on this machine, measured in
  the config's (resolved) dtype for the layer's real shapes: its input ``[h, w, frames, c_in]`` with
  ``frames = min(batch, net_cfg.frame_batch)`` (the conv layers run on `net_cfg.frame_batch` frames at a
  time), the forward pass and the gradients the network needs (conv1: no input gradient), jitted, best of
  `REPS` calls after a warm-up, the candidates interleaved call by call (so the machine's drift affects them
  alike); "matmul" unless another is clearly faster (`choose`, `PREFER`). Candidates that compute alike
  (`conv.formulation`: "matmul" and "im2col" at stride 3, or at stride 1 in bfloat16) are measured once, as
  the first of them in `conv.IMPLS`. A layer timed alone misses what XLA does across layers, so each layer
  whose choice alone is not "matmul" is then confirmed in the whole gradient step (`measure_step`; `tune`) and
  kept only if the step is faster with it.

Measurements are cached in a JSON file (`cache_path`: ``$JAXSOCIAL_CACHE/autotune.json``, by default
``~/.cache/jaxsocial/autotune.json`` beside the compilation cache's ``xla`` directory): each layer's timings
under `LayerSpec.key` (the machine, `machine_id`: platform, device kind or CPU model, the CPU flags that
decide bfloat16's speed, core count, ``$XLA_FLAGS``, the jax and jaxlib versions; the dtype; the layer's kind,
stride, shapes and frame count), and each network's choices under its own key (the machine, dtype, frames,
architecture and the `conv_impl` asked for). With the network's entry `resolve` measures nothing, so its
result is a pure function of the machine and the cache. An unreadable cache is reported (a warning) and
measured afresh; one that cannot be written is reported and the choice used anyway. The paper network's six
layers and two confirming steps took about 20 s on a 2-core CPU at 256 frames, most of it compiling.

Every implementation computes the same function (to float32 rounding), so the choice changes speed only. A
resolved config names every layer's choice (``conv_impl="conv1=matmul,conv2=matmul,...,deconv3=xla"``),
which is what a run's config.json and a saved policy record.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import logging
import os
import sys
import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxsocial import user_cache
from jaxsocial.agents import network
from jaxsocial.agents.fast import conv
from jaxsocial.agents.network_config import (
    AUTO,
    CONV_IMPLS,
    OBS_SHAPE,
    STRIDES,
    NetworkConfig,
    format_conv_impl,
    parse_conv_impl,
)
from jaxsocial.agents.symbolic import SYMBOLIC_SHAPE
from jaxsocial.run import cpuinfo

__all__ = [
    "CACHE_VERSION",
    "REPS",
    "LayerChoice",
    "LayerSpec",
    "Tuning",
    "auto_dtype",
    "cache_path",
    "choose",
    "layer_specs",
    "machine_id",
    "measure",
    "measure_step",
    "resolve",
    "tune",
]

log = logging.getLogger(__name__)

CACHE_VERSION = 1
"""Version of the cache file's layout (a file of another version is measured afresh and rewritten)."""
REPS = 5
"""Timed calls per candidate (best of them), after one untimed warm-up call."""
PREFER = 0.8
"""The first candidate ("matmul", the default) is kept unless another's best time is below this fraction of
its own: a layer timed alone misses what XLA fuses across layers in the network (paper network, float32, 256
frames: conv1 alone measured 0.73 ms with "xla" against 0.84 ms with "matmul", yet the whole gradient step ran
5-9% slower with "xla" for conv1, in 4 of 4 interleaved pairs), and a busy machine's noise."""
STEP_PREFER = 0.97
"""A layer's choice alone is kept in the network only if the gradient step takes less than this fraction of
the time it takes with "matmul" for that layer (`tune`)."""
GIVE_UP = 3.0
"""A candidate whose best time is this many times the best candidate's after a round is timed no further."""
MACHINE_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_tile", "amx_bf16")
"""The /proc/cpuinfo flags that decide the formulations' relative speed (bfloat16: AVX512-BF16, AMX)."""


def backend() -> str:
    """JAX's default backend: "cpu", "gpu" or "tpu"."""
    return jax.default_backend()


def auto_dtype() -> str:
    """``dtype="auto"``: "bfloat16" on GPUs, TPUs and CPUs with AMX (`amx_bf16` flag), "float32" otherwise."""
    if backend() != "cpu":
        return "bfloat16"
    return "bfloat16" if "amx_bf16" in cpuinfo.flags() else "float32"


def machine_id() -> str:
    """What the measurements depend on besides the layer: device (GPU: its kind; CPU: model, `MACHINE_FLAGS`
    present, core count), $XLA_FLAGS, jax and jaxlib versions."""
    import jaxlib

    device = jax.devices()[0]
    if device.platform == "cpu":
        model, flags = (
            cpuinfo.model_name(),
            cpuinfo.flags(),
        )
        present = "+".join(f for f in MACHINE_FLAGS if f in flags) or "-"
        what = f"cpu {model} [{present}] x{os.cpu_count()}"
    else:
        what = f"{device.platform} {device.device_kind} x{jax.device_count()}"
    xla_flags = os.environ.get("XLA_FLAGS", "").strip()
    return f"{what}|jax {jax.__version__} jaxlib {jaxlib.__version__}" + (
        f"|XLA_FLAGS {xla_flags}" if xla_flags else ""
    )


# ---------------------------------------------------------------------------------------------- layers


@dataclasses.dataclass(frozen=True)
class LayerSpec:
    """One conv layer as the network calls it: HWNC input [size, size, frames, c_in], kernel [3, 3, c_in,
    c_out], `conv.conv` or (`transpose`) `conv.deconv`; `input_grad`: the network needs its input's gradient
    (not conv1's, whose input is the observation)."""

    layer: str
    transpose: bool
    stride: int
    size: int
    c_in: int
    c_out: int
    frames: int
    input_grad: bool = True

    def key(self, dtype: str, machine: str) -> str:
        """The cache key of this layer's choice in `dtype` on `machine` (`machine_id`)."""
        kind = "deconv" if self.transpose else "conv"
        grads = "dx,dw" if self.input_grad else "dw"
        return (
            f"{machine}|{dtype}|{kind} stride {self.stride} "
            f"in {self.size}x{self.size}x{self.frames}x{self.c_in} out {self.c_out} grads {grads}"
        )

    def candidates(self, dtype: str) -> tuple[str, ...]:
        """`conv.IMPLS` less those that compute like an earlier one (`conv.formulation`)."""
        seen, out = set(), []
        for impl in CONV_IMPLS:
            if (form := conv.formulation(impl, self.stride, dtype)) not in seen:
                seen.add(form)
                out.append(impl)
        return tuple(out)


def layer_specs(net_cfg: NetworkConfig, batch: int) -> dict[str, LayerSpec]:
    """`net_cfg.conv_layers` -> their `LayerSpec` for calls of `batch` frames (in batches of
    `net_cfg.frame_batch`)."""
    if not (isinstance(batch, int) and not isinstance(batch, bool) and batch > 0):
        raise ValueError(f"batch must be a positive integer (frames per network call), got {batch!r}")
    frames = min(batch, net_cfg.frame_batch)
    c1, c2, c3 = net_cfg.conv_channels
    size = OBS_SHAPE[0]
    sizes = [size // STRIDES[0]]  # 7: conv2's input (conv1's output, or the symbolic view's cells)
    for stride in STRIDES[1:]:
        sizes.append((sizes[-1] - conv.KERNEL) // stride + 1)  # 5, 3
    assert SYMBOLIC_SHAPE[0] == sizes[0]
    specs = {
        "conv1": LayerSpec("conv1", False, STRIDES[0], size, OBS_SHAPE[-1], c1, frames, input_grad=False),
        "conv2": LayerSpec("conv2", False, STRIDES[1], sizes[0], c1, c2, frames),
        "conv3": LayerSpec("conv3", False, STRIDES[2], sizes[1], c2, c3, frames),
        "deconv1": LayerSpec("deconv1", True, STRIDES[2], sizes[2], c3, c2, frames),
        "deconv2": LayerSpec("deconv2", True, STRIDES[1], sizes[1], c2, c1, frames),
        "deconv3": LayerSpec("deconv3", True, STRIDES[0], sizes[0], c1, OBS_SHAPE[-1], frames),
    }
    return {layer: specs[layer] for layer in net_cfg.conv_layers}


# ------------------------------------------------------------------------------------------ measuring


def _compiled(spec: LayerSpec, impl: str, dtype: str):
    """The jitted forward + backward of `spec` computed by `impl`, and its arguments."""
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(spec.size, spec.size, spec.frames, spec.c_in)), jnp.float32)
    kernel = jnp.asarray(
        rng.uniform(-0.3, 0.3, (conv.KERNEL, conv.KERNEL, spec.c_in, spec.c_out)), jnp.float32
    )
    bias = jnp.asarray(rng.uniform(-0.3, 0.3, (spec.c_out,)), jnp.float32)
    layer = conv.deconv if spec.transpose else conv.conv
    out_shape = jax.eval_shape(
        lambda x, k, b: layer(x, k, b, spec.stride, impl, dtype), x, kernel, bias
    ).shape
    cotangent = jnp.asarray(rng.normal(size=out_shape), jnp.float32)

    def loss(x, kernel, bias, cotangent):  # (the cotangent an argument: XLA would fold a constant)
        return jnp.vdot(layer(x, kernel, bias, spec.stride, impl, dtype), cotangent)

    argnums = (0, 1, 2) if spec.input_grad else (1, 2)
    args = (x, kernel, bias, cotangent)
    return jax.jit(jax.grad(loss, argnums)).lower(*args).compile(), args


def measure(spec: LayerSpec, impls: tuple[str, ...], dtype: str, reps: int = REPS) -> dict[str, float]:
    """Best seconds of `reps` forward + backward calls of `spec` per implementation of `impls` (`_best`)."""
    return _best({impl: _compiled(spec, impl, dtype) for impl in impls}, reps)


def _step(net_cfg: NetworkConfig, frames: int):
    """The jitted gradient of a loss on all of `net_cfg`'s heads (value, policy, the auxiliary decoder through
    `network.aux_loss`) for one step of `frames` sequences, and its arguments."""
    rng = np.random.default_rng(0)
    params = jax.jit(network.init, static_argnums=1)(jax.random.key(0), net_cfg)
    if net_cfg.symbolic:
        obs = jnp.zeros((1, frames, *net_cfg.obs_shape), net_cfg.obs_dtype)
    else:
        obs = jnp.asarray(rng.integers(0, 256, (1, frames, *net_cfg.obs_shape)), net_cfg.obs_dtype)
    actions = jnp.asarray(rng.integers(0, net_cfg.n_actions, (1, frames)), jnp.int32)

    def loss(params, obs, actions):
        carry = network.initial_carry(net_cfg, (frames,))
        _, out = network.unroll(params, net_cfg, carry, obs, jnp.zeros((1, frames), bool))
        total = jnp.mean(out.value**2) - jnp.mean(jax.nn.log_softmax(out.logits))
        if net_cfg.frame_aux != "none":
            weight = jnp.full(actions.shape, 1.0 / actions.size)
            total += network.aux_loss(params, net_cfg, out.hidden, actions, obs, weight)
        return total

    args = (params, obs, actions)
    return jax.jit(jax.grad(loss)).lower(*args).compile(), args


def measure_step(nets: tuple[NetworkConfig, ...], frames: int, reps: int = REPS) -> tuple[float, ...]:
    """Best seconds of `reps` gradient steps (`_step`) of `frames` frames per network of `nets` (`_best`)."""
    times = _best({i: _step(net_cfg, frames) for i, net_cfg in enumerate(nets)}, reps)
    return tuple(times[i] for i in range(len(nets)))


def _best(calls: dict, reps: int) -> dict:
    """Best seconds of `reps` calls of each compiled ``(fn, args)`` of `calls`, after a warm-up call each; the
    calls interleaved; one more than `GIVE_UP` times slower than the best after a round is timed no further
    (its best so far is returned)."""
    for fn, args in calls.values():
        jax.block_until_ready(fn(*args))
    best = dict.fromkeys(calls, float("inf"))
    running = list(calls)
    for _ in range(max(1, reps)):
        for name in running:
            fn, args = calls[name]
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*args))
            best[name] = min(best[name], time.perf_counter() - t0)
        fastest = min(best.values())
        running = [name for name in running if best[name] <= GIVE_UP * fastest]
    return best


def choose(times: dict[str, float], candidates: tuple[str, ...]) -> str:
    """The fastest of `candidates` by `times`, except that the first is kept unless the fastest takes less
    than `PREFER` times as long."""
    fastest = min(candidates, key=lambda c: times[c])
    return fastest if times[fastest] < PREFER * times[candidates[0]] else candidates[0]


# ------------------------------------------------------------------------------------------ the cache


def cache_path() -> Path:
    """The cache file: ``$JAXSOCIAL_CACHE/autotune.json``, or ``autotune.json`` beside the default compilation
    cache directory (``${XDG_CACHE_HOME:-~/.cache}/jaxsocial``)."""
    if directory := os.environ.get("JAXSOCIAL_CACHE"):
        return Path(directory).expanduser() / "autotune.json"
    return user_cache.ROOT / "autotune.json"


def _read_cache(path: Path) -> dict[str, dict]:
    """The cache's entries; {} if there is no file; {} and a warning if it is unreadable."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return {}
    except OSError as err:
        warnings.warn(f"autotune cache {path} cannot be read ({err}); measuring again", stacklevel=3)
        return {}
    try:
        data = json.loads(text)
        if not isinstance(data, dict) or not isinstance(data.get("entries"), dict):
            raise ValueError("not an object with an 'entries' object")
        if data.get("version") != CACHE_VERSION:
            raise ValueError(f"version {data.get('version')!r}, not {CACHE_VERSION}")
    except ValueError as err:  # (json.JSONDecodeError is a ValueError)
        warnings.warn(
            f"autotune cache {path} is unusable ({err}); measuring again and rewriting it", stacklevel=3
        )
        return {}
    return data["entries"]


def _write_cache(path: Path, entries: dict[str, dict]) -> None:
    """Writes `entries` merged into the file's current ones (another process may have added some), atomically
    (a temporary file renamed over it); a warning if that fails."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # (reported once, by the read before measuring)
            merged = _read_cache(path) | entries
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(
            json.dumps({"version": CACHE_VERSION, "entries": merged}, indent=1, sort_keys=True) + "\n"
        )
        os.replace(tmp, path)
    except OSError as err:
        warnings.warn(
            f"autotune cache {path} cannot be written ({err}); the choices are not kept", stacklevel=3
        )


# ------------------------------------------------------------------------------------------ resolving


@dataclasses.dataclass(frozen=True)
class LayerChoice:
    """One "auto" layer: its choice `impl`; `alone`, the fastest implementation timed alone (`choose`), and
    `times_s`, the best seconds of its forward + backward per candidate (`measure`)."""

    layer: str
    impl: str
    alone: str
    times_s: dict[str, float]


@dataclasses.dataclass(frozen=True)
class Tuning:
    """`tune`'s result: the "auto" layers' `choices`, the whole gradient steps timed to confirm them
    (`step_s`: per-layer `conv_impl` -> best seconds; {} when every layer kept its default alone), whether it
    all came from the cache (`cached`), and its cache `key`."""

    choices: dict[str, LayerChoice]
    step_s: dict[str, float]
    cached: bool
    key: str

    @property
    def impls(self) -> dict[str, str]:
        return {layer: choice.impl for layer, choice in self.choices.items()}


def _network_key(net_cfg: NetworkConfig, frames: int, machine: str) -> str:
    """The cache key of a network's choices: `machine`, dtype, frames, the architecture and `conv_impl`."""
    fields = {
        k: v for k, v in dataclasses.asdict(net_cfg).items() if k not in ("frame_batch", "dtype", "conv_impl")
    }
    arch = ",".join(f"{k}={v}" for k, v in sorted(fields.items())).replace(" ", "")
    return f"{machine}|{net_cfg.dtype}|network {arch} frames {frames} conv_impl {net_cfg.conv_impl}"


def _cached_times(entry, candidates: tuple[str, ...]) -> dict[str, float] | None:
    """A layer entry's timings of `candidates`, or None if it lacks one or is malformed."""
    try:
        times = {c: float(entry["times_s"][c]) for c in candidates}
    except (KeyError, TypeError, ValueError):
        return None
    return times if all(t > 0 for t in times.values()) else None


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def _cached_tuning(
    entry, key: str, specs: dict[str, LayerSpec], auto: list[str], dtype: str, path: Path
) -> Tuning | None:
    """`tune`'s result from the network's cache `entry` (under `key`), for its `auto` layers in `dtype`; None
    if there is none, or (with a warning) if it is unusable."""
    if entry is None:
        return None
    try:
        layers, impls = entry["layers"], parse_conv_impl(entry["conv_impl"])
        choices = {
            layer: LayerChoice(layer, impls[layer], layers[layer]["alone"], dict(layers[layer]["times_s"]))
            for layer in auto
        }
        if all(c.impl in specs[c.layer].candidates(dtype) for c in choices.values()):
            return Tuning(choices, dict(entry.get("step_s", {})), True, key)
        raise ValueError("an implementation that is not a candidate")
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        warnings.warn(f"autotune cache {path}: entry {key!r} unusable ({err}); measuring again", stacklevel=3)
    return None


def _layer_times(
    spec: LayerSpec, dtype: str, machine: str, entries: dict[str, dict], path: Path, reps: int
) -> tuple[dict[str, float], dict[str, dict]]:
    """A layer's timings per candidate in `dtype` on `machine`: the cache `entries`' for its key, else (with
    a warning if that entry is unusable) measured (`measure`); and the new cache entry ({} if none)."""
    layer_key = spec.key(dtype, machine)
    candidates = spec.candidates(dtype)
    entry = entries.get(layer_key)
    if (cached_times := _cached_times(entry, candidates)) is not None:
        return cached_times, {}
    if entry is not None:
        warnings.warn(f"autotune cache {path}: entry {layer_key!r} unusable; measuring again", stacklevel=3)
    times = measure(spec, candidates, dtype, reps)
    return times, {layer_key: {"times_s": times, "measured": _now()}}


def _confirm(
    net_cfg: NetworkConfig, auto: list[str], alone: dict[str, str], frames: int, reps: int
) -> tuple[dict[str, str], dict[str, float]]:
    """Every layer's implementation after confirming the `auto` layers' choices `alone` in the gradient step
    of `frames` frames (`tune`), and the steps timed (per-layer `conv_impl` -> best seconds)."""
    impls = net_cfg.impls | dict.fromkeys(auto, CONV_IMPLS[0])
    step_s: dict[str, float] = {}
    for layer in auto:
        if alone[layer] == CONV_IMPLS[0]:
            continue
        current = dataclasses.replace(net_cfg, conv_impl=format_conv_impl(impls))
        trial = dataclasses.replace(net_cfg, conv_impl=format_conv_impl(impls | {layer: alone[layer]}))
        before, after = measure_step((current, trial), frames, reps)
        step_s |= {current.conv_impl: before, trial.conv_impl: after}
        kept = after < STEP_PREFER * before
        log.info(
            "autotune %s=%s in the gradient step: %.2f ms against %.2f ms: %s", layer, alone[layer],
            after * 1e3, before * 1e3, "kept" if kept else "not kept",
        )  # fmt: skip
        if kept:
            impls[layer] = alone[layer]
    return impls, step_s


def tune(net_cfg: NetworkConfig, batch: int, *, path: str | Path | None = None, reps: int = REPS) -> Tuning:
    """The choice of every layer of `net_cfg` whose `conv_impl` entry is "auto", in `net_cfg`'s dtype
    (resolved with `auto_dtype` if "auto"), for calls of `batch` frames (`layer_specs`).

    From the cache file `path` (default `cache_path()`) where it holds this network's key; else each layer's
    fastest implementation alone (`measure`, or the cache's entry for the layer's key; `choose`), confirmed in
    the whole gradient step (`measure_step`): starting from every "auto" layer at "matmul" (the first of
    `conv.IMPLS`), the layers whose choice alone differs are switched one at a time, in network order, each
    kept only if the step then takes less than `STEP_PREFER` times as long. Everything measured is added to
    the file.
    """
    net_cfg = dataclasses.replace(net_cfg, dtype=auto_dtype()) if net_cfg.dtype == AUTO else net_cfg
    specs = layer_specs(net_cfg, batch)
    auto = [layer for layer, impl in net_cfg.layer_impls.items() if impl == AUTO]
    frames = min(batch, net_cfg.frame_batch)
    machine = machine_id()
    key = _network_key(net_cfg, frames, machine)
    if not auto:
        return Tuning({}, {}, True, key)
    path = Path(path) if path is not None else cache_path()
    entries = _read_cache(path)
    if (tuning := _cached_tuning(entries.get(key), key, specs, auto, net_cfg.dtype, path)) is not None:
        return tuning
    print(
        f"autotune: measuring the {len(auto)} 'auto' layers on this machine ({net_cfg.dtype}, {frames} "
        f"frames), once: the choice is cached in {path}",
        file=sys.stderr,
        flush=True,
    )
    alone, times, new = {}, {}, {}
    for layer in auto:
        times[layer], measured = _layer_times(specs[layer], net_cfg.dtype, machine, entries, path, reps)
        new |= measured
        candidates = specs[layer].candidates(net_cfg.dtype)
        alone[layer] = choose(times[layer], candidates)
        log.info(
            "autotune %s (%s, %d frames): %s alone (%s)", layer, net_cfg.dtype, frames, alone[layer],
            ", ".join(f"{c} {times[layer][c] * 1e3:.2f} ms" for c in candidates),
        )  # fmt: skip
    impls, step_s = _confirm(net_cfg, auto, alone, frames, reps)
    choices = {layer: LayerChoice(layer, impls[layer], alone[layer], times[layer]) for layer in auto}
    new[key] = {
        "conv_impl": format_conv_impl({layer: impls[layer] for layer in auto}),
        "layers": {layer: {"alone": alone[layer], "times_s": times[layer]} for layer in auto},
        "step_s": step_s,
        "measured": _now(),
    }
    _write_cache(path, new)
    return Tuning(choices, step_s, False, key)


def resolve(
    net_cfg: NetworkConfig, batch: int, *, path: str | Path | None = None, reps: int = REPS
) -> NetworkConfig:
    """`net_cfg` with every "auto" replaced by this machine's choice: `dtype` first (`auto_dtype`), then each
    "auto" conv layer's implementation (`tune`: cached, else measured in the resolved dtype). The result names
    every layer's implementation ("conv1=matmul,conv2=xla,...") when some layer was "auto"; `net_cfg` itself
    when nothing is "auto".

    `batch`: frames per call of the network in the step that matters for speed, the gradient step (PPO: a
    minibatch, ``minibatch_segments * segment_length`` samples); the layers are measured at
    ``min(batch, net_cfg.frame_batch)`` frames, the frame batch the conv layers run on. `path`: the cache file
    (default `cache_path()`).
    """
    if not net_cfg.unresolved:
        return net_cfg
    if net_cfg.dtype == AUTO:
        net_cfg = dataclasses.replace(net_cfg, dtype=auto_dtype())
    tuning = tune(net_cfg, batch, path=path, reps=reps)
    if not tuning.choices:
        return net_cfg
    impls = net_cfg.impls | tuning.impls
    return dataclasses.replace(
        net_cfg, conv_impl=format_conv_impl({layer: impls[layer] for layer in net_cfg.conv_layers})
    )
