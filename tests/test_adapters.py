"""The gymnax and JaxMARL adapters against the real libraries: spaces, their own wrappers under jit and vmap,
auto-reset, and rollouts that match the native step exactly. The dev extra installs both libraries, so a
missing one fails the suite rather than skipping it."""

import importlib.util
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY
from jaxmarl.wrappers import baselines as jaxmarl_wrappers

from jaxsocial.adapters import gymnax_env, jaxmarl_env
from jaxsocial.agents import acting, network, population
from jaxsocial.env import core
from jaxsocial.run import policy_io

SMALL = {"width": 7, "height": 7, "max_steps": 12}  # 30 steps cross two episode ends
STEPS, ENVS = 30, 2


def tree_equal(a, b) -> None:
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.fixture(scope="module")
def gymnax_rollout():
    """The learner (slot 0, random actions) beside two scripted explorers, ENVS environments vmapped, STEPS
    steps under jit: (env, params, keys [T, E], the states before each step [T, E], the step outputs)."""
    env, params = gymnax_env.make("goalcycle3", **SMALL)
    keys = jax.random.split(jax.random.key(0), (STEPS, ENVS))
    _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(1), ENVS), params)
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def body(state, key):
        action = jax.vmap(env.action_space(params).sample)(
            jax.random.split(jax.random.fold_in(key[0], 7), ENVS)
        )
        return (out := step(key, state, action, params))[1], (state, out)

    _, (before, outputs) = jax.jit(lambda s: jax.lax.scan(body, s, keys))(state)
    return env, params, keys, before, outputs


def test_gymnax_spaces_auto_reset_and_vmap():
    env, params = gymnax_env.make("goalcycle3", slots="learner,random,random", **SMALL)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(0), ENVS), params)
    space = env.observation_space(params)
    assert (space.shape, space.dtype) == ((21, 21, 3), jnp.uint8) and obs.shape == (ENVS, 21, 21, 3)
    assert env.action_space(params).n == env.num_actions == 7 and env.name == "jaxsocial/goalcycle3"
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    for t in range(params.max_steps):
        keys = jax.random.split(jax.random.key(t), ENVS)
        obs, state, reward, terminated, truncated, info = step(keys, state, jnp.full(ENVS, 2), params)
        assert bool(jnp.all(jax.vmap(space.contains)(obs)))
    assert (
        truncated.all()
        and not terminated.any()
        and bool(jnp.all(state.starts))
        and int(state.time.max()) == 0
    )
    assert info["final_observation"].shape == obs.shape and reward.dtype == jnp.float32
    symbolic, symbolic_params = gymnax_env.make("goalcycle3-solo", observation="symbolic")
    obs, _ = symbolic.reset(jax.random.key(0), symbolic_params)
    assert obs.dtype == jnp.int8 and bool(symbolic.observation_space(symbolic_params).contains(obs))


@pytest.mark.slow
def test_gymnax_step_is_the_native_world_step_with_the_experts_acting(gymnax_rollout):
    env, params, keys, before, (obs, after, reward, terminated, truncated, info) = gymnax_rollout
    flat = jax.tree.map(lambda x: x.reshape(STEPS * ENVS, *x.shape[2:]), (before.world, info["actions"]))
    views, world, rewards, term, trunc = jax.vmap(core.step_env, in_axes=(0, 0, None))(*flat, params)
    unflat = jax.tree.map(
        lambda x: x.reshape(STEPS, ENVS, *x.shape[1:]), (views, world, rewards, term, trunc)
    )
    views, world, rewards, term, trunc = unflat
    np.testing.assert_array_equal(info["final_observation"], views[:, :, 0])
    np.testing.assert_array_equal(info["rewards"], rewards)
    np.testing.assert_array_equal(reward, rewards[..., 0])
    np.testing.assert_array_equal(terminated, term[..., 0])
    np.testing.assert_array_equal(truncated, trunc)
    done = np.asarray(terminated | truncated)
    assert done.sum() == 2 * ENVS  # 30 steps of 12-step episodes: every environment reset twice
    # Where the episode went on, the next state is the stepped world; where it ended, a new episode drawn
    # with gymnax's reset key (the second half of the step key).
    reset_obs, reset_world = jax.vmap(jax.vmap(core.reset, in_axes=(0, None)), in_axes=(0, None))(
        jax.vmap(jax.vmap(lambda k: jax.random.split(k)[1]))(keys), params
    )
    expected = jax.tree.map(
        lambda r, s: np.where(done.reshape(done.shape + (1,) * (r.ndim - 2)), r, s), reset_world, world
    )
    tree_equal(after.world, expected)
    np.testing.assert_array_equal(
        obs, np.where(done[..., None, None, None], reset_obs[:, :, 0], views[:, :, 0])
    )
    np.testing.assert_array_equal(after.starts, done)

    # The experts' actions are what the training rollout's `acting.act` chooses, batched over the
    # environments, on the same states (the explorer is deterministic: no random draws).
    pop = population.Population(population.parse_slots("random,expert:explorer,expert:explorer", 3, False))
    net = network.NetworkConfig()

    def native(slot_state, step):
        world, views, starts, reward = step
        actions, slot_state, _, _ = acting.act(
            jax.random.key(0), pop, net, params, None, slot_state, views, world, starts
        )
        return acting.with_rewards(slot_state, reward), actions

    _, expert_actions = jax.jit(
        lambda: jax.lax.scan(
            native,
            acting.init_slot_state(pop, net, params, ENVS),
            (before.world, before.views, before.starts, info["rewards"]),
        )
    )()
    np.testing.assert_array_equal(info["actions"][..., 1:], expert_actions[..., 1:])


