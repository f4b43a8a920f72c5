"""Where a recipe's seeds are: the run directory of each seed of a condition, whichever of the condition's
runs holds it (`condition_seed_dirs`). Read by the runner (what has finished), the figures and the records."""

from __future__ import annotations

import re
from pathlib import Path

from jaxsocial.experiments.analyse import records
from jaxsocial.experiments.plan import recipes
from jaxsocial.experiments.plan.recipes import Scale
from jaxsocial.run import rundir, runlock
from jaxsocial.run.config import TrainConfig

FINISHED, TRAINING, PARTIAL, MISSING = "finished", "training now", "partial", "missing"
"""A run's state: every iteration logged; training now in a live process (its lock is held: left to it);
begun and stopped (its config is there: training resumes it); not begun."""
LEFT_ALONE = (FINISHED, TRAINING)
"""The states of a run that no runner starts or resumes."""
RESTORED_FILE = "restored.json"
"""In a run directory copied from its record (`launch.restore`): the record's path, the commit it was read at,
and when; `record` leaves such a directory alone."""


def config_seed_dirs(cfg: TrainConfig) -> list[Path]:
    """The run directory of every seed of a condition's config."""
    return rundir.seed_dirs(rundir.run_path(cfg), cfg.seed, cfg.seeds)


def finished(seed_dir: Path, iterations: int) -> bool:
    """Whether the run in `seed_dir` is over: it logged `iterations` rows, or its `stop_at_return` ended it
    earlier (`records.stopped_early`), so resuming it would train past its stop."""
    if not rundir.has_metrics(seed_dir):
        return False
    rows = rundir.read_metrics(seed_dir)
    return len(rows) >= iterations or records.stopped_early(rundir.read_config(seed_dir), rows)


def run_state(run_dir: Path, iterations: int, seed_dirs: list[Path] | None = None) -> str:
    """FINISHED (each of `seed_dirs`, or the run directory itself where a run has one seed, is over:
    `finished`), TRAINING (a live process holds its lock, `runlock.RunLock.live_holder`: from the run's start,
    before it writes anything), PARTIAL (the run's config is written, so training resumes it) or MISSING. The
    one rule for every run a design or the sweep trains: a recipe's conditions, branches, sweep seeds,
    follow-ups; a runner starts only the PARTIAL and MISSING ones, so two runners share a design's seeds."""
    if all(finished(d, iterations) for d in seed_dirs or [run_dir]):
        return FINISHED
    if runlock.RunLock(run_dir).live_holder() is not None:
        return TRAINING
    return PARTIAL if (run_dir / rundir.CONFIG_FILE).exists() else MISSING


def condition_seed_dirs(
    scale: Scale, condition: str, seed: int, seeds: int, runs_dir: str, pick: tuple[str, ...] = ()
) -> list[Path]:
    """The run directory of each seed seed..seed+seeds-1 of a condition, from whichever of the condition's
    runs at this scale (`<condition>-s<first>-<last>`) holds it: the recipe's own run, or another (e.g.
    seeds trained in two programs, `--seeds 3` then `--seed 3 --seeds 3`, read together as `--seeds 6`). A
    seed that no run holds keeps the directory the recipe's own run would give it.

    A seed held by several runs is never chosen silently: ValueError naming them, unless exactly one of them
    is in `pick` (run directory names, e.g. 'social_rec-s0-5')."""
    own = [
        d
        for cfg in recipes.condition_programs(scale, condition, seed, seeds, runs_dir)
        for d in config_seed_dirs(cfg)
    ]
    held: dict[int, list[Path]] = {}
    for run_dir in sorted((Path(runs_dir) / scale.runs_root).glob(f"{condition}-s*")):
        match = re.fullmatch(rf"{re.escape(condition)}-s(\d+)-(\d+)", run_dir.name)
        if not match:
            continue
        first, last = int(match[1]), int(match[2])
        for s in range(first, last + 1):
            d = run_dir if first == last else run_dir / rundir.seed_name(s)
            if rundir.has_metrics(d):
                held.setdefault(s, []).append(d)
    return [_one_holder(condition, s, held.get(s, []), d, pick) for s, d in enumerate(own, start=seed)]


def records_beside_runs(
    scale: Scale,
    conditions: tuple[str, ...],
    seed: int,
    seeds: int,
    runs_dir: str,
    records_dir: str,
    pick: tuple[str, ...] = (),
) -> list[tuple[str, int, Path, Path]]:
    """(condition, seed, record directory, run directory) of each seed seed..seed+seeds-1 of every condition,
    each directory as `condition_seed_dirs` finds it under `records_dir` and under `runs_dir`."""
    return [
        (condition, k, record_dir, run_dir)
        for condition in conditions
        for k, record_dir, run_dir in zip(
            range(seed, seed + seeds),
            condition_seed_dirs(scale, condition, seed, seeds, records_dir, pick),
            condition_seed_dirs(scale, condition, seed, seeds, runs_dir, pick),
            strict=True,
        )
    ]


def _one_holder(condition: str, seed: int, holders: list[Path], default: Path, pick: tuple[str, ...]) -> Path:
    """The one directory of `holders` that holds `seed` (`default` if none; see `condition_seed_dirs`)."""
    if len(holders) <= 1:
        return holders[0] if holders else default
    picked = [d for d in holders if run_of(d).name in pick]
    if len(picked) == 1:
        return picked[0]
    runs = ", ".join(str(run_of(d)) for d in holders)
    raise ValueError(
        f"seed {seed} of {condition} is held by {len(holders)} runs ({runs}); name the one to read with "
        f"--pick RUN (e.g. --pick {run_of(holders[0]).name})"
    )


def run_of(seed_dir: Path) -> Path:
    """The run directory of a seed directory (itself for a one-seed run)."""
    return seed_dir.parent if re.fullmatch(r"s\d+", seed_dir.name) else seed_dir
