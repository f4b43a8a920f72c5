"""Mean episode return of scripted agents: every expert (and a random agent) alone in each environment, or
the 8x8 Goal Cycle's experts at several imperfections beside a random walker in the learner's slot.

    python benchmarks/expert_returns.py [--episodes 1000] [--out benchmarks/results/expert_returns.json]
    python benchmarks/expert_returns.py --rows goalcycle8 --episodes 256 \
        --out benchmarks/results/expert_returns_8x8.json

Each row is `python -m jaxsocial.evaluate --env ENV --slots SLOTS --episodes N` (full 250-step episodes, a
fresh random layout each); prints a Markdown table of every slot's mean return and writes JSON with versions
and the git revision. The 8x8 rows measure what the designs at the laptop8 scale state of their scripted
agents before any run: how good the imperfect experts are (imperfect8) and a random walker's return with and
without the penalty (nopenalty8).
"""

from __future__ import annotations

import argparse
import time

from run_info import metadata, write_json

from jaxsocial.evaluate import EvalConfig, evaluate

EIGHT = "width=8,height=8"
GOAL_CYCLE_EXPERTS = (
    "expert:explorer",
    "expert:oracle",
    "expert:explorer:epsilon=0.1,forget=0.01",
    "expert:oracle:epsilon=0.1",
    "random",
)
ROW_SETS = {
    "solo": [
        *((env, kind) for env in ("goalcycle3-solo", "goalcycle4-solo") for kind in GOAL_CYCLE_EXPERTS),
        *(
            (env, kind)
            for env in ("fourrooms-solo", "maze-solo")
            for kind in ("expert:navigator", "expert:navigator:epsilon=0.1", "random")
        ),
    ],
    "goalcycle8": [
        *(
            (f"goalcycle3:{EIGHT}", f"random,{expert},{expert}")
            for expert in (
                "expert:explorer",
                "expert:explorer:epsilon=0.2,forget=0.01",
                "expert:explorer:epsilon=0.3,forget=0.05",
                "expert:explorer:epsilon=0.4,forget=0.02",
                "expert:explorer:epsilon=0.5,forget=0.03",
                "expert:explorer:epsilon=0.6,forget=0.02",
            )
        ),
        (f"goalcycle3-solo:{EIGHT}", "random"),
        (f"goalcycle3-solo:{EIGHT},penalty=0", "random"),
    ],
}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", choices=tuple(ROW_SETS), default="solo")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="benchmarks/results/expert_returns.json")
    args = parser.parse_args()
    results = []
    print("| environment | slots | slot | mean return | 95% CI |\n|---|---|---|---|---|")
    for env, slots in ROW_SETS[args.rows]:
        t0 = time.perf_counter()
        out = evaluate(EvalConfig(env=env, slots=slots, episodes=args.episodes, seed=args.seed))
        seconds = time.perf_counter() - t0
        for k, row in enumerate(out["results"]):
            low, high = row["ci95"]
            print(
                f"| {env} | `{slots}` | {k} | {row['mean_return']:.3f} | [{low:.3f}, {high:.3f}] |",
                flush=True,
            )
            results.append({"env": env, "slots": slots, "slot": k, **row, "seconds": seconds})
    write_json(args.out, {"meta": metadata(args), "rows": results})


if __name__ == "__main__":
    main()
