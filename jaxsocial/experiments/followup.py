"""The follow-ups of a pre-registered design's learners that learned: exploratory measurements made after the
design's result, on every seed (of any condition) whose final return exceeds the design's threshold.

* **Zero-shot transfer (H2):** the seed's final policy, unchanged, alone in 3-goal Goal Cycle and beside
  experts in 4-goal Goal Cycle, Four Rooms and Maze (`zero_shot_specs`), `EVAL_EPISODES` episodes each.
* **Cultural transmission:** the CT score and recall (`evaluate --protocol ct`) in the scale's 3-goal Goal
  Cycle.
* **The paper's mixing test, by branching:** two runs from the seed's final checkpoint (params, optimiser
  state; `train --init-from`), for the same `BRANCH_FRACTION` of the design's iterations and the same seed,
  in 3-goal Goal Cycle beside the experts (`BRANCH_ENV`, a solo-trained seed too): one with every episode
  social, one with `MIXED_SOLO_PROB` of them solo (the paper's Fig. 6). Each is
  evaluated at its end alone in 3-goal Goal Cycle and beside experts in 4-goal, `EVAL_EPISODES` episodes
  each.

The branches need the final checkpoint, which records keep only where asked (`experiments record
--final-checkpoint learned`). Layout under `<runs_dir>/<scale>/followup-<design>/` (records mirror it):
``<condition>-s<seed>/eval/`` (the evaluations of the design's policy) and the branch runs
``<condition>-s<seed>-social/``, ``<condition>-s<seed>-mixed/``.

    python -m jaxsocial.experiments followup run h1_laptop --from benchmarks/results/records --cores 0 1
    python -m jaxsocial.experiments followup record h1_laptop --device "AMD EPYC, 2 cores"
    python -m jaxsocial.experiments followup figure h1_laptop
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial import stats
from jaxsocial.experiments.analyse import kinds, plot_figures, records, rundirs
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import conditions, paths, prereg, recipes
from jaxsocial.run import checkout, jsonio, metrics, provenance, rundir
from jaxsocial.run.config import TrainConfig
from jaxsocial.run.flags import config_flags
from jaxsocial.specs import CheckpointRef, EnvSpec

EVAL_EPISODES = 256
"""Episodes per evaluation (the issue asks for at least 256)."""
BRANCH_FRACTION = 0.25
"""The branches' length, as a fraction of the design's iterations (5.0M env-steps at the laptop scale)."""
MIXED_SOLO_PROB = 0.75
"""The share of solo episodes in the mixed branch (the paper's 75%)."""
ARMS = {"social": 0.0, "mixed": MIXED_SOLO_PROB}
"""Branch name -> its share of solo episodes."""
BRANCH_ENV = conditions.LEARNERS["social"]
"""Every branch trains beside the experts, whatever the source's condition: a seed that learned alone
(solo PPO + aux pred) meets them there for the first time."""


@dataclasses.dataclass(frozen=True)
class Source:
    """A design seed that learned: its condition, seed and run (or record) directory."""

    condition: str
    seed: int
    seed_dir: Path

    @property
    def name(self) -> str:
        """`<condition>-s<seed>`: the follow-ups' directory of this seed (`condition_of` reads it back)."""
        return f"{self.condition}-s{self.seed}"

    @staticmethod
    def condition_of(name: str) -> str:
        """The condition in a `name`."""
        return name.rsplit("-s", 1)[0]


@dataclasses.dataclass(frozen=True)
class Plan:
    """A design's follow-ups: the recipe that carries it, the scale it runs at and the design."""

    recipe: recipes.Recipe
    scale: recipes.Scale
    design: prereg.TrainingDesign
    episodes: int = EVAL_EPISODES
    """Episodes per evaluation."""

    @classmethod
    def of(cls, recipe_name: str) -> Plan:
        """The follow-ups of a recipe's design. ValueError if the recipe carries none."""
        recipe = recipes.RECIPES[recipe_name]
        if recipe.design is None:
            raise ValueError(f"recipe {recipe_name} carries no pre-registered design")
        design = prereg.TrainingDesign.read(recipe.design)
        return cls(recipe, prereg.recipe_scale(recipe, recipes.SCALES[design.scale]), design)

    def root(self, runs_dir: str | Path) -> Path:
        """Where the follow-ups go under a runs (or records) root."""
        return Path(runs_dir) / self.scale.name / f"followup-{self.design.name}"

    @property
    def branch_iterations(self) -> int:
        return max(1, round(self.design.iterations * BRANCH_FRACTION))


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


def zero_shot_specs(scale: recipes.Scale) -> list[str]:
    """The environments a learned policy is played in unchanged: alone in 3-goal Goal Cycle, beside the
    default experts in 4-goal Goal Cycle, Four Rooms and Maze (Goal Cycle with the scale's grid)."""
    names = ("goalcycle3-solo", "goalcycle4", "fourrooms", "maze")
    return [str(recipes.goalcycle_spec(name, scale)) for name in names]


def branch_specs(scale: recipes.Scale) -> list[str]:
    """The environments a branch is evaluated in at its end (the paper's Fig. 6)."""
    return zero_shot_specs(scale)[:2]


def arm_config(plan: Plan, source: Source, arm: str, runs_dir: str) -> TrainConfig:
    """The training config of one branch: the source's condition, beside the experts (`BRANCH_ENV`) with the
    arm's share of solo episodes, from the source's final checkpoint, evaluated at its end."""
    scale, iterations = plan.scale, plan.branch_iterations
    cfg = recipes.condition_config(scale, source.condition, source.seed, 1, runs_dir)
    return dataclasses.replace(
        cfg,
        env=BRANCH_ENV,
        env_args=recipes.with_env_args(cfg.env_args, (("solo_prob", ARMS[arm]),)),
        iterations=iterations,
        init_from=CheckpointRef(source.seed_dir),
        eval_envs=tuple(EnvSpec.parse(spec) for spec in branch_specs(scale)),
        eval_every=iterations,
        eval_episodes=plan.episodes,
        run_name=str(branch_dir(plan, source, arm, "")),
    )


def branch_dir(plan: Plan, source: Source, arm: str, runs_dir: str | Path) -> Path:
    """The run directory of one branch of a learned seed."""
    return plan.root(runs_dir) / f"{source.name}-{arm}"


def evaluate_source(plan: Plan, source: Source, out_dir: Path, command: str) -> None:
    """The zero-shot and cultural-transmission evaluations of a learned seed's final policy, into
    `out_dir/eval/` (those already there are kept), and how they were made (the process file, `provenance`:
    `command`)."""
    from jaxsocial.experiments.launch import runner  # JAX: imported to evaluate, not by a refusal

    scale, started, written = plan.scale, provenance.now(), False
    plays = [(spec, kinds.RETURNS) for spec in zero_shot_specs(scale)] + [(kinds.ct_spec(scale), kinds.CT)]
    for spec, evaluation in plays:
        path = evaluation.path(out_dir, spec, scale)
        if path.exists():
            continue
        result = runner.evaluate_into(path, source.seed_dir, spec, plan.episodes, evaluation.protocol)
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
            state = rundirs.branch_state(run_dir, plan.branch_iterations)
            print(f"  {source.name}-{arm}: {state}")
            if dry_run:
                print("    python -m jaxsocial.train " + " ".join(flags))
            elif state != rundirs.FINISHED:
                train_argv = pinned.train_command([*flags, *rundirs.resume_flags(state)])
                jobs.append(pinned.Job(f"{source.name}-{arm}", train_argv, run_dir))
    if dry_run:
        return []
    for source in found:
        evaluate_source(plan, source, plan.root(runs_dir) / source.name, command)
    return pinned.run(jobs, cores) if jobs else []


def record(plan: Plan, runs_dir: str, out_dir: str, device: str, jax_version: str) -> list[Path]:
    """Pack every finished follow-up under `runs_dir` into `out_dir` (the branches with `records.pack`, the
    evaluations with their provenance); those recorded already are kept. Everything is checked first."""
    source_root, target_root = plan.root(runs_dir), plan.root(out_dir)
    packing = []
    for directory in sorted(p for p in source_root.glob("*") if p.is_dir()):
        target = target_root / directory.name
        if target.exists():
            print(f"  {target}: already recorded, kept")
            continue
        run = pinned.run_provenance(directory, device, jax_version)
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


def _experts_return(result: dict[str, Any]) -> float | None:
    others = [r["mean_return"] for r in result["results"][1:] if r.get("episodes")]
    return float(np.mean(others)) if others else None


def summarise(plan: Plan, records_dir: str) -> dict[str, Any]:
    """Each learned seed's follow-ups (zero-shot returns, CT, the branches' evaluations) and, per measure,
    the mean over seeds (`measures`): over every learned seed, and over each condition's apart
    (`conditions`), since learners trained alone and beside the experts differ."""
    scale, base = plan.scale, plan.root(records_dir)
    seeds: dict[str, Any] = {}
    for eval_dir in sorted(base.glob(f"*/{rundir.EVAL_DIR}")):
        name, seed_dir = eval_dir.parent.name, eval_dir.parent
        results = {spec: jsonio.read_json(kinds.eval_path(seed_dir, spec)) for spec in zero_shot_specs(scale)}
        zero_shot = {
            spec: {"learner": kinds.RETURNS.score(r), "experts": _experts_return(r)}
            for spec, r in results.items()
        }
        ct = jsonio.read_json(kinds.ct_path(seed_dir, scale))
        branches = {}
        for arm in ARMS:
            rows = rundir.read_metrics(base / f"{name}-{arm}")
            branches[arm] = {
                spec: metrics.final_eval(rows, metrics.eval_key(spec)) for spec in branch_specs(scale)
            }
        seeds[name] = {
            "condition": Source.condition_of(name),
            "source": next(iter(results.values()))["checkpoints"][0],
            "zero_shot": zero_shot,
            "ct": {score: ct[score]["mean"] for score in kinds.CT_SCORES},
            "branches": branches,
        }
    learned = list(seeds.values())
    summary: dict[str, Any] = {
        "design": plan.design.name,
        "scale": scale.name,
        "exploratory": "follow-ups of the seeds that learned, chosen after the design's runs: no "
        "confirmatory test",
        "eval_episodes": plan.episodes,
        "branch_iterations": plan.branch_iterations,
        "mixed_solo_prob": MIXED_SOLO_PROB,
        "seeds": seeds,
    }
    if learned:
        summary.update(measures(learned, scale))
        summary["conditions"] = {}
        for condition in plan.recipe.conditions:
            group = [s for s in learned if s["condition"] == condition]
            if group:
                summary["conditions"][condition] = {"seeds": len(group), **measures(group, scale)}
    return summary


def measures(learned: list[dict[str, Any]], scale: recipes.Scale) -> dict[str, Any]:
    """Over some learned seeds (`summarise`'s entries): each zero-shot return's and CT score's mean and
    interval (`stats.summary`), and each branch evaluation's, with the paired mixed-minus-social
    difference."""
    return {
        "zero_shot": {
            spec: stats.summary([s["zero_shot"][spec]["learner"] for s in learned])
            for spec in zero_shot_specs(scale)
        },
        "ct": {score: stats.summary([s["ct"][score] for s in learned]) for score in kinds.CT_SCORES},
        "mixing": {
            spec: {
                **{arm: stats.summary([s["branches"][arm][spec] for s in learned]) for arm in ARMS},
                "mixed_minus_social": stats.paired_difference(
                    [s["branches"]["social"][spec] for s in learned],
                    [s["branches"]["mixed"][spec] for s in learned],
                ),
            }
            for spec in branch_specs(scale)
        },
    }


def _make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m jaxsocial.experiments followup", description=__doc__.split("\n")[0]
    )
    sub = parser.add_subparsers(dest="command", required=True)
    designed = sorted(r.name for r in recipes.RECIPES.values() if r.design)
    run_p = sub.add_parser("run", help="evaluate the learned seeds and train their branches")
    record_p = sub.add_parser("record", help="pack the finished follow-ups into records")
    figure_p = sub.add_parser("figure", help="the summary JSON and figure, from records")
    for p in (run_p, record_p, figure_p):
        p.add_argument("recipe", choices=designed)
    run_p.add_argument(
        "--from",
        dest="from_dir",
        default=str(paths.RECORDS),
        help="where the design's seeds are (records or runs)",
    )
    for p in (run_p, record_p):
        p.add_argument(
            "--runs-dir", default=str(paths.EXPERIMENT_RUNS), help="root of the follow-ups' run directories"
        )
    run_p.add_argument(
        "--cores", type=int, nargs="+", default=[0], help="cores for the branches, one process a core"
    )
    run_p.add_argument(
        "--dry-run", action="store_true", help="print the learned seeds and the branch commands"
    )
    record_p.add_argument("--out-dir", default=str(paths.RECORDS))
    record_p.add_argument("--device", required=True, help="the machine the follow-ups ran on, in words")
    figure_p.add_argument("--records-dir", default=str(paths.RECORDS))
    figure_p.add_argument("--out-dir", default=str(paths.SCIENCE))
    return parser


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    args = paths.parse_command(_make_parser, argv)
    try:
        plan = Plan.of(args.recipe)
        if args.command == "run":
            command = "python -m jaxsocial.experiments followup " + " ".join(argv)
            codes = run(plan, args.from_dir, args.runs_dir, args.cores, command, args.dry_run)
            sys.exit(max(codes, default=0))
        if args.command == "record":
            import jax

            record(plan, args.runs_dir, args.out_dir, args.device, jax.__version__)
            return
        summary = summarise(plan, args.records_dir)
        out = Path(args.out_dir) / f"followup-{summary['design']}-{summary['scale']}"
        out.parent.mkdir(parents=True, exist_ok=True)
        jsonio.write_json(out.with_suffix(".json"), summary)
        plot_figures.draw_followup(summary, out.with_suffix(".png"), tuple(ARMS), kinds.CT_SCORES)
        print(
            f"{len(summary['seeds'])} learned seeds; wrote {out.with_suffix('.json')} and "
            f"{out.with_suffix('.png')}"
        )
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from err
