"""Expert dropout and drop-in within episodes (docs/environment.md 10.4): presence windows drawn at reset,
slots leaving and joining during `step`, and absent slots not drawn, not acting and not rewarded."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsocial
from jaxsocial.env import core
from jaxsocial.env.types import FORWARD, PICKUP

LAYOUT = [
    "#######",
    "#.....#",
    "#.....#",
    "#.....#",
    "#.....#",
    "#0....#",
    "#######",
]
NEVER = core.NEVER


def scene(window):
    """Learner (slot 0) at (3, 4) facing north; expert 1 two cells ahead at (3, 2) facing east; expert 2 on
    (2, 5) facing west, in front of bonus tile 0 at (1, 5). All in the learner's view. Symbolic views;
    `window` int[3, 2] presence windows."""
    params = jaxsocial.make(
        "goalcycle3", width=7, height=7, n_goals=1, clutter_density=0.0, observation="symbolic"
    )[1]
    window = np.asarray(window)
    state = core.state_from_layout(
        params, LAYOUT, pos=[[3, 4], [3, 2], [2, 5]], dir=[3, 0, 2], present=window[:, 0] == 0, window=window
    )
    return params, state


def seen_agents(obs):
    """Slots visible in the learner's symbolic view (the agent channel holds slot + 1)."""
    return {int(a) - 1 for a in np.unique(np.asarray(obs[0, ..., 1]))} - {-1}


def test_a_slot_leaves_at_the_end_of_its_window(rollout):
    params, state = scene([[0, NEVER], [0, 2], [0, NEVER]])
    actions = jnp.array([[PICKUP, FORWARD, FORWARD]] * 3, jnp.int32)
    obs, states, rewards, terminated, _ = rollout(state, actions, params)
    assert seen_agents(obs[0]) == {0, 1, 2} and seen_agents(obs[1]) == {0, 2}  # expert 1 gone after step 2
    np.testing.assert_array_equal(states.present[:, 1], [True, False, False])
    np.testing.assert_array_equal(states.active[:, 1], [True, False, False])
    np.testing.assert_array_equal(terminated[:, 1], [False, True, True])  # absent slots are terminated
    # Expert 1 acts during its last step, then no longer moves, whatever it is told.
    np.testing.assert_array_equal(states.pos[:, 1], [[4, 2], [5, 2], [5, 2]])
    assert float(rewards[0, 2]) == 1.0  # expert 2, still present, is paid as usual


def test_a_slot_joins_at_the_start_of_its_window_where_it_spawned(rollout):
    params, state = scene([[0, NEVER], [2, NEVER], [0, NEVER]])
    assert not bool(state.present[1]) and not bool(state.active[1])
    obs, states, rewards, terminated, _ = rollout(state, jnp.full((3, 3), PICKUP, jnp.int32), params)
    np.testing.assert_array_equal(states.present[:, 1], [False, True, True])
    np.testing.assert_array_equal(terminated[:, 1], [True, False, False])
    assert 1 not in seen_agents(obs[0]) and 1 in seen_agents(obs[1])
    np.testing.assert_array_equal(states.pos[1, 1], [3, 2])
    assert int(states.arrival[1, 1]) == 2


def test_absent_slot_does_not_act_before_joining(rollout):
    params, state = scene([[0, NEVER], [0, NEVER], [3, NEVER]])
    actions = jnp.array([[PICKUP, PICKUP, FORWARD]] * 4, jnp.int32)
    _, states, rewards, _, _ = rollout(state, actions, params)
    np.testing.assert_array_equal(rewards[:3, 2], [0, 0, 0])  # absent: the forward moves are ignored
    np.testing.assert_array_equal(states.pos[2, 2], [2, 5])
    assert float(rewards[3, 2]) == 1.0  # joined at step 3, steps onto the tile at step 4


def windows(n_episodes=2000, **overrides):
    params = jaxsocial.make("goalcycle3", **overrides)[1]
    keys = jax.random.split(jax.random.key(0), n_episodes)
    _, states = jax.jit(jax.vmap(core.reset, in_axes=(0, None)), static_argnums=1)(keys, params)
    return np.asarray(states.window), np.asarray(states.present)


def test_reset_draws_windows_with_the_configured_probabilities_and_steps():
    window, present = windows(dropout_prob=0.3, dropin_prob=0.2, dropout_min_step=10, dropout_max_step=20)
    np.testing.assert_array_equal(window[:, 0], [[0, NEVER]] * len(window))  # slot 0 (< solo_agents) stays
    others = window[:, 1:].reshape(-1, 2)
    leaves, joins = others[:, 1] != NEVER, others[:, 0] != 0
    assert not np.any(leaves & joins)
    assert abs(leaves.mean() - 0.3) < 0.03 and abs(joins.mean() - 0.2) < 0.03
    steps = np.concatenate([others[leaves, 1], others[joins, 0]])
    assert steps.min() == 10 and steps.max() == 20
    np.testing.assert_array_equal(present[:, 1:].ravel(), ~joins)


def test_fixed_dropout_step_and_solo_slots_never_join():
    window, _ = windows(200, dropout_prob=1.0, dropout_min_step=125, dropout_max_step=125)
    np.testing.assert_array_equal(window[:, 1:], [[[0, 125], [0, 125]]] * 200)
    window, present = windows(200, solo_prob=1.0, dropin_prob=1.0)
    assert np.all(window[:, 1:, 0] == NEVER) and not present[:, 1:].any()


@pytest.mark.parametrize("overrides", [{}, {"dropout_prob": 0.5, "dropin_prob": 0.5}])
def test_auto_reset_redraws_windows(overrides):
    params = jaxsocial.make("goalcycle3", max_steps=4, **overrides)[1]
    reset, step = jax.jit(core.reset, static_argnums=1), jax.jit(core.step, static_argnums=3)
    _, state = reset(jax.random.key(0), params)
    for k in range(4):
        _, state, *_ = step(jax.random.key(k + 1), state, jnp.zeros(3, jnp.int32), params)
    assert int(state.time) == 0
    fresh = reset(jax.random.key(4), params)[1]
    np.testing.assert_array_equal(state.window, fresh.window)
