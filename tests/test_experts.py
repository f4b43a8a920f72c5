"""Scripted experts: the explorer's penalty bound, the oracle, the navigator, imperfect variants, batching.

Compile time dominates on CPU, so each environment configuration is compiled once: hand-built scenes
(embedded in 13x13 grids) and random layouts run in the same batch, and Goal Cycle agents, which never
interact, play side by side in one environment.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsocial
from jaxsocial.agents import expert_spec
from jaxsocial.agents.expert_spec import ExpertSpec, check_playable, parse_expert
from jaxsocial.agents.experts import act_batch, act_one, init_memory
from jaxsocial.env import core, state_from_layout
from jaxsocial.env.dynamics import world_step
from jaxsocial.env.layouts import generate
from jaxsocial.env.types import BONUS, FORWARD, NUM_ACTIONS, RIGHT, WALL

EXPLORER, ORACLE, NAVIGATOR = ExpertSpec("explorer"), ExpertSpec("oracle"), ExpertSpec("navigator")
RANDOM = None  # a slot playing uniformly random actions
NOISY, NOISY_ORACLE = ExpertSpec("explorer", epsilon=0.3), parse_expert("oracle:epsilon=0.1,forget=0.02")
FORGETFUL = parse_expert("explorer:forget=0.02")
# Slots of the Goal Cycle runs. Slot 2 of goalcycle3 is an explorer that is shown the rewards it would get
# with penalty=0 and initial_reward=False (those change the rewards only, never the cycle state).
SPECS3 = (EXPLORER, ORACLE, EXPLORER, NOISY, NOISY_ORACLE, RANDOM)
BLIND = 2
SPECS4 = (EXPLORER, ORACLE, FORGETFUL, RANDOM)

# Three tiles in a row: going from 0 to 2 means a detour around 1. The corridor forces crossings.
OPEN3 = ["#########", "#.......#", "#0..1..2#", "#.......#", "#########"]
CORRIDOR3 = ["#########", "#########", "#0..1..2#", "#########", "#########"]
ROOM4 = ["#######", "#0...1#", "#.....#", "#..#..#", "#.....#", "#2...3#", "#######"]
ORDERS3 = list(itertools.permutations(range(3)))
ORDERS4 = list(itertools.permutations(range(4)))
STARTS3 = [(1, 1, 0), (4, 3, 2), (7, 1, 1)]  # (x, y, dir)
STARTS4 = [(3, 2, 3), (1, 3, 0)]
N_RANDOM = 64  # random-layout environments per run (2 episodes each)


def new_episode(key, params):
    """`core.reset`'s state without its observation (tracing the renderer would dominate compile time)."""
    k_layout, k_spawn = jax.random.split(key)
    layout = generate(k_layout, params)
    return core._spawn(k_spawn, layout.grid, layout.goal_id, layout.spawn_mask, params)


def expand(mask, like):
    return mask.reshape(mask.shape + (1,) * (like.ndim - mask.ndim))


def batched(tree, size):
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (size, *a.shape)), tree)


def make_rollout(params, specs, steps, auto_reset=True, blind=None):
    """Jitted `run(key, states, fresh)`: `steps` steps of E environments where slot i plays `specs[i]`
    (None: uniformly random actions); environments with `fresh` bool[E] start from a random episode instead.
    Slot `blind` sees its rewards as with penalty=0 and initial_reward=False.

    The dynamics are `core.step_env`'s and `core.step_batch`'s auto-reset, without rendering observations.
    Returns rewards float32[T, E, N], done bool[T, E] (the episode ended at that step; without auto-reset,
    only at max_steps), the final memories and, per step, the (grid, goal_id, pos) the action was taken in
    and each slot's `Memory.succ` before it.
    """

    def run(key, states, fresh):
        size = fresh.shape[0]
        memories = tuple(batched(init_memory(params), size) for _ in specs)

        def body(carry, k):
            states, memories, prev_reward, pending = carry
            ks = jax.random.split(k, (len(specs) + 1, size))

            def with_resets():  # episodes start here: at step 0 where `fresh`, later after `done`
                drawn = jax.vmap(new_episode, in_axes=(0, None))(ks[-1], params)
                return jax.tree.map(lambda a, b: jnp.where(expand(pending, a), a, b), drawn, states)

            states = jax.lax.cond(jnp.any(pending), with_resets, lambda: states)
            reset = pending | (states.time == 0)
            actions, new_memories = [], []
            for slot, spec in enumerate(specs):
                if spec is None:
                    actions.append(jax.random.randint(ks[slot, 0], (size,), 0, NUM_ACTIONS, jnp.int32))
                    new_memories.append(memories[slot])
                    continue
                a, m = act_batch(
                    ks[slot], spec, params, states, slot, memories[slot], prev_reward[:, slot], reset
                )
                actions.append(a)
                new_memories.append(m)
            seen = (states.grid, states.goal_id, states.pos, tuple(m.succ for m in memories))
            started = states.cycle_state >= 0
            next_states, reward = jax.vmap(world_step, in_axes=(0, 0, None))(
                states, jnp.stack(actions, -1), params
            )
            if auto_reset:
                done = jnp.all(~next_states.active, -1) | (next_states.time >= params.max_steps)
                pending = done
            else:
                done = next_states.time == params.max_steps
                pending = jnp.zeros_like(done)
            shown = reward
            if blind is not None:
                hidden = jnp.where(started[:, blind], jnp.maximum(reward[:, blind], 0.0), 0.0)
                shown = reward.at[:, blind].set(hidden)
            return (next_states, tuple(new_memories), shown, pending), (reward, done, seen)

        init = (states, memories, jnp.zeros((size, params.n_agents)), jnp.asarray(fresh))
        (_, memories, _, _), (reward, done, seen) = jax.lax.scan(body, init, jax.random.split(key, steps))
        return reward, done, memories, seen

    return jax.jit(run)


