"""Where a training iteration's time goes, by component, for social and solo recipes side by side (issue 47:
social programs ran 6x slower than solo ones on an H100, about 10% on CPUs).

Each recipe's iteration is split by ablation into programs over the same T-step rollout, timed in turn:

  env       T steps of every environment with random actions, no view rendered (dynamics, rewards, resets);
  render    the same steps rendering the views the networks read (`rollout.program_observers`):
            render = this - env;
  experts   the same steps with the scripted experts choosing their slots' actions: experts = this - render;
  rollout   the recipe's iteration up to its update (`agents.rollout.iteration` with `ppo_update` left out):
            network = this - experts (the neural slots' steps, sampling, the truncation values, the rollout's
            records and the learners' batches);
  update    the learners' update on that rollout (`rollout.ppo_update`, KL stop off: every minibatch runs).

Every program starts from the state after one warm-up rollout (episodes under way), runs once to compile and
is then timed best of ``--repeats``, the programs interleaved within each repeat. Prints each component in
microseconds per joint env-step and the share of the iteration, and the social/solo ratio per component.

    python benchmarks/rollout_components.py --recipes laptop_rec,laptop_solo_rec --repeats 5 \
        --out benchmarks/results/rollout_components.json

Writes JSON with the CPU model, the commit and the load average (`run_info.metadata`).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import time
from unittest import mock

import jax
from recipe_sps import RECIPES, parse_recipes, recipe
from run_info import metadata, write_results

from jaxsocial import train
from jaxsocial.agents import acting, rollout
from jaxsocial.env import core
from jaxsocial.experiments.plan import recipes
from jaxsocial.run import startup

PROGRAMS = ("env", "render", "experts", "rollout", "update")
COMPONENTS = ("env", "render", "experts", "network", "update")


def programs(name: str) -> tuple[dict, rollout.RunnerState, int]:
    """The recipe's ablation programs (jitted, `PROGRAMS`), the state to start them from and the joint
    env-steps of one rollout."""
    scale, condition, extra = recipe(name)
    cfg = train.parse_args(
        [*recipes.condition_flags(recipes.SCALES[scale], condition, 0, 1, "/tmp/unused"), *extra]
    )
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, kl_target=1e9, kl_hard_limit=1e9))
    static = startup.setup(cfg, load_frozen=False)
    p = cfg.program
    w = rollout.wiring(static.pop, static.env_params, p.net, p.ppo, p.bc, p.algo, p.num_envs, p.rollout_steps)
    n_agents = w.env_params.n_agents

    def env_steps(state: rollout.RunnerState, key: jax.Array, observers: tuple[int, ...], with_experts: bool):
        def step(carry, k):
            env_states, slots, resets = carry
            k_act, k_expert, k_env = jax.random.split(k, 3)
            actions = jax.random.randint(k_act, (w.num_envs, n_agents), 0, 3)
            memory = slots.memory
            if with_experts:  # as `acting.act`: cost fields where an episode starts
                actions, memory = acting.expert_actions(
                    k_expert, w.pop, w.env_params, env_states, memory, slots.reward, resets, actions
                )
            obs, env_states, reward, _, _, info = core.step_batch(
                jax.random.split(k_env, w.num_envs), env_states, actions, w.env_params, observers
            )
            if with_experts:
                slots = slots._replace(memory=memory, reward=reward)
            return (env_states, slots, info["done"]), (obs, reward)  # kept, as the rollout keeps them

        carry = (state.env_states, state.slots, state.resets)
        return jax.lax.scan(step, carry, jax.random.split(key, w.rollout_steps))

    def full_rollout(state, key):  # -> (state, the learners' batches, episodes): the update returns its batch
        with mock.patch.object(rollout, "ppo_update", lambda w, state, batch, key, dp: (state, batch)):
            return rollout.iteration(w, state._replace(key=key), None)

    def update(state, batch, key):
        return rollout.ppo_update(w, state, batch, key)

    state = jax.jit(functools.partial(rollout.init, w))(jax.random.key(0))
    state, batch, _ = jax.jit(full_rollout)(state, jax.random.key(1))  # episodes under way
    jitted = {
        "env": jax.jit(functools.partial(env_steps, observers=(), with_experts=False)),
        "render": jax.jit(functools.partial(env_steps, observers=w.observers, with_experts=False)),
        "experts": jax.jit(functools.partial(env_steps, observers=w.observers, with_experts=True)),
        "rollout": jax.jit(full_rollout),
        "update": jax.jit(lambda s, k: update(s, batch, k)),
    }
    return jitted, state, w.num_envs * w.rollout_steps


def time_programs(jitted: dict, state, repeats: int) -> tuple[dict[str, float], dict[str, float]]:
    """Compile seconds and the best of `repeats` seconds of each program, interleaved."""
    compile_s, best = {}, dict.fromkeys(jitted, float("inf"))
    for name, fn in jitted.items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn(state, jax.random.key(2)))
        compile_s[name] = time.perf_counter() - t0
    for repeat in range(repeats):
        for name, fn in jitted.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn(state, jax.random.key(3 + repeat)))
            best[name] = min(best[name], time.perf_counter() - t0)
    return compile_s, best


def components(best: dict[str, float], env_steps: int) -> dict[str, float]:
    """Microseconds per joint env-step of each component (`COMPONENTS`), by differences of the programs."""
    us = {name: seconds / env_steps * 1e6 for name, seconds in best.items()}
    return {
        "env": us["env"],
        "render": us["render"] - us["env"],
        "experts": us["experts"] - us["render"],
        "network": us["rollout"] - us["experts"],
        "update": us["update"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--recipes", default="laptop_rec,laptop_solo_rec", help=f"of {', '.join(RECIPES)}")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", help="JSON results path")
    args = parser.parse_args()
    names = parse_recipes(args.recipes)
    if any(recipe(name)[2].count("--seeds") for name in names):
        raise SystemExit("rollout_components.py times one seed a program; recipe_sps.py times several")
    meta = metadata(args)
    rows = {}
    for name in names:
        jitted, state, env_steps = programs(name)
        compile_s, best = time_programs(jitted, state, args.repeats)
        split = components(best, env_steps)
        total = sum(split.values())
        rows[name] = {
            "env_steps_per_rollout": env_steps,
            "compile_s": compile_s,
            "best_s": best,
            "us_per_env_step": split,
            "share": {name: value / total for name, value in split.items()},
            "env_steps_per_s": 1e6 / total,
        }
        shown = ", ".join(f"{name} {value:.1f} ({value / total:.0%})" for name, value in split.items())
        print(f"{name}: {1e6 / total:,.0f} joint env-steps/s; us per env-step: {shown}", flush=True)
    if len(names) == 2:
        social, solo = (rows[r]["us_per_env_step"] for r in names)
        ratios = {name: social[name] / solo[name] if solo[name] > 0 else None for name in COMPONENTS}
        rows["ratio"] = {"of": names, "per_component": ratios,
                         "total": sum(social.values()) / sum(solo.values())}  # fmt: skip
        print(f"{names[0]} / {names[1]}: " + ", ".join(
            f"{k} {v:.2f}" if v is not None else f"{k} -" for k, v in ratios.items()
        ) + f"; total {rows['ratio']['total']:.2f}")  # fmt: skip
    if args.out:
        write_results(args.out, meta, {"components": rows})


if __name__ == "__main__":
    main()
