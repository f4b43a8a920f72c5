"""`python -m jaxsocial.experiments {list,run,figure} ...` (see `jaxsocial.experiments`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from jaxsocial.experiments import figures, recipes, runner

DEFAULT_OUT = "benchmarks/results/science"


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m jaxsocial.experiments", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the recipes, their conditions and the scales")
    for name, help_ in (("run", "train and evaluate what a recipe needs"), ("figure", "summarise and draw")):
        p = sub.add_parser(name, help=help_)
        p.add_argument("recipe", choices=sorted(recipes.RECIPES))
        p.add_argument("--scale", default="cpu", choices=sorted(recipes.SCALES))
        seeds_help = {
            "run": "seeds per condition, trained in one program",
            "figure": "seeds per condition, each read from whichever of the condition's runs holds it",
        }
        p.add_argument("--seeds", type=int, default=3, help=seeds_help[name])
        p.add_argument("--seed", type=int, default=0, help="first seed")
        p.add_argument("--runs-dir", default="runs/experiments", help="root of the run directories")
        if name == "run":
            p.add_argument("--dry-run", action="store_true", help="print the training commands and states")
            p.add_argument(
                "--no-train",
                action="store_true",
                help="train nothing: evaluate the conditions already trained (e.g. on another machine)",
            )
        else:
            p.add_argument("--out-dir", default=DEFAULT_OUT, help="where <recipe>-<scale>.json/.png go")
    args = parser.parse_args(argv)
    if args.command != "list" and args.seeds < 1:
        parser.error(f"--seeds {args.seeds} must be >= 1")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.command == "list":
        for r in recipes.RECIPES.values():
            print(f"{r.name:12s} {r.title}\n{'':12s} conditions: {', '.join(r.conditions)}")
        for s in recipes.SCALES.values():
            print(f"scale {s.name}: {s.iterations} iterations; {s.note}")
        return
    recipe, scale = recipes.RECIPES[args.recipe], recipes.SCALES[args.scale]
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
            )
        else:
            runs = figures.RecipeRuns(recipe, scale, args.seed, args.seeds, args.runs_dir)
            for path in figures.write(runs, Path(args.out_dir)):
                print(f"wrote {path}")
    except (ValueError, FileExistsError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from err


if __name__ == "__main__":
    main()
