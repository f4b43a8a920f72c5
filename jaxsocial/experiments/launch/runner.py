"""Run a recipe: train each condition that is not finished (resuming interrupted ones), then evaluate the
trained learners where the recipe asks (zero-shot transfer, the cultural-transmission protocol). Everything
lands in run directories; figures are drawn from them (`jaxsocial.experiments.analyse.summaries`)."""

from __future__ import annotations

import dataclasses
import os
import shlex
import sys
from pathlib import Path

from jaxsocial import train
from jaxsocial.experiments.analyse import kinds, run_times
from jaxsocial.experiments.analyse.rundirs import (
    LEFT_ALONE,
    PARTIAL,
    condition_seed_dirs,
    config_seed_dirs,
    finished,
    run_state,
)
from jaxsocial.experiments.launch import evaluation_play, pinned
from jaxsocial.experiments.plan import paths, prereg, recipes, xla_flags
from jaxsocial.experiments.plan.recipes import Recipe, Scale
from jaxsocial.run import checkout, provenance, rundir
from jaxsocial.run.config import TrainConfig
from jaxsocial.run.flags import config_flags
from jaxsocial.run.startup import setup

BLIND_SCORE = "written (blind until every seed is in)"
"""What `run` prints for a pre-registered design's evaluation in place of its score."""


class TrainingFailed(Exception):
    """A training process (`run` with a launcher) exited with an error."""


def run(
    recipe: Recipe,
    scale: Scale,
    seed: int,
    seeds: int,
    runs_dir: str,
    dry_run: bool = False,
    train_missing: bool = True,
    pick: tuple[str, ...] = (),
    launcher: pinned.Launcher | None = None,
    seeds_per_program: int | None = None,
    max_runs: int | None = None,
    allow_dirty: bool = False,
) -> None:
    """Train and evaluate what `recipe` needs at `scale` for seeds seed..seed+seeds-1 not finished yet.

    Every config is validated before anything trains, so a bad recipe fails at once. `dry_run` prints the
    commands and what is done instead. With `train_missing=False` nothing trains: the conditions already
    trained (e.g. on another machine) are evaluated and the others are skipped with a note; only seeds that
    logged every iteration are evaluated, so a design run over several sittings evaluates each seed once it
    has finished (e.g. `--no-train` at the end of a sitting). `pick`: see `rundirs.condition_seed_dirs`.
    With a `launcher` (`pinned.Cores`, `slurm.Slurm`: `slurm.chosen`), every seed trains as a one-seed
    program (`<condition>-s<k>-<k>`) in a single-core process of its own, pinned to one of the cores or as a
    one-CPU Slurm job, seed by seed (every condition of a seed before the next seed); `TrainingFailed` after
    they end if any failed; a dry run shows what the launcher would start (`show`).
    `seeds_per_program` K: each K consecutive seeds of a condition are one vmapped program
    (`<condition>-s<first>-<last>`, one directory per seed inside, recorded one record per seed), in a
    process of its own with a `launcher`, else in this one (default: a design's own at its scale,
    `designed_per_program`; else one a seed with a launcher, else all).
    `max_runs`: start only the first that many of the launcher's processes (`pinned.first_runs`).
    A design's runs at its own scale train and are evaluated blind (no return or score shown), with its
    `xla_flags` (ValueError if it has them and no `launcher` is given, unless this process's $XLA_FLAGS end
    in them: they must be set before XLA starts), and from a clean tree unless `allow_dirty` (`tree_checked`).
    """
    per_program = seeds_per_program or designed_per_program(recipe, scale) or (1 if launcher else None)
    programs, blind, design_flags = validated_programs(recipe, scale, seed, seeds, runs_dir, per_program)
    if design_flags and train_missing and launcher is None and not dry_run:
        xla_flags_held(recipe, design_flags)
    dirs = {c: condition_seed_dirs(scale, c, seed, seeds, runs_dir, pick) for c in programs}
    states = {(n, c.seed): program_state(c, dirs[n], seed) for n, cs in programs.items() for c in cs}
    if train_missing:
        to_train = [c for n, cs in programs.items() for c in cs if states[n, c.seed] not in LEFT_ALONE]
        tree_checked(recipe, blind, bool(to_train) and not dry_run, allow_dirty)
        print_cost(recipe, scale, to_train, launcher, max_runs)
    prefix = f"[{recipe.name}/{scale.name}]"
    jobs, skipped = train_programs(prefix, programs, states, dirs, seed, dry_run, train_missing, launcher)
    if jobs:
        launch(jobs, launcher, design_flags, max_runs, dry_run)
        dirs = {c: condition_seed_dirs(scale, c, seed, seeds, runs_dir, pick) for c in programs}
    for name in skipped:
        print(f"  {name}: not trained (--no-train); its unfinished seeds are not evaluated")
    if dry_run:
        return
    evaluate_finished(recipe, scale, dirs, blind)
    where = "" if runs_dir == str(paths.EXPERIMENT_RUNS) else f" --runs-dir {runs_dir}"
    figure = f"figure {recipe.name} --scale {scale.name} --seed {seed} --seeds {seeds}{where}"
    print(f"next: python -m jaxsocial.experiments {figure}   # the summary and figure, tests over seeds")


