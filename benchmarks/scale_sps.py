"""Scale-out benchmarks: seeds in one program, host devices, and the persistent compilation cache.

Every measurement runs in a fresh subprocess (`--worker`), so XLA_FLAGS (the number of host devices) and the
compilation cache start clean. Sections (JSON in benchmarks/results/scale_sps.json):

  devices   training throughput of a preset on 1 and on 2 host devices (`XLA_FLAGS=
            --xla_force_host_platform_device_count=2`, `--devices 2`): one compiled chunk of iterations,
            joint env-steps/s (best and median of --repeats calls after a warm-up call), and compile
            seconds; --rounds alternating rounds, the speed-up is the median over rounds of the ratio of
            the median calls.
  seeds     K seeds of the small preset in one program, `seed_batching` vmap and map, against one seed:
            total env-steps/s over all seeds. `--paper-seeds` adds the paper preset with 2 seeds (compile
            seconds and one iteration; minutes).
  cache     start-up of `python -m jaxsocial.train` (wall seconds until the first chunk's metrics are
            written, and in all) with an empty `--compile-cache` directory and again with the filled one.

    python benchmarks/scale_sps.py                       # all sections, small preset (~5 minutes on 2 cores)
    python benchmarks/scale_sps.py --sections devices --preset paper --iterations 1 --repeats 2
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from run_info import REPO, metadata, write_results

DEVICE_FLAG = "--xla_force_host_platform_device_count"


# ------------------------------------------------------------------------------------------------ worker


def worker(spec: dict) -> dict:
    """One measurement in this process: compile and time `run_chunk` of a preset (see `spec` keys)."""
    import jax
    import numpy as np

    from jaxsocial import train
    from jaxsocial.run import compile_cache, config

    if spec.get("compile_cache"):
        compile_cache.enable(spec["compile_cache"])
    cfg = dataclasses.replace(
        config.PRESETS[spec["preset"]],
        seeds=spec["seeds"],
        seed_batching=spec["batching"],
        devices=spec["devices"],
    )
    program = train.compiled_program(cfg)
    seeds = np.arange(cfg.seeds, dtype=np.int32) if cfg.seeds > 1 else np.int32(0)
    state = program.init(seeds)
    n = spec["iterations"]
    t0 = time.perf_counter()
    chunk = program.run_chunk.lower(state, None, n).compile()
    compile_s = time.perf_counter() - t0
    state, metrics = chunk(state, None)  # warm-up, and past the first (all-reset) rollout
    jax.block_until_ready(metrics)
    times = []
    for _ in range(spec["repeats"]):
        t0 = time.perf_counter()
        state, metrics = chunk(state, None)
        jax.block_until_ready(metrics)
        times.append(time.perf_counter() - t0)
    steps = n * cfg.num_envs * cfg.rollout_steps * cfg.seeds
    return {
        **spec,
        "devices_seen": [str(d) for d in jax.devices()],
        "compile_s": compile_s,
        "times_s": times,
        "env_steps_per_call": steps,
        "best_env_steps_per_s": steps / min(times),
        "median_env_steps_per_s": steps / sorted(times)[len(times) // 2],
    }


def child_env() -> dict[str, str]:
    """This environment with the repository first on PYTHONPATH."""
    path = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    return dict(os.environ, PYTHONPATH=path)


def measure(spec: dict, host_devices: int = 1, timeout: int = 3600) -> dict:
    """`worker(spec)` in a subprocess with `host_devices` CPU devices."""
    env = child_env()
    env["XLA_FLAGS"] = " ".join(filter(None, [env.get("XLA_FLAGS", ""), f"{DEVICE_FLAG}={host_devices}"]))
    cmd = [sys.executable, __file__, "--worker", json.dumps(spec)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"worker {spec} failed:\n{proc.stderr[-3000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["host_devices"] = host_devices
    return result


def show(label: str, r: dict) -> None:
    print(
        f"  {label:34s} {r['best_env_steps_per_s']:9,.0f} env-steps/s (median "
        f"{r['median_env_steps_per_s']:,.0f}), compile {r['compile_s']:.1f}s",
        flush=True,
    )


# ---------------------------------------------------------------------------------------------- sections


def base_spec(args: argparse.Namespace, **changes) -> dict:
    spec = {"preset": args.preset, "seeds": 1, "batching": "vmap", "devices": 1}
    spec |= {"iterations": args.iterations, "repeats": args.repeats}
    return spec | changes


def section_devices(args: argparse.Namespace) -> dict:
    """1 and 2 host devices, alternating for --rounds rounds (load on a shared machine drifts); later rounds
    load the programs from a compilation cache."""
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        for round_ in range(args.rounds):
            for host_devices in (1, 2):
                spec = base_spec(args, devices=host_devices, compile_cache=cache)
                r = measure(spec, host_devices) | {"round": round_}
                show(f"{args.preset}, {host_devices} host device(s), round {round_}", r)
                rows.append(r)
    speedups = []
    for round_ in range(args.rounds):
        one, two = (r for r in rows if r["round"] == round_)
        speedups.append(two["median_env_steps_per_s"] / one["median_env_steps_per_s"])
    speedup = statistics.median(speedups)
    print(f"  2 devices / 1 device, median over rounds of the median call: {speedup:.2f}x", flush=True)
    return {"rows": rows, "speedups_per_round": speedups, "speedup_2_over_1": speedup}


def section_seeds(args: argparse.Namespace) -> dict:
    rows = [measure(base_spec(args, preset="small"))]
    show("small, 1 seed", rows[0])
    for k in args.seed_counts:
        for batching in ("vmap", "map"):
            r = measure(base_spec(args, preset="small", seeds=k, batching=batching))
            show(f"small, {k} seeds, {batching}", r)
            rows.append(r)
    if args.paper_seeds:
        for batching in ("vmap", "map"):
            spec = base_spec(args, preset="paper", seeds=2, batching=batching, iterations=1, repeats=1)
            r = measure(spec)
            show(f"paper, 2 seeds, {batching}", r)
            rows.append(r)
    return {"rows": rows}


def cli_run(cache: Path, runs: Path, name: str) -> dict:
    """Wall seconds of a short training CLI run until metrics.jsonl first appears, and until it ends."""
    env = child_env()
    cmd = [sys.executable, "-m", "jaxsocial.train", "--iterations", "10", "--chunk-iterations", "10"]
    cmd += ["--no-progress", "--runs-dir", str(runs), "--run-name", name, "--compile-cache", str(cache)]
    metrics = runs / name / "metrics.jsonl"
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = None
    while proc.poll() is None:
        if first is None and metrics.exists():
            first = time.perf_counter() - t0
        time.sleep(0.05)
    total = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{cmd} failed:\n{proc.stderr.read()[-3000:]}")
    return {"command": cmd, "first_metrics_s": first, "total_s": total}


def section_cache(args: argparse.Namespace) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cache, runs = Path(tmp) / "cache", Path(tmp) / "runs"
        cold = cli_run(cache, runs, "cold")
        files = sorted(p.name for p in cache.iterdir())
        warm = cli_run(cache, runs, "warm")
    for label, r in (("empty cache", cold), ("filled cache", warm)):
        print(f"  {label:14s} first metrics after {r['first_metrics_s']:.1f}s, total {r['total_s']:.1f}s")
    return {"cold": cold, "warm": warm, "cached_programs": files}


SECTIONS = {"devices": section_devices, "seeds": section_seeds, "cache": section_cache}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument(
        "--sections", default="devices,seeds,cache", help=f"comma-separated: {', '.join(SECTIONS)}"
    )
    parser.add_argument("--preset", default="small", help="preset of the devices section")
    parser.add_argument("--iterations", type=int, default=10, help="iterations per compiled call")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per measurement")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds of the devices section")
    parser.add_argument("--seed-counts", default="2,4", help="seed counts of the seeds section")
    parser.add_argument("--paper-seeds", action="store_true", help="also the paper preset with 2 seeds")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "scale_sps.json"))
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(json.loads(args.worker))))
        return
    args.sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    args.seed_counts = [int(k) for k in args.seed_counts.split(",") if k.strip()]
    if unknown := sorted(set(args.sections) - set(SECTIONS)):
        parser.error(f"unknown section(s) {unknown}; choose from {', '.join(SECTIONS)}")
    meta = metadata(args)
    sections = {}
    for name in args.sections:
        print(f"\n== section {name}", flush=True)
        sections[name] = SECTIONS[name](args)
    write_results(args.out, meta, sections)


if __name__ == "__main__":
    main()
