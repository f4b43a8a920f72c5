"""How long the README's Quickstart commands take on this machine, as a newcomer runs them: each command in a
fresh process with an empty compilation cache, one after another, wall-clock seconds (compile included).

The learner trained by the first command is the one the evaluation, rendering and plotting commands read.
Three learners train 50 iterations here; the seconds of the README's 500 follow from the run's own
`compile_s` and env-steps/s (`three_learners_500`), as do those of the set-up command's 500 iterations from
the first run (`train_500`).

    python benchmarks/quickstart_times.py --out benchmarks/results/quickstart_times.json

Writes JSON with the CPU model, the commit and the load average (`run_info.metadata`).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import run_info

from jaxsocial.run import logs, metrics

SHORT = "short"
COMMANDS = {
    "train_200": ["jaxsocial.train", "--env", "goalcycle3", "--iterations", "200", "--run-name", SHORT],
    "three_learners_50": [
        "jaxsocial.train", "--env", "goalcycle3", "--slots", "learner,learner,learner", "--iterations", "50",
        "--run-name", "three",
    ],
    "evaluate": ["jaxsocial.evaluate", "--ckpt", f"RUNS/{SHORT}", "--env", "fourrooms"],
    "render": ["jaxsocial.render", "--ckpt", f"RUNS/{SHORT}", "--out", "RUNS/learner.gif"],
    "plot": ["jaxsocial.plot", f"RUNS/{SHORT}", "--out", "RUNS/curves.png"],
}  # fmt: skip
"""name -> `python -m` arguments ('RUNS' is the runs directory)."""


def timed(args: list[str], runs: Path, cache: Path) -> float:
    """Wall-clock seconds of `python -m ARGS` in the runs directory's parent, with an empty cache `cache`."""
    args = [a.replace("RUNS", str(runs)) for a in args]
    if args[0] == "jaxsocial.train":
        args += ["--runs-dir", str(runs), "--no-progress", "--compile-cache", str(cache)]
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(cache)}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", *args], check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def projected(run_dir: Path, iterations: int) -> float:
    """Seconds a run like `run_dir` takes for `iterations`: its compile seconds and its mean env-steps/s
    after the first chunk (whose rate includes the all-reset first rollout)."""
    rows, config = logs.read_metrics(run_dir), logs.read_config(run_dir)
    later = [r for r in rows if r[metrics.ITERATION] > config["chunk_iterations"]] or rows
    steps_per_s = sum(r[metrics.SPEED] for r in later) / len(later)
    seconds = iterations * metrics.steps_per_iteration(config) / steps_per_s
    return rows[0].get(metrics.COMPILE_S, 0.0) + seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default=None, help="JSON results")
    args = parser.parse_args()
    meta = run_info.metadata(args)
    seconds = {}
    with tempfile.TemporaryDirectory() as work:
        runs = Path(work) / "runs"
        for name, command in COMMANDS.items():
            seconds[name] = timed(command, runs, Path(work) / f"cache-{name}")
            print(f"{name}: {seconds[name]:.1f} s", flush=True)
        for name, run in (("train_500", SHORT), ("three_learners_500", "three")):
            seconds[name] = projected(runs / run, 500)
            print(f"{name} (projected from its run): {seconds[name]:.0f} s", flush=True)
    if args.out:
        run_info.write_results(args.out, meta, {"seconds": seconds})


if __name__ == "__main__":
    main()
