"""Devices: the data-parallel mesh, and moving the training state between the hosts' memory and the devices.

A run splits its environments over a 1-D mesh (axis `DATA`) of devices: every array of the training state with
an environment axis is sharded along it, everything else (learner params, optimiser states, keys) is
replicated. `jax.jit` with these shardings lets GSPMD partition the program: the rollout runs on each device's
share of the environments. Inside the PPO update `DataParallel` keeps the rollout and each minibatch split
(sharding constraints) and runs the network on each device's share (`jax.shard_map`; left to GSPMD, the
reshapes inside the network gathered the whole minibatch onto every device); the losses and each learner's
gradient are means over the global batch (XLA inserts the all-reduces), so D devices run the same algorithm as
one, up to floating-point summation order.

Several hosts: one process per host, started as `jaxsocial.run.processes.initialize` says; `jax.devices()`
then lists every process's devices and the mesh spans them all. Only process 0 writes logs, metrics and
progress (`processes.on_main`); every process takes part in checkpointing, which gathers the state
(`to_host`) and lets orbax write it from process 0. The run directory must be on a file system that every
process sees.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxsocial.agents.devices import ONE_DEVICE, Devices

__all__ = [
    "DATA",
    "DataParallel",
    "batch_sharding",
    "check_batch",
    "data_mesh",
    "data_parallel",
    "describe",
    "put",
    "replicated",
    "select_devices",
    "state_shardings",
    "to_host",
]

DATA = "data"
"""The mesh axis the environments are split over."""


# ----------------------------------------------------------------------------------------------------------
# Devices and shardings
# ----------------------------------------------------------------------------------------------------------


def select_devices(requested: int = 0) -> list[jax.Device]:
    """The first `requested` devices (0: all of them, of every process). ValueError if there are fewer."""
    devices = jax.devices()
    if requested < 0:
        raise ValueError(f"devices must be >= 0 (0: all), got {requested}")
    if requested > len(devices):
        hint = ""
        if devices[0].platform == "cpu":
            hint = (
                "; on CPU, XLA_FLAGS=--xla_force_host_platform_device_count=N (set before JAX starts) "
                "splits the host into N devices"
            )
        platform = devices[0].platform
        raise ValueError(
            f"{requested} devices requested but only {len(devices)} {platform} device(s) exist{hint}"
        )
    n = requested or len(devices)
    if jax.process_count() > 1 and n != len(devices):
        raise ValueError(
            f"a run over {jax.process_count()} processes uses all {len(devices)} devices; got devices={n}"
        )
    return devices[:n]


def check_batch(n_devices: int, **sizes: int) -> None:
    """ValueError unless every batch size (e.g. num_envs=32) splits evenly over the devices."""
    for name, size in sizes.items():
        if size % n_devices:
            raise ValueError(
                f"{name}={size} does not split evenly over {n_devices} devices: choose a multiple of "
                f"{n_devices} (or another number of devices with --devices)"
            )


def data_mesh(requested: int, **sizes: int) -> Mesh:
    """The 1-D mesh (axis `DATA`) of `select_devices(requested)`, checked against the batch `sizes`."""
    devices = select_devices(requested)
    check_batch(len(devices), **sizes)
    return Mesh(np.asarray(devices), (DATA,))


def _spec(axis: int | None) -> PartitionSpec:
    """Split along `axis` over the `DATA` mesh axis (the other axes replicated); None: replicated."""
    return PartitionSpec() if axis is None else PartitionSpec(*([None] * axis), DATA)


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, _spec(None))


def batch_sharding(mesh: Mesh, axis: int) -> NamedSharding:
    """Arrays split along `axis` over the mesh (the other axes replicated)."""
    return NamedSharding(mesh, _spec(axis))


def state_shardings(state: Any, mesh: Mesh, env_axes: Any, offset: int = 0) -> Any:
    """Shardings for `state` (arrays or ShapeDtypeStructs): `env_axes` is a pytree prefix of `state` whose
    ints give the environment axis of the leaves below them (split along axis + `offset`, e.g. behind a
    seed axis) and whose Nones mark replicated leaves."""

    def one(axis: int | None, subtree: Any) -> Any:
        sharding = replicated(mesh) if axis is None else batch_sharding(mesh, axis + offset)
        return jax.tree.map(lambda _: sharding, subtree)

    return jax.tree.map(one, env_axes, state, is_leaf=lambda x: x is None)


class DataParallel:
    """Inside a jitted program: how batch axes are split over the devices of `mesh` (a `devices.Devices`).

    Axes are given as pytree prefixes of ints (the batch axis of those leaves) or None (replicated).
    """

    axis_name = DATA  # inside `per_device` functions: the mesh axis their batch share is split over

    def __init__(self, mesh: Mesh):
        self.mesh = mesh

    def shard(self, tree: Any, axes: Any) -> Any:
        """`tree` with the leaves under each int of `axes` split along that axis (a sharding constraint)."""
        shardings = state_shardings(tree, self.mesh, axes)
        return jax.tree.map(jax.lax.with_sharding_constraint, tree, shardings)

    def per_device(self, fn: Callable, in_axes: Any, out_axes: Any) -> Callable:
        """`fn` run by every device on its share of the batch (`jax.shard_map`): for functions that treat
        every batch element on its own, like the network over a batch of sequences. Its parameters with axis
        None are replicated (their gradient is summed over the devices)."""
        to_spec = functools.partial(jax.tree.map, _spec, is_leaf=lambda x: x is None)
        return jax.shard_map(fn, mesh=self.mesh, in_specs=to_spec(in_axes), out_specs=to_spec(out_axes))


def data_parallel(mesh: Mesh | None) -> Devices:
    """How the batch is split over `mesh`'s devices: its DataParallel, or `ONE_DEVICE` when there is
    nothing to split over (no mesh, one device)."""
    if mesh is None or mesh.size == 1:
        return ONE_DEVICE
    return DataParallel(mesh)


# ----------------------------------------------------------------------------------------------------------
# Host <-> devices
# ----------------------------------------------------------------------------------------------------------


def _is_key(x: Any) -> bool:
    dtype = getattr(x, "dtype", None)
    return dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)


def to_host(tree: Any) -> Any:
    """The whole of every array of `tree` in this process's memory: numpy arrays (typed PRNG keys stay key
    arrays, on this process's first device). In a multi-process run every process must call it (it gathers
    the other processes' shards) and every process gets the full values."""

    def one(x: Any) -> Any:
        if not isinstance(x, jax.Array):
            return x
        if _is_key(x):
            data = one(jax.random.key_data(x))
            return jax.random.wrap_key_data(data, impl=jax.random.key_impl(x))
        if x.is_fully_addressable or x.is_fully_replicated:
            return np.asarray(x)
        return np.asarray(multihost_utils.process_allgather(x, tiled=True))

    return jax.tree.map(one, tree)


def put(tree: Any, shardings: Any) -> Any:
    """Places host values (numpy or single-device arrays, the same on every process) on `shardings` (a tree
    of NamedShardings like `tree`): each process fills in its own devices' shards."""

    def one(x: Any, sharding: NamedSharding) -> jax.Array:
        if _is_key(x):
            impl = jax.random.key_impl(x)
            return jax.random.wrap_key_data(one(jax.random.key_data(x), sharding), impl=impl)
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])

    return jax.tree.map(one, tree, shardings)


def describe(devices: Sequence[jax.Device]) -> str:
    """'2 cpu devices over 2 processes' and the like, for progress lines."""
    processes = len({d.process_index for d in devices})
    text = f"{len(devices)} {devices[0].platform} device{'s' if len(devices) > 1 else ''}"
    return text + (f" over {processes} processes" if processes > 1 else "")
