"""What a training run will cost, said before it compiles (`estimate`): its iterations and env-steps and,
where a committed benchmark measured the rate of its settings, the time at that rate on the CPU it was
measured on.

A rate applies to a preset's settings unchanged (`MEASURED`): the preset's program (network, PPO, rollout,
one seed), environment and slots; the iterations may differ. The rates are read from the benchmark JSON
files of the repository (benchmarks/results); where none applies, or a checkout lacks the file, the line
says so instead of guessing.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from jaxsocial.run import rundir
from jaxsocial.run.config import PRESETS, TrainConfig

REPO = Path(__file__).resolve().parents[2]
LONG_S = 3600.0
"""A run projected longer than this is told the alternatives."""


@dataclasses.dataclass(frozen=True)
class Measured:
    """Where a preset's measured rate is: row `row` (the row whose `key` field is it; the HEAD tree's where
    rows compare trees) of section `section` of the benchmark JSON `path`."""

    path: str
    section: str
    key: str
    row: str


MEASURED = {
    "small": Measured("benchmarks/results/train_sps_train.json", "train", "preset", "small"),
    "paper": Measured("benchmarks/results/train_sps_train.json", "train", "preset", "paper"),
    "laptop": Measured("benchmarks/results/recipe_sps_laptop.json", "recipe", "recipe", "laptop_rec"),
}
"""The presets whose end-to-end training rate a committed benchmark measured (`benchmarks/train_sps.py
--sections train`, `benchmarks/recipe_sps.py`)."""


@dataclasses.dataclass(frozen=True)
class Rate:
    """A measured training rate: env-steps per second after compiling, the compile time, where it ran."""

    env_steps_per_s: float
    compile_s: float
    machine: str
    source: str


def read_rate(measured: Measured, repo: Path = REPO) -> Rate | None:
    """The rate `measured` points at, or None where the checkout lacks its file."""
    path = repo / measured.path
    if not path.is_file():
        return None
    data = json.loads(path.read_text())
    rows = [r for r in data["sections"][measured.section]["rows"] if r.get(measured.key) == measured.row]
    row = next(r for r in rows if r.get("tree", "HEAD") == "HEAD")
    compile_s = row["compile_s"]["full"] if isinstance(row["compile_s"], dict) else row["compile_s"]
    meta = data["metadata"]
    cores = "one core" if meta["args"].get("single_core") else f"{meta['cpu_count']} cores"
    return Rate(
        row["best_env_steps_per_s"],
        compile_s,
        f"{cores} of an {meta['cpu_model']}",
        f"{measured.path}: {measured.row}",
    )


def measured_for(cfg: TrainConfig) -> Measured | None:
    """The measurement that applies to `cfg`: its preset's, if `cfg` keeps the preset's settings (all but
    the iterations and what only the driver does); None otherwise."""
    if cfg.preset not in MEASURED:
        return None
    # the preset's network takes its environment's observations, as `cfg`'s does (`startup.setup` checks)
    preset = PRESETS[cfg.preset]
    preset = dataclasses.replace(preset, net=dataclasses.replace(preset.net, obs=cfg.net.obs))
    same = (cfg.program, cfg.env, cfg.env_args, cfg.slots, cfg.stages) == (
        preset.program,
        preset.env,
        preset.env_args,
        preset.slots,
        preset.stages,
    )
    return MEASURED[cfg.preset] if same else None


def duration(seconds: float) -> str:
    """'40 s', '12 min', '3.5 hours', '4.2 days'."""
    if seconds < 100:
        return f"{seconds:.0f} s"
    if seconds < 6000:
        return f"{seconds / 60:.0f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.1f} hours"
    return f"{seconds / 86400:.1f} days"


def trained_iterations(cfg: TrainConfig, run_dir: Path) -> int:
    """The iterations a run resumed from `run_dir` has trained: its first seed's latest checkpoint (0 for a
    new run, or one that saved none)."""
    from jaxsocial.run import checkpoint  # orbax and JAX: not imported by those that only read rates

    first = rundir.checkpoints(rundir.seed_dirs(run_dir, cfg.seed, cfg.seeds)[0])
    return (checkpoint.latest_step(first) or 0) if cfg.resume and first.is_dir() else 0


def estimate(cfg: TrainConfig, trained: int = 0, repo: Path = REPO) -> str:
    """The cost line a run prints before it compiles (see the module docstring), for the iterations left
    after `trained`."""
    per_iteration = cfg.num_envs * cfg.rollout_steps * cfg.seeds
    left = cfg.iterations - trained
    steps = left * per_iteration
    resumed = f" (of {cfg.iterations:,}: {trained:,} done)" if trained else ""
    head = f"cost: {left:,} iterations{resumed} x {per_iteration:,} env-steps = {steps:,} env-steps"
    measured = measured_for(cfg)
    rate = None if measured is None else read_rate(measured, repo)
    if rate is None:
        why = (
            f"this checkout lacks {measured.path}"
            if measured
            else f"no committed benchmark measured these settings (only the {', '.join(MEASURED)} presets "
            "unchanged)"
        )
        return f"{head}; no time estimate: {why}. The progress line gives the rate once it runs"
    seconds = steps / rate.env_steps_per_s + rate.compile_s
    line = (
        f"{head}: about {duration(seconds)} at {rate.env_steps_per_s:,.0f} env-steps/s, the rate "
        f"of the {cfg.preset} preset on {rate.machine} ({rate.source}); another machine's differs"
    )
    if seconds > LONG_S:
        line += (
            "\nthat is over an hour: for a first look use a smaller preset (--preset small or laptop: "
            "minutes on a CPU) or fewer --iterations, or train on a GPU"
        )
    return line
