"""The compiled training loop: `make_program(program_cfg, env, slots) -> (init, run_chunk)`, the
`RunnerState` it carries, and `compiled(program_cfg, mesh, env, slots)`, its jitted `Program` placed on a
device mesh (several seeds in one program), cached per program. `jaxsocial.train.make_train(cfg)` builds
the whole run of a `TrainConfig` as one function.

One iteration = a rollout of `rollout_steps` steps in `num_envs` environments (`lax.scan`; every slot acts,
neural slots through a `vmap` over their stacked params) followed by one PPO update of every learner
(`lax.map` over learners), whose losses, parameters and optimiser state are checked for non-finite values
(`jaxsocial.run.nonfinite`). A chunk of iterations is one `lax.scan` inside one `jit`; the driver
(`jaxsocial.train.train_chunks` over the steps of `jaxsocial.run.driver`) loops over chunks to log,
checkpoint and draw progress.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxsocial.agents import bc, network, population, ppo
from jaxsocial.env import core, observe
from jaxsocial.env.batching import any_in_batch
from jaxsocial.env.types import EnvParams, EnvState
from jaxsocial.run import distributed, nonfinite
from jaxsocial.run.config import ProgramConfig


class RunnerState(NamedTuple):
    """The whole training state between iterations (a pytree; checkpointed at chunk boundaries)."""

    params: Any  # learner params stacked [S_l, ...]
    opt_state: Any  # learner optimiser states stacked [S_l, ...]
    env_states: EnvState  # [E]
    obs: jax.Array  # uint8[E, K, 21, 21, 3] (symbolic: int8[E, K, 7, 7, 4]) the views of `observers(...)`
    resets: jax.Array  # bool[E]: the next step starts an episode
    slots: population.SlotState  # neural slots' LSTM states [S, E, H], experts' memory, last rewards
    demo_carry: network.Carry | None  # bc: learners' LSTM states on the demonstration streams [S_l, E*D, H]
    episode_return: jax.Array  # float32[E, N] return so far in the current episode
    key: jax.Array
    iteration: jax.Array  # int32[]


ENV_AXES = RunnerState(
    params=None,
    opt_state=None,
    env_states=0,
    obs=0,
    resets=0,
    slots=population.SlotState(carry=1, memory=0, reward=0),
    demo_carry=1,  # the streams are environment-major
    episode_return=0,
    key=None,
    iteration=None,
)
"""The environment axis of the RunnerState's arrays, split over devices (pytree prefix; None: replicated)."""


def ppo_batch(
    traj: ppo.Batch,
    last_obs: jax.Array,
    last_resets: jax.Array,
    last_values: jax.Array,
    carry0: network.Carry,
    segment_length: int,
) -> ppo.Batch:
    """The learners' `ppo.Batch`es, stacked [S_l, T(+1), E, ...], of a rollout `traj` (the scan-stacked
    steps, [T, ...]) that ended with the learners' observations `last_obs` [E, S_l, ...], `last_resets`
    bool[E] and values `last_values` float32[S_l, E] (the bootstrap step), starting from the learners' LSTM
    states `carry0`; the segment-start states are those before every `segment_length`-th step.

    A rollout step is a `ppo.Batch` without the time axis and with carry0 None: obs, actions and valid are of
    the training slots (learners for PPO, demonstrators for BC), the rest of the learners: obs uint8 or int8
    [E, S_r, ...] (the environment's observations), resets bool[E], actions int32[S_r, E], valid bool[S_r, E],
    logp, rewards, values, final_values float32[S_l, E], terminated, done bool[S_l, E], segment_carries the
    LSTM states before the step (Carry of float32[S_l, E, H]) and attention int32[S_l, E, N-1] with an
    attention head (`observe.attention_targets`), else None."""
    obs = jnp.concatenate([traj.obs, last_obs[None]], 0)  # [T + 1, E, S_l, ...]
    resets = jnp.concatenate([traj.resets, last_resets[None]], 0)  # [T + 1, E], shared by the learners
    n_learners = last_obs.shape[1]
    per_learner = traj._replace(obs=None, resets=None)  # the rest are [T, S_l, E, ...]
    batch = jax.tree.map(lambda x: jnp.moveaxis(x, 1, 0), per_learner)
    return batch._replace(
        obs=jnp.moveaxis(obs, 2, 0),
        resets=jnp.broadcast_to(resets, (n_learners, *resets.shape)),
        values=jnp.concatenate([batch.values, last_values[:, None]], 1),
        segment_carries=jax.tree.map(lambda c: c[:, ::segment_length], batch.segment_carries),
        carry0=carry0,
    )


