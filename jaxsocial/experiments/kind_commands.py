"""The verbs of the design kinds that have no recipe (`catalogue.KINDS`), each kind's parser and `main`, which
`python -m jaxsocial.experiments VERB NAME` hands a design of that kind to (`__main__.KIND_COMMANDS`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from jaxsocial.experiments.analyse import evaluation_results
from jaxsocial.experiments.launch import evaluation_play
from jaxsocial.experiments.plan import evaluation_design, paths
from jaxsocial.run import logs

EVALUATION_VERBS = ("power", "run", "figure")
"""What `python -m jaxsocial.experiments VERB NAME` does to an evaluation design: its power, play what is
missing (blind), and its summary, tests and figure."""


def evaluation_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m jaxsocial.experiments", description=evaluation_design.__doc__
    )
    parser.add_argument("action", choices=EVALUATION_VERBS)
    parser.add_argument("design", help="an evaluation design (e.g. transfer)")
    parser.add_argument("--records", default=str(paths.RECORDS), help="root of the records")
    parser.add_argument("--science", default=str(paths.SCIENCE), help="where results and summaries go")
    return parser


def evaluation_main(argv: list[str]) -> None:
    """`VERB NAME [options]` for the evaluation design NAME."""
    args = paths.parse_command(evaluation_parser, argv)
    design = evaluation_design.load(args.design)
    records_root, science = Path(args.records), Path(args.science)
    if args.action == "power":
        print(evaluation_design.describe(design))
    elif args.action == "run":
        evaluation_play.run(design, records_root, science)
    else:
        summary = evaluation_results.summarise(design, records_root, science)
        logs.write_json(science / f"{design.name}.json", summary)
        evaluation_results.draw(summary, science / f"{design.name}.png")
        print(evaluation_results.verdict(summary))
        print(f"wrote {science / design.name}.json and .png")
