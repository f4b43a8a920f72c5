"""One learner's view of a social environment as a gymnax 1.x `Environment` (`pip install -e ".[gymnax]"`).

    env, params = gymnax_env.make("goalcycle3")       # the learner in slot 0 beside two scripted explorers
    obs, state = env.reset(key, params)               # obs uint8[21, 21, 3]: the learner's view
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

The other slots (`slots`, as in training: `expert:KIND`, `frozen:RUN_DIR[#k]`, `random`; default the
environment's scripted experts) act inside `step` exactly as in `jaxsocial.train`'s rollout
(`acting.act`). `params` are the world's `EnvParams` (a static, leafless pytree: pass it like gymnax's).
The learner's episode ends when it is terminated (on a terminal goal) or the world's time limit truncates it;
then the whole world resets. `info` holds gymnax's `terminated`, `truncated`, `final_observation`, and every
slot's `actions` int32[N] and `rewards` float32[N] of the step.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

try:
    from gymnax.environments import environment, spaces
except ModuleNotFoundError as err:  # pragma: no cover - depends on the installed extras
    if err.name != "gymnax":
        raise  # gymnax is installed but one of its own imports is missing: show that one
    raise ImportError('jaxsocial.adapters.gymnax_env needs gymnax: pip install -e ".[gymnax]"') from err

from jaxsocial.agents import acting, network, population
from jaxsocial.env import core, registry
from jaxsocial.env.batching import any_in_batch
from jaxsocial.env.types import NUM_ACTIONS, EnvParams, EnvState
from jaxsocial.run import policy_io


@struct.dataclass
class LearnerViewState(environment.EnvState):
    """One world as the learner sees it (`time`: int32[] steps in the episode, gymnax's field).

    Attributes:
        world: the world's `EnvState`.
        views: the observations uint8[K, 21, 21, 3] (int8[K, 7, 7, 4] symbolic) of the K slots that read
            one (`LearnerView.observers`: the learner and frozen policies; scripted experts read the world).
        companions: the other slots' `acting.SlotState` for a batch of one environment.
        starts: bool[] the next step is the episode's first (companions clear their memory).
    """

    world: EnvState
    views: jax.Array
    companions: acting.SlotState
    starts: jax.Array


def observation_space(params: EnvParams) -> spaces.Box:
    """A slot's observations: RGB uint8 in [0, 255], or symbolic int8 in [-1, 127] (`observe.symbolic`)."""
    if params.observation == "rgb":
        return spaces.Box(0, 255, params.obs_shape, jnp.uint8)
    return spaces.Box(-1, 127, params.obs_shape, jnp.int8)


class LearnerView(environment.Environment[LearnerViewState, EnvParams]):
    """The gymnax environment of the one `learner` slot in `slots` (see the module doc)."""

    def __init__(self, name: str, params: EnvParams, slots: str | None = None):
        super().__init__()
        pop = population.Population(
            population.parse_slots(slots or population.default_slots(params), params.n_agents)
        )
        pop.validate(params)
        if len(pop.learners) != 1:
            raise ValueError(f"slots {slots!r}: a gymnax environment has exactly one 'learner' slot")
        self.slot = pop.learners[0]
        if self.slot >= params.solo_agents and (params.solo_prob > 0 or params.changes_presence):
            raise ValueError(
                f"the learner's slot {self.slot} may be absent from an episode (solo_agents="
                f"{params.solo_agents}): put it among the first solo_agents slots"
            )
        companions = list(pop.slots)
        companions[self.slot] = population.Slot("random")  # its random action is replaced by the learner's
        self.companions = population.Population(tuple(companions))
        frozen = [pop.slots[i].policy for i in pop.frozen]
        self.net = policy_io.saved_net(frozen[0]) if frozen else network.NetworkConfig(obs=params.observation)
        if frozen:
            self.net.check_env(params, f"frozen slot {frozen[0]}")
        self.frozen_params = policy_io.load_frozen(self.companions, self.net)
        self.observers = pop.observers()  # only these views are rendered: the learner's and frozen ones'
        self.row = self.observers.index(self.slot)  # the learner's view in `LearnerViewState.views`
        self.env_name = name
        self._params = params

    @property
    def default_params(self) -> EnvParams:
        return self._params

    def _check(self, params: EnvParams) -> None:
        """ValueError (at trace time) unless the companions can play `params`."""
        if params.n_agents != len(self.companions.slots):
            raise ValueError(f"params have {params.n_agents} agents, the slots {len(self.companions.slots)}")
        self.companions.validate(params)

    def reset_env(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, LearnerViewState]:
        """A new episode (`core.reset`) with the companions' memory cleared; returns the learner's view."""
        self._check(params)
        views, world = core.reset(key, params, self.observers)
        state = LearnerViewState(
            time=world.time,
            world=world,
            views=views,
            companions=acting.init_slot_state(self.companions, self.net, params, 1),
            starts=jnp.ones((), bool),
        )
        return views[self.row], state

    def step_env(
        self, key: jax.Array, state: LearnerViewState, action: int | jax.Array, params: EnvParams
    ) -> tuple[jax.Array, LearnerViewState, jax.Array, jax.Array, dict[str, Any]]:
        """One step without reset: the companions act (`acting.act`), the world steps (`core.step_env`).
        Returns the learner's view, the state, its reward float32[] and terminated bool[], and info."""
        self._check(params)
        actions, companions, _, _ = acting.act(
            key,
            self.companions,
            self.net,
            params,
            self.frozen_params,
            state.companions,
            state.views[None],
            jax.tree.map(lambda x: x[None], state.world),
            state.starts[None],
            self.observers,
        )
        actions = actions[0].at[self.slot].set(jnp.asarray(action, jnp.int32))
        views, world, reward, terminated, _ = core.step_env(state.world, actions, params, self.observers)
        new_state = LearnerViewState(
            time=world.time,
            world=world,
            views=views,
            companions=acting.with_rewards(companions, reward[None]),
            starts=jnp.zeros((), bool),
        )
        info = {"actions": actions, "rewards": reward}
        return views[self.row], new_state, reward[self.slot], terminated[self.slot], info

    def is_terminated(self, state: LearnerViewState, params: EnvParams) -> jax.Array:
        """bool[] the learner is on a terminal goal (it waits there until the episode ends)."""
        return ~state.world.active[self.slot]

    def is_truncated(self, state: LearnerViewState, params: EnvParams) -> jax.Array:
        """bool[] the world's time limit, as `core.step_env` reports it (not when everyone is terminated)."""
        return (state.world.time >= params.max_steps) & ~jnp.all(~state.world.active)

    @partial(jax.jit, static_argnames=("self",))
    def step(
        self,
        key: jax.Array,
        state: LearnerViewState,
        action: int | jax.Array,
        params: EnvParams | None = None,
    ) -> tuple[jax.Array, LearnerViewState, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """gymnax's `Environment.step` (same keys, outputs and info), with the reset drawn only on steps where
        some episode of the batch ended (`any_in_batch`, as `core.step`)."""
        params = self.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        obs_st, state_st, reward, terminated, info = self.step_env(key_step, state, action, params)
        truncated = self.is_truncated(state_st, params)
        done = terminated | truncated

        def with_reset():
            fresh = self.reset_env(key_reset, params)
            return jax.tree.map(lambda r, s: jax.lax.select(done, r, s), fresh, (obs_st, state_st))

        obs, state = jax.lax.cond(any_in_batch(done), with_reset, lambda: (obs_st, state_st))
        info = {**info, "terminated": terminated, "truncated": truncated, "final_observation": obs_st}
        return obs, state, reward, terminated, truncated, info

    @property
    def name(self) -> str:
        return f"jaxsocial/{self.env_name}"

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    def action_space(self, params: EnvParams | None = None) -> spaces.Discrete:
        """Discrete(7): left, right, forward and four no-ops (docs/environment.md 2.1)."""
        return spaces.Discrete(NUM_ACTIONS)

    def observation_space(self, params: EnvParams | None = None) -> spaces.Box:
        return observation_space(self.default_params if params is None else params)


def make(name: str = "goalcycle3", slots: str | None = None, **overrides) -> tuple[LearnerView, EnvParams]:
    """`(env, params)` as `gymnax.make` returns them, for a preset with `EnvParams` overrides.

    `slots`: one entry per agent, exactly one `learner` (default: the learner in slot 0 beside the
    environment's scripted experts). Raises ValueError for a bad name, field or slot before compiling.
    """
    _, params = registry.make(name, **overrides)
    return LearnerView(name, params, slots), params
