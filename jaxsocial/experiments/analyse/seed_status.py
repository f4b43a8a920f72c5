"""Where each seed of a design or recipe stands (`status`, the command `python -m jaxsocial.experiments status
NAME`): a training design's or recipe's seeds and a branch design's branches recorded, finished but not
recorded, training now, stopped partway, or not begun; an evaluation design's plays written or not. It reads
the records, run directories and results and writes nothing. It shows no return or score, only states and
iteration counts; where a design's runs stop at a return (`stop_at_return`), a run that finished early says
it took off."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxsocial.experiments.analyse import rundirs
from jaxsocial.experiments.plan import evaluation_design, recipes
from jaxsocial.experiments.plan.branch_design import BranchDesign
from jaxsocial.experiments.plan.evaluation_design import EvaluationDesign
from jaxsocial.run import rundir, runlock

RECORDED, TWICE, TO_RECORD, TRAINING, STOPPED, NOT_BEGUN = (
    "recorded",
    "recorded, yet training again (two results: keep one)",
    "finished, not recorded",
    rundirs.TRAINING,
    "stopped partway (run resumes it)",
    "not begun",
)
"""A seed's states, in the order `status_lines` reports them."""


@dataclasses.dataclass(frozen=True)
class SeedStatus:
    """One seed of a condition: its `state` and, where it is begun but not finished, the iterations logged."""

    condition: str
    seed: int
    state: str
    logged: int | None = None


def seed_statuses(
    recipe: recipes.Recipe,
    scale: recipes.Scale,
    seed: int,
    seeds: int,
    runs_dir: str,
    records_dir: str,
    pick: tuple[str, ...] = (),
) -> list[SeedStatus]:
    """The state of each seed seed..seed+seeds-1 of every condition of `recipe`: `RECORDED` where
    `records_dir` holds its record (`TWICE` where its run directory is training again beside it), else by its
    run directory under `runs_dir` (`rundirs.run_state`), the one that `condition_seed_dirs` names or, where
    that one is not begun, the one-seed program's `<condition>-s<k>-<k>` that `run --cores` trains."""
    out = []
    dirs = rundirs.records_beside_runs(scale, recipe.conditions, seed, seeds, runs_dir, records_dir, pick)
    for condition, k, record_dir, held in dirs:
        if rundir.has_metrics(record_dir):
            out.append(_recorded(condition, k, held))
            continue
        one_seed = Path(runs_dir) / recipes.condition_run_name(scale, condition, k, 1)
        status = _run_status(condition, k, held, scale.iterations)
        if status.state == NOT_BEGUN and one_seed != held:
            status = _run_status(condition, k, one_seed, scale.iterations)
        out.append(status)
    return out


def branch_statuses(design: BranchDesign, runs_root: Path, records_root: Path) -> list[SeedStatus]:
    """The state of each branch of `design` (its arm as the condition, its source seed as the seed):
    `RECORDED` where `records_root` holds it (`TWICE` where it trains again), else by its run directory under
    `runs_root`."""
    out = []
    for seed in design.seed_range:
        for arm in design.arms:
            name = design.run_name(arm, seed)
            if rundir.has_metrics(records_root / name):
                out.append(_recorded(arm, seed, runs_root / name))
            else:
                out.append(_run_status(arm, seed, runs_root / name, design.iterations))
    return out


def play_lines(design: EvaluationDesign, records_root: Path, science: Path) -> list[str]:
    """Per environment of an evaluation design, how many of its plays have a result under `science`, and the
    players still to play."""
    out = evaluation_design.out_dir(design, science)
    plays = evaluation_design.evaluations(design, records_root)
    lines = []
    for env in dict.fromkeys(p.env for p in plays):
        mine = [p for p in plays if p.env == env]
        left = [p.player for p in mine if not p.path(out).exists()]
        still = f"; to play: {', '.join(left)}" if left else ""
        lines.append(f"  {env}: {len(mine) - len(left)} of {len(mine)} played{still}")
    return lines


def _recorded(condition: str, seed: int, seed_dir: Path) -> SeedStatus:
    """A seed with a record: `RECORDED`, or `TWICE` where a live process trains its run directory again."""
    again = runlock.RunLock(rundirs.run_of(seed_dir)).live_holder() is not None
    return SeedStatus(condition, seed, TWICE if again else RECORDED)


def _run_status(condition: str, seed: int, seed_dir: Path, iterations: int) -> SeedStatus:
    """The state of a seed without a record, from its directory (`rundirs.run_state` of its run)."""
    state = rundirs.run_state(rundirs.run_of(seed_dir), iterations, [seed_dir])
    if state == rundirs.FINISHED:
        return SeedStatus(condition, seed, TO_RECORD)
    if state == rundirs.MISSING:
        return SeedStatus(condition, seed, NOT_BEGUN)
    logged = len(rundir.read_metrics(seed_dir)) if rundir.has_metrics(seed_dir) else 0
    return SeedStatus(condition, seed, TRAINING if state == TRAINING else STOPPED, logged)


def seed_ranges(numbers: list[int]) -> str:
    """Sorted whole numbers as ranges: [1, 2, 3, 5] -> '1-3, 5'."""
    ranges: list[list[int]] = []
    for n in sorted(numbers):
        if ranges and n == ranges[-1][1] + 1:
            ranges[-1][1] = n
        else:
            ranges.append([n, n])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in ranges)


def status_lines(statuses: list[SeedStatus], iterations: int) -> list[str]:
    """Per condition, how many seeds are in each state, with their seeds (and the iterations logged of each
    seed begun but not finished, of `iterations`)."""
    lines = []
    for condition in dict.fromkeys(s.condition for s in statuses):
        parts = []
        for state in (RECORDED, TWICE, TO_RECORD, TRAINING, STOPPED, NOT_BEGUN):
            mine = [s for s in statuses if s.condition == condition and s.state == state]
            if not mine:
                continue
            if state in (TRAINING, STOPPED):
                which = ", ".join(f"{s.seed}: {s.logged:,} of {iterations:,} iterations" for s in mine)
            else:
                which = seed_ranges([s.seed for s in mine])
            parts.append(f"{len(mine)} {state} ({which})")
        lines.append(f"  {condition}: " + "; ".join(parts))
    return lines
