"""Training: `TrainConfig`, `make_train(cfg) -> (init, run_chunk, train)`, the chunked driver and the CLI.

One iteration = a rollout of `rollout_steps` steps in `num_envs` environments (`lax.scan`; every slot acts,
neural slots through a `vmap` over their stacked params) followed by one PPO update of every learner
(`lax.map` over learners). A chunk of iterations is one `lax.scan` inside one `jit`; the Python driver loops
over chunks to log, checkpoint and draw progress.

    python -m jaxsocial.train --env goalcycle3            # small default, a few minutes on 2 CPU cores
    python -m jaxsocial.train --preset paper --env goalcycle3
"""

from __future__ import annotations

import dataclasses
import functools
import json
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import jaxsocial
from jaxsocial import checkpoint, compile_cache, distributed, evaluate, logs, schedule
from jaxsocial.agents import bc, network, population, ppo
from jaxsocial.agents.bc import BCConfig
from jaxsocial.agents.network import NetworkConfig
from jaxsocial.agents.ppo import PPOConfig
from jaxsocial.env import core, observe
from jaxsocial.env.types import NUM_ACTIONS, EnvParams, EnvState


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """A training run. Every field is a command-line flag."""

    env: str = "goalcycle3"
    """Environment preset (see `jaxsocial.registered_envs()`)."""
    algo: str = "ppo"
    """'ppo' (reinforcement learning) or 'bc' (behaviour cloning of the expert and frozen slots)."""
    env_args: str = ""
    """EnvParams overrides, e.g. 'penalty=0.5,max_steps=100'."""
    slots: str = ""
    """One entry per agent slot: learner | random | frozen:RUN_DIR[@k] | expert:ckpt=RUN_DIR[@k] (a trained
    expert) | expert:KIND[:epsilon=E,forget=F] (scripted: explorer, oracle, navigator). Default: a learner in
    slot 0, the environment's scripted expert in the next two (explorer in Goal Cycle, navigator in Four
    Rooms and Maze), random distractors in any others."""
    stages: str = ""
    """Environment changes during training, e.g. the penalty curriculum
    '0:penalty=0.5;return>=20:penalty=1.0;return>=20:penalty=1.5' or the switch to mixed solo/social
    training '5000:solo_prob=0.75' (see jaxsocial.schedule)."""
    seed: int = 0
    """PRNG seed."""
    iterations: int = 500
    """PPO iterations (one rollout + one update each)."""
    num_envs: int = 32
    """Parallel environments per rollout."""
    rollout_steps: int = 32
    """Steps per rollout (a multiple of ppo.chunk_length)."""
    chunk_iterations: int = 10
    """Iterations per compiled chunk (the driver logs and may checkpoint between chunks)."""
    checkpoint_every: int = 100
    """Save a checkpoint every this many iterations (rounded up to whole chunks) and at the end."""
    keep_checkpoints: int = 3
    """Checkpoints (and exported policies) kept per seed: the latest N; older ones are deleted."""
    run_name: str | None = None
    """Run directory name under runs_dir (default: '<env>-s<seed>')."""
    runs_dir: str = "runs"
    """Where run directories go."""
    resume: bool = False
    """Continue the run in the existing run directory from its latest checkpoint."""
    overwrite: bool = False
    """Delete an existing run directory of the same name and start again."""
    logger: str | None = None
    """Extra metrics sink: 'tensorboard' or 'wandb' (off by default)."""
    progress: bool = True
    """Show a progress line."""
    preset: str = "small"
    """Hyperparameter preset the other defaults came from: 'small', 'paper' or 'expert'."""
    net: NetworkConfig = NetworkConfig(conv_channels=(8, 16, 16), hidden=32, mlp=32)
    """Network (the paper's is conv (32, 64, 64), hidden 192, mlp 64)."""
    ppo: PPOConfig = PPOConfig(
        lr=5e-4, num_minibatches=8, minibatch_chunks=64, kl_target=0.02, kl_hard_limit=0.05
    )
    """PPO hyperparameters."""
    bc: BCConfig = BCConfig()
    """Behaviour-cloning hyperparameters (with --algo bc)."""
    # Scale-out (see jaxsocial/distributed.py and the README section "Seeds, devices and hosts").
    seeds: int = 1
    """Independent seeds seed, seed + 1, ... trained together in one compiled program; each seed's metrics,
    checkpoints and policy go to run_dir/s<seed>/."""
    seed_batching: str = "auto"
    """How the seeds share the program: 'vmap' (batched), 'map' (one after another, `lax.map`) or 'auto'
    (map on CPUs, where it measured as fast and compiles faster; vmap on GPUs and TPUs)."""
    devices: int = 0
    """Devices the environments are split over (data parallel; 0: all devices of all processes)."""
    coordinator: str | None = None
    """Multi-host: HOST:PORT of process 0, the same for every process, or 'auto' (Slurm, Open MPI, TPU);
    default $JAX_COORDINATOR_ADDRESS."""
    num_processes: int | None = None
    """Multi-host: number of processes, one per host (default $JAX_NUM_PROCESSES)."""
    process_id: int | None = None
    """Multi-host: this process's index, 0 to num_processes - 1 (default $JAX_PROCESS_ID)."""
    compile_cache: str | None = None
    """Persistent compilation cache directory: a later run of the same program skips compiling (off by
    default; see `python -m jaxsocial.compile_cache`)."""
    # Evaluation during training (see `jaxsocial.evaluate.make_learner_eval`).
    eval_envs: tuple[str, ...] = ()
    """Environments the first learner is evaluated in during training, each NAME or NAME:field=value,...
    (e.g. goalcycle3-solo goalcycle4), beside that environment's default companions; logged in
    metrics.jsonl as 'eval/<spec>' on every eval_every-th iteration and the last."""
    eval_every: int = 100
    """Iterations between evaluations (with eval_envs)."""
    eval_episodes: int = 64
    """Episodes per evaluation environment and evaluation."""

    @property
    def env_overrides(self) -> dict[str, Any]:
        return schedule.parse_assignments(self.env_args)


