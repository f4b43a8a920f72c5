"""A branch design's runs (`plan.branch_design`): every branch not finished trained, one single-core process a
branch (pinned to a core, or a one-CPU Slurm job: the launcher, `slurm.chosen`), and the finished ones
recorded."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxsocial.experiments.analyse import records, run_times, rundirs
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan.branch_design import BranchDesign
from jaxsocial.run import config, rundir
from jaxsocial.run.config import TrainConfig
from jaxsocial.run.flags import config_flags
from jaxsocial.specs import CheckpointRef, EnvSpec


def branch_config(
    design: BranchDesign, arm: str, seed: int, runs_root: Path, records_root: Path
) -> TrainConfig:
    """The training config of `arm`'s branch of source seed `seed`: the source record's own config in the
    arm's environment, from the record's policy, for the design's iterations with its branch seed, evaluated
    at its end, blind."""
    source = design.source_dir(arm, seed, records_root)
    cfg = config.config_from_dict(rundir.read_config(source))
    spec = EnvSpec.parse(design.arms[arm].env)
    return dataclasses.replace(
        cfg,
        env=spec.name,
        env_args=spec.args,
        iterations=design.iterations,
        seed=design.branch_seed + seed - design.seed,
        seeds=1,
        init_from=CheckpointRef(source),
        eval_envs=tuple(EnvSpec.parse(e) for e in design.eval_envs),
        eval_every=design.iterations,
        eval_episodes=design.episodes,
        run_name=design.run_name(arm, seed),
        runs_dir=str(runs_root),
        resume=False,
        overwrite=False,
        blind=True,
    )


def missing_sources(design: BranchDesign, records_root: Path) -> list[str]:
    """The design's source records that hold no final policy."""
    wanted = {design.source_dir(a, s, records_root) for a in design.arms for s in design.seed_range}
    return sorted(str(d) for d in wanted if not (d / rundir.POLICY_DIR).is_dir())


def run(
    design: BranchDesign,
    runs_root: Path,
    launcher: pinned.Launcher,
    records_root: Path,
    dry_run: bool = False,
    max_runs: int | None = None,
) -> list[int | None]:
    """Train every branch not finished yet, seed by seed (each source seed's arms before the next seed), one
    single-core process a branch with the `launcher` (`pinned.Cores`: one a core at a time); a begun branch
    resumes; only the first `max_runs` start (`pinned.first_runs`; a dry run shows what the launcher would
    start). Nothing starts if a source record is missing. Returns the exit codes of those started (None: not
    waited for)."""
    missing = missing_sources(design, records_root)
    if missing:
        raise FileNotFoundError(f"the design's material is incomplete: {', '.join(missing)}")
    states = (rundirs.FINISHED, rundirs.TRAINING, rundirs.PARTIAL, rundirs.MISSING)
    jobs, counts = [], dict.fromkeys(states, 0)
    for seed in design.seed_range:
        for arm in design.arms:
            cfg = branch_config(design, arm, seed, runs_root, records_root)
            run_dir = runs_root / cfg.run_name
            state = rundirs.run_state(run_dir, design.iterations)
            counts[state] += 1
            flags = config_flags(cfg)
            if dry_run:
                print(f"  {cfg.run_name}: {state}\n    python -m jaxsocial.train {' '.join(flags)}")
            if state not in rundirs.LEFT_ALONE:
                jobs.append(pinned.training_job(cfg.run_name, flags, run_dir, state == rundirs.PARTIAL))
    print(f"[{design.name}] branches: " + ", ".join(f"{n} {state}" for state, n in counts.items() if n))
    pending = counts[rundirs.PARTIAL] + counts[rundirs.MISSING]
    starting = min(pending, max_runs or pending)
    at_once = launcher.slots(starting)
    pace = run_times.recorded_pace(records_root / design.out, starting, at_once) if pending else None
    if pace:
        print(f"[{design.name}] at the pace of its records: {pace}")
    if dry_run and jobs:
        launcher.show(jobs[:max_runs], design.xla_flags)
    if dry_run or not jobs:
        return []
    return launcher.run(pinned.first_runs(jobs, max_runs), design.xla_flags)


def record(design: BranchDesign, runs_root: Path, records_root: Path) -> list[Path]:
    """Pack every finished branch under `runs_root` that has no record yet into the records root, with its
    process's provenance (the machine it measured); every one is checked before the first is written."""
    packing, not_started = [], 0
    for seed in design.seed_range:
        for arm in design.arms:
            name = design.run_name(arm, seed)
            run_dir, target = runs_root / name, records_root / name
            if target.exists():
                continue
            state = rundirs.run_state(run_dir, design.iterations)
            not_started += state == rundirs.MISSING
            if state in (rundirs.PARTIAL, rundirs.TRAINING):
                print(f"  {name}: not finished, not recorded")
            if state != rundirs.FINISHED:
                continue
            try:
                run_info = pinned.run_provenance(run_dir)
            except pinned.RunNotEnded as err:
                print(f"  {name}: {err}; not recorded")
                continue
            records.packable(run_dir)
            packing.append((run_dir, target, run_info, name))
    if not_started:
        print(f"  {not_started} branches not started under {runs_root}")
    for run_dir, target, run_info, name in packing:
        records.pack(run_dir, target, run_info, name)
        print(f"recorded {run_dir} -> {target}")
    return [target for _, target, _, _ in packing]
