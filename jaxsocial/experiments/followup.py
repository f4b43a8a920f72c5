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

This module is the command; the parts are in the three layers: `plan.followup_plan` (the seeds, arms and
environments), `launch.followup_runs` (evaluations, branches, records), `analyse.followup_results` (the
summary).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from jaxsocial.experiments.analyse import kinds, plot_figures
from jaxsocial.experiments.analyse.followup_results import summarise
from jaxsocial.experiments.launch.followup_runs import record, run
from jaxsocial.experiments.plan import paths, prereg, recipes
from jaxsocial.experiments.plan.followup_plan import ARMS, Plan
from jaxsocial.run import jsonio


def plan_of(recipe_name: str) -> Plan:
    """The follow-ups of a recipe's design. ValueError if the recipe carries none."""
    recipe = recipes.RECIPES[recipe_name]
    if recipe.design is None:
        raise ValueError(f"recipe {recipe_name} carries no pre-registered design")
    design = prereg.TrainingDesign.read(recipe.design)
    return Plan(recipe, prereg.recipe_scale(recipe, recipes.SCALES[design.scale]), design)


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
    record_p.add_argument(
        "--device",
        default=None,
        help="the machine they ran on, in words (default: what each process measured)",
    )
    figure_p.add_argument("--records-dir", default=str(paths.RECORDS))
    figure_p.add_argument("--out-dir", default=str(paths.SCIENCE))
    return parser


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    args = paths.parse_command(_make_parser, argv)
    try:
        plan = plan_of(args.recipe)
        if args.command == "run":
            command = "python -m jaxsocial.experiments followup " + " ".join(argv)
            codes = run(plan, args.from_dir, args.runs_dir, args.cores, command, args.dry_run)
            sys.exit(max(codes, default=0))
        if args.command == "record":
            record(plan, args.runs_dir, args.out_dir, args.device)
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