EXPERT_CURRICULUM = "0:penalty=0.5;return>=10:penalty=1.0;return>=10:penalty=1.5"
"""The penalty curriculum (paper section 3.1): low penalty first, raised once the learner's mean episode
return reaches 10 (a third of what a perfect 250-step Goal Cycle episode collects)."""

PRESETS = {
    "small": TrainConfig(),
    "paper": TrainConfig(
        preset="paper",
        iterations=11445,  # 375M env steps, the paper's budget
        num_envs=128,
        rollout_steps=256,
        chunk_iterations=10,
        checkpoint_every=500,
        net=NetworkConfig(),
        ppo=PPOConfig(),
    ),
}
PRESETS["expert"] = dataclasses.replace(
    PRESETS["paper"],
    preset="expert",
    env="goalcycle3-solo",
    stages=EXPERT_CURRICULUM,
    ppo=PPOConfig(lr=1e-5),
)
"""The paper's expert training: paper network and PPO with the expert learning rate 1e-5, alone, through
the penalty curriculum; later runs load the result with `expert:ckpt=RUN_DIR`."""


ALGOS = ("ppo", "bc")


class Setup(NamedTuple):
    """Everything static about a run, validated."""

    env_params: EnvParams
    pop: population.Population
    stages: tuple[schedule.Stage, ...]
    frozen_params: Any  # stacked params of frozen slots, or None (also None when not loaded)


def stage_config(cfg: TrainConfig, stages: tuple[schedule.Stage, ...], index: int) -> TrainConfig:
    """The single-stage config whose program runs stage `index` of `cfg` (-1: before the first stage).

    Its `env_args` are canonical (sorted, without values equal to the preset's), so stages with the same
    environment share one compiled program.
    """
    base = jaxsocial.make(cfg.env)[1]
    env_args = {**cfg.env_overrides, **schedule.overrides_at(stages, index)}
    env_args = {k: v for k, v in sorted(env_args.items()) if not hasattr(base, k) or getattr(base, k) != v}
    return dataclasses.replace(cfg, env_args=schedule.format_assignments(env_args), stages="")


def _check_stage(env_params: EnvParams, first: EnvParams, pop: population.Population, where: str) -> None:
    changed = [f for f in schedule.STRUCTURAL_FIELDS if getattr(env_params, f) != getattr(first, f)]
    if changed:
        raise ValueError(f"{where} changes {changed}, which set array shapes; a stage may not change them")
    population.require_rgb(env_params, where)
    if env_params.solo_prob > 0 and any(i >= env_params.solo_agents for i in pop.learners):
        raise ValueError(
            f"{where}: solo episodes keep only the first solo_agents={env_params.solo_agents} slots, but "
            f"learners are in slots {pop.learners}; put learners first or raise solo_agents"
        )
    pop.validate(env_params)


