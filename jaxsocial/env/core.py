"""The public environment API: reset, step with auto-reset, and states built from explicit layouts.

Shapes (N agents, one environment; batch with `jax.vmap(..., in_axes=(0, 0, 0, None))`):
`obs uint8[N, 21, 21, 3]`, `reward float32[N]`, `terminated bool[N]`, `truncated bool[]`.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxsocial.env.batching import any_in_batch
from jaxsocial.env.dynamics import world_step
from jaxsocial.env.layouts import generate, parse_ascii
from jaxsocial.env.observe import Observers, observe
from jaxsocial.env.types import BONUS, NUM_ACTIONS, WALL, EnvParams, EnvState


def _present(key: jax.Array, env_params: EnvParams) -> jax.Array:
    """bool[N] who takes part in a new episode: everyone, or in a solo episode the first `solo_agents`."""
    n = env_params.n_agents
    if env_params.solo_prob == 0.0:
        return jnp.ones(n, bool)
    solo = jax.random.bernoulli(key, env_params.solo_prob)
    return ~solo | (jnp.arange(n) < env_params.solo_agents)


NEVER = np.iinfo(np.int32).max
"""A presence-window bound no episode reaches."""


def fixed_window(present) -> jax.Array:
    """int32[N, 2] presence windows of slots that neither leave nor join: [0, never) if present, else
    [never, never)."""
    present = jnp.asarray(present, bool)
    return jnp.stack([jnp.where(present, 0, NEVER), jnp.full(present.shape, NEVER)], -1).astype(jnp.int32)


def _window(key: jax.Array, present: jax.Array, env_params: EnvParams) -> jax.Array:
    """int32[N, 2] each slot's presence window [join, leave) (docs/environment.md 10.4): slots from
    `solo_agents` on leave (`dropout_prob`) or join (`dropin_prob`) at a uniform step in
    [dropout_min_step, dropout_max_step]; slots absent from a solo episode never join."""
    n = env_params.n_agents
    if not env_params.changes_presence:
        return fixed_window(present)
    k_kind, k_step = jax.random.split(key)
    u = jax.random.uniform(k_kind, (n,))
    other = jnp.arange(n) >= env_params.solo_agents
    leaves = other & (u < env_params.dropout_prob)
    joins = other & ~leaves & (u < env_params.dropout_prob + env_params.dropin_prob)
    at = jax.random.randint(k_step, (n,), env_params.dropout_min_step, env_params.dropout_last_step + 1)
    join = jnp.where(present, jnp.where(joins, at, 0), NEVER)
    leave = jnp.where(leaves, at, NEVER)
    return jnp.stack([join, leave], -1).astype(jnp.int32)


def _spawn(key: jax.Array, grid: jax.Array, goal_id: jax.Array, spawn_mask: jax.Array, env_params: EnvParams):
    k_pos, k_dir = jax.random.split(key)
    n = env_params.n_agents
    present = _present(jax.random.fold_in(key, 1), env_params)
    window = _window(jax.random.fold_in(key, 2), present, env_params)
    present = window[:, 0] == 0
    cells = jax.random.categorical(k_pos, jnp.where(spawn_mask.ravel(), 0.0, -jnp.inf), shape=(n,))
    y, x = jnp.divmod(cells, env_params.width)
    direction = (
        jax.random.randint(k_dir, (n,), 0, 4) if env_params.random_spawn_dir else jnp.zeros(n, jnp.int32)
    )
    return EnvState(
        grid=grid,
        goal_id=goal_id,
        pos=jnp.stack([x, y], -1).astype(jnp.int32),
        dir=direction.astype(jnp.int32),
        cycle_state=jnp.full(n, -1, jnp.int32),
        prestige=jnp.zeros(n, jnp.float32),
        active=present,
        present=present,
        window=window,
        arrival=jnp.zeros(n, jnp.int32),
        time=jnp.zeros((), jnp.int32),
    )


def reset(key: jax.Array, env_params: EnvParams, observers: Observers = None) -> tuple[jax.Array, EnvState]:
    """A new episode: a fresh layout and agents placed independently and uniformly on spawn cells
    (they may share a cell or stand on a bonus tile, docs/environment.md 1.3); with `env_params.solo_prob` it
    is a solo episode (see `EnvParams.solo_prob`, docs/environment.md 10.2). Returns `(obs, state)`, obs
    the views of `observers` only (static agent indices, `observe.Observers`; None: every agent's)."""
    state = _new_episode(key, env_params)
    return observe(state, env_params, observers), state


def _new_episode(key: jax.Array, env_params: EnvParams) -> EnvState:
    """The state of `reset`, without rendering it."""
    k_layout, k_spawn = jax.random.split(key)
    layout = generate(k_layout, env_params)
    return _spawn(k_spawn, layout.grid, layout.goal_id, layout.spawn_mask, env_params)


def check_actions(actions: jax.Array, env_params: EnvParams) -> None:
    """Raise ValueError unless `actions` is an integer array of shape (n_agents,) (checked when traced) with
    values in the action space [0, 7) (checked when the values are known: eager calls; under `jit` or `vmap`
    an out-of-range action is not checked and does nothing, docs/environment.md 10.1)."""
    shape = getattr(actions, "shape", None)
    if shape != (env_params.n_agents,) or not jnp.issubdtype(jnp.asarray(actions).dtype, jnp.integer):
        raise ValueError(
            f"actions must be an integer array of shape ({env_params.n_agents},), one per agent; got "
            f"{getattr(actions, 'dtype', type(actions))} {shape}. Batch with jax.vmap."
        )
    if not isinstance(actions, jax.core.Tracer):
        values = np.asarray(actions)
        if values.min() < 0 or values.max() >= NUM_ACTIONS:
            raise ValueError(
                f"actions must be in [0, {NUM_ACTIONS}) (Discrete({NUM_ACTIONS})), got {values.tolist()}"
            )


def _advance(
    state: EnvState, actions: jax.Array, env_params: EnvParams
) -> tuple[EnvState, jax.Array, jax.Array, jax.Array]:
    """The world step of `step_env`, without rendering: (state, reward, terminated, truncated)."""
    check_actions(actions, env_params)
    state, reward = world_step(state, actions.astype(jnp.int32), env_params)
    terminated = ~state.active
    truncated = (state.time >= env_params.max_steps) & ~jnp.all(terminated)
    return state, reward, terminated, truncated


def step_env(
    state: EnvState, actions: jax.Array, env_params: EnvParams, observers: Observers = None
) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, jax.Array]:
    """One step without auto-reset.

    Args:
        actions: int32[N], values in [0, 7) (3-6 are no-ops).
        observers: whose views `obs` holds (static agent indices, `observe.Observers`; None: every agent's).
    Returns:
        obs, state, reward float32[N], terminated bool[N] (agent is on a terminal goal; stays True for the
        rest of the episode), truncated bool[] (time limit reached while some agent is still active).
    """
    state, reward, terminated, truncated = _advance(state, actions, env_params)
    return observe(state, env_params, observers), state, reward, terminated, truncated


