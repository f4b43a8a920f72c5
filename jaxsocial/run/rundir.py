"""The run directory's one owner: every file and directory name in it, preparing it, its config.json, its
metrics log and its seeds::

    <runs_dir>/<run_name>/          (`run_path`, `prepare_run_dir`) config.json (`CONFIG_FILE`,
                                    `write_config`), metrics.jsonl (`METRICS_FILE`, `MetricsLog`),
                                    process.json (`RUN_FILE`)
    <runs_dir>/.<run_name>.lock     the writer's lock (`lock_name`; held by `jaxsocial.run.runlock`)
        s<seed>/                    one per seed of a several-seed run; a one-seed run is its own seed
            config.json             the config of a one-seed run of that seed (it reads like one)
            checkpoints/<it>/       params, optimiser state and stage, to resume or branch from
            policy/<it>/            the exported policy (`run.policy_io`)
            eval/<spec>.json        evaluations after training (`EVAL_DIR`)

Records (`experiments.records`) keep the same layout, less the checkpoints, and their metrics gzipped
(`METRICS_GZ_FILE`). What the rows of metrics.jsonl hold is `jaxsocial.run.metrics`'; JSON files are written
and read through `jaxsocial.run.jsonio`.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

from jaxsocial.run.jsonio import atomic_write, read_json, to_json, write_json

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.jsonl"
METRICS_GZ_FILE = METRICS_FILE + ".gz"
"""A run record's compressed metrics (`experiments.analyse.records`), read where no `METRICS_FILE` is."""
EVAL_DIR = "eval"
"""A seed's evaluations after training, one JSON per environment (`experiments.analyse.kinds.eval_path`)."""
CHECKPOINTS_DIR = "checkpoints"
RUN_FILE = "process.json"
"""What the processes that trained in a run directory were (`jaxsocial.run.provenance`)."""
POLICY_DIR = "policy"
"""A seed's exported policy: the learners' params (stacked [S_l, ...]), which frozen slots load."""
REQUIRED = {"env", "seed", "seeds", "num_envs", "rollout_steps"}
"""Keys a training run's config.json must have to be read as one."""


# ----------------------------------------------------------------------------------------------------------
# Names and seeds
# ----------------------------------------------------------------------------------------------------------


def run_path(cfg: Any) -> Path:
    """The run directory of a config (a `TrainConfig`, not imported on this floor): `runs_dir/run_name`."""
    return Path(cfg.runs_dir).expanduser() / run_name(cfg)


def run_name(cfg: Any) -> str:
    """`cfg.run_name`, or '<env>-s<seed>' ('<env>-s<first>-<last>' for several seeds)."""
    if cfg.run_name:
        return cfg.run_name
    last = f"-{cfg.seed + cfg.seeds - 1}" if cfg.seeds > 1 else ""
    return f"{cfg.env}-s{cfg.seed}{last}"


def lock_name(dir_name: str) -> str:
    """The lock file of the run directory named `dir_name`, beside it in its parent (so `--overwrite` can
    delete the directory while holding it): `.<dir_name>.lock`."""
    return f".{dir_name}.lock"


def seed_name(seed: int) -> str:
    """The sub-directory of `seed` in a several-seed run (or in the records of a sweep setting)."""
    return f"s{seed}"


def seed_dir_names(seed: int, seeds: int) -> list[str]:
    """The sub-directory of each seed of a run of `seeds` seeds from `seed` ('' for a one-seed run: the run
    itself)."""
    return [""] if seeds == 1 else [seed_name(s) for s in range(seed, seed + seeds)]


def seed_dirs(run_dir: Path, seed: int, seeds: int) -> list[Path]:
    """The directory of each seed of the run `run_dir` of `seeds` seeds from `seed`."""
    return [run_dir / name if name else run_dir for name in seed_dir_names(seed, seeds)]


def checkpoints(seed_dir: Path) -> Path:
    """A seed's checkpoint directory."""
    return Path(seed_dir) / CHECKPOINTS_DIR