def observers(pop: population.Population, algo: str) -> tuple[int, ...]:
    """The slots whose views a program of `algo` renders (`Population.observers`; behaviour cloning trains
    on the demonstrators' views too), so a step beside two scripted experts renders one view, not three."""
    return pop.observers(cloned=algo == "bc")


def make_program(
    cfg: ProgramConfig,
    env_params: EnvParams,
    pop: population.Population,
    mesh: jax.sharding.Mesh | None = None,
):
    """The pure training functions of one program: `cfg` in the validated environment `env_params` with the
    slots `pop` (see `config.setup`).

    Returns `(init, run_chunk)`: `init(key) -> RunnerState`; `run_chunk(state, frozen_params, n) ->
    (state, metrics)` runs n iterations (static n) in one scan, with the frozen slots' stacked params (or
    None). Metrics are dicts of arrays with a leading iteration axis; `metrics[nonfinite.KEY]` holds the
    iteration's finiteness checks ({quantity: bool[n, S_l]}). One seed (`cfg.seeds` is handled by
    `compiled`); `mesh`: the devices the environments will be split over (the PPO update then splits its
    minibatches over them too).
    """
    dp = distributed.data_parallel(mesh)
    net, ppo_cfg = cfg.net, cfg.ppo
    learners = jnp.asarray(pop.learners)
    n_learners, n_neural = len(pop.learners), len(pop.neural)
    n_envs, n_steps = cfg.num_envs, cfg.rollout_steps
    bc_mode = cfg.algo == "bc"
    observed = observers(pop, cfg.algo)
    training = pop.demonstrators if bc_mode else pop.learners
    training_slots = jnp.asarray(training)
    training_views = jnp.asarray(population.view_rows(training, observed))  # their rows of state.obs
    learner_views = jnp.asarray(population.view_rows(pop.learners, observed))
    n_demo_streams = n_envs * len(pop.demonstrators)
    optimizer = bc.make_optimizer(cfg.bc) if bc_mode else ppo.make_optimizer(ppo_cfg)

    def init(key: jax.Array) -> RunnerState:
        k_params, k_env, k_run = jax.random.split(key, 3)
        params = jax.vmap(network.init, in_axes=(0, None))(jax.random.split(k_params, n_learners), net)
        reset = functools.partial(core.reset, observers=observed)
        obs, env_states = jax.vmap(reset, in_axes=(0, None))(jax.random.split(k_env, n_envs), env_params)
        return RunnerState(
            params=params,
            opt_state=jax.vmap(optimizer.init)(params),
            env_states=env_states,
            obs=obs,
            resets=jnp.ones(n_envs, bool),
            slots=population.init_slot_state(pop, net, env_params, n_envs),
            demo_carry=network.initial_carry(net, (n_learners, n_demo_streams)) if bc_mode else None,
            episode_return=jnp.zeros((n_envs, env_params.n_agents), jnp.float32),
            key=k_run,
            iteration=jnp.zeros((), jnp.int32),
        )

    def all_params(state: RunnerState, frozen_params):
        if frozen_params is None:
            return state.params
        return jax.tree.map(lambda a, b: jnp.concatenate([a, b]), state.params, frozen_params)

    def attention_targets(env_states: EnvState) -> jax.Array | None:
        if not net.attention:
            return None
        targets = jax.vmap(observe.attention_targets, in_axes=(0, None))(env_states, env_params)
        return jnp.moveaxis(targets[:, learners], 1, 0)

    def env_step(carry, key):
        state, params = carry
        k_act, k_env = jax.random.split(key)
        actions, slots, logp, values = population.act(
            k_act,
            pop,
            net,
            env_params,
            params,
            state.slots,
            state.obs,
            state.env_states,
            state.resets,
            observed,
        )
        alive, present = state.env_states.active, state.env_states.present  # [E, N] at the step's start
        obs, env_states, reward, terminated, truncated, info = core.step_batch(
            jax.random.split(k_env, n_envs), state.env_states, actions, env_params, observed
        )
        done = info["done"]
        final_values = jax.lax.cond(
            any_in_batch(done),
            lambda: population.values(pop, net, params, slots.carry, info["final_obs"], observers=observed),
            lambda: jnp.zeros((n_neural, n_envs), jnp.float32),
        )
        episode_return = state.episode_return + reward
        finished = (done[:, None] & present).astype(jnp.float32)  # episodes each slot took part in
        stats = (jnp.sum(episode_return * finished, 0), jnp.sum(finished, 0))
        agent_done = terminated | done[:, None]
        transition = ppo.Batch(
            obs=state.obs[:, training_views],
            resets=state.resets,
            actions=actions[:, training_slots].T,
            logp=logp[:n_learners],
            rewards=reward[:, learners].T,
            terminated=terminated[:, learners].T,
            done=agent_done[:, learners].T,
            final_values=final_values[:n_learners],
            valid=alive[:, training_slots].T,
            carry0=None,
            attention=attention_targets(state.env_states),
            values=None if bc_mode else values[:n_learners],
            segment_carries=None if bc_mode else jax.tree.map(lambda c: c[:n_learners], state.slots.carry),
        )
        new_state = state._replace(
            env_states=env_states,
            obs=obs,
            resets=done,
            slots=population.with_rewards(slots, reward),
            episode_return=jnp.where(done[:, None], 0.0, episode_return),
        )
        return (new_state, params), (transition, stats)

    def ppo_update(state: RunnerState, params, traj: ppo.Batch, carry0, k_update):
        bootstrap = population.values(pop, net, params, state.slots.carry, state.obs, state.resets, observed)
        batch = ppo_batch(  # [S_l, T(+1), E, ...]
            traj,
            state.obs[:, learner_views],
            state.resets,
            bootstrap[:n_learners],
            carry0,
            ppo_cfg.segment_length,
        )

        # Learners are updated one after another (`lax.map`, same result as a vmap): XLA:CPU stalled on the
        # vmapped paper-size network, whose convolutions in frame batches are themselves a `lax.map`.
        def update(args):
            key, params, opt_state, learner_batch = args
            return ppo.update(key, params, opt_state, net, ppo_cfg, learner_batch, dp)

        new_params, new_opt, losses = jax.lax.map(
            update, (jax.random.split(k_update, n_learners), state.params, state.opt_state, batch)
        )
        return state._replace(params=new_params, opt_state=new_opt), losses

    def bc_update(state: RunnerState, traj: ppo.Batch):
        # Demonstration streams, time-major [T, E * D, ...] (environment-major, demonstrator-minor).
        def streams(x):  # [T, E, D, ...] -> [T, E * D, ...]
            return x.reshape(n_steps, n_demo_streams, *x.shape[3:])

        n_demo = len(pop.demonstrators)
        obs = streams(traj.obs)
        resets = jnp.repeat(traj.resets, n_demo, axis=1)
        actions, valid = (streams(jnp.moveaxis(x, 1, 2)) for x in (traj.actions, traj.valid))

        def update(args):
            params, opt_state, carry = args
            return bc.update(params, opt_state, carry, net, cfg.bc, obs, resets, actions, valid)

        new_params, new_opt, carry, losses = jax.lax.map(
            update, (state.params, state.opt_state, state.demo_carry)
        )
        return state._replace(params=new_params, opt_state=new_opt, demo_carry=carry), losses

    def iteration(state: RunnerState, frozen_params):
        key, k_roll, k_update = jax.random.split(state.key, 3)
        params = all_params(state, frozen_params)
        carry0 = jax.tree.map(lambda c: c[:n_learners], state.slots.carry)
        (state, _), (traj, (return_sum, episodes)) = jax.lax.scan(
            env_step, (state, params), jax.random.split(k_roll, n_steps)
        )
        if bc_mode:
            state, losses = bc_update(state, traj)
        else:
            state, losses = ppo_update(state, params, traj, carry0, k_update)
        episodes_per_slot = jnp.sum(episodes, 0)
        metrics = {
            "episodes": episodes_per_slot,
            "return": jnp.sum(return_sum, 0) / jnp.maximum(episodes_per_slot, 1.0),
            **losses,
            nonfinite.KEY: nonfinite.check(losses, state.params, state.opt_state),
        }
        return state._replace(key=key, iteration=state.iteration + 1), metrics

    def run_chunk(state: RunnerState, frozen_params, n: int):
        return jax.lax.scan(lambda s, _: iteration(s, frozen_params), state, None, length=n)

    return init, run_chunk


