"""The public API contract: presets, shapes, jit/vmap, determinism, auto-reset and bad input."""

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsocial
from jaxsocial.env import reset, step, step_batch
from jaxsocial.env.observe import observe

ENVS = jaxsocial.registered_envs()
SHORT = jaxsocial.make("goalcycle3", max_steps=4)[1]
"""Episodes of 4 steps: `play(SHORT, key, 9)` resets twice (one compiled program for the tests below)."""
# Jitted (eager op-by-op dispatch compiles every primitive separately and is slower).
jit_reset = jax.jit(reset, static_argnums=1)
jit_step = jax.jit(step, static_argnums=3)


def play(params, key, n_steps, step_fn=step):
    """Reset then take random actions; returns the stacked per-step outputs."""
    k_reset, k_run = jax.random.split(key)
    obs, state = reset(k_reset, params)

    def body(state, k):
        k_act, k_step = jax.random.split(k)
        actions = jax.random.randint(k_act, (params.n_agents,), 0, 7)
        obs, state, reward, terminated, truncated, info = step_fn(k_step, state, actions, params)
        return state, (obs, reward, terminated, truncated, info["final_obs"], info["done"], state.time)

    return jax.lax.scan(body, state, jax.random.split(k_run, n_steps))[1]


@pytest.mark.parametrize("name", ENVS)
def test_every_preset_traces_with_the_documented_shapes(name):
    """Shapes and dtypes of reset and step for every preset (traced, not compiled: execution is covered by
    the scene, layout and parity tests)."""
    env, params = jaxsocial.make(name)
    n = params.n_agents
    obs, state = jax.eval_shape(env.reset, jax.random.key(0), params)
    assert obs.shape == (n, 21, 21, 3) and obs.dtype == jnp.uint8
    out = jax.eval_shape(env.step, jax.random.key(1), state, jnp.zeros(n, jnp.int32), params)
    obs, state, reward, terminated, truncated, info = out
    assert obs.shape == info["final_obs"].shape == (n, 21, 21, 3)
    assert (reward.shape, reward.dtype) == ((n,), jnp.float32)
    assert (terminated.shape, terminated.dtype) == ((n,), jnp.bool_)
    assert (truncated.shape, truncated.dtype) == ((), jnp.bool_)
    assert state.pos.shape == (n, 2) and state.grid.shape == (params.height, params.width)


def test_preset_values():
    p = jaxsocial.make("goalcycle3")[1]
    assert (p.width, p.n_goals, p.n_clutter, p.penalty, p.n_agents, p.max_steps) == (13, 3, 12, 1.5, 3, 250)
    assert p.prestige_beta == 0.99 and p.view_offset == 1 and p.agent_colors == "prestige"
    assert jaxsocial.make("goalcycle4")[1].n_goals == 4
    assert jaxsocial.make("goalcycle3-solo")[1].n_agents == 1
    assert jaxsocial.make("goalcycle3-distractors")[1].n_agents == 5
    assert jaxsocial.make("fourrooms")[1].width == 17 and jaxsocial.make("maze")[1].width == 19
    assert jaxsocial.make("goalcycle3", penalty=0.0, view_offset=2)[1].view_offset == 2


class JitEqualsNoJit(chex.TestCase):
    """Random play (reset, then steps with auto-reset) compiled, and run op by op, equals a reference with
    jit disabled altogether (`lax.scan` as a Python loop)."""

    @classmethod
    def setUpClass(cls):
        super().setUpClass()
        with jax.disable_jit():
            cls.reference = play(SHORT, jax.random.key(3), 9)

    @chex.variants(with_jit=True, without_jit=True)
    def test_play_equals_the_disabled_jit_reference(self):
        out = self.variant(play, static_argnums=(0, 2))(SHORT, jax.random.key(3), 9)
        chex.assert_trees_all_equal(out, self.reference)


def test_same_key_same_episodes_other_key_others():
    run = jax.jit(play, static_argnums=(0, 2))
    first, again, other = (run(SHORT, jax.random.key(k), 9) for k in (3, 3, 4))
    chex.assert_trees_all_equal(first, again)
    assert not np.array_equal(first[0], other[0])


