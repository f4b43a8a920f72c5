"""Does the laptop recipe learn on a GPU as it does on CPU cores? The seeds of one run (K seeds vmapped in
one program on the GPU) beside every fresh social PPO + rec seed of the pooled laptop designs (one CPU core
a seed, `benchmarks/results/science/laptop-pooled-all.json`): each seed's takeoff (`takeoff.seed_takeoff`,
censored at its run's end), the Kaplan-Meier fraction past the plateau at the pooled budgets, and a two-sided
log-rank test (exploratory: a difference says the device changes the learning, not which is right).

    # on the GPU machine (16 seeds, `experts`' budget of 1,464 iterations; about 4 minutes on one H100):
    python -m jaxsocial.train --preset laptop --iterations 1464 --seed 0 --seeds 16 --runs-dir $OUT/runs
    # here, on the run it brought back:
    python benchmarks/gpu_learning.py RUN_DIR --out benchmarks/results/gpu_learning_h100.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from run_info import metadata, write_results

from jaxsocial import stats
from jaxsocial.experiments.analyse import takeoff, takeoff_power
from jaxsocial.experiments.plan import paths
from jaxsocial.run import rundir


def fractions(seeds: list[dict]) -> dict:
    """Takeoffs and ends of `seeds` (`takeoff_power.seed_lift`): how many took off, and the Kaplan-Meier
    fraction past the plateau with its 95% band at each of `takeoff_power.POOLED_AT` their runs reached."""
    lifts, ends = takeoff_power.lifts_and_ends(seeds)
    curve = stats.kaplan_meier(lifts, ends)
    at = {str(steps): takeoff_power.kaplan_meier_at(curve, steps)
          for steps in takeoff_power.POOLED_AT if max(ends) >= steps}  # fmt: skip
    return {"seeds": len(seeds), "took_off": sum(t is not None for t in lifts), "kaplan_meier": at}


def compare(run_dir: Path, records_root: Path) -> dict:
    """The seeds of `run_dir` (its s<seed>/ folders) against the pooled CPU social PPO + rec seeds."""
    config = rundir.read_config(run_dir)
    if (config["env"], config["net"]["aux"], config.get("preset")) != ("goalcycle3", "rec", "laptop"):
        raise SystemExit(f"{run_dir} is not a laptop social PPO + rec run (`train --preset laptop`)")
    device = [takeoff_power.seed_lift(d) for d in sorted(run_dir.glob("s[0-9]*")) if d.is_dir()]
    designs = takeoff_power.POOLED[paths.POOLED_ALL_SUMMARY.name]
    cpu = [seed for _, seed in takeoff_power.seed_takeoffs("social_rec", designs, records_root)]
    return {
        "run_dir": str(run_dir),
        "window_env_steps": takeoff.WINDOW_STEPS,
        "device": fractions(device) | {"seed_list": device},
        "cpu_pooled": fractions(cpu) | {"designs": list(designs)},
        "logrank_two_sided": stats.logrank(
            takeoff_power.lifts_and_ends(device), takeoff_power.lifts_and_ends(cpu), alternative="two-sided"
        ),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dir", help="a `train --preset laptop --seeds K` run directory")
    parser.add_argument("--out", help="JSON to write (with this script's metadata)")
    args = parser.parse_args(argv)
    run_dir = Path(args.run_dir)
    if not (run_dir / "config.json").is_file():
        raise SystemExit(f"{run_dir}: no config.json (not a run directory)")
    result = compare(run_dir, paths.RECORDS)
    for name in ("device", "cpu_pooled"):
        at = ", ".join(
            f"{int(s) / 1e6:g}M {v['kaplan_meier']:.2f}" for s, v in result[name]["kaplan_meier"].items()
        )
        print(f"{name}: {result[name]['took_off']} of {result[name]['seeds']} took off; Kaplan-Meier {at}")
    print(f"log-rank, two-sided: {json.dumps(result['logrank_two_sided'])}")
    if args.out:
        write_results(args.out, metadata(args), {"gpu_learning": result})
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
