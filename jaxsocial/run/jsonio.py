"""JSON files: plain JSON values of numpy/jax values and paths (`to_json`), written atomically (`write_json`,
`atomic_write`) and read back (`read_json`). The files of a run directory are `jaxsocial.run.rundir`'s.
Dependency-free (numpy only)."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["atomic_write", "read_json", "to_json", "write_json"]


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


def atomic_write(path: Path, text: str) -> None:
    """Writes `text` to `path` through a temporary file beside it: a reader sees the old file or the new one,
    never part of one."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json(path: str | Path, obj: Any, *, indent: int | None = 2, sort_keys: bool = False) -> Path:
    """Writes `obj` (through `to_json`) to the JSON file `path`, atomically (a reader sees the old file or
    the new one, never part of one). Returns the path."""
    path = Path(path)
    atomic_write(path, json.dumps(to_json(obj), indent=indent, sort_keys=sort_keys) + "\n")
    return path


def read_json(path: str | Path) -> Any:
    """The contents of the JSON file `path` (FileNotFoundError if missing)."""
    return json.loads(Path(path).read_text())
