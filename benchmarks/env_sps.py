"""Environment throughput: steps per second of `jaxsocial.env.step_batch` under `lax.scan`.

`step_batch` is `jax.vmap(jaxsocial.env.step)`, the standard gymnax-style path: the auto-reset inside `step`
is a `lax.cond` on "some episode of the batch ended", so plain `vmap(env.step)` runs at this speed too.

For each environment, observation kind and batch size B, one jitted call runs `--steps` steps of B
environments with uniformly random actions (drawn inside the scan) and auto-reset. Episodes last at most
250 steps, so the default 500 steps per call include the cost of generating and rendering new episodes.
The scan carries a checksum of every observation and returns it, so XLA cannot drop the rendering.

Reported numbers:
  env-steps/s    joint environment steps per second (one env-step = all N agents act once), i.e.
                 B * steps / seconds per call;
  agent-steps/s  env-steps/s * N (per-agent transitions per second);
  compile s      `jax.jit(f).lower(...).compile()` time, measured separately; one untimed warm-up call
                 follows, then `--repeats` timed calls (best and median reported).

Run from the repository root:

    python benchmarks/env_sps.py
    python benchmarks/env_sps.py --envs goalcycle3,fourrooms,maze --batch-sizes 1024 --obs both
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import jax
import jax.numpy as jnp
from run_info import REPO, metadata, write_json

import jaxsocial
from jaxsocial.env import reset, step_batch

NUM_ACTIONS = 7
REFERENCE = (
    "The original numpy marlgrid (rendered observations) ran about 960 joint env-steps/s on one core of "
    "this machine kind (figure from docs/environment.md section 8, not measured by this script)."
)


def make_rollout(params, batch: int, steps: int):
    """`rollout(key, states) -> (key, states, checksum, episodes)` running `steps` batched steps."""

    def body(carry, _):
        key, states, checksum, episodes = carry
        key, k_act, k_reset = jax.random.split(key, 3)
        actions = jax.random.randint(k_act, (batch, params.n_agents), 0, NUM_ACTIONS, dtype=jnp.int32)
        obs, states, _, _, _, info = step_batch(jax.random.split(k_reset, batch), states, actions, params)
        checksum = checksum + jnp.sum(obs.astype(jnp.uint32), dtype=jnp.uint32)
        episodes = episodes + jnp.sum(info["done"], dtype=jnp.int32)
        return (key, states, checksum, episodes), None

    def rollout(key, states):
        init = (key, states, jnp.zeros((), jnp.uint32), jnp.zeros((), jnp.int32))
        carry, _ = jax.lax.scan(body, init, None, length=steps)
        return carry

    return rollout


def bench(name: str, obs_kind: str, batch: int, steps: int, repeats: int, seed: int = 0) -> dict:
    _, params = jaxsocial.make(name, observation=obs_kind)
    key, k_reset = jax.random.split(jax.random.key(seed))
    _, states = jax.jit(jax.vmap(reset, in_axes=(0, None)), static_argnums=1)(
        jax.random.split(k_reset, batch), params
    )
    jax.block_until_ready(states)

    t0 = time.perf_counter()
    rollout = jax.jit(make_rollout(params, batch, steps)).lower(key, states).compile()
    compile_s = time.perf_counter() - t0

    key, states, checksum, episodes = jax.block_until_ready(rollout(key, states))  # warm-up, untimed
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        key, states, checksum, episodes = jax.block_until_ready(rollout(key, states))
        times.append(time.perf_counter() - t0)

    n = params.n_agents
    best_sps, median_sps = batch * steps / min(times), batch * steps / statistics.median(times)
    return {
        "env": name,
        "obs": obs_kind,
        "n_agents": n,
        "batch_size": batch,
        "steps_per_call": steps,
        "times_s": times,
        "best_env_sps": best_sps,
        "median_env_sps": median_sps,
        "best_agent_sps": best_sps * n,
        "median_agent_sps": median_sps * n,
        "compile_s": compile_s,
        "episodes_ended_last_call": int(episodes),
        "obs_checksum_last_call": int(checksum),
    }


def print_table(rows: list[dict]) -> None:
    r0 = rows[0]
    print(
        f"\n{r0['env']} (N={r0['n_agents']} agents), obs={r0['obs']}, {r0['steps_per_call']} steps per call"
    )
    print("  env-steps/s = joint steps (all N agents act once) per second; agent-steps/s = env-steps/s * N")
    header = (
        f"{'batch':>6} | {'env-steps/s best':>16} {'median':>12} | {'agent-steps/s best':>18} "
        f"{'median':>12} | {'compile s':>9}"
    )
    print(header)
    print("-" * len(header))
    for r in rows:
        print(
            f"{r['batch_size']:>6} | {r['best_env_sps']:>16,.0f} {r['median_env_sps']:>12,.0f} | "
            f"{r['best_agent_sps']:>18,.0f} {r['median_agent_sps']:>12,.0f} | {r['compile_s']:>9.2f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", default="goalcycle3", help="comma-separated registered env names")
    parser.add_argument("--batch-sizes", default="1,8,64,512,1024,2048,4096,8192")
    parser.add_argument("--steps", type=int, default=500, help="env-steps per timed call")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls (best and median reported)")
    parser.add_argument("--obs", choices=["rgb", "symbolic", "both"], default="rgb")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "env_sps.json"))
    args = parser.parse_args()

    envs = [e.strip() for e in args.envs.split(",") if e.strip()]
    unknown = sorted(set(envs) - set(jaxsocial.registered_envs()))
    if unknown:
        parser.error(f"unknown env(s) {unknown}; choose from {', '.join(jaxsocial.registered_envs())}")
    batch_sizes = [int(b) for b in args.batch_sizes.split(",")]
    obs_kinds = ["rgb", "symbolic"] if args.obs == "both" else [args.obs]

    print(f"devices: {jax.devices()}  cpu_count: {os.cpu_count()}")
    rows = []
    for name in envs:
        for obs_kind in obs_kinds:
            group = []
            for batch in batch_sizes:
                row = bench(name, obs_kind, batch, args.steps, args.repeats)
                print(
                    f"  {name} {obs_kind} B={batch}: {row['best_env_sps']:,.0f} env-steps/s "
                    f"(compile {row['compile_s']:.1f}s)",
                    flush=True,
                )
                group.append(row)
            print_table(group)
            rows.extend(group)

    write_json(args.out, {"metadata": {**metadata(args), "reference": REFERENCE}, "rows": rows})


if __name__ == "__main__":
    main()
