"""How the slots of a `population.Population` act, step by step in a batch of E environments (traced under
`jit`): the neural slots' networks step on their own views and sample their actions (`sample_actions`),
scripted experts read the full `EnvState`, random slots draw uniformly (`act`); `values` values views
without acting. What each slot carries from one step to the next is a `SlotState`.
Shapes: E environments, N agents (slots), S neural slots (`Population.neural`), K rendered views, H LSTM
units.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxsocial.agents import experts, network
from jaxsocial.agents.population import Population
from jaxsocial.env.observe import Observers
from jaxsocial.env.types import NUM_ACTIONS, EnvParams, EnvState


class SlotState(NamedTuple):
    """What the slots carry from step to step, for a batch of E environments.

    carry: network.Carry of float32[S, E, H] (neural slots, `Population.neural` order); memory: one
    experts.Memory with a leading [E] axis per expert slot; reward: float32[E, N] every agent's reward of
    the previous step (scripted experts learn from their own).
    """

    carry: network.Carry
    memory: tuple
    reward: jax.Array


def init_slot_state(
    pop: Population, net_cfg: network.NetworkConfig, env_params: EnvParams, n_envs: int
) -> SlotState:
    """The slot state before the first step (every environment starts an episode then)."""
    batched = jax.tree.map(lambda x: jnp.broadcast_to(x, (n_envs, *x.shape)), experts.init_memory(env_params))
    return SlotState(
        carry=network.initial_carry(net_cfg, (len(pop.neural), n_envs)),
        memory=(batched,) * len(pop.experts),
        reward=jnp.zeros((n_envs, env_params.n_agents), jnp.float32),
    )


def view_rows(slots: tuple[int, ...], observers: Observers) -> tuple[int, ...]:
    """Where each of `slots` finds its view in observations of `observers` (`observe.Observers`: obs
    [E, K, ...] holds those slots' views in that order; None: every slot's, [E, N, ...])."""
    if observers is None:
        return slots
    missing = [i for i in slots if i not in observers]
    if missing:
        raise ValueError(f"slots {missing} have no view among the observers {observers}")
    return tuple(observers.index(i) for i in slots)


def step_networks(
    pop: Population, net_cfg: network.NetworkConfig, slot_params, carry, obs, resets, observers
):
    """One network step of every neural slot (vmapped over slots), each on its own view of obs [E, K, ...]
    (the views of `observers`)."""
    neural_obs = jnp.moveaxis(obs[:, jnp.asarray(view_rows(pop.neural, observers))], 1, 0)
    return jax.vmap(network.step, in_axes=(0, None, 0, 0, None))(
        slot_params, net_cfg, carry, neural_obs, resets
    )


def sample_actions(key: jax.Array, logits: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Actions int32[...] drawn from the policies' logits float32[..., A], and their log-probabilities
    float32[...]."""
    chosen = jax.random.categorical(key, logits)
    return chosen, jnp.take_along_axis(jax.nn.log_softmax(logits), chosen[..., None], -1)[..., 0]


def act(
    key: jax.Array,
    pop: Population,
    net_cfg: network.NetworkConfig,
    env_params: EnvParams,
    slot_params,
    slot_state: SlotState,
    obs: jax.Array,
    env_states: EnvState,
    resets: jax.Array,
    observers: Observers = None,
) -> tuple[jax.Array, SlotState, jax.Array, jax.Array]:
    """Every slot's action for a batch of environments.

    Args:
        slot_params: neural-slot params stacked [S, ...] in `pop.neural` order (None when there are none);
        obs: uint8[E, K, 21, 21, 3] (symbolic: int8[E, K, 7, 7, 4]) the views of `observers` (static slot
        indices that include every neural slot; None: every slot's, K = N); env_states: EnvState [E]
        (scripted experts read it); resets: bool[E] the step starts an episode (zero the LSTM state, clear
        the experts' memory).
    Returns:
        actions int32[E, N]; the new slot state (rewards still those of the previous step, see
        `with_rewards`); log-probabilities and values float32[S, E] of the neural slots.
    """
    n_envs, n_agents = obs.shape[0], env_params.n_agents
    k_neural, k_random, k_experts = jax.random.split(key, 3)
    actions = jax.random.randint(k_random, (n_envs, n_agents), 0, NUM_ACTIONS)
    carry, logp, value = slot_state.carry, jnp.zeros((0, n_envs)), jnp.zeros((0, n_envs))
    if pop.neural:
        carry, out = step_networks(pop, net_cfg, slot_params, carry, obs, resets, observers)
        chosen, logp = sample_actions(k_neural, out.logits)
        actions = actions.at[:, jnp.asarray(pop.neural)].set(chosen.T.astype(actions.dtype))
        value = out.value
    actions, memory = expert_actions(
        k_experts, pop, env_params, env_states, slot_state.memory, slot_state.reward, resets, actions
    )
    return actions, SlotState(carry, memory, slot_state.reward), logp, value


def expert_actions(
    key: jax.Array,
    pop: Population,
    env_params: EnvParams,
    env_states: EnvState,
    memory: tuple,
    reward: jax.Array,
    resets: jax.Array,
    actions: jax.Array,
) -> tuple[jax.Array, tuple]:
    """`actions` int32[E, N] with every scripted expert slot's action set, and the experts' new memory (one
    entry per slot of `pop.experts`). env_states: EnvState [E] (what the experts read); reward f32[E, N] the
    previous step's rewards; resets bool[E] the step starts an episode (the experts' memory is cleared)."""
    new_memory = []
    for slot, mem, k in zip(pop.experts, memory, jax.random.split(key, len(pop.experts)), strict=True):
        chosen, mem = experts.act_batch(
            jax.random.split(k, actions.shape[0]),
            pop.slots[slot].expert,
            env_params,
            env_states,
            slot,
            mem,
            reward[:, slot],
            resets,
        )
        actions = actions.at[:, slot].set(chosen.astype(actions.dtype))
        new_memory.append(mem)
    return actions, tuple(new_memory)


def with_rewards(slot_state: SlotState, reward: jax.Array) -> SlotState:
    """Keep float32[E, N] this step's rewards for the scripted experts' next decision."""
    return slot_state._replace(reward=reward)


def values(
    pop: Population,
    net_cfg: network.NetworkConfig,
    slot_params,
    carry: network.Carry,
    obs: jax.Array,
    resets: jax.Array | None = None,
    observers: Observers = None,
) -> jax.Array:
    """float32[S, E] neural slots' values of `obs` ([E, K, ...], the views of `observers` as in `act`)
    continuing from `carry`, zeroed first where `resets` (bool[E]; None: nowhere)."""
    resets = jnp.zeros(obs.shape[0], bool) if resets is None else resets
    _, out = step_networks(pop, net_cfg, slot_params, carry, obs, resets, observers)
    return out.value
