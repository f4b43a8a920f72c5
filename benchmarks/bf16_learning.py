"""Learning evidence for `--net.dtype bfloat16`: the cpu-scale runs of two conditions in float32 and in
bfloat16, their final returns compared and their curves drawn side by side.

Reads the run directories `RUNS_DIR/<float32 prefix>/<condition>-s0-2` and `RUNS_DIR/<bfloat16 prefix>/...`
(written by `python -m jaxsocial.train` with the cpu scale's flags of `experiments.plan.recipes`, the
bfloat16 ones with `--net.dtype bfloat16` added) and writes:

* `OUT.json`: per condition and dtype, the learner's final return per seed (`metrics.final_return`: the
  episode-weighted mean over the last 10% of iterations), its mean and 95% Student-t interval over seeds, and
  whether each dtype's mean lies within the other's interval (issue 28's criterion); with the runs' configs'
  provenance (run directories relative to RUNS_DIR, iterations, dtype) and this script's metadata.
* `OUT.png`: the learning curves (`jaxsocial.plot.draw`), one group per condition and dtype.

    python benchmarks/bf16_learning.py --runs-dir runs/experiments --out benchmarks/results/bf16_learning

(run from the directory that holds `runs/`; the output path is recorded relative to the repository).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from run_info import REPO, metadata, write_results

from jaxsocial import plot, stats
from jaxsocial.run import metrics, rundir

CONDITIONS = ("social_pred_nopenalty", "social_pred")
"""The cpu-scale conditions compared (issue 28: the h1 social PPO + pred, and the no-penalty social one)."""


def within(value: float, interval: list[float] | None) -> bool | None:
    return None if interval is None or value is None else interval[0] <= value <= interval[1]


def compare(
    runs_dir: Path, conditions: list[str], prefixes: dict[str, str], seeds: str
) -> tuple[dict, list[plot.Group]]:
    """Per condition: each dtype's final-return stats and the mutual-interval check; the plot groups."""
    result, groups = {}, []
    for condition in conditions:
        entry = {}
        for dtype, prefix in prefixes.items():
            run_dir = runs_dir / prefix / f"{condition}-{seeds}"
            (group,) = plot.load_groups([run_dir])
            group.label = f"{condition} {dtype}"
            groups.append(group)
            config = rundir.read_config(run_dir)
            entry[dtype] = stats.summary([metrics.final_return(rows) for rows in group.rows]) | {
                "run_dir": str(run_dir.relative_to(runs_dir)),
                "net_dtype": config["net"].get("dtype", "float32"),
                "iterations": [len(rows) for rows in group.rows],
            }
        (a, sa), (b, sb) = entry.items()
        entry[f"{a}_mean_within_{b}_ci95"] = within(sa["mean"], sb["ci95"])
        entry[f"{b}_mean_within_{a}_ci95"] = within(sb["mean"], sa["ci95"])
        result[condition] = entry
    return result, groups


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs-dir", required=True, help="the runs root holding both prefixes")
    parser.add_argument("--float32-prefix", default="cpu", help="sub-directory of the float32 runs")
    parser.add_argument("--bfloat16-prefix", default="cpu-bf16", help="sub-directory of the bfloat16 runs")
    parser.add_argument("--seeds", default="s0-2", help="the runs' seed suffix")
    parser.add_argument("--conditions", default=",".join(CONDITIONS), help="comma-separated conditions")
    parser.add_argument("--out", required=True, help="output path without extension (.json and .png)")
    args = parser.parse_args()
    args.conditions = [c for c in args.conditions.split(",") if c]
    runs_dir = Path(args.runs_dir)
    out = Path(args.out).resolve()
    if out.is_relative_to(REPO):  # provenance without this machine's paths
        args.out = str(out.relative_to(REPO))
    prefixes = {"float32": args.float32_prefix, "bfloat16": args.bfloat16_prefix}
    meta = metadata(args)  # before the outputs change the checkout (its `dirty` flag)
    result, groups = compare(runs_dir, args.conditions, prefixes, args.seeds)
    print(json.dumps(result, indent=2))
    figure = plot.draw(groups)
    figure.savefig(f"{out}.png", dpi=80)
    write_results(f"{out}.json", meta, {"final_returns": result})


if __name__ == "__main__":
    main()