def test_auto_reset_and_final_obs():
    params = SHORT
    obs, reward, terminated, truncated, final_obs, done, time = jax.jit(play, static_argnums=(0, 2))(
        params, jax.random.key(5), 9
    )
    np.testing.assert_array_equal(done, [False, False, False, True] * 2 + [False])
    np.testing.assert_array_equal(truncated, done)
    np.testing.assert_array_equal(time, [1, 2, 3, 0, 1, 2, 3, 0, 1])  # the state after a reset is fresh
    same = np.array([np.array_equal(o, f) for o, f in zip(obs, final_obs, strict=True)])
    np.testing.assert_array_equal(same, ~np.asarray(done))  # final_obs differs from obs only at resets
    # final_obs at a reset is the observation step_env gives for the last step of the episode.
    k_reset, _ = jax.random.split(jax.random.key(5))
    assert not np.array_equal(final_obs[3], jit_reset(k_reset, params)[0])


def test_episode_ends_when_every_agent_is_terminated():
    params = jaxsocial.make("goalcycle3", width=5, height=3, n_goals=1, clutter_density=0.0, n_agents=2)[1]
    state = jaxsocial.state_from_layout(params, ["#####", "#.G.#", "#####"], [(1, 1), (3, 1)], [0, 2])
    key = jax.random.key(0)
    _, state1, _, terminated, truncated, info = jit_step(key, state, jnp.array([2, 6]), params)
    assert terminated.tolist() == [True, False] and not info["done"] and int(state1.time) == 1
    _, state2, _, terminated, truncated, info = jit_step(key, state1, jnp.array([0, 2]), params)
    assert terminated.all() and not truncated and info["done"]
    assert int(state2.time) == 0 and state2.active.all()  # auto-reset


def test_step_renders_once_when_final_obs_is_unused():
    """A vmapped `step` whose `info["final_obs"]` is unused renders one observation per step (the reset draws
    a state, not a picture): its program holds the gathers of the state update plus those of one `observe`,
    also in the branch that resets (before, that branch rendered the new episodes a second time)."""
    params = jaxsocial.make("goalcycle3", max_steps=4)[1]
    keys = jax.random.split(jax.random.key(0), 2)
    states = jax.vmap(reset, in_axes=(0, None))(keys, params)[1]
    actions = jnp.zeros((2, params.n_agents), jnp.int32)

    def gathers(fn, *args):
        return jax.jit(fn).lower(*args).as_text().count("stablehlo.gather")

    render = gathers(jax.vmap(lambda s: observe(s, params)), states)
    state_only = gathers(lambda k, s, a: step_batch(k, s, a, params)[1], keys, states, actions)
    with_obs = gathers(lambda k, s, a: step_batch(k, s, a, params)[0], keys, states, actions)
    assert render > 0 and with_obs == state_only + render


def test_vmap_and_step_batch_equal_per_env_step():
    """Under vmap the auto-reset is a cond on "some episode ended" plus a select: with episodes ending at
    different steps in different environments, every environment of the batch is the same as running it
    alone, and `step_batch` is the same as the vmap (with `observers`, on those agents' views)."""
    params = SHORT
    n_envs, n_steps = 4, 9
    _, states = jax.jit(jax.vmap(reset, in_axes=(0, None)), static_argnums=1)(
        jax.random.split(jax.random.key(9), n_envs), params
    )
    states = states.replace(time=jnp.arange(n_envs, dtype=jnp.int32))  # truncated at steps 4, 3, 2, 1, ...
    keys = jax.random.split(jax.random.key(10), (n_steps, n_envs))
    actions = jax.random.randint(jax.random.key(11), (n_steps, n_envs, params.n_agents), 0, 7)

    def run(step_fn, states, keys, actions):
        def body(s, inputs):
            out = step_fn(*inputs[:1], s, inputs[1], params)
            return out[1], (*out[:5], out[5]["final_obs"], out[5]["done"])

        return jax.lax.scan(body, states, (keys, actions))[1]

    vmapped = jax.jit(lambda *a: run(jax.vmap(step, in_axes=(0, 0, 0, None)), *a))(states, keys, actions)
    done = np.asarray(vmapped[-1])
    assert np.all((done.sum(1) > 0) & (done.sum(1) < n_envs))  # every step resets some environments only
    chex.assert_trees_all_equal(vmapped, jax.jit(lambda *a: run(step_batch, *a))(states, keys, actions))
    # Some agents' views only: obs and final_obs are those agents' rows of every view; the rest the same.
    some = jax.jit(lambda *a: run(functools.partial(step_batch, observers=(2, 0)), *a))(states, keys, actions)
    rows = [(x[:, :, [2, 0]] if k in (0, 5) else x) for k, x in enumerate(vmapped)]
    chex.assert_trees_all_equal(tuple(rows), some)
    alone = jax.jit(lambda *a: run(step, *a))
    for i in range(n_envs):
        one = alone(jax.tree.map(lambda x, i=i: x[i], states), keys[:, i], actions[:, i])
        chex.assert_trees_all_equal(jax.tree.map(lambda x, i=i: x[:, i], vmapped), one)


