"""GAE, the PPO loss and update: ratio 1 on the first minibatch, stored-state replay, KL stop and revert,
and the auxiliary targets. Synthetic data and a tiny network keep these exact and fast."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from conftest import U32, reordered_tolerance

from jaxsocial.agents import network, ppo, ppo_config, rollout
from jaxsocial.agents.network import NetworkConfig
from jaxsocial.agents.ppo_config import PPOConfig

NET = NetworkConfig(conv_channels=(4, 8, 8), hidden=16, mlp=8)
T, E, L = 32, 6, 8
CFG = PPOConfig(segment_length=L, minibatch_segments=8, num_minibatches=4, lr=1e-3)
# Rollout and replay evaluate NET in other orders: its widest dot products have 72 terms (conv 3, FC), and a
# log-probability passes 3 convolutions, the FC layer, L LSTM steps and 3 MLP layers.
NET_REORDERED = reordered_tolerance(terms=72, depth=3 + 1 + L + 3)

# Jitted once for the module (eager op-by-op dispatch compiles every primitive separately and is slower).
init = jax.jit(network.init, static_argnums=1)
unroll = jax.jit(network.unroll, static_argnums=1)
decode = jax.jit(network.decode, static_argnums=1)
recompute = jax.jit(ppo.recompute, static_argnums=(1, 2))
loss = jax.jit(ppo.loss_fn, static_argnums=(1, 2))


def gae_reference(rewards, values, next_values, terminated, done, gamma, lam):
    adv = np.zeros_like(rewards)
    running = np.zeros(rewards.shape[1:])
    for t in reversed(range(len(rewards))):
        delta = rewards[t] + gamma * next_values[t] * (1 - terminated[t]) - values[t]
        running = delta + gamma * lam * (1 - done[t]) * running
        adv[t] = running
    return adv


def test_gae_matches_python_loop_with_truncation_bootstrap():
    rng = np.random.default_rng(0)
    rewards, values, next_values = (rng.normal(size=(40, 5)).astype(np.float32) for _ in range(3))
    terminated = rng.random((40, 5)) < 0.05
    done = terminated | (rng.random((40, 5)) < 0.05)  # some episodes truncated: bootstrap next_values
    gamma, lam = 0.993, 0.97
    adv, ret = ppo.gae(rewards, values, next_values, terminated, done, gamma, lam)
    expected = gae_reference(rewards, values, next_values, terminated, done, gamma, lam)
    # Both are float32 recursions adv = delta + gamma lam adv': 5 roundings a step (3 in delta, 2 in the
    # recursion) of values below |r| + |v'| + |v| + |adv|, damped by gamma lam: each is within
    # 5 u max(...) / (1 - gamma lam) of the exact advantages, so the two within twice that.
    scale = np.abs(rewards) + np.abs(next_values) + np.abs(values) + np.abs(expected)
    bound = 2 * 5 * U32 * scale.max() / (1 - gamma * lam)
    np.testing.assert_allclose(adv, expected, rtol=0, atol=bound)
    np.testing.assert_allclose(ret, expected + values, rtol=0, atol=bound + 2 * U32 * np.abs(ret).max())
    # one-step check by hand: a truncated last step bootstraps from its final value
    a, _ = ppo.gae(
        np.ones((1, 1)), np.zeros((1, 1)), np.full((1, 1), 2.0), np.zeros((1, 1)), np.ones((1, 1)), 0.5, 1
    )
    assert float(a[0, 0]) == 2.0


def synthetic_rollout(key, params, net=NET):
    """A step-by-step rollout of the network on random observations with episode boundaries."""
    k_obs, k_reset, k_act, k_rew = jax.random.split(key, 4)
    obs = jax.random.randint(k_obs, (T + 1, E, 21, 21, 3), 0, 256).astype(jnp.uint8)
    resets = jax.random.bernoulli(k_reset, 0.08, (T + 1, E)).at[0].set(True)
    carry0 = network.initial_carry(NET, (E,))

    def body(carry, inputs):
        o, r, k = inputs
        new_carry, out = network.step(params, net, carry, o, r)
        action = jax.random.categorical(k, out.logits)
        logp = jax.nn.log_softmax(out.logits)[jnp.arange(E), action]
        return new_carry, (action, logp, out.value, carry)

    last_carry, (actions, logp, values, carries) = jax.lax.scan(
        body, carry0, (obs[:T], resets[:T], jax.random.split(k_act, T))
    )
    _, last = network.step(params, net, last_carry, obs[T], resets[T])  # the bootstrap step
    done = resets[1:]
    return ppo.Batch(
        obs=obs,
        resets=resets,
        actions=actions,
        logp=logp,
        rewards=jax.random.normal(k_rew, (T, E)),
        terminated=done & (jnp.arange(E) % 2 == 0),
        agent_done=done,
        final_values=jnp.ones((T, E)),
        valid=jnp.ones((T, E), bool),
        carry0=carry0,
        values=jnp.concatenate([values, last.value[None]]),
        segment_carries=jax.tree.map(lambda c: c[::L], carries),
    )


@pytest.fixture(scope="module")
def recorded():
    """Params and a rollout that recorded its values and segment-start states (as the trainer's does)."""
    params = init(jax.random.key(0), NET)
    return params, jax.jit(synthetic_rollout, static_argnums=2)(jax.random.key(1), params)


@pytest.fixture(scope="module")
def setup(recorded):
    """Params and the rollout without its recorded values: minibatch 0 recomputes its targets."""
    params, batch = recorded
    return params, batch._replace(values=None, segment_carries=None)


def test_replay_from_stored_states_equals_step_by_step_and_ratio_is_one(setup):
    params, batch = setup
    targets = recompute(params, NET, CFG, batch)
    idx = jnp.arange(T // L * E)  # every segment, across episode boundaries
    mb = ppo.minibatch(batch, targets, idx, L)
    _, metrics = loss(params, NET, CFG, mb)
    np.testing.assert_allclose(metrics["ratio_mean"], 1.0, atol=NET_REORDERED)  # exp(d) - 1 ~ d
    assert float(metrics["kl"]) < 1e-9
    # The stored segment-start states reproduce the step-by-step rollout's log-probabilities exactly.
    _, out = unroll(params, NET, mb["carry"], mb["obs"], mb["resets"])
    logp = jnp.take_along_axis(jax.nn.log_softmax(out.logits), mb["actions"][..., None], -1)[..., 0]
    np.testing.assert_allclose(logp, mb["logp"], atol=NET_REORDERED)


def test_a_minibatch_holds_exactly_its_segments_steps(recorded):
    """Segment c * E + e is steps c * L .. c * L + L - 1 of environment e (the next frames one step later),
    and the segment-start state the targets stored for it."""
    params, batch = recorded
    targets = ppo.rollout_targets(CFG, batch)
    idx = jax.random.permutation(jax.random.key(3), T // L * E)[:5]
    mb = ppo.minibatch(batch, targets, idx, L)
    for m, segment in enumerate(np.asarray(idx)):
        c, e = divmod(int(segment), E)
        steps = slice(c * L, c * L + L)
        np.testing.assert_array_equal(mb["obs"][:, m], batch.obs[steps, e])
        np.testing.assert_array_equal(mb["next_obs"][:, m], batch.obs[c * L + 1 : c * L + L + 1, e])
        for name in ("actions", "valid", "logp"):
            np.testing.assert_array_equal(mb[name][:, m], getattr(batch, name)[steps, e])
        np.testing.assert_array_equal(mb["advantages"][:, m], targets.advantages[steps, e])
        for got, stored in zip(jax.tree.leaves(mb["carry"]), jax.tree.leaves(targets.carries), strict=True):
            np.testing.assert_array_equal(got[m], stored[c, e])


def test_rollout_targets_equal_the_recompute_with_the_rollout_params(recorded):
    params, batch = recorded
    expected = recompute(params, NET, CFG, batch)
    targets = ppo.rollout_targets(CFG, batch)
    for got, want in zip(jax.tree.leaves(targets.carries), jax.tree.leaves(expected.carries), strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=NET_REORDERED)  # tanh-bounded states
    # The values differ by NET_REORDERED of their size; an advantage sums (gamma lambda)^k-weighted
    # differences of two values a step, so it moves by at most 2 that / (1 - gamma lambda).
    size = float(jnp.abs(batch.values).max())
    bound = 2 * NET_REORDERED * size / (1 - CFG.gamma * CFG.gae_lambda)
    np.testing.assert_allclose(targets.advantages, expected.advantages, rtol=0, atol=bound)
    np.testing.assert_allclose(targets.returns, expected.returns, rtol=0, atol=bound + NET_REORDERED * size)


@pytest.mark.parametrize("aux", ["none", "pred"])
def test_update_from_rollout_targets_has_the_recomputed_update_losses(aux):
    """Minibatch 0 on the rollout's own targets: its losses are those with the targets recomputed (to 1e-5
    relative: the targets differ by float rounding, about 1e-6, see the test above), and a rollout that
    recorded its values one step late moves them far beyond that."""
    net = NetworkConfig(conv_channels=(4, 8, 8), hidden=16, mlp=8, aux=aux)
    params = init(jax.random.key(0), net)
    batch = jax.jit(synthetic_rollout, static_argnums=2)(jax.random.key(1), params, net)
    cfg = PPOConfig(**{**CFG.__dict__, "num_minibatches": 1})
    opt_state = ppo.make_optimizer(cfg).init(params)
    update = jax.jit(ppo.update, static_argnums=(3, 4))

    def losses(b):
        *_, metrics = update(jax.random.key(2), params, opt_state, net, cfg, b)
        assert float(metrics["minibatches"]) == 1.0
        names = ("policy_loss", "value_loss", "entropy", "kl", *(("aux_loss",) if aux != "none" else ()))
        return np.array([float(metrics[name]) for name in names])

    recomputed = losses(batch._replace(values=None, segment_carries=None))
    np.testing.assert_allclose(losses(batch), recomputed, rtol=1e-5, atol=1e-7)
    late = losses(batch._replace(values=jnp.roll(batch.values, 1, axis=0)))
    assert not np.allclose(late, recomputed, rtol=1e-5, atol=1e-7)


def test_minibatch_next_obs_is_the_following_step(setup):
    params, batch = setup
    targets = recompute(params, NET, CFG, batch)
    idx = jnp.array([0, E + 3, 3 * E - 1])  # segment c * E + e
    mb = ppo.minibatch(batch, targets, idx, L)
    for j, (c, e) in enumerate([(0, 0), (1, 3), (2, E - 1)]):
        np.testing.assert_array_equal(mb["obs"][:, j], batch.obs[c * L : (c + 1) * L, e])
        np.testing.assert_array_equal(mb["next_obs"][:, j], batch.obs[c * L + 1 : (c + 1) * L + 1, e])
        np.testing.assert_array_equal(mb["actions"][:, j], batch.actions[c * L : (c + 1) * L, e])


@pytest.mark.parametrize("aux", ["pred", "rec"])
def test_aux_loss_targets(setup, aux):
    params, batch = setup
    net = NetworkConfig(conv_channels=(4, 8, 8), hidden=16, mlp=8, aux=aux)
    targets = recompute(params, net, CFG, batch)
    mb = ppo.minibatch(batch, targets, jnp.arange(8), L)
    _, metrics = loss(params, net, CFG, mb)
    _, out = unroll(params, net, mb["carry"], mb["obs"], mb["resets"])
    prediction = decode(params, net, out.hidden, mb["actions"])
    target, mask = (
        (mb["next_obs"], ~mb["agent_done"]) if aux == "pred" else (mb["obs"], jnp.ones_like(mb["agent_done"]))
    )
    error = jnp.abs(prediction - target / 255.0).mean(axis=(-3, -2, -1))
    # The same decoder (4 layers after the LSTM output, at most 8 * 9 = 72 terms a dot product) in two
    # programs; the mean absolute error is a relative 1-Lipschitz function of its inputs, and each mean
    # over 21 * 21 * 3 pixels (as a tree, log2 1323 < 11 levels) adds 11 u per side.
    bound = reordered_tolerance(terms=72, depth=4) + 2 * 11 * U32
    np.testing.assert_allclose(metrics["aux_loss"], (error * mask).sum() / mask.sum(), rtol=bound)


def test_attention_loss_term_uses_the_minibatch_targets_on_valid_steps(setup):
    _, batch = setup
    net = NetworkConfig(conv_channels=(4, 8, 8), hidden=16, mlp=8, aux="attention", n_others=2)
    params = init(jax.random.key(0), net)
    cells = jax.random.randint(jax.random.key(5), (T, E, 2), 0, network.ATTENTION_CLASSES)
    batch = batch._replace(attention=cells, valid=jnp.arange(T)[:, None] < T - 5 + jnp.zeros((1, E), int))
    targets = recompute(params, net, CFG, batch)
    mb = ppo.minibatch(batch, targets, jnp.arange(8), L)
    total, metrics = loss(params, net, CFG, mb)
    _, out = unroll(params, net, mb["carry"], mb["obs"], mb["resets"])
    weight = mb["valid"] / mb["valid"].sum()
    expected = jax.jit(network.attention_loss, static_argnums=1)(
        params, net, out.hidden, mb["attention"], weight
    )
    np.testing.assert_allclose(metrics["attention_loss"], expected, rtol=1e-6)
    cfg0 = PPOConfig(**{**CFG.__dict__, "attention_coef": 0.0})
    total0, _ = loss(params, net, cfg0, mb)
    np.testing.assert_allclose(total - total0, CFG.attention_coef * expected, rtol=1e-4)
    # Its gradient reaches the LSTM, not only the head.
    grads = jax.jit(jax.grad(lambda p: ppo.loss_fn(p, net, CFG, mb)[0] - ppo.loss_fn(p, net, cfg0, mb)[0]))(
        params
    )
    assert (
        float(jnp.abs(grads["lstm"]["wi"]).max()) > 0
        and float(jnp.abs(grads["policy"]["out"]["kernel"]).max()) == 0
    )


def run_update(params, batch, cfg):
    opt_state = ppo.make_optimizer(cfg).init(params)
    fn = jax.jit(ppo.update, static_argnums=(3, 4))
    return opt_state, fn(jax.random.key(2), params, opt_state, NET, cfg, batch)


def leaves_equal(a, b):
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def test_kl_hard_limit_reverts_params_and_optimizer_state_exactly(setup):
    params, batch = setup
    cfg = PPOConfig(**{**CFG.__dict__, "lr": 0.05, "kl_target": 1e-12, "kl_hard_limit": 1e-12})
    opt0, (new_params, new_opt, metrics) = run_update(params, batch, cfg)
    assert float(metrics["reverted"]) == 1.0
    assert leaves_equal(new_params, params) and leaves_equal(new_opt, opt0)


def test_kl_target_stops_early_and_normal_update_changes_params(setup):
    params, batch = setup
    cfg = PPOConfig(**{**CFG.__dict__, "lr": 0.05, "kl_target": 1e-12, "kl_hard_limit": 10.0})
    _, (stopped, _, metrics) = run_update(params, batch, cfg)
    assert float(metrics["minibatches"]) == 1.0 and float(metrics["reverted"]) == 0.0
    assert not leaves_equal(stopped, params)
    _, (_, _, metrics) = run_update(params, batch, CFG)
    assert float(metrics["minibatches"]) == CFG.num_minibatches


def test_minibatches_after_the_kl_stop_compute_no_loss_or_gradient(setup, monkeypatch):
    params, batch = setup
    calls = []

    def counted_loss(*args, **kwargs):
        jax.debug.callback(lambda: calls.append(1))
        return loss_fn(*args, **kwargs)

    loss_fn = ppo.loss_fn
    monkeypatch.setattr(ppo, "loss_fn", counted_loss)
    # A config of its own, so that no update compiled by another test (without the counter) is reused.
    changes = {"lr": 0.05, "kl_target": 1e-12, "kl_hard_limit": 9.0, "num_minibatches": 5}
    cfg = PPOConfig(**{**CFG.__dict__, **changes})
    _, (_, _, metrics) = run_update(params, batch, cfg)
    jax.effects_barrier()
    # Minibatch 0 is applied; minibatch 1 measures the KL, stops the loop, and is the last to compute.
    assert float(metrics["minibatches"]) == 1.0
    assert len(calls) == 2


@pytest.mark.parametrize(
    ("kl", "running", "expected"),
    [
        (0.005, True, (True, False)),
        (0.02, True, (False, False)),
        (0.05, True, (False, True)),
        (0.05, False, (False, False)),
    ],
)
def test_kl_stop_applies_up_to_the_target_and_reverts_past_the_hard_limit_while_running(
    kl, running, expected
):
    cfg = PPOConfig(kl_target=0.01, kl_hard_limit=0.03)
    apply, revert = ppo.kl_stop(jnp.float32(kl), jnp.array(running), cfg)
    assert (bool(apply), bool(revert)) == expected


@pytest.mark.parametrize(
    ("apply", "revert", "expected"), [(True, False, 1.0), (False, False, 2.0), (False, True, 3.0)]
)
def test_keep_or_revert_takes_the_new_the_old_or_the_first_tree(apply, revert, expected):
    trees = [{"w": jnp.full(2, value), "b": jnp.float32(value)} for value in (1.0, 2.0, 3.0)]
    kept = ppo.keep_or_revert(jnp.array(apply), jnp.array(revert), *trees)
    assert leaves_equal(kept, trees[int(expected) - 1])


def update_state(params, batch, running=True):
    """The minibatch loop's state before a step: fresh optimiser, the targets of `params`."""
    opt_state = ppo.make_optimizer(CFG).init(params)
    targets = recompute(params, NET, CFG, batch)
    return ppo.UpdateState(params, opt_state, jnp.array(running), jnp.array(False), jnp.array(0), targets)


def one_step(state, m, key, batch, cfg=CFG):
    step = functools.partial(
        ppo.minibatch_step, first=(state.params, state.opt_state), batch=batch, net_cfg=NET
    )
    step_or_skip = functools.partial(ppo.step_or_skip, functools.partial(step, ppo_cfg=cfg), NET)
    return jax.jit(step_or_skip)(state, (m, key))


def test_a_minibatch_step_is_one_optimiser_step_on_its_drawn_segments(setup):
    params, batch = setup
    state, key = update_state(params, batch), jax.random.key(7)
    new, (metrics, ran) = one_step(state, jnp.int32(1), key, batch)  # minibatch 1: no recompute
    idx = jax.random.choice(key, T // L * E, (CFG.minibatch_segments,), replace=False)
    mb = ppo.minibatch(batch, state.targets, idx, L)
    grads = jax.jit(jax.grad(lambda p: ppo.loss_fn(p, NET, CFG, mb)[0]))(params)
    updates, _ = ppo.make_optimizer(CFG).update(grads, state.opt_state, params)
    for x, y in zip(
        jax.tree.leaves(new.params), jax.tree.leaves(optax.apply_updates(params, updates)), strict=True
    ):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)
    assert bool(ran) and bool(new.running) and int(new.steps) == 1 and not bool(new.reverted)
    assert leaves_equal(new.targets, state.targets) and float(metrics["kl"]) < CFG.kl_target


def test_a_minibatch_step_past_the_hard_limit_reverts_to_the_first_params(setup):
    params, batch = setup
    far = batch._replace(logp=batch.logp + 0.5)  # KL about 0.11 from the rollout policy
    state = update_state(params, far)._replace(params=jax.tree.map(lambda x: x + 1e-3, params))
    first = update_state(params, far)
    step = functools.partial(
        ppo.minibatch_step, first=(first.params, first.opt_state), batch=far, net_cfg=NET
    )
    new, metrics = jax.jit(functools.partial(step, ppo_cfg=CFG))(state, (jnp.int32(1), jax.random.key(7)))
    assert float(metrics["kl"]) > CFG.kl_hard_limit
    assert bool(new.reverted) and not bool(new.running) and int(new.steps) == 0
    assert leaves_equal(new.params, params) and leaves_equal(new.opt_state, first.opt_state)


def test_a_stopped_loop_skips_the_step_keeping_its_state_with_zero_metrics(setup):
    params, batch = setup
    state = update_state(params, batch, running=False)
    new, (metrics, ran) = one_step(state, jnp.int32(1), jax.random.key(7), batch)
    assert not bool(ran) and leaves_equal(new, state)
    assert all(float(value) == 0.0 for value in metrics.values())


def test_vmapped_learners_stopping_at_different_minibatches_equal_their_own_updates(setup):
    """Learner 1's rollout policy is far from its params (KL 0.11 at once): it reverts on minibatch 0 while
    learner 0 runs every minibatch; the vmapped update skips nothing that learner 0 still needs."""
    params, batch = setup
    far = batch._replace(logp=batch.logp + 0.5)
    batches = jax.tree.map(lambda a, b: jnp.stack([a, b]), batch, far)
    opt_state = ppo.make_optimizer(CFG).init(params)
    update = jax.jit(jax.vmap(ppo.update, in_axes=(None, None, None, None, None, 0)), static_argnums=(3, 4))
    both = update(jax.random.key(2), params, opt_state, NET, CFG, batches)
    for i, b in enumerate((batch, far)):
        _, alone = run_update(params, b, CFG)
        for x, y in zip(jax.tree.leaves(alone), jax.tree.leaves(both), strict=True):
            np.testing.assert_allclose(y[i], x, rtol=1e-5, atol=1e-6)
    assert both[2]["minibatches"].tolist() == [CFG.num_minibatches, 0.0]
    assert both[2]["reverted"].tolist() == [0.0, 1.0]


@pytest.mark.parametrize(
    ("changes", "steps", "envs", "message"),
    [
        ({"segment_length": 16}, 40, 8, "must divide"),
        ({"minibatch_segments": 512}, 64, 8, "larger than the batch"),
        ({"kl_target": 0.1, "kl_hard_limit": 0.03, "minibatch_segments": 8}, 64, 8, "kl_target"),
    ],
)
def test_impossible_configs_are_rejected(changes, steps, envs, message):
    with pytest.raises(ValueError, match=message):
        ppo_config.validate(PPOConfig(**changes), steps, envs)


@pytest.mark.slow  # compiles TINY's chunk twice; the fast path keeps the synthetic-rollout test above
def test_trainer_records_the_targets_its_recompute_would_compute(monkeypatch):
    """The TINY run's first iteration (episodes end and are truncated inside its rollouts) with minibatch 0
    on the targets the rollout recorded, and with them recomputed: the same losses up to float rounding."""
    from conftest import TINY

    from jaxsocial import train

    def first_iteration():
        init, run_chunk, _ = train.make_train(TINY)
        _, metrics = jax.jit(run_chunk, static_argnums=2)(jax.jit(init)(jax.random.key(0)), None, 1)
        return {name: float(metrics[name][0, 0]) for name in ("policy_loss", "value_loss", "entropy", "kl")}

    recorded = first_iteration()
    record = rollout.ppo_batch
    without_targets = {"values": None, "segment_carries": None}
    monkeypatch.setattr(rollout, "ppo_batch", lambda *a: record(*a)._replace(**without_targets))
    recomputed = first_iteration()
    for name, value in recorded.items():
        np.testing.assert_allclose(value, recomputed[name], rtol=1e-5, atol=1e-7, err_msg=name)
