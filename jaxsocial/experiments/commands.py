"""The verbs of `python -m jaxsocial.experiments` that train, read runs or records, or load a design:
imported by its `main` once the command line is accepted, since they import JAX, orbax and scipy (the
refusals of bad input come before them)."""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

from jaxsocial.experiments.analyse import records, rundirs, summaries, verdicts
from jaxsocial.experiments.launch import pinned, runner, slurm
from jaxsocial.experiments.plan import designs, paths, prereg, recipes
from jaxsocial.run import checkout, jsonio
from jaxsocial.run.metrics import LEARNED_RETURN, final_return


def act(args: argparse.Namespace) -> None:
    """The accepted command line `args` (`__main__.parse_args`) carried out: `power`, or a recipe command
    (`run`, `record`, `figure`); a refusal found on the way is a SystemExit naming it."""
    if args.command == "power":
        print(designs.load(args.design).describe())
        return
    recipe = recipes.RECIPES[args.recipe]
    scale = prereg.recipe_scale(recipe, recipes.SCALES[args.scale])
    try:
        if args.command == "run":
            runner.run(
                recipe,
                scale,
                args.seed,
                args.seeds,
                args.runs_dir,
                dry_run=args.dry_run,
                train_missing=not args.no_train,
                pick=tuple(args.pick),
                launcher=slurm.chosen(args),
                seeds_per_program=args.vmap_seeds,
                max_runs=args.max_runs,
                allow_dirty=args.allow_dirty,
            )
        elif args.command == "record":
            record(args, recipe, scale)
        else:
            figure(args, recipe, scale)
    except (ValueError, FileExistsError, FileNotFoundError, runner.TrainingFailed) as err:
        raise SystemExit(f"error: {err}") from err


def record(args: argparse.Namespace, recipe: recipes.Recipe, scale: recipes.Scale) -> None:
    """Pack every finished seed of the recipe that has no record yet (or every one, with --overwrite); seeds
    still training or not evaluated yet (the evaluations the recipe's kind asks for) are skipped with a note,
    and everything is checked before the first write. Unless --allow-dirty, a dirty tree here
    (`checkout.tree`) and runs whose process file says they trained from one are refused first."""
    tree = checkout.tree()
    if tree.dirty and not args.allow_dirty:
        raise ValueError(
            f"refusing to record from a dirty tree: {tree.describe()}, so a record made now would name a "
            'commit it may not be rebuilt from. Commit first (docs/your-experiment.md, "4. Record it"), or '
            "pass --allow-dirty to record anyway (each record then says packed_dirty). Nothing was recorded"
        )
    plan = record_plan(args, recipe, scale)
    dirty = [
        f"{seed_dir} ({', '.join(diffs)})"
        for seed_dir, _, run, _ in plan
        if (diffs := records.dirty_diffs(run))
    ]
    if dirty and not args.allow_dirty:
        raise ValueError(
            f"refusing to record runs trained from a dirty tree, whose process file names the diff that "
            f"rebuilds their code from its commit: {', '.join(dirty)}. Train them again from a commit, or "
            "pass --allow-dirty to record them with their diffs. Nothing was recorded"
        )
    for seed_dir, relative, run, reason in plan:
        record_dir = Path(args.out_dir) / relative
        if record_dir.exists() and any(record_dir.iterdir()) and not args.overwrite:
            print(f"  {record_dir}: already recorded, kept (--overwrite replaces it)")
            continue
        records.pack(seed_dir, record_dir, run, str(relative), args.overwrite, checkpoint_reason=reason)
        with_checkpoint = f", with its final checkpoint: {reason}" if reason else ""
        print(
            f"recorded {seed_dir} -> {record_dir} ({records.size_bytes(record_dir) / 1024:.0f} KiB"
            f"{with_checkpoint})"
        )


