"""PPO for one recurrent learner, with the paper's details (appendix): GAE, clipped policy loss, value MSE,
entropy bonus and the auxiliary observation loss; minibatches of trajectory segments seeded with stored LSTM
states; hidden states and advantages recomputed every few minibatches; KL early stop and hard-limit revert.

Everything here is for a single learner; the trainer maps it over learner slots. The devices the batch is
split over are a `devices.Devices` (`dp`, one device by default): the network runs on each device's share,
the losses' means and the gradient are taken over the whole batch, so the result is that of one device.
Hyperparameters: `ppo_config.PPOConfig`.
Shapes: T rollout steps, E environments, L segment length, C = T / L segments per environment.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from jaxsocial.agents import network
from jaxsocial.agents.devices import ONE_DEVICE, Devices
from jaxsocial.agents.network import NetworkConfig
from jaxsocial.agents.ppo_config import PPOConfig
from jaxsocial.env.batching import any_in_batch


class Batch(NamedTuple):
    """One learner's rollout. Time axis first; obs has T + 1 steps (the last one bootstraps).

    obs: uint8[T+1, E, 21, 21, 3] (symbolic: int8[T+1, E, 7, 7, 4]); resets: bool[T+1, E] (the step starts
    a new episode: reset the LSTM);
    actions: int32[T, E]; logp: float32[T, E] rollout log-probabilities; rewards: float32[T, E];
    terminated: bool[T, E] (the agent reached a terminal state, no bootstrap); agent_done: bool[T, E] (its
    episode ended after this step: it terminated or the environment's episode ended, `info["done"]`);
    final_values: float32[T, E] value of `info["final_obs"]` where the episode was truncated (bootstrap
    through the time limit); valid: bool[T, E] the agent was acting (not done earlier);
    carry0: the LSTM state before step 0 (network.Carry of float32[E, H]); attention: int32[T, E, K] each
    other slot's cell in the learner's view (`observe.attention_targets`), None without an attention head.
    values: float32[T+1, E] the rollout policy's values (the last of the bootstrap step) and segment_carries:
    its LSTM states before each segment's first step (Carry of float32[C, E, H]); both given, they are the
    targets of minibatch 0 (`rollout_targets`: what its recompute would compute, without the unroll), both
    None, minibatch 0 recomputes them. The rollout makes it of its steps (`rollout.ppo_batch`).
    """

    obs: jax.Array
    resets: jax.Array
    actions: jax.Array
    logp: jax.Array
    rewards: jax.Array
    terminated: jax.Array
    agent_done: jax.Array
    final_values: jax.Array
    valid: jax.Array
    carry0: network.Carry
    attention: jax.Array | None = None
    values: jax.Array | None = None
    segment_carries: network.Carry | None = None


def gae(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    terminated: jax.Array,
    agent_done: jax.Array,
    gamma: float,
    lam: float,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation over a [T, ...] time axis.

    `next_values[t]` is the value of the state after step t (for a truncated episode, the value of its final
    observation); it is ignored where `terminated[t]`. The recursion is cut where `agent_done[t]`.
    Returns (advantages, returns = advantages + values), float32[T, ...].
    """
    delta = rewards + gamma * next_values * (1.0 - terminated) - values

    def backward(next_adv, inputs):
        d, cut = inputs
        adv = d + gamma * lam * (1.0 - cut) * next_adv
        return adv, adv

    _, adv = jax.lax.scan(
        backward, jnp.zeros_like(delta[0]), (delta, agent_done.astype(jnp.float32)), reverse=True
    )
    return adv, adv + values


class Targets(NamedTuple):
    """Recomputed per rollout: segment-start LSTM states (Carry of float32[C, E, H]), advantages and returns
    float32[T, E]."""

    carries: network.Carry
    advantages: jax.Array
    returns: jax.Array


BATCH_ENV_AXES = Batch(**{name: 1 for name in Batch._fields})._replace(carry0=0)
"""The environment axis of each Batch field."""
TARGETS_ENV_AXES = Targets(carries=1, advantages=1, returns=1)


def recompute(
    params, net_cfg: NetworkConfig, ppo_cfg: PPOConfig, batch: Batch, dp: Devices = ONE_DEVICE
) -> Targets:
    """Unroll the current network over the whole rollout: new segment-start hidden states, values and GAE.

    Every environment on its own, so each device of `dp` computes its environments' targets. The bootstrap
    values of truncated episodes (`batch.final_values`) stay those of the rollout policy: they need the
    pre-reset observation, which the batch does not keep (one value per truncation, at most a couple per
    environment and rollout).
    """
    local = dp.per_device(
        functools.partial(_recompute, net_cfg=net_cfg, ppo_cfg=ppo_cfg),
        in_axes=(None, BATCH_ENV_AXES),
        out_axes=TARGETS_ENV_AXES,
    )
    return local(params, batch)


def _recompute(params, batch: Batch, net_cfg: NetworkConfig, ppo_cfg: PPOConfig) -> Targets:
    """`recompute` on one device."""
    length = ppo_cfg.segment_length
    n_steps = batch.actions.shape[0]

    def unroll_segment(carry, segment):
        obs, resets = segment
        new_carry, out = network.unroll(params, net_cfg, carry, obs, resets)
        return new_carry, (carry, out.value)

    segments = jax.tree.map(
        lambda x: x[:n_steps].reshape(n_steps // length, length, *x.shape[1:]), (batch.obs, batch.resets)
    )
    last_carry, (carries, values) = jax.lax.scan(unroll_segment, batch.carry0, segments)
    values = values.reshape(n_steps, *values.shape[2:])
    _, last = network.unroll(params, net_cfg, last_carry, batch.obs[-1:], batch.resets[-1:])
    return Targets(carries, *advantages(ppo_cfg, batch, jnp.concatenate([values, last.value], axis=0)))


def advantages(ppo_cfg: PPOConfig, batch: Batch, values: jax.Array) -> tuple[jax.Array, jax.Array]:
    """GAE of values float32[T+1, E] (the last bootstraps) over the batch's rewards, where a truncated
    episode bootstraps from the value of its final observation (`batch.final_values`): (advantages,
    returns), float32[T, E] each."""
    truncated = batch.agent_done & ~batch.terminated
    next_values = jnp.where(truncated, batch.final_values, values[1:])
    return gae(
        batch.rewards,
        values[:-1],
        next_values,
        batch.terminated,
        batch.agent_done,
        ppo_cfg.gamma,
        ppo_cfg.gae_lambda,
    )


def rollout_advantages(ppo_cfg: PPOConfig, batch: Batch) -> tuple[jax.Array, jax.Array] | None:
    """The rollout policy's `advantages`, of the values the rollout recorded (`batch.values`); None where the
    batch holds none (minibatch 0 then recomputes them)."""
    return None if batch.values is None else advantages(ppo_cfg, batch, batch.values)


def rollout_targets(ppo_cfg: PPOConfig, batch: Batch) -> Targets:
    """The targets of the rollout policy from the values and segment-start states the rollout recorded
    (`batch.values`, `batch.segment_carries`): `recompute` with the rollout's params, up to float rounding."""
    return Targets(batch.segment_carries, *rollout_advantages(ppo_cfg, batch))


def minibatch(batch: Batch, targets: Targets, idx: jax.Array, length: int) -> dict[str, jax.Array]:
    """Gather segments `idx` (int32[M]; segment c * E + e is steps c * L .. c * L + L - 1 of environment e)
    into time-major arrays [L, M, ...], reading only those steps (no copy of the whole batch)."""
    n_envs = batch.actions.shape[1]
    steps = (idx // n_envs)[None, :] * length + jnp.arange(length)[:, None]  # int32[L, M]
    envs = (idx % n_envs)[None, :]  # int32[1, M]

    def take(x, shift=0):
        return x[steps + shift, envs]

    return {
        "obs": take(batch.obs),
        "next_obs": take(batch.obs, 1),
        "resets": take(batch.resets),
        "actions": take(batch.actions),
        "logp": take(batch.logp),
        "agent_done": take(batch.agent_done),
        "valid": take(batch.valid),
        "advantages": take(targets.advantages),
        "returns": take(targets.returns),
        "carry": jax.tree.map(lambda c: c.reshape(-1, c.shape[-1])[idx], targets.carries),
        "attention": None if batch.attention is None else take(batch.attention),
    }


def _masked_mean(x: jax.Array, mask: jax.Array) -> jax.Array:
    mask = mask.astype(x.dtype)
    return jnp.sum(x * mask) / jnp.maximum(jnp.sum(mask), 1.0)


LOSS_METRICS = ("policy_loss", "value_loss", "entropy", "kl", "clip_frac", "ratio_mean")
"""`loss_fn`'s metrics (float32 scalars) of every network; `loss_metric_names` adds its heads' losses."""


def loss_metric_names(net_cfg: NetworkConfig) -> tuple[str, ...]:
    """The names of `loss_fn`'s metrics for `net_cfg`: `LOSS_METRICS`, then "aux_loss" with a frame
    auxiliary head and "attention_loss" with the attention head."""
    heads = (("aux_loss",) if net_cfg.frame_aux != "none" else ()) + (
        ("attention_loss",) if net_cfg.attention else ()
    )
    return LOSS_METRICS + heads


def loss_fn(
    params, net_cfg: NetworkConfig, ppo_cfg: PPOConfig, mb: dict[str, jax.Array], dp: Devices = ONE_DEVICE
):
    """The paper's total loss on one minibatch: L_pi + c_V L_V + c_aux L_aux - c_ent H (+ c_att L_att with
    the attention head).

    Returns (loss, metrics dict with 'kl' = estimated KL(rollout || current) on valid steps). The network
    runs on each device of `dp` on its segments of the minibatch ([L, M] arrays split along M).
    """

    def unroll(params, carry, obs, resets):
        return network.unroll(params, net_cfg, carry, obs, resets)

    def aux_part(params, hidden, actions, target, weight):  # f32[1], one per device, summed below
        return network.aux_loss(params, net_cfg, hidden, actions, target, weight, dp.axis_name)[None]

    unroll = dp.per_device(unroll, in_axes=(None, 0, 1, 1), out_axes=(0, 1))
    aux_part = dp.per_device(aux_part, in_axes=(None, 1, 1, 1, 1), out_axes=0)
    _, out = unroll(params, mb["carry"], mb["obs"], mb["resets"])
    valid = mb["valid"]
    log_probs = jax.nn.log_softmax(out.logits)
    logp = jnp.take_along_axis(log_probs, mb["actions"][..., None], -1)[..., 0]
    log_ratio = logp - mb["logp"]
    ratio = jnp.exp(log_ratio)
    adv = mb["advantages"]
    if ppo_cfg.normalize_advantages:
        mean = _masked_mean(adv, valid)
        std = jnp.sqrt(_masked_mean((adv - mean) ** 2, valid))
        adv = (adv - mean) / (std + 1e-8)
    policy_loss = _masked_mean(
        -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - ppo_cfg.clip, 1 + ppo_cfg.clip) * adv), valid
    )
    value_loss = _masked_mean((out.value - mb["returns"]) ** 2, valid)
    entropy = _masked_mean(-jnp.sum(jnp.exp(log_probs) * log_probs, -1), valid)
    kl = _masked_mean(ratio - 1.0 - log_ratio, valid)
    loss = policy_loss + ppo_cfg.value_coef * value_loss - ppo_cfg.entropy_coef * entropy
    clip_frac = _masked_mean((jnp.abs(ratio - 1.0) > ppo_cfg.clip).astype(jnp.float32), valid)
    values = (policy_loss, value_loss, entropy, kl, clip_frac, _masked_mean(ratio, valid))
    metrics = dict(zip(LOSS_METRICS, values, strict=True))
    if net_cfg.frame_aux != "none":
        predict = net_cfg.frame_aux == "pred"
        target = mb["next_obs"] if predict else mb["obs"]
        # A next observation after the episode ended belongs to a new episode: nothing to predict.
        aux_mask = (valid & ~mb["agent_done"] if predict else valid).astype(jnp.float32)
        weight = aux_mask / jnp.maximum(jnp.sum(aux_mask), 1.0)  # the masked mean of the frames' errors
        metrics["aux_loss"] = jnp.sum(aux_part(params, out.hidden, mb["actions"], target, weight))
        loss = loss + ppo_cfg.aux_coef * metrics["aux_loss"]
    if net_cfg.attention:
        weight = valid.astype(jnp.float32) / jnp.maximum(jnp.sum(valid), 1.0)
        metrics["attention_loss"] = network.attention_loss(
            params, net_cfg, out.hidden, mb["attention"], weight
        )
        loss = loss + ppo_cfg.attention_coef * metrics["attention_loss"]
    return loss, metrics


def make_optimizer(ppo_cfg: PPOConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(ppo_cfg.max_grad_norm), optax.adam(ppo_cfg.lr, eps=1e-5))


class UpdateState(NamedTuple):
    """The minibatch loop's state: the learner's params and optimiser state, and the loop's bookkeeping."""

    params: dict
    opt_state: optax.OptState
    running: jax.Array  # bool[]: the minibatch loop goes on
    reverted: jax.Array  # bool[]: the hard KL limit was hit and the update was undone
    steps: jax.Array  # int32[]: minibatch updates applied
    targets: Targets


def kl_stop(kl: jax.Array, running: jax.Array, ppo_cfg: PPOConfig) -> tuple[jax.Array, jax.Array]:
    """(apply, revert), bool[] each, for a minibatch whose params are at KL `kl` float32[] from the rollout
    policy while the loop is `running`: apply its step while the KL is at most `kl_target`; revert the whole
    update once it exceeds `kl_hard_limit`. The loop ends unless the step applies."""
    apply = running & (kl <= ppo_cfg.kl_target)
    revert = running & (kl > ppo_cfg.kl_hard_limit)
    return apply, revert


def keep_or_revert(apply: jax.Array, revert: jax.Array, new, old, first):
    """Leaf by leaf, of trees of one structure: `first` (before the update) where `revert`, else `new` (after
    this minibatch's step) where `apply`, else `old` (before it)."""
    return jax.tree.map(lambda n, o, f: jnp.where(revert, f, jnp.where(apply, n, o)), new, old, first)


def minibatch_step(
    state: UpdateState,
    inputs: tuple[jax.Array, jax.Array],
    first: tuple[dict, optax.OptState],
    batch: Batch,
    net_cfg: NetworkConfig,
    ppo_cfg: PPOConfig,
    dp: Devices = ONE_DEVICE,
) -> tuple[UpdateState, dict[str, jax.Array]]:
    """Minibatch m of the update (`inputs` = (m int32[], key)): targets recomputed before minibatches k, 2k,
    ... (and 0 without the rollout's), `minibatch_segments` segments drawn, one gradient step, kept, ended
    or reverted to `first` (the params and optimiser state before the update) by `kl_stop`. Returns the new
    state and the minibatch's `loss_fn` metrics."""
    m, key = inputs
    from_rollout = batch.values is not None
    targets = jax.lax.cond(
        (m % ppo_cfg.recompute_every == 0) & ((m > 0) | (not from_rollout)),
        lambda: recompute(state.params, net_cfg, ppo_cfg, batch, dp),
        lambda: state.targets,
    )
    n_segments = batch.actions.shape[0] // ppo_cfg.segment_length * batch.actions.shape[1]
    idx = jax.random.choice(key, n_segments, (ppo_cfg.minibatch_segments,), replace=False)
    mb = minibatch(batch, targets, idx, ppo_cfg.segment_length)
    mb = dp.shard(mb, {name: int(name != "carry") for name in mb})  # [L, M, ...] along M, carry [M, H]
    (_, metrics), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params, net_cfg, ppo_cfg, mb, dp)
    apply, revert = kl_stop(metrics["kl"], state.running, ppo_cfg)
    updates, opt_state = make_optimizer(ppo_cfg).update(grads, state.opt_state, state.params)
    params = keep_or_revert(apply, revert, optax.apply_updates(state.params, updates), state.params, first[0])
    opt_state = keep_or_revert(apply, revert, opt_state, state.opt_state, first[1])
    reverted = state.reverted | revert
    return UpdateState(params, opt_state, apply, reverted, state.steps + apply, targets), metrics


