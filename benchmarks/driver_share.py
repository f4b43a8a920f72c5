"""Where a finished run's wall-clock time went, from its record (or run directory) alone: inside the compiled
chunks (each metrics row's `env_steps_per_s` gives its iteration's time), compiling (`compile_s` rows), and
everything else: the driver (metrics rows, checkpoints, progress), start-up and imports.

The wall time is the provenance's start to end (whole seconds, from the commands log), so "other" is an
upper bound on the driver's share.

    python benchmarks/driver_share.py benchmarks/results/records/laptop/prereg-h1_sooner/*/ \
        --out benchmarks/results/driver_share.json
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from jaxsocial.experiments.analyse import records  # noqa: E402
from jaxsocial.run import metrics, rundir  # noqa: E402


def seconds_between(start: str, end: str) -> float:
    """Seconds from one ISO date to another ('Z' allowed)."""
    parse = datetime.datetime.fromisoformat
    return (parse(end.replace("Z", "+00:00")) - parse(start.replace("Z", "+00:00"))).total_seconds()


def share(run_dir: Path) -> dict:
    """The wall, inside-chunk, compile and other seconds of one seed's record or run directory."""
    run = (records.read_provenance(run_dir) or {}).get("run") or {}
    if not run.get("started") or not run.get("ended"):
        raise SystemExit(f"error: {run_dir} has no provenance with start and end dates")
    config, rows = rundir.read_config(run_dir), rundir.read_metrics(run_dir)
    per_iteration = config["num_envs"] * config["rollout_steps"]
    wall = seconds_between(run["started"], run["ended"])
    inside = metrics.cpu_minutes(rows, per_iteration, cores=1) * 60  # each row's time, from its speed
    compile_s = sum(row.get("compile_s", 0.0) for row in rows)
    return {
        "run": str(run_dir),
        "iterations": len(rows),
        "device": run.get("device"),
        "wall_s": wall,
        "inside_chunks_s": inside,
        "compile_s": compile_s,
        "other_s": wall - inside - compile_s,
        "other_fraction": (wall - inside - compile_s) / wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", help="seed records or run directories")
    parser.add_argument("--out", help="JSON results path")
    args = parser.parse_args()
    rows = [share(Path(run)) for run in args.runs]
    for row in rows:
        print(
            f"{row['run']}: {row['wall_s']:.0f} s: chunks {row['inside_chunks_s']:.0f} s, compile "
            f"{row['compile_s']:.0f} s, other {row['other_s']:.0f} s ({row['other_fraction']:.1%})"
        )
    fractions = [row["other_fraction"] for row in rows]
    summary = {"runs": len(rows), "median_other_fraction": statistics.median(fractions),
               "max_other_fraction": max(fractions)}  # fmt: skip
    print(f"{len(rows)} runs: other (driver, start-up) median {summary['median_other_fraction']:.1%}, "
          f"max {summary['max_other_fraction']:.1%} of the wall time")  # fmt: skip
    if args.out:
        from run_info import metadata, write_results

        write_results(args.out, metadata(args), {"driver_share": {"summary": summary, "rows": rows}})


if __name__ == "__main__":
    main()
