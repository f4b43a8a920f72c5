"""Run directories, config files and JSONL metrics (the progress line and the external loggers are
`jaxsocial.run.loggers`').

A run directory ``root/name`` holds ``config.json`` (``write_config``), ``metrics.jsonl`` (``MetricsLog``;
what its rows hold is ``jaxsocial.run.metrics``) and whatever else the caller puts there (e.g. checkpoints,
``eval/``). Dependency-free.
"""

from __future__ import annotations

import gzip
import json
import math
import os
import shutil
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "MetricsLog",
    "config_diff",
    "has_metrics",
    "prepare_run_dir",
    "read_config",
    "read_json",
    "read_metrics",
    "to_json",
    "write_config",
    "write_json",
]

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.jsonl"
METRICS_GZ_FILE = METRICS_FILE + ".gz"
"""A run record's compressed metrics (`experiments.analyse.records`), read where no `METRICS_FILE` is."""
EVAL_DIR = "eval"
"""A seed's evaluations after training, one JSON per environment (`experiments.analyse.kinds.eval_path`)."""


# ----------------------------------------------------------------------------------------------------------
# Run directory and config
# ----------------------------------------------------------------------------------------------------------


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


def to_json(x: Any) -> Any:
    """Converts `x` to plain JSON values: numpy/jax scalars -> int/float/bool, arrays -> (nested) lists,
    tuples -> lists, Paths -> str; non-finite floats (NaN, inf) -> None. Raises TypeError otherwise."""
    if x is None or isinstance(x, bool | str):
        return x
    if isinstance(x, int):
        return int(x)
    if isinstance(x, float):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): to_json(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [to_json(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, np.generic | np.ndarray) or hasattr(x, "__array__"):
        a = np.asarray(x)
        if a.dtype.kind in "biuf":
            return to_json(a.tolist())  # numpy scalars/arrays -> python (nested lists of) values
    raise TypeError(f"not JSON serialisable: {type(x).__name__}: {x!r:.80}")


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json(path: str | Path, obj: Any, *, indent: int | None = 2, sort_keys: bool = False) -> Path:
    """Writes `obj` (through `to_json`) to the JSON file `path`, atomically (a reader sees the old file or
    the new one, never part of one). Returns the path."""
    path = Path(path)
    _atomic_write(path, json.dumps(to_json(obj), indent=indent, sort_keys=sort_keys) + "\n")
    return path


def read_json(path: str | Path) -> Any:
    """The contents of the JSON file `path` (FileNotFoundError if missing)."""
    return json.loads(Path(path).read_text())


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


# ----------------------------------------------------------------------------------------------------------
# Metrics
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
            _atomic_write(self.path, "".join(line + "\n" for line in kept))
        return len(rows) - len(kept)

    def read(self) -> list[dict[str, Any]]:
        """All rows, in order."""
        return [row for _, row in _read_rows(self.path)]


def read_metrics(run_dir: str | Path) -> list[dict[str, Any]]:
    """Rows of `run_dir/metrics.jsonl`, or of a record's gzipped `metrics.jsonl.gz` where there is no plain
    one ([] if neither exists); non-finite values read back as None."""
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