def record_plan(
    args: argparse.Namespace, recipe: recipes.Recipe, scale: recipes.Scale
) -> list[tuple[Path, Path, dict[str, Any], str | None]]:
    """What `record` packs: each finished and evaluated seed's directory, its path under --runs-dir, its
    run's provenance and why its final checkpoint goes in (None: it does not); each other seed is skipped
    with a note. ValueError for a run that failed or whose diff is missing or altered."""
    commands = records.read_commands_log(args.commands_log) if args.commands_log else None
    threshold = (
        prereg.TrainingDesign.read(recipe.design).learned_threshold if recipe.design else LEARNED_RETURN
    )
    plan = []
    for condition in recipe.conditions:
        for seed_dir in rundirs.condition_seed_dirs(
            scale, condition, args.seed, args.seeds, args.runs_dir, tuple(args.pick)
        ):
            planned = _record_seed(args, recipe, scale, condition, seed_dir, commands, threshold)
            if planned is not None:
                plan.append(planned)
    return plan


def _record_seed(
    args: argparse.Namespace,
    recipe: recipes.Recipe,
    scale: recipes.Scale,
    condition: str,
    seed_dir: Path,
    commands: dict[str, dict[str, Any]] | None,
    threshold: float,
) -> tuple[Path, Path, dict[str, Any], str | None] | None:
    """One seed of `record_plan` (None: skipped, with a note)."""
    if not seed_dir.is_dir():
        print(f"  {condition}: no run {seed_dir}, skipped")
        return None
    try:
        iteration, rows = records.packable(seed_dir)
    except (ValueError, FileNotFoundError) as err:  # still training, or stopped: not a result yet
        print(f"  {condition}: {err}; skipped")
        return None
    outputs = runner.evaluation_outputs(recipe, scale, seed_dir)
    unevaluated = [spec for _, spec, out in outputs if not out.exists()]
    if unevaluated:  # a record holds the seed's evaluations: `run --no-train` makes them
        print(f"  {condition}: {seed_dir} not evaluated yet in {', '.join(unevaluated)}; skipped")
        return None
    runs_dir = Path(args.runs_dir)
    relative = seed_dir.relative_to(runs_dir)
    one_of_several = re.fullmatch(r"s\d+", relative.name) and len(relative.parts) > 2
    run_name = relative.parent if one_of_several else relative
    if commands is None:
        try:
            run = pinned.run_provenance(runs_dir / run_name, args.device, args.jax)
        except FileNotFoundError as err:  # its command has not ended yet (or recorded no process file)
            print(f"  {condition}: {err}; skipped")
            return None
        run = pinned.with_measured(run, args.device, args.jax, seed_dir)
    else:
        run = records.logged_provenance(str(run_name), commands, args.device, args.jax)
    if run["rc"] not in (None, 0):
        raise ValueError(f"{seed_dir}: its command exited with {run['rc']}; not a result to record")
    records.tree_diffs(seed_dir, run)
    reason = records.checkpoint_reason(args.final_checkpoint, final_return(rows), threshold)
    if reason:
        records.require_checkpoint(seed_dir, iteration)
    return seed_dir, relative, run, reason


def figure(args: argparse.Namespace, recipe: recipes.Recipe, scale: recipes.Scale) -> None:
    """`figure`: the recipe's summary and figure (a design's stay blind until every seed is in, unless
    --interim), its outcome, how it compares with the committed summary, and a design's verdict."""
    runs = summaries.RecipeRuns(recipe, scale, args.seed, args.seeds, args.runs_dir, tuple(args.pick))
    blind = summaries.incomplete_design(runs)
    if blind and not args.interim:
        print(f"{blind}; its results stay blind until every seed is in (--interim shows them now)")
        return
    json_path, png_path = summaries.write(runs, args.out_dir)
    print(f"wrote {json_path}\nwrote {png_path}")
    summary = jsonio.read_json(json_path)
    print("\n".join(summaries.outcome_lines(summary)))
    committed = paths.SCIENCE / json_path.name
    if committed.is_file() and committed.resolve() != json_path.resolve():
        print(f"against the committed summary {committed}:")
        print(
            "\n".join(
                f"  {line}" for line in summaries.against_committed(summary, jsonio.read_json(committed))
            )
        )
    if recipe.design is not None:
        print(verdicts.verdict(summary))
