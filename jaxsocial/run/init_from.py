"""`--init-from RUN_DIR[@ITERATION]`: start a new run from another run's learners.

The new run gets the source's learner params and optimiser state (Adam moments and step count) from its
checkpoint of ITERATION (default: the latest every source seed has); everything else is the new run's own:
fresh environments, LSTM states and random keys from its seed, its flags, stages and `--iterations`. Its
iteration counter starts at 0, so `--iterations N` trains N more iterations and stages are counted from the
branch point; the source and the iteration are in its `config.json` (`init_from`: `RUN_DIR@ITERATION`), so the
total training a learner has had is the source's ITERATION plus the new run's.

RUN_DIR is one seed's run directory (every seed of the new run starts from it) or a several-seed run
directory holding `s<seed>/` for each of the new run's seeds (each starts from its own). The network
architecture and the learner slots must be the source's (`check`, called by the driver before anything is
written or compiled). A resumed run continues from its own checkpoints; `init_from` then does nothing. This
module validates and names the source; the driver loads its learners (`driver.load_source_learners`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jaxsocial
from jaxsocial.agents import policy_io, population
from jaxsocial.run import checkpoint, config, logs, rundir
from jaxsocial.run.config import TrainConfig
from jaxsocial.specs import CheckpointRef


def source_dirs(cfg: TrainConfig) -> list[Path]:
    """The source seed directory of each of the new run's seeds. FileNotFoundError if there is none."""
    run_dir = cfg.init_from.run
    if not run_dir.is_dir():
        raise FileNotFoundError(f"--init-from {cfg.init_from}: no directory {run_dir}")
    if rundir.checkpoints(run_dir).is_dir():
        return [run_dir] * cfg.seeds
    dirs = [run_dir / rundir.seed_name(seed) for seed in range(cfg.seed, cfg.seed + cfg.seeds)]
    missing = [str(d) for d in dirs if not rundir.checkpoints(d).is_dir()]
    if missing:
        raise FileNotFoundError(
            f"--init-from {cfg.init_from}: neither {run_dir} nor {missing} hold checkpoints; pass one seed's "
            "run directory (e.g. RUN_DIR/s0) or a run holding every seed of this one"
        )
    return dirs


def source_iteration(cfg: TrainConfig) -> int:
    """The checkpoint iteration the run starts from: the one asked for, or the latest every source has.
    FileNotFoundError if a source lacks it."""
    dirs = source_dirs(cfg)
    iteration = cfg.init_from.iteration
    steps = [set(checkpoint.all_steps(rundir.checkpoints(d))) for d in dirs]
    common = set.intersection(*steps)
    if iteration is None:
        if not common:
            raise FileNotFoundError(f"--init-from {cfg.init_from}: no checkpoint that every source seed has")
        return max(common)
    if iteration not in common:
        raise FileNotFoundError(
            f"--init-from {cfg.init_from}: no checkpoint of iteration {iteration} (checkpoints: "
            f"{sorted(common)})"
        )
    return iteration


def source_config(seed_dir: Path) -> TrainConfig:
    """The source seed's config, without its own `init_from` (a branch of a branch needs only its source)."""
    return dataclasses.replace(config.config_from_dict(logs.read_config(seed_dir)), init_from=None)


def _learners(cfg: TrainConfig) -> tuple[int, ...]:
    """The learner slots of a run's config."""
    _, env_params = jaxsocial.make(cfg.env, **cfg.env_overrides)
    return population.Population(population.run_slots(cfg.slots, env_params)).learners


def check(cfg: TrainConfig, learners: tuple[int, ...]) -> None:
    """Validate `cfg.init_from` for a run whose learners are in slots `learners` (nothing to check without
    it, or when the run resumes: it then loads its own state): the source exists, has the checkpoint, and
    has this run's network architecture and learner slots. ValueError or FileNotFoundError naming the
    difference; nothing is compiled."""
    if not cfg.init_from or cfg.resume:
        return
    source_iteration(cfg)
    for seed_dir in sorted(set(source_dirs(cfg))):
        source = source_config(seed_dir)
        theirs, ours = policy_io.architecture(source.net), policy_io.architecture(cfg.net)
        diff = sorted(k for k in ours if theirs.get(k) != ours[k])
        if diff:
            raise ValueError(
                f"--init-from {seed_dir}: its network differs in {diff} "
                f"({ {k: theirs.get(k) for k in diff} } there, { {k: ours[k] for k in diff} } here)"
            )
        if _learners(source) != learners:
            raise ValueError(
                f"--init-from {seed_dir}: its learners are in slots {_learners(source)}, this run's in "
                f"{learners}; the population layouts must match"
            )


def pin(cfg: TrainConfig, run_dir: str | Path) -> TrainConfig:
    """`cfg` with `init_from` at the iteration it will load (`RUN_DIR@ITERATION` in its config.json).
    ValueError if the new run directory `run_dir` is the source or holds it (--overwrite would delete it)."""
    if not cfg.init_from or cfg.resume:
        return cfg
    source = cfg.init_from.run
    new = Path(run_dir).resolve()
    if new == source.resolve() or new in source.resolve().parents:
        raise ValueError(f"--init-from {cfg.init_from}: the new run directory {run_dir} holds the source")
    return dataclasses.replace(cfg, init_from=CheckpointRef(source, source_iteration(cfg)))
