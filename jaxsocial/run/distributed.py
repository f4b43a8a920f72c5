"""Devices and processes: the data-parallel mesh, multi-host start-up, and moving the training state between
the hosts' memory and the devices.

A run splits its environments over a 1-D mesh (axis `DATA`) of devices: every array of the training state with
an environment axis is sharded along it, everything else (learner params, optimiser states, keys) is
replicated. `jax.jit` with these shardings lets GSPMD partition the program: the rollout runs on each device's
share of the environments. Inside the PPO update `DataParallel` keeps the rollout and each minibatch split
(sharding constraints) and runs the network on each device's share (`jax.shard_map`; left to GSPMD, the
reshapes inside the network gathered the whole minibatch onto every device); the losses and each learner's
gradient are means over the global batch (XLA inserts the all-reduces), so D devices run the same algorithm as
one, up to floating-point summation order.

Several hosts: one process per host, started with the same command plus `initialize`'s arguments (or the
environment variables below); `jax.devices()` then lists every process's devices and the mesh spans them all.
Only process 0 writes logs, metrics and progress (`on_main`); every process takes part in checkpointing, which
gathers the state (`to_host`) and lets orbax write it from process 0. The run directory must be on a file
system that every process sees.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxsocial.agents.devices import ONE_DEVICE, Devices

__all__ = [
    "DATA",
    "ENV_COORDINATOR",
    "ENV_NUM_PROCESSES",
    "ENV_PROCESS_ID",
    "DataParallel",
    "ProcessZeroError",
    "batch_sharding",
    "check_batch",
    "data_mesh",
    "data_parallel",
    "describe",
    "initialize",
    "is_main",
    "on_main",
    "put",
    "replicated",
    "select_devices",
    "state_shardings",
    "to_host",
]

DATA = "data"
"""The mesh axis the environments are split over."""
ENV_COORDINATOR = "JAX_COORDINATOR_ADDRESS"
ENV_NUM_PROCESSES = "JAX_NUM_PROCESSES"
ENV_PROCESS_ID = "JAX_PROCESS_ID"

T = TypeVar("T")


class ProcessZeroError(ValueError):
    """Raised on the other processes when process 0 failed in `on_main` (its own error says why)."""


# ----------------------------------------------------------------------------------------------------------
# Processes
# ----------------------------------------------------------------------------------------------------------


def _env_int(name: str) -> int | None:
    text = os.environ.get(name, "").strip()
    if not text:
        return None
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"${name}={text!r} is not an integer") from None


def initialize(
    coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> bool:
    """Starts `jax.distributed` for a run over several processes (one per host); returns whether it is one.

    Values not given come from $JAX_COORDINATOR_ADDRESS, $JAX_NUM_PROCESSES and $JAX_PROCESS_ID. Nothing to do
    (False) without a coordinator and with at most one process. `coordinator` is HOST:PORT of process 0 (every
    process passes the same one), or 'auto' to let JAX detect the cluster (Slurm, Open MPI, TPU pods). On CPU
    the processes talk through gloo. Must run before anything else uses JAX (ValueError otherwise, as for
    missing or inconsistent values); calling it again once started is a no-op.
    """
    coordinator = coordinator or os.environ.get(ENV_COORDINATOR) or None
    num_processes = _env_int(ENV_NUM_PROCESSES) if num_processes is None else num_processes
    process_id = _env_int(ENV_PROCESS_ID) if process_id is None else process_id
    if coordinator is None:
        if num_processes not in (None, 1) or process_id not in (None, 0):
            raise ValueError(
                f"num_processes={num_processes}, process_id={process_id} need a coordinator: pass "
                f"--coordinator HOST:PORT (process 0's address) or set ${ENV_COORDINATOR}"
            )
        return False
    if jax.distributed.is_initialized():
        return True
    kwargs: dict[str, Any] = {}
    if coordinator != "auto":
        host, sep, port = coordinator.rpartition(":")
        if not sep or not host or not port.isdigit():
            raise ValueError(f"coordinator {coordinator!r} is not HOST:PORT (or 'auto')")
        if num_processes is None or process_id is None:
            raise ValueError(
                f"coordinator {coordinator!r} also needs --num-processes and --process-id "
                f"(or ${ENV_NUM_PROCESSES} and ${ENV_PROCESS_ID})"
            )
        kwargs["coordinator_address"] = coordinator
    if num_processes is not None:
        if num_processes < 1:
            raise ValueError(f"num_processes must be >= 1, got {num_processes}")
        kwargs["num_processes"] = num_processes
    if process_id is not None:
        if num_processes is not None and not 0 <= process_id < num_processes:
            raise ValueError(f"process_id must be in 0..{num_processes - 1}, got {process_id}")
        kwargs["process_id"] = process_id
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        jax.distributed.initialize(**kwargs)
    except RuntimeError as err:
        if "before" in str(err) or "already" in str(err):
            raise ValueError(
                f"cannot start the multi-process run: {err} (initialize before anything uses JAX)"
            ) from err
        raise
    return True


def is_main() -> bool:
    """Whether this is process 0, the one that writes logs, metrics and progress."""
    return jax.process_index() == 0


def on_main(fn: Callable[[], T]) -> T | None:
    """`fn()` on process 0 only; the other processes wait for it and get None.

    If `fn` raises, process 0 re-raises its error and the others raise ProcessZeroError, so every process
    stops (instead of waiting forever at the next collective).
    """
    if jax.process_count() == 1:
        return fn()
    result, error = None, None
    if is_main():
        try:
            result = fn()
        except Exception as err:  # re-raised below, after telling the other processes
            error = err
    ok = multihost_utils.broadcast_one_to_all(np.int32(error is None))
    if error is not None:
        raise error
    if not int(ok):
        raise ProcessZeroError("process 0 stopped with an error (see its output)")
    return result


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
