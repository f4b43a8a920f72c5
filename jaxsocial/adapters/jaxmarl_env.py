"""A social environment as a JaxMARL `MultiAgentEnv` (`pip install -e ".[jaxmarl]"`): every slot is an agent.

    env = jaxmarl_env.make("goalcycle3")               # agents 'agent_0', 'agent_1', 'agent_2'
    obs, state = env.reset(key)                        # obs {'agent_0': uint8[21, 21, 3], ...}
    obs, state, rewards, dones, infos = env.step(key, state, {a: action for a in env.agents})

The state is the world's `EnvState`; `step(key, ...)` is `core.step(jax.random.split(key)[1], ...)` (the
native step, auto-reset included) with the arrays split into per-agent dicts. `dones[a]` is the agent's
episode over (it is on a terminal goal, or the episode ended), `dones["__all__"]` the episode's end;
`infos` holds per-agent bool[N] arrays `terminated` and `truncated`, shaped as JaxMARL's wrappers expect.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

try:
    from jaxmarl.environments import spaces
    from jaxmarl.environments.multi_agent_env import MultiAgentEnv
except ModuleNotFoundError as err:  # pragma: no cover - depends on the installed extras
    if err.name != "jaxmarl":
        raise  # jaxmarl is installed but one of its own imports is missing: show that one
    raise ImportError('jaxsocial.adapters.jaxmarl_env needs jaxmarl: pip install -e ".[jaxmarl]"') from err

from jaxsocial.env import core, registry
from jaxsocial.env.types import NUM_ACTIONS, EnvParams, EnvState


class SocialMultiAgentEnv(MultiAgentEnv):
    """The JaxMARL environment of `params` (see the module doc); `name` is the preset's."""

    def __init__(self, name: str, params: EnvParams):
        super().__init__(num_agents=params.n_agents)
        self.env_name = name
        self.params = params
        low, high, dtype = (0, 255, jnp.uint8) if params.observation == "rgb" else (-1, 127, jnp.int8)
        self.observation_spaces = {a: spaces.Box(low, high, params.obs_shape, dtype) for a in self.agents}
        self.action_spaces = {a: spaces.Discrete(NUM_ACTIONS) for a in self.agents}

    def observation_space(self, agent: str | None = None) -> spaces.Box:
        """Every slot's observation space (one for all, so the agent may be left out, as JaxMARL's own
        baselines do)."""
        return self.observation_spaces[agent or self.agents[0]]

    def action_space(self, agent: str | None = None) -> spaces.Discrete:
        """Every slot's action space (one for all; the agent may be left out)."""
        return self.action_spaces[agent or self.agents[0]]

    def _split(self, x: jax.Array) -> dict[str, jax.Array]:
        return {a: x[i] for i, a in enumerate(self.agents)}

    def _joint(self, actions: dict[str, Any]) -> jax.Array:
        """int[N] actions in agent order; ValueError (at trace time) unless every agent has one."""
        if set(actions) != set(self.agents):
            raise ValueError(f"actions must have one entry per agent {self.agents}, got {sorted(actions)}")
        return jnp.stack([jnp.asarray(actions[a]) for a in self.agents])

    @partial(jax.jit, static_argnums=(0,))
    def reset(self, key: jax.Array) -> tuple[dict[str, jax.Array], EnvState]:
        """A new episode (`core.reset`)."""
        obs, state = core.reset(key, self.params)
        return self._split(obs), state

    def _outputs(self, obs, reward, terminated, truncated):
        done = jnp.all(terminated) | truncated
        dones = {**self._split(terminated | done), "__all__": done}
        infos = {"terminated": terminated, "truncated": jnp.full(self.num_agents, truncated)}
        return self._split(obs), self._split(reward), dones, infos

    def step_env(self, key: jax.Array, state: EnvState, actions: dict[str, Any]):
        """One step without reset (`core.step_env`): obs, state, rewards, dones, infos."""
        obs, state, reward, terminated, truncated = core.step_env(state, self._joint(actions), self.params)
        obs, rewards, dones, infos = self._outputs(obs, reward, terminated, truncated)
        return obs, state, rewards, dones, infos

    @partial(jax.jit, static_argnums=(0,))
    def step(
        self, key: jax.Array, state: EnvState, actions: dict[str, Any], reset_state: EnvState | None = None
    ):
        """JaxMARL's `MultiAgentEnv.step` (same outputs; `reset_state` replaces the new episode), computed by
        the native `core.step`, which draws a new episode only on steps where some episode of the batch
        ended."""
        _, key_reset = jax.random.split(key)
        joint = self._joint(actions)
        if reset_state is None:
            obs, state, reward, terminated, truncated, _ = core.step(key_reset, state, joint, self.params)
        else:
            obs, state, reward, terminated, truncated = core.step_env(state, joint, self.params)
            done = jnp.all(terminated) | truncated
            state = jax.tree.map(lambda r, s: jax.lax.select(done, r, s), reset_state, state)
            obs = jax.lax.select(done, core.observe(reset_state, self.params), obs)
        obs, rewards, dones, infos = self._outputs(obs, reward, terminated, truncated)
        return obs, state, rewards, dones, infos

    def get_obs(self, state: EnvState) -> dict[str, jax.Array]:
        return self._split(core.observe(state, self.params))

    @partial(jax.jit, static_argnums=(0,))
    def get_avail_actions(self, state: EnvState) -> dict[str, jax.Array]:
        """Every action is always available (3-6 are no-ops)."""
        return {a: jnp.ones(NUM_ACTIONS, bool) for a in self.agents}

    @property
    def name(self) -> str:
        return f"jaxsocial/{self.env_name}"

    @property
    def agent_classes(self) -> dict[str, list[str]]:
        return {"agent": list(self.agents)}


def make(name: str = "goalcycle3", **overrides) -> SocialMultiAgentEnv:
    """The JaxMARL environment of a preset with `EnvParams` overrides (ValueError if bad), as
    `jaxmarl.make` returns one."""
    _, params = registry.make(name, **overrides)
    return SocialMultiAgentEnv(name, params)
