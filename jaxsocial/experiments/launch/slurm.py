"""A design's seeds as jobs on a Slurm cluster through submitit (an optional extra: `pip install
jaxsocial[slurm]`), and the one place a command picks its launcher (`chosen`): `pinned.Cores` on this
machine, or `Slurm`.

Each job is what the local launcher starts for a seed: the same command line (`pinned.Job`), on one CPU
(`cpus_per_task=1`), with the single-core XLA flags and then the design's (`pinned.process_xla_flags`,
worked out where the jobs are submitted). Inside the job `run_in_job` starts that process through
`pinned.run_processes`, pinned to the job's CPU, so its run directory gets the process file a local run gets
(`RUN_FILE`, written by the job, since no parent can watch it from the submitting machine) and
`experiments record` packs it the same way. The Slurm options come from a file (`--slurm-config`, JSON or
TOML) and from flags, which override it, and are all checked before anything is submitted (`options`). The
launcher waits for the jobs unless told not to (`--no-wait`); beside each run directory, `<run>.slurm.json`
names the job that trains it, and a later call submits nothing for a run whose job is still queued or running
(`squeue`), so re-running the same command submits only the seeds that are missing or partial.
"""

from __future__ import annotations

import argparse
import dataclasses
import getpass
import json
import math
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import paths
from jaxsocial.run import jsonio, provenance

INSTALL = "pip install 'jaxsocial[slurm]'"
"""What installs submitit (the optional extra `slurm`)."""
DEFAULT_FOLDER = paths.RUNS / "slurm"
"""Where submitit keeps each job's pickled call, result and Slurm log (`--slurm-folder`)."""
CLUSTERS = ("slurm", "local")
"""`cluster`: Slurm, or submitit's local executor (each job a process on this machine: the tests, a trial)."""
FLAGS = {
    "partition": "--slurm-partition",
    "time": "--slurm-time",
    "account": "--slurm-account",
    "folder": "--slurm-folder",
    "additional_parameters": "--slurm-param",
}
"""The options with a flag of their own; `setup` and `cluster` are the config file's only."""
OPTIONS = (*FLAGS, "setup", "cluster")
"""Every key a `--slurm-config` file may hold."""
LAUNCHERS_OWN = {
    **{key: f"the launcher asks for one CPU, one task on one node ({key})" for key in (
        "cpus_per_task", "ntasks", "ntasks_per_node", "nodes", "array")},
    **{key: f"the launcher names the job and its logs ({key}; --slurm-folder)" for key in (
        "job_name", "output", "error", "open_mode", "signal")},
    "time": "give --slurm-time", "partition": "give --slurm-partition", "account": "give --slurm-account",
}  # fmt: skip
"""The sbatch options `additional_parameters` may not set, and why."""
TIME_FORMATS = (
    r"(?P<m>\d+)",
    r"(?P<m>\d+):(?P<s>\d+)",
    r"(?P<h>\d+):(?P<m>\d+):(?P<s>\d+)",
    r"(?P<d>\d+)-(?P<h>\d+)",
    r"(?P<d>\d+)-(?P<h>\d+):(?P<m>\d+)",
    r"(?P<d>\d+)-(?P<h>\d+):(?P<m>\d+):(?P<s>\d+)",
)
"""Slurm's time limits: minutes, MM:SS, HH:MM:SS, D-HH, D-HH:MM, D-HH:MM:SS."""
POLL_SECONDS = 10.0
"""How often waiting asks whether a job has ended."""


def submitit_module():
    """The submitit module; ValueError saying how to install it where it is not."""
    try:
        import submitit
    except ImportError as err:
        raise ValueError(
            f"--launcher slurm submits through submitit, which is not installed: {INSTALL} "
            '(docs/scale-out.md, "A design\'s seeds on a Slurm cluster")'
        ) from err
    return submitit


