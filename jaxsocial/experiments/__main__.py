"""`python -m jaxsocial.experiments VERB NAME ...`: recipes, designs of every kind, records and the commands
of the modules beside it (`DELEGATED`); see `jaxsocial.experiments`. NAME is a recipe or a design; a
design's kind comes from its file (`catalogue`): a training design is its recipe's, an evaluation or branch
design goes to its kind's command (`kind_commands`)."""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

from jaxsocial.experiments.analyse import seed_status, summaries, verdicts
from jaxsocial.experiments.launch import pinned, recipe_records, slurm, verify
from jaxsocial.experiments.plan import catalogue, designs, paths, prereg, recipes, sweep_settings
from jaxsocial.run import jsonio, provenance, rundir
from jaxsocial.run.metrics import LEARNED_RETURN

RECIPE_COMMANDS = {
    "run": "train and evaluate what a recipe needs",
    "figure": "summarise and draw",
    "record": "pack a recipe's run directories into records (config, metrics, final policy, evaluations)",
    "restore": "copy a recipe's committed records back into its run directories, so `run` trains only the "
    "seeds not recorded (a fresh machine, or a worktree at a design's commit)",
    "status": "where each seed stands: recorded, finished but not recorded, training now, stopped partway or "
    "not begun (states and iteration counts, no returns)",
}
"""The subcommands that act on a recipe's conditions and seeds, and their help."""


def _make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m jaxsocial.experiments", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the recipes, their conditions and the scales")
    options = {
        "run": _run_options,
        "figure": _figure_options,
        "record": _record_options,
        "restore": _records_option,
        "status": _records_option,
    }
    for name, help_ in RECIPE_COMMANDS.items():
        options[name](_recipe_parser(sub, name, help_))
    for name, (_, help_) in DELEGATED.items():
        sub.add_parser(name, help=help_ + f" (python -m jaxsocial.experiments {name} --help)", add_help=False)
    power = "a pre-registered design of any kind: its tests and its power"
    p = sub.add_parser("power", help=power, description=power)
    p.add_argument(
        "design",
        choices=catalogue.design_names(),
        metavar="DESIGN",
        help=f"designs of every kind: {catalogue.design_names()}",
    )
    _verify_parser(sub)
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line, after `--results DIR` is read, checked, with the committed results found."""
    return paths.parse_command(_make_parser, argv, check_args)


def check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The combinations of options the parser cannot refuse alone, each through `parser.error`."""
    if args.command == "verify" and args.iterations is not None and args.iterations < 1:
        parser.error(f"--iterations {args.iterations} must be >= 1")
    if args.command in RECIPE_COMMANDS:
        _seed_range(parser, args)
    if args.command == "record" and args.commands_log and None in (args.device, args.jax):
        parser.error("--commands-log: give --device and --jax, what its runs trained on (not measured here)")


def _recipe_parser(sub, name: str, help_: str) -> argparse.ArgumentParser:
    """The subcommand `name` with the options every recipe command has: the recipe, scale, seeds, runs."""
    p = sub.add_parser(name, help=help_)
    p.add_argument("recipe", choices=sorted(recipes.RECIPES), metavar="NAME", help=f"{_names_help()}")
    p.add_argument("--scale", default="cpu", choices=sorted(recipes.SCALES))
    seeds_help = {
        "run": "seeds per condition, trained in one program",
        "figure": "seeds per condition, each read from whichever of the condition's runs holds it",
        "record": "seeds per condition to pack (those without metrics are skipped)",
        "restore": "seeds per condition to restore (those without a record are left to train)",
        "status": "seeds per condition to report",
    }
    p.add_argument(
        "--seeds", type=int, default=None, help=seeds_help[name] + " (default 3, or the recipe's design)"
    )
    p.add_argument("--seed", type=int, default=None, help="first seed (default 0, or the recipe's design)")
    p.add_argument("--runs-dir", default=str(paths.EXPERIMENT_RUNS), help="root of the run directories")
    p.add_argument(
        "--pick",
        action="append",
        default=[],
        metavar="RUN",
        help="the run to read a seed from when several runs of its condition hold it (a run directory "
        "name, e.g. social_rec-s0-5; repeatable)",
    )
    return p


