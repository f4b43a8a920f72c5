"""One training iteration, top to bottom (`iteration`): every slot acts in E environments for T steps (one
`lax.scan`), then the learners learn from them, by PPO (GAE, then `ppo.update`, learner after learner:
`ppo_update`) or by behaviour cloning from the demonstrators (`bc.update`), and the `RunnerState` they carry
between iterations. `jaxsocial.run.loop.make_program` scans it over iterations.

Everything static (slots, network, environment, hyperparameters) is a `Wiring`, made once by `wiring`.
Names: `done` bool[E] an environment's episode ended (`info["done"]`); `agent_done` bool[..., E] an agent's
episode ended (it terminated, or `done`); `resets` bool[E] the step starts an episode (the previous `done`).
Shapes: E environments, N agents, T rollout steps, S neural slots (S_l learners first, then frozen
policies), K rendered views (`program_observers`), D demonstrators, H LSTM units.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from jaxsocial.agents import acting, bc, network, population, ppo
from jaxsocial.agents.bc_config import BCConfig
from jaxsocial.agents.devices import ONE_DEVICE, Devices
from jaxsocial.agents.ppo_config import PPOConfig
from jaxsocial.env import core, observe
from jaxsocial.env.batching import any_in_batch
from jaxsocial.env.types import EnvParams, EnvState


class RunnerState(NamedTuple):
    """The whole training state between iterations (a pytree; checkpointed at chunk boundaries)."""

    params: Any  # the learners' params stacked [S_l, ...] (every neural slot's: `all_params`)
    opt_state: Any  # learner optimiser states stacked [S_l, ...]
    env_states: EnvState  # [E]
    obs: jax.Array  # uint8[E, K, 21, 21, 3] (symbolic: int8[E, K, 7, 7, 4]), the views of `program_observers`
    resets: jax.Array  # bool[E]: the next step starts an episode
    slots: acting.SlotState  # neural slots' LSTM states [S, E, H], experts' memory, last rewards
    demo_carry: network.Carry | None  # bc: learners' LSTM states on the demonstration streams [S_l, E*D, H]
    episode_return: jax.Array  # float32[E, N] return so far in the current episode
    key: jax.Array
    iteration: jax.Array  # int32[]


def program_observers(pop: population.Population, algo: str) -> tuple[int, ...]:
    """The slots whose views a program of `algo` renders (`Population.observers`; behaviour cloning trains
    on the demonstrators' views too), so a step beside two scripted experts renders one view, not three."""
    return pop.observers(cloned=algo == "bc")


class LearnerStep(NamedTuple):
    """The learners' record of one rollout step (`record_learners`); the scan stacks them into [T, ...] and
    `ppo_batch` makes each learner's `ppo.Batch` of them. Leaves in `ppo.Batch`'s order.

    obs: uint8[E, S_l, 21, 21, 3] (symbolic: int8[E, S_l, 7, 7, 4]) the learners' views; resets: bool[E];
    actions: int32[S_l, E]; logp, rewards, final_values, values: float32[S_l, E]; terminated, agent_done,
    valid: bool[S_l, E]; attention: int32[S_l, E, N-1] with an attention head (`observe.attention_targets`),
    else None; carry: the learners' LSTM states before the step (Carry of float32[S_l, E, H])."""

    obs: jax.Array
    resets: jax.Array
    actions: jax.Array
    logp: jax.Array
    rewards: jax.Array
    terminated: jax.Array
    agent_done: jax.Array
    final_values: jax.Array
    valid: jax.Array
    attention: jax.Array | None
    values: jax.Array
    carry: network.Carry


@dataclasses.dataclass(frozen=True)
class Wiring:
    """The static side of one program: its slots `pop` in the environment `env_params`, the network, the
    algorithm ('ppo' or 'bc') and its hyperparameters, E = `num_envs`, T = `rollout_steps`, and the index
    arrays derived from them (made once by `wiring`, outside any trace)."""

    pop: population.Population
    env_params: EnvParams
    net_cfg: network.NetworkConfig
    ppo_cfg: PPOConfig
    bc_cfg: BCConfig
    algo: str
    num_envs: int
    rollout_steps: int
    observers: tuple[int, ...]  # the slots whose views are rendered (`program_observers`)
    learners: jax.Array  # int32[S_l] the learner slots
    learner_views: jax.Array  # int32[S_l] their rows of the rendered views
    training_slots: jax.Array  # int32[S_l] (bc: [D]) the slots whose actions are trained on
    training_views: jax.Array  # int32[S_l] (bc: [D]) their rows of the rendered views

    @property
    def cloning(self) -> bool:
        return self.algo == "bc"

    @property
    def n_learners(self) -> int:
        return len(self.pop.learners)

    @property
    def n_demo_streams(self) -> int:
        """E * D: behaviour cloning's demonstration streams, environment-major."""
        return self.num_envs * len(self.pop.demonstrators)


def wiring(
    pop: population.Population,
    env_params: EnvParams,
    net_cfg: network.NetworkConfig,
    ppo_cfg: PPOConfig,
    bc_cfg: BCConfig,
    algo: str,
    num_envs: int,
    rollout_steps: int,
) -> Wiring:
    """The `Wiring` of a program (arguments as its fields)."""
    observers = program_observers(pop, algo)
    training = pop.demonstrators if algo == "bc" else pop.learners
    return Wiring(
        pop=pop,
        env_params=env_params,
        net_cfg=net_cfg,
        ppo_cfg=ppo_cfg,
        bc_cfg=bc_cfg,
        algo=algo,
        num_envs=num_envs,
        rollout_steps=rollout_steps,
        observers=observers,
        learners=jnp.asarray(pop.learners),
        learner_views=jnp.asarray(acting.view_rows(pop.learners, observers)),
        training_slots=jnp.asarray(training),
        training_views=jnp.asarray(acting.view_rows(training, observers)),
    )


def optimizer(w: Wiring) -> optax.GradientTransformation:
    """The learners' optimiser (PPO's or behaviour cloning's)."""
    return bc.make_optimizer(w.bc_cfg) if w.cloning else ppo.make_optimizer(w.ppo_cfg)


def init(w: Wiring, key: jax.Array) -> RunnerState:
    """The state before the first iteration: fresh learners, every environment reset."""
    k_params, k_env, k_run = jax.random.split(key, 3)
    params = jax.vmap(network.init, in_axes=(0, None))(jax.random.split(k_params, w.n_learners), w.net_cfg)
    reset = functools.partial(core.reset, observers=w.observers)
    obs, env_states = jax.vmap(reset, in_axes=(0, None))(jax.random.split(k_env, w.num_envs), w.env_params)
    return RunnerState(
        params=params,
        opt_state=jax.vmap(optimizer(w).init)(params),
        env_states=env_states,
        obs=obs,
        resets=jnp.ones(w.num_envs, bool),
        slots=acting.init_slot_state(w.pop, w.net_cfg, w.env_params, w.num_envs),
        demo_carry=network.initial_carry(w.net_cfg, (w.n_learners, w.n_demo_streams)) if w.cloning else None,
        episode_return=jnp.zeros((w.num_envs, w.env_params.n_agents), jnp.float32),
        key=k_run,
        iteration=jnp.zeros((), jnp.int32),
    )


def all_params(state: RunnerState, frozen_params) -> Any:
    """Every neural slot's params, stacked [S, ...]: the learners', then the frozen slots' (or None)."""
    if frozen_params is None:
        return state.params
    return jax.tree.map(lambda a, b: jnp.concatenate([a, b]), state.params, frozen_params)


def _attention_targets(w: Wiring, env_states: EnvState) -> jax.Array | None:
    """int32[S_l, E, N-1] where each learner sees the other agents (`observe.attention_targets`), or None
    without an attention head."""
    if not w.net_cfg.attention:
        return None
    targets = jax.vmap(observe.attention_targets, in_axes=(0, None))(env_states, w.env_params)
    return jnp.moveaxis(targets[:, w.learners], 1, 0)


def iteration(
    w: Wiring, state: RunnerState, frozen_params, dp: Devices = ONE_DEVICE
) -> tuple[RunnerState, dict[str, jax.Array], tuple[jax.Array, jax.Array]]:
    """One training iteration: every slot acts in every environment for T steps, then every learner learns
    from them. `frozen_params`: the frozen slots' params stacked [S - S_l, ...] (or None); `dp`: the devices
    the PPO update splits its batch over. Returns the state after it (its key advanced), the learners'
    losses ({name: float32[S_l]}) and the episodes that ended at each step (the sum of their returns and
    their count per agent, float32[T, N] each)."""
    key, k_rollout, k_update = jax.random.split(state.key, 3)
    slot_params = all_params(state, frozen_params)  # [S, ...]: the learners', then the frozen slots'
    carry0 = jax.tree.map(lambda c: c[: w.n_learners], state.slots.carry)  # the learners' LSTM states

    # COLLECT: T steps of every environment, a scan of env_step
    def env_step(carry, key):
        state, slot_params = carry
        k_act, k_env = jax.random.split(key)
        # ACT: every slot on the same joint state; the neural slots sample from their networks' policies
        actions, slots, logp, values = _act(w, k_act, slot_params, state)
        # STEP every environment; the last views of truncated episodes are valued to bootstrap them
        obs, env_states, reward, terminated, _, info = core.step_batch(
            jax.random.split(k_env, w.num_envs), state.env_states, actions, w.env_params, w.observers
        )
        final_values = truncation_values(w, slot_params, slots.carry, info)
        # RECORD the episodes that ended and the step: the learners', or the demonstrators' to clone
        episode_return, ended = ended_episodes(state, reward, info["done"])
        if w.cloning:
            step = record_demonstrations(w, state, actions)
        else:
            step = record_learners(w, state, actions, logp, values, reward, terminated, info, final_values)
        state = state._replace(
            env_states=env_states,
            obs=obs,
            resets=info["done"],
            slots=acting.with_rewards(slots, reward),
            episode_return=jnp.where(info["done"][:, None], 0.0, episode_return),
        )
        return (state, slot_params), (step, ended)

    keys = jax.random.split(k_rollout, w.rollout_steps)
    (state, _), (traj, ended) = jax.lax.scan(env_step, (state, slot_params), keys)
    if w.cloning:  # BEHAVIOUR CLONING: the learners fit the demonstrators' actions
        state, losses = bc_update(w, state, traj)
        return state._replace(key=key), losses, ended
    # BATCH each learner's steps, bootstrapped by the values of the views after the last step
    bootstrap = acting.values(
        w.pop, w.net_cfg, slot_params, state.slots.carry, state.obs, state.resets, w.observers
    )
    learner_obs = state.obs[:, w.learner_views]
    batch = ppo_batch(
        traj, learner_obs, state.resets, bootstrap[: w.n_learners], carry0, w.ppo_cfg.segment_length
    )
    # ADVANTAGE and UPDATE, learner after learner (`ppo_update`): GAE of the values the rollout recorded
    # (`ppo.rollout_advantages`), then PPO's minibatch loop from them (`ppo.update`, which recomputes them)
    state, losses = ppo_update(w, state, batch, k_update, dp)
    return state._replace(key=key), losses, ended


def _act(w: Wiring, key: jax.Array, slot_params, state: RunnerState):
    """`acting.act` of every slot on the joint state `state`, with every neural slot's params [S, ...]:
    actions int32[E, N], the slots' new `acting.SlotState`, logp and values float32[S, E]."""
    slots, obs, env_states, resets = state.slots, state.obs, state.env_states, state.resets
    return acting.act(
        key, w.pop, w.net_cfg, w.env_params, slot_params, slots, obs, env_states, resets, w.observers
    )


def truncation_values(w: Wiring, slot_params, carry: network.Carry, info: dict) -> jax.Array:
    """float32[S, E] every neural slot's value of its view where the episode ended (`info["final_obs"]`,
    before the reset), continuing from the LSTM states `carry` [S, E, H]; zeros in a step without an end."""
    return jax.lax.cond(
        any_in_batch(info["done"]),
        lambda: acting.values(w.pop, w.net_cfg, slot_params, carry, info["final_obs"], observers=w.observers),
        lambda: jnp.zeros((len(w.pop.neural), w.num_envs), jnp.float32),
    )


def ended_episodes(state: RunnerState, reward: jax.Array, done: jax.Array):
    """The returns so far with the step's rewards float32[E, N] added, and the episodes that ended with the
    step (`done` bool[E]): per agent, the sum of their returns and their count, float32[N] each (an agent
    counts the episodes it took part in)."""
    episode_return = state.episode_return + reward
    ended = (done[:, None] & state.env_states.present).astype(jnp.float32)
    return episode_return, (jnp.sum(episode_return * ended, 0), jnp.sum(ended, 0))


def record_learners(
    w: Wiring, state: RunnerState, actions, logp, values, reward, terminated, info: dict, final_values
) -> LearnerStep:
    """The learners' step from the step's `state` (before it), every slot's actions int32[E, N], the neural
    slots' logp and values float32[S, E], every agent's reward float32[E, N] and terminated bool[E, N],
    `info` and `truncation_values`."""
    n_learners = w.n_learners
    agent_done = terminated | info["done"][:, None]
    return LearnerStep(
        obs=state.obs[:, w.training_views],
        resets=state.resets,
        actions=actions[:, w.training_slots].T,
        logp=logp[:n_learners],
        rewards=reward[:, w.learners].T,
        terminated=terminated[:, w.learners].T,
        agent_done=agent_done[:, w.learners].T,
        final_values=final_values[:n_learners],
        valid=state.env_states.active[:, w.training_slots].T,
        attention=_attention_targets(w, state.env_states),
        values=values[:n_learners],
        carry=jax.tree.map(lambda c: c[:n_learners], state.slots.carry),
    )


def record_demonstrations(w: Wiring, state: RunnerState, actions: jax.Array) -> bc.Demonstration:
    """The demonstrators' step, from the step's `state` (before it) and every slot's actions int32[E, N]."""
    return bc.Demonstration(
        obs=state.obs[:, w.training_views],
        resets=state.resets,
        actions=actions[:, w.training_slots].T,
        valid=state.env_states.active[:, w.training_slots].T,
    )


def ppo_batch(
    traj: LearnerStep,
    last_obs: jax.Array,
    last_resets: jax.Array,
    last_values: jax.Array,
    carry0: network.Carry,
    segment_length: int,
) -> ppo.Batch:
    """The learners' `ppo.Batch`es, stacked [S_l, T(+1), E, ...], of a rollout `traj` (the scan-stacked
    `LearnerStep`s, [T, ...]) that ended with the learners' observations `last_obs` [E, S_l, ...],
    `last_resets` bool[E] and values `last_values` float32[S_l, E] (the bootstrap step), starting from the
    learners' LSTM states `carry0`; the segment-start states are those before every `segment_length`-th
    step."""
    obs = jnp.concatenate([traj.obs, last_obs[None]], 0)  # [T + 1, E, S_l, ...]
    resets = jnp.concatenate([traj.resets, last_resets[None]], 0)  # [T + 1, E], shared by the learners
    n_learners = last_obs.shape[1]
    per_learner = traj._replace(obs=None, resets=None)  # the rest are [T, S_l, E, ...]
    step = jax.tree.map(lambda x: jnp.moveaxis(x, 1, 0), per_learner)
    return ppo.Batch(
        obs=jnp.moveaxis(obs, 2, 0),
        resets=jnp.broadcast_to(resets, (n_learners, *resets.shape)),
        actions=step.actions,
        logp=step.logp,
        rewards=step.rewards,
        terminated=step.terminated,
        agent_done=step.agent_done,
        final_values=step.final_values,
        valid=step.valid,
        carry0=carry0,
        attention=step.attention,
        values=jnp.concatenate([step.values, last_values[:, None]], 1),
        segment_carries=jax.tree.map(lambda c: c[:, ::segment_length], step.carry),
    )


def ppo_update(
    w: Wiring, state: RunnerState, batch: ppo.Batch, key: jax.Array, dp: Devices = ONE_DEVICE
) -> tuple[RunnerState, dict[str, jax.Array]]:
    """Every learner's advantages and PPO update on its `batch` (`ppo_batch`, stacked [S_l, ...]): GAE of
    the values the rollout recorded (`ppo.rollout_advantages`), then `ppo.update` from them. Returns the
    state with the new params and optimiser states, and the losses ({name: float32[S_l]})."""

    # Learners are updated one after another (`lax.map`, same result as a vmap): XLA:CPU stalled on the
    # vmapped paper-size network, whose convolutions in frame batches are themselves a `lax.map`.
    def update(args):
        key, params, opt_state, learner_batch = args
        learner_batch = dp.shard(learner_batch, ppo.BATCH_ENV_AXES)  # each device its environments
        advantages = ppo.rollout_advantages(w.ppo_cfg, learner_batch)  # (advantages, returns) float32[T, E]
        return ppo.update(key, params, opt_state, w.net_cfg, w.ppo_cfg, learner_batch, dp, advantages)

    new_params, new_opt, losses = jax.lax.map(
        update, (jax.random.split(key, w.n_learners), state.params, state.opt_state, batch)
    )
    return state._replace(params=new_params, opt_state=new_opt), losses


def bc_update(
    w: Wiring, state: RunnerState, traj: bc.Demonstration
) -> tuple[RunnerState, dict[str, jax.Array]]:
    """Every learner's behaviour-cloning update (`bc.update`) on the rollout's demonstrations `traj`
    (`record_demonstrations`, stacked [T, ...]) as E * D streams (`bc.streams`). Returns the state with the
    new params, optimiser states and streams' LSTM states, and the losses."""
    demos = bc.streams(traj)

    def update(args):
        params, opt_state, carry = args
        return bc.update(params, opt_state, carry, w.net_cfg, w.bc_cfg, *demos)

    new_params, new_opt, carry, losses = jax.lax.map(
        update, (state.params, state.opt_state, state.demo_carry)
    )
    return state._replace(params=new_params, opt_state=new_opt, demo_carry=carry), losses