@dataclasses.dataclass(frozen=True)
class Slurm:
    """The Slurm launcher: one job a `pinned.Job`, one CPU each, for at most `time_min` minutes, on
    `partition` with `account` and the other sbatch options `additional_parameters` (`setup`: shell lines the
    job runs first, e.g. activating the environment); submitit's files under `folder`. `wait`: wait for the
    jobs to end (their exit codes), else return once they are submitted."""

    time_min: int
    partition: str | None = None
    account: str | None = None
    additional_parameters: dict[str, Any] = dataclasses.field(default_factory=dict)
    setup: tuple[str, ...] = ()
    folder: Path = DEFAULT_FOLDER
    cluster: str = "slurm"
    wait: bool = True

    def slots(self, runs: int) -> int:
        """All of them: the cluster schedules each job on a CPU of its own."""
        return max(runs, 1)

    def parameters(self) -> dict[str, Any]:
        """submitit's `AutoExecutor.update_parameters` for these jobs."""
        slurm = {
            "slurm_partition": self.partition,
            "slurm_account": self.account,
            "slurm_additional_parameters": dict(self.additional_parameters) or None,
            "slurm_setup": list(self.setup) or None,
        }
        own = {"name": "jaxsocial", "timeout_min": self.time_min, "cpus_per_task": 1}
        return own | {"nodes": 1, "tasks_per_node": 1} | {k: v for k, v in slurm.items() if v is not None}

    def show(self, jobs: list[pinned.Job], extra_xla_flags: str) -> None:
        """`--dry-run`: the jobs that would be submitted, each job's resources and Slurm options."""
        where = "submitit's local executor" if self.cluster == "local" else "Slurm"
        print(f"would submit {len(jobs)} job(s) to {where} (nothing submitted: --dry-run), each with")
        print(f"  {', '.join(f'{k}={v!r}' for k, v in self.parameters().items())}")
        print(f"  XLA_FLAGS={pinned.process_xla_flags(extra_xla_flags)!r}; submitit's files in {self.folder}")
        for job in jobs:
            print(f"  {job.label}: {shlex.join(['python', *job.argv])}\n    log {job.log}")

    def run(self, jobs: list[pinned.Job], extra_xla_flags: str) -> list[int | None]:
        """Submit a job for each of `jobs` not queued or running already (`queued`), as one job array, then
        wait for them (`wait`) unless not `wait`. Their exit codes in the order of `jobs`; None for one not
        waited for."""
        process_flags = pinned.process_xla_flags(extra_xla_flags)
        submitit = submitit_module()
        waiting = queued(jobs) if self.cluster == "slurm" else {}
        for job in jobs:
            if job.run_dir in waiting:
                print(
                    f"{job.label}: still queued or running as Slurm job {waiting[job.run_dir]}; not submitted"
                )
        todo = [job for job in jobs if job.run_dir not in waiting]
        if not todo:
            return [None] * len(jobs)
        check_cluster(self.cluster)
        executor = submitit.AutoExecutor(folder=self.folder, cluster=self.cluster)
        executor.update_parameters(**self.parameters())
        with executor.batch():
            submitted = [executor.submit(run_in_job, job, process_flags) for job in todo]
        for job, sub in zip(todo, submitted, strict=True):
            job.log.parent.mkdir(parents=True, exist_ok=True)
            jsonio.write_json(
                marker(job), {"job_id": sub.job_id, "folder": str(self.folder), "at": provenance.now()}
            )
            print(f"{job.label}: Slurm job {sub.job_id}, log {job.log}", flush=True)
        if not self.wait:
            ids = [sub.job_id for sub in submitted]
            print(
                f"submitted, not waiting (--no-wait): squeue -j {','.join(ids)} shows them, scancel "
                f"{' '.join(ids)} cancels them; the same command again submits what is neither finished nor "
                "queued, and `record` packs the finished runs"
            )
            return [None] * len(jobs)
        codes = wait(dict(zip(todo, submitted, strict=True)), submitit)
        return [codes.get(job) for job in jobs]