def setup(cfg: TrainConfig, load_frozen: bool = True) -> Setup:
    """Validate the config (every stage) and load frozen policies; raises ValueError before anything
    compiles."""
    stages = schedule.parse_stages(cfg.stages)
    _, env_params = jaxsocial.make(cfg.env, **cfg.env_overrides)
    pop = population.Population(
        population.parse_slots(cfg.slots or population.default_slots(env_params), env_params.n_agents)
    )
    _check_stage(env_params, env_params, pop, "--env-args")
    for index in range(len(stages)):
        overrides = stage_config(cfg, stages, index).env_overrides
        _check_stage(jaxsocial.make(cfg.env, **overrides)[1], env_params, pop, f"stage {index}")
    if cfg.algo not in ALGOS:
        raise ValueError(f"unknown --algo {cfg.algo!r}; choose one of {ALGOS}")
    for name in ("num_envs", "rollout_steps", "keep_checkpoints"):
        value = getattr(cfg, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name}={value!r} must be a whole number >= 1 (for every --algo)")
    if cfg.algo == "bc" and not pop.demonstrators:
        raise ValueError("--algo bc clones expert or frozen slots, and --slots has none")
    if cfg.algo == "bc" and cfg.net.n_actions != NUM_ACTIONS:
        raise ValueError(
            f"--algo bc clones demonstrators that use all {NUM_ACTIONS} actions (scripted experts idle with "
            f"'done' and act at random with epsilon), so net.n_actions must be {NUM_ACTIONS}, not "
            f"{cfg.net.n_actions}"
        )
    if cfg.net.attention and (cfg.algo != "ppo" or cfg.net.n_others != env_params.n_agents - 1):
        raise ValueError(
            f"net.aux={cfg.net.aux!r}: the attention loss trains PPO learners to locate the "
            f"{env_params.n_agents - 1} other agent slots, so it needs --algo ppo and net.n_others "
            f"{env_params.n_agents - 1} (got --algo {cfg.algo}, net.n_others {cfg.net.n_others})"
        )
    if cfg.algo == "ppo":
        ppo.validate(cfg.ppo, cfg.rollout_steps, cfg.num_envs)
    if cfg.iterations < 1 or cfg.chunk_iterations < 1 or cfg.checkpoint_every < 1:
        raise ValueError("iterations, chunk_iterations and checkpoint_every must be >= 1")
    if isinstance(cfg.seeds, bool) or not isinstance(cfg.seeds, int) or cfg.seeds < 1:
        raise ValueError(f"seeds must be a whole number >= 1, got {cfg.seeds!r}")
    if cfg.seed_batching not in SEED_BATCHING:
        raise ValueError(f"unknown seed_batching {cfg.seed_batching!r}; choose from {SEED_BATCHING}")
    if cfg.eval_envs:
        if cfg.eval_every < 1:
            raise ValueError(f"eval_every={cfg.eval_every} must be >= 1")
        evaluate.make_learner_eval(cfg.eval_envs, cfg.net, cfg.eval_episodes)  # validates, compiles nothing
    if cfg.seeds > 1 and any(stage.threshold is not None for stage in stages):
        raise ValueError(
            "--seeds > 1 trains the seeds in one program, which is in one stage at a time; a stage "
            "triggered by the return would start at another iteration for each seed: train them one by one"
        )
    frozen = None
    if pop.frozen and load_frozen:
        frozen = population.stack([population.load_policy(pop.slots[i].path, cfg.net) for i in pop.frozen])
    return Setup(env_params, pop, stages, frozen)


SEED_BATCHING = ("auto", "vmap", "map")


class RunnerState(NamedTuple):
    """The whole training state between iterations (a pytree; checkpointed at chunk boundaries)."""

    params: Any  # learner params stacked [S_l, ...]
    opt_state: Any  # learner optimiser states stacked [S_l, ...]
    env_states: EnvState  # [E]
    obs: jax.Array  # uint8[E, N, 21, 21, 3]
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


class Transition(NamedTuple):
    """One rollout step. obs, actions and valid are of the recorded slots (learners for PPO, demonstrators
    for BC), the rest of the learners."""

    obs: jax.Array  # uint8[E, S_r, ...]
    resets: jax.Array
    actions: jax.Array  # int32[S_l, E]
    logp: jax.Array
    rewards: jax.Array
    terminated: jax.Array
    done: jax.Array
    final_values: jax.Array
    valid: jax.Array
    attention: jax.Array | None  # int32[S_l, E, N-1] with an attention head (`observe.attention_targets`)


