"""Whole episodes played to their end with every slot acting (`acting.act`): each slot's return, its return
over the second half, and who was present. `play_episodes` is the compiled form every evaluation shares: the
zero-shot evaluation (`jaxsocial.evaluate`) and a training run's evaluations (`jaxsocial.run.outputs`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxsocial.agents import acting, network, population
from jaxsocial.env import core
from jaxsocial.env.types import EnvParams


class Episodes(NamedTuple):
    """Per-episode results, [E, N] each: the slots' returns, their returns over the second half of the
    episode (steps after `max_steps // 2`), and whether the slot was present at the start (solo episodes
    leave experts out)."""

    returns: jax.Array
    late_returns: jax.Array
    present: jax.Array


def episode_returns(
    key: jax.Array,
    pop: population.Population,
    net_cfg: network.NetworkConfig,
    env_params: EnvParams,
    params,
    n_episodes: int,
) -> Episodes:
    """Play `n_episodes` episodes in parallel, each to its end. Jittable (static pop, net_cfg, env_params,
    n_episodes). The episodes depend on `key` only through their layouts, spawns and actions: playing
    the same key with other presence settings (`solo_prob`, `dropout_prob`) gives the same layouts.

    Args:
        params: neural-slot params stacked [S, ...] in `pop.neural` order, or None.
    """
    k_reset, k_run = jax.random.split(key)
    observers = pop.observers()  # the only views anyone reads: scripted experts read the state
    reset = functools.partial(core.reset, observers=observers)
    obs, states = jax.vmap(reset, in_axes=(0, None))(jax.random.split(k_reset, n_episodes), env_params)
    present = states.present
    slots = acting.init_slot_state(pop, net_cfg, env_params, n_episodes)

    def body(carry, key):
        obs, states, slots, first, done, returns, late = carry
        actions, slots, _, _ = acting.act(
            key, pop, net_cfg, env_params, params, slots, obs, states, first, observers
        )
        step = functools.partial(core.step_env, observers=observers)
        obs, states, reward, terminated, truncated = jax.vmap(step, in_axes=(0, 0, None))(
            states, actions, env_params
        )
        reward = jnp.where(done[:, None], 0.0, reward)
        returns = returns + reward
        late = late + jnp.where(states.time[:, None] > env_params.max_steps // 2, reward, 0.0)
        done = done | jnp.all(terminated, -1) | truncated
        slots = acting.with_rewards(slots, reward)
        return (obs, states, slots, jnp.zeros_like(first), done, returns, late), None

    zeros = jnp.zeros((n_episodes, env_params.n_agents), jnp.float32)
    start = (obs, states, slots, jnp.ones(n_episodes, bool), jnp.zeros(n_episodes, bool), zeros, zeros)
    (*_, returns, late), _ = jax.lax.scan(body, start, jax.random.split(k_run, env_params.max_steps))
    return Episodes(returns, late, present)


play_episodes = jax.jit(episode_returns, static_argnums=(1, 2, 3, 5))
"""`episode_returns`, compiled once a process for each population, network, environment and episode count
(every evaluation and every training run's evaluations share it)."""
