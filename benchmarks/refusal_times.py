"""How long `python -m jaxsocial.train` and `python -m jaxsocial.experiments` take to refuse bad input
(issue 84, item 5): each refusal as a newcomer meets it, in a fresh process, wall-clock seconds from start to
exit, `--repeats` times (the minimum and the median are reported), beside three floors: the Python start,
`import jax` (which no refusal pays: they come before it, `tests/test_refusals.py`) and `import jaxsocial`
(whose names are imported at first use).

    python benchmarks/refusal_times.py --out benchmarks/results/refusal_times.json
    python benchmarks/refusal_times.py --before HEAD~1   # also the package of another commit, for comparison

Every command must be refused (exit status 1 or 2); this tree's must also say why (its message) and print no
cost line first (each row says whether one was). Writes JSON with the CPU model, the commit and the load
average at the start and the end (`run_info.metadata`): the numbers are wall-clock, so quote them with the
load.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

import run_info

from jaxsocial.run import config, rundir, runlock
from jaxsocial.run.config import TrainConfig

TRAIN, EXPERIMENTS = "jaxsocial.train", "jaxsocial.experiments"
REFUSALS = {
    "unknown_env": (TRAIN, ["--env", "goalcycle9"], "unknown environment 'goalcycle9'"),
    "bad_flag_value": (TRAIN, ["--num-envs", "many"], "--num-envs"),
    "out_of_range": (TRAIN, ["--iterations", "0"], "iterations=0 must be >= 1"),
    "run_dir_with_metrics": (TRAIN, ["--run-name", "trained"], "trained already exists and is not empty"),
    "run_dir_with_metrics_cached": (
        TRAIN,
        ["--run-name", "trained", "--compile-cache", "RUNS/cache"],
        "trained already exists and is not empty",
    ),
    "run_dir_of_another_config": (
        TRAIN,
        ["--run-name", "unstarted", "--iterations", "7"],
        "differs in ['iterations']",
    ),
    "run_dir_in_use": (TRAIN, ["--resume", "RUNS/live"], "live is in use by process"),
    "unknown_recipe": (EXPERIMENTS, ["run", "goalcycle9"], "invalid choice: 'goalcycle9'"),
    "unknown_design": (EXPERIMENTS, ["power", "pred9"], "invalid choice: 'pred9'"),
    "design_seed_changed": (
        EXPERIMENTS,
        ["run", "pred8", "--scale", "laptop8", "--seed", "3"],
        "--seed 3: the pre-registered design pred8 fixes",
    ),
    "unknown_option": (
        EXPERIMENTS,
        ["record", "pred8", "--scale", "laptop8", "--checkpoint", "all"],
        "unrecognized arguments: --checkpoint all",
    ),
    "design_kind_option": (EXPERIMENTS, ["run", "transfer8", "--core", "0"], "unrecognized arguments"),
    "delegated_verb": (EXPERIMENTS, ["sweep", "maps"], "invalid choice: 'maps'"),
    "verify_no_record": (EXPERIMENTS, ["verify", "RUNS"], "holds no config.json"),
}
"""name -> (the module `python -m` runs, its arguments (a training's after `--runs-dir RUNS`; RUNS: the run
directories `make_runs` made), a part of the message it must print)."""


def command(module: str, flags: list[str], runs: Path) -> list[str]:
    """The `python` arguments of the refusal of `module` with `flags` (`REFUSALS`), RUNS made `runs`; the
    experiments read this checkout's results (`--results`), as from the root of a clone."""
    flags = [f.replace("RUNS", str(runs)) for f in flags]
    where = (
        ["--runs-dir", str(runs)]
        if module == TRAIN
        else ["--results", str(run_info.REPO / "benchmarks/results")]
    )
    return ["-m", module, *where, *flags]


FLOORS = {
    "python": ["-c", "pass"],
    "import_jax": ["-c", "import jax"],
    "import_jaxsocial": ["-c", "import jaxsocial"],
}
"""name -> Python arguments: what a command pays before the training's own code runs (JAX: a command that
trains)."""


