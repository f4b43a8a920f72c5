"""Property-based tests of the environment (hypothesis): random layouts, spawns and action sequences (no-op
actions included) in a fixed set of configurations that span the presets and `EnvParams` ranges (solo,
dropout and drop-in episodes included), each compiled once; every step must keep the invariants below.

A configuration is static (`EnvParams` is hashed into the program), so hypothesis draws it from `CONFIGS`
instead of inventing one per example: the rollout is compiled at most once per configuration."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from conftest import U32
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxsocial
from jaxsocial.env import core
from jaxsocial.env.types import LEFT, NUM_ACTIONS, PICKUP, WALL
from jaxsocial.specs import ENV_ARGS

STEPS = 24  # several episodes per rollout: every configuration's max_steps is <= 12
CONFIGS = (
    ("goalcycle3", "width=7,height=7,max_steps=12,penalty=0.7,reward_decay=True,dropout_prob=0.4,"
     "dropin_prob=0.3"),
    ("goalcycle4-solo", "width=6,height=8,max_steps=9,clutter_density=0.3,initial_reward=False,"
     "reset_on_mistake=True,prestige_formula='paper',prestige_beta=1.0,goal_reward=2.5"),
    ("goalcycle3-distractors", "width=8,height=6,n_goals=1,max_steps=7,penalty=0.0,solo_prob=0.5,"
     "solo_agents=2,view_offset=0,view_size=5,prestige_beta=0.0,random_spawn_dir=False"),
    ("fourrooms", "width=9,height=11,max_steps=10,solo_prob=0.5,dropout_prob=0.5,dropout_min_step=3"),
    ("maze", "width=7,height=9,max_steps=11,dropin_prob=0.6,agent_colors='fixed'"),
)  # fmt: skip
"""(preset, EnvParams overrides), all with symbolic views (the RGB renderer draws the same agents: its
pixels are checked against the original code in test_parity and test_observe)."""
SETTINGS = settings(
    max_examples=10, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow]
)


@functools.cache
def params_of(index: int):
    name, overrides = CONFIGS[index]
    defaults = {"observation": "symbolic"}
    return jaxsocial.make(name, **{**defaults, **dict(ENV_ARGS.parse(overrides))})[1]


@functools.cache
def rollout_of(index: int):
    """Jitted `rollout(key, actions int32[STEPS, N]) -> (state0, states, obs, rewards, done)` of `step` with
    auto-reset from `reset(key)`; states, obs, rewards and done stacked on a leading step axis."""
    params = params_of(index)

    def rollout(key, actions):
        k_reset, k_steps = jax.random.split(key)
        _, state0 = core.reset(k_reset, params)

        def body(state, inputs):
            k, a = inputs
            obs, state, reward, _, _, info = core.step(k, state, a, params)
            return state, (state, obs, reward, info["done"])

        keys = jax.random.split(k_steps, STEPS)
        return (state0, *jax.lax.scan(body, state0, (keys, actions))[1])

    return jax.jit(rollout)


@st.composite
def episodes(draw, configs: tuple[int, ...] | None = None):
    """(configuration index, seed, actions int32[STEPS, N]) of one of `configs`: no-ops (3-6) as likely as
    each move."""
    index = draw(st.sampled_from(configs or range(len(CONFIGS))))
    n = params_of(index).n_agents
    seed = draw(st.integers(0, 2**31 - 1))
    actions = draw(st.lists(st.integers(0, NUM_ACTIONS - 1), min_size=STEPS * n, max_size=STEPS * n))
    return index, seed, np.asarray(actions, np.int32).reshape(STEPS, n)


def allowed_rewards(params, time: np.ndarray) -> np.ndarray:
    """float64[T, K]: the K rewards the rules can pay at each step's time t (1-based, before any reset)."""
    payments = [0.0, params.goal_reward]
    if params.layout == "goalcycle":
        payments.append(-abs(params.penalty))
    decay = 1.0 - 0.9 * time / params.max_steps if params.reward_decay else np.ones_like(time, np.float64)
    return decay[:, None] * np.asarray(payments)[None, :]