def wait(submitted: dict[pinned.Job, Any], submitit) -> dict[pinned.Job, int]:
    """Each submitted job's exit code, said as it ends (1 for a job Slurm ended before its process: killed,
    timed out, cancelled). On Ctrl-C the jobs stay queued, and it says how to cancel them."""
    by_id = {sub.job_id: job for job, sub in submitted.items()}
    codes = {}
    try:
        for sub in submitit.helpers.as_completed(list(submitted.values()), poll_frequency=POLL_SECONDS):
            job = by_id[sub.job_id]
            try:
                codes[job] = sub.result()
            except submitit.core.utils.UncompletedJobError as err:
                codes[job] = 1
                why = str(err).splitlines()[0]
                print(f"{job.label}: Slurm job {sub.job_id} ended before its process: {why}")
                print(f"  its logs: {sub.paths.stdout} and {sub.paths.stderr}")
            print(f"{job.label}: exit {codes[job]} (Slurm job {sub.job_id})", flush=True)
    except KeyboardInterrupt:
        ids = " ".join(by_id)
        print(
            f"stopped waiting; the jobs stay queued or running (scancel {ids} cancels them)", file=sys.stderr
        )
        raise
    return codes


def run_in_job(job: pinned.Job, process_flags: str) -> int | None:
    """Inside a Slurm job: `job`'s process pinned to the first CPU the job has, with $XLA_FLAGS
    `process_flags` (`pinned.run_processes`: the process file as a local run's); its exit code (None: left to
    another process that trains it)."""
    (rc,) = pinned.run_processes([job], (provenance.visible_cores() or [0])[:1], process_flags)
    return rc


def marker(job: pinned.Job) -> Path:
    """`<run_dir>.slurm.json` beside the run directory: the Slurm job that trains it."""
    return job.run_dir.with_name(job.run_dir.name + ".slurm.json")


def queued(jobs: list[pinned.Job]) -> dict[Path, str]:
    """The run directories of `jobs` whose last Slurm job (`marker`) is still queued or running (this user's
    jobs that `squeue` lists), with its id; {} where there is no `squeue`, with a warning if it fails."""
    submitted = {
        job.run_dir: jsonio.read_json(marker(job))["job_id"] for job in jobs if marker(job).is_file()
    }
    if not submitted or not shutil.which("squeue"):
        return {}
    listed = subprocess.run(
        ["squeue", "-h", "-r", "-o", "%i", "-u", getpass.getuser()], capture_output=True, text=True
    )
    if listed.returncode != 0:
        print(
            f"warning: squeue failed ({listed.stderr.strip()}); submitting without checking", file=sys.stderr
        )
        return {}
    active = set(listed.stdout.split())
    return {run_dir: job_id for run_dir, job_id in submitted.items() if job_id in active}


def check_cluster(cluster: str) -> None:
    """ValueError where `cluster` is Slurm and this machine cannot submit to it (no `sbatch` and `srun`)."""
    missing = [tool for tool in ("sbatch", "srun") if cluster == "slurm" and not shutil.which(tool)]
    if missing:
        raise ValueError(
            f"--launcher slurm: no {' or '.join(missing)} here; submit from a machine of the Slurm cluster "
            '(its login node), or try the jobs on this machine with "cluster" = "local" in --slurm-config. '
            "Nothing was submitted"
        )


def slurm_minutes(value: Any, where: str) -> int:
    """A Slurm time limit (`TIME_FORMATS`, or a number of minutes) in whole minutes (rounded up, at least
    1); ValueError naming `where` it came from otherwise."""
    text = str(value).strip() if isinstance(value, int | str) and not isinstance(value, bool) else ""
    match = next((m for f in TIME_FORMATS if (m := re.fullmatch(f, text))), None)
    if match is None:
        raise ValueError(
            f"{where} {value!r}: not a Slurm time limit (minutes, MM:SS, HH:MM:SS, D-HH, D-HH:MM or "
            "D-HH:MM:SS)"
        )
    parts = {k: int(v) for k, v in match.groupdict().items() if v is not None}
    seconds = ((parts.get("d", 0) * 24 + parts.get("h", 0)) * 60 + parts.get("m", 0)) * 60 + parts.get("s", 0)
    if seconds < 1:
        raise ValueError(f"{where} {value!r}: a time limit must be above zero")
    return math.ceil(seconds / 60)