def make_train(cfg: TrainConfig, mesh: jax.sharding.Mesh | None = None):
    """Build the pure training functions for `cfg`, a single-stage config (see `stage_config`); validated
    first.

    Returns `(init, run_chunk, train)`: `init(key) -> RunnerState`; `run_chunk(state, frozen_params, n) ->
    (state, metrics)` runs n iterations (static n) in one scan, with the frozen slots' stacked params (or
    None); `train(key) -> (state, metrics)` is the whole run (it loads frozen policies when traced).
    Metrics are dicts of arrays with a leading iteration axis. One seed (`cfg.seeds` is handled by
    `compiled`); `mesh`: the devices the environments will be split over (the PPO update then splits its
    minibatches over them too).
    """
    if cfg.stages:
        raise ValueError("make_train builds one stage's program; the driver (run) switches stages")
    env_params, pop, _, _ = setup(cfg, load_frozen=False)
    dp = distributed.data_parallel(mesh)
    net, ppo_cfg = cfg.net, cfg.ppo
    learners = jnp.asarray(pop.learners)
    n_learners, n_neural = len(pop.learners), len(pop.neural)
    n_envs, n_steps = cfg.num_envs, cfg.rollout_steps
    bc_mode = cfg.algo == "bc"
    recorded = jnp.asarray(pop.demonstrators if bc_mode else pop.learners)
    n_demo_streams = n_envs * len(pop.demonstrators)
    optimizer = bc.make_optimizer(cfg.bc) if bc_mode else ppo.make_optimizer(ppo_cfg)

    def init(key: jax.Array) -> RunnerState:
        k_params, k_env, k_run = jax.random.split(key, 3)
        params = jax.vmap(network.init, in_axes=(0, None))(jax.random.split(k_params, n_learners), net)
        obs, env_states = jax.vmap(core.reset, in_axes=(0, None))(jax.random.split(k_env, n_envs), env_params)
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
        actions, slots, logp, _ = population.act(
            k_act, pop, net, env_params, params, state.slots, state.obs, state.env_states, state.resets
        )
        alive, present = state.env_states.active, state.env_states.present  # [E, N] at the step's start
        obs, env_states, reward, terminated, truncated, info = core.step_batch(
            jax.random.split(k_env, n_envs), state.env_states, actions, env_params
        )
        done = info["done"]
        final_values = jax.lax.cond(
            core.any_in_batch(done),
            lambda: population.values(pop, net, params, slots.carry, info["final_obs"]),
            lambda: jnp.zeros((n_neural, n_envs), jnp.float32),
        )
        episode_return = state.episode_return + reward
        finished = (done[:, None] & present).astype(jnp.float32)  # episodes each slot took part in
        stats = (jnp.sum(episode_return * finished, 0), jnp.sum(finished, 0))
        agent_done = terminated | done[:, None]
        transition = Transition(
            obs=state.obs[:, recorded],
            resets=state.resets,
            actions=actions[:, recorded].T,
            logp=logp[:n_learners],
            rewards=reward[:, learners].T,
            terminated=terminated[:, learners].T,
            done=agent_done[:, learners].T,
            final_values=final_values[:n_learners],
            valid=alive[:, recorded].T,
            attention=attention_targets(state.env_states),
        )
        new_state = state._replace(
            env_states=env_states,
            obs=obs,
            resets=done,
            slots=population.record_rewards(slots, reward),
            episode_return=jnp.where(done[:, None], 0.0, episode_return),
        )
        return (new_state, params), (transition, stats)

    def ppo_update(state: RunnerState, traj: Transition, carry0, k_update):
        # Per learner, time-major: [S_l, T(+1), E, ...].
        obs = jnp.concatenate([traj.obs, state.obs[None, :, learners]], 0)
        resets = jnp.concatenate([traj.resets, state.resets[None]], 0)
        batch = ppo.Batch(
            obs=jnp.moveaxis(obs, 2, 0),
            resets=jnp.broadcast_to(resets, (n_learners, *resets.shape)),
            actions=jnp.moveaxis(traj.actions, 1, 0),
            logp=jnp.moveaxis(traj.logp, 1, 0),
            rewards=jnp.moveaxis(traj.rewards, 1, 0),
            terminated=jnp.moveaxis(traj.terminated, 1, 0),
            done=jnp.moveaxis(traj.done, 1, 0),
            final_values=jnp.moveaxis(traj.final_values, 1, 0),
            valid=jnp.moveaxis(traj.valid, 1, 0),
            carry0=carry0,
            attention=None if traj.attention is None else jnp.moveaxis(traj.attention, 1, 0),
        )

        # Learners are updated one after another (`lax.map`, same result as a vmap): XLA:CPU stalled on the
        # vmapped paper-size network, whose chunked convolutions are themselves a `lax.map`.
        def update(args):
            key, params, opt_state, learner_batch = args
            return ppo.update(key, params, opt_state, net, ppo_cfg, learner_batch, dp)

        new_params, new_opt, losses = jax.lax.map(
            update, (jax.random.split(k_update, n_learners), state.params, state.opt_state, batch)
        )
        return state._replace(params=new_params, opt_state=new_opt), losses

    def bc_update(state: RunnerState, traj: Transition):
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
            state, losses = ppo_update(state, traj, carry0, k_update)
        episodes_per_slot = jnp.sum(episodes, 0)
        metrics = {
            "episodes": episodes_per_slot,
            "return": jnp.sum(return_sum, 0) / jnp.maximum(episodes_per_slot, 1.0),
            **losses,
        }
        return state._replace(key=key, iteration=state.iteration + 1), metrics

    def run_chunk(state: RunnerState, frozen_params, n: int):
        return jax.lax.scan(lambda s, _: iteration(s, frozen_params), state, None, length=n)

    def train(key: jax.Array):
        return run_chunk(init(key), setup(cfg).frozen_params, cfg.iterations)

    return init, run_chunk, train


