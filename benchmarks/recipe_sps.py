"""The science recipe's training speed on this machine, split into rollout, recomputation and gradient
minibatches, optionally side by side with an older commit (``--against REV``).

Each (recipe, tree) pair runs in a worker process of its own (this file with ``--worker``), which compiles
three one-iteration programs of the recipe with the KL stop off, so every minibatch runs:

  full   the recipe as configured: the rollout, R recomputes and M gradient minibatches;
  once   recompute_every = M: the rollout, R0 recomputes (the first minibatch's targets) and M minibatches;
  one    1 minibatch, recompute_every 1: the rollout, R0 recomputes and 1 minibatch;

R0 is 1 where minibatch 0 recomputes its targets and 0 where it takes the rollout's (`ppo.rollout_targets`),
so recompute = (full - once) / (R - R0), gradient minibatch = (once - one) / (M - 1), rollout = one - R0
recompute - gradient. The parent asks the workers for one timed iteration of each program in turn, so the
trees' timings interleave (only one worker computes at a time), and reports each tree's best of
``--repeats``, its joint env-steps/s, the breakdown and the ratio to the first tree. ``--against REV``
checks REV out in a temporary git worktree and imports jaxsocial from there. ``--xla-flags=FLAGS``
(repeatable; written with "=", as FLAGS begin with "--") also times this tree with ``$XLA_FLAGS`` set to
FLAGS, side by side the same way.

A recipe of several seeds (``laptop_rec_2seeds``, or any recipe as ``NAME*K`` for K seeds: ``--recipes
laptop_rec*1,laptop_rec*8,laptop_rec*64`` is a curve of throughput against seeds per program) compiles them
into one program as a run does (`loop.over_seeds`) and counts every seed's env-steps.

``--single-core`` also measures the throughput of two seeds as two processes pinned to one core each
(XLA:CPU single-threaded), both timing the full program at once, against one process on all cores: for this
tree and ``--against``'s, taking turns in every repeat (the layout the sweep and the designs run seeds in).

    python benchmarks/recipe_sps.py --recipes cpu_rec,gpu_rec --against 191032c --repeats 3 \
        --out benchmarks/results/recipe_sps.json

Writes JSON with the CPU model and flags, the commits and the load average (`run_info.metadata`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RECIPES = {
    "cpu_rec": ("cpu", "social_rec", ()),
    "cpu_pred": ("cpu", "social_pred", ()),
    "cpu_rec_symbolic": ("cpu", "social_rec", ("--net.obs", "symbolic")),
    "gpu_rec": ("gpu", "social_rec", ()),
    "gpu_pred": ("gpu", "social_pred", ()),
    "gpu_solo_pred": ("gpu", "solo_pred", ()),  # no experts: gpu_pred less this is the experts' share
    # the CPU's frame batches (same values up to rounding); --net.chunk: --against trees before the rename
    "gpu_rec_fb512": ("gpu", "social_rec", ("--net.chunk", "512")),
    "cpu_rec_mb8k8": ("cpu", "social_rec", ("--ppo.num-minibatches", "8", "--ppo.recompute-every", "8")),
    "cpu_rec_mb8k2": ("cpu", "social_rec", ("--ppo.num-minibatches", "8", "--ppo.recompute-every", "2")),
    "cpu_rec_k4": ("cpu", "social_rec", ("--ppo.recompute-every", "4")),
    "laptop_rec": ("laptop", "social_rec", ()),
    "laptop_solo_rec": ("laptop", "solo_rec", ()),
    "laptop_none": ("laptop", "social_none", ()),  # no decoder: laptop_rec less this is the decoder's share
    "laptop_rec_2seeds": ("laptop", "social_rec", ("--seeds", "2", "--seed-batching", "vmap")),  # 2 vmapped
}
"""name -> (scale, condition, extra train flags): the recipe's conditions and the levers that change
learning (measured for speed only)."""


def recipe(name: str) -> tuple[str, str, tuple[str, ...]]:
    """`RECIPES[name]`, or for ``NAME*K`` that recipe with K seeds vmapped in one program (as a run of K seeds
    compiles them; e.g. ``laptop_rec*16``). ValueError for an unknown name or a K below 1."""
    base, _, seeds = name.partition("*")
    if base not in RECIPES or (seeds and not (seeds.isdigit() and int(seeds) >= 1)):
        raise ValueError(f"unknown recipe {name!r}; choose from {', '.join(RECIPES)}, each as NAME or NAME*K")
    scale, condition, extra = RECIPES[base]
    return scale, condition, (*extra, "--seeds", seeds, "--seed-batching", "vmap") if seeds else extra


def parse_recipes(names: str) -> list[str]:
    """A comma-separated list of `recipe` names, checked (SystemExit naming the unknown ones)."""
    names = names.split(",")
    unknown = []
    for name in names:
        try:
            recipe(name)
        except ValueError:
            unknown.append(name)
    if unknown:
        choices = ", ".join(RECIPES)
        raise SystemExit(f"unknown recipes {unknown}; choose from {choices}, each as NAME or NAME*K")
    return names


VARIANTS = ("full", "once", "one")


def worker(name: str) -> None:
    """Compile the recipe's variants, print one JSON line, then time a variant per line read from stdin."""
    import jax

    from jaxsocial import train
    from jaxsocial.agents import population, ppo
    from jaxsocial.experiments.plan import recipes

    try:
        from jaxsocial.run import loop
    except ImportError:  # a tree from before the run/ package (--against 191032c, the baseline)
        from jaxsocial import loop
    try:
        from jaxsocial.run.startup import setup
    except ImportError:  # a tree from before run/startup.py, where setup was the config's
        from jaxsocial.run.config import setup

    scale, condition, extra = recipe(name)
    flags = [*recipes.condition_flags(recipes.SCALES[scale], condition, 0, 1, "/tmp/unused"), *extra]
    base = train.parse_args(flags)
    static = setup(base, load_frozen=False)
    m, k = base.ppo.num_minibatches, base.ppo.recompute_every
    programs, compile_s = {}, {}
    for variant, (mb, every) in {"full": (m, k), "once": (m, m), "one": (1, 1)}.items():
        ppo_cfg = dataclasses.replace(
            base.ppo, num_minibatches=mb, recompute_every=every, kl_target=1e9, kl_hard_limit=1e9
        )
        cfg = dataclasses.replace(base, ppo=ppo_cfg)
        init, run_chunk = loop.make_program(cfg.program, static.env_params, static.pop)
        states = [jax.jit(init)(jax.random.key(seed)) for seed in range(base.seeds)]
        state = states[0] if base.seeds == 1 else population.stack(states)
        if base.seeds > 1:  # as a run of several seeds compiles them (`loop.compiled`)
            run_chunk = loop.over_seeds(run_chunk, base.seed_batching)
        t0 = time.perf_counter()
        fn = jax.jit(run_chunk, static_argnums=2, donate_argnums=0).lower(state, None, 1).compile()
        compile_s[variant] = time.perf_counter() - t0
        state, metrics = fn(state, None)  # warm-up: past the first, all-reset rollout
        jax.block_until_ready(metrics)
        programs[variant] = [fn, state]
    first_from_rollout = hasattr(ppo, "rollout_targets")
    recomputes = -(-m // k) - int(first_from_rollout)
    print(json.dumps({"compile_s": compile_s, "minibatches": m, "recompute_every": k,
                      "recomputes": recomputes, "first_recompute": int(not first_from_rollout),
                      "env_steps": base.num_envs * base.rollout_steps * base.seeds}), flush=True)  # fmt: skip
    for line in sys.stdin:
        fn, state = programs[line.strip()]
        t0 = time.perf_counter()
        state, metrics = fn(state, None)
        jax.block_until_ready(metrics)
        programs[line.strip()][1] = state
        print(json.dumps({"seconds": time.perf_counter() - t0}), flush=True)


class Worker:
    """A worker process for one recipe, importing jaxsocial from `tree`."""

    def __init__(self, recipe: str, tree: Path, env: dict[str, str] | None = None, cpus: str | None = None):
        path = os.pathsep.join(p for p in (str(tree), os.environ.get("PYTHONPATH")) if p)  # tree first
        env = {**os.environ, **(env or {}), "PYTHONPATH": path}
        command = [sys.executable, str(Path(__file__).resolve()), "--worker", recipe]
        if cpus is not None:
            command = ["taskset", "-c", cpus, *command]
        self.proc = subprocess.Popen(
            command, cwd=tree, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        self.info = self._read()

    def _read(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"worker exited with {self.proc.wait()}")
        return json.loads(line)

    def ask(self, variant: str) -> None:
        self.proc.stdin.write(variant + "\n")
        self.proc.stdin.flush()

    def time(self, variant: str) -> float:
        self.ask(variant)
        return self._read()["seconds"]

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def breakdown(info: dict, best: dict[str, float]) -> dict[str, float]:
    """Seconds per iteration of each part (see the module docstring)."""
    m, r, r0 = info["minibatches"], info["recomputes"], info["first_recompute"]
    recompute = (best["full"] - best["once"]) / (r - r0) if r > r0 else float("nan")
    gradient = (best["once"] - best["one"]) / (m - 1) if m > 1 else float("nan")
    rollout = best["one"] - r0 * (recompute if r0 else 0.0) - gradient
    return {
        "rollout_s": rollout,
        "recompute_s_each": recompute,
        "recomputes": r,
        "recompute_s": recompute * r if r else 0.0,
        "gradient_s_each": gradient,
        "gradient_s": gradient * m,
        "iteration_s": best["full"],
    }


def worktree(rev: str, where: Path) -> Path:
    """A detached git worktree of `rev` under `where`."""
    path = where / f"against-{rev}"
    subprocess.run(["git", "worktree", "add", "--detach", str(path), rev], check=True, capture_output=True)
    return path


def single_core_pairs(recipe: str, trees: dict[str, Path], repeats: int) -> dict[str, dict]:
    """Per tree, two single-core workers timing the full program at the same moment: their summed
    env-steps/s, the trees taking turns in every repeat."""
    # this tree's flags, imported here: workers may load an older jaxsocial
    from jaxsocial.experiments.launch.pinned import SINGLE_CORE_XLA_FLAGS

    env = {"XLA_FLAGS": SINGLE_CORE_XLA_FLAGS}
    workers = {
        label: [Worker(recipe, tree, env, cpus=str(core)) for core in range(2)]
        for label, tree in trees.items()
    }
    rates: dict[str, list[float]] = {label: [] for label in trees}
    for _ in range(repeats):
        for label, pair in workers.items():
            for w in pair:
                w.ask("full")
            seconds = [w._read()["seconds"] for w in pair]
            rates[label].append(sum(pair[0].info["env_steps"] / s for s in seconds))
    for pair in workers.values():
        for w in pair:
            w.close()
    return {label: {"best_total_env_steps_per_s": max(r), "totals": r} for label, r in rates.items()}


def recomputes(row: dict) -> str:
    """The recomputes of a timed row, as the table shows them."""
    return (
        f"recompute {row['recomputes']}x{row['recompute_s_each']:.3f}s"
        if row["recomputes"]
        else "no recompute"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument(
        "--recipes", default="cpu_rec,gpu_rec", help=f"of {', '.join(RECIPES)}; NAME*K: K seeds a program"
    )
    parser.add_argument("--against", help="a git revision to time side by side")
    parser.add_argument(
        "--xla-flags", action="append", default=[], metavar="FLAGS",
        help="also time this tree with $XLA_FLAGS=FLAGS (repeatable; write --xla-flags=FLAGS)",
    )  # fmt: skip
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--single-core", action="store_true", help="also two single-core processes")
    parser.add_argument("--out", help="JSON results path")
    args = parser.parse_args()
    if args.worker:
        return worker(args.worker)
    names = parse_recipes(args.recipes)
    from run_info import REPO, metadata, write_results

    tmp = Path(tempfile.mkdtemp(prefix="recipe_sps-"))
    trees = {"HEAD": REPO}
    if args.against:
        trees[args.against] = worktree(args.against, tmp)
    envs: dict[str, dict[str, str] | None] = dict.fromkeys(trees)
    for flags in args.xla_flags:
        trees[f"HEAD {flags}"], envs[f"HEAD {flags}"] = REPO, {"XLA_FLAGS": flags}
    rows = []
    try:
        for name in names:
            workers = {label: Worker(name, tree, envs[label]) for label, tree in trees.items()}
            times = {label: {v: [] for v in VARIANTS} for label in trees}
            for _ in range(args.repeats):
                for variant in VARIANTS:
                    for label, w in workers.items():  # interleaved: one worker computes at a time
                        times[label][variant].append(w.time(variant))
            for label, w in workers.items():
                w.close()
                best = {v: min(ts) for v, ts in times[label].items()}
                row = {
                    "recipe": name,
                    "tree": label,
                    **w.info,
                    "times_s": times[label],
                    "best_env_steps_per_s": w.info["env_steps"] / best["full"],
                    **breakdown(w.info, best),
                    "loadavg_after": os.getloadavg(),
                }
                rows.append(row)
            base = rows[-len(trees)]["best_env_steps_per_s"]
            for row in rows[-len(trees) :]:
                row["ratio_to_head"] = row["best_env_steps_per_s"] / base
                print(
                    f"{name:18s} {row['tree']:10s} {row['best_env_steps_per_s']:8,.0f} env-steps/s "
                    f"(x{row['ratio_to_head']:.2f}); rollout {row['rollout_s']:.2f}s, {recomputes(row)}, "
                    f"gradient {row['minibatches']}x{row['gradient_s_each']:.3f}s; compile "
                    f"{sum(row['compile_s'].values()):.0f}s (3 programs); load {row['loadavg_after'][0]:.1f}",
                    flush=True,
                )
            if args.single_core:
                plain = {label: trees[label] for label in trees if not envs[label]}
                for label, pair in single_core_pairs(name, plain, args.repeats).items():
                    rows.append({"recipe": name, "tree": label, "layout": "2 processes x 1 core", **pair})
                    one = next(
                        r["best_env_steps_per_s"] for r in rows if r["tree"] == label and r["recipe"] == name
                    )
                    total = pair["best_total_env_steps_per_s"]
                    print(f"{name:18s} {label:10s} 2 x 1 core: {total:8,.0f} env-steps/s in total "
                          f"(x{total / one:.2f} its one 2-core process)", flush=True)  # fmt: skip
    finally:
        if args.against:
            subprocess.run(["git", "worktree", "remove", "--force", str(trees[args.against])], check=False)
    if args.out:
        write_results(args.out, metadata(args), {"recipe": {"rows": rows}})


if __name__ == "__main__":
    main()