def test_no_retracing():
    params = jaxsocial.make("goalcycle3-solo")[1]

    @jax.jit
    @chex.assert_max_traces(n=1)
    def step_fn(key, state, actions):
        return step(key, state, actions, params)

    _, state = jit_reset(jax.random.key(0), params)
    for i in range(3):
        _, state, *_ = step_fn(jax.random.key(i), state, jnp.array([i % 3], jnp.int32))


def test_symbolic_observation():
    env, params = jaxsocial.make("goalcycle3", observation="symbolic")
    obs, _ = jax.jit(env.reset, static_argnums=1)(jax.random.key(0), params)
    chex.assert_shape(obs, (3, 7, 7, 4))
    assert obs.dtype == jnp.int8 and (obs[:, 5, 3, 1] == jnp.arange(1, 4)).all()  # each agent sees itself


@pytest.mark.parametrize(
    ("name", "overrides", "message"),
    [
        ("goalcycle5", {}, "unknown environment"),
        ("goalcycle3", {"view_size": 6}, "view_size=6 must be odd"),
        ("goalcycle3", {"n_agents": 7}, "agent colours"),
        ("goalcycle3", {"width": 4, "height": 4, "n_goals": 4}, "too few"),
        ("goalcycle3", {"penalty_size": 1}, "unknown EnvParams field"),
        ("goalcycle3", {"observation": "pixels"}, "observation="),
        ("maze", {"width": 18}, "odd width"),
        ("goalcycle3", {"penalty": -1.0}, "penalty=-1.0 is a magnitude and must be >= 0"),
        ("goalcycle3", {"penalty": "abc"}, "penalty='abc' must be of type float"),
        ("goalcycle3", {"width": "13"}, "width='13' must be of type int"),
        ("goalcycle3", {"max_steps": 2.5}, "max_steps=2.5 must be of type int"),
        ("goalcycle3", {"initial_reward": 1}, "initial_reward=1 must be of type bool"),
        ("goalcycle3", {"n_goals": True}, "n_goals=True must be of type int"),
        ("goalcycle3", {"prestige_beta": 5.0}, "prestige_beta=5.0 must be in"),
        ("goalcycle3", {"dropout_prob": 0.6, "dropin_prob": 0.6}, "must be <= 1"),
        ("goalcycle3", {"dropout_prob": 0.5, "dropout_min_step": 300}, "dropout_min_step"),
    ],
)
def test_bad_configuration_is_rejected(name, overrides, message):
    with pytest.raises(ValueError, match=message):
        jaxsocial.make(name, **overrides)


def test_int_given_for_a_float_field_is_stored_as_a_float():
    params = jaxsocial.make("goalcycle3", penalty=1)[1]
    assert params.penalty == 1.0 and isinstance(params.penalty, float)


def test_bad_actions_are_rejected_before_compiling():
    env, params = jaxsocial.make("goalcycle3")
    _, state = jax.jit(env.reset, static_argnums=1)(jax.random.key(0), params)
    for actions in (jnp.zeros(2, jnp.int32), jnp.zeros((3, 1), jnp.int32), jnp.zeros(3, jnp.float32)):
        with pytest.raises(ValueError, match="actions must be an integer array of shape"):
            jax.jit(env.step)(jax.random.key(1), state, actions, params)