def _episode_done(terminated: jax.Array, truncated: jax.Array) -> jax.Array:
    return jnp.all(terminated, axis=-1) | truncated


def step(
    key: jax.Array, state: EnvState, actions: jax.Array, env_params: EnvParams, observers: Observers = None
) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
    """One step with auto-reset (gymnax 1.0 shape). `obs` and `final_obs` hold the views of `observers`
    only (static agent indices, `observe.Observers`; None: every agent's), e.g. those a trainer's networks
    read.

    When every agent is terminated or time runs out, the returned `obs` and `state` belong to a new
    episode drawn with `key`; `info["final_obs"]` holds the last observation of the finished episode
    (equal to `obs` otherwise) and `info["done"]` says whether the episode ended.

    Each observation is rendered once. The reset and the final observation are `lax.cond`s on
    `any_in_batch(done)`, so steps where no episode ended neither draw a new episode nor render twice, also
    under `jax.vmap` (where a step in which some episode ended resets, and selects, only the environments
    whose episode ended). A caller that ignores `final_obs` never renders it (it is dead code under `jit`).
    """
    new_state, reward, terminated, truncated = _advance(state, actions, env_params)
    done = _episode_done(terminated, truncated)
    some_ended = any_in_batch(done)

    def with_reset():
        fresh = _new_episode(key, env_params)
        return jax.tree.map(lambda r, s: jnp.where(done, r, s), fresh, new_state)

    next_state = jax.lax.cond(some_ended, with_reset, lambda: new_state)
    obs = observe(next_state, env_params, observers)
    final_obs = jax.lax.cond(some_ended, lambda: observe(new_state, env_params, observers), lambda: obs)
    return obs, next_state, reward, terminated, truncated, {"final_obs": final_obs, "done": done}


def step_batch(
    keys: jax.Array, states: EnvState, actions: jax.Array, env_params: EnvParams, observers: Observers = None
) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
    """`step` over a leading batch axis (keys [B], states [B, ...], actions int32[B, N]): exactly
    `jax.vmap(step, in_axes=(0, 0, 0, None))`, which generates and renders new episodes only on steps where
    some episode of the batch ended."""
    one = functools.partial(step, observers=observers)
    return jax.vmap(one, in_axes=(0, 0, 0, None))(keys, states, actions, env_params)