def skipped_step(
    net_cfg: NetworkConfig, state: UpdateState, inputs
) -> tuple[UpdateState, dict[str, jax.Array]]:
    """A minibatch after the stop (or revert): the state as it is and `loss_fn`'s metrics as zeros, without a
    recompute or a gradient (nor a trace of them: `loss_metric_names` names the metrics)."""
    return state, {name: jnp.zeros((), jnp.float32) for name in loss_metric_names(net_cfg)}


def step_or_skip(step: Callable, net_cfg: NetworkConfig, state: UpdateState, inputs):
    """`step(state, inputs)` while the loop runs, else `skipped_step`. Returns the new state and (the
    metrics, whether the loop ran). Under vmap (learners, seeds) the step runs while any member is running;
    the others discard it."""
    new_state, metrics = jax.lax.cond(
        any_in_batch(state.running), step, functools.partial(skipped_step, net_cfg), state, inputs
    )
    return new_state, (metrics, state.running)


def update(
    key: jax.Array,
    params,
    opt_state,
    net_cfg: NetworkConfig,
    ppo_cfg: PPOConfig,
    batch: Batch,
    dp: Devices = ONE_DEVICE,
    rollout_gae: tuple[jax.Array, jax.Array] | None = None,
) -> tuple[dict, optax.OptState, dict[str, jax.Array]]:
    """One PPO update of one learner on its rollout (the paper's minibatch loop): `num_minibatches`
    `minibatch_step`s in a scan, those after the KL stop skipped (`step_or_skip`).

    Minibatch 0 trains on `rollout_gae`, the rollout policy's advantages and returns float32[T, E]
    (`rollout_advantages`, which `rollout.ppo_update` computes before it calls this; None: computed here),
    with the segment-start states the rollout recorded; without them (a batch with no values) minibatch 0
    recomputes the targets. Returns new params, optimiser state and metrics (means over the minibatches that
    ran, the last KL, the minibatches applied, whether it reverted). `dp`: the devices the batch is split over
    (see the module docstring), `batch` laid out over them by the caller (``dp.shard(batch,
    BATCH_ENV_AXES)``, as `rollout.ppo_update` does).
    """
    if rollout_gae is None:
        rollout_gae = rollout_advantages(ppo_cfg, batch)
    if rollout_gae is not None:
        targets0 = Targets(batch.segment_carries, *rollout_gae)
    else:
        targets0 = jax.tree.map(
            jnp.zeros_like, jax.eval_shape(lambda: recompute(params, net_cfg, ppo_cfg, batch))
        )
    init = UpdateState(params, opt_state, jnp.array(True), jnp.array(False), jnp.array(0), targets0)
    step = functools.partial(
        minibatch_step, first=(params, opt_state), batch=batch, net_cfg=net_cfg, ppo_cfg=ppo_cfg, dp=dp
    )
    steps = (jnp.arange(ppo_cfg.num_minibatches), jax.random.split(key, ppo_cfg.num_minibatches))
    final, (metrics, ran) = jax.lax.scan(functools.partial(step_or_skip, step, net_cfg), init, steps)
    summary = {name: _masked_mean(value, ran) for name, value in metrics.items()}
    summary["kl_last"] = metrics["kl"][jnp.maximum(jnp.sum(ran) - 1, 0)]
    summary["minibatches"] = final.steps.astype(jnp.float32)
    summary["reverted"] = final.reverted.astype(jnp.float32)
    return final.params, final.opt_state, summary
