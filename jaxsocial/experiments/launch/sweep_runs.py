"""The exploratory sweep's seeds trained (`run`: one process a core, `pinned`), continued into a longer
budget (`extend`) and recorded (`record`); the settings are `plan.sweep_settings`'."""

from __future__ import annotations

import shutil
from pathlib import Path

from jaxsocial.experiments.analyse import records, rundirs
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import paths
from jaxsocial.experiments.plan.sweep_settings import RECORDS_SUBDIR, Setting, run_dir, train_flags
from jaxsocial.run import provenance, rundir


def seed_state(setting: Setting, seed: int, runs_dir: str) -> str:
    """`rundirs.run_state` of a seed of `setting` (FINISHED also where it stopped early past the plateau)."""
    return rundirs.run_state(run_dir(setting, seed, runs_dir), setting.iterations)


def run(setting: Setting, seeds: list[int], runs_dir: str, cores: list[int]) -> list[int]:
    """Train `seeds` of `setting` that have not finished, each in its own process pinned to one of `cores`
    (`pinned.run`); an unfinished seed (a sitting stopped it, or `extend` started it) resumes from its latest
    checkpoint. Returns the exit codes of the processes run."""
    jobs = []
    for seed in seeds:
        state = seed_state(setting, seed, runs_dir)
        print(f"{setting.name} seed {seed}: {state}")
        if state not in rundirs.LEFT_ALONE:
            flags = train_flags(setting, seed, runs_dir)
            label = f"{setting.name} seed {seed}"
            jobs.append(
                pinned.training_job(label, flags, run_dir(setting, seed, runs_dir), state == rundirs.PARTIAL)
            )
    return pinned.run(jobs, cores) if jobs else []


def extend(shorter: Setting, setting: Setting, seeds: list[int], runs_dir: str) -> None:
    """Start each seed of `setting` as the continuation of its finished run in `shorter`, the same setting
    with a smaller budget (training has no schedule over iterations, so the continued run is the longer one,
    bit for bit on one CPU model): the shorter run's directory is copied under `setting`'s name, with its
    process file, which the record's provenance then lists under `earlier`. `run` trains the rest.
    ValueError, before anything is copied, if the settings differ otherwise, or a seed's shorter run is
    unfinished or stopped past the plateau, or its longer run exists."""
    if (shorter.condition, shorter.flags) != (setting.condition, setting.flags):
        raise ValueError(f"{setting.name} is not {shorter.name} with another budget: their flags differ")
    if shorter.iterations >= setting.iterations:
        raise ValueError(f"{shorter.name} has {shorter.iterations} iterations: not fewer than {setting.name}")
    pairs = [(run_dir(shorter, seed, runs_dir), run_dir(setting, seed, runs_dir)) for seed in seeds]
    for seed, (source, target) in zip(seeds, pairs, strict=True):
        if target.exists():
            raise ValueError(f"{target} exists: extend only starts a run")
        finished = seed_state(shorter, seed, runs_dir) == rundirs.FINISHED
        if not finished or not (source / provenance.RUN_FILE).is_file():
            raise ValueError(f"{source}: not a finished run of {shorter.name} by `run`; nothing to extend")
        if records.stopped_early(rundir.read_config(source), rundir.read_metrics(source)):
            raise ValueError(f"{source} stopped early past the plateau: nothing to extend")
    for seed, (source, target) in zip(seeds, pairs, strict=True):
        shutil.copytree(source, target)
        print(f"{setting.name} seed {seed}: starts from {source}")


def record(
    setting: Setting, seeds: list[int], runs_dir: str, device: str | None, records_root: Path = paths.RECORDS
) -> list[Path]:
    """Pack each seed's run directory that has no record yet into `records_root/sweep/<setting>/s<seed>`
    (`records.pack`), with its process's provenance: `device`, or where None the CPU its process measured,
    and the jax it trained with. Every seed is read first, so that a run not ended
    or failed (`pinned.run_provenance`) records none. Returns the records written."""
    packing = []
    for seed in seeds:
        source = run_dir(setting, seed, runs_dir)
        name = f"{RECORDS_SUBDIR}/{setting.name}/{rundir.seed_name(seed)}"
        if (records_root / name).exists():
            print(f"  {records_root / name}: already recorded, kept")
            continue
        run = pinned.run_provenance(source, device)
        packing.append((source, records_root / name, run, name))
    for source, target, run, name in packing:
        records.pack(source, target, run, name)
        print(f"recorded {source} -> {target}")
    return [target for _, target, _, _ in packing]