def word(value: Any, where: str) -> str | None:
    """`value` as a Slurm name (partition, account: text without spaces; None if not given); ValueError
    naming `where` otherwise."""
    if value is None:
        return None
    if not isinstance(value, str) or not re.fullmatch(r"[^\s,]+(,[^\s,]+)*", value):
        raise ValueError(f"{where} {value!r}: not a Slurm name (text without spaces)")
    return value


def sbatch_options(values: dict[str, Any], where: str) -> dict[str, Any]:
    """The extra sbatch options (key -> value; '-' in a key read as '_'), checked: each key a word that is not
    the launcher's own (`LAUNCHERS_OWN`), each value text, a number or true (a bare flag)."""
    checked = {}
    for key, value in values.items():
        name = str(key).replace("-", "_")
        if not re.fullmatch(r"[a-z][a-z0-9_]*", name):
            raise ValueError(f"{where} {key!r}: not an sbatch option name")
        if name in LAUNCHERS_OWN:
            raise ValueError(f"{where} {key!r}: not an extra option: {LAUNCHERS_OWN[name]}")
        if not isinstance(value, str | int | float) or value is False:
            raise ValueError(f"{where} {key}={value!r}: give text, a number or true")
        checked[name] = value
    return checked


def read_slurm_config(path: Path) -> dict[str, Any]:
    """A `--slurm-config` file (`.json` or `.toml`): its options, every key one of `OPTIONS`; ValueError
    naming the file and what is wrong."""
    if path.suffix not in (".json", ".toml"):
        raise ValueError(f"--slurm-config {path}: give a .json or .toml file")
    try:
        values = json.loads(path.read_text()) if path.suffix == ".json" else tomllib.loads(path.read_text())
    except (OSError, ValueError) as err:  # JSONDecodeError and TOMLDecodeError are ValueErrors
        raise ValueError(f"--slurm-config {path}: {err}") from err
    if not isinstance(values, dict):
        raise ValueError(f"--slurm-config {path}: not a table of options")
    unknown = sorted(set(values) - set(OPTIONS))
    if unknown:
        raise ValueError(f"--slurm-config {path}: unknown option(s) {unknown}; known: {', '.join(OPTIONS)}")
    return values


def options(config: str | None, given: dict[str, Any], wait: bool = True) -> Slurm:
    """The Slurm launcher of the `--slurm-config` file `config` (None: none) and the options `given` by flags
    (`FLAGS`' keys; None: not given), which override the file's (`additional_parameters` key by key),
    each checked; ValueError naming the flag or the file's key at fault, before anything is submitted."""
    from_file = read_slurm_config(Path(config)) if config else {}
    where = {k: f"--slurm-config {config}: {k!r} =" for k in from_file} | {
        k: FLAGS[k] for k, v in given.items() if v is not None
    }
    extra = from_file.get("additional_parameters", {})
    if not isinstance(extra, dict):
        raise ValueError(f"{where['additional_parameters']} {extra!r}: give a table of sbatch options")
    extra = sbatch_options(extra, where.get("additional_parameters", ""))
    extra |= sbatch_options(given.get("additional_parameters") or {}, FLAGS["additional_parameters"])
    values = from_file | {k: v for k, v in given.items() if v is not None}
    if values.get("time") is None:
        raise ValueError(
            "--launcher slurm: give a time limit a job, --slurm-time (or 'time' in --slurm-config); "
            "submitit would ask for 5 minutes"
        )
    setup, cluster = values.get("setup", []), values.get("cluster", "slurm")
    if not isinstance(setup, list) or not all(isinstance(line, str) for line in setup):
        raise ValueError(f"{where['setup']} {setup!r}: give a list of shell lines")
    if cluster not in CLUSTERS:
        raise ValueError(f"{where['cluster']} {cluster!r}: one of {', '.join(CLUSTERS)}")
    if not isinstance(values.get("folder", ""), str):
        raise ValueError(f"{where['folder']} {values['folder']!r}: give a directory")
    return Slurm(
        time_min=slurm_minutes(values["time"], where["time"]),
        partition=word(values.get("partition"), where.get("partition", "")),
        account=word(values.get("account"), where.get("account", "")),
        additional_parameters=extra,
        setup=tuple(setup),
        folder=Path(values.get("folder") or DEFAULT_FOLDER),
        cluster=cluster,
        wait=wait,
    )


