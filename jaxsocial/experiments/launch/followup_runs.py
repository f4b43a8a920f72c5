"""A design's follow-ups run: its learned seeds found (`sources`), their final policies played zero-shot
(`evaluate_source`), their branches trained one process a core (`run`), and everything recorded (`record`);
the plan is `plan.followup_plan`'s."""

from __future__ import annotations

import shutil
from pathlib import Path

from jaxsocial.experiments.analyse import kinds, records, rundirs
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan.followup_plan import (
    ARMS,
    Plan,
    Source,
    arm_config,
    branch_dir,
    zero_shot_specs,
)
from jaxsocial.run import checkout, jsonio, metrics, provenance, rundir
from jaxsocial.run.flags import config_flags


def sources(plan: Plan, from_dir: str) -> list[Source]:
    """Every finished design seed under `from_dir` (runs or records) whose final return exceeds the design's
    threshold, condition by condition. FileNotFoundError if one of them has no final checkpoint."""
    scale, design = plan.scale, plan.design
    out = []
    for condition in plan.recipe.conditions:
        dirs = rundirs.condition_seed_dirs(scale, condition, design.seed, design.seeds, from_dir)
        for seed, seed_dir in enumerate(dirs, start=design.seed):
            rows = rundir.read_metrics(seed_dir) if rundir.has_metrics(seed_dir) else []
            if len(rows) < design.iterations or metrics.final_return(rows) <= design.learned_threshold:
                continue
            try:
                records.packable(seed_dir, final_checkpoint=True)
            except FileNotFoundError as err:
                raise FileNotFoundError(
                    f"{err}: the seed learned and its branches start there (record it with `experiments "
                    "record --final-checkpoint learned`)"
                ) from err
            out.append(Source(condition, seed, seed_dir))
    return out


def evaluate_source(plan: Plan, source: Source, out_dir: Path, command: str) -> None:
    """The zero-shot and cultural-transmission evaluations of a learned seed's final policy, into
    `out_dir/eval/` (those already there are kept), and how they were made (the process file, `provenance`:
    `command`)."""
    from jaxsocial.experiments.launch import evaluation_play  # JAX: imported to evaluate, not by a refusal

    scale, started, written = plan.scale, provenance.now(), False
    plays = [(spec, kinds.RETURNS) for spec in zero_shot_specs(scale)] + [(kinds.ct_spec(scale), kinds.CT)]
    for spec, evaluation in plays:
        path = evaluation.path(out_dir, spec, scale)
        if path.exists():
            continue
        result = evaluation_play.evaluate_into(
            path, source.seed_dir, spec, plan.episodes, evaluation.protocol
        )
        written = True
        print(
            f"  {source.name} in {spec} ({evaluation.protocol}): {evaluation.score(result):.3f}", flush=True
        )
    if written:  # how they were made, as a training run's process records it
        provenance.write_run_file(out_dir, command, checkout.tree(), None, started, 0)


def run(
    plan: Plan, from_dir: str, runs_dir: str, cores: list[int], command: str, dry_run: bool = False
) -> list[int]:
    """Evaluate every learned seed (in this process; `command` is this one, for their provenance) and train
    its branches (one process per core, seed by seed); what has finished is kept, an interrupted branch
    resumes. Returns the branches' exit codes."""
    found = sources(plan, from_dir)
    names = ", ".join(s.name for s in found) or "none"
    print(f"[followup {plan.design.name}] {len(found)} learned seeds: {names}")
    jobs = []
    for source in found:
        for arm in ARMS:
            flags = config_flags(arm_config(plan, source, arm, runs_dir))
            run_dir = branch_dir(plan, source, arm, runs_dir)
            state = rundirs.run_state(run_dir, plan.branch_iterations)
            print(f"  {source.name}-{arm}: {state}")
            if dry_run:
                print("    python -m jaxsocial.train " + " ".join(flags))
            elif state not in rundirs.LEFT_ALONE:
                jobs.append(
                    pinned.training_job(f"{source.name}-{arm}", flags, run_dir, state == rundirs.PARTIAL)
                )
    if dry_run:
        return []
    for source in found:
        evaluate_source(plan, source, plan.root(runs_dir) / source.name, command)
    return pinned.run(jobs, cores) if jobs else []


def record(plan: Plan, runs_dir: str, out_dir: str, device: str | None) -> list[Path]:
    """Pack every finished follow-up under `runs_dir` into `out_dir` (the branches with `records.pack`, the
    evaluations with their provenance), each with `device` (None: the CPU its process measured) and the jax
    it ran with (`pinned.run_provenance`); those recorded already are kept. Everything is checked first."""
    source_root, target_root = plan.root(runs_dir), plan.root(out_dir)
    packing = []
    for directory in sorted(p for p in source_root.glob("*") if p.is_dir()):
        target = target_root / directory.name
        if target.exists():
            print(f"  {target}: already recorded, kept")
            continue
        run = pinned.run_provenance(directory, device)
        if (directory / rundir.CONFIG_FILE).is_file():
            records.packable(directory)
        elif not (directory / rundir.EVAL_DIR).is_dir():
            raise FileNotFoundError(f"{directory} is neither a branch run nor a seed's evaluations")
        packing.append((directory, target, run))
    for directory, target, run in packing:
        if (directory / rundir.CONFIG_FILE).is_file():
            records.pack(directory, target, run, str(directory.relative_to(runs_dir)))
        else:
            shutil.copytree(directory / rundir.EVAL_DIR, target / rundir.EVAL_DIR)
            jsonio.write_json(target / records.PROVENANCE_FILE, {"run": run})
        print(f"recorded {directory} -> {target}")
    return [target for _, target, _ in packing]