def designed_per_program(recipe: Recipe, scale: Scale) -> int | None:
    """The seeds a program of the recipe's design at its own scale (`seeds_per_program` of its file), so that
    its runs are planned as they train, with a launcher or without; None for a recipe without one."""
    if recipe.design is None or not scale.runs_subdir:
        return None
    return prereg.TrainingDesign.read(recipe.design).seeds_per_program


def program_state(cfg: TrainConfig, condition_dirs: list[Path], seed: int) -> str:
    """`rundirs.run_state` of the program `cfg` of a condition whose seeds from `seed` on have the directories
    `condition_dirs`: FINISHED where each of its seeds is, else TRAINING, PARTIAL or MISSING by its run
    directory."""
    held = condition_dirs[cfg.seed - seed : cfg.seed - seed + cfg.seeds]
    return run_state(rundir.run_path(cfg), cfg.iterations, held)


def validated_programs(
    recipe: Recipe, scale: Scale, seed: int, seeds: int, runs_dir: str, per_program: int | None
) -> tuple[dict[str, list[TrainConfig]], bool, str]:
    """Each condition's programs for seeds seed..seed+seeds-1 (`recipes.condition_programs`), every config
    validated (`setup`); whether they are blind (a design at its own scale: no return or score is shown),
    and the design's `xla_flags` then ('' otherwise)."""
    programs = {
        c: recipes.condition_programs(scale, c, seed, seeds, runs_dir, per_program) for c in recipe.conditions
    }
    blind = recipe.design is not None and bool(scale.runs_subdir)
    if blind:
        programs = {c: [dataclasses.replace(cfg, blind=True) for cfg in cfgs] for c, cfgs in programs.items()}
    for cfgs in programs.values():
        for cfg in cfgs:
            setup(cfg, load_frozen=False)
    design_flags = (prereg.TrainingDesign.read(recipe.design).xla_flags if blind else None) or ""
    return programs, blind, design_flags


def tree_checked(recipe: Recipe, blind: bool, training: bool, allow_dirty: bool) -> None:
    """Before anything trains (`training`): ValueError if the package's files differ from their commit
    (`checkout.tree`) and the runs are a pre-registered design's (`blind`), unless `allow_dirty`; a warning
    on stderr otherwise. Each run's process file records the commit and the diff either way."""
    tree = checkout.tree() if training else None
    if tree is None or not tree.dirty:
        return
    if blind and not allow_dirty:
        raise ValueError(
            f"refusing to train the pre-registered design {recipe.design} from a dirty tree: "
            f"{tree.describe()}. A design's runs come from a clean worktree at its commit "
            '(docs/experiments.md, "Pre-registration"): commit or stash the changes, or pass --allow-dirty '
            "to train anyway (each run's process file then says dirty and names the diff beside it). Nothing "
            "was trained"
        )
    print(
        f"warning: {tree.describe()}: each run records the commit and the diff beside its "
        f"{provenance.RUN_FILE}; commit before recording (docs/your-experiment.md)",
        file=sys.stderr,
    )


def xla_flags_held(recipe: Recipe, design_flags: str) -> None:
    """ValueError unless this process's $XLA_FLAGS end in the design's `design_flags`: training in this
    process needs them set before XLA starts."""
    if not xla_flags.hold(os.environ.get("XLA_FLAGS"), design_flags):
        raise ValueError(
            f"the design {recipe.design} trains with $XLA_FLAGS ending in {design_flags!r}: train with "
            "--cores (or --launcher slurm), or set them before starting this process"
        )


def seed_by_seed(jobs: list[tuple[int, pinned.Job]]) -> list[pinned.Job]:
    """The `jobs` (each with its first seed) seed by seed (a stable sort: conditions keep their order, so a
    sitting cut short leaves whole seeds done rather than one condition's)."""
    return [job for _, job in sorted(jobs, key=lambda pair: pair[0])]