@pytest.mark.slow  # compiles the network inside the environment's step
def test_gymnax_frozen_policy_acts_on_its_own_view(tmp_path):
    stacked = jax.vmap(lambda k: network.init(k, TINY.net))(jax.random.split(jax.random.key(0), 1))
    policy_io.export_policy(tmp_path, 1, stacked, TINY.net)
    env, params = gymnax_env.make("goalcycle3", slots=f"learner,frozen:{tmp_path},random", **SMALL)
    _, state = env.reset(jax.random.key(1), params)
    _, after, *_ = env.step(jax.random.key(2), state, 2, params)
    # Its LSTM state after the first step is the network's on slot 1's view, from a zero state (float32
    # rounding of O(1) values: differences of a few 1e-7 from the batching).
    frozen = jax.tree.map(lambda x: x[0], stacked)
    expected, _ = jax.jit(network.step, static_argnums=1)(
        frozen, TINY.net, network.initial_carry(TINY.net, (1,)), state.views[1][None], jnp.ones(1, bool)
    )
    np.testing.assert_allclose(after.companions.carry.h[0], expected.h, atol=1e-5)
    assert float(jnp.abs(expected.h).max()) > 1e-3  # not trivially zero
    with pytest.raises(ValueError, match="observations"):
        gymnax_env.make("goalcycle3", slots=f"learner,frozen:{tmp_path},random", observation="symbolic")


@pytest.mark.slow
def test_gymnax_ppo_trains_on_goalcycle3_unchanged():
    """PureJaxRL's PPO (examples/purejaxrl_ppo.py) with gymnax's own LogWrapper and FlattenObservationWrapper
    on the goalcycle3 preset: 2 environments x 2 updates of 128 steps, so each plays one 250-step episode."""
    path = Path(__file__).parents[1] / "examples" / "purejaxrl_ppo.py"
    spec = importlib.util.spec_from_file_location("purejaxrl_ppo", path)
    example = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = example  # its dataclasses look their module up
    spec.loader.exec_module(example)
    env, params = gymnax_env.make("goalcycle3")
    config = {**example.CONFIG, "NUM_ENVS": 2, "NUM_STEPS": 128, "TOTAL_TIMESTEPS": 512, "UPDATE_EPOCHS": 1}
    config["NUM_MINIBATCHES"] = 2
    out = jax.jit(example.make_train(config, env, params))(jax.random.key(0))
    metrics = jax.device_get(out["metrics"])
    ended = metrics["returned_episode"].reshape(-1, 2)  # [update * step, env]
    assert np.flatnonzero(ended[:, 0]).tolist() == np.flatnonzero(ended[:, 1]).tolist() == [249]
    assert metrics["returned_episode_lengths"].reshape(-1, 2)[249].tolist() == [250, 250]
    assert np.all(np.isfinite(out["loss"][0]))
    # Scripted explorers collect 26.5 [25.9, 27.1] per 250-step episode alone and random play -0.06
    # (README, expert returns): the experts beside the learner are playing well above random.
    expert_returns = metrics["rewards"].reshape(-1, 2, 3)[:250, :, 1:].sum(0)
    assert expert_returns.min() > 10


