"""One step of the world: turning, moving, tile rewards, goal termination and prestige
(docs/environment.md, sections 2, 3 and 5).

All agents are updated at once: agents overlap freely (ghost mode) and tiles are never consumed, so the
original's random within-step order changes no position or reward (docs/environment.md 2.2); it only decides
which agent is drawn on a shared cell, which `arrival` records.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxsocial.env.types import BONUS, DIR_VEC, FORWARD, GOAL, LEFT, RIGHT, WALL, EnvParams, EnvState


def move(state: EnvState, actions: jax.Array) -> tuple[EnvState, jax.Array]:
    """Apply turns and forward moves of active agents; walls block, agents overlap.

    Args:
        actions: int32[N].
    Returns:
        the new state (time not yet advanced) and bool[N]: the agent moved into a new cell.
    """
    active = state.active
    turn = jnp.where(actions == LEFT, -1, 0) + jnp.where(actions == RIGHT, 1, 0)
    new_dir = jnp.where(active, (state.dir + turn) % 4, state.dir)
    target = state.pos + jnp.asarray(DIR_VEC)[state.dir]
    height, width = state.grid.shape
    tx, ty = jnp.clip(target[:, 0], 0, width - 1), jnp.clip(target[:, 1], 0, height - 1)
    moved = active & (actions == FORWARD) & (state.grid[ty, tx] != WALL)
    new_pos = jnp.where(moved[:, None], jnp.stack([tx, ty], -1), state.pos)
    return state.replace(pos=new_pos, dir=new_dir), moved


def cycle_reward(
    cycle_state: jax.Array, tile_id: jax.Array, env_params: EnvParams
) -> tuple[jax.Array, jax.Array]:
    """Goal Cycle rule (docs/environment.md section 3, master `BonusTile.get_reward`) for agents entering
    bonus tile `tile_id`.

    Args:
        cycle_state: int32[N] id of the last correct tile, -1 before the first tile of the episode.
        tile_id: int32[N] id of the entered tile.
    Returns:
        float32[N] reward (before decay) and int32[N] the new cycle state.
    """
    n = env_params.n_goals
    first = cycle_state < 0
    last = jnp.where(first, (tile_id - 1) % n, cycle_state)
    correct = (last + 1) % n == tile_id
    if n == 1:  # docs/environment.md 9.14: a single tile rewards every visit (exp semantics)
        correct = jnp.ones_like(first)
    reward = jnp.where(correct, env_params.goal_reward, -env_params.penalty)
    if not env_params.initial_reward:
        reward = jnp.where(first, 0.0, reward)
    new_state = jnp.where(correct, tile_id, last)
    if env_params.reset_on_mistake:
        new_state = tile_id
    return reward.astype(jnp.float32), new_state.astype(jnp.int32)


def update_prestige(
    prestige: jax.Array, reward: jax.Array, active: jax.Array, env_params: EnvParams
) -> jax.Array:
    """Prestige (docs/environment.md section 5): code c = beta (c + r), paper c = beta c + r; a negative
    reward resets to 0; only active agents change. float32[N] -> float32[N]."""
    beta = env_params.prestige_beta
    grown = beta * (prestige + reward) if env_params.prestige_formula == "code" else beta * prestige + reward
    new = jnp.where(reward < 0, 0.0, grown)
    return jnp.where(active, new, prestige).astype(jnp.float32)


def update_presence(state: EnvState) -> EnvState:
    """Slots whose presence window (`EnvState.window`) starts at `state.time` join, active, where they were
    spawned; slots whose window ends leave (absent and inactive) (docs/environment.md 10.4)."""
    join, leave = state.window[:, 0], state.window[:, 1]
    joins = state.time == join
    leaves = state.time == leave
    return state.replace(
        present=(state.present | joins) & ~leaves,
        active=(state.active | joins) & ~leaves,
        arrival=jnp.where(joins, state.time, state.arrival),
    )


def world_step(state: EnvState, actions: jax.Array, env_params: EnvParams) -> tuple[EnvState, jax.Array]:
    """Advance time, move, pay tile rewards, update prestige and deactivate agents on a terminal goal.

    Returns the new state and float32[N] rewards.
    """
    time = state.time + 1
    moved_state, moved = move(state, actions)
    x, y = moved_state.pos[:, 0], moved_state.pos[:, 1]
    tile = state.grid[y, x]
    on_bonus = moved & (tile == BONUS)
    on_goal = moved & (tile == GOAL)
    cycle_r, cycle_state = cycle_reward(state.cycle_state, state.goal_id[y, x].astype(jnp.int32), env_params)
    reward = jnp.where(on_bonus, cycle_r, 0.0) + jnp.where(on_goal, env_params.goal_reward, 0.0)
    if env_params.reward_decay:
        reward = reward * (1.0 - 0.9 * time / env_params.max_steps)
    reward = reward.astype(jnp.float32)
    new_state = moved_state.replace(
        cycle_state=jnp.where(on_bonus, cycle_state, state.cycle_state),
        prestige=update_prestige(state.prestige, reward, state.active, env_params),
        active=state.active & ~on_goal,
        arrival=jnp.where(moved, time, state.arrival),
        time=time,
    )
    return update_presence(new_state), reward
