"""How long the README's set-up and Quickstart commands take on this machine, as a newcomer runs them: each
command as written (the same iterations), in a fresh process with an empty compilation cache, one after
another, wall-clock seconds (compile included). Nothing is projected.

The learner trained by the set-up command (`setup_train`, 500 iterations) is the one the evaluation, rendering
and plotting commands read.

    python benchmarks/quickstart_times.py --out benchmarks/results/quickstart_times.json

Writes JSON with the CPU model, the commit and the load average at the start and the end
(`run_info.metadata`); quote it only from a quiet machine (a 1-minute load under 1 at the start).
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

SETUP_RUN = "goalcycle3-s0"
COMMANDS = {
    "setup_train": ["jaxsocial.train", "--env", "goalcycle3"],
    "train_200": ["jaxsocial.train", "--env", "goalcycle3", "--iterations", "200", "--run-name", "short"],
    "three_learners": [
        "jaxsocial.train", "--env", "goalcycle3", "--slots", "learner,learner,learner", "--run-name", "three",
    ],
    "evaluate": ["jaxsocial.evaluate", "--ckpt", f"RUNS/{SETUP_RUN}", "--env", "fourrooms"],
    "render": ["jaxsocial.render", "--ckpt", f"RUNS/{SETUP_RUN}", "--out", "RUNS/learner.gif"],
    "plot": ["jaxsocial.plot", f"RUNS/{SETUP_RUN}", "--out", "RUNS/curves.png"],
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
    if args.out:
        run_info.write_results(args.out, meta, {"seconds": seconds})


if __name__ == "__main__":
    main()
