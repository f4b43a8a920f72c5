"""Zero-shot evaluation of saved agents in any environment, beside any companions.

    python -m jaxsocial.evaluate --ckpt runs/goalcycle3-s0 --env fourrooms --episodes 100
    python -m jaxsocial.evaluate --ckpt runs/a runs/b --env goalcycle4 --slots learner,expert:explorer,random
    python -m jaxsocial.evaluate --env maze --slots expert:navigator,random,random     # no saved agent

The saved agent (`--ckpt`: run directories, one per training seed; `RUN_DIR@k` picks its k-th learner) plays
the `learner` slot; the other slots are scripted experts, frozen policies or random distractors (default:
the environment's scripted experts, as in training). Every episode runs to its end (no auto-reset). The
result is JSON: each slot's mean episode return with a 95% confidence interval, over training seeds when
there are several checkpoints (Student t on the per-seed means) and over episodes otherwise.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import jaxsocial
from jaxsocial import schedule
from jaxsocial.agents import network, population
from jaxsocial.env import core
from jaxsocial.env.types import EnvParams


@dataclasses.dataclass(frozen=True)
class EvalConfig:
    """An evaluation. Every field is a command-line flag."""

    ckpt: tuple[str, ...] = ()
    """Run directories of the agent under test (RUN_DIR or RUN_DIR@k), one per training seed."""
    env: str = "goalcycle3"
    """Environment preset."""
    env_args: str = ""
    """EnvParams overrides, e.g. 'penalty=0.5,solo_prob=1.0'."""
    slots: str = ""
    """Slots as in training; 'learner' is the agent under test (default: the learner in slot 0 and the
    environment's scripted experts and distractors)."""
    episodes: int = 100
    """Episodes per checkpoint."""
    seed: int = 0
    """PRNG seed of the evaluation episodes."""
    out: str | None = None
    """Also write the JSON here (an existing file is not replaced without --overwrite)."""
    overwrite: bool = False
    """Replace an existing --out file."""


T_975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145)
"""Student t 0.975 quantiles for 1-14 degrees of freedom (larger: 1.96 + 2.4 / df is within 0.3%)."""


def mean_ci95(values: np.ndarray) -> tuple[float, float, float]:
    """Mean and a 95% t-interval of the mean of independent samples (half-width 0 for one sample)."""
    values = np.asarray(values, np.float64)
    mean = float(values.mean())
    n = len(values)
    if n < 2:
        return mean, mean, mean
    df = n - 1
    t = T_975[df - 1] if df <= len(T_975) else 1.96 + 2.4 / df
    half = t * float(values.std(ddof=1)) / math.sqrt(n)
    return mean, mean - half, mean + half


def episode_returns(
    key: jax.Array,
    pop: population.Population,
    net: network.NetworkConfig,
    env_params: EnvParams,
    params,
    n_episodes: int,
) -> tuple[jax.Array, jax.Array]:
    """Play `n_episodes` episodes in parallel, each to its end. Jittable (static pop, net, env_params,
    n_episodes).

    Args:
        params: neural-slot params stacked [S, ...] in `pop.neural` order, or None.
    Returns:
        float32[E, N] each slot's episode return and bool[E, N] whether the slot took part (solo episodes
        leave experts out).
    """
    k_reset, k_run = jax.random.split(key)
    obs, states = jax.vmap(core.reset, in_axes=(0, None))(jax.random.split(k_reset, n_episodes), env_params)
    present = states.present
    slots = population.init_slot_state(pop, net, env_params, n_episodes)

    def body(carry, key):
        obs, states, slots, first, done, returns = carry
        actions, slots, _, _ = population.act(key, pop, net, env_params, params, slots, obs, states, first)
        obs, states, reward, terminated, truncated = jax.vmap(core.step_env, in_axes=(0, 0, None))(
            states, actions, env_params
        )
        returns = returns + jnp.where(done[:, None], 0.0, reward)
        done = done | jnp.all(terminated, -1) | truncated
        slots = population.record_rewards(slots, reward)
        return (obs, states, slots, jnp.zeros_like(first), done, returns), None

    start = (
        obs,
        states,
        slots,
        jnp.ones(n_episodes, bool),
        jnp.zeros(n_episodes, bool),
        jnp.zeros((n_episodes, env_params.n_agents), jnp.float32),
    )
    (*_, returns), _ = jax.lax.scan(body, start, jax.random.split(k_run, env_params.max_steps))
    return returns, present


def parse_env_spec(spec: str) -> EnvParams:
    """The parameters of an evaluation environment 'NAME' or 'NAME:field=value,...' (ValueError if bad)."""
    name, _, args = spec.partition(":")
    return jaxsocial.make(name.strip(), **schedule.parse_assignments(args))[1]