@SETTINGS
@given(episodes())
def test_every_step_keeps_the_invariants(episode):
    index, seed, actions = episode
    params = params_of(index)
    state0, states, obs, rewards, done = jax.device_get(rollout_of(index)(jax.random.key(seed), actions))
    before = jax.tree.map(lambda first, rest: np.concatenate([first[None], rest[:-1]]), state0, states)
    x, y = states.pos[..., 0], states.pos[..., 1]
    assert ((x >= 0) & (x < params.width) & (y >= 0) & (y < params.height)).all()
    walls = np.take_along_axis(states.grid.reshape(STEPS, -1), y * params.width + x, axis=1) == WALL
    assert not walls.any(), "an agent stands on a wall"
    assert ((states.dir >= 0) & (states.dir < 4)).all()
    assert ((states.time >= 0) & (states.time < params.max_steps)).all()  # a finished episode resets
    assert np.isfinite(states.prestige).all() and np.isfinite(rewards).all()
    assert ((states.cycle_state >= -1) & (states.cycle_state < params.n_goals)).all()
    # Rewards: only what the rules pay at that time (a few float32 roundings of values <= 2.5: < 1e-6).
    allowed = allowed_rewards(params, before.time + 1.0)
    assert (np.abs(rewards[..., None] - allowed[:, None, :]).min(-1) <= 1e-6).all(), rewards
    # Absent agents are never paid (an agent leaving at this step still acted in it) and never drawn.
    assert (rewards[~before.present] == 0).all()
    if params.observation == "symbolic":
        for t in range(STEPS):
            drawn = set(np.unique(obs[t][..., 1]).tolist()) - {0}  # the agent channel holds slot + 1
            assert drawn <= {i + 1 for i in np.flatnonzero(states.present[t])}, (t, drawn)
    # The layout is the episode's until it resets; a present, active agent's no-op action changes nothing.
    kept = ~done
    assert (states.grid[kept] == before.grid[kept]).all() and (
        states.goal_id[kept] == before.goal_id[kept]
    ).all()
    idle = kept[:, None] & (actions >= PICKUP) & before.active & before.present  # actions 3-6
    assert (states.pos[idle] == before.pos[idle]).all() and (states.dir[idle] == before.dir[idle]).all()
    turned = kept[:, None] & (actions == LEFT) & before.active
    assert (states.dir[turned] == (before.dir[turned] - 1) % 4).all()


@settings(max_examples=2, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(episodes(configs=(0,)))  # the un-jitted step compiles every operation of a configuration on its own
def test_the_jitted_step_equals_the_eager_one(episode):
    """The rollout's first step (jitted) against the same step un-jitted: the same integers and booleans,
    observations included; floats within twice the error bound of the longest float computation, the
    decayed reward (28u, see test_parity), since XLA may fuse or order its operations otherwise."""
    index, seed, actions = episode
    params = params_of(index)
    state0, states, obs, rewards, done = rollout_of(index)(jax.random.key(seed), actions)
    k_step = jax.random.split(jax.random.split(jax.random.key(seed))[1], STEPS)[0]  # as in the rollout
    eager_obs, eager_state, eager_reward, _, _, info = core.step(
        k_step, state0, jnp.asarray(actions[0]), params
    )
    jitted = (obs[0], jax.tree.map(lambda x: x[0], states), rewards[0], done[0])
    for a, b in zip(
        jax.tree.leaves((eager_obs, eager_state, eager_reward, info["done"])),
        jax.tree.leaves(jitted),
        strict=True,
    ):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype.kind == "f":
            np.testing.assert_allclose(a, b, rtol=2 * 28 * U32, atol=0)
        else:
            np.testing.assert_array_equal(a, b)


@settings(max_examples=40, deadline=None, database=None)
@given(
    penalty=st.floats(0, 10),
    prestige_beta=st.floats(0, 1),
    solo_prob=st.floats(0, 1),
    dropout=st.floats(0, 1),
    clutter_density=st.floats(0, 0.3),
    max_steps=st.integers(2, 500),
    view=st.sampled_from([(3, 0), (5, 4), (7, 1), (9, 3)]),
)
def test_overrides_within_their_ranges_are_accepted(
    penalty, prestige_beta, solo_prob, dropout, clutter_density, max_steps, view
):
    """No compile: every in-range combination builds, and the values are the ones asked for."""
    overrides = {
        "penalty": penalty,
        "prestige_beta": prestige_beta,
        "solo_prob": solo_prob,
        "dropout_prob": dropout,
        "dropin_prob": (1.0 - dropout) / 2,
        "clutter_density": clutter_density,
        "max_steps": max_steps,
        "view_size": view[0],
        "view_offset": view[1],
    }
    params = jaxsocial.make("goalcycle3", **overrides)[1]
    assert {k: getattr(params, k) for k in overrides} == overrides