def _run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dry-run", action="store_true", help="print the training commands and states")
    p.add_argument(
        "--no-train",
        action="store_true",
        help="train nothing: evaluate the conditions already trained (e.g. on another machine)",
    )
    p.add_argument(
        "--cores",
        type=int,
        nargs="+",
        default=[],
        metavar="CORE",
        help="train every seed as a one-seed program in its own single-threaded process pinned to "
        "one of these CPU cores, one per core at a time (e.g. --cores 0 1; default: in this process, each "
        "condition's seeds in one program, or as many a program as a design says)",
    )
    p.add_argument(
        "--vmap-seeds",
        type=int,
        default=None,
        metavar="K",
        help="train each K consecutive seeds of a condition as one vmapped program, one record per "
        "seed as before (a GPU's way; a design fixes its own, `seeds_per_program`)",
    )
    p.add_argument(
        "--max-runs",
        type=pinned.positive_int,
        default=None,
        metavar="N",
        help="with --cores or --launcher slurm: start only the first N pending runs, seed by seed (those "
        "that can end within a sitting); a later call resumes from the rest",
    )
    p.add_argument(
        "--allow-dirty",
        action="store_true",
        help="train a pre-registered design's runs although jaxsocial/ differs from its commit (refused "
        "otherwise; every run records the commit and the diff that rebuilds its code either way)",
    )
    slurm.add_options(p)


def _figure_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out-dir", default=str(paths.FIGURES), help="where <recipe>-<scale>.json/.png go")
    p.add_argument(
        "--interim",
        action="store_true",
        help="summarise a pre-registered design before every seed is in (by default its results stay "
        "blind until then: figure says how many runs are in and writes nothing)",
    )


def _record_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out-dir", default=str(paths.RECORDS_OUT), help="root of the records (mirrors --runs-dir)"
    )
    p.add_argument(
        "--commands-log",
        default=None,
        help="log of the training commands: '<ISO date> <commit> <command with --run-name>' lines "
        f"(default: each run's {provenance.RUN_FILE}, which every training process writes)",
    )
    p.add_argument(
        "--device",
        default=None,
        help="the device the runs trained on, in words (default: the CPU each run's process file "
        f"measured, {provenance.RUN_FILE}; required with --commands-log, whose runs trained elsewhere)",
    )
    p.add_argument(
        "--jax",
        default=None,
        help="the jax version the runs trained with (default: the version each run's process file "
        "recorded; required with --commands-log)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace existing records")
    p.add_argument(
        "--allow-dirty",
        action="store_true",
        help="record although jaxsocial/ differs from its commit here, or the runs trained from such a tree "
        "(refused otherwise); their records carry the diffs that rebuild the code",
    )
    p.add_argument(
        "--final-checkpoint",
        choices=recipe_records.CHECKPOINT_CHOICES,
        default=None,
        help="also keep the final checkpoint (params and optimiser state) of the seeds that learned "
        f"(final return > the design's threshold, else {LEARNED_RETURN:g}) or of all, so later "
        "sittings can branch from the records (default: none)",
    )


def _records_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--records",
        default=str(paths.RECORDS),
        help="root of the records to read (default: the committed ones; mirrors --runs-dir)",
    )


def _verify_parser(sub) -> None:
    p = sub.add_parser(
        "verify", help="re-train a record's first iterations and compare its metrics rows (timings aside)"
    )
    p.add_argument("record", help="a record (or run) directory of one seed")
    p.add_argument(
        "--iterations",
        type=int,
        default=None,
        help=f"iterations to re-train (default: {verify.DEFAULT_ITERATIONS}, or the record's rows if fewer)",
    )
    p.add_argument("--out", default=None, help="also write the result as JSON here (never into the record)")