def make_learner_eval(specs: tuple[str, ...], net: network.NetworkConfig, episodes: int):
    """Evaluation during training: `fn(key, params) -> {spec: mean return}` plays `episodes` episodes of
    each environment spec (`parse_env_spec`) with one learner's `params` (unstacked) in slot 0 beside the
    environment's default companions (scripted experts, distractors), and returns the learner's mean episode
    return over the episodes it took part in. Validates everything (ValueError) before compiling."""
    if episodes < 1:
        raise ValueError(f"eval_episodes={episodes} must be >= 1")
    setups = []
    for spec in specs:
        env_params = parse_env_spec(spec)
        population.require_rgb(env_params, f"eval env {spec!r}")
        setups.append((spec, population.default_population(env_params), env_params))
    play = jax.jit(episode_returns, static_argnums=(1, 2, 3, 5))

    def run(key: jax.Array, params) -> dict[str, float]:
        stacked = jax.tree.map(lambda x: x[None], params)
        out = {}
        for (spec, pop, env_params), k in zip(setups, jax.random.split(key, len(setups)), strict=True):
            returns, present = jax.device_get(play(k, pop, net, env_params, stacked, episodes))
            out[spec] = float(returns[present[:, 0], 0].mean())
        return out

    return run


def _setup(cfg: EvalConfig):
    """Validate everything and load the policies; raises ValueError before compiling."""
    if cfg.episodes < 1:
        raise ValueError(f"--episodes {cfg.episodes} must be >= 1")
    _, env_params = jaxsocial.make(cfg.env, **schedule.parse_assignments(cfg.env_args))
    population.require_rgb(env_params, f"--env {cfg.env}")
    slots_text = cfg.slots or population.default_slots(env_params)
    pop = population.Population(population.parse_slots(slots_text, env_params.n_agents, need_learner=False))
    pop.validate(env_params)
    if len(pop.learners) > 1:
        raise ValueError("evaluate one agent at a time: one 'learner' slot (use frozen:PATH for others)")
    if bool(pop.learners) != bool(cfg.ckpt):
        raise ValueError(
            "--ckpt fills the 'learner' slot: give both, or neither (then --slots must have no learner)"
        )
    paths = [pop.slots[i].path for i in pop.frozen]
    first = (list(cfg.ckpt) + paths)[:1]
    net = population.saved_net(first[0]) if first else network.NetworkConfig()
    frozen = [population.load_policy(p, net) for p in paths]
    per_ckpt = [population.stack([population.load_policy(c, net), *frozen]) for c in cfg.ckpt]
    if not cfg.ckpt:
        per_ckpt = [population.stack(frozen) if frozen else None]
    return env_params, pop, net, per_ckpt


def evaluate(cfg: EvalConfig) -> dict[str, Any]:
    """Run the evaluation and return the JSON-able results."""
    env_params, pop, net, per_ckpt = _setup(cfg)
    play = jax.jit(episode_returns, static_argnums=(1, 2, 3, 5))
    key = jax.random.key(cfg.seed)
    results = [jax.device_get(play(key, pop, net, env_params, params, cfg.episodes)) for params in per_ckpt]
    slots = []
    for i, slot in enumerate(pop.slots):
        samples = [returns[present[:, i], i] for returns, present in results]
        seed_means = np.array([s.mean() for s in samples if len(s)])
        over_seeds = len(seed_means) > 1
        all_samples = np.concatenate(samples)
        if not len(all_samples):
            slots.append({"slot": i, "kind": slot.kind, "episodes": 0})
            continue
        mean, low, high = mean_ci95(seed_means if over_seeds else all_samples)
        slots.append(
            {
                "slot": i,
                "kind": slot.kind,
                "spec": slot.path or (slot.expert and dataclasses.asdict(slot.expert)) or None,
                "mean_return": mean,
                "ci95": [low, high],
                "ci_over": "seeds" if over_seeds else "episodes",
                "episodes": int(len(all_samples)),
                "per_seed_mean": seed_means.tolist(),
            }
        )
    return {
        "env": cfg.env,
        "env_args": cfg.env_args,
        "slots": [s.label for s in pop.slots],
        "checkpoints": list(cfg.ckpt),
        "episodes_per_checkpoint": cfg.episodes,
        "seed": cfg.seed,
        "max_steps": env_params.max_steps,
        "results": slots,
    }


def main(argv: list[str] | None = None) -> None:
    import tyro

    cfg = tyro.cli(EvalConfig, args=sys.argv[1:] if argv is None else argv, description=__doc__)
    if cfg.out and Path(cfg.out).exists() and not cfg.overwrite:
        raise SystemExit(f"error: {cfg.out} exists; pass --overwrite to replace it")
    try:
        result = evaluate(cfg)
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from err
    text = json.dumps(result, indent=2)
    print(text)
    if cfg.out:
        Path(cfg.out).parent.mkdir(parents=True, exist_ok=True)
        Path(cfg.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
