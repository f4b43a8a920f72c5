"""What a training process records of itself in its run directory: `RUN_FILE`, with its command, which code
(`checkout.Tree.fields`: the commit, whether the package's files were that commit's, and the name and sha256
of the diff written beside it where they were not), where (`machine`: the CPU, $XLA_FLAGS, the cores it could
see, instruction sets, caches and package versions), when (start, end) and its exit status.

One format, two writers: `experiments.launch.pinned.run` writes it for each process it starts (setting
`PARENT_WRITES` in their environment), and `jaxsocial.train.run` for a process nobody else records (a plain
`python -m jaxsocial.train`, or `experiments run` training in its own process), through `recorded`. A run
resumed by a later process keeps the earlier processes' entries under `earlier`, a killed one's with a null
end. Records take it as the run's provenance (`experiments.records`), and `verify` reads it from a run
directory that is no record.
"""

from __future__ import annotations

import contextlib
import datetime
import importlib.metadata
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from jaxsocial.run import checkout, cpuinfo, jsonio, rundir

RUN_FILE = rundir.RUN_FILE
PARENT_WRITES = "JAXSOCIAL_PARENT_WRITES_RUN_FILE"
"""Set to '1' in the environment of a process whose `RUN_FILE` the process that started it writes
(`pinned.run`): the training then writes none itself."""
RUN_FIELDS = ("command", "commit", "device", "jax", "started", "ended", "rc")
"""What a record's provenance says about the run that trained it (None where unknown)."""
ENVIRONMENT_FIELDS = ("cpu_features", "cache_sizes", "versions")
"""The fields of `environment`."""
MACHINE_FIELDS = ("cpu", "xla_flags", "visible_cores", *ENVIRONMENT_FIELDS)
"""What `RUN_FILE` says of where the run trained, beside `RUN_FIELDS`: the CPU (model, family and
model numbers, `cpuinfo.model`), the process's $XLA_FLAGS, the cores it could run on (`visible_cores`:
XLA's CPU bits depend on how many) and its `environment`; records carry them in provenance, and `verify`
compares them with the machine it re-trains on, and re-trains on as many cores."""
VERSIONED = ("jax", "jaxlib", "flax", "optax", "numpy")
"""The packages whose versions a run's floats depend on."""


def visible_cores(pid: int = 0) -> list[int] | None:
    """The CPU cores process `pid` (0: this one) may run on, sorted (`os.sched_getaffinity`; None where the OS
    has no such call)."""
    return sorted(os.sched_getaffinity(pid)) if hasattr(os, "sched_getaffinity") else None


def machine(xla_flags: str | None) -> dict[str, Any]:
    """Where a process with $XLA_FLAGS `xla_flags` trains (`MACHINE_FIELDS`): this CPU (`cpuinfo.model`),
    the flags, the cores this process sees (`visible_cores`: a process it starts sees the same unless pinned)
    and the `environment`. A GPU block logs it in its commands log (`records.read_commands_log`): its flags
    say whether `--xla_gpu_deterministic_ops` was on."""
    seen = visible_cores()
    return {"cpu": cpuinfo.model(), "xla_flags": xla_flags, "visible_cores": seen, **environment()}


def environment() -> dict[str, Any]:
    """What besides the program and its XLA flags decides the floats a CPU run computes: the instruction sets
    present (`cpuinfo.NUMERICS_FLAGS`; XLA's code and YNNPACK's kernels follow them), the cache sizes (Eigen
    sizes its blocks from them) and the versions of the `VERSIONED` packages (None: not installed)."""
    return {
        "cpu_features": sorted(cpuinfo.NUMERICS_FLAGS & cpuinfo.flags()),
        "cache_sizes": cpuinfo.cache_sizes(),
        "versions": {package: package_version(package) for package in VERSIONED},
    }


def package_version(package: str) -> str | None:
    """An installed package's version (None: not installed)."""
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def now() -> str:
    """The current UTC time, ISO 8601 to the second (what `RUN_FILE` records)."""
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def earlier_processes(run_dir: Path) -> list[dict[str, Any]]:
    """The processes that trained `run_dir` before (its `RUN_FILE`'s entries, oldest first; [] if none)."""
    path = Path(run_dir) / RUN_FILE
    if not path.is_file():
        return []
    last = jsonio.read_json(path)
    return [*last.pop("earlier", []), last]


def write_run_file(
    run_dir: Path,
    command: str,
    tree: checkout.Tree,
    cores: int | None,
    started: str,
    rc: int | None,
    xla_flags: str | None = None,
    earlier: list[dict[str, Any]] | None = None,
    seen: list[int] | None = None,
) -> None:
    """Write `RUN_FILE` into `run_dir`: what made it (command, the code: `tree`'s fields, cores given), where
    (this machine's CPU, the process's $XLA_FLAGS, the cores it could see (`seen`, None: not measured), the
    `environment`: `MACHINE_FIELDS`), when (start, and now as its end unless `rc` is None: still running) and
    its exit status, with the `earlier` processes of a resumed run; and the tree's diff beside it if dirty."""
    info = {
        "command": command,
        **tree.fields(),
        "cores": cores,
        **machine(xla_flags),
        "visible_cores": seen,
        "started": started,
        "ended": None if rc is None else now(),
        "rc": rc,
    }
    tree.write_diff(run_dir)
    jsonio.write_json(Path(run_dir) / RUN_FILE, info | ({"earlier": earlier} if earlier else {}))


@contextlib.contextmanager
def recorded(run_dir: Path, command: str, resume: bool, writes: bool = True) -> Iterator[None]:
    """Around a training process's work in `run_dir`: its `RUN_FILE` written before (no end) and after, with
    exit status 0, or 1 (130 for an interrupt) if the work raised; the earlier processes kept if it `resume`s.
    Nothing where it `writes` not (another process of a multi-process run) or a parent records this process
    (`PARENT_WRITES`)."""
    if not writes or os.environ.get(PARENT_WRITES) == "1":
        yield
        return
    earlier = earlier_processes(run_dir) if resume else []
    process = (run_dir, command, checkout.tree(), None, now())
    flags, seen = os.environ.get("XLA_FLAGS", ""), visible_cores()
    write_run_file(*process, None, flags, earlier, seen)
    rc = 1
    try:
        yield
        rc = 0
    except KeyboardInterrupt:
        rc = 130
        raise
    finally:
        write_run_file(*process, rc, flags, earlier, seen)
