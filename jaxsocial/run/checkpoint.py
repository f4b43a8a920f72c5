"""Checkpoints of pytrees on disk (orbax-checkpoint backend; swapping backends only touches this file).

Layout: ``directory/<step>/`` holds three orbax items:

- ``state``: the pytree's leaves as a flat dict of numpy arrays (typed PRNG keys stored as their
  ``jax.random.key_data``),
- ``manifest``: JSON list of the leaves (key path, shape, dtype, PRNG impl) used to check a restore target
  cheaply, before anything is read or compiled,
- ``metadata``: caller's JSON dict (e.g. the config).

The tree structure itself is not stored: ``restore`` rebuilds it from ``target``, matching leaves by key path.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

__all__ = [
    "CheckpointMismatchError",
    "all_steps",
    "latest_step",
    "read_metadata",
    "restore",
    "save",
]

_FORMAT = 1
_MAX_REPORTED = 5


class CheckpointMismatchError(ValueError):
    """The stored tree's structure, shapes or dtypes differ from the restore target."""


# ----------------------------------------------------------------------------------------------------------
# Leaves
# ----------------------------------------------------------------------------------------------------------


def _is_prng_key(x: Any) -> bool:
    dtype = getattr(x, "dtype", None)
    return dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)


def _leaf_spec(x: Any, path: str) -> dict[str, Any]:
    """{"shape", "dtype", "py"} of a leaf (array, ShapeDtypeStruct, numpy or python scalar) as JSON values."""
    if _is_prng_key(x):
        return {"shape": list(x.shape), "dtype": str(x.dtype), "py": False}
    if isinstance(x, jax.ShapeDtypeStruct | jax.Array | np.ndarray | np.generic):
        return {"shape": list(x.shape), "dtype": str(np.dtype(x.dtype)), "py": False}
    if isinstance(x, bool | int | float | complex):
        return {"shape": [], "dtype": str(np.asarray(x).dtype), "py": True}
    raise TypeError(f"checkpoint: unsupported leaf at {path or '<root>'}: {type(x).__name__}")


def _kind(dtype: str) -> str:
    return dtype if dtype.startswith("key<") else np.dtype(dtype).kind


def _compatible(want: Mapping[str, Any], stored: Mapping[str, Any]) -> bool:
    """Same shape and dtype; for python scalars (float64 vs `jax.eval_shape`'s float32) only same kind."""
    if list(want["shape"]) != list(stored["shape"]):
        return False
    if want["py"] or stored.get("py"):
        return _kind(want["dtype"]) == _kind(stored["dtype"])
    return want["dtype"] == stored["dtype"]


def _fmt_spec(spec: Mapping[str, Any]) -> str:
    return f"{spec['dtype']}{list(spec['shape'])}"


def _flatten(state: Any) -> tuple[dict[str, np.ndarray], list[dict[str, Any]]]:
    """state -> ({"00000": np.ndarray, ...}, manifest entries [{"path", "shape", "dtype", "key_impl"}])."""
    arrays: dict[str, np.ndarray] = {}
    manifest: list[dict[str, Any]] = []
    for i, (kp, leaf) in enumerate(jax.tree_util.tree_flatten_with_path(state)[0]):
        path = jax.tree_util.keystr(kp)
        entry = {"path": path, **_leaf_spec(leaf, path), "key_impl": None}
        if _is_prng_key(leaf):
            entry["key_impl"] = str(jax.random.key_impl(leaf))
            data = np.asarray(jax.random.key_data(leaf))
        else:
            data = np.asarray(leaf)
            if data.dtype.kind in "OSU":
                raise TypeError(f"checkpoint: unsupported leaf at {path or '<root>'}: dtype {data.dtype}")
        arrays[f"{i:05d}"] = data
        manifest.append(entry)
    return arrays, manifest


