"""Behaviour cloning: the learner's network is trained to output the demonstrators' actions from the
demonstrators' own egocentric observations (cross-entropy, Adam). The paper's imitation-learning baseline,
which, unlike the social learners, gets the experts' observations and actions.

The trainer collects demonstrations inside its jitted rollout (every scripted-expert and frozen slot is a
demonstrator; `python -m jaxsocial.train --algo bc`) and calls `update` once per iteration. The network's
value and auxiliary heads are not trained.
Shapes: T rollout steps, B demonstration streams (environments x demonstrators).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from jaxsocial.agents import network
from jaxsocial.agents.bc_config import BCConfig
from jaxsocial.agents.network import NetworkConfig


class Demonstration(NamedTuple):
    """The demonstrators' steps of a rollout (`rollout.record_demonstrations`), time-major: obs uint8[T, E, D,
    21, 21, 3] (symbolic: int8[T, E, D, 7, 7, 4]) their views, resets bool[T, E] the step starts an episode,
    actions int32[T, D, E], valid bool[T, D, E] the demonstrator was acting. Without the time axis: one step.
    """

    obs: jax.Array
    resets: jax.Array
    actions: jax.Array
    valid: jax.Array


def streams(demos: Demonstration) -> Demonstration:
    """The demonstrations as E * D streams, environment-major and demonstrator-minor: obs [T, E * D, ...],
    resets, actions and valid [T, E * D] (the arguments of `update`)."""
    n_steps, n_envs, n_demo = demos.obs.shape[:3]

    def flat(x):  # [T, E, D, ...] -> [T, E * D, ...]
        return x.reshape(n_steps, n_envs * n_demo, *x.shape[3:])

    obs = flat(demos.obs)
    resets = jnp.repeat(demos.resets, n_demo, axis=1)
    actions, valid = (flat(jnp.moveaxis(x, 1, 2)) for x in (demos.actions, demos.valid))
    return Demonstration(obs, resets, actions, valid)


def make_optimizer(bc_cfg: BCConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(bc_cfg.max_grad_norm), optax.adam(bc_cfg.lr))


def loss_fn(params, net_cfg: NetworkConfig, carry: network.Carry, obs, resets, actions, valid):
    """Mean cross-entropy of the demonstrators' actions over valid steps.

    obs uint8[T, B, 21, 21, 3] (or int8[T, B, 7, 7, 4]); resets bool[T, B]; actions int32[T, B]; valid
    bool[T, B] (the demonstrator was acting). Returns (loss, (final carry, metrics)).
    """
    carry, out = network.unroll(params, net_cfg, carry, obs, resets)
    log_probs = jax.nn.log_softmax(out.logits)
    nll = -jnp.take_along_axis(log_probs, actions[..., None], -1)[..., 0]
    weight = valid.astype(jnp.float32)
    count = jnp.maximum(weight.sum(), 1.0)
    loss = jnp.sum(nll * weight) / count
    accuracy = jnp.sum((jnp.argmax(out.logits, -1) == actions) * weight) / count
    return loss, (carry, {"bc_loss": loss, "bc_accuracy": accuracy})


def update(
    params,
    opt_state,
    carry: network.Carry,
    net_cfg: NetworkConfig,
    bc_cfg: BCConfig,
    obs,
    resets,
    actions,
    valid,
):
    """`bc_cfg.epochs` gradient steps on one batch of demonstrations (arguments as in `loss_fn`).

    The LSTM runs over the batch from `carry`, the demonstration streams' state at its start. Returns new
    params and optimiser state, the carry at the end of the batch for the next one (computed by the last
    step's forward pass, i.e. with the params before that step) and the metrics of the first step (the
    fit to fresh data).
    """
    optimizer = make_optimizer(bc_cfg)
    grad_fn = jax.value_and_grad(loss_fn, has_aux=True)

    def epoch(state, _):
        params, opt_state = state
        (_, (end_carry, metrics)), grads = grad_fn(params, net_cfg, carry, obs, resets, actions, valid)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), (end_carry, metrics)

    (params, opt_state), (end_carries, metrics) = jax.lax.scan(
        epoch, (params, opt_state), None, bc_cfg.epochs
    )
    last = jax.tree.map(lambda x: x[-1], end_carries)
    return params, opt_state, last, jax.tree.map(lambda x: x[0], metrics)
