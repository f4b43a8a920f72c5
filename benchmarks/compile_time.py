"""What the persistent compilation cache (`jaxsocial.run.compile_cache`, through train's ``--compile-cache``)
saves a recipe's seeds: each seed trains as its own process (as `experiments run --cores` and the sweep train
them), the first with an empty cache, the others loading the programs the first stored. Reports each process's
compile time (the `compile_s` of its first metrics row: the chunk program and the state's initialiser), apart
from its steps/s.

    python benchmarks/compile_time.py --scale laptop --condition social_rec --seeds 3 \
        --out benchmarks/results/compile_cache.json

Writes JSON with the CPU model, the commit and the load average (`run_info.metadata`).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import run_info

from jaxsocial.experiments.plan import conditions, recipes
from jaxsocial.run import metrics, rundir


def seed_flags(scale: recipes.Scale, condition: str, seed: int, runs_dir: str, iterations: int) -> list[str]:
    """The condition's training flags for one seed, `iterations` long, without progress output."""
    flags = recipes.condition_flags(scale, condition, seed, 1, runs_dir)
    return [*flags, "--iterations", str(iterations), "--run-name", f"s{seed}", "--no-progress"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scale", default="laptop", choices=sorted(recipes.SCALES))
    parser.add_argument("--condition", default="social_rec", choices=sorted(conditions.CONDITIONS))
    parser.add_argument("--seeds", type=int, default=3, help="processes, one seed each, one after another")
    parser.add_argument("--iterations", type=int, default=10, help="iterations per process (one chunk)")
    parser.add_argument("--out", default=None, help="JSON results")
    args = parser.parse_args()
    meta = run_info.metadata(args)
    scale = recipes.SCALES[args.scale]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cache, runs = Path(tmp) / "cache", Path(tmp) / "runs"
        for seed in range(args.seeds):
            flags = seed_flags(scale, args.condition, seed, str(runs), args.iterations)
            subprocess.run(
                [sys.executable, "-m", "jaxsocial.train", *flags, "--compile-cache", str(cache)], check=True
            )
            first = rundir.read_metrics(runs / f"s{seed}")[0]
            rows.append(
                {
                    "seed": seed,
                    "cache": "empty" if seed == 0 else "filled by seed 0",
                    "compile_s": first[metrics.COMPILE_S],
                    "env_steps_per_s": first[metrics.SPEED],
                }
            )
            print(f"seed {seed}: compile {rows[-1]['compile_s']:.1f} s ({rows[-1]['cache']})", flush=True)
    later = [r["compile_s"] for r in rows[1:]]
    summary = {
        "scale": args.scale,
        "condition": args.condition,
        "seeds": rows,
        "compile_s_empty_cache": rows[0]["compile_s"],
        "compile_s_filled_cache_mean": sum(later) / len(later) if later else None,
    }
    if args.out:
        run_info.write_results(args.out, meta, {"compile_cache": summary})


if __name__ == "__main__":
    main()
