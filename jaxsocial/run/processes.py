"""The processes of a run: multi-host start-up (`initialize`), which process is process 0 (`is_main`) and
what only it does (`on_main`).

Several hosts: one process per host, started with the same command plus `initialize`'s arguments (or the
environment variables below); `jaxsocial.run.distributed` spreads the run over their devices. Only process 0
writes logs, metrics and progress. JAX is imported only where the run has several processes: a
single-process run checks its command and its run directory before JAX is imported.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from types import ModuleType
from typing import Any, TypeVar

__all__ = [
    "ENV_COORDINATOR",
    "ENV_NUM_PROCESSES",
    "ENV_PROCESS_ID",
    "ProcessZeroError",
    "initialize",
    "is_main",
    "on_main",
]

ENV_COORDINATOR = "JAX_COORDINATOR_ADDRESS"
ENV_NUM_PROCESSES = "JAX_NUM_PROCESSES"
ENV_PROCESS_ID = "JAX_PROCESS_ID"

T = TypeVar("T")


class ProcessZeroError(ValueError):
    """Raised on the other processes when process 0 failed in `on_main` (its own error says why)."""


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
    import jax

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


def _jax() -> ModuleType | None:
    """JAX where something has imported it, else None: then this process is the only one (a run over several
    processes imports JAX to start, `initialize`)."""
    return sys.modules.get("jax")


def is_main() -> bool:
    """Whether this is process 0, the one that writes logs, metrics and progress."""
    jax = _jax()
    return jax is None or jax.process_index() == 0


def on_main(fn: Callable[[], T]) -> T | None:
    """`fn()` on process 0 only; the other processes wait for it and get None.

    If `fn` raises, process 0 re-raises its error and the others raise ProcessZeroError, so every process
    stops (instead of waiting forever at the next collective).
    """
    jax = _jax()
    if jax is None or jax.process_count() == 1:
        return fn()
    import numpy as np
    from jax.experimental import multihost_utils

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