def launch(
    jobs: list[tuple[int, pinned.Job]],
    launcher: pinned.Launcher,
    design_flags: str,
    max_runs: int | None,
    dry_run: bool = False,
) -> None:
    """Train the `jobs` (each with its first seed) with the `launcher`, seed by seed (`seed_by_seed`), only
    the first `max_runs`; TrainingFailed after they end if any failed (a job not waited for is not). A
    `dry_run` starts none and shows what the launcher would start (`show`)."""
    if dry_run:
        launcher.show(seed_by_seed(jobs)[:max_runs], design_flags)
        return
    ordered = pinned.first_runs(seed_by_seed(jobs), max_runs)
    codes = launcher.run(ordered, design_flags)
    failed = [job.label for job, rc in zip(ordered, codes, strict=True) if rc not in (0, None)]
    if failed:
        raise TrainingFailed(f"training failed for {', '.join(failed)}: see the logs beside their runs")


def print_cost(
    recipe: Recipe,
    scale: Scale,
    to_train: list[TrainConfig],
    launcher: pinned.Launcher | None,
    max_runs: int | None,
) -> None:
    """The cost line of the programs `to_train` (nothing if none), with the `launcher` (as many at once as its
    `slots`) or in this process, and with a launcher, what the first `max_runs` (None: all) take at the pace
    of the runs recorded in their folder (`run_times.recorded_pace`)."""
    if not to_train:
        return
    runs = sum(cfg.seeds for cfg in to_train)
    steps = to_train[0].iterations * to_train[0].num_envs * to_train[0].rollout_steps
    at_once = launcher.slots(runs) if launcher else 1
    estimate = recipes.cost(scale, runs, steps, at_once) or f"{runs} runs (no measured CPU rate)"
    mode = (
        "" if launcher else " (the rate is one seed a process, as --cores trains; in one process it differs)"
    )
    print(f"[{recipe.name}/{scale.name}] to train: {estimate}{mode}")
    recorded = paths.RECORDS / Path(to_train[0].run_name).parent
    starting = min(runs, max_runs or runs)
    pace = run_times.recorded_pace(recorded, starting, launcher.slots(starting)) if launcher else None
    if pace:
        print(f"[{recipe.name}/{scale.name}] at the pace of its records: {pace}")


def train_programs(
    prefix: str,
    programs: dict[str, list[TrainConfig]],
    states: dict[tuple[str, int], str],
    dirs: dict[str, list[Path]],
    seed: int,
    dry_run: bool,
    train_missing: bool,
    launcher: pinned.Launcher | None,
) -> tuple[list[tuple[int, pinned.Job]], list[str]]:
    """Say each program's state (and its command, `dry_run`) and, for those not finished: make it a job for
    the `launcher` (returned with its first seed, not started; in a dry run too), train it in this process
    (updating `dirs`), or, without `train_missing`, skip its condition (returned)."""
    skipped, jobs = [], []
    for name, cfgs in programs.items():
        for cfg in cfgs:
            state = states[name, cfg.seed]
            last = cfg.seed + cfg.seeds - 1
            label = name if len(cfgs) == 1 else f"{name} s{cfg.seed}" + (f"-{last}" if cfg.seeds > 1 else "")
            print(f"{prefix} {label}: {state}")
            flags = config_flags(cfg)
            if dry_run:
                print("  python -m jaxsocial.train " + shlex.join(flags))
            if state in LEFT_ALONE:
                continue
            if train_missing and launcher:
                jobs.append(
                    (cfg.seed, pinned.training_job(label, flags, rundir.run_path(cfg), state == PARTIAL))
                )
            elif dry_run:
                continue
            elif train_missing:
                train.run(dataclasses.replace(cfg, resume=state == PARTIAL))
                dirs[name][cfg.seed - seed : cfg.seed - seed + cfg.seeds] = config_seed_dirs(cfg)
            elif name not in skipped:
                skipped.append(name)
    return jobs, skipped


def evaluate_finished(recipe: Recipe, scale: Scale, dirs: dict[str, list[Path]], blind: bool) -> None:
    """Make what the recipe's kind evaluates of every seed in `dirs` that logged every iteration and lacks
    it; a blind design's scores are not shown."""
    for name, seed_dirs_ in dirs.items():
        for seed_dir in [d for d in seed_dirs_ if finished(d, scale.iterations)]:
            for evaluation, spec, out in kinds.evaluation_outputs(recipe, scale, seed_dir):
                if out.exists():
                    continue
                result = evaluation_play.evaluate_into(
                    out, seed_dir, spec, scale.eval_episodes, evaluation.protocol
                )
                shown = BLIND_SCORE if blind else f"{evaluation.score(result):.3f}"
                print(f"  {name} {seed_dir.name} in {spec} ({evaluation.protocol}): {shown}")
