"""Where the experiments read and write, relative to the repository root: the committed results under
`RESULTS` (records, summaries, deviations, evidence) and the default scratch directories under `RUNS`.

Every other module of `jaxsocial.experiments` names these paths through this one, read when a command runs
(never bound at import), so every command's `--results DIR` moves them all (`parse_command`). A
command-line default is the path as a string (`str(paths.RECORDS)`), since commands are written into the
summaries."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

RESULTS = Path("benchmarks/results")
"""The repository's committed results."""
RECORDS = RESULTS / "records"
"""The runs' records (`records.pack`), mirroring the run directories."""
SCIENCE = RESULTS / "science"
"""The committed summaries and figures (`figure --out-dir benchmarks/results/science`)."""
DEVIATIONS = RESULTS / "deviations"
"""`<design>.json`: what happened to a design's runs that its rules did not foresee (`prereg.deviations`)."""
EVIDENCE = SCIENCE / "experts-evidence"
"""The committed evaluations a takeoff design's power is simulated from (`takeoff_power`)."""
POOLED_SUMMARY = SCIENCE / "laptop-pooled.json"
"""The pooled laptop seeds' summary (`takeoff_power.pooled_summary`): the designs that chose `experts`."""
POOLED_ALL_SUMMARY = SCIENCE / "laptop-pooled-all.json"
"""The same over every laptop design's fresh PPO + rec seeds, `experts` included."""
SWEEP_SUMMARY = SCIENCE / "sweep"
"""The exploratory sweep's summary and figure, without their suffix (.json, .png)."""
MAP_SUMMARY = SCIENCE / "map"
"""The map of where solo learners fail, without its suffix (.json, .png)."""

RUNS = Path("runs")
"""The default root of everything trained or written here that is not committed."""
EXPERIMENT_RUNS = RUNS / "experiments"
"""The recipes' and follow-ups' run directories (`--runs-dir`)."""
FIGURES = EXPERIMENT_RUNS / "figures"
"""Where `figure` writes by default."""
RECORDS_OUT = RUNS / "records"
"""Where `record` writes by default (the repository's records: `--out-dir benchmarks/results/records`)."""
SWEEP_RUNS = RUNS / "sweep"
"""The exploratory sweep's run directories."""


RESULTS_HELP = (
    f"the committed results to read and write (default: {RESULTS}, from the root of a checkout); the run "
    "directories stay under the working directory"
)
"""The help of every experiments command's `--results DIR`."""


def use_results(root: Path) -> None:
    """Read and write the committed results under `root` in place of `RESULTS`: every path here under
    `RESULTS` moves with it (the run directories under `RUNS` stay)."""
    names = globals()
    old = names["RESULTS"]
    for name, value in list(names.items()):
        if isinstance(value, Path) and value.is_relative_to(old):
            names[name] = root / value.relative_to(old)


def take_results_option(argv: list[str] | None) -> list[str]:
    """Read `--results DIR` (anywhere in `argv`, default `sys.argv[1:]`) and point the committed results
    there (`use_results`); return the other arguments."""
    early = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    early.add_argument("--results", type=Path)
    known, rest = early.parse_known_args(sys.argv[1:] if argv is None else argv)
    if known.results is not None:
        use_results(known.results)
    return rest


def parse_command(
    make_parser: Callable[[], argparse.ArgumentParser],
    argv: list[str] | None,
    check: Callable[[argparse.ArgumentParser, argparse.Namespace], None] | None = None,
) -> argparse.Namespace:
    """Every experiments command's parsing, in order: read `--results DIR` first (`take_results_option`);
    make the command's parser after it, so that its defaults name DIR, and list the option in its help;
    parse the other arguments; run `check(parser, args)`, which reports bad combinations through
    `parser.error`; then stop where there are no committed results (`require_checkout`)."""
    rest = take_results_option(argv)
    parser = make_parser()
    parser.add_argument("--results", metavar="DIR", help=RESULTS_HELP)
    args = parser.parse_args(rest)
    if check is not None:
        check(parser, args)
    require_checkout()
    return args


def require_checkout() -> None:
    """Stop with a clear error, before anything is read or written, where `RESULTS` is not a folder: the
    experiments work on the committed results of a checkout of the repository, from its root or through
    `--results DIR`."""
    if not RESULTS.is_dir():
        where = f"{RESULTS}/ in {Path.cwd()}" if not RESULTS.is_absolute() else f"{RESULTS}/"
        raise SystemExit(
            f"error: no {where}: the experiments read and write the committed results of a checkout of the "
            "repository; run them from the root of a clone, or name its results with --results DIR (e.g. "
            "--results ~/jaxsocial/benchmarks/results; an installed jaxsocial package holds the library, "
            "not the experiments' records)"
        )


def env_tag(env: str) -> str:
    """A file-name-safe form of an environment spec, as evaluations are named ('maze:width=7,height=7' ->
    'maze_width=7_height=7')."""
    return env.rstrip(":").replace(":", "_").replace(",", "_")


def missing_records(folder: Path | str) -> str | None:
    """Where `folder` is a committed records folder this checkout lacks (a code-only clone leaves
    `benchmarks/results/records/` out: README, "Set up"), the line that says so and how to fetch it; None
    where it is here or is not under the committed records. `folder` may be relative to the checkout's
    root or absolute."""
    folder, n = Path(folder), len(RECORDS.parts)
    starts = [i for i in range(len(folder.parts)) if folder.parts[i : i + n] == RECORDS.parts]
    if folder.exists() or not starts:
        return None
    inside = Path(*folder.parts[starts[-1] :]).as_posix()
    return (
        f"{inside}/ is not in this checkout (a code-only clone leaves the records out); fetch it with: "
        f"git sparse-checkout add '/{inside}/'"
    )
