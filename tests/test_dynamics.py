"""Movement, the goal-cycle reward rule, goal termination and prestige on hand-built scenes
(docs/environment.md, sections 2, 3 and 5)."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxsocial
from jaxsocial.env import state_from_layout
from jaxsocial.env.types import FORWARD, LEFT, PICKUP, RIGHT

L, R, F = LEFT, RIGHT, FORWARD
CORRIDOR3 = ["#########", "#.0.1.2.#", "#########"]
CORRIDOR4 = ["###########", "#.0.1.2.3.#", "###########"]


def corridor_params(map_rows, n_goals, **kw):
    kw = {"clutter_density": 0.0, "n_agents": 1, **kw}
    return jaxsocial.make("goalcycle3", width=len(map_rows[0]), height=len(map_rows), n_goals=n_goals, **kw)[
        1
    ]


def run(rollout, state, params, actions):
    """Play a list of per-step action lists; returns (states, rewards float[T, N])."""
    actions = np.asarray(actions, np.int32).reshape(len(actions), -1)
    _, states, reward, _, _ = rollout(state, actions, params)
    return states, np.asarray(reward)


def test_spec_trace_three_goals(rollout):
    """The worked example of docs/environment.md section 3: 1->6->2->6 over tiles 0,1,2 gives
    +1 +1 +1, -1.5, +1, +1 +1."""
    params = corridor_params(CORRIDOR3, 3)
    state = state_from_layout(params, CORRIDOR3, [(1, 1)], [0])
    actions = [F] * 5 + [L, L] + [F] * 4 + [R, R] + [F] * 4
    states, reward = run(rollout, state, params, actions)
    paid = reward[:, 0][reward[:, 0] != 0].tolist()
    assert paid == [1.0, 1.0, 1.0, -1.5, 1.0, 1.0, 1.0]
    # No cycle reset after the mistake: the state stays at the last correct tile (2), so 0 is next.
    np.testing.assert_array_equal(states.cycle_state[:, 0][reward[:, 0] != 0], [0, 1, 2, 2, 0, 1, 2])


def test_first_goal_always_rewarded_and_reentry_penalised(rollout):
    params = corridor_params(CORRIDOR3, 3)
    state = state_from_layout(params, CORRIDOR3, [(3, 1)], [0])  # starts between tiles 0 and 1
    # Enter tile 1 first (+1), step off and back on (-1.5), then 2 (+1: the mistake did not reset the
    # cycle), then step off and back onto 2 (-1.5).
    actions = [F, F, L, L, F, L, L, F, F, F, L, L, F]
    _, reward = run(rollout, state, params, actions)
    assert reward[reward != 0].tolist() == [1.0, -1.5, 1.0, -1.5]


def test_initial_reward_off_and_reset_on_mistake(rollout):
    params = corridor_params(CORRIDOR3, 3, initial_reward=False, reset_on_mistake=True)
    state = state_from_layout(params, CORRIDOR3, [(3, 1)], [0])
    # tile 1 first (0), tile 2 (+1), back to 1 (-1.5, cycle restarts from 1), 2 again (+1 after reset).
    actions = [F, F, F, L, L, F, F, R, R, F, F]
    _, reward = run(rollout, state, params, actions)
    np.testing.assert_array_equal(reward[[0, 2, 6, 10], 0], [0.0, 1.0, -1.5, 1.0])
    assert np.count_nonzero(reward) == 3


def test_four_goals_order(rollout):
    params = corridor_params(CORRIDOR4, 4, penalty=2.0)
    state = state_from_layout(params, CORRIDOR4, [(1, 1)], [0])
    actions = [F] * 7 + [L, L] + [F] * 6 + [R, R] + [F] * 2
    # 0 1 2 3 (+4), back over 2 (-2) and 1 (-2) to 0 (+1: 0 follows 3), then 1 (+1).
    _, reward = run(rollout, state, params, actions)
    assert reward[reward != 0].tolist() == [1.0, 1.0, 1.0, 1.0, -2.0, -2.0, 1.0, 1.0]


def test_walls_block_agents_overlap_noops_and_turns(rollout):
    rows = ["#####", "#...#", "#.#.#", "#...#", "#####"]
    params = corridor_params(rows, 1, n_agents=3)
    state = state_from_layout(params, rows, [(1, 1), (3, 1), (1, 3)], [2, 2, 3])
    # agent 0 faces the border wall; agent 1 walks west twice onto (1, 1); agent 2 turns and does no-ops.
    states, reward = run(rollout, state, params, [[F, F, R], [L, F, PICKUP], [F, F, 6]])
    np.testing.assert_array_equal(states.pos[-1], [(1, 2), (1, 1), (1, 3)])
    # agent 0 turned left (west -> south) then moved south; agent 2: right (north -> east), then no-ops.
    np.testing.assert_array_equal(states.dir[-1], [1, 2, 0])
    np.testing.assert_array_equal(states.pos[0], [(1, 1), (2, 1), (1, 3)])  # walls block, agents share
    assert not reward.any()
    state = state_from_layout(params, rows, [(1, 1), (1, 1), (2, 1)], [1, 1, 2])
    states, _ = run(rollout, state, params, [[F, F, F]])
    np.testing.assert_array_equal(states.pos[0], [(1, 2), (1, 2), (1, 1)])  # ghost mode: all share cells


def test_prestige_code_and_paper_formulas(rollout):
    for formula, expected in [("code", [0.99, 0.9801, 1.960299]), ("paper", [1.0, 0.99, 1.9801])]:
        params = corridor_params(CORRIDOR3, 3, prestige_formula=formula)
        state = state_from_layout(params, CORRIDOR3, [(1, 1)], [0])
        states, _ = run(rollout, state, params, [F, F, F, L, L, F, F])
        np.testing.assert_allclose(states.prestige[:3, 0], expected, rtol=1e-6)
        assert states.prestige[-1, 0] == 0.0  # a penalty resets prestige


def test_reward_decay_goal_termination_and_frozen_done_agent(rollout):
    rows = ["#######", "#..G..#", "#######"]
    params = corridor_params(rows, 1, n_agents=2, reward_decay=True, max_steps=10)
    state = state_from_layout(params, rows, [(1, 1), (5, 1)], [0, 2])
    states, reward = run(rollout, state, params, [[F, L], [F, F], [L, R], [F, F]])
    # Agent 0 enters the goal at step 2: reward 1 - 0.9 * 2 / 10; it then stays, frozen, and ignores actions.
    np.testing.assert_allclose(reward[:, 0], [0, 1 - 0.18, 0, 0], rtol=1e-6)
    np.testing.assert_array_equal(states.active[:, 0], [True, False, False, False])
    np.testing.assert_array_equal(states.pos[-1, 0], (3, 1))
    assert int(states.dir[-1, 0]) == 0
    np.testing.assert_allclose(states.prestige[1:, 0], 0.99 * 0.82, rtol=1e-6)
    assert np.all(np.asarray(states.active[:, 1]))
    # Agent 1 turns south, bumps the wall, turns back west and steps: walls block without penalty.
    np.testing.assert_array_equal(states.pos[:, 1], [(5, 1), (5, 1), (5, 1), (4, 1)])


@pytest.mark.parametrize("n_goals", [1])
def test_single_goal_rewards_every_visit(rollout, n_goals):
    rows = ["#####", "#.0.#", "#####"]
    params = corridor_params(rows, n_goals)
    state = state_from_layout(params, rows, [(1, 1)], [0])
    _, reward = run(rollout, state, params, [F, F, L, L, F])
    assert reward[reward != 0].tolist() == [1.0, 1.0]


def test_truncation_at_max_steps(step_env):
    params = corridor_params(CORRIDOR3, 3, max_steps=2)
    state = state_from_layout(params, CORRIDOR3, [(1, 1)], [1])
    for expected in (False, True):
        _, state, _, terminated, truncated = step_env(state, jnp.array([LEFT]), params)
        assert bool(truncated) == expected and not terminated.any()
