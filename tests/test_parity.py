"""Parity with episodes recorded from the original marlgrid code (tests/data; the files are
described in docs/environment.md section 11).

Positions, directions, rewards, prestige, cycle state and done flags must match on every step; observations
must match pixel for pixel wherever the original's random within-step order could not matter
(`obs_order_dependent` False; docs/environment.md 9.11).
"""

from pathlib import Path

import numpy as np
import pytest
from conftest import U32

import jaxsocial
from jaxsocial.env import state_from_layout

DATA = Path(__file__).parent / "data"


def _matching_obs(obs, expected, order_dependent):
    """Number of observations compared; fails on any pixel difference where the order cannot matter."""
    keep = ~order_dependent
    assert np.array_equal(np.asarray(obs)[keep], expected[keep])
    return int(keep.sum())


def prestige_bound(z, episode, beta: float = 0.99) -> float:
    """How far our float32 prestige may be from the original's float64 one: each step of c = beta (c + r)
    rounds twice and uses beta rounded to float32 (3u of the result), and earlier errors decay by beta, so
    the error stays below 3u max|c| / (1 - beta) (a penalty resets both to 0 exactly)."""
    return 3 * U32 * float(np.abs(z["prestige"][episode]).max()) / (1 - beta)


@pytest.fixture(scope="module")
def goal_cycle():
    return np.load(DATA / "marlgrid_goalcycle_dev.npz")


@pytest.fixture(scope="module")
def four_rooms():
    return np.load(DATA / "marlgrid_fourroom_dev.npz")


@pytest.mark.parametrize("episode", range(8))
def test_goal_cycle_matches_marlgrid(episode, goal_cycle, rollout, observe_fn):
    z = goal_cycle
    _, params = jaxsocial.make("goalcycle3", n_goals=int(z["n_bonus_tiles"][episode]))
    state = state_from_layout(
        params,
        z["cell_type"][episode].T,
        z["init_pos"][episode],
        z["init_dir"][episode],
        z["bonus_id"][episode].T,
    )
    checked = _matching_obs(
        observe_fn(state, params), z["reset_obs"][episode], z["reset_obs_order_dependent"][episode]
    )
    obs, states, reward, terminated, truncated = rollout(
        state, z["actions"][episode].astype(np.int32), params
    )
    np.testing.assert_array_equal(states.pos, z["pos"][episode])
    np.testing.assert_array_equal(states.dir, z["dir"][episode])
    np.testing.assert_array_equal(reward, z["rewards"][episode])
    np.testing.assert_allclose(
        states.prestige, z["prestige"][episode], rtol=0, atol=prestige_bound(z, episode)
    )
    np.testing.assert_array_equal(states.cycle_state, z["bonus_state"][episode])
    assert not np.asarray(terminated).any()
    np.testing.assert_array_equal(truncated, z["done"][episode])
    checked += _matching_obs(obs, z["obs"][episode], z["obs_order_dependent"][episode])
    assert checked > 700


@pytest.mark.parametrize("episode", range(4))
def test_four_rooms_matches_marlgrid(episode, four_rooms, rollout):
    z = four_rooms
    _, params = jaxsocial.make("fourrooms")
    # The original places agents at the start of step 1 (docs/environment.md 9.7): start from those cells.
    state = state_from_layout(
        params, z["cell_type"][episode].T, z["spawn_pos"][episode], z["init_dir"][episode]
    )
    actions = np.maximum(z["actions"][episode], 0).astype(np.int32)  # padding (-1) past the episode's end
    obs, states, reward, terminated, truncated = rollout(state, actions, params)
    n = int(z["n_steps"][episode])
    np.testing.assert_array_equal(states.pos[:n], z["pos"][episode, :n])
    np.testing.assert_array_equal(states.dir[:n], z["dir"][episode, :n])
    # Decay 1 - 0.9 t / 250 in float32: 0.9 t / 250 within 3u (0.9, the product, the quotient), and the
    # subtraction scales that by 0.9 / 0.1 at most, plus its own rounding: 28u relative.
    np.testing.assert_allclose(reward[:n], z["rewards"][episode, :n], rtol=28 * U32)
    np.testing.assert_allclose(
        states.prestige[:n], z["prestige"][episode, :n], rtol=0, atol=prestige_bound(z, episode)
    )
    np.testing.assert_array_equal(states.active[:n], z["active"][episode, :n])
    np.testing.assert_array_equal(terminated[:n] | truncated[:n, None], z["agent_done"][episode, :n])
    episode_done = np.asarray(terminated).all(-1) | np.asarray(truncated)
    np.testing.assert_array_equal(episode_done[:n], z["done"][episode, :n])
    assert _matching_obs(obs[:n], z["obs"][episode, :n], z["obs_order_dependent"][episode, :n]) > 400
