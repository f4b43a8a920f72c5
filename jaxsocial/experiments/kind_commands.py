"""The verbs of the design kinds that have no recipe (`catalogue.VERBS`): each kind's parser and `main`
(`<kind>_main`), which `python -m jaxsocial.experiments VERB NAME` hands a design of that kind to. Each
kind's parts are in the three layers: `plan.<kind>_design`, `launch.evaluation_play` or `launch.branch_runs`,
`analyse.<kind>_results`."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from jaxsocial.experiments.analyse import branch_results, evaluation_results, seed_status, verdicts
from jaxsocial.experiments.launch import branch_runs, evaluation_play, pinned, slurm
from jaxsocial.experiments.plan import branch_design, catalogue, evaluation_design, paths
from jaxsocial.run import jsonio


def design_parser(verbs: tuple[str, ...], module) -> argparse.ArgumentParser:
    """The options every design kind's verbs have: the verb, the design, where records and results are."""
    parser = argparse.ArgumentParser(prog="python -m jaxsocial.experiments", description=module.__doc__)
    parser.add_argument("action", choices=verbs)
    parser.add_argument("design", help="the design's name")
    parser.add_argument("--records", default=str(paths.RECORDS), help="root of the records")
    parser.add_argument("--science", default=str(paths.SCIENCE), help="where results and summaries go")
    return parser


def _own_verbs(kind: str) -> tuple[str, ...]:
    """The verbs of `kind` this module acts on: all but `power`, which `__main__` answers for every kind."""
    return tuple(v for v in catalogue.VERBS[kind] if v != "power")


def write_figure(summary: dict[str, Any], science: Path, draw: Callable) -> None:
    """`figure`: the summary `<science>/<design>.json`, its figure beside it, and the verdict printed."""
    stem = science / summary["design"]
    science.mkdir(parents=True, exist_ok=True)
    jsonio.write_json(stem.with_suffix(".json"), summary)
    draw(summary, stem.with_suffix(".png"))
    print(verdicts.verdict(summary))
    print(f"wrote {stem}.json and .png")


def evaluation_main(argv: list[str]) -> None:
    """`VERB NAME [options]` for the evaluation design NAME."""
    args = paths.parse_command(lambda: design_parser(_own_verbs("evaluation"), evaluation_design), argv)
    design = evaluation_design.EvaluationDesign.read(args.design)
    records_root, science = Path(args.records), Path(args.science)
    if args.action == "run":
        evaluation_play.run(design, records_root, science)
    elif args.action == "status":
        print(f"[{design.name}] plays written under {evaluation_design.out_dir(design, science)}")
        print("\n".join(seed_status.play_lines(design, records_root, science)))
    else:
        summary = evaluation_results.summarise(design, records_root, science)
        write_figure(summary, science, evaluation_results.draw)


def branch_parser() -> argparse.ArgumentParser:
    parser = design_parser(_own_verbs("branch"), branch_design)
    parser.add_argument("--runs-dir", default=str(paths.EXPERIMENT_RUNS), help="root of the run directories")
    parser.add_argument(
        "--cores", type=int, nargs="+", default=None, help="one training process a core (default: 0)"
    )
    parser.add_argument("--dry-run", action="store_true", help="print each branch's state and command")
    parser.add_argument(
        "--max-runs",
        type=pinned.positive_int,
        default=None,
        metavar="N",
        help="run: start only the first N pending branches (those that can end within a sitting)",
    )
    slurm.add_options(parser)
    parser.add_argument(
        "--interim", action="store_true", help="figure: summarise before every branch is recorded (unblinds)"
    )
    return parser


def branch_main(argv: list[str]) -> None:
    """`VERB NAME [options]` for the branch design NAME."""
    args = paths.parse_command(branch_parser, argv)
    try:
        design = branch_design.BranchDesign.read(args.design)
        records_root, runs_root, science = Path(args.records), Path(args.runs_dir), Path(args.science)
        if args.action == "run":
            launcher = slurm.chosen(args, default_cores=(0,))
            codes = branch_runs.run(design, runs_root, launcher, records_root, args.dry_run, args.max_runs)
            raise SystemExit(max((rc for rc in codes if rc is not None), default=0))
        elif args.action == "record":
            branch_runs.record(design, runs_root, records_root)
        elif args.action == "status":
            statuses = seed_status.branch_statuses(design, runs_root, records_root)
            seeds = seed_status.seed_ranges(list(design.seed_range))
            print(f"[{design.name}] branches by arm, source seeds {seeds}")
            print("\n".join(seed_status.status_lines(statuses, design.iterations)))
        else:
            recorded = branch_results.as_designed(design, records_root)
            if not recorded["every_branch_recorded"] and not args.interim:
                print(
                    f"[{design.name}] {recorded['recorded']} of {design.seeds * len(design.arms)} branches "
                    "recorded; the results stay blind until every branch is in (--interim shows them now)"
                )
                return
            summary = branch_results.summarise(design, records_root)
            write_figure(summary, science, branch_results.draw)
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from err