DRIVER_FIELDS = {
    "iterations",
    "resume",
    "overwrite",
    "progress",
    "logger",
    "checkpoint_every",
    "keep_checkpoints",
    "run_name",
    "runs_dir",
    "devices",
    "coordinator",
    "num_processes",
    "process_id",
    "compile_cache",
    "eval_envs",
    "eval_every",
    "eval_episodes",
}
"""Fields that do not change the compiled program (or only its placement: `devices`), so a run can be resumed
with other values."""


def over_seeds(run_chunk, batching: str = "vmap"):
    """`run_chunk` of `make_train` over a leading seed axis of the state and the metrics (the frozen params
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
def _compiled(program_cfg: TrainConfig, mesh: jax.sharding.Mesh) -> Program:
    init, run_chunk, _ = make_train(program_cfg, mesh)
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


def data_mesh(cfg: TrainConfig) -> jax.sharding.Mesh:
    """The devices `cfg` splits its environments over (ValueError, before compiling, if they do not split)."""
    sizes = {"num_envs": cfg.num_envs}
    if cfg.algo == "ppo":
        sizes["minibatch_chunks"] = cfg.ppo.minibatch_chunks
    return distributed.data_mesh(cfg.devices, **sizes)


def compiled(cfg: TrainConfig, mesh: jax.sharding.Mesh | None = None) -> Program:
    """The `Program` of `cfg` on `mesh` (default: `data_mesh(cfg)`), shared
    between runs whose programs are the same (tests, notebooks and sweeps in one process compile once)."""
    if mesh is None:
        mesh = data_mesh(cfg)
    defaults = TrainConfig()
    unused = DRIVER_FIELDS | {"seed"}  # the seeds are an argument of `init`
    return _compiled(dataclasses.replace(cfg, **{f: getattr(defaults, f) for f in unused}), mesh)


def config_dict(cfg: TrainConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def metric_rows(
    metrics: dict[str, np.ndarray], first_iteration: int, sps: float, pop
) -> list[dict[str, Any]]:
    """One JSON row per iteration: per-slot returns and episode counts, per-learner losses."""
    rows = []
    n = len(next(iter(metrics.values())))
    for i in range(n):
        row: dict[str, Any] = {"iteration": first_iteration + i + 1, "env_steps_per_s": sps}
        for slot in range(len(pop.slots)):
            row[f"return/{slot}"] = float(metrics["return"][i][slot])
            row[f"episodes/{slot}"] = int(metrics["episodes"][i][slot])
        for name, value in metrics.items():
            if name in ("return", "episodes"):
                continue
            for j, slot in enumerate(pop.learners):
                row[f"{name}/{slot}"] = float(value[i][j])
        rows.append(row)
    return rows


def progress_fields(metrics: dict[str, np.ndarray], sps: float, pop: population.Population) -> dict[str, Any]:
    """What the progress line shows for a chunk: speed and each slot's mean return over the episodes that
    finished in the chunk ('-' where none did), named `return[<slot> <kind>]`, e.g. 'return[1 explorer]'."""
    episodes = metrics["episodes"].sum(0)
    returns = (metrics["return"] * metrics["episodes"]).sum(0) / np.maximum(episodes, 1)
    shown: dict[str, Any] = {"env-steps/s": int(sps)}
    for s, (r, n) in enumerate(zip(returns, episodes, strict=True)):
        shown[f"return[{s} {pop.slots[s].label.split(':')[-1]}]"] = float(r) if n else "-"
    return shown


def learner_return(metrics: dict[str, np.ndarray], pop: population.Population) -> float | None:
    """The learners' mean episode return over a chunk's finished episodes (None if none finished)."""
    learners = list(pop.learners)
    episodes = metrics["episodes"][:, learners]
    if episodes.sum() == 0:
        return None
    return float((metrics["return"][:, learners] * episodes).sum() / episodes.sum())


def run_name(cfg: TrainConfig) -> str:
    """`cfg.run_name`, or '<env>-s<seed>' ('<env>-s<first>-<last>' for several seeds)."""
    if cfg.run_name:
        return cfg.run_name
    last = f"-{cfg.seed + cfg.seeds - 1}" if cfg.seeds > 1 else ""
    return f"{cfg.env}-s{cfg.seed}{last}"


def seed_runs(cfg: TrainConfig, run_dir: Path) -> list[tuple[TrainConfig, Path]]:
    """(config, directory) of each seed: the run itself for one seed; for several, `run_dir/s<seed>/` with
    the config of a one-seed run of that seed (so it reads like one, e.g. for `frozen:RUN_DIR/s1`)."""
    if cfg.seeds == 1:
        return [(cfg, run_dir)]
    runs = []
    for seed in range(cfg.seed, cfg.seed + cfg.seeds):
        name = f"{run_name(cfg)}/s{seed}"
        runs.append((dataclasses.replace(cfg, seed=seed, seeds=1, run_name=name), run_dir / f"s{seed}"))
    return runs


def run(cfg: TrainConfig) -> Path:
    """Train with logging and checkpoints in `runs_dir/run_name`; returns the run directory.

    The run goes through the stages of `cfg.stages` (one compiled program each, switched between chunks);
    metrics rows record the stage, and checkpoints the stage to resume in. Several seeds train in one
    program; each seed's config, metrics, checkpoints and policy go to its own directory (`seed_runs`). In a
    multi-process run every process calls this with the same config (and its own process_id); only process 0
    writes logs, metrics and progress.
    """
    distributed.initialize(cfg.coordinator, cfg.num_processes, cfg.process_id)
    if cfg.compile_cache:
        compile_cache.enable(cfg.compile_cache)
    _, pop, stages, frozen = setup(cfg)  # validate before touching the disk or compiling
    mesh = data_mesh(cfg)
    name = run_name(cfg)
    run_dir = Path(cfg.runs_dir).expanduser() / name
    seeds = seed_runs(cfg, run_dir)
    config = config_dict(cfg)

    def prepare() -> None:
        logs.prepare_run_dir(cfg.runs_dir, name, resume=cfg.resume, overwrite=cfg.overwrite)
        if cfg.resume and (run_dir / "config.json").exists():
            diff = [k for k in logs.config_diff(logs.read_config(run_dir), config) if k not in DRIVER_FIELDS]
            if diff:
                raise ValueError(f"cannot resume {run_dir}: the config differs in {diff}")
        for _, seed_dir in seeds:
            for sub in ("checkpoints", population.POLICY_DIR):  # made here, before any process looks
                (seed_dir / sub).mkdir(parents=True, exist_ok=True)
        if not cfg.resume:  # a resumed run's config is rewritten once it has succeeded
            write_configs()

    def write_configs() -> None:
        logs.write_config(run_dir, config)
        for seed_cfg, seed_dir in seeds:
            if seed_cfg is not cfg:
                logs.write_config(seed_dir, config_dict(seed_cfg))

    distributed.on_main(prepare)
    main = distributed.is_main()
    stage = schedule.initial_index(stages)
    program = compiled(stage_config(cfg, stages, stage), mesh)
    state = program.init(np.asarray([c.seed for c, _ in seeds] if cfg.seeds > 1 else cfg.seed, np.int32))
    if frozen is not None:
        frozen = distributed.put(frozen, jax.tree.map(lambda _: distributed.replicated(mesh), frozen))
    if cfg.resume:
        state, stage = restore_seeds(cfg, [d / "checkpoints" for _, d in seeds], state, program, stage, pop)
    start = int(np.asarray(state.iteration).reshape(-1)[0])
    metrics_logs = [logs.MetricsLog(d) for _, d in seeds] if main else []
    for metrics_log in metrics_logs:
        metrics_log.truncate_after(start)
    extras = [logs.make_logger(cfg.logger, d, config_dict(c)) for c, d in seeds] if main else []
    progress = None
    parts = [f"{cfg.seeds} seeds"] if cfg.seeds > 1 else []
    parts += [distributed.describe(list(mesh.devices.flat))] if mesh.size > 1 else []
    desc = f"{name} ({', '.join(parts)})" if parts else name
    executables: dict[tuple[int, int], Any] = {}  # (stage, n) -> compiled chunk of n iterations
    steps_per_iteration = cfg.num_envs * cfg.rollout_steps
    learner_eval = evaluate.make_learner_eval(cfg.eval_envs, cfg.net, cfg.eval_episodes) if main else None
    last_saved = start
    it = start
    while it < cfg.iterations:
        n = min(cfg.chunk_iterations, cfg.iterations - it)
        switch = schedule.next_start(stages, stage)
        if switch is not None and switch > it:
            n = min(n, switch - it)  # land exactly on the next stage's first iteration
        if cfg.eval_envs:
            n = min(n, cfg.eval_every - it % cfg.eval_every)  # end chunks on evaluation iterations
        compile_s = None
        if (stage, n) not in executables:  # compiled ahead of time, so the speed below excludes it
            if cfg.progress and main:
                print(f"{desc}: compiling the {n}-iteration chunk (stage {stage}) ...", flush=True)
            t0 = time.perf_counter()
            program = compiled(stage_config(cfg, stages, stage), mesh)
            executables[stage, n] = program.run_chunk.lower(state, frozen, n).compile()
            compile_s = time.perf_counter() - t0
        if progress is None and cfg.progress and main:
            progress = logs.Progress(cfg.iterations, desc=desc, initial=it)
        t0 = time.perf_counter()
        state, metrics = executables[stage, n](state, frozen)
        metrics = jax.device_get(metrics)
        sps = n * steps_per_iteration / (time.perf_counter() - t0)  # per seed
        for k, (metrics_log, extra) in enumerate(zip(metrics_logs, extras, strict=True)):
            rows = metric_rows(seed_part(metrics, k, cfg.seeds), it, round(sps), pop)
            for row in rows:
                row["stage"] = stage
            if compile_s is not None:
                rows[0]["compile_s"] = round(compile_s, 2)
            end = it + n
            if cfg.eval_envs and (end % cfg.eval_every == 0 or end == cfg.iterations):
                seed = seeds[k][0].seed
                host_params = jax.device_get(seed_part(state.params, k, cfg.seeds))  # replicated: local
                params = jax.tree.map(lambda x: x[0], host_params)  # the first learner
                key = jax.random.fold_in(jax.random.key(seed), end)
                rows[-1].update({f"eval/{s}": r for s, r in learner_eval(key, params).items()})
            metrics_log.append(rows)
            for row in rows:
                extra.log(row, row["iteration"])
        it += n
        all_seeds = jax.tree.map(lambda m: m.reshape(-1, *m.shape[2:]), metrics) if cfg.seeds > 1 else metrics
        stage = schedule.advance(stages, stage, it, learner_return(all_seeds, pop))
        if it - last_saved >= cfg.checkpoint_every or it == cfg.iterations:
            save_seeds(cfg, seeds, it, state, pop, stage)
            last_saved = it
        if progress is not None:
            shown = {"stage": stage} if stages else {}
            progress.update(it, **shown, **progress_fields(all_seeds, sps * cfg.seeds, pop))
    if progress is not None:
        progress.close()
    for extra in extras:
        extra.close()
    if cfg.resume:
        distributed.on_main(write_configs)
    return run_dir


def seed_part(tree: Any, k: int, seeds: int) -> Any:
    """Seed k's part of `tree`, whose leaves have a leading seed axis when there are several `seeds`."""
    return tree if seeds == 1 else jax.tree.map(lambda x: x[k], tree)


