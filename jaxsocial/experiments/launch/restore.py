"""A recipe's committed records copied back into run directories (`restore`, the command `python -m
jaxsocial.experiments restore NAME`), so that on a fresh machine the runner counts the recorded seeds finished
and trains only the rest.

A record reads like a run directory (`rundir.read_metrics` reads its gzipped metrics), and the records mirror
the run directories, so a record goes back to the path it was packed from. A design's runs come from a
worktree at the design's commit, which holds none of the records committed since: `restore` runs from main
with `--runs-dir` pointing into that worktree. Each restored directory holds `rundirs.RESTORED_FILE`, which
`record` reads to leave it alone: its record is already committed."""

from __future__ import annotations

import shutil
from pathlib import Path

from jaxsocial.experiments.analyse import rundirs
from jaxsocial.experiments.plan import recipes
from jaxsocial.run import checkout, jsonio, provenance, rundir


def into_run_dirs(
    recipe: recipes.Recipe,
    scale: recipes.Scale,
    seed: int,
    seeds: int,
    runs_dir: str,
    records_dir: str,
    pick: tuple[str, ...] = (),
) -> list[Path]:
    """Copy the record of each seed seed..seed+seeds-1 of every condition from `records_dir` to its run
    directory under `runs_dir`, and return the directories written. A seed with no record is left to train; a
    seed whose directory is there already is kept. ValueError, before anything is copied, where a seed with a
    record has begun training again without finishing: that run and its record would be two results."""
    planned = []
    dirs = rundirs.records_beside_runs(scale, recipe.conditions, seed, seeds, runs_dir, records_dir, pick)
    for _, _, record_dir, held in dirs:
        if not rundir.has_metrics(record_dir):
            continue
        seed_dir = Path(runs_dir) / record_dir.relative_to(records_dir)
        if not seed_dir.exists() and not rundir.has_metrics(held):
            planned.append((record_dir, seed_dir))
        elif (seed_dir / rundirs.RESTORED_FILE).is_file() or _logged_as_much(held, record_dir):
            print(f"  {held}: there already, kept")
        else:
            raise ValueError(
                f"{held} has begun training again while {record_dir} records it: keep one of the two "
                "(remove the run directory to restore the record). Nothing was restored"
            )
    commit = checkout.head_commit()
    for record_dir, seed_dir in planned:
        shutil.copytree(record_dir, seed_dir)
        jsonio.write_json(
            seed_dir / rundirs.RESTORED_FILE,
            {"record": str(record_dir), "commit": commit, "restored": provenance.now()},
        )
        print(f"restored {record_dir} -> {seed_dir}")
    print(f"{len(planned)} record(s) restored into {runs_dir}; `run` counts them finished")
    return [seed_dir for _, seed_dir in planned]


def _logged_as_much(seed_dir: Path, record_dir: Path) -> bool:
    """Whether the run in `seed_dir` logged as many iterations as its record (the run the record was packed
    from, on the machine that trained it)."""
    logged = len(rundir.read_metrics(seed_dir)) if rundir.has_metrics(seed_dir) else 0
    return logged >= len(rundir.read_metrics(record_dir))
