"""Training runs as processes of their own, each pinned to one CPU core with a single-threaded XLA, as many at
a time as cores are given: on 2 cores, two such processes train 1.6x the env-steps/s of one process on both
(docs/performance.md, "The science recipe"). The sweep runs its seeds this way, and `experiments run
--cores` a recipe's seeds: the local launcher (`Cores`), which `experiments run` takes in place of the Slurm
one (`slurm.Slurm`, whose jobs start their process through `run_processes`); both are a `Launcher`.

Each run directory gets `RUN_FILE` (`jaxsocial.run.provenance`): what the runner knows of its process
(command, commit and whether the package's files were that commit's, with the diff beside it where not, cores,
the cores it could see, CPU, start, end, exit status), written once the process has made the directory (end
and status null until it ends) and again when it ends; the training process itself writes none
(`provenance.PARENT_WRITES`). A run resumed by a later process, maybe on another machine, keeps the earlier
processes' entries under `earlier`, a killed one's with a null end. Records take it as the run's provenance
(`records.pack`); its log goes beside the run directory (`<run_dir>.log`).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Protocol

from jaxsocial.experiments.analyse import records
from jaxsocial.experiments.plan import xla_flags
from jaxsocial.run import checkout, compile_cache, jsonio, provenance, rundir, runlock

SINGLE_CORE_XLA_FLAGS = "--xla_cpu_multi_thread_eigen=false"
"""What each pinned process adds to the caller's $XLA_FLAGS (`process_xla_flags`). Until 2026-11-27 it ended
in a stray `intra_op_parallelism_threads=1`, which is no XLA flag: XLA ignored it and every flag after it (the
tests' optimisation level, the settings of benchmarks/reproducibility.py); the numbers it trained are the same
bit for bit without it (measured on an Intel Xeon family 6 model 167)."""
CROSS_CPU_XLA_FLAGS = "--xla_cpu_enable_platform_dependent_math=false"
"""XLA's CPU numerics without its "platform dependent math", whose approximate reciprocal square root (in
the orthogonal initialiser) AMD and Intel CPUs round differently. Pre-registered designs since 2026-11-28
train with it (`TrainingDesign.xla_flags`), at no speed cost. It does not make every CPU kind agree: after the
single-core flags, the committed operation fingerprints show `CROSS_CPU_KINDS` agreeing and no other kind
measured under it agreeing with them (an AVX2 kind differs in Eigen's transposed products and the orthogonal
initialiser); `cpu_kinds` reads the files, `verify` predicts from them (docs/reproducibility.md, "Does the
training re-run?")."""
CROSS_CPU_KINDS = ("AMD EPYC (family 26, model 2)", "Intel(R) Xeon(R) Processor (family 6, model 167)")
"""The CPU kinds (`cpuinfo.model`) whose committed operation fingerprints all agree under
`SINGLE_CORE_XLA_FLAGS` then `CROSS_CPU_XLA_FLAGS`: every fingerprint, the laptop recipe's state after one
iteration included (measured in processes whose cores were not recorded). A test derives the agreement
from the files and fails where this says more or less than they show."""
POLL_SECONDS = 2.0


@dataclasses.dataclass(frozen=True)
class Job:
    """One process: `argv` after the interpreter (e.g. ['-m', 'jaxsocial.train', ...]), writing `run_dir`."""

    label: str
    argv: tuple[str, ...]
    run_dir: Path
    afresh: bool = False
    """Whether it starts its run anew (a training job of a run not begun when planned: no --resume)."""

    @property
    def log(self) -> Path:
        return self.run_dir.with_suffix(".log")


def train_command(flags: list[str]) -> tuple[str, ...]:
    """The argv of `python -m jaxsocial.train FLAGS` after the interpreter, with the persistent compilation
    cache (`compile_cache.default_dir()`) unless FLAGS name one: the seeds of a condition are one program, so
    every process after the first loads it (benchmarks/compile_time.py measures what that saves)."""
    cache = [] if "--compile-cache" in flags else ["--compile-cache", str(compile_cache.default_dir())]
    return ("-m", "jaxsocial.train", *flags, *cache)


def training_job(label: str, flags: list[str], run_dir: Path, begun: bool) -> Job:
    """The job that trains the run `run_dir`: its `train_command`, with `--resume` where it has `begun`
    (`rundirs.PARTIAL`: it goes on from its latest checkpoint)."""
    return Job(label, train_command([*flags, *(["--resume"] if begun else [])]), run_dir, afresh=not begun)


def pin(cores: list[int] | None) -> list[str]:
    """The argv prefix that starts a process on `cores` only (`taskset -c`, Linux's util-linux; [] where there
    is none, or no `cores`: the process then sees the caller's)."""
    return ["taskset", "-c", ",".join(map(str, cores))] if cores and shutil.which("taskset") else []


def cores_seen(cores: list[int] | None) -> int | None:
    """How many cores a process started after `pin(cores)` sees (None: not known here)."""
    if cores and pin(cores):
        return len(cores)
    return len(provenance.visible_cores() or []) or None


def process_xla_flags(extra: str = "") -> str:
    """$XLA_FLAGS of a pinned process: the caller's, then `SINGLE_CORE_XLA_FLAGS`, then `extra` (e.g. a
    design's). ValueError if a word of them is not a `--flag` (`xla_flags.normalised`)."""
    return xla_flags.normalised(
        f"{os.environ.get('XLA_FLAGS', '')} {SINGLE_CORE_XLA_FLAGS} {extra}", "$XLA_FLAGS"
    )


def positive_int(text: str) -> int:
    """`text` as an int of at least 1 (argparse's type for --max-runs; its error otherwise)."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def first_runs(jobs: list[Job], max_runs: int | None) -> list[Job]:
    """The first `max_runs` of `jobs` (all of them if None), saying so when some are left for later: a
    sitting starts only the runs that can end within it."""
    if max_runs is None or max_runs >= len(jobs):
        return jobs
    print(f"starting {max_runs} of {len(jobs)} pending runs (--max-runs); the rest wait for a later call")
    return jobs[:max_runs]


class Launcher(Protocol):
    """What starts a design's jobs (each one seed's `train_command`, or a few vmapped): `Cores` here, or
    `slurm.Slurm` on a cluster. `slurm.chosen` picks one from the command line; its callers (`runner`,
    `branch_runs`) only hand it their jobs."""

    def slots(self, runs: int) -> int:
        """How many of `runs` jobs train at once (what a cost estimate divides by)."""
        ...

    def show(self, jobs: list[Job], extra_xla_flags: str) -> None:
        """`--dry-run`: print what starting `jobs` would do beyond the commands its caller prints."""
        ...

    def run(self, jobs: list[Job], extra_xla_flags: str) -> list[int | None]:
        """Start `jobs` with the single-core flags then `extra_xla_flags` (`process_xla_flags`), each writing
        its `RUN_FILE`; their exit codes in the order of `jobs` (None: not waited for)."""
        ...


@dataclasses.dataclass(frozen=True)
class Cores:
    """The local launcher: the jobs as processes on this machine, one a core of `cores` at a time (`run`)."""

    cores: tuple[int, ...]

    def slots(self, runs: int) -> int:
        return len(self.cores)

    def show(self, jobs: list[Job], extra_xla_flags: str) -> None:
        """Nothing: the commands its callers print are what it starts."""

    def run(self, jobs: list[Job], extra_xla_flags: str) -> list[int | None]:
        return list(run(jobs, list(self.cores), extra_xla_flags))


def run(jobs: list[Job], cores: list[int], extra_xla_flags: str = "") -> list[int | None]:
    """Run `jobs` in order, one process per core of `cores` at a time, each pinned to its core (`pin`) with a
    single-threaded XLA after the caller's $XLA_FLAGS and before `extra_xla_flags` (`process_xla_flags`);
    write `RUN_FILE`, with the cores the process could see and the package's files as they were when it
    started (`checkout.tree`), into each run directory the process created. Returns the exit codes, in the
    order of `jobs` (None: left to another process, `taken_by_another`)."""
    if not cores:
        raise ValueError("give at least one core")
    return run_processes(jobs, cores, process_xla_flags(extra_xla_flags))


def taken_by_another(job: Job) -> str | None:
    """Why `job` must not start now, or None: a live process trains its run directory (`runlock`), or one
    began it since it was planned (its config is there, and the job would start it afresh). Asked just
    before it starts, so that two runners on one design share its seeds (`rundirs.run_state`)."""
    if runlock.RunLock(job.run_dir).live_holder() is not None:
        return "training now in another process"
    if job.afresh and (job.run_dir / rundir.CONFIG_FILE).is_file():
        return "begun by another process since this run was planned"
    return None


def run_processes(jobs: list[Job], cores: list[int], process_flags: str) -> list[int | None]:
    """`run` with the processes' $XLA_FLAGS whole (`process_xla_flags`, worked out where the jobs were
    launched: a Slurm job runs its seed through this, `slurm.run_in_job`). A job `taken_by_another` when its
    turn comes is left to it (exit code None), and its log is not touched."""
    env = {**os.environ, "XLA_FLAGS": process_flags, provenance.PARENT_WRITES: "1"}
    pending, active, codes = list(enumerate(jobs)), {}, {}
    free = list(cores)
    while pending or active:
        while pending and free:
            i, job = pending.pop(0)
            taken = taken_by_another(job)
            if taken:
                print(f"{job.label}: {taken}, left to it", flush=True)
                codes[i] = None
                continue
            core, tree = free.pop(0), checkout.tree()
            job.log.parent.mkdir(parents=True, exist_ok=True)
            proc = subprocess.Popen(
                [*pin([core]), sys.executable, *job.argv],
                stdout=job.log.open("w"),
                stderr=subprocess.STDOUT,
                env=env,
            )
            active[i] = (proc, core, provenance.now(), tree, None, None)  # None: its RUN_FILE not written yet
            print(f"{job.label}: core {core}, log {job.log}", flush=True)
        time.sleep(POLL_SECONDS)
        for i, (proc, core, started, tree, earlier, seen) in list(active.items()):
            job = jobs[i]
            process = (job.run_dir, shlex.join(["python", *job.argv]), tree, 1, started)
            if earlier is None and (job.run_dir / rundir.CONFIG_FILE).is_file():
                # its directory is there: say so before it ends
                earlier = provenance.earlier_processes(job.run_dir)
                # python itself runs, pinned; `poll` has not reaped it
                seen = provenance.visible_cores(proc.pid)
                active[i] = (proc, core, started, tree, earlier, seen)
                if proc.poll() is None:
                    provenance.write_run_file(*process, None, process_flags, earlier, seen)
            rc = proc.poll()
            if rc is None:
                continue
            del active[i]
            free.append(core)
            codes[i] = rc
            if earlier is not None:  # it made its run directory
                provenance.write_run_file(*process, rc, process_flags, earlier, seen)
            print(f"{job.label}: exit {rc}", flush=True)
    return [codes[i] for i in range(len(jobs))]


class RunNotEnded(FileNotFoundError):
    """A run has no `RUN_FILE` of an ended process: trained before training wrote one (by other means than
    `run`, before 2026-12-03), or its process has not ended."""


def run_provenance(
    run_dir: Path, device: str | None = None, jax_version: str | None = None
) -> dict[str, Any]:
    """The `run` part of a record's provenance from a run's `RUN_FILE`, with the device and jax version it
    ran on (where None, what its process measured: `with_measured`), the cores it had and the processes
    before its last (`earlier`, if it was resumed). RunNotEnded if the run has none, or its process has not
    ended; ValueError if it failed (`records.ended_well`) or the file does not say what is not given."""
    path = Path(run_dir) / provenance.RUN_FILE
    if not path.is_file():
        raise RunNotEnded(
            f"{path} does not exist: the run was not trained by `pinned.run`, nor by a `train` that writes "
            "one (since 2026-12-03)"
        )
    info = jsonio.read_json(path)
    if info.get("ended") is None:
        raise RunNotEnded(f"{path}: its process (started {info.get('started')}) has not ended")
    records.ended_well(info, run_dir)
    later = (*provenance.MACHINE_FIELDS, *checkout.TREE_FIELDS)
    machine = {k: info[k] for k in later if k in info}  # runs written before these fields lack them
    run = (
        {k: info.get(k) for k in provenance.RUN_FIELDS}
        | machine
        | {"cores": info.get("cores")}
        | ({"earlier": info["earlier"]} if info.get("earlier") else {})
    )
    return with_measured(run, device, jax_version, run_dir)


def with_measured(run: dict, device: str | None, jax_version: str | None, seed_dir: Path) -> dict:
    """`run` (`run_provenance`'s fields) with `device` and `jax_version`, or where not given, what its process
    file measured (`machine`): the CPU (one core per seed where pinned) and the jax it had. ValueError
    naming the flags to give where the file lacks them (written before it held them)."""
    cpu, cores = run.get("cpu"), run.get("cores")
    pinned_to = "" if cores is None else ", one core per seed" if cores == 1 else f", {cores} cores"
    run = run | {
        "device": device or (cpu and cpu + pinned_to),
        "jax": jax_version or (run.get("versions") or {}).get("jax"),
    }
    unknown = [f"--{key}" for key in ("device", "jax") if not run[key]]
    if unknown:
        raise ValueError(f"{seed_dir}: its {provenance.RUN_FILE} does not say; give {' and '.join(unknown)}")
    return run