def save_seeds(
    cfg: TrainConfig, seeds: list[tuple[TrainConfig, Path]], it: int, state: RunnerState, pop, stage: int
) -> None:
    """Policy, then checkpoint (with the stage to resume in), of every seed at iteration `it` (every process
    takes part). The policy goes first, so a checkpoint always has its policy: an interruption between the
    two leaves a policy ahead of the checkpoints, which the resumed run reaches again (and skips)."""
    host = distributed.to_host(state)
    for k, (seed_cfg, seed_dir) in enumerate(seeds):
        seed_state = seed_part(host, k, cfg.seeds)
        export_policy(cfg, seed_dir, it, seed_state.params, pop)
        ckpt_dir = seed_dir / "checkpoints"
        if it not in checkpoint.all_steps(ckpt_dir):  # else saved before an interruption: the same state
            metadata = {**config_dict(seed_cfg), "stage": stage}
            checkpoint.save(ckpt_dir, it, seed_state, metadata=metadata, keep=cfg.keep_checkpoints)


def export_policy(cfg: TrainConfig, seed_dir: Path, it: int, params: Any, pop: population.Population) -> None:
    """Write the learners' params (stacked [S_l, ...]) to `seed_dir/policy/<it>` unless that step exists."""
    if it in checkpoint.all_steps(seed_dir / population.POLICY_DIR):
        return
    meta = {"net": population.json_net(cfg.net), "n_learners": len(pop.learners), "slots": cfg.slots}
    path = seed_dir / population.POLICY_DIR
    checkpoint.save(path, it, {"params": params}, metadata=meta, keep=cfg.keep_checkpoints)