def key_value(text: str) -> tuple[str, str]:
    """`--slurm-param KEY=VALUE` (argparse's type; its error otherwise)."""
    key, sep, value = text.partition("=")
    if not sep or not key or not value:
        raise argparse.ArgumentTypeError(f"{text!r}: give KEY=VALUE, e.g. mem=4G")
    return key, value


def add_options(parser: argparse.ArgumentParser) -> None:
    """The launcher's options on a `run` parser (which has --cores and --dry-run)."""
    group = parser.add_argument_group("launcher", "where the runs train (docs/scale-out.md)")
    group.add_argument(
        "--launcher",
        choices=("local", "slurm"),
        default="local",
        help="local: processes on this machine (--cores); slurm: one one-CPU Slurm job a seed, through "
        f"submitit ({INSTALL}), waited for",
    )
    group.add_argument("--slurm-config", default=None, metavar="FILE", help="Slurm options, JSON or TOML")
    group.add_argument("--slurm-partition", default=None, metavar="NAME")
    group.add_argument(
        "--slurm-time", default=None, metavar="TIME", help="a job's time limit, e.g. 90, 2:00:00"
    )
    group.add_argument("--slurm-account", default=None, metavar="NAME")
    group.add_argument(
        "--slurm-param",
        type=key_value,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="another sbatch option of each job, e.g. mem=4G or qos=short (repeatable)",
    )
    group.add_argument(
        "--slurm-folder",
        default=None,
        metavar="DIR",
        help=f"submitit's files and logs (default {DEFAULT_FOLDER})",
    )
    group.add_argument(
        "--no-wait", action="store_true", help="slurm: submit, print the job ids and return without waiting"
    )


def chosen(args: argparse.Namespace, default_cores: tuple[int, ...] = ()) -> pinned.Launcher | None:
    """The launcher the command line asks for, the one place it is chosen: `Slurm` (`--launcher slurm`, its
    options checked and, unless a dry run, submitit and the cluster's commands present), else `pinned.Cores`
    on --cores (or `default_cores`), else None (train in this process). ValueError naming an option that
    does not fit, before anything is submitted."""
    slurm_flags = {key: getattr(args, flag[2:].replace("-", "_")) for key, flag in FLAGS.items()}
    slurm_flags["additional_parameters"] = dict(slurm_flags["additional_parameters"])
    if args.launcher == "local":
        given = [flag for key, flag in FLAGS.items() if slurm_flags[key]]
        given += [f for f, v in (("--slurm-config", args.slurm_config), ("--no-wait", args.no_wait)) if v]
        if given:
            raise ValueError(f"{', '.join(given)}: the Slurm launcher's; add --launcher slurm")
        cores = tuple(args.cores or default_cores)
        return pinned.Cores(cores) if cores else None
    if args.cores:
        raise ValueError("--cores: the local launcher's; a Slurm job gets one CPU (--launcher slurm)")
    launcher = options(args.slurm_config, slurm_flags, wait=not args.no_wait)
    if not args.dry_run:
        submitit_module()
        check_cluster(launcher.cluster)
    return launcher