class SeedRun(NamedTuple):
    """One seed of a run: its PRNG seed, its directory and its config.json values (which its checkpoints
    carry as metadata)."""

    seed: int
    dir: Path
    config: dict[str, Any]


def prepare_run_dir(root: str | Path, name: str, *, resume: bool = False, overwrite: bool = False) -> Path:
    """Creates (or, with `resume`, reuses) the run directory `root/name` and returns it.

    An existing non-empty directory raises FileExistsError unless `resume` (keep it; FileNotFoundError if it
    does not exist) or `overwrite` (delete it and start fresh). Both together: ValueError.
    """
    if resume and overwrite:
        raise ValueError("choose at most one of resume and overwrite")
    parts = Path(name).parts
    if not parts or Path(name).is_absolute() or any(p in (".", "..") for p in parts):
        raise ValueError(f"run name must be a relative path without '.' or '..', got {name!r}")
    run_dir = Path(root).expanduser() / name
    if run_dir.exists() and not run_dir.is_dir():
        raise FileExistsError(f"run path {run_dir} exists and is not a directory")
    if resume:
        if not run_dir.is_dir():
            raise FileNotFoundError(f"cannot resume: run directory {run_dir} does not exist")
        return run_dir
    if run_dir.is_dir() and any(run_dir.iterdir()):
        if not overwrite:
            raise FileExistsError(
                f"run directory {run_dir} already exists and is not empty; pass --resume to continue "
                "that run or --overwrite to delete it and start fresh (or choose another --run-name)"
            )
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    return run_dir


# ----------------------------------------------------------------------------------------------------------
# config.json
# ----------------------------------------------------------------------------------------------------------


def write_config(run_dir: str | Path, config: Mapping[str, Any]) -> Path:
    """Writes `config` to `run_dir/config.json` (indent 2, sorted keys; values through `to_json`)."""
    return write_json(Path(run_dir) / CONFIG_FILE, config, sort_keys=True)


def read_config(run_dir: str | Path) -> dict[str, Any]:
    """Reads `run_dir/config.json` (FileNotFoundError if missing)."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise FileNotFoundError(f"no {CONFIG_FILE} in run directory {run_dir}")
    return read_json(path)


def config_diff(a: Mapping[str, Any], b: Mapping[str, Any]) -> list[str]:
    """Sorted dotted keys (e.g. "agent.lr") whose values differ between configs `a` and `b`, including keys
    present in only one. Values are compared after `to_json` (so tuples equal lists, as in config.json)."""

    def walk(x: Any, y: Any, prefix: str) -> Iterable[str]:
        if isinstance(x, dict) and isinstance(y, dict):
            for k in sorted(set(x) | set(y)):
                key = f"{prefix}.{k}" if prefix else k
                if k not in x or k not in y:
                    yield key
                else:
                    yield from walk(x[k], y[k], key)
        elif x != y:
            yield prefix

    return list(walk(to_json(a), to_json(b), ""))


def run_config(run_dir: Path) -> dict[str, Any]:
    """The config.json of a training run. ValueError if `run_dir` is not a run written by
    `python -m jaxsocial.train`."""
    if not run_dir.is_dir():
        raise ValueError(f"run directory {run_dir} does not exist")
    try:
        config = read_config(run_dir)
    except FileNotFoundError:
        raise ValueError(
            f"{run_dir} is not a run directory (no {CONFIG_FILE}): expected a directory written by "
            "python -m jaxsocial.train"
        ) from None
    except json.JSONDecodeError as err:
        raise ValueError(f"{run_dir / CONFIG_FILE} is not valid JSON: {err}") from None
    if not isinstance(config, dict) or not set(config) >= REQUIRED:
        raise ValueError(f"{run_dir / CONFIG_FILE} is not the config of a training run")
    return config


def written_seed_dirs(run_dir: str | Path) -> list[Path]:
    """The directory of every seed of a training run (the run itself for one seed). ValueError if
    `run_dir` is not a run written by `python -m jaxsocial.train`, or a seed's directory is missing."""
    run_dir = Path(run_dir)
    config = run_config(run_dir)
    dirs = seed_dirs(run_dir, config["seed"], config["seeds"])
    for d in dirs:
        if not (d / CONFIG_FILE).is_file():
            raise ValueError(f"{d} is missing ({run_dir} was trained with --seeds {config['seeds']})")
    return dirs