def restore_seeds(
    cfg: TrainConfig, ckpt_dirs: list[Path], state: RunnerState, program: Program, stage: int, pop
) -> tuple[RunnerState, int]:
    """The state and stage from the latest checkpoint that every seed has and can read (unchanged if none
    has one). An unreadable checkpoint (a truncated or emptied file) is skipped with a warning naming it, for
    the one before; a checkpoint of another config raises. A seed whose policy export is missing at that
    step (an interruption between the two writes of an older version) gets it re-exported."""
    steps = [checkpoint.all_steps(d) for d in ckpt_dirs]
    if not any(steps):
        return state, stage
    if not all(steps):
        missing = [str(d.parent) for d, s in zip(ckpt_dirs, steps, strict=True) if not s]
        raise ValueError(f"cannot resume: no checkpoint in {missing}; start again with --overwrite")
    lead = int(cfg.seeds > 1)
    template = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[lead:], x.dtype), state)
    for step in sorted(set.intersection(*map(set, steps)), reverse=True):
        try:
            restored = [checkpoint.restore(d, template, step) for d in ckpt_dirs]
            stage = int(checkpoint.read_metadata(ckpt_dirs[0], step).get("stage", stage))
        except checkpoint.CheckpointMismatchError:
            raise
        except Exception as err:  # noqa: BLE001 - orbax, json and OS errors of a damaged checkpoint
            where = [str(d / str(step)) for d in ckpt_dirs]
            print(f"warning: {where} unreadable ({type(err).__name__}: {err}); trying the checkpoint before",
                  file=sys.stderr)  # fmt: skip
            continue
        for restored_state, ckpt_dir in zip(restored, ckpt_dirs, strict=True):
            export_policy(cfg, ckpt_dir.parent, step, restored_state.params, pop)
        host = restored[0] if cfg.seeds == 1 else population.stack(restored)
        return distributed.put(host, program.shardings), stage
    raise ValueError(f"cannot resume: no readable checkpoint in {[str(d) for d in ckpt_dirs]}")


