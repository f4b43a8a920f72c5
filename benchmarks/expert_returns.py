"""Mean episode return of every scripted expert (and of a random agent) alone in each environment.

    python benchmarks/expert_returns.py [--episodes 1000] [--out benchmarks/results/expert_returns.json]

Each row is `python -m jaxsocial.evaluate --env ENV-solo --slots KIND --episodes N` (full 250-step episodes,
a fresh random layout each); prints a Markdown table and writes JSON with versions and the git revision.
"""

from __future__ import annotations

import argparse
import time

from run_info import metadata, write_json

from jaxsocial.evaluate import EvalConfig, evaluate

ROWS = [
    ("goalcycle3-solo", ["expert:explorer", "expert:oracle", "expert:explorer:epsilon=0.1,forget=0.01",
                         "expert:oracle:epsilon=0.1", "random"]),
    ("goalcycle4-solo", ["expert:explorer", "expert:oracle", "expert:explorer:epsilon=0.1,forget=0.01",
                         "expert:oracle:epsilon=0.1", "random"]),
    ("fourrooms-solo", ["expert:navigator", "expert:navigator:epsilon=0.1", "random"]),
    ("maze-solo", ["expert:navigator", "expert:navigator:epsilon=0.1", "random"]),
]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="benchmarks/results/expert_returns.json")
    args = parser.parse_args()
    results = []
    print("| environment | slot | mean return | 95% CI |\n|---|---|---|---|")
    for env, kinds in ROWS:
        for kind in kinds:
            t0 = time.perf_counter()
            out = evaluate(EvalConfig(env=env, slots=kind, episodes=args.episodes, seed=args.seed))
            row = out["results"][0]
            low, high = row["ci95"]
            print(f"| {env} | `{kind}` | {row['mean_return']:.3f} | [{low:.3f}, {high:.3f}] |", flush=True)
            results.append({"env": env, "slot": kind, **row, "seconds": time.perf_counter() - t0})
    write_json(args.out, {"meta": metadata(args), "rows": results})


if __name__ == "__main__":
    main()
