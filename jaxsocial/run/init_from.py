"""`--init-from RUN_DIR[@ITERATION]`: start a new run from another run's learners.

The new run gets the source's learner params and optimiser state (Adam moments and step count) from its
checkpoint of ITERATION (default: the latest every source seed has). A source without checkpoints, such as a
record that kept only its exported policy, gives the params of its `policy/` export of ITERATION, and the
optimiser starts fresh (the new run's own initial state: Adam's zero moments and step 0, which do not depend
on the params); every source seed must be of one kind (`params_only`). Everything else is the new run's own:
fresh environments, LSTM states and random keys from its seed, its flags, stages and `--iterations`. Its
iteration counter starts at 0, so `--iterations N` trains N more iterations and stages are counted from the
branch point; the source and the iteration are in its `config.json` (`init_from`: `RUN_DIR@ITERATION`), so the
total training a learner has had is the source's ITERATION plus the new run's.

RUN_DIR is one seed's run directory (every seed of the new run starts from it) or a several-seed run
directory holding `s<seed>/` for each of the new run's seeds (each starts from its own). The network
architecture and the learner slots must be the source's (`check_source`, called by `jaxsocial.train.run`
before anything is written or compiled). A resumed run continues from its own checkpoints and ignores the
source. This module validates and names the source; the driver loads its learners
(`driver.load_source_learners`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxsocial.agents import population
from jaxsocial.agents.network_config import NetworkConfig
from jaxsocial.env import registry
from jaxsocial.run import checkpoint, config, policy_io, rundir
from jaxsocial.run.config import RunConfig, TrainConfig
from jaxsocial.specs import CheckpointRef


def _has_learners(seed_dir: Path) -> bool:
    """Whether `seed_dir` holds checkpoints or an exported policy."""
    return rundir.checkpoints(seed_dir).is_dir() or (seed_dir / rundir.POLICY_DIR).is_dir()


def _saved_steps(seed_dir: Path) -> set[int]:
    """The iterations a seed directory's learners can be loaded from: its checkpoints' or, without any, its
    policy exports'."""
    if rundir.checkpoints(seed_dir).is_dir():
        return set(checkpoint.all_steps(rundir.checkpoints(seed_dir)))
    return set(checkpoint.all_steps(seed_dir / rundir.POLICY_DIR))


def source_dirs(source: CheckpointRef, seeds: list[int]) -> list[Path]:
    """The seed directory of `source` each of the run's `seeds` starts from. FileNotFoundError if there is
    none."""
    run_dir = source.run
    if not run_dir.is_dir():
        raise FileNotFoundError(f"--init-from {source}: no directory {run_dir}")
    if _has_learners(run_dir):
        return [run_dir] * len(seeds)
    dirs = [run_dir / rundir.seed_name(seed) for seed in seeds]
    missing = [str(d) for d in dirs if not _has_learners(d)]
    if missing:
        raise FileNotFoundError(
            f"--init-from {source}: neither {run_dir} nor {missing} hold checkpoints or a policy; pass one "
            "seed's run directory (e.g. RUN_DIR/s0) or a run holding every seed of this one"
        )
    return dirs


def params_only(source: CheckpointRef, seeds: list[int]) -> bool:
    """Whether the run of `seeds` loads only params from `source` (its seeds hold a policy export and no
    checkpoints), with a fresh optimiser state. ValueError if some of its seeds hold checkpoints and some
    do not."""
    kinds = {not rundir.checkpoints(d).is_dir() for d in source_dirs(source, seeds)}
    if len(kinds) > 1:
        raise ValueError(f"--init-from {source}: some seeds hold checkpoints and some only a policy")
    return kinds.pop()


def source_iteration(source: CheckpointRef, seeds: list[int]) -> int:
    """The iteration the run of `seeds` starts from: `source.iteration`, or the latest every source seed
    has (checkpoints, or policy exports for a `params_only` source). FileNotFoundError if a source lacks
    it."""
    dirs = source_dirs(source, seeds)
    params_only(source, seeds)
    steps = [_saved_steps(d) for d in dirs]
    common = set.intersection(*steps)
    if source.iteration is None:
        if not common:
            raise FileNotFoundError(f"--init-from {source}: no checkpoint that every source seed has")
        return max(common)
    if source.iteration not in common:
        saved = "policy exports" if params_only(source, seeds) else "checkpoints"
        raise FileNotFoundError(
            f"--init-from {source}: no checkpoint of iteration {source.iteration} ({saved}: {sorted(common)})"
        )
    return source.iteration


def source_config(seed_dir: Path) -> TrainConfig:
    """The source seed's config, without its own `init_from` (a branch of a branch needs only its source)."""
    return dataclasses.replace(config.config_from_dict(rundir.read_config(seed_dir)), init_from=None)


def _learners(run: RunConfig) -> tuple[int, ...]:
    """The learner slots of a run."""
    _, env_params = registry.make(run.env, **dict(run.env_args))
    return population.Population(population.run_slots(run.slots, env_params)).learners


def check_source(
    source: CheckpointRef, seeds: list[int], net_cfg: NetworkConfig, learners: tuple[int, ...]
) -> None:
    """Validate `source` for a new run of `seeds` with the network `net_cfg` and its learners in slots
    `learners`: the source exists, has the checkpoint, and has this run's network architecture and learner
    slots. ValueError or FileNotFoundError naming the difference; nothing is compiled."""
    source_iteration(source, seeds)
    for seed_dir in sorted(set(source_dirs(source, seeds))):
        theirs_cfg = source_config(seed_dir)
        theirs, ours = policy_io.architecture(theirs_cfg.net), policy_io.architecture(net_cfg)
        diff = sorted(k for k in ours if theirs.get(k) != ours[k])
        if diff:
            raise ValueError(
                f"--init-from {seed_dir}: its network differs in {diff} "
                f"({ {k: theirs.get(k) for k in diff} } there, { {k: ours[k] for k in diff} } here)"
            )
        if _learners(theirs_cfg) != learners:
            raise ValueError(
                f"--init-from {seed_dir}: its learners are in slots {_learners(theirs_cfg)}, this run's in "
                f"{learners}; the population layouts must match"
            )


def pin_iteration(source: CheckpointRef, seeds: list[int], run_dir: str | Path) -> CheckpointRef:
    """`source` at the iteration the new run of `seeds` in `run_dir` will load (`RUN_DIR@ITERATION` in its
    config.json). ValueError if `run_dir` is the source or holds it (--overwrite would delete it)."""
    new = Path(run_dir).resolve()
    if new == source.run.resolve() or new in source.run.resolve().parents:
        raise ValueError(f"--init-from {source}: the new run directory {run_dir} holds the source")
    return CheckpointRef(source.run, source_iteration(source, seeds))