def stack(states):
    return jax.tree.map(lambda *xs: np.stack(xs), *jax.device_get(states))


def embed(rows, width=13, height=13):
    """An ASCII scene in the top-left corner of a wall-filled grid."""
    return [row.ljust(width, "#") for row in rows] + ["#" * width] * (height - len(rows))


def scene_states(params, rows, starts, orders):
    """One state per (start, order): the tile drawn as digit d gets label order[d], so label i is always
    followed by label i + 1 (mod n) while the tiles' places change. starts: (x, y, dir) tuples."""
    rows = embed(rows, params.width, params.height)
    digits = np.array([[int(c) if c.isdigit() else -1 for c in row] for row in rows])
    states = []
    for (x, y, d), order in itertools.product(starts, orders):
        ids = np.where(digits >= 0, np.asarray(order)[digits], -1).astype(np.int8)
        n = params.n_agents
        states.append(state_from_layout(params, rows, [(x, y)] * n, [d] * n, ids))
    return states


def run_batch(params, specs, scenes, seed, steps=500, blind=None):
    """Hand-built scene states followed by N_RANDOM random environments, `steps` steps with auto-reset."""
    states = stack(scenes + [scenes[0]] * N_RANDOM)
    fresh = np.arange(N_RANDOM + len(scenes)) >= len(scenes)
    run = make_rollout(params, specs, steps, blind=blind)
    return jax.device_get(run(jax.random.key(seed), states, fresh))


def episodes(done):
    """(env, first step, end step + 1) of every episode ended by `done` bool[T, E]."""
    out = []
    for e in range(done.shape[1]):
        ends = np.flatnonzero(done[:, e])
        out += [(e, lo, hi) for lo, hi in zip(np.r_[0, ends[:-1] + 1], ends + 1, strict=True)]
    return out


def fair(grid, pos):
    """Every bonus tile can be reached from every other one, and from `pos` (x, y), without stepping on a
    third one: the layouts where the explorer's bound holds (clutter can wall a tile in)."""
    plain = (grid != WALL) & (grid != BONUS)
    comp = np.full(grid.shape, -1)
    for start in zip(*np.nonzero(plain), strict=True):
        if comp[start] >= 0:
            continue
        comp[start], stack = start[0] * grid.shape[1] + start[1], [start]
        while stack:
            y, x = stack.pop()
            for ny, nx in ((y + 1, x), (y - 1, x), (y, x + 1), (y, x - 1)):
                if plain[ny, nx] and comp[ny, nx] < 0:
                    comp[ny, nx] = comp[start]
                    stack.append((ny, nx))

    def around(y, x):  # components and tiles an agent on (x, y) can step to
        cells = [(y, x), (y + 1, x), (y - 1, x), (y, x + 1), (y, x - 1)]
        return {comp[c] for c in cells if comp[c] >= 0}, {c for c in cells[1:] if grid[c] == BONUS}

    tiles = list(zip(*np.nonzero(grid == BONUS), strict=True))
    for source in [*tiles, (pos[1], pos[0])]:
        comps, adjacent = around(*source)
        for tile in tiles:
            if tile != source and tile not in adjacent and not comps & around(*tile)[0]:
                return False
    return True