def make_runs(runs: Path) -> runlock.RunLock:
    """The run directories the refusals meet, each holding the config.json of a run of the default config
    with 5 iterations: 'trained' and 'live' with a metrics row, 'live' locked by this process (the lock is
    returned), and 'unstarted' with nothing more, as an interrupted run leaves it."""
    for name in ("trained", "live", "unstarted"):
        cfg = dataclasses.replace(TrainConfig(), runs_dir=str(runs), run_name=name, iterations=5)
        (runs / name).mkdir(parents=True)
        rundir.write_config(runs / name, config.config_dict(cfg))
        if name != "unstarted":
            (runs / name / rundir.METRICS_FILE).write_text('{"iteration": 1}\n')
    lock = runlock.RunLock(runs / "live")
    lock.acquire()
    return lock


def timed(argv: list[str], cwd: Path, env: dict[str, str]) -> tuple[float, subprocess.CompletedProcess]:
    """Wall-clock seconds of `python ARGV` in `cwd`, and its outcome."""
    t0 = time.perf_counter()
    out = subprocess.run(
        [sys.executable, *argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )
    return time.perf_counter() - t0, out


def summary(seconds: list[float]) -> dict[str, float | list[float]]:
    return {"min_s": round(min(seconds), 3), "median_s": round(statistics.median(seconds), 3),
            "all_s": [round(s, 3) for s in seconds]}  # fmt: skip


def time_refusals(runs: Path, env: dict[str, str], repeats: int, check: bool) -> dict[str, dict]:
    """Each of `REFUSALS` `repeats` times, each a refusal (with `check`, also `CHECKED`); then the `FLOORS`.
    Each row says whether the refusal printed the cost line first."""
    rows = {}
    for name, (module, flags, message) in REFUSALS.items():
        argv = command(module, flags, runs)
        seconds, costs = [], False
        for _ in range(repeats):
            took, out = timed(argv, runs.parent, env)
            said = out.stdout + out.stderr
            costs = costs or "cost:" in said
            if out.returncode not in (1, 2) or (check and (message not in said or costs)):
                raise SystemExit(
                    f"{name}: expected a refusal saying {message!r}, got {out.returncode}:\n{said}"
                )
            seconds.append(took)
        rows[name] = {"argv": argv[1:], "cost_line_first": costs, **summary(seconds)}
        print(f"{name}: min {rows[name]['min_s']:.2f} s, median {rows[name]['median_s']:.2f} s", flush=True)
    for name, argv in FLOORS.items():
        rows[name] = {"argv": argv, **summary([timed(argv, runs.parent, env)[0] for _ in range(repeats)])}
        print(f"{name}: min {rows[name]['min_s']:.2f} s", flush=True)
    return rows


def imported(env: dict[str, str], cwd: Path) -> str:
    """The file `jaxsocial.train` is imported from under `env`."""
    out = timed(["-c", "import jaxsocial.train as t; print(t.__file__)"], cwd, env)[1]
    return out.stdout.strip()


def package_of(rev: str, into: Path) -> Path:
    """The `jaxsocial` package of commit `rev`, extracted under `into` (the folder to put on PYTHONPATH)."""
    archive = subprocess.run(
        ["git", "archive", rev, "jaxsocial"], cwd=run_info.REPO, capture_output=True, check=True
    ).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(into, filter="data")
    return into


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default=None, help="JSON results")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--before", default=None, help="also time the package of this commit (e.g. HEAD~1)")
    args = parser.parse_args()
    meta = run_info.metadata(args)
    sections = {}
    with tempfile.TemporaryDirectory() as work:
        runs = Path(work) / "runs"
        lock = make_runs(runs)
        try:
            trees = {"refusals": ("this tree", run_info.REPO)}
            if args.before:
                trees["refusals_before"] = (args.before, package_of(args.before, Path(work) / "before"))
            for section, (package, path) in trees.items():
                env = {**os.environ, "PYTHONPATH": str(path)}
                print(f"{package}:", flush=True)
                rows = time_refusals(runs, env, args.repeats, check=section == "refusals")
                sections[section] = {"package": package, "imported": imported(env, runs.parent), "rows": rows}
        finally:
            lock.release()
    if args.out:
        run_info.write_results(args.out, meta, sections)


if __name__ == "__main__":
    main()