USAGE = """Train independent conv-LSTM PPO learners (or behaviour cloning) beside experts in a jaxsocial
environment. Every option below is a flag; `--preset small|paper|expert` picks the defaults first.

  python -m jaxsocial.train --env goalcycle3                  # the small default, minutes on 2 CPU cores
  python -m jaxsocial.train --preset paper --env goalcycle3   # the paper's network and PPO (for GPUs)
  python -m jaxsocial.train --resume runs/goalcycle3-s0       # continue a run with its own config

Environments: {envs}. Results go to runs_dir/run_name: config.json, metrics.jsonl, checkpoints/, policy/."""


def config_from_dict(values: dict[str, Any]) -> TrainConfig:
    """A TrainConfig from `config_dict` output (config.json): nested configs rebuilt, lists made tuples,
    fields added since the run was written take their defaults."""

    def build(cls, raw: dict[str, Any]):
        kwargs, defaults = {}, cls()
        for field in dataclasses.fields(cls):
            if field.name not in raw:
                continue
            value = raw[field.name]
            default = getattr(defaults, field.name)
            if dataclasses.is_dataclass(default):
                value = build(type(default), value)
            elif isinstance(value, list):
                value = tuple(value)
            kwargs[field.name] = value
        return cls(**kwargs)

    return build(TrainConfig, values)


def _resume_from(argv: list[str]) -> tuple[TrainConfig | None, list[str]]:
    """`--resume RUN_DIR`: the run's saved config (to resume with) and argv without the path."""
    for i, arg in enumerate(argv[:-1]):
        if arg == "--resume" and not argv[i + 1].startswith("-"):
            run_dir = Path(argv[i + 1])
            if not (run_dir / logs.CONFIG_FILE).is_file():
                raise SystemExit(
                    f"error: --resume {run_dir}: no {logs.CONFIG_FILE} there (not a run directory)"
                )
            saved = config_from_dict(logs.read_config(run_dir))
            saved = dataclasses.replace(saved, runs_dir=str(run_dir.parent), run_name=run_dir.name)
            return saved, argv[:i] + argv[i + 2 :]
    return None, argv


def parse_args(argv: list[str]) -> TrainConfig:
    """Parse the CLI: `--preset NAME` picks the defaults, every TrainConfig field is a flag; `--resume
    RUN_DIR` starts from the run's saved config instead (flags given with it still apply)."""
    import tyro

    saved, argv = _resume_from(argv)
    default = saved
    if saved is None:
        preset = "small"
        for i, arg in enumerate(argv):  # '--preset NAME' or '--preset=NAME' (the last one counts)
            if arg == "--preset":
                preset = argv[i + 1] if i + 1 < len(argv) else ""
            elif arg.startswith("--preset="):
                preset = arg.removeprefix("--preset=")
        if preset not in PRESETS:
            raise SystemExit(f"unknown --preset {preset!r}; choose one of {sorted(PRESETS)}")
        default = PRESETS[preset]
    usage = USAGE.format(envs=", ".join(jaxsocial.registered_envs()))
    cfg = tyro.cli(
        TrainConfig, default=default, args=argv, description=usage, prog="python -m jaxsocial.train"
    )
    return cfg if saved is None else dataclasses.replace(cfg, resume=True, overwrite=False)


def main(argv: list[str] | None = None) -> None:
    cfg = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        run_dir = run(cfg)
    except (ValueError, FileExistsError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from err
    except OSError as err:  # e.g. an unwritable runs_dir or a full disk while checkpointing
        where = f" ({err.filename})" if err.filename else ""
        raise SystemExit(
            f"error: cannot write the run{where}: {err.strerror or err}. Checkpoints and metrics written "
            "before this are kept; fix the cause and continue with --resume."
        ) from err
    if distributed.is_main():
        seed_dirs = [d for _, d in seed_runs(cfg, run_dir)]
        rows = logs.read_metrics(seed_dirs[0])
        where = f" ({len(seed_dirs)} seeds: s{cfg.seed}/ ...)" if len(seed_dirs) > 1 else ""
        print(f"wrote {run_dir}{where} ({len(rows)} iterations)")


if __name__ == "__main__":
    main()