def one_seed_of_many(config: Mapping[str, Any]) -> bool:
    """Whether a seed directory's config is that of one seed of a multi-seed run (its run name ends in
    '/s<seed>', see `outputs.seed_runs`)."""
    return (config.get("run_name") or "").endswith(f"/{seed_name(config['seed'])}")


# ----------------------------------------------------------------------------------------------------------
# metrics.jsonl
# ----------------------------------------------------------------------------------------------------------


def _read_rows(path: Path) -> list[tuple[str, dict[str, Any]]]:
    """(line, row) pairs of a JSONL file; unreadable lines (interrupted writes) are skipped with a warning."""
    if not path.is_file():
        return []
    rows = []
    for i, line in enumerate(path.read_text().splitlines()):
        if not line.strip():
            continue
        try:
            rows.append((line, json.loads(line)))
        except json.JSONDecodeError:
            warnings.warn(f"{path}: skipping truncated line {i + 1}: {line[:60]!r}", stacklevel=3)
    return rows


class MetricsLog:
    """Append-only `run_dir/metrics.jsonl`, one JSON object per row.

    Values go through `to_json`: numpy/jax scalars and small arrays become python numbers/lists and
    non-finite floats (NaN, inf) are written as null.
    """

    def __init__(self, run_dir: str | Path):
        self.path = Path(run_dir) / METRICS_FILE

    def append(self, rows: Iterable[Mapping[str, Any]]) -> None:
        """Writes `rows` (dicts of str -> scalar/array) and flushes them to disk."""
        text = "".join(json.dumps(to_json(dict(r)), allow_nan=False) + "\n" for r in rows)
        if not text:
            return
        with open(self.path, "a+b") as f:
            if f.tell() > 0:  # a crash may have left a partial line: start on a new one
                f.seek(-1, os.SEEK_END)
                if f.read(1) != b"\n":
                    text = "\n" + text
            f.write(text.encode())
            f.flush()
            os.fsync(f.fileno())

    def truncate_after(self, iteration: int) -> int:
        """Drops rows with `row["iteration"] > iteration` (rows without "iteration" are kept), e.g. when
        resuming from the checkpoint of `iteration`. Returns the number of dropped rows."""
        rows = _read_rows(self.path)
        kept = [
            line
            for line, row in rows
            if not (row.get("iteration") is not None and row["iteration"] > iteration)
        ]
        if self.path.is_file():
            atomic_write(self.path, "".join(line + "\n" for line in kept))
        return len(rows) - len(kept)

    def read(self) -> list[dict[str, Any]]:
        """All rows, in order."""
        return [row for _, row in _read_rows(self.path)]


def read_metrics(run_dir: str | Path) -> list[dict[str, Any]]:
    """Rows of `run_dir/metrics.jsonl` (a seed's), or of a record's gzipped `metrics.jsonl.gz` where there is
    no plain one ([] if neither exists); non-finite values read back as None."""
    log = MetricsLog(run_dir)
    packed = Path(run_dir) / METRICS_GZ_FILE
    if not log.path.is_file() and packed.is_file():
        return [
            json.loads(line) for line in gzip.decompress(packed.read_bytes()).decode().splitlines() if line
        ]
    return log.read()


def has_metrics(run_dir: str | Path) -> bool:
    """Whether `run_dir` holds a non-empty `metrics.jsonl` or `metrics.jsonl.gz`."""
    return any(
        (p := Path(run_dir) / name).is_file() and p.stat().st_size > 0
        for name in (METRICS_FILE, METRICS_GZ_FILE)
    )