def random_episodes(out, n_scenes):
    """Rewards float[episodes, T, N] of the random-layout environments and whether each layout is fair."""
    reward, done, _, (grid, _, pos, _) = out
    eps = [(e, lo, hi) for e, lo, hi in episodes(done[:, n_scenes:])]
    assert len(eps) == 2 * N_RANDOM and all(hi - lo == 250 for _, lo, hi in eps)
    rewards = np.stack([reward[lo:hi, n_scenes + e] for e, lo, hi in eps])
    is_fair = np.array([fair(grid[lo, n_scenes + e], pos[lo, n_scenes + e, 0]) for e, lo, _ in eps])
    return rewards, is_fair


def after_last_penalty(reward):
    """Positive rewards after the last penalty of each column. reward float[T, E] -> int[E]."""
    out = []
    for r in np.asarray(reward).T:
        bad = np.flatnonzero(r < 0)
        out.append(int((r[bad[-1] + 1 :] > 0).sum() if len(bad) else (r > 0).sum()))
    return np.array(out)


def true_successors(n):
    return (np.arange(n) + 1) % n


# ------------------------------------------------------------------------------------------------ Goal Cycle


@pytest.fixture(scope="module")
def goalcycle3():
    """goalcycle3 (SPECS3): the open row (every order, 3 starts), the corridor (every order), then
    random layouts; 500 steps."""
    params = jaxsocial.make("goalcycle3", n_agents=len(SPECS3))[1]
    scenes = scene_states(params, OPEN3, STARTS3, ORDERS3) + scene_states(
        params, CORRIDOR3, [(2, 2, 0)], ORDERS3
    )
    return run_batch(params, SPECS3, scenes, seed=3, blind=BLIND), len(scenes)


@pytest.fixture(scope="module")
def goalcycle4():
    """goalcycle4 (SPECS4): the room (every order, 2 starts), then random layouts."""
    params = jaxsocial.make("goalcycle4", n_agents=len(SPECS4))[1]
    scenes = scene_states(params, ROOM4, STARTS4, ORDERS4)
    return run_batch(params, SPECS4, scenes, seed=4), len(scenes)


def test_explorer_three_goals_pays_at_most_one_penalty(goalcycle3):
    (reward, _, _, (_, _, _, knowledge)), _ = goalcycle3
    n_open = len(STARTS3) * len(ORDERS3)
    reward = reward[:250, :n_open, 0]  # the first episode: the hand-built scene
    penalties = (reward < 0).sum(0)
    assert penalties.max() == 1  # the bound, reached by the unlucky orders
    assert (penalties == 0).any()
    assert after_last_penalty(reward).min() >= 20  # it never errs again and keeps collecting
    # Memory.succ at the scene's last step: it has learned the whole order.
    np.testing.assert_array_equal(knowledge[0][249, :n_open], np.tile(true_successors(3), (n_open, 1)))


def test_explorer_four_goals_pays_at_most_three_penalties(goalcycle4):
    (reward, _, _, (_, _, _, knowledge)), n_scenes = goalcycle4
    reward = reward[:250, :n_scenes, 0]
    penalties = (reward < 0).sum(0)
    assert penalties.max() == 3  # (n-1)(n-2)/2, reached by the unlucky orders
    assert after_last_penalty(reward).min() >= 15
    np.testing.assert_array_equal(knowledge[0][249, :n_scenes], np.tile(true_successors(4), (n_scenes, 1)))


def test_oracle_never_errs_and_avoids_other_tiles(goalcycle3, goalcycle4):
    n_open = len(STARTS3) * len(ORDERS3)
    for (reward, _, _, _), n in [(goalcycle3[0], n_open), (goalcycle4[0], goalcycle4[1])]:
        oracle, explorer = reward[:250, :n, 1], reward[:250, :n, 0]
        assert (oracle >= 0).all()  # in the open row it walks around the middle tile
        assert (oracle > 0).sum(0).min() >= 20
        assert oracle.sum() > explorer.sum()


