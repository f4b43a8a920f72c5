"""Where things go in a training run's directory, named in one place::

    <runs_dir>/<run_name>/          (`run_path`) config.json, metrics.jsonl (`logs`), process.json
                                    (`RUN_FILE`), the writer's lock (`runlock`)
        s<seed>/                    one per seed of a several-seed run; a one-seed run is its own seed
            config.json             the config of a one-seed run of that seed (it reads like one)
            checkpoints/<it>/       params, optimiser state and stage, to resume or branch from
            policy/<it>/            the exported policy (`run.policy_io`)
            eval/<spec>.json        evaluations after training (`logs.EVAL_DIR`)

Records (`experiments.records`) keep the same layout, less the checkpoints.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

CHECKPOINTS_DIR = "checkpoints"
RUN_FILE = "process.json"
"""What the processes that trained in a run directory were (`jaxsocial.run.provenance`)."""
POLICY_DIR = "policy"
"""A seed's exported policy: the learners' params (stacked [S_l, ...]), which frozen slots load."""


def run_path(cfg: Any) -> Path:
    """The run directory of a config (a `TrainConfig`, not imported on this floor): `runs_dir/run_name`."""
    return Path(cfg.runs_dir).expanduser() / run_name(cfg)


def run_name(cfg: Any) -> str:
    """`cfg.run_name`, or '<env>-s<seed>' ('<env>-s<first>-<last>' for several seeds)."""
    if cfg.run_name:
        return cfg.run_name
    last = f"-{cfg.seed + cfg.seeds - 1}" if cfg.seeds > 1 else ""
    return f"{cfg.env}-s{cfg.seed}{last}"


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
