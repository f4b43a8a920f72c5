"""What the per-iteration non-finite check (`jaxsocial.run.nonfinite.check`) costs on the paper preset.

Times the check alone, jitted, on the paper learner's parameters, optimiser state and losses (the values it
reduces every iteration), and one training iteration of the paper preset (a compiled 1-iteration chunk,
which includes the check), and reports their ratio. The check alone is an upper bound of its cost inside
the iteration, where XLA may fuse its reductions with the update.

    python benchmarks/nonfinite_cost.py [--repeats 2] [--out benchmarks/results/nonfinite_cost.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import jax
import numpy as np
from run_info import REPO, metadata, write_results

from jaxsocial import train
from jaxsocial.run import config, flags, nonfinite


def time_calls(fn, repeats: int) -> list[float]:
    """Seconds of `repeats` calls of `fn()` (each waited for), after one untimed call."""
    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="goalcycle3")
    parser.add_argument("--repeats", type=int, default=2, help="timed iterations (after a warm-up one)")
    parser.add_argument("--check-repeats", type=int, default=200, help="timed calls of the check alone")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "nonfinite_cost.json"))
    args = parser.parse_args()
    meta = metadata(args)

    cfg = flags.with_env_observation(dataclasses.replace(config.PRESETS["paper"], env=args.env))
    program = train.compiled_program(cfg)
    state = program.init(np.int32(0))
    shapes = jax.eval_shape(program.run_chunk, state, None, 1)[1]
    shapes.pop(nonfinite.KEY)
    losses = {k: np.zeros(v.shape[1:], v.dtype) for k, v in shapes.items() if k not in ("return", "episodes")}
    check = jax.jit(nonfinite.check)
    check_s = time_calls(lambda: check(losses, state.params, state.opt_state), args.check_repeats)
    checked = sum(x.size for x in jax.tree.leaves((state.params, state.opt_state)))
    print(
        f"check alone: median {statistics.median(check_s) * 1e3:.3f} ms over {checked:,} values", flush=True
    )

    t0 = time.perf_counter()
    chunk = program.run_chunk.lower(state, None, 1).compile()
    compile_s = time.perf_counter() - t0
    print(f"paper preset: compiled the 1-iteration chunk in {compile_s:.0f} s", flush=True)
    holder = {"state": state}

    def one_iteration():
        holder["state"], metrics = chunk(holder["state"], None)
        return metrics

    iteration_s = time_calls(one_iteration, args.repeats)
    ratio = statistics.median(check_s) / statistics.median(iteration_s)
    print(f"iteration: median {statistics.median(iteration_s):.1f} s; the check is {100 * ratio:.5f}% of it")
    write_results(
        args.out,
        meta,
        {
            "nonfinite_cost": {
                "env": args.env,
                "checked_values": checked,
                "check_s": check_s,
                "check_median_s": statistics.median(check_s),
                "compile_s": compile_s,
                "iteration_s": iteration_s,
                "iteration_median_s": statistics.median(iteration_s),
                "check_fraction_of_iteration": ratio,
            }
        },
    )


if __name__ == "__main__":
    main()