@pytest.mark.slow
def test_jaxmarl_interface_and_exact_native_steps():
    env = jaxmarl_env.make("goalcycle3", **SMALL)
    assert env.agents == ["agent_0", "agent_1", "agent_2"] and env.num_agents == 3
    assert env.agent_classes == {"agent": env.agents}
    for agent in env.agents:
        assert env.action_space(agent).n == 7 and env.observation_space(agent).shape == (21, 21, 3)
    logged = jaxmarl_wrappers.LogWrapper(env)
    # JaxMARL's baselines ask for the spaces without an agent, through the wrapper
    assert logged.action_space().n == 7 and logged.observation_space().shape == (21, 21, 3)
    params = env.params
    keys = jax.random.split(jax.random.key(0), (STEPS, ENVS))
    obs0, state0 = jax.vmap(logged.reset)(jax.random.split(jax.random.key(1), ENVS))
    native0 = jax.vmap(core.reset, in_axes=(0, None))(jax.random.split(jax.random.key(1), ENVS), params)

    def body(carry, key):
        state, native_state = carry
        actions = jax.random.randint(jax.random.fold_in(key[0], 3), (ENVS, 3), 0, 7)
        as_dict = {a: actions[:, i] for i, a in enumerate(env.agents)}
        obs, state, rewards, dones, infos = jax.vmap(logged.step)(key, state, as_dict)
        reset_keys = jax.vmap(lambda k: jax.random.split(k)[1])(key)
        native = jax.vmap(core.step, in_axes=(0, 0, 0, None))(reset_keys, native_state, actions, params)
        return (state, native[1]), ((obs, state.env_state, rewards, dones, infos), native)

    _, (ours, native) = jax.jit(lambda: jax.lax.scan(body, (state0, native0[1]), keys))()
    tree_equal(obs0, {a: native0[0][:, i] for i, a in enumerate(env.agents)})
    obs, world, rewards, dones, infos = ours
    n_obs, n_world, n_reward, n_terminated, n_truncated, n_info = native
    tree_equal(world, n_world)
    for i, agent in enumerate(env.agents):
        np.testing.assert_array_equal(obs[agent], n_obs[:, :, i])
        np.testing.assert_array_equal(rewards[agent], n_reward[..., i])
        np.testing.assert_array_equal(dones[agent], n_terminated[..., i] | n_info["done"])
    np.testing.assert_array_equal(dones["__all__"], n_info["done"])
    assert np.asarray(dones["__all__"]).sum() == 2 * ENVS
    # JaxMARL's LogWrapper: the return of each finished episode is the sum of that episode's rewards.
    done = np.asarray(dones["__all__"])
    per_step = np.asarray(n_reward)
    for e in range(ENVS):
        ends = np.flatnonzero(done[:, e])
        starts = np.concatenate([[0], ends[:-1] + 1])
        for s, t in zip(starts, ends, strict=True):
            np.testing.assert_allclose(
                infos["returned_episode_returns"][t, e], per_step[s : t + 1, e].sum(0), rtol=1e-6
            )


def test_jaxmarl_reset_state_replaces_the_new_episode():
    env = jaxmarl_env.make("goalcycle3-solo", max_steps=1, observation="symbolic")
    _, state = env.reset(jax.random.key(0))
    _, chosen = env.reset(jax.random.key(5))
    obs, new, _, dones, _ = env.step(jax.random.key(1), state, {"agent_0": 2}, chosen)
    assert bool(dones["__all__"])
    tree_equal(new, chosen)
    tree_equal(obs, env.get_obs(chosen))


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: gymnax_env.make("goalcycle3", slots="learner,learner,expert:explorer"), "exactly one"),
        (lambda: gymnax_env.make("goalcycle3", slots="learner,expert:navigator,random"), "navigator"),
        (
            lambda: gymnax_env.make("goalcycle3", slots="expert:explorer,learner,random", solo_prob=0.5),
            "absent",
        ),
        (lambda: jaxmarl_env.make("goalcycle3", penalty=-1.0), "penalty=-1.0"),
        (
            lambda: jaxmarl_env.make("goalcycle3").step(jax.random.key(0), None, {"agent_0": 0}),
            "one entry per",
        ),
    ],
)
def test_bad_input_is_a_clear_error(make, message):
    with pytest.raises(ValueError, match=message):
        make()
