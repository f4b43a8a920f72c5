"""What XLA flags cost the test suite: the compile and run time of the tests' training programs under each
flag setting (`SETTINGS`), each in a fresh process (XLA reads its flags once, at start) with no compilation
cache, the settings interleaved over the repeats.

    python benchmarks/compile_flags.py --out benchmarks/results/compile_flags.json
    python benchmarks/compile_flags.py --programs tiny --settings opt0 tests --repeats 3

Per program and setting: the seconds to trace, lower and compile one training chunk, to run it twice (the
second run apart: no first-call costs), and a digest of its outputs (settings that compile differently may
give other float rounding). Writes JSON with the CPU model, the commit and the load average.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time

import run_info

SETTINGS = {
    "default": "",
    "opt0": "--xla_backend_optimization_level=0",
    "tests": "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false",
    "opt1": "--xla_backend_optimization_level=1",
}
"""Setting name -> $XLA_FLAGS: XLA's defaults (training, and the learning tests until 2026-11-29), LLVM at
level 0 (the tests until 2026-11-27), `conftest.TEST_XLA_FLAGS` (the tests since), and LLVM at level 1 with
XLA's fusion emitters (`conftest.RUN_FAST`, the learning tests since 2026-11-29)."""
PROGRAMS = {"tiny": 2, "learning": 10}
"""Program -> iterations in its chunk: TINY (most test files) and SOLO_LEARNING (the learning tests)."""


def measure(program: str) -> dict:
    """Trace, lower, compile and run twice one chunk of `program` in this process (its $XLA_FLAGS)."""
    sys.path.insert(0, str(run_info.REPO / "tests"))
    import jax
    import numpy as np
    from conftest import SOLO_LEARNING, TINY

    from jaxsocial import train

    iterations = PROGRAMS[program]
    base = TINY if program == "tiny" else SOLO_LEARNING
    cfg = dataclasses.replace(base, iterations=iterations, chunk_iterations=iterations)
    init, run_chunk, _ = train.make_train(cfg)
    state = jax.jit(init)(jax.random.key(0))
    seconds = {}
    start = time.perf_counter()
    traced = jax.jit(run_chunk, static_argnums=2).trace(state, None, iterations)
    seconds["trace"] = time.perf_counter() - start
    start = time.perf_counter()
    lowered = traced.lower()
    seconds["lower"] = time.perf_counter() - start
    start = time.perf_counter()
    compiled = lowered.compile()
    seconds["compile"] = time.perf_counter() - start
    digest = hashlib.sha256()
    for key in ("first_run", "second_run"):
        start = time.perf_counter()
        out = jax.block_until_ready(compiled(state, None))
        seconds[key] = time.perf_counter() - start
    for leaf in jax.tree_util.tree_leaves(out):
        if not jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            digest.update(np.asarray(leaf).tobytes())
    return {"seconds": seconds, "outputs_sha256": digest.hexdigest()[:16]}


def in_fresh_process(program: str, flags: str) -> dict:
    """`measure(program)` in a fresh process with $XLA_FLAGS `flags` and no compilation cache."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"} | {"XLA_FLAGS": flags}
    done = subprocess.run(
        [sys.executable, __file__, "--measure", program], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--programs", nargs="+", default=list(PROGRAMS), choices=list(PROGRAMS))
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", default=None, help="JSON results")
    parser.add_argument("--measure", choices=list(PROGRAMS), help=argparse.SUPPRESS)  # a worker process
    args = parser.parse_args()
    if args.measure:
        print(json.dumps(measure(args.measure)))
        return
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    meta = run_info.metadata(args)
    results = {}
    for program in args.programs:
        runs = {name: [] for name in args.settings}
        for _ in range(args.repeats):
            for name in args.settings:
                runs[name].append(in_fresh_process(program, SETTINGS[name]))
                took = runs[name][-1]["seconds"]
                print(f"{program} {name}: compile {took['compile']:.2f} s, run {took['second_run']:.2f} s")
        results[program] = {
            name: {
                "xla_flags": SETTINGS[name],
                "median_s": {
                    key: statistics.median(r["seconds"][key] for r in measured)
                    for key in measured[0]["seconds"]
                },
                "outputs_sha256": sorted({r["outputs_sha256"] for r in measured}),
                "runs": measured,
            }
            for name, measured in runs.items()
        }
    for program, by_setting in results.items():
        for name, result in by_setting.items():
            median = result["median_s"]
            print(
                f"{program:8s} {name:8s} trace {median['trace']:5.2f}  lower {median['lower']:5.2f}  "
                f"compile {median['compile']:6.2f}  run {median['second_run']:6.2f}  (median s)"
            )
    if args.out:
        run_info.write_results(args.out, meta, {"iterations": PROGRAMS, "programs": results})


if __name__ == "__main__":
    main()