def over_seeds(run_chunk, batching: str = "vmap"):
    """`run_chunk` of `make_program` over a leading seed axis of the state and the metrics (the frozen params
    are shared): 'vmap' batches the seeds, 'map' runs them one after another (`lax.map`); both give every
    seed the result of a run of its own (vmap up to floating-point summation order)."""

    def run_seeds(state, frozen_params, n: int):
        if batching == "vmap":
            return jax.vmap(lambda s: run_chunk(s, frozen_params, n))(state)
        return jax.lax.map(lambda s: run_chunk(s, frozen_params, n), state)

    return run_seeds


class Program(NamedTuple):
    """A run's compiled functions, placed on a device mesh.

    init(seeds): int32[] (or int32[K] for K seeds) -> RunnerState ([K, ...] for K seeds) on `shardings`;
    run_chunk(state, frozen_params, n) -> (state, metrics) (n static; the state is donated; metrics
    replicated, [K, n, ...] for K seeds); frozen params must be placed with `distributed.put`.
    """

    init: Any
    run_chunk: Any
    shardings: RunnerState
    mesh: jax.sharding.Mesh


@functools.lru_cache(maxsize=8)
def compiled(
    program_cfg: ProgramConfig,
    mesh: jax.sharding.Mesh,
    env_params: EnvParams,
    pop: population.Population,
) -> Program:
    """The `Program` of `program_cfg` in the validated environment `env_params` with the slots `pop`
    (`config.Setup`) on `mesh` (`data_mesh`), shared between runs whose programs are the same (tests,
    notebooks, sweeps and a run's stages of one environment compile once)."""
    init, run_chunk = make_program(program_cfg, env_params, pop, mesh)
    replicated = distributed.replicated(mesh)

    def init_from_seed(seed):
        return init(jax.random.key(seed))

    one_seed = jax.eval_shape(init_from_seed, jax.ShapeDtypeStruct((), jnp.int32))
    shardings = distributed.state_shardings(one_seed, mesh, ENV_AXES)
    init_one = jax.jit(init_from_seed, in_shardings=replicated, out_shardings=shardings)
    program_init = init_one
    if program_cfg.seeds > 1:  # each seed's state as in a run of its own, stacked
        batching = program_cfg.seed_batching
        if batching == "auto":
            batching = "map" if mesh.devices.flat[0].platform == "cpu" else "vmap"
        run_chunk = over_seeds(run_chunk, batching)
        stacked = jax.eval_shape(population.stack, [one_seed] * program_cfg.seeds)
        shardings = distributed.state_shardings(stacked, mesh, ENV_AXES, offset=1)
        stack = jax.jit(population.stack, out_shardings=shardings)

        def program_init(seeds):
            return stack([init_one(np.int32(seed)) for seed in seeds])

    return Program(
        program_init,
        jax.jit(
            run_chunk,
            static_argnums=2,
            donate_argnums=0,
            in_shardings=(shardings, replicated),
            out_shardings=(shardings, replicated),
        ),
        shardings,
        mesh,
    )


def data_mesh(program_cfg: ProgramConfig, devices: int) -> jax.sharding.Mesh:
    """The `devices` (0: all) the environments of `program_cfg` are split over (ValueError, before
    compiling, if they do not split)."""
    sizes = {"num_envs": program_cfg.num_envs}
    if program_cfg.algo == "ppo":
        sizes["minibatch_segments"] = program_cfg.ppo.minibatch_segments
    return distributed.data_mesh(devices, **sizes)