def _check_target(manifest: list[dict[str, Any]], target: Any, where: Path) -> list[tuple[str, Any]]:
    """Compares target leaves to the manifest by key path; returns [(array name, target leaf)] in order.

    Raises CheckpointMismatchError naming the first few differing leaves.
    """
    stored = {e["path"]: (f"{i:05d}", e) for i, e in enumerate(manifest)}
    problems: list[str] = []
    matched: list[tuple[str, Any]] = []
    seen: set[str] = set()
    for kp, leaf in jax.tree_util.tree_flatten_with_path(target)[0]:
        path = jax.tree_util.keystr(kp)
        seen.add(path)
        want = _leaf_spec(leaf, path)
        if path not in stored:
            problems.append(f"  {path or '<root>'}: expected {_fmt_spec(want)}, not in checkpoint")
            continue
        name, entry = stored[path]
        if not _compatible(want, entry):
            problems.append(f"  {path or '<root>'}: expected {_fmt_spec(want)}, stored {_fmt_spec(entry)}")
        matched.append((name, leaf))
    for path, (_, entry) in stored.items():
        if path not in seen:
            problems.append(f"  {path or '<root>'}: stored {_fmt_spec(entry)}, not in target")
    if problems:
        more = len(problems) - _MAX_REPORTED
        lines = problems[:_MAX_REPORTED] + ([f"  ... and {more} more"] if more > 0 else [])
        raise CheckpointMismatchError(
            f"checkpoint {where} does not match the restore target ({len(problems)} differing leaves):\n"
            + "\n".join(lines)
            + "\nThis usually means the checkpoint was written with another architecture/config; "
            "compare read_metadata() with your config."
        )
    return matched


def _to_target_type(data: np.ndarray, leaf: Any, entry: Mapping[str, Any]) -> Any:
    """Converts a restored numpy array to the kind of the target leaf."""
    if entry["key_impl"] is not None:
        return jax.random.wrap_key_data(jnp.asarray(data), impl=entry["key_impl"])
    if isinstance(leaf, np.ndarray | np.generic):
        data = data.astype(leaf.dtype, copy=False)
        return data if isinstance(leaf, np.ndarray) else data[()]
    if isinstance(leaf, bool | int | float | complex):
        return type(leaf)(data.item())
    data = data.astype(leaf.dtype, copy=False)
    sharding = getattr(leaf, "sharding", None)
    return jax.device_put(data, sharding) if sharding is not None else jnp.asarray(data)


# ----------------------------------------------------------------------------------------------------------
# JSON
# ----------------------------------------------------------------------------------------------------------


