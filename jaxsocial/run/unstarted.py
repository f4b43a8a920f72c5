"""A run directory left by a new run that completed no iteration (interrupted, killed or failed before its
first chunk): its config.json, its process file and the tree's diff (`provenance`), empty metrics and empty
checkpoint and policy folders, and nothing more. Such a directory does not block the command that made it:
a new run of the same config starts it again (`restarts`). One that holds anything more (metrics rows, a
checkpoint, a policy, a file a run does not write before its first iteration) or another run's config is
refused as before (`refusal`), once the config is valid and before anything is compiled or written.
"""

from __future__ import annotations

import fnmatch
from pathlib import Path
from typing import Any

from jaxsocial.run import checkout, config, rundir
from jaxsocial.run.config import TrainConfig

EMPTY_DIRS = (rundir.CHECKPOINTS_DIR, rundir.POLICY_DIR)
"""The folders a run makes before its first iteration, empty until its first checkpoint."""


def leftovers(run_dir: Path, seed_names: list[str]) -> list[Path]:
    """What `run_dir` holds beyond what a run with the seed folders `seed_names` (`rundir.seed_dir_names`)
    writes before its first iteration completes: [] where it holds nothing more."""
    more = []
    for entry in sorted(Path(run_dir).iterdir()):
        if entry.is_dir() and entry.name in seed_names:
            more += leftovers(entry, [])
        elif not _written_before_an_iteration(entry):
            more.append(entry)
    return more


def _written_before_an_iteration(entry: Path) -> bool:
    if entry.is_dir():
        return entry.name in EMPTY_DIRS and not any(entry.iterdir())
    if entry.name == rundir.METRICS_FILE:
        return entry.is_file() and entry.stat().st_size == 0
    names = (rundir.CONFIG_FILE, rundir.RUN_FILE)
    return entry.is_file() and (entry.name in names or fnmatch.fnmatch(entry.name, checkout.DIFF_GLOB))


def differences(saved: dict[str, Any], cfg: TrainConfig) -> list[str]:
    """The dotted keys in which a run directory's config.json `saved` differs from `cfg`'s (read as
    `config.config_from_dict` reads it, so text written differently does not differ)."""
    saved = config.config_dict(config.config_from_dict(saved))
    return rundir.config_diff(saved, config.config_dict(cfg))


def loose_keys(cfg: TrainConfig) -> set[str]:
    """The keys of `cfg`'s config.json that a run decides after it is validated: the network's "auto"
    choices (`startup.resolve_network`) and a new run's `--init-from` iteration
    (`init_from.pin_iteration`)."""
    loose = {"net.dtype"} if cfg.net.dtype == "auto" else set()
    loose |= {"net.conv_impl"} if "auto" in cfg.net.layer_impls.values() else set()
    return loose | ({"init_from"} if cfg.init_from is not None and not cfg.resume else set())


def refusal(cfg: TrainConfig, run_dir: Path, loose: set[str] | frozenset[str] = frozenset()) -> str | None:
    """Why the new run `cfg` may not start in `run_dir`, or None: it does not exist, is empty, or holds only
    what a run of the same config (up to the keys `loose`) writes before its first iteration."""
    run_dir = Path(run_dir)
    if not run_dir.exists() or (run_dir.is_dir() and not any(run_dir.iterdir())):
        return None
    if not run_dir.is_dir():
        return f"run path {run_dir} exists and is not a directory"
    taken = (
        f"run directory {run_dir} already exists and is not empty; pass --resume to continue that run or "
        "--overwrite to delete it and start fresh (or choose another --run-name)"
    )
    if leftovers(run_dir, rundir.seed_dir_names(cfg.seed, cfg.seeds)):
        return taken  # metrics, checkpoints or policies: a run that trained, or something else
    try:
        diff = [k for k in differences(rundir.read_config(run_dir), cfg) if k not in loose]
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return taken  # no config.json, or one that is no run's
    if diff:
        return (
            f"run directory {run_dir} holds no completed iteration, but it is another run's: its "
            f"{rundir.CONFIG_FILE} differs in {diff}; pass --overwrite to delete it and start fresh (or "
            "choose another --run-name)"
        )
    return None


def check_new_run(cfg: TrainConfig, run_dir: Path) -> None:
    """Before a new run (neither --resume nor --overwrite) prints its cost or compiles: FileExistsError where
    its directory `run_dir` is taken (`refusal`, up to its `loose_keys`)."""
    if cfg.resume or cfg.overwrite:
        return
    why = refusal(cfg, run_dir, loose_keys(cfg))
    if why:
        raise FileExistsError(why)


def restarts(cfg: TrainConfig, run_dir: Path) -> bool:
    """Whether the new run `cfg` (resolved: as its config.json will be) starts again in `run_dir`, which
    holds what a run of exactly its config wrote before its first iteration."""
    run_dir = Path(run_dir)
    taken = run_dir.is_dir() and any(run_dir.iterdir())
    return taken and not cfg.resume and not cfg.overwrite and refusal(cfg, run_dir) is None
