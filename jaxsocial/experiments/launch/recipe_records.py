"""A recipe's finished seeds packed into records (`record`, the command `python -m jaxsocial.experiments
record NAME`): every seed checked first (finished, evaluated, its process ended well, its code rebuildable),
then each packed with its provenance and, where asked, its final checkpoint (`analyse.records.pack`)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

from jaxsocial.experiments.analyse import kinds, records, rundirs
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import prereg, recipes
from jaxsocial.run import checkout
from jaxsocial.run.metrics import LEARNED_RETURN, final_return

CHECKPOINT_CHOICES = ("learned", "all")
"""`record --final-checkpoint`: keep the final checkpoint of the seeds that learned, or of every seed."""


@dataclasses.dataclass(frozen=True)
class RecordOptions:
    """What `record` is asked for (the command's options of the same names)."""

    seed: int
    seeds: int
    runs_dir: str
    out_dir: str
    pick: tuple[str, ...] = ()
    commands_log: str | None = None
    """A log of '<ISO date> <commit> <command>' lines, for runs that trained elsewhere (default: each run's
    process file)."""
    device: str | None = None
    jax: str | None = None
    overwrite: bool = False
    allow_dirty: bool = False
    final_checkpoint: str | None = None
    """One of `CHECKPOINT_CHOICES`, or None: no final checkpoint is kept."""

    @classmethod
    def of(cls, namespace: Any) -> RecordOptions:
        """The options from a parsed command line that has them all (its `pick`, a list, as a tuple)."""
        found = {f.name: getattr(namespace, f.name) for f in dataclasses.fields(cls)}
        return cls(**found | {"pick": tuple(found["pick"])})


def record(recipe: recipes.Recipe, scale: recipes.Scale, options: RecordOptions) -> None:
    """Pack every finished seed of the recipe that has no record yet (or every one, with --overwrite); seeds
    still training or not evaluated yet (the evaluations the recipe's kind asks for) are skipped with a note,
    and everything is checked before the first write. Unless --allow-dirty, a dirty tree here
    (`checkout.tree`) and runs whose process file says they trained from one are refused first."""
    tree = checkout.tree()
    if tree.dirty and not options.allow_dirty:
        raise ValueError(
            f"refusing to record from a dirty tree: {tree.describe()}, so a record made now would name a "
            'commit it may not be rebuilt from. Commit first (docs/your-experiment.md, "4. Record it"), or '
            "pass --allow-dirty to record anyway (each record then says packed_dirty). Nothing was recorded"
        )
    plan = record_plan(recipe, scale, options)
    dirty = [
        f"{seed_dir} ({', '.join(diffs)})"
        for seed_dir, _, run, _ in plan
        if (diffs := records.dirty_diffs(run))
    ]
    if dirty and not options.allow_dirty:
        raise ValueError(
            f"refusing to record runs trained from a dirty tree, whose process file names the diff that "
            f"rebuilds their code from its commit: {', '.join(dirty)}. Train them again from a commit, or "
            "pass --allow-dirty to record them with their diffs. Nothing was recorded"
        )
    for seed_dir, relative, run, reason in plan:
        record_dir = Path(options.out_dir) / relative
        records.pack(seed_dir, record_dir, run, str(relative), options.overwrite, checkpoint_reason=reason)
        with_checkpoint = f", with its final checkpoint: {reason}" if reason else ""
        print(
            f"recorded {seed_dir} -> {record_dir} ({records.size_bytes(record_dir) / 1024:.0f} KiB"
            f"{with_checkpoint})"
        )


def record_plan(
    recipe: recipes.Recipe, scale: recipes.Scale, options: RecordOptions
) -> list[tuple[Path, Path, dict[str, Any], str | None]]:
    """What `record` packs: each finished and evaluated seed's directory, its path under --runs-dir, its
    run's provenance and why its final checkpoint goes in (None: it does not); each other seed is skipped
    with a note. ValueError for a run that failed or whose diff is missing or altered."""
    commands = records.read_commands_log(options.commands_log) if options.commands_log else None
    threshold = (
        prereg.TrainingDesign.read(recipe.design).learned_threshold if recipe.design else LEARNED_RETURN
    )
    plan = []
    for condition in recipe.conditions:
        for seed_dir in rundirs.condition_seed_dirs(
            scale, condition, options.seed, options.seeds, options.runs_dir, options.pick
        ):
            planned = _record_seed(options, recipe, scale, condition, seed_dir, commands, threshold)
            if planned is not None:
                plan.append(planned)
    return plan


def _record_seed(
    options: RecordOptions,
    recipe: recipes.Recipe,
    scale: recipes.Scale,
    condition: str,
    seed_dir: Path,
    commands: dict[str, dict[str, Any]] | None,
    threshold: float,
) -> tuple[Path, Path, dict[str, Any], str | None] | None:
    """One seed of `record_plan` (None: skipped, with a note: not there, restored, recorded already unless
    --overwrite, not finished or evaluated, or its process not ended)."""
    if not seed_dir.is_dir():
        print(f"  {condition}: no run {seed_dir}, skipped")
        return None
    if (seed_dir / rundirs.RESTORED_FILE).is_file():
        print(f"  {condition}: {seed_dir} was restored from its record, kept as it is")
        return None
    runs_dir = Path(options.runs_dir)
    relative = seed_dir.relative_to(runs_dir)
    record_dir = Path(options.out_dir) / relative
    if record_dir.exists() and any(record_dir.iterdir()) and not options.overwrite:
        print(f"  {record_dir}: already recorded, kept (--overwrite replaces it)")
        return None
    try:
        iteration, rows = records.packable(seed_dir)
    except (ValueError, FileNotFoundError) as err:  # still training, or stopped: not a result yet
        print(f"  {condition}: {err}; skipped")
        return None
    outputs = kinds.evaluation_outputs(recipe, scale, seed_dir)
    unevaluated = [spec for _, spec, out in outputs if not out.exists()]
    if unevaluated:  # a record holds the seed's evaluations: `run --no-train` makes them
        print(f"  {condition}: {seed_dir} not evaluated yet in {', '.join(unevaluated)}; skipped")
        return None
    one_of_several = re.fullmatch(r"s\d+", relative.name) and len(relative.parts) > 2
    run_name = relative.parent if one_of_several else relative
    if commands is None:
        try:
            run = pinned.run_provenance(runs_dir / run_name, options.device, options.jax)
        except FileNotFoundError as err:  # its command has not ended yet (or recorded no process file)
            print(f"  {condition}: {err}; skipped")
            return None
    else:
        run = records.logged_provenance(str(run_name), commands, options.device, options.jax)
    records.tree_diffs(seed_dir, run)
    reason = records.checkpoint_reason(options.final_checkpoint, final_return(rows), threshold)
    if reason:
        records.require_checkpoint(seed_dir, iteration)
    return seed_dir, relative, run, reason