def _jsonable(metadata: Mapping[str, Any] | None) -> dict[str, Any]:
    """`metadata` ({} for None), checked to be plain JSON values (`jsonio.to_json` makes them: dicts, lists,
    str, finite numbers, bool, None); TypeError otherwise."""
    if metadata is None:
        return {}
    if not isinstance(metadata, Mapping):
        raise TypeError(f"checkpoint metadata must be a dict, got {type(metadata).__name__}")
    try:
        json.dumps(metadata, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise TypeError(
            f"checkpoint metadata must be plain JSON values (jsonio.to_json makes them): {err}"
        ) from None
    return dict(metadata)


# ----------------------------------------------------------------------------------------------------------
# Manager
# ----------------------------------------------------------------------------------------------------------


def _dir(directory: str | Path) -> Path:
    return Path(directory).expanduser().absolute()


def _manager(directory: Path, *, keep: int | None = None, write: bool = False) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(
        max_to_keep=keep,
        create=write,
        cleanup_tmp_directories=write,
        enable_async_checkpointing=False,
    )
    return ocp.CheckpointManager(directory, options=options)


def all_steps(directory: str | Path) -> list[int]:
    """Sorted steps of the complete checkpoints in `directory` ([] if it does not exist)."""
    directory = _dir(directory)
    if not directory.is_dir():
        return []
    with _manager(directory) as mngr:
        return sorted(int(s) for s in mngr.all_steps())


def latest_step(directory: str | Path) -> int | None:
    """Largest checkpointed step in `directory`, or None if there is none."""
    steps = all_steps(directory)
    return steps[-1] if steps else None


def _resolve_step(directory: Path, step: int | None) -> int:
    if not directory.is_dir():
        raise FileNotFoundError(f"checkpoint directory {directory} does not exist")
    steps = all_steps(directory)
    if not steps:
        raise FileNotFoundError(f"no checkpoint in {directory}")
    if step is None:
        return steps[-1]
    if int(step) not in steps:
        raise FileNotFoundError(f"no checkpoint for step {step} in {directory} (steps: {steps})")
    return int(step)


def save(
    directory: str | Path,
    step: int,
    state: Any,
    *,
    keep: int | None = 3,
    metadata: Mapping[str, Any] | None = None,
) -> Path:
    """Saves pytree `state` under `directory/<step>` and waits until it is written.

    state: nested dicts/lists/tuples/NamedTuples/flax struct dataclasses of jax or numpy arrays (typed PRNG
    keys included) and python scalars. keep: number of most recent steps kept (None: all). metadata: small
    dict of plain JSON values stored alongside (TypeError otherwise). Steps must increase: an existing step
    raises FileExistsError, a step below the latest one ValueError. Returns the step directory.
    """
    directory = _dir(directory)
    step = int(step)
    if step < 0:
        raise ValueError(f"checkpoint step must be >= 0, got {step}")
    if keep is not None and keep < 1:
        raise ValueError(f"keep must be None or >= 1, got {keep}")
    path = directory / str(step)
    steps = all_steps(directory)
    if path.exists() or step in steps:
        raise FileExistsError(f"checkpoint {path} already exists; refusing to overwrite it")
    if steps and step < steps[-1]:
        raise ValueError(f"checkpoint step {step} is below the latest step {steps[-1]} in {directory}")
    arrays, leaves = _flatten(state)
    items: dict[str, Any] = {
        "manifest": ocp.args.JsonSave({"format": _FORMAT, "leaves": leaves}),
        "metadata": ocp.args.JsonSave(_jsonable(metadata)),
    }
    if arrays:  # orbax refuses empty items
        items["state"] = ocp.args.StandardSave(arrays)
    with _manager(directory, keep=keep, write=True) as mngr:
        saved = mngr.save(step, args=ocp.args.Composite(**items))
        mngr.wait_until_finished()
    if not saved or not path.is_dir():
        raise RuntimeError(f"orbax did not write checkpoint {path}")
    return path


def _read_json_item(directory: Path, step: int, item: str) -> Any:
    with _manager(directory) as mngr:
        return mngr.restore(step, args=ocp.args.Composite(**{item: ocp.args.JsonRestore()}))[item]


def read_metadata(directory: str | Path, step: int | None = None) -> dict[str, Any]:
    """The metadata dict saved with `step` (latest by default); {} if none was given."""
    directory = _dir(directory)
    step = _resolve_step(directory, step)
    return dict(_read_json_item(directory, step, "metadata") or {})


def leaf_shapes(directory: str | Path, step: int | None = None) -> dict[str, tuple[int, ...]]:
    """The shape of every leaf saved at `step` (latest by default), by key path (`jax.tree_util.keystr`)."""
    directory = _dir(directory)
    manifest = _read_json_item(directory, _resolve_step(directory, step), "manifest")
    return {e["path"]: tuple(e["shape"]) for e in manifest["leaves"]}


def restore(directory: str | Path, target: Any, step: int | None = None) -> Any:
    """Restores checkpoint `step` (latest by default) into the structure of `target`.

    target: pytree like the saved state whose leaves are arrays, `jax.ShapeDtypeStruct`s (typed PRNG key
    dtypes included), numpy arrays or python scalars; leaves are matched by key path. Returned leaves are jax
    arrays (on the target's sharding if it has one), or numpy/python values where the target leaf is one.
    Raises FileNotFoundError if there is no such checkpoint and CheckpointMismatchError (before reading any
    array) if structure, shapes or dtypes differ.
    """
    directory = _dir(directory)
    step = _resolve_step(directory, step)
    where = directory / str(step)
    manifest = _read_json_item(directory, step, "manifest")
    if not isinstance(manifest, dict) or manifest.get("format") != _FORMAT:
        raise CheckpointMismatchError(f"checkpoint {where} has an unknown format: {str(manifest)[:200]}")
    entries = manifest["leaves"]
    matched = _check_target(entries, target, where)
    stored: dict[str, np.ndarray] = {}
    if matched:
        abstract = {}
        for name, leaf in matched:
            if _is_prng_key(leaf):  # stored as key data
                abstract[name] = jax.eval_shape(
                    jax.random.key_data, jax.ShapeDtypeStruct(leaf.shape, leaf.dtype)
                )
            else:
                spec = entries[int(name)]
                abstract[name] = jax.ShapeDtypeStruct(tuple(spec["shape"]), np.dtype(spec["dtype"]))
        with _manager(directory) as mngr:
            args = ocp.args.Composite(state=ocp.args.StandardRestore(abstract))
            stored = mngr.restore(step, args=args)["state"]
    leaves = [_to_target_type(np.asarray(stored[name]), leaf, entries[int(name)]) for name, leaf in matched]
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(target), leaves)