def _seed_range(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Fill --seed and --seeds: the defaults, or a design's own (which may not be changed at its scale)."""
    recipe = recipes.RECIPES[args.recipe]
    design = prereg.TrainingDesign.read(recipe.design) if recipe.design else None
    if design is not None and design.scale == args.scale:
        given = {"--seed": (args.seed, design.seed), "--seeds": (args.seeds, design.seeds)}
        for flag, (value, designed) in given.items():
            if value is not None and value != designed:
                parser.error(f"{flag} {value}: the pre-registered design {design.name} fixes {designed}")
        args.seed, args.seeds = design.seed, design.seeds
        stated = design.seeds_per_program
        given = getattr(args, "vmap_seeds", None)
        if stated is not None and given is not None and given != stated:
            parser.error(
                f"--vmap-seeds {given}: the pre-registered design {design.name} runs {stated} seed(s) a "
                "program"
            )
    args.seed = 0 if args.seed is None else args.seed
    args.seeds = 3 if args.seeds is None else args.seeds
    if args.seeds < 1:
        parser.error(f"--seeds {args.seeds} must be >= 1")
    if getattr(args, "vmap_seeds", None) is not None and args.vmap_seeds < 1:
        parser.error(f"--vmap-seeds {args.vmap_seeds} must be >= 1")


def run_verify(args: argparse.Namespace) -> None:
    """`verify`: checked before anything trains (the record, the --out file), then re-trained and reported."""
    out = Path(args.out) if args.out else None
    if out is not None and out.exists():
        raise SystemExit(f"error: {out} exists; choose another --out")
    if out is not None and out.resolve().is_relative_to(Path(args.record).resolve()):
        raise SystemExit(f"error: --out {out} is inside the record; verify writes nothing there")
    if out is not None:  # its folder, made before anything trains: one that cannot be made fails now
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise SystemExit(f"error: --out {out}: cannot make its folder ({err.strerror or err})") from err
    record_dir = Path(args.record)
    try:
        iterations = args.iterations or min(verify.DEFAULT_ITERATIONS, len(rundir.read_metrics(record_dir)))
        result = verify.verify(record_dir, iterations)
    except (ValueError, FileNotFoundError, RuntimeError) as err:
        raise SystemExit(f"error: {err}") from err
    print(verify.report(result))
    if out is not None:
        jsonio.write_json(out, result)
        print(f"wrote {out}")


DELEGATED = {
    "sweep": ("jaxsocial.experiments.sweep", "the exploratory sweep and the map"),
    "followup": ("jaxsocial.experiments.followup", "a design's learned seeds followed up"),
    "pooled": ("jaxsocial.experiments.analyse.takeoff_power", "the pooled laptop seeds' summary"),
    "inflight": ("jaxsocial.experiments.launch.inflight", "a GPU design's resume state slimmed for git"),
}
"""Commands with a module of their own, reached only through this one: `experiments sweep ARGS` is
`jaxsocial.experiments.sweep.main(ARGS)`."""


SWEEP_VERBS = ("run", "record")
"""What `python -m jaxsocial.experiments VERB SETTING` does to a sweep setting: train its seeds, or record
them (`experiments sweep VERB SETTING`); the sweep's summary and map are `experiments sweep figure` and
`map`."""


def _names_help() -> str:
    """The names a recipe command takes: the recipes, and the designs of the other kinds, with their verbs."""
    others = [
        f"{kind} designs ({', '.join(verbs)}): {', '.join(catalogue.design_names(kind))}"
        for kind, verbs in catalogue.VERBS.items()
    ]
    sweep = f"sweep settings ({', '.join(SWEEP_VERBS)}): {len(sweep_settings.SETTINGS)}, see `sweep list`"
    return f"a recipe ({', '.join(recipes.RECIPES)}); {'; '.join(others)}; {sweep}"


def kind_command(argv: list[str]):
    """The `main` that acts on the design `VERB NAME ...` names, where it is of a kind with verbs of its own
    (`catalogue.VERBS`), or on the sweep setting it names (`sweep.main`, `SWEEP_VERBS`); None otherwise.
    Imported only then; SystemExit where VERB is not one of the kind's."""
    if len(argv) >= 2 and argv[1] in sweep_settings.SETTINGS:
        if argv[0] not in SWEEP_VERBS:
            raise SystemExit(
                f"error: {argv[0]} {argv[1]}: the sweep setting {argv[1]} takes {', '.join(SWEEP_VERBS)}"
            )
        return importlib.import_module("jaxsocial.experiments.sweep").main
    verbs = {verb for kind_verbs in catalogue.VERBS.values() for verb in kind_verbs}
    if len(argv) < 2 or argv[0] not in verbs - {"power"} or argv[1] not in catalogue.design_names():
        return None  # `power` is every kind's, in one place
    kind = catalogue.design_kind(argv[1])
    if kind not in catalogue.VERBS:
        return None
    kind_verbs = catalogue.VERBS[kind]
    if argv[0] not in kind_verbs:
        raise SystemExit(
            f"error: {argv[0]} {argv[1]}: the {kind} design {argv[1]} takes {', '.join(kind_verbs)}"
        )
    return getattr(importlib.import_module("jaxsocial.experiments.kind_commands"), f"{kind}_main")


def main(argv: list[str] | None = None) -> None:
    argv = paths.take_results_option(argv)
    if argv and argv[0] in DELEGATED:
        importlib.import_module(DELEGATED[argv[0]][0]).main(argv[1:])
        return
    kind_main = kind_command(argv)
    if kind_main is not None:
        kind_main(argv)
        return
    args = parse_args(argv)
    if args.command == "list":
        list_recipes()
        return
    if args.command == "verify":
        run_verify(args)
        return
    if args.command == "power":
        print(designs.load(args.design).describe())
        return
    recipe = recipes.RECIPES[args.recipe]
    scale = prereg.recipe_scale(recipe, recipes.SCALES[args.scale])
    try:
        commands = {
            "run": train_recipe,
            "record": record,
            "restore": restore_records,
            "status": status,
            "figure": figure,
        }
        commands[args.command](args, recipe, scale)
    except (ValueError, FileExistsError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from err


def train_recipe(args: argparse.Namespace, recipe: recipes.Recipe, scale: recipes.Scale) -> None:
    """`run`: train and evaluate what the recipe's seeds lack (`runner.run`), which imports JAX and the
    training's modules: only once the command line is accepted."""
    from jaxsocial.experiments.launch import runner

    try:
        runner.run(
            recipe,
            scale,
            args.seed,
            args.seeds,
            args.runs_dir,
            dry_run=args.dry_run,
            train_missing=not args.no_train,
            pick=tuple(args.pick),
            launcher=slurm.chosen(args),
            seeds_per_program=args.vmap_seeds,
            max_runs=args.max_runs,
            allow_dirty=args.allow_dirty,
        )
    except runner.TrainingFailed as err:
        raise SystemExit(f"error: {err}") from err


def list_recipes() -> None:
    """`list`: every recipe with its conditions, every design by kind, and every scale with the cost of one
    run."""
    for r in recipes.RECIPES.values():
        print(f"{r.name:12s} {r.title}\n{'':12s} conditions: {', '.join(r.conditions)}")
    for kind in catalogue.DESIGN_KINDS:
        print(f"{kind} designs: {', '.join(catalogue.design_names(kind))}")
    for s in recipes.SCALES.values():
        per_run = s.iterations * s.config.num_envs * s.config.rollout_steps
        unmeasured = (
            "under a minute, most of it compiling"
            if s.name == "tiny"
            else "no measured CPU rate (meant for GPUs)"
            if s.for_gpus
            else "no measured CPU rate (a design's `run --dry-run` gives its records' pace on this CPU kind)"
        )
        cost = recipes.cost(s, 1, per_run, 1) or unmeasured
        print(f"scale {s.name}: {s.iterations} iterations; one run: {cost}\n  {s.note}")


def record(args: argparse.Namespace, recipe: recipes.Recipe, scale: recipes.Scale) -> None:
    """`record`: pack the recipe's finished seeds (`recipe_records.record`)."""
    recipe_records.record(recipe, scale, recipe_records.RecordOptions.of(args))


def restore_records(args: argparse.Namespace, recipe: recipes.Recipe, scale: recipes.Scale) -> None:
    """`restore`: copy the recipe's records back into its run directories (`launch.restore`)."""
    from jaxsocial.experiments.launch import restore

    restore.into_run_dirs(recipe, scale, args.seed, args.seeds, args.runs_dir, args.records, tuple(args.pick))


def status(args: argparse.Namespace, recipe: recipes.Recipe, scale: recipes.Scale) -> None:
    """`status`: where each seed of the recipe stands (`seed_status`), read from the records and the runs."""
    statuses = seed_status.seed_statuses(
        recipe, scale, args.seed, args.seeds, args.runs_dir, args.records, tuple(args.pick)
    )
    last = args.seed + args.seeds - 1
    print(f"[{recipe.name}/{scale.name}] seeds {args.seed}-{last}, {scale.iterations:,} iterations a run")
    print("\n".join(seed_status.status_lines(statuses, scale.iterations)))


def figure(args: argparse.Namespace, recipe: recipes.Recipe, scale: recipes.Scale) -> None:
    """`figure`: the recipe's summary and figure (a design's stay blind until every seed is in, unless
    --interim), its outcome, how it compares with the committed summary, and a design's verdict."""
    runs = summaries.RecipeRuns(recipe, scale, args.seed, args.seeds, args.runs_dir, tuple(args.pick))
    blind = summaries.incomplete_design(runs)
    if blind and not args.interim:
        print(f"{blind}; its results stay blind until every seed is in (--interim shows them now)")
        return
    json_path, png_path = summaries.write(runs, args.out_dir)
    print(f"wrote {json_path}\nwrote {png_path}")
    summary = jsonio.read_json(json_path)
    print("\n".join(summaries.outcome_lines(summary)))
    committed = paths.SCIENCE / json_path.name
    if committed.is_file() and committed.resolve() != json_path.resolve():
        print(f"against the committed summary {committed}:")
        print(
            "\n".join(
                f"  {line}" for line in summaries.against_committed(summary, jsonio.read_json(committed))
            )
        )
    if recipe.design is not None:
        print(verdicts.verdict(summary))


if __name__ == "__main__":
    main()