def _layout_arrays(layout: str | list[str] | np.ndarray, goal_id) -> tuple[np.ndarray, np.ndarray]:
    """The tiles uint8[H, W] and bonus ids int8[H, W] of `state_from_layout`'s `layout` (an ASCII map or a
    tile array) and `goal_id` (None: the map's digits; for an array, its bonus tiles in row-major order)."""
    if isinstance(layout, str | list):
        grid, parsed_ids = parse_ascii(layout)
        goal_id = parsed_ids if goal_id is None else goal_id
    else:
        grid = np.asarray(layout, np.uint8)
    if goal_id is None:
        goal_id = np.full(grid.shape, -1, np.int8)
        bonus = np.flatnonzero(grid == BONUS)
        goal_id.ravel()[bonus] = np.arange(len(bonus))
    return grid, np.asarray(goal_id, np.int8)


def _check_scene(
    env_params: EnvParams, grid: np.ndarray, goal_id: np.ndarray, pos: np.ndarray, dir: np.ndarray
) -> None:
    """ValueError unless the tiles and bonus ids fit `env_params` and its N agents (int32[N, 2] positions,
    int32[N] directions) stand on free cells inside the grid."""
    n = env_params.n_agents
    if grid.shape != (env_params.height, env_params.width) or goal_id.shape != grid.shape:
        raise ValueError(
            f"layout is {grid.shape} (rows, cols) but env_params say {(env_params.height, env_params.width)}"
        )
    if len(pos) != n or len(dir) != n:
        raise ValueError(f"need {n} agent positions and directions, got {len(pos)} and {len(dir)}")
    if np.any((pos < 0) | (pos >= [env_params.width, env_params.height])) or np.any(
        grid[pos[:, 1], pos[:, 0]] == WALL
    ):
        raise ValueError(f"agents must stand on free cells inside the grid, got {pos.tolist()}")
    if np.any(goal_id >= env_params.n_goals):
        raise ValueError(f"bonus ids must be < n_goals={env_params.n_goals}")


def _per_agent(values, default, n: int, dtype) -> jax.Array:
    """`values` (None: `default`) broadcast to one per agent, [n] of `dtype`."""
    return jnp.asarray(np.broadcast_to(default if values is None else values, (n,)), dtype)


def state_from_layout(
    env_params: EnvParams,
    layout: str | list[str] | np.ndarray,
    pos,
    dir,
    goal_id=None,
    *,
    prestige=None,
    cycle_state=None,
    active=None,
    present=None,
    arrival=None,
    window=None,
    time: int = 0,
) -> EnvState:
    """Build an exact state from an explicit layout (for tests, notebooks and scripted scenes).

    Args:
        env_params: the environment's parameters; the layout must be `env_params.height x env_params.width`.
        layout: an ASCII map (rows along y: '#' wall, '.' empty, 'G' goal, '0'-'9' bonus tile with that
            cycle id; see `layouts.parse_ascii`) or a uint8[H, W] array of tile types indexed [y, x].
        pos: int[N, 2] agent (x, y) positions; x points east, y south.
        dir: int[N] directions (0 east, 1 south, 2 west, 3 north).
        goal_id: int8[H, W] bonus ids when `layout` is an array (default: bonus tiles numbered in
            row-major order).
        prestige, cycle_state, active, present, arrival: optional per-agent values (defaults: 0, -1,
            True, True, 0); absent agents (`present` False) are also inactive.
        window: optional int[N, 2] presence windows [join, leave) (default: present ones from step 0 on,
            absent ones never).
        time: steps already taken in the episode.
    """
    grid, goal_id = _layout_arrays(layout, goal_id)
    n = env_params.n_agents
    pos, dir = np.asarray(pos, np.int32).reshape(-1, 2), np.asarray(dir, np.int32).reshape(-1)
    _check_scene(env_params, grid, goal_id, pos, dir)
    present = _per_agent(present, True, n, bool)
    window = fixed_window(present) if window is None else window

    return EnvState(
        grid=jnp.asarray(grid),
        goal_id=jnp.asarray(goal_id),
        pos=jnp.asarray(pos),
        dir=jnp.asarray(dir % 4),
        cycle_state=_per_agent(cycle_state, -1, n, jnp.int32),
        prestige=_per_agent(prestige, 0.0, n, jnp.float32),
        active=_per_agent(active, True, n, bool) & present,
        present=present,
        window=jnp.asarray(np.broadcast_to(window, (n, 2)), jnp.int32),
        arrival=_per_agent(arrival, 0, n, jnp.int32),
        time=jnp.asarray(time, jnp.int32),
    )


class Env:
    """A named environment: gymnax-style methods over static `EnvParams`.

    `obs, state = env.reset(key, env_params)`;
    `obs, state, reward, terminated, truncated, info = env.step(key, state, actions, env_params)`.
    """

    def __init__(self, name: str, env_params: EnvParams):
        self.name = name
        self.default_params = env_params

    reset = staticmethod(reset)
    step = staticmethod(step)
    step_batch = staticmethod(step_batch)
    step_env = staticmethod(step_env)
    observe = staticmethod(observe)

    @property
    def num_agents(self) -> int:
        return self.default_params.n_agents

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    def __repr__(self) -> str:
        return f"Env({self.name!r}, {self.default_params})"