def test_corridor_falls_back_to_paths_through_other_tiles(goalcycle3):
    """In the corridor every lap must cross the middle tile once; the experts still get round."""
    (reward, _, _, _), n_scenes = goalcycle3
    corridor = reward[:250, len(STARTS3) * len(ORDERS3) : n_scenes, :2]
    assert ((corridor > 0).sum(0) >= 10).all()
    oracle = corridor[..., 1]
    assert ((oracle < 0).sum(0) <= (oracle > 0).sum(0) // 3 + 1).all()


def test_explorer_learns_without_penalties(goalcycle3):
    """penalty=0 and no initial reward: mistakes and the first tile pay 0, yet it learns the order."""
    (reward, _, _, _), _ = goalcycle3
    n_open = len(STARTS3) * len(ORDERS3)
    blind, explorer = reward[:250, :n_open, BLIND], reward[:250, :n_open, 0]
    # It plays exactly like the explorer that sees the penalties (same bound, same collecting).
    assert (blind < 0).sum(0).max() == 1
    np.testing.assert_array_equal(blind, explorer)


@pytest.mark.parametrize("layout", ["goalcycle3", "goalcycle4"])
def test_random_layouts_explorer_bound_and_oracle(layout, request):
    out, n_scenes = request.getfixturevalue(layout)
    rewards, is_fair = random_episodes(out, n_scenes)
    n_goals = int(layout[-1])
    # Clutter walls a tile in now and then (each lap must then cross another tile); the bounds hold on
    # the other layouts.
    assert is_fair.mean() >= 0.8
    explorer, oracle = rewards[is_fair, :, 0], rewards[is_fair, :, 1]
    assert (explorer < 0).sum(1).max() <= (n_goals - 1) * (n_goals - 2) // 2
    assert (oracle < 0).sum() == 0
    collected = after_last_penalty(explorer.T)  # +1 rewards after the explorer's last penalty
    assert np.median(collected) >= 20 and np.mean(collected >= 10) >= 0.9
    assert np.median((oracle > 0).sum(1)) >= 20
    assert oracle.sum(1).mean() > explorer.sum(1).mean()


def test_imperfect_experts_between_random_and_perfect(goalcycle3, goalcycle4):
    rewards, _ = random_episodes(*goalcycle3)
    explorer, oracle, _, noisy, noisy_oracle, random = rewards.sum(1).mean(0)
    assert random < 1.0
    assert random + 5 < noisy < explorer - 3
    assert random + 5 < noisy_oracle < oracle - 3
    rewards, _ = random_episodes(*goalcycle4)
    explorer, _, forgetful, random = rewards.sum(1).mean(0)
    assert random < 1.0
    assert random + 5 < forgetful < explorer - 1


# ------------------------------------------------------------------------------------------ navigation


@pytest.mark.parametrize("name", ["maze-solo", "fourrooms-solo"])
def test_navigator_reaches_every_goal(name):
    params = jaxsocial.make(name)[1]
    # Placeholder states (replaced by 64 random episodes at the first step).
    rows = (
        ["#" * params.width]
        + ["#G" + "." * (params.width - 3) + "#"]
        + ["#" * params.width] * (params.height - 2)
    )
    states = stack([state_from_layout(params, rows, [(2, 1)], [0])] * 64)
    run = make_rollout(params, (NAVIGATOR,), params.max_steps, auto_reset=False)
    reward, _, _, _ = jax.device_get(run(jax.random.key(5), states, np.ones(64, bool)))
    reward = reward[..., 0]
    assert ((reward > 0).sum(0) == 1).all()  # reached once, then inactive on the goal
    assert (reward >= 0).all()


def test_single_env_act_steps_off_its_target_and_back():
    """The oracle stands on the tile it must enter next (cycle state 2, tile 0) facing east."""
    params = jaxsocial.make("goalcycle3", n_agents=1)[1]
    state = state_from_layout(params, embed(OPEN3), [(1, 2)], [0], cycle_state=[2])
    policy, step = jax.jit(act_one, static_argnums=(1, 2, 4)), jax.jit(world_step, static_argnums=2)
    memory, reward, actions, rewards = init_memory(params), jnp.float32(0), [], []
    for t in range(4):
        action, memory = policy(jax.random.key(t), ORACLE, params, state, 0, memory, reward, t == 0)
        state, reward = step(state, action[None], params)
        actions.append(int(action))
        rewards.append(float(reward[0]))
        reward = reward[0]
    assert actions == [FORWARD, RIGHT, RIGHT, FORWARD]  # off, turn round (it is behind), back on
    assert rewards == [0.0, 0.0, 0.0, 1.0]
    assert int(memory.target) == 0 and int(state.cycle_state[0]) == 0


# -------------------------------------------------------------------------------------------- batching


def test_act_batch_equals_vmapped_act():
    """Same actions and memories step by step, with episode ends (max_steps=15) and random extra resets.
    The kinds differ only inside `_decide`, which both paths share; one imperfect explorer covers them."""
    params = jaxsocial.make("goalcycle3", n_agents=1, max_steps=15)[1]
    spec = ExpertSpec("explorer", epsilon=0.2, forget=0.05)
    size, steps = 8, 60

    def one(key, state, memory, reward, reset):
        return act_one(key, spec, params, state, 0, memory, reward, reset)

    @jax.jit
    def run(key):
        k_init, k_run = jax.random.split(key)
        states = jax.vmap(new_episode, in_axes=(0, None))(jax.random.split(k_init, size), params)
        memory = batched(init_memory(params), size)

        def body(carry, k):
            states, mem_a, mem_b, prev_reward, reset = carry
            ks = jax.random.split(k, 3)
            reset = reset | jax.random.bernoulli(ks[0], 0.05, (size,))
            keys = jax.random.split(ks[1], size)
            a, mem_a = act_batch(keys, spec, params, states, 0, mem_a, prev_reward, reset)
            b, mem_b = jax.vmap(one)(keys, states, mem_b, prev_reward, reset)
            next_states, reward = jax.vmap(world_step, in_axes=(0, 0, None))(states, a[:, None], params)
            done = next_states.time >= params.max_steps
            fresh = jax.vmap(new_episode, in_axes=(0, None))(jax.random.split(ks[2], size), params)
            next_states = jax.tree.map(lambda x, y: jnp.where(expand(done, x), x, y), fresh, next_states)
            return (next_states, mem_a, mem_b, reward[:, 0], done), (a, b, mem_a, mem_b, reset)

        init = (states, memory, memory, jnp.zeros(size), jnp.ones(size, bool))
        return jax.lax.scan(body, init, jax.random.split(k_run, steps))[1]

    actions_a, actions_b, mem_a, mem_b, resets = jax.device_get(run(jax.random.key(6)))
    np.testing.assert_array_equal(actions_a, actions_b)
    for a, b in zip(jax.tree.leaves(mem_a), jax.tree.leaves(mem_b), strict=True):
        np.testing.assert_array_equal(a, b)
    assert resets[1:].sum() >= 8 and not resets[1:].all(1).all()  # mid-rollout resets, not all at once
    assert len(np.unique(actions_a)) >= 4
    assert (mem_a.succ >= 0).any() and mem_a.mistake.any()  # it did learn something


# ------------------------------------------------------------------------------------- parsing, checks


def test_parse_expert():
    assert parse_expert("explorer") == ExpertSpec("explorer")
    assert parse_expert("oracle:epsilon=0.1") == ExpertSpec("oracle", epsilon=0.1)
    assert parse_expert(" explorer : epsilon=0.1, forget=0.02 ") == ExpertSpec("explorer", 0.1, 0.02)
    assert hash(parse_expert("navigator")) == hash(NAVIGATOR)
    for text, match in [
        ("teacher", "unknown expert kind"),
        ("explorer:temperature=1", "unknown expert field"),
        ("explorer:epsilon", "field=value"),
        ("explorer:epsilon=lots", "not a number"),
        ("explorer:epsilon=1.5", r"\[0, 1\]"),
        ("oracle:forget=-0.1", r"\[0, 1\]"),
        ("oracle:forget=0.1,forget=0.2", "twice"),
    ]:
        with pytest.raises(ValueError, match=match):
            parse_expert(text)
    with pytest.raises(ValueError, match="probability"):
        ExpertSpec("oracle", epsilon=2.0)


def test_validate():
    gc3 = jaxsocial.make("goalcycle3")[1]
    for spec in (EXPLORER, ORACLE):
        check_playable(spec, gc3)
        with pytest.raises(ValueError, match="n_goals >= 2"):
            check_playable(spec, gc3.replace(n_goals=1))
        with pytest.raises(ValueError, match="Goal Cycle"):
            check_playable(spec, jaxsocial.make("maze")[1])
    check_playable(NAVIGATOR, jaxsocial.make("fourrooms")[1])
    check_playable(NAVIGATOR, jaxsocial.make("maze")[1])
    with pytest.raises(ValueError, match="navigator"):
        check_playable(NAVIGATOR, gc3)


def test_memory_shapes():
    memory = init_memory(jaxsocial.make("goalcycle4")[1])
    assert memory.cost.shape == (4, 13, 13) and memory.cost.dtype == jnp.int16
    assert memory.succ.shape == (4,) and memory.mistake.shape == (4, 4)
    assert init_memory(jaxsocial.make("maze")[1]).cost.shape == (1, 19, 19)
    assert expert_spec.KINDS == ("explorer", "oracle", "navigator")
